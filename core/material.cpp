#include "core/material.h"

#include <cmath>

namespace physketch {

namespace {
constexpr const char* kKindNames[kMaterialKindCount] = {"rigid", "soft",  "fluid", "rope",      "cloth",
                                                        "elastic", "sand", "snow",  "plasticine"};
}  // namespace

const char* toString(SolverKind solver) { return solver == SolverKind::kPbd ? "pbd" : "mpm"; }

bool parseSolverKind(const std::string& name, SolverKind& out) {
  if (name == "pbd") out = SolverKind::kPbd;
  else if (name == "mpm") out = SolverKind::kMpm;
  else return false;
  return true;
}

const char* toString(MaterialKind kind) {
  const int i = static_cast<int>(kind);
  return i >= 0 && i < kMaterialKindCount ? kKindNames[i] : "?";
}

bool parseMaterialKind(const std::string& name, MaterialKind& out) {
  for (int i = 0; i < kMaterialKindCount; ++i)
    if (name == kKindNames[i]) {
      out = static_cast<MaterialKind>(i);
      return true;
    }
  return false;
}

std::string materialKindList() {
  std::string s;
  for (const char* k : kKindNames) s += (s.empty() ? "" : ", ") + std::string(k);
  return s;
}

double presetYoungsModulus(StiffnessPreset preset) {
  switch (preset) {
    case StiffnessPreset::kSoft: return 5e4;
    case StiffnessPreset::kMedium: return 5e5;
    case StiffnessPreset::kHard: return 5e6;
    case StiffnessPreset::kNone: break;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

bool Material::wasGiven(const std::string& key) const {
  for (const auto& k : given)
    if (k == key) return true;
  return false;
}

double softCompliance(const Material& m, double spacing) {
  if (!std::isnan(m.soft.compliance)) return m.soft.compliance;
  return 1.0 / (m.elastic.youngs * spacing);
}

int findMaterial(const std::vector<Material>& materials, const std::string& name) {
  for (std::size_t i = 0; i < materials.size(); ++i)
    if (materials[i].name == name) return static_cast<int>(i);
  return -1;
}

SolverModel solverModel(MaterialKind kind, SolverKind solver) {
  using K = MaterialKind;
  const bool pbd = solver == SolverKind::kPbd;
  auto runs = [solver](K as, const char* how) { return SolverModel{true, as, solver, how}; };
  auto onlyBy = [](SolverKind other) { return SolverModel{false, K::kRigid, other, ""}; };
  switch (kind) {
    case K::kRigid:
      return pbd ? runs(K::kRigid, "shape matching, one cluster per body (Müller et al. 2005)")
                 : runs(K::kElastic, "a stiff elastic: corotated, E = 5e6 Pa (the hard preset), nu = 0.3");
    case K::kSoft:
      return pbd ? runs(K::kSoft, "clustered shape matching (Phys-Sketch Fig. 3), XPBD compliance")
                 : runs(K::kElastic, "elastic with the material's E, corotated, nu = 0.3");
    case K::kFluid:
      return pbd ? runs(K::kFluid, "position-based fluids (Macklin & Müller 2013)")
                 : runs(K::kFluid, "weakly compressible fluid (Tait equation of state)");
    case K::kRope:
    case K::kCloth:
      return pbd ? runs(kind, "XPBD distance and bending constraints") : onlyBy(SolverKind::kPbd);
    case K::kElastic:
      return pbd ? runs(K::kSoft, "soft with the material's E and the soft cluster defaults")
                 : runs(K::kElastic, "hyperelastic: fixed corotated or neo-Hookean");
    case K::kSand:
      return pbd ? onlyBy(SolverKind::kMpm) : runs(K::kSand, "Drucker-Prager plasticity (Klár et al. 2016)");
    case K::kSnow:
      return pbd ? onlyBy(SolverKind::kMpm) : runs(K::kSnow, "corotated with hardening (Stomakhin et al. 2013)");
    case K::kPlasticine:
      return pbd ? onlyBy(SolverKind::kMpm) : runs(K::kPlasticine, "von Mises plasticity");
  }
  return onlyBy(SolverKind::kPbd);
}

void pairFriction(const Material& a, const Material& b, double& mus, double& muk) {
  using Rule = Material::FrictionRule;
  const bool ownA = a.frictionRule == Rule::kOwn, ownB = b.frictionRule == Rule::kOwn;
  const bool otherA = a.frictionRule == Rule::kOther, otherB = b.frictionRule == Rule::kOther;
  if (ownA != ownB) {
    const Material& m = ownA ? a : b;
    mus = m.staticFriction, muk = m.dynamicFriction;
  } else if (!ownA && otherA != otherB) {
    const Material& m = otherA ? b : a;
    mus = m.staticFriction, muk = m.dynamicFriction;
  } else if (!ownA && otherA) {
    mus = muk = 0.5;  // two tools without friction=: neither names one
  } else {
    mus = 0.5 * (a.staticFriction + b.staticFriction);
    muk = 0.5 * (a.dynamicFriction + b.dynamicFriction);
  }
}

}  // namespace physketch
