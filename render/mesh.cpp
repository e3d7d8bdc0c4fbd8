#include "render/mesh.h"

#include <charconv>
#include <cmath>
#include <cstdio>

#include "core/atomic_file.h"
#include "core/error.h"

namespace physketch::render {
namespace {

// std::to_chars gives the shortest text that reads back to the same float and, unlike
// printf, ignores the C locale (a "," decimal separator would corrupt the OBJ).
void appendFloat(std::string& out, float v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v);
  out.append(buf, r.ptr);
}

void appendVec(std::string& out, const char* tag, const Vec3f& v) {
  out += tag;
  for (int c = 0; c < 3; ++c) {
    out += ' ';
    appendFloat(out, v[c]);
  }
  out += '\n';
}

}  // namespace

TriangleMesh tubeMesh(const std::vector<std::vector<Vec3>>& chains, double radius, int sides) {
  if (!(radius > 0.0) || !std::isfinite(radius)) throw RuntimeError("tubeMesh: radius must be finite and > 0 m");
  if (sides < 3) throw RuntimeError("tubeMesh: need at least 3 sides");
  TriangleMesh mesh;
  const double step = 2.0 * 3.14159265358979323846 / sides;
  for (std::size_t c = 0; c < chains.size(); ++c) {
    std::vector<Vec3> pts = chains[c];
    if (pts.empty()) continue;
    for (const Vec3& q : pts)
      if (!q.allFinite()) throw RuntimeError("tubeMesh: chain " + std::to_string(c) + " has a point that is not finite");
    if (pts.size() == 1) pts = {pts[0] - Vec3(radius, 0, 0), pts[0] + Vec3(radius, 0, 0)};
    const std::size_t n = pts.size();
    // Direction at each point (central differences; one-sided at the ends; the previous one
    // where two points coincide, +x for the first).
    std::vector<Vec3> dir(n);
    for (std::size_t i = 0; i < n; ++i) {
      const Vec3 d = pts[std::min(i + 1, n - 1)] - pts[i > 0 ? i - 1 : 0];
      dir[i] = d.norm() > 0.0 ? d.normalized() : (i > 0 ? dir[i - 1] : Vec3::UnitX());
    }
    Vec3 normal = dir[0].unitOrthogonal();
    const auto first = static_cast<std::uint32_t>(mesh.positions.size());
    for (std::size_t i = 0; i < n; ++i) {
      if (i > 0) {
        // Parallel transport: turn the frame by the rotation taking the last direction to this one.
        const Eigen::Quaterniond turn = Eigen::Quaterniond::FromTwoVectors(dir[i - 1], dir[i]);
        normal = (turn * normal - (turn * normal).dot(dir[i]) * dir[i]).normalized();
      }
      const Vec3 binormal = dir[i].cross(normal);
      for (int k = 0; k < sides; ++k) {
        const Vec3 radial = std::cos(k * step) * normal + std::sin(k * step) * binormal;
        mesh.positions.push_back((pts[i] + radius * radial).cast<float>());
        mesh.normals.push_back(radial.cast<float>());
      }
    }
    auto ring = [&](std::size_t i, int k) { return first + static_cast<std::uint32_t>(i * sides + ((k % sides) + sides) % sides); };
    for (std::size_t i = 0; i + 1 < n; ++i)
      for (int k = 0; k < sides; ++k) {
        // Counter-clockwise seen from outside: the ring turns right-handed about dir.
        mesh.indices.insert(mesh.indices.end(), {ring(i, k), ring(i + 1, k + 1), ring(i + 1, k)});
        mesh.indices.insert(mesh.indices.end(), {ring(i, k), ring(i, k + 1), ring(i + 1, k + 1)});
      }
    // Caps: a fan around each end point, facing away from the tube.
    const auto startCentre = static_cast<std::uint32_t>(mesh.positions.size());
    mesh.positions.push_back(pts.front().cast<float>());
    mesh.normals.push_back((-dir.front()).cast<float>());
    const auto endCentre = static_cast<std::uint32_t>(mesh.positions.size());
    mesh.positions.push_back(pts.back().cast<float>());
    mesh.normals.push_back(dir.back().cast<float>());
    for (int k = 0; k < sides; ++k) {
      mesh.indices.insert(mesh.indices.end(), {startCentre, ring(0, k + 1), ring(0, k)});
      mesh.indices.insert(mesh.indices.end(), {endCentre, ring(n - 1, k), ring(n - 1, k + 1)});
    }
  }
  return mesh;
}

TriangleMesh sheetMesh(const std::vector<Vec3>& nodes, const std::vector<std::uint8_t>& alive, int rows, int cols,
                       double halfThickness) {
  if (!(halfThickness > 0.0) || !std::isfinite(halfThickness))
    throw RuntimeError("sheetMesh: the half thickness must be finite and > 0 m");
  if (rows < 1 || cols < 1 || nodes.size() != std::size_t(rows) * std::size_t(cols) || alive.size() != nodes.size())
    throw RuntimeError("sheetMesh: " + std::to_string(nodes.size()) + " nodes and " + std::to_string(alive.size()) +
                       " alive flags for a " + std::to_string(rows) + " x " + std::to_string(cols) + " lattice");
  const auto at = [&](int r, int c) { return std::size_t(r) * std::size_t(cols) + std::size_t(c); };
  for (std::size_t k = 0; k < nodes.size(); ++k)
    if (alive[k] && !nodes[k].allFinite())
      throw RuntimeError("sheetMesh: node " + std::to_string(k) + " is not finite");
  // A cell (r, c) spans nodes (r, c), (r, c+1), (r+1, c+1), (r+1, c).
  const auto live = [&](int r, int c) {
    return r >= 0 && c >= 0 && r + 1 < rows && c + 1 < cols && alive[at(r, c)] && alive[at(r, c + 1)] &&
           alive[at(r + 1, c + 1)] && alive[at(r + 1, c)];
  };
  std::vector<Vec3> normal(nodes.size(), Vec3::Zero());
  for (int r = 0; r + 1 < rows; ++r)
    for (int c = 0; c + 1 < cols; ++c) {
      if (!live(r, c)) continue;
      // Twice the cell's vector area (the diagonals' cross product), in the node order's sense.
      const Vec3 n = (nodes[at(r + 1, c + 1)] - nodes[at(r, c)]).cross(nodes[at(r + 1, c)] - nodes[at(r, c + 1)]);
      for (std::size_t k : {at(r, c), at(r, c + 1), at(r + 1, c + 1), at(r + 1, c)}) normal[k] += n;
    }
  TriangleMesh mesh;
  // Two vertices per node, on its +normal and -normal side (a node without a normal gets
  // none: it is in no live cell).
  std::vector<std::uint32_t> top(nodes.size(), 0);
  for (std::size_t k = 0; k < nodes.size(); ++k) {
    if (!(normal[k].norm() > 0.0)) continue;
    const Vec3 n = normal[k].normalized();
    top[k] = static_cast<std::uint32_t>(mesh.positions.size());
    mesh.positions.push_back((nodes[k] + halfThickness * n).cast<float>());
    mesh.normals.push_back(n.cast<float>());
    mesh.positions.push_back((nodes[k] - halfThickness * n).cast<float>());
    mesh.normals.push_back((-n).cast<float>());
  }
  const auto up = [&](std::size_t k) { return top[k]; };
  const auto down = [&](std::size_t k) { return top[k] + 1; };
  for (int r = 0; r + 1 < rows; ++r)
    for (int c = 0; c + 1 < cols; ++c) {
      if (!live(r, c)) continue;
      const std::size_t a = at(r, c), b = at(r, c + 1), e = at(r + 1, c + 1), d = at(r + 1, c);
      // Counter-clockwise seen from the +normal side: a, b, e, d.
      mesh.indices.insert(mesh.indices.end(), {up(a), up(b), up(e), up(a), up(e), up(d)});
      mesh.indices.insert(mesh.indices.end(), {down(a), down(e), down(b), down(a), down(d), down(e)});
      // Walls on the edges no other live cell shares, in the same order (u to v), facing out:
      // (v - u) x n, the right of the edge seen from the +normal side.
      const std::size_t corner[4] = {a, b, e, d};
      const bool shared[4] = {live(r - 1, c), live(r, c + 1), live(r + 1, c), live(r, c - 1)};
      for (int side = 0; side < 4; ++side) {
        if (shared[side]) continue;
        const std::size_t u = corner[side], v = corner[(side + 1) % 4];
        const Vec3 n = 0.5 * (normal[u].normalized() + normal[v].normalized());
        const Vec3 out = (nodes[v] - nodes[u]).cross(n);
        const Vec3f o = (out.norm() > 0.0 ? out.normalized() : Vec3(n.unitOrthogonal())).cast<float>();
        const auto w = static_cast<std::uint32_t>(mesh.positions.size());
        for (std::uint32_t src : {up(u), down(u), down(v), up(v)}) {
          const Vec3f copy = mesh.positions[src];  // a copy: push_back may move the array
          mesh.positions.push_back(copy);
          mesh.normals.push_back(o);
        }
        mesh.indices.insert(mesh.indices.end(), {w, w + 1, w + 2, w, w + 2, w + 3});
      }
    }
  return mesh;
}

namespace {
// The sum of f(p0, p1, p2) over the mesh's triangles, in double, in index order.
template <class F>
double sumOverTriangles(const TriangleMesh& mesh, F f) {
  double sum = 0.0;
  for (std::size_t t = 0; t + 2 < mesh.indices.size(); t += 3)
    sum += f(mesh.positions[mesh.indices[t]].cast<double>(), mesh.positions[mesh.indices[t + 1]].cast<double>(),
             mesh.positions[mesh.indices[t + 2]].cast<double>());
  return sum;
}
}  // namespace

double enclosedVolume(const TriangleMesh& mesh) {
  return sumOverTriangles(mesh, [](const Vec3& p0, const Vec3& p1, const Vec3& p2) { return p0.dot(p1.cross(p2)) / 6.0; });
}

double surfaceArea(const TriangleMesh& mesh) {
  return sumOverTriangles(mesh, [](const Vec3& p0, const Vec3& p1, const Vec3& p2) {
    return 0.5 * (p1 - p0).cross(p2 - p0).norm();
  });
}

void writeObj(const std::string& path, const TriangleMesh& mesh) {
  const std::size_t n = mesh.positions.size();
  if (!mesh.normals.empty() && mesh.normals.size() != n) {
    throw RuntimeError(path + ": mesh has " + std::to_string(mesh.normals.size()) + " normals for " +
                       std::to_string(n) + " positions");
  }
  if (mesh.indices.size() % 3 != 0) {
    throw RuntimeError(path + ": mesh index count " + std::to_string(mesh.indices.size()) +
                       " is not a multiple of 3");
  }
  for (std::uint32_t i : mesh.indices) {
    if (i >= n) {
      throw RuntimeError(path + ": mesh index " + std::to_string(i) + " out of range (" + std::to_string(n) +
                         " vertices)");
    }
  }

  // Format the whole file in memory (a few MB at most), then one fwrite.
  std::string text = "# physketch mesh: " + std::to_string(n) + " vertices, " +
                     std::to_string(mesh.triangleCount()) + " triangles, units m\n";
  text.reserve(text.size() + n * 2 * 40 + mesh.indices.size() * 12);
  for (const Vec3f& p : mesh.positions) appendVec(text, "v", p);
  for (const Vec3f& nm : mesh.normals) appendVec(text, "vn", nm);
  const bool withNormals = !mesh.normals.empty();
  for (std::size_t t = 0; t < mesh.indices.size(); t += 3) {
    text += 'f';
    for (int c = 0; c < 3; ++c) {
      const std::string idx = std::to_string(mesh.indices[t + c] + 1u);  // OBJ indices are 1-based
      text += ' ';
      text += idx;
      if (withNormals) {
        text += "//";
        text += idx;
      }
    }
    text += '\n';
  }

  AtomicFile out(path);
  if (std::fwrite(text.data(), 1, text.size(), out.file()) != text.size()) out.fail("write failed");
  out.commit();
}

}  // namespace physketch::render
