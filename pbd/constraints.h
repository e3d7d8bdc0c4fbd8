// Particle groups and constraints, one array per kind and one loop per kind (no virtual
// call per constraint; Jolt's ApplyEdgeConstraints, Box2D's solver stages). Rigid bodies
// are member lists in PbdWorld; soft bodies are overlapping clusters; ropes and cloth are
// distance (and bending) constraints. The kinds the scene format defines but PBD does not
// simulate yet (soft, rope, cloth, fluid) fill these in the PBD issue; the layout and the
// XPBD distance loop are settled here so each kind adds an array and a loop, not a design.
#pragma once

#include <cstdint>
#include <vector>

namespace physketch::pbd {

// Overlapping particle index lists in CSR form: cluster k is index[offset[k] .. offset[k+1]).
// Shape-matching clusters of radius R whose centres are at least dC apart (Phys-Sketch Fig. 3).
struct Clusters {
  std::vector<std::int32_t> offset{0};
  std::vector<std::int32_t> index;
  std::vector<float> stiffness;  // per cluster, in [0, 1]
  std::size_t size() const { return offset.size() - 1; }
  void add(const std::vector<std::int32_t>& members, float k) {
    index.insert(index.end(), members.begin(), members.end());
    offset.push_back(static_cast<std::int32_t>(index.size()));
    stiffness.push_back(k);
  }
};

// Distance constraints C = |x_i - x_j| - rest with XPBD compliance alpha (m/N), so the
// stiffness does not change with iterations or substeps (Macklin et al. 2016, "XPBD").
struct DistanceConstraints {
  std::vector<std::int32_t> i, j;
  std::vector<float> rest;        // m
  std::vector<float> compliance;  // m/N; 0 = inextensible
  std::vector<float> lambda;      // accumulated Lagrange multiplier of this substep (N s^2)
  // Colour: a run of consecutive constraints with the same colour >= 0 shares no particle,
  // so the run can be solved in parallel with the same result (each particle is written by
  // one constraint of it). -1: solved in order with its neighbours.
  std::vector<std::int32_t> colour;
  std::size_t size() const { return i.size(); }
  void add(std::int32_t a, std::int32_t b, float restLength, float alpha, std::int32_t c = -1) {
    i.push_back(a), j.push_back(b), rest.push_back(restLength), compliance.push_back(alpha), lambda.push_back(0.0f);
    colour.push_back(c);
  }
  void resetMultipliers() { lambda.assign(lambda.size(), 0.0f); }
};

// One Gauss-Seidel sweep over all distance constraints in array order (deterministic; a run
// of one colour, whose constraints share no particle, in parallel chunks):
// dlambda = (-C - alpha~ lambda) / (w_i + w_j + alpha~), alpha~ = alpha / h^2, and each end
// moves by w dlambda along the constraint gradient (XPBD Eq. 18 and 17). Positions are the
// predicted positions p; invMass 0 holds a particle still.
void solveDistances(DistanceConstraints& c, float* px, float* py, float* pz, const float* invMass, double h);

}  // namespace physketch::pbd
