// Voxel set -> closed triangle surface, through OpenVDB:
//   lattice voxels -> BoolGrid topology -> tools::topologyToLevelSet -> tools::volumeToMesh.
// Implemented in vdb_bridge.cpp, the only translation unit that includes OpenVDB.
#pragma once

#include <vector>

#include "core/math.h"
#include "render/mesh.h"

namespace physketch::render {

struct VoxelMeshOptions {
  int halfWidth = 3;        // narrow-band half width of the level set (voxels)
  int closingSteps = 0;     // dilate/erode steps that close small gaps (voxels)
  int smoothingSteps = 1;   // level-set smoothing steps; 0 keeps the blocky "legolized" look
  double adaptivity = 0.0;  // volumeToMesh adaptivity; 0 gives watertight, non-self-intersecting meshes
};

// voxels: integer lattice coordinates of occupied cells; the centre of cell (i,j,k)
// is origin + h*(i,j,k) in metres. Returns a closed mesh around the union of the
// cells (each cell a cube of edge h), normals outward, triangles counter-clockwise.
// An empty voxel list gives an empty mesh.
TriangleMesh meshVoxels(const std::vector<Vec3i>& voxels, double voxelSize, const Vec3& origin,
                        const VoxelMeshOptions& options = {});

}  // namespace physketch::render
