// Materials: named physical behaviour plus a display colour.
#pragma once

#include <array>
#include <string>
#include <vector>

namespace physketch {

// v1 simulates rigid bodies only; the enum grows with the solvers (soft, fluid, cloth, ...).
enum class MaterialKind { kRigid };
const char* toString(MaterialKind kind);
// Returns false when `name` is not a known kind.
bool parseMaterialKind(const std::string& name, MaterialKind& out);

struct Material {
  std::string name;
  MaterialKind kind = MaterialKind::kRigid;
  double density = 1000.0;  // kg/m^3; particle mass = density * spacing^3
  double friction = 0.5;    // Coulomb coefficient against the ground, [0, 2]
  std::array<float, 3> color{0.7f, 0.7f, 0.7f};  // linear RGB in [0, 1]
};

// Index of the material called `name`, or -1.
int findMaterial(const std::vector<Material>& materials, const std::string& name);

}  // namespace physketch
