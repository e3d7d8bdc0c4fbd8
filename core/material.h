// Materials: a kind (how it behaves), its parameters and a display colour.
//
// One format serves both solvers: a scene names a kind and sets parameters as key=value
// (docs/formats.md, "Materials"). The parameter table (names, units, defaults, ranges,
// which solver uses each) lives in core/material_table.h; this header holds the typed
// result that solvers read.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace physketch {

enum class SolverKind { kPbd, kMpm };
constexpr int kSolverKindCount = 2;
const char* toString(SolverKind solver);
// Returns false when `name` is not a solver ("pbd", "mpm").
bool parseSolverKind(const std::string& name, SolverKind& out);

// PBD kinds first (Phys-Sketch §5.1), then MPM kinds (VR-Doh supplement §1.1). `fluid`
// is simulated by both: position-based fluids under pbd, weakly compressible under mpm.
enum class MaterialKind { kRigid, kSoft, kFluid, kRope, kCloth, kElastic, kSand, kSnow, kPlasticine };
constexpr int kMaterialKindCount = 9;
const char* toString(MaterialKind kind);
// Returns false when `name` is not a known kind.
bool parseMaterialKind(const std::string& name, MaterialKind& out);
// "rigid, soft, ..." in enum order, for messages.
std::string materialKindList();

// MPM hyperelastic energy (VR-Doh supplement §1.2): fixed corotated (Stomakhin et al. 2012)
// or neo-Hookean.
enum class ElasticModel { kCorotated, kNeoHookean };

// PhysGen3D's material classes (supplement §A.4): E = 5e4 / 5e5 / 5e6 Pa.
enum class StiffnessPreset { kNone = -1, kSoft = 0, kMedium = 1, kHard = 2 };
double presetYoungsModulus(StiffnessPreset preset);  // Pa

// A material as the scene defines it. Typed per-kind parameter groups rather than a
// key -> value map: solvers read `m.sand.frictionAngleDeg`, a rename is a compile error
// and no string is looked up in a solver loop. The table in core/material_table.h binds
// each scene key to one of these fields, so names, units, defaults and ranges still have
// one source. `Material{}` is a rigid material with the table's defaults; build other
// kinds with makeMaterial(kind) to get that kind's defaults.
struct Material {
  std::string name;
  MaterialKind kind = MaterialKind::kRigid;
  int line = 0;  // line of its scene record (0: made in code)

  // Every kind.
  double density = 1000.0;       // kg/m^3; particle mass = density * spacing^3 (fluid: rest density)
  double staticFriction = 0.5;   // Coulomb coefficient against everything it touches, [0, 2]
  double dynamicFriction = 0.5;  // kinetic coefficient, [0, staticFriction]
  double restitution = 0.0;                       // [0, 1], normal speed kept after a contact
  std::array<float, 3> color{0.7f, 0.7f, 0.7f};  // linear RGB in [0, 1]
  double roughness = 0.5;  // rendering only, [0, 1]: 0 a sharp highlight, 1 a broad faint one (render/renderer.h)
  // How this material's friction combines with another's at a contact (pairFriction): kMean, the
  // mean of both (every scene material); kOwn, this material's coefficients decide (a tool stroke
  // with friction=mu); kOther, the other material's decide (a tool stroke without it).
  enum class FrictionRule : std::uint8_t { kMean, kOwn, kOther };
  FrictionRule frictionRule = FrictionRule::kMean;
  // Rendering only: how frames draw its particles: a surface (kMesh) or Gaussian splats (kSplats,
  // `look=splats`; physketch run --look splats draws every material so).
  enum class Look : std::uint8_t { kMesh, kSplats };
  Look look = Look::kMesh;

  // Young's modulus and friends: soft (E only), elastic, sand, snow, plasticine.
  struct Elastic {
    double youngs = 5e5;   // E, Pa
    double poisson = 0.3;  // nu, (0, 0.5); Lamé: lambda = E nu/((1+nu)(1-2nu)), mu = E/(2(1+nu))
    ElasticModel model = ElasticModel::kCorotated;
    StiffnessPreset preset = StiffnessPreset::kNone;  // the preset E came from, if any
  } elastic;

  // soft: clustered shape matching (Phys-Sketch §5.1, Fig. 3) with XPBD compliance.
  struct Soft {
    // XPBD compliance of the cluster goal constraints, m/N. NaN: derived from elastic.youngs
    // (softCompliance()).
    double compliance = std::numeric_limits<double>::quiet_NaN();
    double clusterRadius = 3.0;   // R, in particle spacings
    double clusterSpacing = 2.0;  // dC, minimum distance between cluster centres, in particle spacings
    double plasticYield = 0.1;    // c_yield: strain norm above which the rest shape creeps (Müller 2005 §4.4)
    double plasticCreep = 0.0;    // c_creep, 1/s; 0 = purely elastic
  } soft;

  // fluid. pbd: position-based fluids (Macklin & Müller 2013); mpm: weakly compressible.
  struct Fluid {
    double xsphViscosity = 0.01;  // pbd: XSPH c (Eq. 17), dimensionless
    double vorticity = 0.0;       // pbd: vorticity confinement epsilon (Eq. 16), m/s
    double cohesion = 0.0;        // pbd: cohesion gamma (Akinci et al. 2013), m/s^2
    double relaxation = 0.1;      // pbd: constraint relaxation epsilon (Eq. 11), relative (pbd/fluid.h)
    // pbd: sound speed c (m/s) of the density constraint's XPBD compliance (pbd/fluid.h);
    // NaN = auto (FluidSolver::autoSoundSpeed from the fluid's height and fastest particle).
    double soundSpeed = std::numeric_limits<double>::quiet_NaN();
    double bulkModulus = 1e5;     // mpm: K, Pa; p = K/gamma ((rho/rho0)^gamma - 1)
    double gamma = 7.0;           // mpm: EOS exponent
    double viscosity = 1e-3;      // mpm, pbd (implicit, above 10x water's mu / rho0): dynamic viscosity, Pa*s
  } fluid;

  // rope, cloth: XPBD distance and bending constraints.
  struct Strand {
    double stretchCompliance = 0.0;  // m/N
    double bendCompliance = 1.0;     // m/N, of the links across two particles
  } strand;

  // sand: Drucker-Prager plasticity (Klár et al. 2016).
  struct Sand {
    double frictionAngleDeg = 30.0;  // internal friction angle, degrees
    double cohesion = 0.0;           // Pa, shifts the yield cone
    double hardening = 0.0;          // degrees per unit plastic strain q: angle = frictionAngleDeg + hardening*q
    // hardening_law=klar: Klár et al. 2016's law (§7.3) instead, angle = h0 + (h1 q - h3) e^(-h2 q)
    // (h0, h1, h3 in degrees), their values by default: 25 degrees at q = 0, rising to 48 at
    // q = 6.1 and settling to h0.
    bool klar = false;
    double h0 = 35.0, h1 = 9.0, h2 = 0.2, h3 = 10.0;
  } sand;

  // snow: Stomakhin et al. 2013.
  struct Snow {
    double thetaC = 2.5e-2;  // critical compression
    double thetaS = 7.5e-3;  // critical stretch
    double hardening = 10.0;  // xi
  } snow;

  // plasticine: von Mises plasticity (VR-Doh supplement Eq. 10).
  struct Plasticine {
    double yieldStress = 1e4;  // tau_Y, Pa
  } plasticine;

  // Parameter keys the scene set explicitly, in record order (the solver check reports a
  // key the chosen solver does not use).
  std::vector<std::string> given;
  bool wasGiven(const std::string& key) const;
};

// XPBD compliance (m/N) of a soft material for particle spacing h (m): the given
// compliance, or 1/(E h) — a cube of edge h under E has spring stiffness k = E h^2 / h.
double softCompliance(const Material& m, double spacing);

// The static and dynamic Coulomb coefficients of a contact between materials a and b: the one
// whose rule is kOwn decides (both: their mean); else the other of one whose rule is kOther
// (both: 0.5, the default coefficient); else the mean of the two.
void pairFriction(const Material& a, const Material& b, double& mus, double& muk);

// Index of the material called `name`, or -1.
int findMaterial(const std::vector<Material>& materials, const std::string& name);

// What a solver runs for a material kind. Every kind means something under both solvers
// or is an error naming the solver that simulates it.
struct SolverModel {
  bool simulated = false;  // false: `solver` never simulates `kind`; `simulatedBy` does
  MaterialKind runsAs = MaterialKind::kRigid;
  SolverKind simulatedBy = SolverKind::kPbd;
  const char* how = "";  // one line: the model and what carries over
};
SolverModel solverModel(MaterialKind kind, SolverKind solver);

}  // namespace physketch
