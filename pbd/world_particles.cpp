// The particle-level kinds of the PBD world: soft bodies (clustered shape matching),
// ropes and cloth (XPBD distance and bending constraints), fluids' particles, their
// contacts with each other, with rigid bodies and with the ground (Macklin et al. 2014,
// "Unified particle physics for real-time applications", Alg. 1; XPBD: Macklin et al.
// 2016). Rigid bodies stay bodies (pbd/world.cpp); a particle touching one moves it
// through its generalized inverse mass at the contact point, so coupling is two-way.
//
// Every constraint loop here is a Gauss-Seidel sweep in a fixed order (pairs by id,
// clusters by index): deterministic, the same state for any thread count.
#include <algorithm>
#include <cstdio>
#include <cmath>
#include <limits>
#include <map>
#include <tuple>
#include <unordered_map>

#include "core/error.h"
#include "core/neighbor_grid.h"
#include "pbd/cell_walk.h"
#include "pbd/cluster_kernels.h"
#include "pbd/parallel.h"
#include "pbd/shape_matching.h"
#include "pbd/world.h"

namespace physketch::pbd {

namespace {

// The predicted position x + h v (float), one expression for predict() and particleUpdate(),
// which must round it the same way (the build has -ffp-contract=off: no FMA at one site only).
inline float predicted(float x, float h, float v) { return x + h * v; }

// Coulomb friction on a position-level contact (Macklin et al. 2014, Eq. 24): the
// tangential relative displacement `t` of this substep is removed while it is within
// mu_s times the penetration depth d (static), else reduced by mu_k d (dynamic).
// Returns the displacement to remove.
Vec3 frictionCorrection(const Vec3& t, double d, double mus, double muk) {
  const double len = t.norm();
  if (len == 0.0) return Vec3::Zero();
  if (len < mus * d) return t;
  return t * std::min(muk * d / len, 1.0);
}

// Whether the cluster kernels take their AVX2 form (the same bits as the other, faster).
bool clusterAvx2() {
#if defined(__x86_64__)
  static const bool yes = __builtin_cpu_supports("avx2");
  return yes;
#else
  return false;
#endif
}

// Fluid against a solid: solid particles count as smaller (R_solid = r / 2 < R_fluid = r,
// Phys-Sketch §5.1), so the pair touches at 0.75 of its two radii, and fluid does not pass
// between two solid particles. The density constraint's boundary term keeps the fluid off
// the solid; the contact holds it at that reach.
constexpr double kFluidReach = 0.75;

Vec3 at(const std::vector<float>& x, const std::vector<float>& y, const std::vector<float>& z, std::size_t i) {
  return Vec3(x[i], y[i], z[i]);
}

void put(std::vector<float>& x, std::vector<float>& y, std::vector<float>& z, std::size_t i, const Vec3& p) {
  x[i] = float(p.x()), y[i] = float(p.y()), z[i] = float(p.z());
}

}  // namespace

// --- setup ------------------------------------------------------------------------

void PbdWorld::setupParticleBody(std::size_t b, const BodyRange& range) {
  switch (kind_[b]) {
    case MaterialKind::kSoft:
      buildClusters(b);
      clusterColoursDirty_ = true;
      break;
    case MaterialKind::kRope:
    case MaterialKind::kCloth:
      strandRadius_[b] = range.radius;
      if (kind_[b] == MaterialKind::kCloth) lattice_[b] = {range.first, range.rows, range.cols};
      buildStrand(b, range);
      break;
    default: break;  // fluid: free particles; the density pass finds their neighbours
  }
  looseDirty_ = true;
}

void PbdWorld::refreshInverseMasses(std::size_t b) {
  if (!particleLevel_) return;  // rigid bodies only: no particle-level inverse masses to keep
  const bool dyn = !isRigid(b) && moving(b);  // a sleeper is held (sleepLoose)
  for (std::int32_t i : members_[b]) {
    const auto k = std::size_t(i);
    invMassP_[k] = dyn && !pinned_[k] && alive(i) && parts_.mass[k] > 0.0f ? 1.0f / parts_.mass[k] : 0.0f;
  }
  looseDirty_ = true;
}

bool PbdWorld::hasLoose() const {
  for (std::size_t b = 0; b < kind_.size(); ++b)
    if (!isRigid(b) && mode_[b] != BodyMode::kEmpty) return true;
  return false;
}

// Clusters (Phys-Sketch Fig. 3): centres chosen greedily in particle order, each at least
// dC from every earlier centre; a cluster holds the body's particles within R of its
// centre. With R < dC a particle can lie in no cluster: it joins its nearest centre's.
void PbdWorld::buildClusters(std::size_t b) {
  const auto& mem = members_[b];
  if (mem.empty()) return;
  const double spacing = 2.0 * params_.particleRadius;
  const Material& mat = materials_[std::size_t(parts_.material[std::size_t(mem.front())])];
  const double R = mat.soft.clusterRadius * spacing, dC = mat.soft.clusterSpacing * spacing;
  const std::size_t n = mem.size();
  std::vector<float> x(n), y(n), z(n);
  for (std::size_t k = 0; k < n; ++k) {
    const auto i = std::size_t(mem[k]);
    x[k] = parts_.x[i], y[k] = parts_.y[i], z[k] = parts_.z[i];
  }
  // Centres: a hash of cells of edge dC; a candidate checks the 27 cells around it.
  const auto key = [&](double v) { return static_cast<std::int64_t>(std::floor(v / dC)); };
  const auto pack = [](std::int64_t a, std::int64_t c, std::int64_t d) {
    return (a & 0x1FFFFF) | ((c & 0x1FFFFF) << 21) | ((d & 0x1FFFFF) << 42);
  };
  std::unordered_map<std::int64_t, std::vector<std::int32_t>> cells;
  std::vector<std::int32_t> centres;
  const double dC2 = dC * dC * (1.0 - 1e-9);
  for (std::size_t k = 0; k < n; ++k) {
    const std::int64_t cx = key(x[k]), cy = key(y[k]), cz = key(z[k]);
    bool free = true;
    for (int dz = -1; dz <= 1 && free; ++dz)
      for (int dy = -1; dy <= 1 && free; ++dy)
        for (int dx = -1; dx <= 1 && free; ++dx) {
          const auto it = cells.find(pack(cx + dx, cy + dy, cz + dz));
          if (it == cells.end()) continue;
          for (std::int32_t c : it->second) {
            const double ex = x[k] - x[std::size_t(c)], ey = y[k] - y[std::size_t(c)], ez = z[k] - z[std::size_t(c)];
            if (ex * ex + ey * ey + ez * ez < dC2) {
              free = false;
              break;
            }
          }
        }
    if (!free) continue;
    centres.push_back(static_cast<std::int32_t>(k));
    cells[pack(cx, cy, cz)].push_back(static_cast<std::int32_t>(k));
  }
  // Members: the body's particles within R of each centre (a NeighborGrid of cell R).
  NeighborGrid grid;
  grid.build(x.data(), y.data(), z.data(), n, static_cast<float>(R));
  std::vector<std::vector<std::int32_t>> lists(centres.size());
  std::vector<std::uint8_t> covered(n, 0);
  for (std::size_t c = 0; c < centres.size(); ++c) {
    const std::int32_t k = centres[c];
    lists[c].push_back(k);
    covered[std::size_t(k)] = 1;
    grid.forEachNeighbor(k, static_cast<float>(R), [&](std::int32_t j) {
      lists[c].push_back(j);
      covered[std::size_t(j)] = 1;
    });
  }
  for (std::size_t k = 0; k < n; ++k) {
    if (covered[k]) continue;
    std::size_t best = 0;
    double bestD = std::numeric_limits<double>::infinity();
    for (std::size_t c = 0; c < centres.size(); ++c) {
      const auto j = std::size_t(centres[c]);
      const double d = (Vec3(x[k], y[k], z[k]) - Vec3(x[j], y[j], z[j])).squaredNorm();
      if (d < bestD) bestD = d, best = c;
    }
    lists[best].push_back(static_cast<std::int32_t>(k));
  }
  // Each particle is held to its goal by one constraint per cluster it belongs to, in
  // parallel: their compliance is that many times the per-particle one, so the particle's
  // total stiffness is 1/softCompliance = E h whatever R and dC are.
  std::size_t memberships = 0;
  for (const auto& list : lists) memberships += list.size();
  const double perParticle = double(memberships) / double(n);
  const float alpha = static_cast<float>(softCompliance(mat, spacing) * perParticle);
  for (auto& list : lists) {
    std::sort(list.begin(), list.end());
    std::vector<std::int32_t> ids(list.size());
    double m = 0.0;
    Vec3 c0 = Vec3::Zero();
    for (std::size_t k = 0; k < list.size(); ++k) {
      ids[k] = mem[std::size_t(list[k])];
      const double mi = parts_.mass[std::size_t(ids[k])];
      m += mi;
      c0 += mi * at(parts_.x, parts_.y, parts_.z, std::size_t(ids[k]));
    }
    c0 /= m;
    double extent = 0.0;
    for (std::int32_t i : ids) extent = std::max(extent, (at(parts_.x, parts_.y, parts_.z, std::size_t(i)) - c0).norm());
    clusters_.restCentre.push_back(c0);
    clusters_.extent.push_back(static_cast<float>(extent));
    for (std::int32_t i : ids) {
      const Vec3 q = at(parts_.x, parts_.y, parts_.z, std::size_t(i)) - c0;
      clusters_.qx.push_back(float(q.x())), clusters_.qy.push_back(float(q.y())), clusters_.qz.push_back(float(q.z()));
      clusters_.lambda.push_back(0.0f);
    }
    clusters_.members.add(ids, 1.0f);
    // Plasticity's parameters exist only once some cluster is plastic (then for every cluster,
    // 0 for the elastic ones): a scene without plastic_creep holds nothing for the pass.
    if (mat.soft.plasticCreep > 0.0 || !clusters_.creep.empty()) {
      clusters_.yield.resize(clusters_.compliance.size(), 0.0f);
      clusters_.creep.resize(clusters_.compliance.size(), 0.0f);
      clusters_.yield.push_back(static_cast<float>(mat.soft.plasticYield));
      clusters_.creep.push_back(static_cast<float>(mat.soft.plasticCreep));
    }
    clusters_.compliance.push_back(alpha);
    clusters_.rotation.push_back(Quat::Identity());
    clusters_.body.push_back(static_cast<std::int32_t>(b));
  }
}

// Rope: links k-(k+1) (stretch) and k-(k+2) (bending as a distance across two links, as
// FleX does). Cloth: structural and shear links of the lattice (stretch), and links two
// nodes apart along rows and columns (bending). Rest lengths are the drawn distances.
void PbdWorld::buildStrand(std::size_t b, const BodyRange& range) {
  const auto& mem = members_[b];
  const Material& mat = materials_[std::size_t(parts_.material[std::size_t(mem.front())])];
  const float stretch = static_cast<float>(mat.strand.stretchCompliance);
  const float bend = static_cast<float>(mat.strand.bendCompliance);
  // Each family-and-colour group below gets its own colour number, so that two groups next
  // to each other in the array (or two bodies' groups) never merge into one parallel run.
  std::int32_t colour = nextColour_;
  const auto link = [&](std::int32_t a, std::int32_t c, float alpha, std::int32_t via = -1) {
    if (!alive(a) || !alive(c) || (via >= 0 && !alive(via))) return;  // a hole of a cut cloth
    const float len = static_cast<float>(
        (at(parts_.x, parts_.y, parts_.z, std::size_t(a)) - at(parts_.x, parts_.y, parts_.z, std::size_t(c))).norm());
    distances_.add(a, c, len, alpha, colour);
    distanceVia_.push_back(via);
  };
  struct NextColour {  // advances the colour when a group ends, and the world's counter at the end
    std::int32_t& c;
    std::int32_t& next;
    ~NextColour() { next = c + 1; }
  } advance{colour, nextColour_};
  const std::int32_t f = range.first, n = range.count;
  if (kind_[b] == MaterialKind::kRope) {
    if (range.layout != BodyLayout::kChain)
      throw RuntimeError("PbdWorld: rope body " + std::to_string(b) + " is not laid out as a chain");
    // In colours, like the cloth's links below: even links, odd links, then the bending
    // links in pairs of pairs.
    for (std::int32_t parity = 0; parity < 2; ++parity, ++colour)
      for (std::int32_t k = parity; k + 1 < n; k += 2) link(f + k, f + k + 1, stretch);
    for (std::int32_t pair = 0; pair < 2; ++pair, ++colour)
      for (std::int32_t k = 0; k + 2 < n; ++k)
        if ((k / 2) % 2 == pair) link(f + k, f + k + 2, bend, f + k + 1);
    return;
  }
  if (range.layout != BodyLayout::kLattice || range.rows * range.cols != n)
    throw RuntimeError("PbdWorld: cloth body " + std::to_string(b) + " is not laid out as a rows x cols lattice");
  // Links go in families (along rows, along columns, both diagonals, then the skip-one
  // bending links), each family in two colours whose links share no node. One sweep per
  // substep over links emitted node by node (a row link, a column link, the diagonals, the
  // bending links of one node, then the next node's) diverged: at 30 substeps x 1
  // iteration a 45 x 45 sheet pinned at two corners reached 100 m/s within a second (a
  // standalone loop reproduced it; grouped by family it swings at 2 m/s), because within
  // a node's links the corrections chase each other around the shear triangles and the
  // velocity update turns what is left into speed. Colours also make each group's links
  // independent, the precondition for solving a colour in parallel.
  const std::int32_t rows = range.rows, cols = range.cols;
  const auto id = [&](std::int32_t r, std::int32_t c) { return f + r * cols + c; };
  for (std::int32_t parity = 0; parity < 2; ++parity, ++colour)  // along rows: by column parity
    for (std::int32_t r = 0; r < rows; ++r)
      for (std::int32_t c = parity; c + 1 < cols; c += 2) link(id(r, c), id(r, c + 1), stretch);
  for (std::int32_t parity = 0; parity < 2; ++parity, ++colour)  // along columns: by row parity
    for (std::int32_t r = parity; r + 1 < rows; r += 2)
      for (std::int32_t c = 0; c < cols; ++c) link(id(r, c), id(r + 1, c), stretch);
  for (std::int32_t parity = 0; parity < 2; ++parity, ++colour)  // one diagonal: by row parity
    for (std::int32_t r = parity; r + 1 < rows; r += 2)
      for (std::int32_t c = 0; c + 1 < cols; ++c) link(id(r, c), id(r + 1, c + 1), stretch);
  for (std::int32_t parity = 0; parity < 2; ++parity, ++colour)  // the other diagonal
    for (std::int32_t r = parity; r + 1 < rows; r += 2)
      for (std::int32_t c = 0; c + 1 < cols; ++c) link(id(r, c + 1), id(r + 1, c), stretch);
  for (std::int32_t pair = 0; pair < 2; ++pair, ++colour)  // bending along rows: by column pair
    for (std::int32_t r = 0; r < rows; ++r)
      for (std::int32_t c = 0; c + 2 < cols; ++c)
        if ((c / 2) % 2 == pair) link(id(r, c), id(r, c + 2), bend, id(r, c + 1));
  for (std::int32_t pair = 0; pair < 2; ++pair, ++colour)  // bending along columns: by row pair
    for (std::int32_t r = 0; r + 2 < rows; ++r)
      if ((r / 2) % 2 == pair)
        for (std::int32_t c = 0; c < cols; ++c) link(id(r, c), id(r + 2, c), bend, id(r + 1, c));
}

// A strand attaches where it touches another body at play: a node whose sphere (the
// strand's radius from the brush) reaches a voxel of the body, with half a spacing of slack
// for a stroke drawn against it (within radius + the voxel's half-diagonal + r of a voxel
// centre; at least 1.5 spacings): a rope by its two ends, a cloth by every node. On a fixed body
// the node is pinned; a rope end on a dynamic rigid body is held to that point of the body
// (the pail, rope and bucket of Phys-Sketch Fig. 5); on a soft body, to the nearest particle.
// Then every particle of a strand with pinned nodes gets a tether to its nearest anchor.
void PbdWorld::attachStrandEnds(std::size_t b) {
  const auto& mem = members_[b];
  if (mem.empty()) return;
  const double r = params_.particleRadius;
  const double reachDist = std::max(3.0 * r, double(strandRadius_[b]) + std::sqrt(3.0) * r + r);
  std::vector<std::int32_t> nodes;
  if (kind_[b] == MaterialKind::kRope) {
    nodes.push_back(mem.front());
    if (mem.size() > 1) nodes.push_back(mem.back());
  } else {
    nodes = mem;
  }
  // Candidates: particles of other, non-fluid bodies within reach of the strand's box.
  Eigen::AlignedBox3d box;
  for (std::int32_t i : nodes) box.extend(at(parts_.x, parts_.y, parts_.z, std::size_t(i)));
  box.min().array() -= reachDist;
  box.max().array() += reachDist;
  std::vector<float> x, y, z;
  std::vector<std::int32_t> id;
  for (std::int32_t i : nodes) {
    const auto k = std::size_t(i);
    x.push_back(parts_.x[k]), y.push_back(parts_.y[k]), z.push_back(parts_.z[k]);
    id.push_back(i);
  }
  const std::size_t nn = id.size();
  for (std::size_t o = 0; o < members_.size(); ++o) {
    if (o == b || mode_[o] == BodyMode::kEmpty || kind_[o] == MaterialKind::kFluid) continue;
    for (std::int32_t i : members_[o]) {
      const auto k = std::size_t(i);
      if (!box.contains(at(parts_.x, parts_.y, parts_.z, k))) continue;
      x.push_back(parts_.x[k]), y.push_back(parts_.y[k]), z.push_back(parts_.z[k]);
      id.push_back(i);
    }
  }
  if (id.size() == nn) return;
  NeighborGrid grid;
  grid.build(x.data(), y.data(), z.data(), x.size(), static_cast<float>(reachDist));
  for (std::size_t k = 0; k < nn; ++k) {
    std::int32_t best = -1;
    double bestD = std::numeric_limits<double>::infinity();
    grid.forEachNeighbor(static_cast<std::int32_t>(k), static_cast<float>(reachDist), [&](std::int32_t j) {
      if (std::size_t(j) < nn) return;
      const double d = (Vec3(x[k], y[k], z[k]) - Vec3(x[std::size_t(j)], y[std::size_t(j)], z[std::size_t(j)])).squaredNorm();
      if (d < bestD) bestD = d, best = j;  // ascending rank: ties keep the first
    });
    if (best < 0) continue;
    const std::int32_t i = id[k], j = id[std::size_t(best)];
    const auto o = std::size_t(parts_.group(std::size_t(j)));
    if (kind_[b] == MaterialKind::kRope) {
      // The rope's particles within its contact distance of the tied end (rest positions)
      // overlap the body it is tied to: they do not touch it.
      const Vec3 end = at(parts_.x, parts_.y, parts_.z, std::size_t(i));
      const double within = radiusOf(std::size_t(i)) + params_.particleRadius;
      for (std::int32_t m : mem)
        if ((at(parts_.x, parts_.y, parts_.z, std::size_t(m)) - end).norm() <= within)
          contactSkip_[std::size_t(m)] = static_cast<std::int32_t>(o);
    }
    if (mode_[o] == BodyMode::kFixed) {
      pinned_[std::size_t(i)] = 1;
    } else if (kind_[b] == MaterialKind::kRope && isRigid(o)) {
      Attachment a;
      a.particle = i;
      a.body = static_cast<std::int32_t>(o);
      const Motion& mo = motion_[o];
      a.local = mo.q.toRotationMatrix().transpose() * (at(parts_.x, parts_.y, parts_.z, std::size_t(i)) - mo.c);
      attachments_.push_back(a);
    } else if (kind_[b] == MaterialKind::kRope && !isRigid(o)) {
      distances_.add(i, j, static_cast<float>(std::sqrt(bestD)), 0.0f);
      distanceVia_.push_back(-1);
    }
  }
  // Phase flags follow the pins.
  setMode(static_cast<int>(b), mode_[b]);
  // Tethers: each particle to its nearest pinned node (rope: along the chain; cloth: the
  // straight rest distance, Kim et al. 2012), which it may never leave farther than that.
  std::vector<std::int32_t> anchors;
  for (std::int32_t i : mem)
    if (pinned_[std::size_t(i)]) anchors.push_back(i);
  // Only for inextensible strands: a compliant one must be free to stretch.
  const Material& mat = materials_[std::size_t(parts_.material[std::size_t(mem.front())])];
  if (anchors.empty() || anchors.size() > 1024 || mat.strand.stretchCompliance > 0.0) return;
  const auto rest = [&](std::int32_t a) { return at(parts_.x, parts_.y, parts_.z, std::size_t(a)); };
  if (kind_[b] == MaterialKind::kRope) {
    // Path length along the chain from its first particle.
    std::vector<double> s(mem.size(), 0.0);
    for (std::size_t k = 1; k < mem.size(); ++k) s[k] = s[k - 1] + (rest(mem[k]) - rest(mem[k - 1])).norm();
    std::vector<std::size_t> anchorAt;
    for (std::size_t k = 0; k < mem.size(); ++k)
      if (pinned_[std::size_t(mem[k])]) anchorAt.push_back(k);
    for (std::size_t k = 0; k < mem.size(); ++k) {
      if (pinned_[std::size_t(mem[k])]) continue;
      std::size_t best = anchorAt.front();
      for (std::size_t a : anchorAt)
        if (std::abs(s[a] - s[k]) < std::abs(s[best] - s[k])) best = a;
      tethers_.push_back({mem[k], mem[best], static_cast<float>(std::abs(s[best] - s[k]))});
    }
    for (Attachment& a : attachments_) {
      if (parts_.group(std::size_t(a.particle)) != static_cast<std::int32_t>(b)) continue;
      const auto k = std::size_t(std::find(mem.begin(), mem.end(), a.particle) - mem.begin());
      std::size_t best = anchorAt.front();
      for (std::size_t an : anchorAt)
        if (std::abs(s[an] - s[k]) < std::abs(s[best] - s[k])) best = an;
      a.anchor = mem[best];
      a.length = static_cast<float>(std::abs(s[best] - s[k]));
    }
    return;
  }
  for (std::int32_t i : mem) {
    if (pinned_[std::size_t(i)]) continue;
    std::int32_t best = anchors.front();
    for (std::int32_t a : anchors)
      if ((rest(a) - rest(i)).squaredNorm() < (rest(best) - rest(i)).squaredNorm()) best = a;
    tethers_.push_back({i, best, static_cast<float>((rest(best) - rest(i)).norm())});
  }
}

// After a removal: constraints, tethers and attachments that reach a removed particle go,
// and clusters lose their removed members (a cluster left with none goes too).
void PbdWorld::dropRemovedConstraints() {
  // A bending link goes with the node it bends over (a rope cut at k loses k-1..k+1).
  DistanceConstraints kept;
  std::vector<std::int32_t> via;
  for (std::size_t k = 0; k < distances_.size(); ++k)
    if (alive(distances_.i[k]) && alive(distances_.j[k]) && (distanceVia_[k] < 0 || alive(distanceVia_[k]))) {
      kept.add(distances_.i[k], distances_.j[k], distances_.rest[k], distances_.compliance[k], distances_.colour[k]);
      via.push_back(distanceVia_[k]);
    }
  distances_ = std::move(kept);
  distanceVia_ = std::move(via);
  tethers_.erase(std::remove_if(tethers_.begin(), tethers_.end(),
                                [&](const Tether& t) { return !alive(t.particle) || !alive(t.anchor); }),
                 tethers_.end());
  attachments_.erase(std::remove_if(attachments_.begin(), attachments_.end(),
                                    [&](const Attachment& a) {
                                      return !alive(a.particle) || mode_[std::size_t(a.body)] == BodyMode::kEmpty;
                                    }),
                     attachments_.end());
  for (Attachment& a : attachments_)
    if (a.anchor >= 0 && !alive(a.anchor)) a.anchor = -1;
  // A cut strand no longer hangs from anchors on the other side of the cut: tethers are
  // kept only while the chain between particle and anchor is whole (checked on ropes, whose
  // chain is their id order; a torn cloth keeps its straight-line tethers).
  tethers_.erase(std::remove_if(tethers_.begin(), tethers_.end(),
                                [&](const Tether& t) {
                                  const auto b = std::size_t(parts_.group(std::size_t(t.particle)));
                                  if (kind_[b] != MaterialKind::kRope) return false;
                                  const std::int32_t lo = std::min(t.particle, t.anchor), hi = std::max(t.particle, t.anchor);
                                  for (std::int32_t i = lo; i <= hi; ++i)
                                    if (!alive(i)) return true;
                                  return false;
                                }),
                 tethers_.end());
  SoftClusters kc;
  for (std::size_t c = 0; c < clusters_.members.size(); ++c) {
    std::vector<std::int32_t> ids;
    for (std::int32_t m = clusters_.members.offset[c]; m < clusters_.members.offset[c + 1]; ++m) {
      const std::int32_t i = clusters_.members.index[std::size_t(m)];
      if (!alive(i)) continue;
      ids.push_back(i);
      kc.qx.push_back(clusters_.qx[std::size_t(m)]), kc.qy.push_back(clusters_.qy[std::size_t(m)]),
          kc.qz.push_back(clusters_.qz[std::size_t(m)]);
      kc.lambda.push_back(0.0f);
    }
    if (ids.empty()) continue;
    kc.members.add(ids, 1.0f);
    kc.compliance.push_back(clusters_.compliance[c]);
    if (!clusters_.creep.empty()) {
      kc.yield.push_back(clusters_.yield[c]);
      kc.creep.push_back(clusters_.creep[c]);
    }
    kc.rotation.push_back(clusters_.rotation[c]);
    kc.body.push_back(clusters_.body[c]);
    kc.restCentre.push_back(clusters_.restCentre[c]);
    kc.extent.push_back(clusters_.extent[c]);
  }
  clusters_ = std::move(kc);
  clusterColoursDirty_ = true;
}

// Two clusters share a particle only if their centres where they were made lie within the
// sum of their extents then (membership never grows), so with cells of edge twice the
// largest extent, clusters of one colour in different cells never share one: exact, whatever
// the bodies have done since.
void PbdWorld::colourClusters() {
  const Clusters& cl = clusters_.members;
  // clusterMatch moves each member by its correction, which is the Jacobi update only while no
  // particle is a member twice (buildClusters and refresh never make one; checked here, where
  // clusters change, not per step).
  std::vector<std::int32_t> seen(parts_.size(), -1);
  for (std::size_t c = 0; c < cl.size(); ++c)
    for (std::int32_t k = cl.offset[c]; k < cl.offset[c + 1]; ++k) {
      std::int32_t& mark = seen[std::size_t(cl.index[std::size_t(k)])];
      if (mark == std::int32_t(c)) throw RuntimeError("PbdWorld::colourClusters: a particle is a member of one cluster twice");
      mark = std::int32_t(c);
    }
  double extent = 0.0;
  for (float e : clusters_.extent) extent = std::max(extent, double(e));
  const double cell = 2.0 * extent * (1.0 + 1e-6) + 1e-9;
  std::vector<std::map<std::tuple<std::int64_t, std::int64_t, std::int64_t>, std::vector<std::int32_t>>> byCell(8);
  for (std::size_t c = 0; c < cl.size(); ++c) {
    const Vec3& x = clusters_.restCentre[c];
    const auto ix = std::int64_t(std::floor(x.x() / cell)), iy = std::int64_t(std::floor(x.y() / cell)),
               iz = std::int64_t(std::floor(x.z() / cell));
    const int colour = int(ix & 1) | int(iy & 1) << 1 | int(iz & 1) << 2;
    byCell[std::size_t(colour)][{ix, iy, iz}].push_back(static_cast<std::int32_t>(c));
  }
  clusterCells_.assign(8, {});
  for (int colour = 0; colour < 8; ++colour)
    for (auto& [key, list] : byCell[std::size_t(colour)]) clusterCells_[std::size_t(colour)].push_back(std::move(list));
  clusterColoursDirty_ = false;
}

// --- the passes -----------------------------------------------------------------

void PbdWorld::predict(double h) {
  const float gx = float(params_.gravity.x() * h), gy = float(params_.gravity.y() * h), gz = float(params_.gravity.z() * h);
  const float hf = float(h);
  forRange(loose_.size(), [&](std::size_t lo, std::size_t hi) {
    for (std::size_t k = lo; k < hi; ++k) {
      const auto i = std::size_t(loose_[k]);
      groundApproach_[i] = 0.0f;
      bounceNoted_[i] = 0;
      if (invMassP_[i] > 0.0f) {
        parts_.vx[i] += gx, parts_.vy[i] += gy, parts_.vz[i] += gz;
        px_[i] = predicted(parts_.x[i], hf, parts_.vx[i]);
        py_[i] = predicted(parts_.y[i], hf, parts_.vy[i]);
        pz_[i] = predicted(parts_.z[i], hf, parts_.vz[i]);
      } else {
        px_[i] = parts_.x[i], py_[i] = parts_.y[i], pz_[i] = parts_.z[i];
      }
    }
  });
  particleBounces_.clear();
  distances_.resetMultipliers();
  std::fill(clusters_.lambda.begin(), clusters_.lambda.end(), 0.0f);
  anyBouncy_ = false;
  for (std::size_t b = 0; b < mode_.size() && !anyBouncy_; ++b) {
    anyBouncy_ = mode_[b] != BodyMode::kEmpty && restitution_[b] > 0.0;
  }
  bool bouncy = false;
  for (std::size_t b = 0; b < members_.size() && !bouncy; ++b) bouncy = bouncySoft(b);
  if (!bouncy) {
    std::vector<SoftBounce>().swap(softBounce_);
    std::vector<PartnerHit>().swap(partnerHits_);
    return;
  }
  softBounce_.assign(members_.size(), SoftBounce{});
  partnerHits_.clear();
  for (std::size_t b = 0; b < members_.size(); ++b)
    if (dynamicSoft(b)) softBounce_[b].vBefore = centreVelocity(b);  // a bouncy one's partner too
}

// The mass-weighted mean of a per-particle vector over body b's particles (serial, in id
// order; zero for a body without mass).
Vec3 PbdWorld::massMean(std::size_t b, const std::vector<float>& x, const std::vector<float>& y,
                        const std::vector<float>& z) const {
  Vec3 mv = Vec3::Zero();
  double m = 0.0;
  for (std::int32_t i : members_[b]) {
    const auto k = std::size_t(i);
    mv += double(parts_.mass[k]) * Vec3(x[k], y[k], z[k]);
    m += parts_.mass[k];
  }
  return m > 0.0 ? Vec3(mv / m) : Vec3::Zero();
}

// The mass-weighted mean velocity of a particle-level body's particles.
Vec3 PbdWorld::centreVelocity(std::size_t b) const {
  return massMean(b, parts_.vx, parts_.vy, parts_.vz);
}

// A soft body that hit free dynamic rigid partners, and maybe surfaces too, in one substep
// (softBodyRestitution): the surfaces make one contact along their mean normal (their mean e and
// velocity), each partner one along its own mean normal at its mean contact point. Impulses
// j_c >= 0 on the body (each partner taking -j_c n_c through its generalized inverse mass w_c
// there) so that each contact the body approached faster than `slow` leaves at e_c times its
// approach, unless the others already separate it faster: the linear complementarity problem
//   A j - d >= 0,  j >= 0,  j_c (A j - d)_c = 0,   A_cd = n_c . n_d / m + [c = d] w_c,
// d_c the normal velocity contact c still lacks. A is positive definite (every free partner has
// w_c > 0 and the surfaces are one row), so the problem has one solution, found by trying its
// active sets from all contacts down (at most 2^8: a body with more than 8 contacts approaching
// at once, the surfaces counting as one, stays inelastic). Momentum is kept along whatever the surfaces do not push.
template <class Kick>
void PbdWorld::bounceOffPartners(std::size_t b, double mass, double slow, const SurfaceHits& surfaces,
                                 const std::vector<const PartnerHit*>& partners, Kick&& kick) {
  constexpr std::size_t kMaxContacts = 8;
  const SoftBounce& sb = softBounce_[b];
  const Vec3 vb = centreVelocity(b);
  struct Row {
    Vec3 n, point;
    double d, w;
    const PartnerHit* hit;
  };
  std::vector<Row> rows;
  if (surfaces.count > 0 && surfaces.nSum.norm() > 1e-9) {
    const Vec3 n = surfaces.nSum.normalized();
    const double u = (sb.vBefore - surfaces.before / surfaces.count).dot(n);
    const double e = surfaces.eSum / surfaces.count;
    if (u < -slow) rows.push_back({n, Vec3::Zero(), -e * u - (vb - surfaces.after / surfaces.count).dot(n), 0.0, nullptr});
  }
  for (const PartnerHit* ph : partners) {
    if (!(ph->nSum.norm() > 1e-9)) continue;
    const Vec3 n = ph->nSum.normalized(), point = ph->points / ph->count;
    const Motion& mo = motion_[std::size_t(ph->body)];
    const double u = (sb.vBefore - ph->vBefore / ph->count).dot(n);
    if (!(u < -slow)) continue;
    const double d = -(ph->eSum / ph->count) * u - (vb - (mo.v + mo.w.cross(point - mo.c))).dot(n);
    const RigidPose pose{mo.c, mo.q, invMass_[std::size_t(ph->body)], invInertiaRest_[std::size_t(ph->body)]};
    rows.push_back({n, point, d, generalizedInverseMass(pose, point, n), ph});
  }
  const std::size_t k = rows.size();
  if (k == 0 || k > kMaxContacts) return;
  Eigen::MatrixXd A(k, k);
  Eigen::VectorXd d(k);
  for (std::size_t c = 0; c < k; ++c) {
    d[Eigen::Index(c)] = rows[c].d;
    for (std::size_t o = 0; o < k; ++o)
      A(Eigen::Index(c), Eigen::Index(o)) = rows[c].n.dot(rows[o].n) / mass + (c == o ? rows[c].w : 0.0);
  }
  const double tol = 1e-9 * d.cwiseAbs().sum();
  Eigen::VectorXd j = Eigen::VectorXd::Zero(Eigen::Index(k));
  for (std::uint32_t mask = (1u << k) - 1;; --mask) {
    std::vector<Eigen::Index> on;
    for (std::size_t c = 0; c < k; ++c)
      if (mask & (1u << c)) on.push_back(Eigen::Index(c));
    Eigen::VectorXd trial = Eigen::VectorXd::Zero(Eigen::Index(k));
    if (!on.empty()) {
      const Eigen::VectorXd js = A(on, on).ldlt().solve(d(on));
      for (std::size_t q = 0; q < on.size(); ++q) trial[on[q]] = js[Eigen::Index(q)];
    }
    const Eigen::VectorXd rest = d - A * trial;  // what each contact still lacks
    bool holds = true;
    for (Eigen::Index c = 0; c < Eigen::Index(k) && holds; ++c)
      holds = (mask & (1u << c)) ? trial[c] >= 0.0 && std::abs(rest[c]) <= tol : rest[c] <= tol;
    if (holds) {
      j = trial;
      break;
    }
    if (mask == 0) return;  // no active set holds (round-off): inelastic
  }
  Vec3 dv = Vec3::Zero();
  for (std::size_t c = 0; c < k; ++c) {
    const double jc = j[Eigen::Index(c)];
    if (!(jc > 0.0)) continue;
    dv += (jc / mass) * rows[c].n;
    if (!rows[c].hit) continue;
    const auto r = std::size_t(rows[c].hit->body);
    Motion& mo = motion_[r];
    const Mat3 R = mo.q.toRotationMatrix();
    mo.v -= (jc * invMass_[r]) * rows[c].n;
    mo.w -= R * invInertiaRest_[r] * R.transpose() * (rows[c].point - mo.c).cross(jc * rows[c].n);
  }
  if (dv.squaredNorm() > 0.0) kick(b, dv);
}

// Soft bodies' restitution (SoftBounce above): a body that hit something this substep (its
// contacts that approached faster than 2 g h; what it rests or slides on does not count) leaves
// at e times its centre's approach speed along the mean normal of those contacts, relative to
// the surface: every particle gets the same velocity change, so the body's shape is untouched.
// e: the pair's mean with a body, the body's own against the ground and colliders (which have
// none). Another soft body shares the bounce when it is all the body hit, taking the opposite
// impulse (momentum is kept); a rigid partner the ground, a fixed body or a stack on either holds
// against the blow (heldAgainst) is a fixed surface, also when the body hit it and something else
// at once; free dynamic rigid partners, one or several, with surfaces or without, each take the
// opposite of their own contact's impulse, all solved together (bounceOffPartners). Serial over
// bodies: deterministic.
void PbdWorld::softBodyRestitution(double h) {
  if (softBounce_.empty()) return;
  const double slow = 2.0 * params_.gravity.norm() * h;
  const auto massOf = [&](std::size_t b) {
    double m = 0.0;
    for (std::int32_t i : members_[b]) m += parts_.mass[std::size_t(i)];
    return m;
  };
  const auto kick = [&](std::size_t b, const Vec3& dv) {
    const Vec3f k = dv.cast<float>();
    for (std::int32_t i : members_[b]) {
      const auto q = std::size_t(i);
      if (invMassP_[q] == 0.0f || pinned_[q]) continue;
      parts_.vx[q] += k.x(), parts_.vy[q] += k.y(), parts_.vz[q] += k.z();
    }
  };
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (!bouncySoft(b)) continue;
    SoftBounce& sb = softBounce_[b];
    for (std::int32_t i : members_[b]) {
      if (!(groundApproach_[std::size_t(i)] < -slow)) continue;  // not touching, or resting on it
      sb.nSum += Vec3::UnitY();
      sb.eSum += restitution_[b];
      ++sb.count;
    }
  }
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (!dynamicSoft(b)) continue;
    const SoftBounce& sb = softBounce_[b];
    if (sb.count == 0 || !(sb.nSum.norm() > 1e-9)) continue;
    const Vec3 n = sb.nSum.normalized();
    const double e = sb.eSum / sb.count;
    if (sb.softCount > 0) {
      // Two soft bodies that touched only each other, once per pair (from the lower index).
      if (sb.softPartner < 0 || sb.softCount != sb.count || std::size_t(sb.softPartner) < b) continue;
      const auto o = std::size_t(sb.softPartner);
      const SoftBounce& so = softBounce_[o];
      if (so.softPartner != std::int32_t(b) || so.softCount != so.count) continue;
      const double u = (sb.vBefore - so.vBefore).dot(n);
      if (u >= -slow) continue;
      const double dv = -e * u - (centreVelocity(b) - centreVelocity(o)).dot(n);
      if (dv <= 0.0) continue;
      const double mb = massOf(b), mo = massOf(o);
      const double impulse = dv / (1.0 / mb + 1.0 / mo);
      kick(b, (impulse / mb) * n);
      kick(o, (-impulse / mo) * n);
      continue;
    }
    if (!bouncySoft(b)) continue;
    // The surfaces: the ground, colliders, fixed bodies, and partners held against their blow
    // (heldAgainst: by the ground, a fixed body or a stack standing on one), which take no impulse
    // and may be hit together with others; free partners take the opposite of theirs.
    SurfaceHits surfaces{sb.nSum, sb.vSurface, sb.vSurface, sb.eSum, sb.count};
    std::vector<const PartnerHit*> free;
    for (const PartnerHit& ph : partnerHits_) {
      if (ph.soft != std::int32_t(b)) continue;
      const auto r = std::size_t(ph.body);
      const Vec3 blow = ph.nSum.norm() > 1e-9 ? Vec3(ph.nSum.normalized()) : n;
      if (heldAgainst(r, -blow)) {
        const Motion& mo = motion_[r];
        surfaces.before += ph.vBefore;
        surfaces.after += double(ph.count) * (mo.v + mo.w.cross(ph.points / ph.count - mo.c));
        continue;
      }
      free.push_back(&ph);
      surfaces.nSum -= ph.nSum, surfaces.eSum -= ph.eSum, surfaces.count -= ph.count;
    }
    if (!free.empty()) {
      bounceOffPartners(b, massOf(b), slow, surfaces, free, kick);
      continue;
    }
    const Vec3 before = surfaces.before / surfaces.count, after = surfaces.after / surfaces.count;
    const double u = (sb.vBefore - before).dot(n);
    if (u >= -slow) continue;
    const double dv = -e * u - (centreVelocity(b) - after).dot(n);
    if (dv > 0.0) kick(b, dv * n);
  }
}

void PbdWorld::kinematicParticles(std::size_t b, const Vec3& delta) {
  for (std::int32_t i : members_[b]) {
    const auto k = std::size_t(i);
    put(px_, py_, pz_, k, at(parts_.x, parts_.y, parts_.z, k) + delta);
  }
}

Vec3 PbdWorld::rigidPoint(std::size_t i) const {
  const Motion& mo = motion_[std::size_t(parts_.group(i))];
  return mo.q * Vec3(rx_[i], ry_[i], rz_[i]) + mo.c;
}

// Pairs (i, j) with i a particle-level particle and j any particle of another body (or,
// for fluids, of the same one) closer than one spacing plus a margin at the predicted
// positions. Rigid bodies contribute the particles within reach of the particle-level
// material's bounding box. Pairs are listed by i, then by j's rank: a fixed order.
double PbdWorld::largestContactRadius() const {
  double largest = params_.particleRadius;
  for (std::size_t b = 0; b < members_.size(); ++b)
    if (mode_[b] != BodyMode::kEmpty && !members_[b].empty()) largest = std::max(largest, double(strandRadius_[b]));
  return largest;
}

void PbdWorld::findNeighbors() {
  // Predicted moves that would cross a rigid body stop at its face first (the body taking its
  // share), so the pairs are found where the particles can be: a pair found past a thin sheet
  // pushed a body hidden behind it that the water never reached.
  // Only moves (relative to the body) over half a spacing: a shorter one cannot carry a particle
  // past a sheet, and its contacts are the contact pass's.
  looseBodySweep(params_.dt / params_.substeps, params_.particleRadius);
  ParticlePairContacts& pairs = contacts_.particlePair;
  pairs.clear();
  if (fluid_)  // particleContact reads rigid bodies' face normals for fluid pairs
    for (std::size_t b = 0; b < members_.size(); ++b)
      if (normalsStale_[b]) refreshSurfaceNormals(b);
  const double r = params_.particleRadius, largest = largestContactRadius();
  // Touching (the two largest radii: 2 r without thick strands) plus half a spacing of travel.
  const float radius = static_cast<float>(2.0 * largest + r);
  std::vector<float> x, y, z;
  std::vector<std::int32_t> id;
  // Only pairs of different bodies are contacts, so a particle far from every other body's
  // box (grown by the search radius) has none: a cloth hanging from a bar searches only its
  // rows near the bar. Boxes of particle-level bodies from their predicted positions, of
  // rigid bodies from their centre and reach.
  std::vector<Eigen::AlignedBox3d> bodyBox(members_.size());
  for (std::int32_t i : loose_) {
    const auto k = std::size_t(i);
    bodyBox[std::size_t(parts_.group(k))].extend(Vec3(px_[k], py_[k], pz_[k]));
  }
  for (std::size_t b = 0; b < members_.size(); ++b)
    if (isRigid(b) && mode_[b] != BodyMode::kEmpty && !members_[b].empty()) {
      // The rest box's corners at the body's pose (a long bar's reach would cover a cloth
      // hanging from it).
      const Motion& mo = motion_[b];
      const Mat3 R = mo.q.toRotationMatrix();
      for (int corner = 0; corner < 8; ++corner)
        bodyBox[b].extend(R * restBox_[b].corner(static_cast<Eigen::AlignedBox3d::CornerType>(corner)) + mo.c);
    }
  // Per particle-level body: the parts of its box that another body's grown box covers.
  std::vector<std::vector<Eigen::AlignedBox3d>> near(members_.size());
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (isRigid(b) || bodyBox[b].isEmpty()) continue;
    for (std::size_t o = 0; o < members_.size(); ++o) {
      if (o == b || bodyBox[o].isEmpty()) continue;
      Eigen::AlignedBox3d grown = bodyBox[o];
      grown.min().array() -= radius;
      grown.max().array() += radius;
      const Eigen::AlignedBox3d overlap = grown.intersection(bodyBox[b]);
      if (!overlap.isEmpty()) near[b].push_back(overlap);
    }
  }
  Eigen::AlignedBox3d box;
  for (std::int32_t i : loose_) {
    const auto k = std::size_t(i);
    const Vec3 p(px_[k], py_[k], pz_[k]);
    const auto& boxes = near[std::size_t(parts_.group(k))];
    if (std::none_of(boxes.begin(), boxes.end(), [&](const Eigen::AlignedBox3d& bx) { return bx.contains(p); }))
      continue;
    x.push_back(px_[k]), y.push_back(py_[k]), z.push_back(pz_[k]);
    id.push_back(i);
    box.extend(p);
  }
  const std::size_t nl = id.size();
  if (nl == 0) return;
  box.min().array() -= radius;
  box.max().array() += radius;
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (!isRigid(b) || mode_[b] == BodyMode::kEmpty) continue;
    const Motion& mo = motion_[b];
    if (box.exteriorDistance(mo.c) > reach_[b]) continue;
    const Mat3 R = mo.q.toRotationMatrix();
    for (std::int32_t i : members_[b]) {
      const auto k = std::size_t(i);
      const Vec3 p = R * Vec3(rx_[k], ry_[k], rz_[k]) + mo.c;
      if (!box.contains(p)) continue;
      x.push_back(float(p.x())), y.push_back(float(p.y())), z.push_back(float(p.z()));
      id.push_back(i);
    }
  }
  NeighborGrid grid;
  grid.build(x.data(), y.data(), z.data(), x.size(), radius);
  std::vector<ParticlePairContacts> chunks((nl + kChunk - 1) / kChunk);
  forRange(nl, [&](std::size_t lo, std::size_t hi) {
    ParticlePairContacts& out = chunks[lo / kChunk];
    for (std::size_t k = lo; k < hi; ++k) {
      const std::int32_t i = id[k];
      const std::uint32_t phi = parts_.phase[std::size_t(i)];
      grid.forEachNeighbor(static_cast<std::int32_t>(k), radius, [&](std::int32_t j) {
        const std::int32_t other = id[std::size_t(j)];
        const bool looseJ = std::size_t(j) < nl;
        if (looseJ && other < i) return;  // each particle-level pair once
        const std::uint32_t phj = parts_.phase[std::size_t(other)];
        const bool sameBody = phase::group(phi) == phase::group(phj);
        if (sameBody) return;  // a body's own particles: clusters, links or density hold them
        // A rope's end where it is tied (contactSkip_).
        if (contactSkip_[std::size_t(i)] == phase::group(phj) || (looseJ && contactSkip_[std::size_t(other)] == phase::group(phi)))
          return;
        // Fluid against fluid is the density constraint's, not a contact.
        if (phase::has(phi, phase::kFluid) && phase::has(phj, phase::kFluid)) return;
        if (invMassP_[std::size_t(i)] == 0.0f && (!looseJ || invMassP_[std::size_t(other)] == 0.0f)) return;
        out.i.push_back(i);
        out.j.push_back(other);
      });
    }
  });
  for (const ParticlePairContacts& c : chunks) {
    pairs.i.insert(pairs.i.end(), c.i.begin(), c.i.end());
    pairs.j.insert(pairs.j.end(), c.j.begin(), c.j.end());
  }
  // A rigid body awake particle-level material touches is marked (it sleeps only with what touches
  // it: updateSleep); a rigid sleeper wakes now, before the pairs are solved (in pair order: the
  // same for any thread count).
  for (std::int32_t j : pairs.j) {
    const auto b = std::size_t(parts_.group(std::size_t(j)));
    if (isRigid(b) && mode_[b] == BodyMode::kDynamic && !looseTouch_[b]) touchedByLoose(b);
  }
}

// One sweep over the particle pairs, then the ground. A pair closer than one spacing is
// pushed apart along the line of centres, each side by its share of the inverse mass (a
// rigid body's share is its generalized inverse mass at the contact point), then friction
// removes (static) or reduces (dynamic) their relative tangential motion of this substep.
void PbdWorld::particleContact() {
  const ParticlePairContacts& pairs = contacts_.particlePair;
  for (std::size_t c = 0; c < pairs.size(); ++c) {
    const auto i = std::size_t(pairs.i[c]), j = std::size_t(pairs.j[c]);
    const auto bj = std::size_t(parts_.group(j));
    const bool rigidJ = isRigid(bj);
    const double touch = radiusOf(i) + radiusOf(j);  // 2 r but where a thick strand is
    const Vec3 pi = at(px_, py_, pz_, i);
    const Vec3 pj = rigidJ ? rigidPoint(j) : at(px_, py_, pz_, j);
    const Vec3 d = pi - pj;
    const double dist = d.norm();
    const bool fluidPair = phase::has(parts_.phase[i], phase::kFluid) != phase::has(parts_.phase[j], phase::kFluid);
    const double reach = fluidPair ? kFluidReach * touch : touch;
    const bool faceNear = fluidPair && rigidJ && !surfaceNormal_[j].isZero();
    if (!(dist < reach) && !faceNear) continue;
    Motion* mj = rigidJ ? &motion_[bj] : nullptr;
    const Vec3 startI = at(parts_.x, parts_.y, parts_.z, i);
    const Vec3 startJ = rigidJ ? Vec3(mj->qPrev * Vec3(rx_[j], ry_[j], rz_[j]) + mj->cPrev) : at(parts_.x, parts_.y, parts_.z, j);
    const Vec3 s = startI - startJ, path = d - s;
    // Fluid on a rigid body's surface particle that started the substep outside it (s and the
    // normal at the substep's start pose; a one-particle sheet's face on the side i started
    // on): held reach off the surface layer along the body's normal there now (surfaceNormal_).
    // It meets the face as a plane: the pair acts wherever i lies over j's tile of the face
    // (within half a diagonal of the lattice, 0.71 spacings, of j's normal line), not only
    // within reach of j's centre. Gated by that sphere, the face was an egg crate: in the
    // hollows between its particles, where no pair reached, fluid sank to the cells' faces (half
    // a spacing above the face's centres, where the sweep holds it), and was pushed back up to
    // reach whenever its flow over the face brought it within reach of one, a push that
    // v = (p - x) / h turned into speed away from the face. A blob thrown at a slab left it
    // again at 28 % of its speed (16 substeps; 7 % at 4), and water resting in a cup kept moving
    // at 4 cm/s. One that started behind the face meets j as a sphere of radius reach.
    Vec3 face = Vec3::Zero();  // in the body's rest frame
    if (faceNear) {
      face = surfaceNormal_[j].cast<double>();
      const double side = (mj->qPrev.conjugate() * s).dot(face);
      if (side < 0.0) face = sheetFace_[j] ? Vec3(-face) : Vec3::Zero();
    }
    const bool onFace = !face.isZero();
    const Vec3 faceNormal = onFace ? Vec3(mj->q * face) : Vec3::Zero();  // now, in the world
    if (onFace) {
      const double spacing = 2.0 * params_.particleRadius;
      if (!((d - d.dot(faceNormal) * faceNormal).squaredNorm() <= 0.5 * spacing * spacing)) continue;
    } else if (!(dist < reach)) {
      continue;
    }
    // The normal off a face, as above; else where the pair first touched this substep, if it
    // came into touch during it (i's path relative to j, from s at the start to d now,
    // entering the sphere of radius reach at its first crossing), else the line of centres.
    // A particle fast enough to be predicted past a solid particle's centre was pushed on
    // through along the line of centres: water poured into a cup left through its floor,
    // three particles thick.
    Vec3 n;
    double pen;
    if (onFace) {
      n = faceNormal;
      pen = reach - d.dot(n);
    } else if (s.squaredNorm() >= reach * reach && path.squaredNorm() > 0.0) {
      // |s + t path|^2 = reach^2: qa t^2 + 2 qb t + qc = 0, the smaller root.
      const double qa = path.squaredNorm(), qb = s.dot(path), qc = s.squaredNorm() - reach * reach;
      const double t = std::clamp((-qb - std::sqrt(std::max(qb * qb - qa * qc, 0.0))) / qa, 0.0, 1.0);
      const Vec3 q = s + t * path;
      if (!(q.norm() > 0.0)) continue;
      n = q / q.norm();
      pen = reach - d.dot(n);
    } else {
      if (dist == 0.0) continue;
      n = d / dist;
      pen = reach - dist;
    }
    if (!(pen > 0.0)) continue;
    RigidPose pose;
    if (rigidJ) pose = RigidPose{mj->c, mj->q, invMass_[bj], invInertiaRest_[bj]};
    // Where a rigid side takes its share: off a face, the face's point under i (up to 0.71
    // spacings from j's centre), else j's centre.
    const Vec3 touchAt = onFace ? Vec3(pj + (d - d.dot(n) * n)) : pj;
    const double wi = invMassP_[i];
    const double wj = rigidJ ? (mode_[bj] == BodyMode::kDynamic ? generalizedInverseMass(pose, touchAt, n) : 0.0)
                             : double(invMassP_[j]);
    if (wi + wj <= 0.0) continue;
    const double lambda = pen / (wi + wj);
    // For the bounces: the other side's velocity at the contact and i's relative to it, before
    // the solve (evaluated only where a bounce is recorded).
    const auto otherVelocity = [&]() -> Vec3 {
      return rigidJ ? Vec3(mj->v + mj->w.cross(pj - mj->c)) : at(parts_.vx, parts_.vy, parts_.vz, j);
    };
    const auto relativeVelocity = [&]() -> Vec3 { return at(parts_.vx, parts_.vy, parts_.vz, i) - otherVelocity(); };
    if (!softBounce_.empty() && rigidJ && (mode_[bj] == BodyMode::kFixed || mode_[bj] == BodyMode::kDynamic)) {
      const auto bi = std::size_t(parts_.group(i));
      if (bouncySoft(bi) && approaching(relativeVelocity(), n)) {
        SoftBounce& sb = softBounce_[bi];
        sb.nSum += n;
        sb.eSum += 0.5 * (restitution_[bi] + restitution_[bj]);
        ++sb.count;
        if (mode_[bj] == BodyMode::kDynamic) {
          const auto same = [&](const PartnerHit& ph) { return ph.soft == std::int32_t(bi) && ph.body == std::int32_t(bj); };
          auto hit = std::find_if(partnerHits_.begin(), partnerHits_.end(), same);
          if (hit == partnerHits_.end()) hit = partnerHits_.insert(hit, PartnerHit{std::int32_t(bi), std::int32_t(bj)});
          ++hit->count;
          hit->points += pj;
          hit->vBefore += otherVelocity();
          hit->nSum += n;
          hit->eSum += 0.5 * (restitution_[bi] + restitution_[bj]);
        }
      }
    }
    if (!softBounce_.empty() && !rigidJ) {
      const auto bi = std::size_t(parts_.group(i));
      if (bi != bj && dynamicSoft(bi) && dynamicSoft(bj) && restitution_[bi] + restitution_[bj] > 0.0 &&
          approaching(relativeVelocity(), n)) {
        const double e = 0.5 * (restitution_[bi] + restitution_[bj]);
        const auto note = [&](std::size_t self, std::size_t other, const Vec3& normal) {
          SoftBounce& sb = softBounce_[self];
          sb.nSum += normal;
          sb.eSum += e;
          ++sb.count;
          ++sb.softCount;
          sb.softPartner = sb.softPartner == -1 || sb.softPartner == std::int32_t(other) ? std::int32_t(other) : -2;
        };
        note(bi, bj, n);
        note(bj, bi, -n);
      }
    }
    if (!bounceNoted_[i] && (rigidJ || !bounceNoted_[j])) {  // a body (its mean e) or another particle
      const double ej = rigidJ ? restitution_[bj] : materials_[std::size_t(parts_.material[j])].restitution;
      const double e = 0.5 * (materials_[std::size_t(parts_.material[i])].restitution + ej);
      noteParticleBounce({std::int32_t(i), rigidJ ? std::int32_t(bj) : -2, std::int32_t(j), n, pj,
                          relativeVelocity().dot(n), e});
    }
    Vec3 newI = pi + (wi * lambda) * n;
    Vec3 newJ = pj - (wj * lambda) * n;
    // Friction: relative tangential displacement over the substep.
    Vec3 rel = (newI - startI) - (newJ - startJ);
    rel -= n.dot(rel) * n;
    const Material& mi = materials_[std::size_t(parts_.material[i])];
    const Material& mjm = materials_[std::size_t(parts_.material[j])];
    double mus = 0.0, muk = 0.0;
    pairFriction(mi, mjm, mus, muk);
    const Vec3 f = frictionCorrection(rel, pen, mus, muk);
    newI -= (wi / (wi + wj)) * f;
    put(px_, py_, pz_, i, newI);
    if (rigidJ) {
      if (wj > 0.0) {
        applyPointCorrection(pose, touchAt, -n, wj * lambda);
        const double ft = f.norm();
        if (ft > 0.0) {
          const Vec3 t = f / ft;
          const double wt = generalizedInverseMass(pose, touchAt, t);
          applyPointCorrection(pose, touchAt, t, ft * wt / (wi + wt));
        }
        mj->c = pose.c, mj->q = pose.q;
      }
    } else {
      newJ += (wj / (wi + wj)) * f;
      put(px_, py_, pz_, j, newJ);
    }
  }
  looseColliderContact();
  // The ground (and its friction) for every dynamic particle-level particle, its centre held
  // at its contact radius above the plane.
  forRange(loose_.size(), [&](std::size_t lo, std::size_t hi) {
    for (std::size_t k = lo; k < hi; ++k) {
      const auto i = std::size_t(loose_[k]);
      const double floorY = params_.groundY + radiusOf(i);
      if (invMassP_[i] == 0.0f || !(py_[i] < floorY)) continue;
      const double pen = floorY - py_[i];
      if (groundApproach_[i] == 0.0f) groundApproach_[i] = std::min(parts_.vy[i], -1e-30f);
      py_[i] = static_cast<float>(floorY);
      const Material& m = materials_[std::size_t(parts_.material[i])];
      const Vec3 t(px_[i] - parts_.x[i], 0.0, pz_[i] - parts_.z[i]);
      const Vec3 f = frictionCorrection(t, pen, m.staticFriction, m.dynamicFriction);
      px_[i] = static_cast<float>(px_[i] - f.x());
      pz_[i] = static_cast<float>(pz_[i] - f.z());
    }
  });
}

// Cluster c's members over the positions x, y, z (v.lambda and v.w left for the caller).
detail::ClusterView PbdWorld::clusterView(std::size_t c, const float* x, const float* y, const float* z) {
  detail::ClusterView v;
  v.idx = clusters_.members.index.data();
  v.qx = clusters_.qx.data(), v.qy = clusters_.qy.data(), v.qz = clusters_.qz.data();
  v.x = x, v.y = y, v.z = z;
  v.mass = parts_.mass.data();
  v.lo = clusters_.members.offset[c], v.hi = clusters_.members.offset[c + 1];
  return v;
}

// The view's mass moments relative to its first member's position, returned in p0 (positions
// are ~0.5 m, a cluster's offsets ~cm: the float lanes keep their bits for the offsets).
detail::ClusterMoments PbdWorld::clusterMoments(const detail::ClusterView& v, float (&p0)[3]) const {
  const auto f = std::size_t(v.idx[v.lo]);
  p0[0] = v.x[f], p0[1] = v.y[f], p0[2] = v.z[f];
  return detail::clusterMoments(v, p0, clusterAvx2());
}

// Clustered shape matching with XPBD compliance: per cluster, the best rigid transform of
// its rest shape onto the current positions (Müller 2005, Eq. 5-7; polar decomposition by
// extractRotation), then per member the constraint C = |p - g| towards its goal g with
// compliance alpha: dlambda = (-C - alpha~ lambda) / (w + alpha~), alpha~ = alpha / h^2.
// Three sweeps over a cluster's members: the moments and the corrections (cluster_kernels.h,
// eight members at a time), then the net-momentum shift.
void PbdWorld::clusterMatch(double h) {
  if (clusterColoursDirty_) colourClusters();
  const double invH2 = 1.0 / (h * h);
  const Clusters& cl = clusters_.members;
  const bool avx2 = clusterAvx2();
  const auto match = [&](std::size_t c) {
    if (!moving(std::size_t(clusters_.body[c]))) return;  // fixed, carried or asleep
    const std::int32_t lo = cl.offset[c], hi = cl.offset[c + 1];
    if (hi - lo < 2) return;
    detail::ClusterView v = clusterView(c, px_.data(), py_.data(), pz_.data());
    v.lambda = clusters_.lambda.data();
    v.w = invMassP_.data();
    float p0[3];
    const detail::ClusterMoments mo = clusterMoments(v, p0);
    const Vec3 o = mo.offset();  // centre - p0
    Quat& rot = clusters_.rotation[c];
    rot = extractRotation(mo.matrix(), rot);
    const Mat3 R = rot.toRotationMatrix();
    // The members' corrections are computed from the same positions (Jacobi within the
    // cluster), then their net momentum is removed: a member's goal moves with the others
    // (XPBD's per-member gradient ignores that), and without this the compliance term
    // would push the cluster as a whole.
    const float Rf[9] = {float(R(0, 0)), float(R(0, 1)), float(R(0, 2)), float(R(1, 0)), float(R(1, 1)),
                         float(R(1, 2)), float(R(2, 0)), float(R(2, 1)), float(R(2, 2))};
    const float of[3] = {float(o[0]), float(o[1]), float(o[2])};
    double net[3], mDyn = 0.0;
    thread_local std::vector<float> dp;
    const auto n = std::size_t(hi - lo);
    dp.resize(3 * n);
    v.dx = dp.data(), v.dy = v.dx + n, v.dz = v.dy + n;
    detail::clusterCorrections(v, p0, Rf, of, static_cast<float>(clusters_.compliance[c] * invH2), net, mDyn, avx2);
    if (mDyn == 0.0) return;
    // Each member moves by its correction less the net shift, added first and rounded once at
    // the position. Subtracted apart, a shift under half the float spacing of a position (3e-8
    // m at 0.5 m) was lost from every member alike, and momentum with it: two soft cubes
    // colliding in zero gravity wandered by 6.5e-3 of their momentum.
    const float shift[3] = {float(net[0] / mDyn), float(net[1] / mDyn), float(net[2] / mDyn)};
    for (std::int32_t k = lo; k < hi; ++k) {
      const auto i = std::size_t(v.idx[k]);
      if (invMassP_[i] == 0.0f) continue;
      const auto m = std::size_t(k - lo);
      px_[i] += v.dx[m] - shift[0];
      py_[i] += v.dy[m] - shift[1];
      pz_[i] += v.dz[m] - shift[2];
    }
  };
  // Colour by colour; the cells of a colour in parallel, each cell's clusters in order.
  for (const auto& cells : clusterCells_)
    forEach(cells.size(), [&](std::size_t j) {
      for (std::int32_t c : cells[j]) match(std::size_t(c));
    });
}

// Stretch and bending (XPBD distances), then attachments to rigid bodies (zero rest
// length, the body's share through its generalized inverse mass), then tethers.
void PbdWorld::distanceConstraints(double h) {
  solveDistances(distances_, px_.data(), py_.data(), pz_.data(), invMassP_.data(), h);
  for (const Attachment& a : attachments_) {
    const auto i = std::size_t(a.particle), b = std::size_t(a.body);
    Motion& mo = motion_[b];
    const bool dyn = mode_[b] == BodyMode::kDynamic;
    RigidPose pose{mo.c, mo.q, invMass_[b], invInertiaRest_[b]};
    const Vec3 target = mo.q * a.local + mo.c;
    const Vec3 p = at(px_, py_, pz_, i);
    Vec3 d = p - target;
    double C = d.norm();
    if (C > 0.0) {
      const Vec3 n = d / C;
      const double wi = invMassP_[i], wb = dyn ? generalizedInverseMass(pose, target, n) : 0.0;
      if (wi + wb > 0.0) {
        const double lambda = C / (wi + wb);
        put(px_, py_, pz_, i, p - (wi * lambda) * n);
        if (wb > 0.0) applyPointCorrection(pose, target, n, wb * lambda);
      }
    }
    // The body's point hangs no farther from the strand's anchor than the strand is long.
    if (a.anchor >= 0 && dyn) {
      const Vec3 anchor = at(px_, py_, pz_, std::size_t(a.anchor));
      const Vec3 pt = pose.q * a.local + pose.c;
      d = pt - anchor;
      C = d.norm() - a.length;
      if (C > 0.0) applyPointCorrection(pose, pt, -d.normalized(), C);
    }
    mo.c = pose.c, mo.q = pose.q;
  }
  // Tethers in parallel: each particle has at most one, and its anchor is pinned (read only).
  forRange(tethers_.size(), [&](std::size_t lo, std::size_t hi) {
    for (std::size_t k = lo; k < hi; ++k) {
      const Tether& t = tethers_[k];
      const auto i = std::size_t(t.particle);
      if (invMassP_[i] == 0.0f) continue;
      const Vec3 anchor = at(px_, py_, pz_, std::size_t(t.anchor));
      const Vec3 d = at(px_, py_, pz_, i) - anchor;
      const double len = d.norm();
      if (len > t.length) put(px_, py_, pz_, i, anchor + d * (t.length / len));
    }
  });
}

bool PbdWorld::RestCells::filled(const Vec3i& c) const {
  const Vec3i k = c - lo;
  if ((k.array() < 0).any() || (k.array() >= size.array()).any()) return false;
  const std::uint64_t n =
      std::uint64_t(k.x()) + std::uint64_t(size.x()) * (std::uint64_t(k.y()) + std::uint64_t(size.y()) * std::uint64_t(k.z()));
  return ((bits[n >> 6] >> (n & 63u)) & 1u) != 0;
}

// Body b's rest lattice as a bit box (restCells' cells: one spacing, centred on its particles,
// relative to its first member). Bodies of the sketch always sit on one; a box beyond 2^26
// cells (a body of the API spread over kilometres) keeps none, and its contacts act alone.
void PbdWorld::refreshRestCells(std::size_t b) {
  RestCells& rc = restCells_[b];
  rc = RestCells{};
  rc.stale = false;
  const auto& mem = members_[b];
  if (!isRigid(b) || mem.empty() || mode_[b] == BodyMode::kEmpty) return;
  const double inv = 1.0 / (2.0 * params_.particleRadius);
  const auto f = std::size_t(mem.front());
  rc.origin = Vec3(rx_[f], ry_[f], rz_[f]);
  const std::vector<Vec3i> cells = restCells(b);
  Vec3i lo = cells.front(), hi = cells.front();
  for (std::size_t k = 0; k < cells.size(); ++k) {
    const auto i = std::size_t(mem[k]);
    const Vec3 off = (Vec3(rx_[i], ry_[i], rz_[i]) - rc.origin) * inv - cells[k].cast<double>();
    if (!(off.cwiseAbs().maxCoeff() < 0.05)) return;  // not on one lattice (or not finite)
    lo = lo.cwiseMin(cells[k]), hi = hi.cwiseMax(cells[k]);
  }
  const Eigen::Array3d size = (hi - lo + Vec3i::Ones()).cast<double>().array();
  if (size.prod() > double(std::uint64_t(1) << 26)) return;
  rc.lo = lo, rc.size = hi - lo + Vec3i::Ones();
  const auto volume = std::uint64_t(rc.size.x()) * std::uint64_t(rc.size.y()) * std::uint64_t(rc.size.z());
  rc.bits.assign(std::size_t((volume + 63) / 64), 0);
  for (const Vec3i& c : cells) {
    const Vec3i k = c - lo;
    const std::uint64_t n = std::uint64_t(k.x()) +
                            std::uint64_t(rc.size.x()) * (std::uint64_t(k.y()) + std::uint64_t(rc.size.y()) * std::uint64_t(k.z()));
    rc.bits[std::size_t(n >> 6)] |= std::uint64_t(1) << (n & 63u);
  }
  rc.onLattice = true;
}

// Continuous collision of particle-level particles against sketched rigid bodies, the sweep
// colliders get (particleUpdate) for the lattice a rigid body is made of. A particle's move of
// the substep relative to each body near it (its start in the body's frame at the substep's
// start pose, its end at the pose now) is walked through the body's rest cells; one that enters
// a taken cell stops outside the face it entered by (at the pair's contact distance, or less if
// it started nearer), so nothing passes through a wall however thin it is or however fast it
// comes: contacts are found at the predicted positions within a spacing and a half, and the
// density or cluster passes after the last contact sweep may push a particle on. A dynamic body
// takes its share of each stop as a contact does (the correction split by the two inverse masses,
// the body's generalized one at the stop point, and the body's velocities made anew from its
// moved pose), so momentum is kept: water thrown at a free plate pushes it. The stops are found
// for each particle alone, in parallel, against the poses the substep ended with; the shares are
// then applied serially in particle order: deterministic.
void PbdWorld::looseBodySweep(double h, double minMove) {
  struct Near {
    std::size_t body;
    Eigen::AlignedBox3d box;  // world, over the substep
    Mat3 toStart, toEnd;      // world -> rest frame at the substep's start and end poses
    Vec3 cStart, cEnd;
    Mat3 fromEnd;
    double travel;  // m, the farthest any point of the body moved over the substep
  };
  std::vector<char> active(members_.size(), 0);
  for (std::int32_t b : active_) active[std::size_t(b)] = 1;
  Eigen::AlignedBox3d all;
  // A particle not finite at either end is left to the guard (it names it after the step).
  const auto finiteMove = [&](std::size_t k) {
    return at(parts_.x, parts_.y, parts_.z, k).allFinite() && at(px_, py_, pz_, k).allFinite();
  };
  for (std::int32_t i : loose_) {
    const auto k = std::size_t(i);
    if (invMassP_[k] == 0.0f || !finiteMove(k)) continue;
    all.extend(Vec3(parts_.x[k], parts_.y[k], parts_.z[k]));
    all.extend(Vec3(px_[k], py_[k], pz_[k]));
  }
  if (all.isEmpty() || !all.sizes().allFinite()) return;
  std::vector<Near> bodies;
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (!isRigid(b) || mode_[b] == BodyMode::kEmpty || members_[b].empty()) continue;
    const Motion& mo = motion_[b];
    // The start pose is the substep's only where integrate or kinematic set it this substep.
    const bool moved = (mode_[b] == BodyMode::kDynamic && active[b]) || mode_[b] == BodyMode::kKinematic;
    const Mat3 Rs = (moved ? mo.qPrev : mo.q).toRotationMatrix(), Re = mo.q.toRotationMatrix();
    const Vec3 cs = moved ? mo.cPrev : mo.c;
    Eigen::AlignedBox3d box;
    for (int corner = 0; corner < 8; ++corner) {
      const Vec3 x = restBox_[b].corner(static_cast<Eigen::AlignedBox3d::CornerType>(corner));
      box.extend(Rs * x + cs);
      box.extend(Re * x + mo.c);
    }
    if (!box.intersects(all)) continue;
    if (restCells_[b].stale) refreshRestCells(b);
    if (!restCells_[b].onLattice) continue;
    const double turn = moved ? 2.0 * std::acos(std::min(1.0, std::abs(mo.q.dot(mo.qPrev)))) : 0.0;
    bodies.push_back({b, box, Rs.transpose(), Re.transpose(), cs, mo.c, Re, (mo.c - cs).norm() + turn * reach_[b]});
  }
  if (bodies.empty()) return;
  double mostTravel = 0.0;
  for (const Near& nb : bodies) mostTravel = std::max(mostTravel, nb.travel);
  const double r = params_.particleRadius, spacing = 2.0 * r, inv = 1.0 / spacing;
  // The bodies binned by their boxes in a coarse grid over the paths' box (cells of 8 spacings,
  // or more for at most 32 a side), so a pool beside a pile of boxes tries each particle against
  // the few boxes near its path, not all of them. Lists in ascending body order.
  const double binSize = std::max(8.0 * spacing, all.sizes().maxCoeff() / 32.0);
  const Vec3i bins = (all.sizes() / binSize).array().floor().cast<int>() + 1;
  const auto binOf = [&](const Vec3& x) -> Vec3i {
    const Vec3i c = ((x - all.min()) / binSize).array().floor().cast<int>();
    return c.cwiseMax(Vec3i::Zero()).cwiseMin(bins - Vec3i::Ones());
  };
  const auto binIndex = [&](int x, int y, int z) { return std::size_t(x + bins.x() * (y + bins.y() * z)); };
  const auto forBins = [&](const Eigen::AlignedBox3d& box, const auto& f) {
    const Vec3i lo = binOf(box.min()), hi = binOf(box.max());
    for (int z = lo.z(); z <= hi.z(); ++z)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int x = lo.x(); x <= hi.x(); ++x) f(binIndex(x, y, z));
  };
  std::vector<std::uint32_t> binStart(std::size_t(bins.prod()) + 1, 0), binBodies;
  for (const Near& nb : bodies) forBins(nb.box, [&](std::size_t c) { ++binStart[c + 1]; });
  for (std::size_t c = 1; c < binStart.size(); ++c) binStart[c] += binStart[c - 1];
  binBodies.resize(binStart.back());
  std::vector<std::uint32_t> fill(binStart.begin(), binStart.end() - 1);
  for (std::size_t n = 0; n < bodies.size(); ++n) forBins(bodies[n].box, [&](std::size_t c) { binBodies[fill[c]++] = std::uint32_t(n); });
  // The stops against dynamic bodies, per unit of the loop: the particle, the body (bodies[near]),
  // where it stopped and the correction it took there.
  struct Stop {
    std::size_t particle, near;
    Vec3 point, correction;
  };
  std::vector<std::vector<Stop>> stops((loose_.size() + kChunk - 1) / kChunk);
  forRange(loose_.size(), [&](std::size_t lo, std::size_t hi) {
    std::vector<std::uint32_t> nearPath;
    std::vector<Stop>& unitStops = stops[lo / kChunk];
    for (std::size_t k = lo; k < hi; ++k) {
      const auto i = std::size_t(loose_[k]);
      if (invMassP_[i] == 0.0f || !finiteMove(i)) continue;
      const Vec3 from = at(parts_.x, parts_.y, parts_.z, i), predicted = at(px_, py_, pz_, i);
      const double move = (predicted - from).norm();
      if (move + mostTravel < minMove) continue;
      const bool fluid = phase::has(parts_.phase[i], phase::kFluid);
      Eigen::AlignedBox3d reach(at(parts_.x, parts_.y, parts_.z, i));
      reach.extend(at(px_, py_, pz_, i));
      reach.min().array() -= spacing;  // a stop lies within a spacing of the path
      reach.max().array() += spacing;
      const std::uint32_t* first = nullptr;
      const std::uint32_t* last = nullptr;
      if (binOf(reach.min()) == binOf(reach.max())) {  // most paths: one bin's list as it is
        const std::size_t c = binIndex(binOf(reach.min()).x(), binOf(reach.min()).y(), binOf(reach.min()).z());
        first = binBodies.data() + binStart[c], last = binBodies.data() + binStart[c + 1];
      } else {
        nearPath.clear();
        forBins(reach, [&](std::size_t c) { nearPath.insert(nearPath.end(), &binBodies[binStart[c]], &binBodies[binStart[c + 1]]); });
        std::sort(nearPath.begin(), nearPath.end());
        nearPath.erase(std::unique(nearPath.begin(), nearPath.end()), nearPath.end());
        first = nearPath.data(), last = nearPath.data() + nearPath.size();
      }
      // Each body is tried against the path as the bodies before it left it, so a stop at one
      // body found further along than another's is replaced by that one: the particle stops
      // once, at the last body it was stopped by, and only that body takes a share. A stop that
      // slid (below) ends off the path the bodies before it were tried against, so they are all
      // tried once more against the path to where it slid, stopping it without a slide.
      std::size_t stoppedBy = bodies.size();
      bool slid = false;
      for (int pass = 0; pass < 2 && (pass == 0 || slid); ++pass) {
        for (const std::uint32_t* n = first; n != last; ++n) {
          const Near& nb = bodies[*n];
          if (move + nb.travel < minMove) continue;
          const Vec3 to = at(px_, py_, pz_, i);
          Eigen::AlignedBox3d path(from);
          path.extend(to);
          if (!path.intersects(nb.box) || contactSkip_[i] == std::int32_t(nb.body)) continue;
          const RestCells& rc = restCells_[nb.body];
          // Cell units: the rest offset less cell (0, 0, 0)'s centre, over the spacing, plus a half.
          const Vec3 a = (nb.toStart * (from - nb.cStart) - rc.origin) * inv + Vec3::Constant(0.5);
          const Vec3 b = (nb.toEnd * (to - nb.cEnd) - rc.origin) * inv + Vec3::Constant(0.5);
          // The walk over the part of the path within the body's cells grown by one (slabs).
          double t0 = 0.0, t1 = 1.0;
          for (int ax = 0; ax < 3 && t0 <= t1; ++ax) {
            const double below = rc.lo[ax] - 1.0, above = rc.lo[ax] + rc.size[ax] + 1.0, da = b[ax] - a[ax];
            if (da == 0.0) {
              if (a[ax] < below || a[ax] > above) t1 = -1.0;
              continue;
            }
            const double u = (below - a[ax]) / da, v = (above - a[ax]) / da;
            t0 = std::max(t0, std::min(u, v)), t1 = std::min(t1, std::max(u, v));
          }
          if (!(t0 <= t1)) continue;
          const Vec3 a0 = a + t0 * (b - a);
          const auto filled = [&](const Vec3i& c) { return rc.filled(c); };
          const CellEntry e = firstTakenCell(a0, (t1 - t0) * (b - a), filled);
          if (!e.hit) continue;
          const double t = t0 + e.t * (t1 - t0);
          // Out of the entered face by the pair's contact distance beyond the cell (its half
          // spacing), or by as far as the particle started from it if nearer, and by at most half
          // a cell (the cell the walk left is empty; one further back along the axis, beside a
          // thick strand's path, may not be).
          const double touch = (fluid ? kFluidReach : 1.0) * (radiusOf(i) + r);
          const auto back = [&](double before) { return std::max(std::min({(touch - r) * inv, before, 0.5}), 1e-3); };
          Vec3 stop = a + t * (b - a);
          stop[e.axis] -= e.dir * back(t * std::abs(b[e.axis] - a[e.axis]));
          // Then on along the face by what is left of the move across it, less Coulomb friction
          // against the part of the move the face stopped (as a contact would), up to a second
          // face it may meet there. Stopped on its path, a particle lost its move along the face
          // too: frictionless water thrown at 6 m/s and 45 degrees at a sheet (2 substeps) kept
          // 19 % of its speed along it, where off the ground it keeps all of it.
          // (The body's friction is its members' mean, as at body level.)
          Vec3 slide = (1.0 - t) * (b - a);
          const double across = std::abs(slide[e.axis]);
          slide[e.axis] = 0.0;
          if (pass == 0) {
            double mus = 0.0, muk = 0.0;
            pairFriction(materials_[std::size_t(parts_.material[i])], bodyFriction(nb.body), mus, muk);
            slide -= frictionCorrection(slide, across, mus, muk);
          }
          if (pass == 0 && slide.squaredNorm() > 0.0) {
            const CellEntry f = firstTakenCell(stop, slide, filled);
            stop += f.t * slide;
            if (f.hit) stop[f.axis] -= f.dir * back(f.t * std::abs(slide[f.axis]));
            slid = true;
          }
          // Never below the ground: a body coming down on a particle (a stone sinking through
          // water to the floor) carried the stop with it into the ground, past the contacts'
          // ground, and the guard stopped the honey example at frame 6.
          Vec3 world = nb.fromEnd * ((stop - Vec3::Constant(0.5)) * spacing + rc.origin) + nb.cEnd;
          world.y() = std::max(world.y(), params_.groundY + radiusOf(i));
          put(px_, py_, pz_, i, world);
          stoppedBy = *n;
        }
      }
      if (stoppedBy < bodies.size() && mode_[bodies[stoppedBy].body] == BodyMode::kDynamic) {
        const Vec3 p = at(px_, py_, pz_, i);
        unitStops.push_back({i, stoppedBy, p, p - predicted});
      }
    }
  });
  // The dynamic bodies' shares, one stop after another (Gauss-Seidel, as the contacts): the
  // stop point rides with the body as the shares before it moved it, the correction still needed
  // along the stop's direction is what is left of it, and that is split by the inverse masses:
  // the particle keeps w_i / (w_i + w_b) of it and the body moves the rest the other way at the
  // stop point. Along the correction, not a face normal: the correction also holds the friction
  // the slide along the face lost, and the body takes that too. Split against the pose the stops
  // were found at, every stop on a light body added its whole share: a 6^3 jelly thrown at
  // 6 m/s at the corner of a plate a fifth its mass (2 substeps) threw the plate off at 38 m/s
  // and 290 rad/s, and the guard stopped the energy growth. The bodies' moves here are not swept
  // again: the stops hold to first order in them (a light body turned by an off-centre hit may
  // bring a cell to within its move of a stopped particle).
  std::vector<std::size_t> moved;
  for (const std::vector<Stop>& unit : stops)
    for (const Stop& st : unit) {
      const double d = st.correction.norm();
      if (!(d > 0.0)) continue;
      const Near& nb = bodies[st.near];
      const std::size_t b = nb.body;
      if (!looseTouch_[b]) touchedByLoose(b);  // marked as a contact marks it (a sleeper woken)
      const Vec3 n = st.correction / d, predicted = st.point - st.correction;
      Motion& mo = motion_[b];
      const Vec3 stopNow = mo.q * (nb.toEnd * (st.point - nb.cEnd)) + mo.c;
      const double left = (stopNow - predicted).dot(n);
      if (!(left > 0.0)) {  // the body has moved out of the particle's way
        put(px_, py_, pz_, st.particle, predicted);
        continue;
      }
      RigidPose pose{mo.c, mo.q, invMass_[b], invInertiaRest_[b]};
      const double wi = invMassP_[st.particle], wb = generalizedInverseMass(pose, stopNow, n);
      const double lambda = left / (wi + wb);
      put(px_, py_, pz_, st.particle, predicted + (wi * lambda) * n);
      applyPointCorrection(pose, stopNow, -n, wb * lambda);
      mo.c = pose.c, mo.q = pose.q;
      moved.push_back(b);
    }
  std::sort(moved.begin(), moved.end());
  moved.erase(std::unique(moved.begin(), moved.end()), moved.end());
  for (const std::size_t b : moved) velocitiesFromPoses(b, h);  // as update() made them
}

// v = (p - x) / h, x = p for dynamic and carried particles. A particle that hit the
// ground faster than 2 |g| h leaves it at e times its approach speed.
void PbdWorld::particleUpdate(double h) {
  looseBodySweep(h, 0.0);
  if (colliders_ && colliders_->size() > 0) {
    // Colliders have the last word (with the ground, below): the constraint passes after the
    // last contact sweep (links, density) may have pushed a particle into or through one. The
    // contact planes found this substep push it back out, and a particle whose whole move
    // of the substep still crosses a surface stops at the first touch.
    looseColliderContact();
    const double r = params_.particleRadius;
    forRange(loose_.size(), [&](std::size_t lo, std::size_t hi) {
      for (std::size_t k = lo; k < hi; ++k) {
        const auto i = std::size_t(loose_[k]);
        if (invMassP_[i] == 0.0f) continue;
        const Vec3 from = at(parts_.x, parts_.y, parts_.z, i), to = at(px_, py_, pz_, i);
        if ((to - from).norm() <= 0.25 * r) continue;
        const SweepHit hit = colliders_->sweep(from, to, r);
        if (hit.hit) put(px_, py_, pz_, i, hit.centre);
      }
    });
  }
  const float invH = static_cast<float>(1.0 / h), hf = static_cast<float>(h);
  const float slow = static_cast<float>(2.0 * params_.gravity.norm() * h);
  forRange(loose_.size(), [&](std::size_t lo, std::size_t hi) {
    for (std::size_t k = lo; k < hi; ++k) {
      const auto i = std::size_t(loose_[k]);
      const bool moves = invMassP_[i] > 0.0f || mode_[std::size_t(parts_.group(i))] == BodyMode::kKinematic;
      if (!moves || pinned_[i]) continue;
      if (invMassP_[i] > 0.0f) {
        // The ground has the last word too: the passes after the iteration's last contact
        // sweep can press a particle back into it (a rope's links, where another rope lies
        // across it: 0.13 mm; while the clusters ran after the contacts, a landing stiff soft
        // ball's, whose lowest layer went up to 2.6 radii under the ground at 4 iterations and
        // stopped the run). Held at its contact height before its velocity is taken, the
        // particle leaves the substep no faster downwards than the ground allows.
        const float floorY = static_cast<float>(params_.groundY + radiusOf(i));
        if (py_[i] < floorY) {
          if (groundApproach_[i] == 0.0f) groundApproach_[i] = std::min(parts_.vy[i], -1e-30f);
          py_[i] = floorY;
        }
        // v = (p - x) / h, written as the predicted velocity plus what the constraints moved
        // the particle: p - x rounds to the positions' float ulp (6e-8 m at 0.5 m), which at
        // 256 substeps of a 60 Hz step is more than a substep of gravity's motion, so a
        // hanging cloth lost its weight. predicted() repeats predict()'s expression exactly.
        parts_.vx[i] += (px_[i] - predicted(parts_.x[i], hf, parts_.vx[i])) * invH;
        parts_.vy[i] += (py_[i] - predicted(parts_.y[i], hf, parts_.vy[i])) * invH;
        parts_.vz[i] += (pz_[i] - predicted(parts_.z[i], hf, parts_.vz[i])) * invH;
      } else {
        parts_.vx[i] = (px_[i] - parts_.x[i]) * invH;
        parts_.vy[i] = (py_[i] - parts_.y[i]) * invH;
        parts_.vz[i] = (pz_[i] - parts_.z[i]) * invH;
      }
      parts_.x[i] = px_[i], parts_.y[i] = py_[i], parts_.z[i] = pz_[i];
      const float u = groundApproach_[i];
      if (u < -slow && (softBounce_.empty() || !bouncySoft(std::size_t(parts_.group(i))))) {
        const float e = static_cast<float>(materials_[std::size_t(parts_.material[i])].restitution);
        parts_.vy[i] = std::max(parts_.vy[i], -e * u);
      }
    }
  });
  particleRestitution(h);
  softBodyRestitution(h);
}

// A contact worth a bounce (e > 0, the particle approaching, not part of a soft body that
// bounces as a whole: softBodyRestitution) is kept, once per particle and substep: the particle
// (and a particle on the other side) is marked only when its bounce is kept, so a contact not
// worth one (a neighbour it rests against or slides along) does not use up the one that is.
void PbdWorld::noteParticleBounce(const ParticleBounce& b) {
  const auto i = std::size_t(b.particle);
  if (!(b.e > 0.0) || !(b.approach < 0.0) || invMassP_[i] == 0.0f || pinned_[i]) return;
  const auto bouncesAsABody = [&](std::size_t k) { return !softBounce_.empty() && bouncySoft(std::size_t(parts_.group(k))); };
  if (bouncesAsABody(i) || (b.body == -2 && bouncesAsABody(std::size_t(b.other)))) return;
  bounceNoted_[i] = 1;
  if (b.body == -2) bounceNoted_[std::size_t(b.other)] = 1;
  particleBounces_.push_back(b);
}

// Restitution particle by particle (Müller et al. 2020 §3.6, Eq. 34, as at the ground): a
// particle that hit a body, a collider or another particle faster than 2 |g| h leaves it at e
// times its approach speed along the contact normal, relative to the surface's velocity now. A
// dynamic body (through its generalized inverse mass at the contact point) or the other
// particle takes the opposite impulse, so momentum is kept; fixed and carried bodies and
// colliders do not move. Many particles hitting one free body share it: one pass in order let
// the first ones leave against a body the later ones had not pushed yet, 5.6 % faster than e
// allows (energy would grow at e = 1), so the impulses are found by Gauss-Seidel sweeps with
// each contact's accumulated impulse kept >= 0 (a contact pushes, never pulls). Serial, in the
// order recorded: deterministic.
void PbdWorld::particleRestitution(double h) {
  const double slow = 2.0 * params_.gravity.norm() * h;
  constexpr int kSweeps = 8;
  bounceImpulse_.assign(particleBounces_.size(), 0.0);
  for (int sweep = 0; sweep < kSweeps; ++sweep) {
    for (std::size_t k = 0; k < particleBounces_.size(); ++k) {
      const ParticleBounce& b = particleBounces_[k];
      if (b.approach >= -slow) continue;
      const auto i = std::size_t(b.particle);
      const Vec3 vi = at(parts_.vx, parts_.vy, parts_.vz, i);
      const double wi = invMassP_[i];
      Vec3 vs = Vec3::Zero(), point = b.point;
      double ws = 0.0;  // the other side's inverse mass along the normal
      Motion* mo = nullptr;
      if (b.body == -2) {
        const auto j = std::size_t(b.other);
        vs = at(parts_.vx, parts_.vy, parts_.vz, j);
        ws = pinned_[j] ? 0.0 : double(invMassP_[j]);
      } else if (b.body >= 0) {
        const auto r = std::size_t(b.body);
        mo = &motion_[r];
        point = rigidPoint(std::size_t(b.other));
        vs = mo->v + mo->w.cross(point - mo->c);
        if (mode_[r] == BodyMode::kDynamic)
          ws = generalizedInverseMass(RigidPose{mo->c, mo->q, invMass_[r], invInertiaRest_[r]}, point, b.normal);
      } else {
        vs = colliders_->surfaceVelocity(std::size_t(b.other), point);
      }
      const double dv = -b.e * b.approach - (vi - vs).dot(b.normal);
      const double total = std::max(bounceImpulse_[k] + dv / (wi + ws), 0.0);
      const double impulse = total - bounceImpulse_[k];
      if (impulse == 0.0) continue;
      bounceImpulse_[k] = total;
      put(parts_.vx, parts_.vy, parts_.vz, i, vi + (impulse * wi) * b.normal);
      if (b.body == -2) {
        const auto j = std::size_t(b.other);
        put(parts_.vx, parts_.vy, parts_.vz, j, vs - (impulse * ws) * b.normal);
      } else if (mo && ws > 0.0) {
        const auto r = std::size_t(b.body);
        const Mat3 R = mo->q.toRotationMatrix();
        mo->v -= (impulse * invMass_[r]) * b.normal;
        mo->w -= R * invInertiaRest_[r] * R.transpose() * (point - mo->c).cross(impulse * b.normal);
      }
    }
  }
}

// Plastic creep (Müller et al. 2005 §4.4, in the rest offsets of each cluster): where the
// cluster's deformation S = R^T A (A the best linear fit of the rest shape) is strained
// more than plastic_yield (Frobenius norm of S - I), the rest offsets move towards the
// current shape seen in the cluster's frame at rate plastic_creep (1/s).
void PbdWorld::plasticity(double h) {
  const Clusters& cl = clusters_.members;
  if (clusters_.creep.empty()) return;  // no plastic cluster
  // Clusters in parallel, 64 a unit (most are elastic and skipped at once): each writes only its
  // own memberships' rest offsets.
  forChunks(cl.size(), 64, [&](std::size_t first, std::size_t last) {
    for (std::size_t c = first; c < last; ++c) plasticCreep(c, h);
  });
}

// One cluster's plastic creep (plasticity()).
void PbdWorld::plasticCreep(std::size_t c, double h) {
  const Clusters& cl = clusters_.members;
  if (clusters_.creep[c] <= 0.0f || !moving(std::size_t(clusters_.body[c]))) return;
  const std::int32_t lo = cl.offset[c], hi = cl.offset[c + 1];
  if (hi - lo < 4) return;
  // The centre and A_pq as cluster_match sums them (at the positions after the substep), A_qq
  // in a second sweep over the rest offsets alone.
  float p0[3];
  const detail::ClusterMoments mo = clusterMoments(clusterView(c, parts_.x.data(), parts_.y.data(), parts_.z.data()), p0);
  const Vec3 cm = Vec3(p0[0], p0[1], p0[2]) + mo.offset();
  const Mat3 Apq = mo.matrix();
  Mat3 Aqq = Mat3::Zero();
  for (std::int32_t k = lo; k < hi; ++k) {
    const Vec3 q(clusters_.qx[std::size_t(k)], clusters_.qy[std::size_t(k)], clusters_.qz[std::size_t(k)]);
    Aqq += double(parts_.mass[std::size_t(cl.index[std::size_t(k)])]) * q * q.transpose();
  }
  if (std::abs(Aqq.determinant()) < 1e-30) return;  // flat or linear cluster: no 3D strain
  const Mat3 R = clusters_.rotation[c].toRotationMatrix();
  const Mat3 S = R.transpose() * Apq * Aqq.inverse();
  if ((S - Mat3::Identity()).norm() <= clusters_.yield[c]) return;
  const double a = std::min(1.0, double(clusters_.creep[c]) * h);
  for (std::int32_t k = lo; k < hi; ++k) {
    const auto i = std::size_t(cl.index[std::size_t(k)]);
    const Vec3 q(clusters_.qx[std::size_t(k)], clusters_.qy[std::size_t(k)], clusters_.qz[std::size_t(k)]);
    const Vec3 now = R.transpose() * (at(parts_.x, parts_.y, parts_.z, i) - cm);
    const Vec3 nq = q + a * (now - q);
    clusters_.qx[std::size_t(k)] = float(nq.x()), clusters_.qy[std::size_t(k)] = float(nq.y()),
    clusters_.qz[std::size_t(k)] = float(nq.z());
  }
}

bool PbdWorld::summarizeLoose(std::size_t b) {
  const auto& mem = members_[b];
  double m = 0.0;
  Vec3 c = Vec3::Zero(), v = Vec3::Zero();
  float maxV2 = 0.0f, minY = 3.4e38f;
  bool bad = false;
  for (std::int32_t i : mem) {
    const auto k = std::size_t(i);
    const double mi = parts_.mass[k];
    const Vec3 p = at(parts_.x, parts_.y, parts_.z, k), u = at(parts_.vx, parts_.vy, parts_.vz, k);
    bad = bad || !p.allFinite() || !u.allFinite();
    m += mi;
    c += mi * p;
    v += mi * u;
    if (pinned_[k]) continue;
    maxV2 = std::max(maxV2, float(u.squaredNorm()));
    minY = std::min(minY, parts_.y[k]);
  }
  if (m > 0.0 && !bad) {
    motion_[b].c = c / m;
    motion_[b].v = v / m;
  }
  if (mode_[b] != BodyMode::kDynamic) return bad;
  const double floorY = params_.groundY + params_.particleRadius;
  return bad || !(double(maxV2) <= 0.999 * params_.maxSpeed * params_.maxSpeed) ||
         !(double(minY) >= floorY - params_.particleRadius);
}

}  // namespace physketch::pbd

namespace physketch::pbd {

// --- fluids (pbd/fluid.h) -------------------------------------------------------------

// A rope or cloth particle thicker than a voxel is several samples of the fluid kernel
// (fluidNeighbors): n = round(2 radius / spacing) across. A rope particle weighs density x
// spacing^3 x (2 radius / spacing)^2, the square cross-section n x n samples fill; a cloth
// particle density x spacing^3 x (2 radius / spacing), the n samples across its sheet. Every
// other particle (and a cloth drawn as no lattice) is one.
int PbdWorld::strandSamples(std::size_t i) const {
  const auto b = std::size_t(parts_.group(i));
  const bool rope = kind_[b] == MaterialKind::kRope,
             sheet = kind_[b] == MaterialKind::kCloth && lattice_[b][1] >= 1 && lattice_[b][2] >= 1;
  if (!(rope || sheet) || !(strandRadius_[b] > 0.0f)) return 1;
  return std::max(1, int(std::lround(double(strandRadius_[b]) / params_.particleRadius)));
}

// A rope particle's direction along the rope at its predicted position: from the particle
// before it to the one after it on the chain (consecutive ids of its body within two
// spacings; one side at an end), +x for a lone particle.
Vec3 PbdWorld::strandTangent(std::size_t i) const {
  const auto b = parts_.group(i);
  const double reach = 4.0 * params_.particleRadius;
  const Vec3 x = at(px_, py_, pz_, i);
  const auto near = [&](std::size_t j, Vec3& out) {
    if (j >= parts_.size() || parts_.group(j) != b) return false;
    out = at(px_, py_, pz_, j);
    return (out - x).norm() < reach;
  };
  Vec3 prev = x, next = x;
  const bool hasPrev = i > 0 && near(i - 1, prev), hasNext = near(i + 1, next);
  const Vec3 t = (hasNext ? next : x) - (hasPrev ? prev : x);
  return t.norm() > 0.0 ? Vec3(t.normalized()) : Vec3::UnitX();
}

// A cloth particle's normal to its sheet at the predicted positions: the cross product of the
// lattice's directions along its row and down its column, each from the neighbour before to the
// one after (one side at an edge; neighbours of its body within two spacings), +y where the
// lattice gives none (a lone particle, a row or column cut away).
Vec3 PbdWorld::sheetNormal(std::size_t i) const {
  const auto b = std::size_t(parts_.group(i));
  const std::int64_t first = lattice_[b][0], cols = lattice_[b][2], k = std::int64_t(i) - first;
  const std::int64_t row = k / cols, col = k % cols, rows = lattice_[b][1];
  if (k < 0 || row >= rows) return Vec3::UnitY();
  const double reach = 4.0 * params_.particleRadius;
  const Vec3 x = at(px_, py_, pz_, i);
  const auto along = [&](std::int64_t dr, std::int64_t dc) {  // from the neighbour before to the one after
    Vec3 ends[2] = {x, x};
    for (int s = 0; s < 2; ++s) {
      const std::int64_t r = row + (s ? dr : -dr), c = col + (s ? dc : -dc);
      if (r < 0 || r >= rows || c < 0 || c >= cols) continue;
      const auto j = std::size_t(first + r * cols + c);
      if (j >= parts_.size() || std::size_t(parts_.group(j)) != b) continue;
      const Vec3 y = at(px_, py_, pz_, j);
      if ((y - x).norm() < reach) ends[s] = y;
    }
    return Vec3(ends[1] - ends[0]);
  };
  const Vec3 n = along(0, 1).cross(along(1, 0));
  return n.norm() > 0.0 ? Vec3(n.normalized()) : Vec3::UnitY();
}

// One kernel for every fluid of the scene, kernel radius 2.1 spacings (~30 neighbours,
// Macklin & Müller 2013). Each particle keeps its own rest density, so fluids of different
// densities layer, and its own material's xsph_viscosity, vorticity, cohesion, relaxation
// and sound_speed (per-particle parameters when the scene's fluids differ in any of them).
// Called again for every body added after play: a new fluid material joins the list.
void PbdWorld::makeFluidSolver() {
  const bool hadAuto = fluid_ && fluidSoundAuto_;
  fluidMaterials_.clear();
  for (std::size_t b = 0; b < kind_.size(); ++b)
    if (kind_[b] == MaterialKind::kFluid && !members_[b].empty()) {
      const auto m = std::size_t(parts_.material[std::size_t(members_[b].front())]);
      if (std::find(fluidMaterials_.begin(), fluidMaterials_.end(), m) == fluidMaterials_.end()) fluidMaterials_.push_back(m);
    }
  if (fluidMaterials_.empty()) return;
  const Material::Fluid& first = materials_[fluidMaterials_.front()].fluid;
  if (!fluid_) {
    FluidParams fp;
    fp.particleRadius = static_cast<float>(params_.particleRadius);
    fp.kernelRadius = static_cast<float>(2.1 * 2.0 * params_.particleRadius);
    fp.relaxation = static_cast<float>(first.relaxation);
    fp.xsph = static_cast<float>(first.xsphViscosity);
    fp.vorticity = static_cast<float>(first.vorticity);
    fp.cohesion = static_cast<float>(first.cohesion);
    fp.viscosity = static_cast<float>(first.viscosity);
    fp.warmStart = static_cast<float>(params_.warmStart);
    fp.warmSmoothing = params_.warmSmoothing;
    fp.wallLo[1] = static_cast<float>(params_.groundY);
    fluid_ = std::make_unique<FluidSolver>(fp);
  }
  fluidMixed_ = false, fluidSoundAuto_ = false, fluidVelocity_ = false;
  const auto same = [](double a, double b) { return a == b || (std::isnan(a) && std::isnan(b)); };
  for (std::size_t m : fluidMaterials_) {
    const Material::Fluid& f = materials_[m].fluid;
    fluidMixed_ |= !same(f.relaxation, first.relaxation) || !same(f.xsphViscosity, first.xsphViscosity) ||
                   !same(f.vorticity, first.vorticity) || !same(f.cohesion, first.cohesion) ||
                   !same(f.soundSpeed, first.soundSpeed) || !same(f.viscosity, first.viscosity);
    fluidSoundAuto_ |= std::isnan(f.soundSpeed);
    fluidVelocity_ |= f.xsphViscosity > 0.0 || f.vorticity > 0.0 || f.cohesion > 0.0 ||
                      FluidSolver::viscosityMatters(f.viscosity, materials_[m].density);
  }
  // The auto sound speed (it starts at 0 and rises, and keeps rising after a new body), or
  // the single material's.
  if (!fluidSoundAuto_) fluidSoundSpeed_ = static_cast<float>(first.soundSpeed);
  else if (!hadAuto) fluidSoundSpeed_ = 0.0f;
}

// A fluid material's sound speed now: its own, or the automatic one.
float PbdWorld::fluidSoundOf(const Material& m) const {
  return std::isnan(m.fluid.soundSpeed) ? fluidSoundSpeed_ : static_cast<float>(m.fluid.soundSpeed);
}

// The density pass's sound speeds, for the plan: "sound speed 4 m/s", "sound speed auto,
// now 12 m/s", or per material with several fluids ("sound speed water 4 m/s, oil auto; auto
// now 12 m/s").
std::string PbdWorld::fluidSoundText() const {
  char c[96];
  if (fluidSoundSpeed_ > 0.0f) std::snprintf(c, sizeof c, "auto, now %.3g m/s", double(fluidSoundSpeed_));
  const std::string autoText = fluidSoundSpeed_ > 0.0f ? std::string(c) : "auto, 15 max(sqrt(2 g H), v_max)";
  std::string out = "; sound speed ";
  for (std::size_t k = 0; k < fluidMaterials_.size() && (k == 0 || fluidMixed_); ++k) {
    const Material& m = materials_[fluidMaterials_[k]];
    if (fluidMixed_) out += (k ? ", " : "") + m.name + " ";
    std::snprintf(c, sizeof c, "%.3g m/s", m.fluid.soundSpeed);
    out += !std::isnan(m.fluid.soundSpeed) ? std::string(c) : fluidMixed_ ? std::string("auto") : autoText;
  }
  if (fluidMixed_ && fluidSoundAuto_) out += "; " + autoText;
  return out;
}

// The kernel's particles this substep: every dynamic fluid particle, then the solid
// particles within a kernel radius of the fluid's bounding box (particle-level ones at
// their predicted positions, rigid ones at their body's pose). A solid's inverse mass is
// its own (rigid: the particle's 1/m, so the body takes sum m dp as an impulse; fixed and
// carried: 0).
void PbdWorld::fluidNeighbors() {
  fluidIds_.clear();
  Eigen::AlignedBox3d box;
  float v2 = 0.0f;  // the fastest fluid particle's speed squared
  for (std::int32_t i : loose_) {
    const auto k = std::size_t(i);
    if (!phase::has(parts_.phase[k], phase::kFluid) || invMassP_[k] == 0.0f) continue;
    fluidIds_.push_back(i);
    box.extend(at(px_, py_, pz_, k));
    v2 = std::max(v2, (parts_.vx[k] * parts_.vx[k] + parts_.vy[k] * parts_.vy[k]) + parts_.vz[k] * parts_.vz[k]);
  }
  fluidCount_ = fluidIds_.size();
  if (fluidCount_ == 0) return;
  if (fluidSoundAuto_) {
    const double height = box.max().y() - box.min().y() + 2.0 * params_.particleRadius;
    fluidSoundSpeed_ = std::max(fluidSoundSpeed_, FluidSolver::autoSoundSpeed(static_cast<float>(params_.gravity.norm()),
                                                                               static_cast<float>(height), std::sqrt(v2)));
  }
  const double reachH = fluid_->params().kernelRadius;
  box.min().array() -= reachH;
  box.max().array() += reachH;
  fsample_.clear();
  const auto entry = [&](std::int32_t i, const Vec3& off, float share) {
    fluidIds_.push_back(i);
    fsample_.push_back({float(off.x()), float(off.y()), float(off.z()), share});
  };
  for (std::int32_t i : loose_) {
    const auto k = std::size_t(i);
    if (phase::has(parts_.phase[k], phase::kFluid)) continue;
    const int ns = strandSamples(k);
    const Vec3 x = at(px_, py_, pz_, k);
    if (ns == 1) {
      if (box.contains(x)) entry(i, Vec3::Zero(), 1.0f);
      continue;
    }
    if (box.exteriorDistance(x) > radiusOf(k)) continue;
    const double radius = radiusOf(k), step = 2.0 * radius / ns;
    if (kind_[std::size_t(parts_.group(k))] == MaterialKind::kCloth) {  // n samples across the sheet
      const Vec3 nrm = sheetNormal(k);
      for (int a = 0; a < ns; ++a) entry(i, ((a + 0.5) * step - radius) * nrm, 1.0f / float(ns));
      continue;
    }
    // A thick rope's cross-section, n x n samples at spacing s = 2 radius / n across the
    // tangent, in a fixed order.
    const Vec3 t = strandTangent(k);
    int minor = 0;
    t.cwiseAbs().minCoeff(&minor);
    const Vec3 u = t.cross(Vec3::Unit(minor)).normalized(), v = t.cross(u);
    for (int a = 0; a < ns; ++a)
      for (int c = 0; c < ns; ++c)
        entry(i, ((a + 0.5) * step - radius) * u + ((c + 0.5) * step - radius) * v, 1.0f / float(ns * ns));
  }
  for (std::size_t b = 0; b < members_.size(); ++b) {
    if (!isRigid(b) || mode_[b] == BodyMode::kEmpty || box.exteriorDistance(motion_[b].c) > reach_[b]) continue;
    for (std::int32_t i : members_[b])
      if (box.contains(rigidPoint(std::size_t(i)))) entry(i, Vec3::Zero(), 1.0f);
  }
  const std::size_t n = fluidIds_.size();
  fx_.resize(n), fy_.resize(n), fz_.resize(n), fw_.resize(n), frho_.resize(n), fflag_.resize(n);
  fdx_.resize(n), fdy_.resize(n), fdz_.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    const auto i = std::size_t(fluidIds_[k]);
    const auto b = std::size_t(parts_.group(i));
    const bool rigid = isRigid(b);
    put(fx_, fy_, fz_, k, rigid ? rigidPoint(i) : at(px_, py_, pz_, i) + sampleOffset(k));
    fflag_[k] = k < fluidCount_ ? 1 : 0;
    // A sleeper: at rest, fixed. A thick rope's sample: its share of the particle's mass.
    fw_[k] = rigid ? (moving(b) ? 1.0f / parts_.mass[i] : 0.0f) : invMassP_[i] / sampleShare(k);
    frho_[k] = static_cast<float>(materials_[std::size_t(parts_.material[i])].density);
  }
  if (fluidMixed_) {  // each fluid particle its material's parameters (solids' entries unread)
    frelax_.assign(n, 0.0f), fxsph_.assign(n, 0.0f), fvort_.assign(n, 0.0f), fcoh_.assign(n, 0.0f), fsound_.assign(n, 0.0f);
    fmu_.assign(n, 0.0f);
    for (std::size_t k = 0; k < fluidCount_; ++k) {
      const Material& m = materials_[std::size_t(parts_.material[std::size_t(fluidIds_[k])])];
      frelax_[k] = static_cast<float>(m.fluid.relaxation);
      fxsph_[k] = static_cast<float>(m.fluid.xsphViscosity);
      fvort_[k] = static_cast<float>(m.fluid.vorticity);
      fcoh_[k] = static_cast<float>(m.fluid.cohesion);
      fsound_[k] = fluidSoundOf(m);
      fmu_[k] = static_cast<float>(m.fluid.viscosity);
    }
  }
  FluidInput in;
  in.count = n;
  in.x = fx_.data(), in.y = fy_.data(), in.z = fz_.data();
  in.invMass = fw_.data();
  in.fluid = fflag_.data();
  in.restDensity = frho_.data();
  in.substep = static_cast<float>(params_.dt / params_.substeps);
  in.iterations = params_.iterations;
  in.soundSpeed = fluidSoundSpeed_;
  if (fluidMixed_) {
    in.relaxation = frelax_.data(), in.xsph = fxsph_.data(), in.vorticity = fvort_.data(), in.cohesion = fcoh_.data();
    in.soundSpeeds = fsound_.data(), in.viscosity = fmu_.data();
  }
  // The multipliers of the substep just before this one (not of an earlier one: a step or a
  // substep without dynamic fluid between starts the solve from zero), while the fluid's
  // particles are the same ones and no body was edited since (a sketch edit, a cut, a particle
  // fixed starts the solve from zero once).
  densityIteration_ = 0;
  if (params_.warmStart > 0.0 && fluidCarryStamp_ == substepStamp_ - 1 && fluidCarryEdits_ == bodyEdits_ &&
      fluidCarryIds_.size() == fluidCount_ && std::equal(fluidCarryIds_.begin(), fluidCarryIds_.end(), fluidIds_.begin())) {
    fcarried_.assign(n, 0.0f);
    std::copy(fluidCarry_.begin(), fluidCarry_.end(), fcarried_.begin());
    in.carried = fcarried_.data();
  } else if (params_.warmStart > 0.0) {
    ++fluidColdStarts_;
  }
  fluid_->begin(in);
}

// One Jacobi density iteration on the current positions (other passes moved particles and
// bodies since the last one); fluid and particle-level solids take their dp, a rigid body
// the impulse sum m dp of its particles, at body level: dc = sum m dp / M and the rotation
// by I^-1 sum r x m dp (momentum is conserved: the kernel's sum of m dp is zero).
void PbdWorld::density() {
  if (fluidCount_ == 0) return;
  // The warm start's correction first, on the first iteration of a substep (FluidSolver::warmStart).
  if (densityIteration_++ == 0 && params_.warmStart > 0.0) {
    loadFluidPositions();
    if (fluid_->warmStart()) applyFluidCorrections();
  }
  loadFluidPositions();
  fluid_->densityIteration();
  applyFluidCorrections();
  if (densityIteration_ == params_.iterations && params_.warmStart > 0.0) {
    fcarried_.resize(fluidIds_.size());
    fluid_->multipliers(fcarried_.data());
    fluidCarry_.assign(fcarried_.begin(), fcarried_.begin() + std::ptrdiff_t(fluidCount_));
    fluidCarryIds_.assign(fluidIds_.begin(), fluidIds_.begin() + std::ptrdiff_t(fluidCount_));
    fluidCarryEdits_ = bodyEdits_;
    fluidCarryStamp_ = substepStamp_;
  }
}

// The kernel's particles where the other passes left them: loose ones at their predicted
// positions, rigid ones at their body's pose.
void PbdWorld::loadFluidPositions() {
  const std::size_t n = fluidIds_.size();
  for (std::size_t k = 0; k < n; ++k) {
    const auto i = std::size_t(fluidIds_[k]);
    put(fx_, fy_, fz_, k,
        isRigid(std::size_t(parts_.group(i))) ? rigidPoint(i) : at(px_, py_, pz_, i) + sampleOffset(k));
  }
  fluid_->setPositions(fx_.data(), fy_.data(), fz_.data());
}

// The kernel's corrections: fluid and particle-level solids take their dp, a rigid body the
// impulse sum m dp of its particles.
void PbdWorld::applyFluidCorrections() {
  const std::size_t n = fluidIds_.size();
  fluid_->corrections(fdx_.data(), fdy_.data(), fdz_.data());
  std::map<std::size_t, std::pair<Vec3, Vec3>> impulse;  // body -> (sum m dp, sum r x m dp)
  for (std::size_t k = 0; k < n; ++k) {
    if (fw_[k] == 0.0f) continue;
    const auto i = std::size_t(fluidIds_[k]);
    const Vec3 d(fdx_[k], fdy_[k], fdz_[k]);
    const auto b = std::size_t(parts_.group(i));
    if (!isRigid(b)) {  // a thick rope's sample moves its particle by its share: sum m dp / M
      put(px_, py_, pz_, i, at(px_, py_, pz_, i) + double(sampleShare(k)) * d);
      continue;
    }
    auto it = impulse.find(b);
    if (it == impulse.end()) it = impulse.emplace(b, std::make_pair(Vec3::Zero(), Vec3::Zero())).first;  // Eigen leaves a default Vec3 unset
    auto& [lin, ang] = it->second;
    const Vec3 md = double(parts_.mass[i]) * d;
    lin += md;
    ang += (rigidPoint(i) - motion_[b].c).cross(md);
  }
  for (const auto& [b, j] : impulse) {
    Motion& mo = motion_[b];
    mo.c += invMass_[b] * j.first;
    const Mat3 R = mo.q.toRotationMatrix();
    const Vec3 dtheta = R * invInertiaRest_[b] * R.transpose() * j.second;
    const double a = dtheta.norm();
    if (a > 0.0) mo.q = (Quat(Eigen::AngleAxisd(a, dtheta / a)) * mo.q).normalized();
  }
}

// The fluids' velocity passes. Solids in range enter with their velocities now (a rigid
// point's from its body's motion). With a viscosity the solve drags them back
// (ViscousSolids): a dynamic rigid body awake is six unknowns (its mass and world-frame
// inertia), a dynamic particle-level solid particle one of its own; fixed, carried and
// sleeping ones stay fixed velocities.
void PbdWorld::fluidVelocity(double h) {
  if (fluidCount_ == 0) return;
  const std::size_t n = fluidIds_.size();
  std::vector<float> vx(n), vy(n), vz(n);
  std::vector<std::int32_t> role(n, ViscousSolids::kFixed);
  std::vector<std::size_t> bodies;             // table index -> body
  std::map<std::size_t, std::int32_t> index;   // body -> table index
  // A dynamic thick rope or cloth particle's samples are one unknown of the particle's own,
  // entered as a body of their square or column (its mass, the samples' inertia about it; the
  // spin it would take is dropped, a strand particle has none): table index bodies.size() + strandOf[k].
  std::vector<std::size_t> strandParticles;
  std::map<std::size_t, std::int32_t> strandIndex;  // particle -> its place in strandParticles
  std::vector<std::int32_t> strandOf(n, -1);
  for (std::size_t k = 0; k < n; ++k) {
    const auto i = std::size_t(fluidIds_[k]);
    const auto b = std::size_t(parts_.group(i));
    if (!isRigid(b)) {
      put(fx_, fy_, fz_, k, at(parts_.x, parts_.y, parts_.z, i) + sampleOffset(k));
      vx[k] = parts_.vx[i], vy[k] = parts_.vy[i], vz[k] = parts_.vz[i];
      if (k < fluidCount_ || !(fw_[k] > 0.0f)) continue;
      if (sampleShare(k) == 1.0f) {
        role[k] = ViscousSolids::kFree;
        continue;
      }
      auto it = strandIndex.find(i);
      if (it == strandIndex.end()) {
        it = strandIndex.emplace(i, std::int32_t(strandParticles.size())).first;
        strandParticles.push_back(i);
      }
      strandOf[k] = it->second;
      continue;
    }
    const Vec3 p = rigidPoint(i), v = motion_[b].v + motion_[b].w.cross(p - motion_[b].c);
    put(fx_, fy_, fz_, k, p);
    vx[k] = static_cast<float>(v.x()), vy[k] = static_cast<float>(v.y()), vz[k] = static_cast<float>(v.z());
    if (!moving(b)) continue;
    auto it = index.find(b);
    if (it == index.end()) {
      it = index.emplace(b, std::int32_t(bodies.size())).first;
      bodies.push_back(b);
    }
    role[k] = it->second;
  }
  const std::size_t nb = bodies.size(), nr = strandParticles.size();
  viscousBodies_ = nb;
  viscousLoose_ = std::size_t(std::count(role.begin(), role.end(), ViscousSolids::kFree)) + nr;
  for (std::size_t k = 0; k < n; ++k)
    if (strandOf[k] >= 0) role[k] = std::int32_t(nb) + strandOf[k];
  std::vector<double> mass(nb + nr), inertia(9 * (nb + nr), 0.0), centre(3 * (nb + nr)), bv(3 * (nb + nr)),
      bw(3 * (nb + nr), 0.0);
  for (std::size_t t = 0; t < nb; ++t) {
    const std::size_t b = bodies[t];
    const Motion& mo = motion_[b];
    const Mat3 R = mo.q.toRotationMatrix();
    mass[t] = 1.0 / invMass_[b];
    const Mat3 I = R * inertiaRest_[b] * R.transpose();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) inertia[9 * t + std::size_t(3 * r + c)] = I(r, c);
      centre[3 * t + std::size_t(r)] = mo.c[r], bv[3 * t + std::size_t(r)] = mo.v[r], bw[3 * t + std::size_t(r)] = mo.w[r];
    }
  }
  for (std::size_t r = 0; r < nr; ++r) {
    const std::size_t i = strandParticles[r], t = nb + r;
    mass[t] = double(parts_.mass[i]);
    centre[3 * t] = parts_.x[i], centre[3 * t + 1] = parts_.y[i], centre[3 * t + 2] = parts_.z[i];
    bv[3 * t] = parts_.vx[i], bv[3 * t + 1] = parts_.vy[i], bv[3 * t + 2] = parts_.vz[i];
  }
  // The samples' inertia about their particle, sum m (|r|^2 1 - r r^T), and each sample's own as a
  // cube of a spacing's side (m s^2 / 6): a cloth particle's samples lie on a line, which alone
  // would leave the block singular about it.
  const double own = std::pow(2.0 * params_.particleRadius, 2) / 6.0;
  for (std::size_t k = 0; k < n; ++k) {
    if (strandOf[k] < 0) continue;
    const std::size_t t = nb + std::size_t(strandOf[k]);
    const Vec3 r = sampleOffset(k);
    const Mat3 I = (double(parts_.mass[std::size_t(fluidIds_[k])]) * double(sampleShare(k))) *
                   ((r.squaredNorm() + own) * Mat3::Identity() - r * r.transpose());
    for (int a = 0; a < 3; ++a)
      for (int c = 0; c < 3; ++c) inertia[9 * t + std::size_t(3 * a + c)] += I(a, c);
  }
  ViscousSolids solids;
  solids.role = role.data(), solids.bodies = nb + nr;
  solids.mass = mass.data(), solids.inertia = inertia.data(), solids.centre = centre.data();
  solids.v = bv.data(), solids.w = bw.data();
  fluid_->setPositions(fx_.data(), fy_.data(), fz_.data());
  fluid_->velocityPasses(vx.data(), vy.data(), vz.data(), static_cast<float>(h), &solids);
  for (std::size_t k = 0; k < n; ++k) {
    if (k >= fluidCount_ && role[k] != ViscousSolids::kFree) continue;
    const auto i = std::size_t(fluidIds_[k]);
    parts_.vx[i] = vx[k], parts_.vy[i] = vy[k], parts_.vz[i] = vz[k];
  }
  for (std::size_t t = 0; t < nb; ++t) {
    Motion& mo = motion_[bodies[t]];
    mo.v = Vec3(bv[3 * t], bv[3 * t + 1], bv[3 * t + 2]);
    mo.w = Vec3(bw[3 * t], bw[3 * t + 1], bw[3 * t + 2]);
  }
  for (std::size_t r = 0; r < nr; ++r) {
    const std::size_t i = strandParticles[r], t = nb + r;
    parts_.vx[i] = float(bv[3 * t]), parts_.vy[i] = float(bv[3 * t + 1]), parts_.vz[i] = float(bv[3 * t + 2]);
  }
}

}  // namespace physketch::pbd

namespace physketch::pbd {

DensityError PbdWorld::fluidDensityError() const {
  if (!fluid_ || fluidCount_ == 0 || fluid_->count() == 0) return DensityError{};
  return fluid_->densityError();
}

}  // namespace physketch::pbd

namespace physketch::pbd {

// Particle-level particles against the collider contacts found this substep: pushed out of
// the contact plane to a radius from it, then Coulomb friction against the surface's motion.
void PbdWorld::looseColliderContact() {
  if (looseHits_.empty()) return;
  const double h = params_.dt / params_.substeps;
  for (const MeshContact& c : looseHits_) {
    const auto i = std::size_t(c.particle);
    Vec3 p = at(px_, py_, pz_, i);
    const double pen = radiusOf(i) - (p - c.point).dot(c.normal);
    if (pen <= 0.0) continue;
    p += pen * c.normal;
    const Material& m = materials_[std::size_t(parts_.material[i])];
    const auto& fr = colliders_->collider(std::size_t(c.collider)).friction;
    if (!softBounce_.empty()) {
      const auto bi = std::size_t(parts_.group(i));
      if (bouncySoft(bi) &&
          approaching(at(parts_.vx, parts_.vy, parts_.vz, i) - colliders_->surfaceVelocity(std::size_t(c.collider), c.point),
                      c.normal)) {
        SoftBounce& sb = softBounce_[bi];
        sb.nSum += c.normal;
        sb.vSurface += colliders_->surfaceVelocity(std::size_t(c.collider), c.point);
        sb.eSum += restitution_[bi];
        ++sb.count;
      }
    }
    if (!bounceNoted_[i]) {
      const Vec3 vs = colliders_->surfaceVelocity(std::size_t(c.collider), c.point);
      noteParticleBounce({std::int32_t(i), -1, c.collider, c.normal, c.point,
                          (at(parts_.vx, parts_.vy, parts_.vz, i) - vs).dot(c.normal), m.restitution});
    }
    Vec3 rel = (p - at(parts_.x, parts_.y, parts_.z, i)) - colliders_->surfaceVelocity(std::size_t(c.collider), c.point) * h;
    rel -= rel.dot(c.normal) * c.normal;
    p -= frictionCorrection(rel, pen, fr ? *fr : m.staticFriction, fr ? *fr : m.dynamicFriction);
    put(px_, py_, pz_, i, p);
  }
}

}  // namespace physketch::pbd

namespace physketch::pbd {

// The fluids' mean compression against the guard's bound, at the kernel's current
// positions (after the last density iteration). The record names the fluid's first particle:
// the error is a mean over the fluid, not one particle's.
GuardRecord PbdWorld::checkCompression() const {
  GuardRecord r;
  if (!fluid_ || fluidCount_ == 0) return r;
  DensityError e;
  e.meanCompression = fluid_->lastMeanCompression();
  if (!(double(e.meanCompression) > params_.maxCompression) && std::isfinite(e.meanCompression)) return r;
  const auto i = std::size_t(fluidIds_.front());
  r.kind = GuardKind::kCompression;
  r.particle = fluidIds_.front();
  r.body = parts_.group(i);
  r.stroke = parts_.stroke[i];
  r.value = e.meanCompression;
  r.bound = params_.maxCompression;
  r.hint = "The fluid is compressed beyond the bound.";
  // A soft fluid by choice (the lowest sound_speed a fluid material sets): its own weight
  // compresses it by g d / c^2.
  const Material* soft = nullptr;
  for (std::size_t m : fluidMaterials_)
    if (!std::isnan(materials_[m].fluid.soundSpeed) && (!soft || materials_[m].fluid.soundSpeed < soft->fluid.soundSpeed))
      soft = &materials_[m];
  if (soft) {
    const double c = soft->fluid.soundSpeed, g = std::max(params_.gravity.norm(), 9.81);
    char note[300];
    std::snprintf(note, sizeof note,
                  " Fluid material '%s' has sound_speed %.3g m/s: its own weight compresses it by g d / c^2 = %.3g %% per"
                  " metre of depth d: raise sound_speed.",
                  soft->name.c_str(), c, 100.0 * g / (c * c));
    r.hint += note;
  }
  return r;
}

}  // namespace physketch::pbd
