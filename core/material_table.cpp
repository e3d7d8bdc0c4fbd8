#include "core/material_table.h"

#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "core/error.h"

namespace physketch {
namespace {

constexpr double kNone = std::numeric_limits<double>::quiet_NaN();

ParamRange closed(double lo, double hi) { return {lo, hi, false, false}; }
ParamRange openLo(double lo, double hi) { return {lo, hi, true, false}; }
ParamRange open(double lo, double hi) { return {lo, hi, true, true}; }

ParamSpec number(const char* kind, const char* key, const char* unit, double def, ParamRange range, unsigned solvers,
                 double& (*field)(Material&)) {
  return {kind, key, ParamType::kNumber, unit, def, nullptr, range, nullptr, solvers, field};
}
ParamSpec choice(const char* kind, const char* key, const char* choices, bool hasDefault, unsigned solvers) {
  return {kind, key, ParamType::kChoice, "-", hasDefault ? 0.0 : kNone, nullptr, {}, choices, solvers, nullptr};
}

// Where each number lives in Material (captureless lambdas: plain function pointers).
#define PHYSKETCH_FIELD(expr) [](Material& m) -> double& { return m.expr; }

std::vector<ParamSpec> buildTable() {
  std::vector<ParamSpec> t;
  const unsigned P = kUsedByPbd, M = kUsedByMpm, B = kUsedByBoth;
  // Every kind.
  t.push_back(number("all", "density", "kg/m^3", 1000, openLo(0, 1e5), B, PHYSKETCH_FIELD(density)));
  t.push_back(number("all", "static_friction", "-", 0.5, closed(0, 2), B, PHYSKETCH_FIELD(staticFriction)));
  ParamSpec dyn = number("all", "dynamic_friction", "-", kNone, closed(0, 2), B, PHYSKETCH_FIELD(dynamicFriction));
  dyn.defaultFrom = "static_friction";
  t.push_back(dyn);
  t.push_back(number("all", "restitution", "-", 0, closed(0, 1), P, PHYSKETCH_FIELD(restitution)));
  t.push_back({"all", "color", ParamType::kColor, "-", 0.7, nullptr, closed(0, 1), nullptr, B, nullptr});
  t.push_back(number("all", "roughness", "-", 0.5, closed(0, 1), B, PHYSKETCH_FIELD(roughness)));
  t.push_back(choice("all", "look", "mesh|splats", true, B));
  // soft (pbd: clustered shape matching; mpm runs it as elastic).
  t.push_back(number("soft", "E", "Pa", 5e5, openLo(0, 1e12), B, PHYSKETCH_FIELD(elastic.youngs)));
  t.push_back(choice("soft", "preset", "soft|medium|hard", false, B));
  t.push_back(number("soft", "compliance", "m/N", kNone, closed(0, 1), P, PHYSKETCH_FIELD(soft.compliance)));
  t.push_back(number("soft", "nu", "-", 0.3, open(0, 0.5), M, PHYSKETCH_FIELD(elastic.poisson)));
  t.push_back(choice("soft", "model", "corotated|neohookean", true, M));
  t.push_back(number("soft", "cluster_radius", "h", 3, closed(1, 20), P, PHYSKETCH_FIELD(soft.clusterRadius)));
  t.push_back(number("soft", "cluster_spacing", "h", 2, closed(1, 40), P, PHYSKETCH_FIELD(soft.clusterSpacing)));
  t.push_back(number("soft", "plastic_yield", "-", 0.1, closed(0, 10), P, PHYSKETCH_FIELD(soft.plasticYield)));
  t.push_back(number("soft", "plastic_creep", "1/s", 0, closed(0, 1000), P, PHYSKETCH_FIELD(soft.plasticCreep)));
  // fluid (pbd: PBF; mpm: weakly compressible).
  t.push_back(number("fluid", "xsph_viscosity", "-", 0.01, closed(0, 1), P, PHYSKETCH_FIELD(fluid.xsphViscosity)));
  t.push_back(number("fluid", "vorticity", "m/s", 0, closed(0, 100), P, PHYSKETCH_FIELD(fluid.vorticity)));
  t.push_back(number("fluid", "cohesion", "m/s^2", 0, closed(0, 10), P, PHYSKETCH_FIELD(fluid.cohesion)));
  t.push_back(number("fluid", "relaxation", "-", 0.1, openLo(0, 1000), P, PHYSKETCH_FIELD(fluid.relaxation)));
  t.push_back(number("fluid", "sound_speed", "m/s", kNone, openLo(0, 1e5), P, PHYSKETCH_FIELD(fluid.soundSpeed)));
  t.push_back(number("fluid", "bulk_modulus", "Pa", 1e5, openLo(0, 1e10), M, PHYSKETCH_FIELD(fluid.bulkModulus)));
  t.push_back(number("fluid", "gamma", "-", 7, closed(1, 10), M, PHYSKETCH_FIELD(fluid.gamma)));
  t.push_back(number("fluid", "viscosity", "Pa*s", 1e-3, closed(0, 1e6), B, PHYSKETCH_FIELD(fluid.viscosity)));
  // rope, cloth (pbd only).
  for (const char* k : {"rope", "cloth"}) {
    t.push_back(number(k, "stretch_compliance", "m/N", 0, closed(0, 1), P, PHYSKETCH_FIELD(strand.stretchCompliance)));
    t.push_back(number(k, "bend_compliance", "m/N", 1, closed(0, 1e6), P, PHYSKETCH_FIELD(strand.bendCompliance)));
  }
  // elastic (mpm; pbd runs it as soft).
  t.push_back(number("elastic", "E", "Pa", 5e5, openLo(0, 1e12), B, PHYSKETCH_FIELD(elastic.youngs)));
  t.push_back(choice("elastic", "preset", "soft|medium|hard", false, B));
  t.push_back(number("elastic", "nu", "-", 0.3, open(0, 0.5), M, PHYSKETCH_FIELD(elastic.poisson)));
  t.push_back(choice("elastic", "model", "corotated|neohookean", true, M));
  // sand (mpm only): Klár et al. 2016 (E, nu); bulk density of dry sand.
  t.push_back(number("sand", "density", "kg/m^3", 1600, openLo(0, 1e5), M, PHYSKETCH_FIELD(density)));
  t.push_back(number("sand", "E", "Pa", 3.537e5, openLo(0, 1e12), M, PHYSKETCH_FIELD(elastic.youngs)));
  t.push_back(choice("sand", "preset", "soft|medium|hard", false, M));
  t.push_back(number("sand", "nu", "-", 0.3, open(0, 0.5), M, PHYSKETCH_FIELD(elastic.poisson)));
  t.push_back(number("sand", "friction_angle", "deg", 30, closed(0, 80), M, PHYSKETCH_FIELD(sand.frictionAngleDeg)));
  t.push_back(number("sand", "cohesion", "Pa", 0, closed(0, 1e9), M, PHYSKETCH_FIELD(sand.cohesion)));
  t.push_back(number("sand", "hardening", "deg", 0, closed(0, 90), M, PHYSKETCH_FIELD(sand.hardening)));
  t.push_back(choice("sand", "hardening_law", "linear|klar", true, M));
  t.push_back(number("sand", "h0", "deg", 35, closed(0, 80), M, PHYSKETCH_FIELD(sand.h0)));
  t.push_back(number("sand", "h1", "deg", 9, closed(0, 90), M, PHYSKETCH_FIELD(sand.h1)));
  t.push_back(number("sand", "h2", "-", 0.2, closed(0, 100), M, PHYSKETCH_FIELD(sand.h2)));
  t.push_back(number("sand", "h3", "deg", 10, closed(0, 80), M, PHYSKETCH_FIELD(sand.h3)));
  // snow (mpm only): Stomakhin et al. 2013, Table 1 reference values.
  t.push_back(number("snow", "density", "kg/m^3", 400, openLo(0, 1e5), M, PHYSKETCH_FIELD(density)));
  t.push_back(number("snow", "E", "Pa", 1.4e5, openLo(0, 1e12), M, PHYSKETCH_FIELD(elastic.youngs)));
  t.push_back(choice("snow", "preset", "soft|medium|hard", false, M));
  t.push_back(number("snow", "nu", "-", 0.2, open(0, 0.5), M, PHYSKETCH_FIELD(elastic.poisson)));
  t.push_back(number("snow", "theta_c", "-", 2.5e-2, open(0, 1), M, PHYSKETCH_FIELD(snow.thetaC)));
  t.push_back(number("snow", "theta_s", "-", 7.5e-3, open(0, 1), M, PHYSKETCH_FIELD(snow.thetaS)));
  t.push_back(number("snow", "hardening", "-", 10, closed(0, 100), M, PHYSKETCH_FIELD(snow.hardening)));
  // plasticine (mpm only): von Mises.
  t.push_back(number("plasticine", "E", "Pa", 5e5, openLo(0, 1e12), M, PHYSKETCH_FIELD(elastic.youngs)));
  t.push_back(choice("plasticine", "preset", "soft|medium|hard", false, M));
  t.push_back(number("plasticine", "nu", "-", 0.3, open(0, 0.5), M, PHYSKETCH_FIELD(elastic.poisson)));
  t.push_back(number("plasticine", "yield_stress", "Pa", 1e4, openLo(0, 1e9), M,
                     PHYSKETCH_FIELD(plasticine.yieldStress)));
  return t;
}

#undef PHYSKETCH_FIELD

std::vector<std::string> splitChoices(const char* choices) {
  std::vector<std::string> out;
  std::string cur;
  for (const char* c = choices; *c; ++c) {
    if (*c == '|') {
      out.push_back(cur);
      cur.clear();
    } else {
      cur += *c;
    }
  }
  out.push_back(cur);
  return out;
}

std::string num(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

// Sets a choice parameter by its index in the row's choices.
void setChoice(Material& m, const std::string& key, int index) {
  if (key == "model") m.elastic.model = static_cast<ElasticModel>(index);
  else if (key == "look") m.look = static_cast<Material::Look>(index);
  else if (key == "hardening_law") m.sand.klar = index == 1;
  else if (key == "preset") {
    m.elastic.preset = static_cast<StiffnessPreset>(index);
    m.elastic.youngs = presetYoungsModulus(m.elastic.preset);
  }
}

// Every key of every kind: the options a material record may name at all.
const std::vector<std::string>& allKeys() {
  static const std::vector<std::string> keys = [] {
    std::vector<std::string> k;
    for (const ParamSpec& p : materialParams()) {
      bool seen = false;
      for (const auto& s : k) seen = seen || s == p.key;
      if (!seen) k.push_back(p.key);
    }
    return k;
  }();
  return keys;
}

// Parses and range-checks one option into `m`. Throws InputError naming the key.
void applyOption(const RecordFile& file, int line, const ParamSpec& spec, const RecordOption& o, Material& m) {
  const std::string& key = o.key;
  switch (spec.type) {
    case ParamType::kNumber: {
      const double v = parseNumberList(file, line, key, o.value, 1)[0];
      if (!spec.range.contains(v))
        throw InputError(file.path, line, key, "must be in " + spec.range.text() + " " + spec.unit + " (got " + o.value + ")");
      spec.field(m) = v;
      break;
    }
    case ParamType::kColor: {
      const auto c = parseNumberList(file, line, key, o.value, 3);
      for (int i = 0; i < 3; ++i) {
        if (!spec.range.contains(c[static_cast<std::size_t>(i)]))
          throw InputError(file.path, line, key, "each channel must be in " + spec.range.text() + " (got " + o.value + ")");
        m.color[static_cast<std::size_t>(i)] = static_cast<float>(c[static_cast<std::size_t>(i)]);
      }
      break;
    }
    case ParamType::kChoice: {
      const auto choices = splitChoices(spec.choices);
      int index = -1;
      for (std::size_t i = 0; i < choices.size(); ++i)
        if (choices[i] == o.value) index = static_cast<int>(i);
      if (index < 0) {
        std::string list;
        for (const auto& c : choices) list += (list.empty() ? "" : ", ") + c;
        throw InputError(file.path, line, key, "unknown " + key + " '" + o.value + "' (known: " + list + ")");
      }
      setChoice(m, key, index);
      break;
    }
  }
}

// Checks between parameters, after all are set: one source for E, friction order, clusters overlap.
void checkCombinations(const RecordFile& file, int line, Material& m) {
  const bool E = m.wasGiven("E"), preset = m.wasGiven("preset"), compliance = m.wasGiven("compliance");
  if (E && preset)
    throw InputError(file.path, line, "preset", "give either preset= or E=, not both (a preset sets E)");
  if (compliance && (E || preset))
    throw InputError(file.path, line, "compliance",
                     std::string("give either compliance= or ") + (E ? "E=" : "preset=") + ", not both");
  // Sand's friction angle comes from one law: friction_angle (+ hardening), or Klár's h0..h3.
  if (m.sand.klar) {
    for (const char* k : {"friction_angle", "hardening"})
      if (m.wasGiven(k))
        throw InputError(file.path, line, k,
                         std::string("hardening_law=klar sets the friction angle from h0..h3 (h0 + (h1 q - h3) e^(-h2 q)); "
                                     "give ") + k + "= or hardening_law=klar, not both");
    if (m.sand.h0 - m.sand.h3 < 0.0)
      throw InputError(file.path, line, "h3", "h0 - h3, the angle at q = 0, must be >= 0 (got " + num(m.sand.h0 - m.sand.h3) + ")");
  } else {
    for (const char* k : {"h0", "h1", "h2", "h3"})
      if (m.wasGiven(k))
        throw InputError(file.path, line, k, std::string(k) + " is a parameter of Klár's hardening law: write hardening_law=klar");
  }
  if (!m.wasGiven("dynamic_friction")) m.dynamicFriction = m.staticFriction;
  if (m.dynamicFriction > m.staticFriction)
    throw InputError(file.path, line, "dynamic_friction",
                     "must be <= static_friction (" + num(m.dynamicFriction) + " > " + num(m.staticFriction) +
                         (m.wasGiven("static_friction") ? "" : ", the default") + ")");
  if (m.kind == MaterialKind::kSoft && !(m.soft.clusterSpacing < 2.0 * m.soft.clusterRadius))
    throw InputError(file.path, line, m.wasGiven("cluster_spacing") ? "cluster_spacing" : "cluster_radius",
                     "cluster_spacing must be < 2 * cluster_radius so neighbouring clusters share particles (got " +
                         num(m.soft.clusterSpacing) + " and " + num(m.soft.clusterRadius) + ")");
}

// The short form of the first release: NAME KIND DENSITY FRICTION R G B.
void applyShortForm(const FieldReader& fr, Material& m) {
  const ParamSpec& density = *findParam(m.kind, "density");
  const ParamSpec& friction = *findParam(m.kind, "static_friction");
  const ParamSpec& color = *findParam(m.kind, "color");
  m.density = fr.number(2);
  if (!density.range.contains(m.density)) fr.fail(2, "must be in " + density.range.text() + " kg/m^3 (got " + fr.word(2) + ")");
  m.staticFriction = m.dynamicFriction = fr.number(3);
  if (!friction.range.contains(m.staticFriction)) fr.fail(3, "must be in " + friction.range.text() + " (got " + fr.word(3) + ")");
  for (std::size_t c = 0; c < 3; ++c) {
    const double v = fr.number(4 + c);
    if (!color.range.contains(v)) fr.fail(4 + c, "must be in " + color.range.text() + " (got " + fr.word(4 + c) + ")");
    m.color[c] = static_cast<float>(v);
  }
  m.given = {"density", "static_friction", "dynamic_friction", "color"};
}

}  // namespace

bool usedBy(unsigned solvers, SolverKind solver) {
  return (solvers & (solver == SolverKind::kPbd ? kUsedByPbd : kUsedByMpm)) != 0;
}

const char* toString(unsigned solvers) {
  return solvers == kUsedByBoth ? "both" : solvers == kUsedByPbd ? "pbd" : solvers == kUsedByMpm ? "mpm" : "none";
}

bool ParamRange::contains(double v) const {
  return (loOpen ? v > lo : v >= lo) && (hiOpen ? v < hi : v <= hi);
}

std::string ParamRange::text() const {
  return std::string(loOpen ? "(" : "[") + num(lo) + ", " + num(hi) + (hiOpen ? ")" : "]");
}

const std::vector<ParamSpec>& materialParams() {
  static const std::vector<ParamSpec> table = buildTable();
  return table;
}

const ParamSpec* findParam(MaterialKind kind, const std::string& key) {
  const ParamSpec* common = nullptr;
  for (const ParamSpec& p : materialParams()) {
    if (key != p.key) continue;
    if (std::string(p.kind) == toString(kind)) return &p;
    if (std::string(p.kind) == "all") common = &p;
  }
  return common;
}

std::string kindsWithParam(const std::string& key) {
  std::string s;
  for (int k = 0; k < kMaterialKindCount; ++k)
    if (findParam(static_cast<MaterialKind>(k), key)) s += (s.empty() ? "" : ", ") + std::string(toString(static_cast<MaterialKind>(k)));
  return s;
}

Material makeMaterial(MaterialKind kind, const std::string& name) {
  Material m;
  m.name = name;
  m.kind = kind;
  auto apply = [&m](const ParamSpec& p) {
    if (p.type == ParamType::kNumber && !std::isnan(p.def)) p.field(m) = p.def;
    if (p.type == ParamType::kColor) m.color.fill(static_cast<float>(p.def));
    if (p.type == ParamType::kChoice && !std::isnan(p.def)) setChoice(m, p.key, 0);
  };
  // The "all" rows first, then the kind's own rows, which override them.
  for (const ParamSpec& p : materialParams())
    if (std::string(p.kind) == "all") apply(p);
  for (const ParamSpec& p : materialParams())
    if (std::string(p.kind) == toString(kind)) apply(p);
  m.dynamicFriction = m.staticFriction;  // dynamic_friction's default is static_friction
  return m;
}

Material parseMaterialRecord(const RecordFile& file, const Record& record) {
  Record pos;
  const auto options = splitOptions(file, record, pos, allKeys());
  FieldReader fr(file, pos, {"name", "kind", "density", "friction", "r", "g", "b"}, 2);
  const std::string& name = fr.word(0);
  // A stroke record's bare flag cannot also be a material name there.
  if (name == "fixed") fr.fail(0, "'fixed' is a reserved word (the flag of create operations); pick another name");
  MaterialKind kind;
  if (!parseMaterialKind(fr.word(1), kind))
    fr.fail(1, "unknown material kind '" + fr.word(1) + "' (known: " + materialKindList() + ")");
  Material m = makeMaterial(kind, name);
  m.line = record.line;
  if (fr.count() > 2) {
    if (fr.count() < 7)
      fr.fail(fr.count(), "missing (the short form is NAME KIND DENSITY FRICTION R G B; or give key=value parameters)");
    if (!options.empty())
      throw InputError(file.path, record.line, options.front().key,
                       "the short form (NAME KIND DENSITY FRICTION R G B) takes no key=value parameters: write "
                       "density=, static_friction=, dynamic_friction=, color= instead");
    applyShortForm(fr, m);
  }
  for (const RecordOption& o : options) {
    const ParamSpec* spec = findParam(kind, o.key);
    if (!spec)
      throw InputError(file.path, record.line, o.key,
                       "kind " + std::string(toString(kind)) + " has no parameter '" + o.key + "' (" + o.key +
                           " belongs to: " + kindsWithParam(o.key) + ")");
    applyOption(file, record.line, *spec, o, m);
    m.given.push_back(o.key);
  }
  checkCombinations(file, record.line, m);
  return m;
}

Material asRunBy(const Material& m, SolverKind solver) {
  const SolverModel model = solverModel(m.kind, solver);
  if (!model.simulated)
    throw std::invalid_argument(std::string("asRunBy: solver ") + toString(solver) + " does not simulate " + toString(m.kind));
  if (model.runsAs == m.kind) return m;
  Material out = makeMaterial(model.runsAs, m.name);
  // What every kind has carries over unchanged.
  out.line = m.line;
  out.density = m.density;
  out.staticFriction = m.staticFriction;
  out.dynamicFriction = m.dynamicFriction;
  out.restitution = m.restitution;
  out.color = m.color;
  out.roughness = m.roughness;
  out.look = m.look;
  out.frictionRule = m.frictionRule;
  out.given = m.given;
  if (m.kind == MaterialKind::kRigid) {
    out.elastic.preset = StiffnessPreset::kHard;  // rigid under mpm: a stiff elastic
    out.elastic.youngs = presetYoungsModulus(StiffnessPreset::kHard);
  } else {
    out.elastic = m.elastic;  // soft <-> elastic: E (and nu, model for mpm)
  }
  return out;
}

}  // namespace physketch
