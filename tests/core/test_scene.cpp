// Scene file parsing and validation.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "core/error.h"
#include "core/material_table.h"
#include "core/scene.h"
#include "core/support.h"

using namespace physketch;

namespace {

const char* kGood =
    "physketch-scene 1\n"
    "strokes s.strokes\n"
    "workspace 0 0.5 0 2\n"
    "dt 0.01\n"
    "substeps 2\n"
    "iterations 3\n"
    "fps 25\n"
    "duration 1\n"
    "material wood rigid 600 0.5 1 0.5 0\n";

InputError sceneError(const std::string& extra) {
  try {
    parseScene(std::string(kGood) + extra, "dir/x.scene");
  } catch (const InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected InputError for: " << extra;
  return InputError("", 0, "", "");
}

}  // namespace

TEST(Scene, ParsesValuesAndResolvesStrokePathRelativeToScene) {
  const SceneDesc s = parseScene(kGood, "dir/x.scene");
  EXPECT_EQ(s.strokesPath, "dir/s.strokes");
  EXPECT_DOUBLE_EQ(s.workspaceSize, 2.0);
  EXPECT_EQ(s.substeps, 2);
  EXPECT_EQ(s.iterations, 3);
  EXPECT_EQ(s.stepsPerFrame(), 4);   // (1/25) / 0.01
  EXPECT_EQ(s.frameCount(), 26);     // frames at t = 0, 0.04, ..., 1.0
  ASSERT_EQ(s.materials.size(), 1u);
  EXPECT_EQ(s.materials[0].name, "wood");
  EXPECT_FLOAT_EQ(s.materials[0].color[1], 0.5f);
}

TEST(Scene, EveryErrorNamesLineAndField) {
  // kGood has 9 lines; an appended record is on line 10.
  auto e = sceneError("bogus 1\n");
  EXPECT_EQ(e.line(), 10);
  EXPECT_NE(std::string(e.what()).find("unknown record 'bogus'"), std::string::npos);
  e = sceneError("material stone rigid -1 0.5 1 1 1\n");
  EXPECT_EQ(e.field(), "density");
  e = sceneError("material stone rigid 100 nan 1 1 1\n");
  EXPECT_EQ(e.field(), "friction");
  e = sceneError("material stone jelly 100 0.5 1 1 1\n");
  EXPECT_EQ(e.field(), "kind");
  e = sceneError("material wood rigid 100 0.5 1 1 1\n");
  EXPECT_EQ(e.field(), "name");
  e = sceneError("image 640\n");
  EXPECT_EQ(e.field(), "height");
  e = sceneError("gravity 0 inf 0\n");
  EXPECT_EQ(e.field(), "gy");
  e = sceneError("dt 0.02\n");  // duplicate
  EXPECT_NE(std::string(e.what()).find("first given on line 4"), std::string::npos);
  e = sceneError("camera 0 1 0 0 0 0 40\n");  // looking straight down
  EXPECT_EQ(e.field(), "tx");
}

TEST(Scene, FrameIntervalMustBeWholeStepsAndStrokesIsRequired) {
  try {
    parseScene("physketch-scene 1\nstrokes a\ndt 0.01\nfps 30\n", "y.scene");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 4);
    EXPECT_EQ(e.field(), "frames_per_second");
  }
  try {
    parseScene("physketch-scene 1\ndt 0.01\n", "y.scene");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "strokes");
  }
}

TEST(Scene, UnknownAndDuplicatedRecordsNameTheRecordField) {
  auto e = sceneError("bogus 1\n");
  EXPECT_EQ(e.field(), "record") << e.what();
  e = sceneError("substeps 3\n");
  EXPECT_EQ(e.line(), 10);
  EXPECT_EQ(e.field(), "record") << e.what();
  EXPECT_NE(std::string(e.what()).find("first given on line 5"), std::string::npos) << e.what();
}

// --- Materials: one format for every kind and both solvers ---

namespace {

Material materialOf(const std::string& record) {
  const SceneDesc s = parseScene("physketch-scene 1\nstrokes s.strokes\n" + record + "\n", "m.scene");
  EXPECT_EQ(s.materials.size(), 1u);
  return s.materials.empty() ? Material{} : s.materials[0];
}

InputError materialError(const std::string& record) {
  try {
    parseScene("physketch-scene 1\nstrokes s.strokes\n" + record + "\n", "m.scene");
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 3) << e.what();
    return e;
  }
  ADD_FAILURE() << "expected InputError for: " << record;
  return InputError("", 0, "", "");
}

bool mentions(const InputError& e, const std::string& text) {
  return std::string(e.what()).find(text) != std::string::npos;
}

}  // namespace

TEST(Material, KeyValueFormSetsTypedParameters) {
  const Material m = materialOf(
      "material jelly soft density=1100 E=2e5 cluster_radius=4 cluster_spacing=3 plastic_creep=5 "
      "static_friction=0.8 dynamic_friction=0.6 restitution=0.25 color=0.9,0.3,0.3");
  EXPECT_EQ(m.name, "jelly");
  EXPECT_EQ(m.kind, MaterialKind::kSoft);
  EXPECT_EQ(m.line, 3);
  EXPECT_DOUBLE_EQ(m.density, 1100);
  EXPECT_DOUBLE_EQ(m.elastic.youngs, 2e5);
  EXPECT_DOUBLE_EQ(m.soft.clusterRadius, 4);
  EXPECT_DOUBLE_EQ(m.soft.clusterSpacing, 3);
  EXPECT_DOUBLE_EQ(m.soft.plasticCreep, 5);
  EXPECT_DOUBLE_EQ(m.staticFriction, 0.8);
  EXPECT_DOUBLE_EQ(m.dynamicFriction, 0.6);
  EXPECT_DOUBLE_EQ(m.restitution, 0.25);
  EXPECT_FLOAT_EQ(m.color[0], 0.9f);
  EXPECT_FLOAT_EQ(m.color[2], 0.3f);
  EXPECT_TRUE(m.wasGiven("E"));
  EXPECT_FALSE(m.wasGiven("nu"));
  // Compliance from E when not given: 1/(E h), h = 0.01 m.
  EXPECT_DOUBLE_EQ(softCompliance(m, 0.01), 1.0 / (2e5 * 0.01));
  EXPECT_DOUBLE_EQ(softCompliance(materialOf("material j soft compliance=1e-4"), 0.01), 1e-4);
}

TEST(Material, KindDefaultsComeFromThePapers) {
  // Stomakhin et al. 2013, Table 1 (reference snow): theta_c 2.5e-2, theta_s 7.5e-3, xi 10,
  // E0 1.4e5 Pa, nu 0.2, rho 400 kg/m^3.
  const Material snow = materialOf("material s snow");
  EXPECT_DOUBLE_EQ(snow.snow.thetaC, 0.025);
  EXPECT_DOUBLE_EQ(snow.snow.thetaS, 0.0075);
  EXPECT_DOUBLE_EQ(snow.snow.hardening, 10);
  EXPECT_DOUBLE_EQ(snow.elastic.youngs, 140000);
  EXPECT_DOUBLE_EQ(snow.elastic.poisson, 0.2);
  EXPECT_DOUBLE_EQ(snow.density, 400);
  // Dry sand: a friction angle of 30 degrees; Klár et al. 2016: E 3.537e5 Pa, nu 0.3.
  const Material sand = materialOf("material s sand");
  EXPECT_DOUBLE_EQ(sand.sand.frictionAngleDeg, 30);
  EXPECT_DOUBLE_EQ(sand.elastic.youngs, 353700);
  // Every kind without its own row takes the common defaults.
  const Material rope = materialOf("material r rope");
  EXPECT_DOUBLE_EQ(rope.density, 1000);
  EXPECT_DOUBLE_EQ(rope.staticFriction, 0.5);
  EXPECT_DOUBLE_EQ(rope.dynamicFriction, 0.5);
  EXPECT_EQ(materialOf("material e elastic").elastic.model, ElasticModel::kCorotated);
  EXPECT_EQ(materialOf("material e elastic model=neohookean").elastic.model, ElasticModel::kNeoHookean);
  // dynamic_friction defaults to static_friction.
  EXPECT_DOUBLE_EQ(materialOf("material r rigid static_friction=0.3").dynamicFriction, 0.3);
}

TEST(Material, PresetsAreThePhysGen3DClasses) {
  // PhysGen3D supplement: soft / medium / hard -> E = 5e4 / 5e5 / 5e6 Pa.
  EXPECT_DOUBLE_EQ(materialOf("material a elastic preset=soft").elastic.youngs, 50000);
  EXPECT_DOUBLE_EQ(materialOf("material a elastic preset=medium").elastic.youngs, 500000);
  EXPECT_DOUBLE_EQ(materialOf("material a plasticine preset=hard").elastic.youngs, 5000000);
  EXPECT_EQ(materialOf("material a elastic preset=hard").elastic.preset, StiffnessPreset::kHard);
  auto e = materialError("material a elastic preset=soft E=1e5");
  EXPECT_EQ(e.field(), "preset");
  EXPECT_TRUE(mentions(e, "not both")) << e.what();
  EXPECT_EQ(materialError("material a elastic preset=squishy").field(), "preset");
  EXPECT_EQ(materialError("material a soft E=1e5 compliance=1e-3").field(), "compliance");
}

TEST(Material, ShortFormOfTheFirstReleaseStillReads) {
  const Material m = materialOf("material wood rigid 600 0.6 0.72 0.50 0.30");
  EXPECT_EQ(m.kind, MaterialKind::kRigid);
  EXPECT_DOUBLE_EQ(m.density, 600);
  EXPECT_DOUBLE_EQ(m.staticFriction, 0.6);
  EXPECT_DOUBLE_EQ(m.dynamicFriction, 0.6);
  EXPECT_FLOAT_EQ(m.color[0], 0.72f);
  EXPECT_FLOAT_EQ(m.color[2], 0.30f);
  EXPECT_EQ(materialError("material wood rigid 600 0.6 0.7").field(), "g");
  EXPECT_EQ(materialError("material wood rigid 600 0.6 0.7 0.5 0.3 restitution=0.5").field(), "restitution");
  EXPECT_EQ(materialError("material wood rigid 600 2.5 0.7 0.5 0.3").field(), "friction");
  EXPECT_EQ(materialError("material wood rigid 600 0.6 0.7 0.5 1.3").field(), "b");
}

TEST(Material, EveryBadParameterNamesItsField) {
  struct Case {
    const char* record;
    const char* field;
  };
  for (const Case& c : std::initializer_list<Case>{
           {"material a elastic nu=0.5", "nu"},  // (0, 0.5) is open at both ends
           {"material a elastic nu=0", "nu"},
           {"material a elastic E=0", "E"},
           {"material a elastic E=nan", "E"},
           {"material a rigid density=-5", "density"},
           {"material a rigid density=1e6", "density"},
           {"material a rigid static_friction=0.4 dynamic_friction=0.5", "dynamic_friction"},
           {"material a rigid dynamic_friction=0.7", "dynamic_friction"},  // > the default static 0.5
           {"material a rigid restitution=1.5", "restitution"},
           {"material a rigid color=1,1", "color"},
           {"material a rigid color=1,1,2", "color"},
           {"material a rigid E=1e5", "E"},  // a parameter of other kinds
           {"material a rigid stiffnes=1", "stiffnes"},
           {"material a elastic model=stvk", "model"},
           {"material a soft cluster_radius=2 cluster_spacing=4", "cluster_spacing"},
           {"material a snow theta_c=0", "theta_c"},
           {"material a sand friction_angle=85", "friction_angle"},
           {"material a sand h0=30", "h0"},  // Klár's law's, without hardening_law=klar
           {"material a sand hardening_law=klar friction_angle=30", "friction_angle"},
           {"material a sand hardening_law=klar hardening=5", "hardening"},
           {"material a sand hardening_law=klar h0=5 h3=10", "h3"},  // 5 - 10 degrees at q = 0
           {"material a sand hardening_law=drucker", "hardening_law"},
           {"material a fluid gamma=0.5", "gamma"},
           {"material a jelly", "kind"},
           {"material fixed rigid", "name"},
           {"material a rigid density=1 density=2", "density"},
       }) {
    const InputError e = materialError(c.record);
    EXPECT_EQ(e.field(), c.field) << c.record << " -> " << e.what();
  }
  EXPECT_TRUE(mentions(materialError("material a rigid E=1e5"), "belongs to: soft, elastic, sand, snow, plasticine"));
  auto e = sceneError("material wood rigid density=600\n");
  EXPECT_EQ(e.field(), "name");
  EXPECT_TRUE(mentions(e, "first on line 9")) << e.what();
}

TEST(Material, EveryKindRunsUnderBothSolversOrNamesTheOne) {
  for (int k = 0; k < kMaterialKindCount; ++k) {
    const auto kind = static_cast<MaterialKind>(k);
    const SolverModel pbd = solverModel(kind, SolverKind::kPbd), mpm = solverModel(kind, SolverKind::kMpm);
    EXPECT_TRUE(pbd.simulated || mpm.simulated) << toString(kind);
    if (!pbd.simulated) {
      EXPECT_EQ(pbd.simulatedBy, SolverKind::kMpm) << toString(kind);
    }
    if (!mpm.simulated) {
      EXPECT_EQ(mpm.simulatedBy, SolverKind::kPbd) << toString(kind);
    }
  }
  // The mappings the format promises (docs/formats.md, "Kinds and solvers").
  EXPECT_EQ(solverModel(MaterialKind::kRigid, SolverKind::kMpm).runsAs, MaterialKind::kElastic);
  EXPECT_EQ(solverModel(MaterialKind::kElastic, SolverKind::kPbd).runsAs, MaterialKind::kSoft);
  EXPECT_EQ(solverModel(MaterialKind::kSoft, SolverKind::kMpm).runsAs, MaterialKind::kElastic);
  EXPECT_FALSE(solverModel(MaterialKind::kRope, SolverKind::kMpm).simulated);
  EXPECT_FALSE(solverModel(MaterialKind::kCloth, SolverKind::kMpm).simulated);
  for (auto k : {MaterialKind::kSand, MaterialKind::kSnow, MaterialKind::kPlasticine})
    EXPECT_FALSE(solverModel(k, SolverKind::kPbd).simulated);
  // rigid under mpm: a stiff elastic, the hard preset E = 5e6 Pa; common parameters carry over.
  const Material wood = materialOf("material wood rigid 600 0.6 0.72 0.50 0.30");
  const Material asMpm = asRunBy(wood, SolverKind::kMpm);
  EXPECT_EQ(asMpm.kind, MaterialKind::kElastic);
  EXPECT_DOUBLE_EQ(asMpm.elastic.youngs, 5e6);
  EXPECT_DOUBLE_EQ(asMpm.density, 600);
  EXPECT_DOUBLE_EQ(asMpm.staticFriction, 0.6);
  // elastic under pbd: soft with the same E and the soft cluster defaults.
  const Material asPbd = asRunBy(materialOf("material j elastic E=2e5"), SolverKind::kPbd);
  EXPECT_EQ(asPbd.kind, MaterialKind::kSoft);
  EXPECT_DOUBLE_EQ(asPbd.elastic.youngs, 2e5);
  EXPECT_DOUBLE_EQ(asPbd.soft.clusterRadius, 3);
  EXPECT_THROW(asRunBy(materialOf("material s sand"), SolverKind::kPbd), std::invalid_argument);
}

// --- The solver check: what the chosen solver does not simulate (yet) is an error at load ---

namespace {

const std::string kSupportScene =
    "physketch-scene 1\n"                       // 1
    "strokes s.strokes\n"                       // 2
    "material wood rigid 600 0.6 0.7 0.5 0.3\n"  // 3
    "material water fluid\n"                    // 4
    "material grit sand friction_angle=33\n"    // 5
    "material jelly elastic E=1e5 nu=0.4\n"     // 6
    "material goo soft E=1e5\n";                // 7

SketchUses usesOfMaterials(std::initializer_list<std::pair<const char*, int>> names) {
  SketchUses u;
  for (const auto& [name, line] : names) u.materials.push_back({name, FirstUse{"s.strokes", line, "material"}});
  return u;
}

SolverSupport pbdToday() {
  SolverSupport s;
  s.solver = SolverKind::kPbd;
  s.kinds = {MaterialKind::kRigid};
  s.initialMotion = s.fixedBodies = true;
  return s;
}

InputError supportError(const SceneDesc& scene, const SketchUses& uses, const SolverSupport& support) {
  try {
    checkSupport(scene, uses, support);
  } catch (const InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected InputError";
  return InputError("", 0, "", "");
}

}  // namespace

TEST(Support, AKindTheSolverDoesNotSimulateYetIsAnErrorAtItsMaterialRecord) {
  const SceneDesc scene = parseScene(kSupportScene, "scenes/x.scene");
  EXPECT_NO_THROW(checkSupport(scene, usesOfMaterials({{"wood", 2}}), pbdToday()));
  auto e = supportError(scene, usesOfMaterials({{"wood", 2}, {"water", 12}}), pbdToday());
  EXPECT_EQ(std::string(e.what()),
            "scenes/x.scene:4: field 'kind': material 'water' is kind fluid: solver pbd does not simulate fluid yet "
            "(first used at s.strokes:12)");
  // A kind pbd never simulates names the solver that does.
  e = supportError(scene, usesOfMaterials({{"grit", 5}}), pbdToday());
  EXPECT_EQ(e.line(), 5);
  EXPECT_EQ(e.field(), "kind");
  EXPECT_TRUE(mentions(e, "solver pbd (the default) does not simulate sand; solver mpm does")) << e.what();
  // A parameter pbd does not use (nu: elastic runs as soft under pbd) is named, not ignored.
  SolverSupport soft = pbdToday();
  soft.kinds.push_back(MaterialKind::kSoft);
  e = supportError(scene, usesOfMaterials({{"jelly", 6}}), soft);
  EXPECT_EQ(e.line(), 6);
  EXPECT_EQ(e.field(), "nu");
  EXPECT_TRUE(mentions(e, "used by solver mpm only")) << e.what();
  EXPECT_NO_THROW(checkSupport(scene, usesOfMaterials({{"goo", 7}}), soft));
  // A material the scene does not define is named at its use.
  e = supportError(scene, usesOfMaterials({{"wod", 9}}), pbdToday());
  EXPECT_EQ(e.file(), "s.strokes");
  EXPECT_EQ(e.line(), 9);
  EXPECT_EQ(e.field(), "material");
  EXPECT_TRUE(mentions(e, "defines: wood, water, grit, jelly, goo")) << e.what();
}

TEST(Support, MpmRunsRigidAsElasticAndRefusesRopes) {
  const SceneDesc scene = parseScene(kSupportScene + "solver mpm\nmaterial cord rope\n", "x.scene");
  EXPECT_EQ(scene.solver, SolverKind::kMpm);
  SolverSupport mpm;
  mpm.solver = SolverKind::kMpm;
  auto e = supportError(scene, usesOfMaterials({{"wood", 2}}), mpm);
  EXPECT_TRUE(mentions(e, "material 'wood' is kind rigid, which it runs as elastic: solver mpm does not simulate "
                          "elastic yet")) << e.what();
  mpm.kinds = {MaterialKind::kElastic, MaterialKind::kSand};
  EXPECT_NO_THROW(checkSupport(scene, usesOfMaterials({{"wood", 2}, {"grit", 3}, {"jelly", 4}}), mpm));
  e = supportError(scene, usesOfMaterials({{"cord", 2}}), mpm);
  EXPECT_EQ(e.line(), 9);
  EXPECT_TRUE(mentions(e, "solver mpm (line 8) does not simulate rope; solver pbd does")) << e.what();
  // restitution is a pbd parameter (MPM grid contacts are inelastic).
  const SceneDesc bouncy = parseScene("physketch-scene 1\nstrokes s\nsolver mpm\nmaterial b rigid restitution=0.5\n", "b.scene");
  EXPECT_EQ(supportError(bouncy, usesOfMaterials({{"b", 1}}), mpm).field(), "restitution");
  EXPECT_THROW(checkSupport(scene, {}, pbdToday()), std::invalid_argument);  // support set of the other solver
}

TEST(Support, FeaturesTheSolverDoesNotSimulateYetAreNamedWhereTheyAreUsed) {
  const SceneDesc scene = parseScene(kSupportScene, "x.scene");
  SketchUses uses = usesOfMaterials({{"wood", 2}});
  uses.toolStroke = FirstUse{"s.strokes", 7, "op"};
  auto e = supportError(scene, uses, pbdToday());
  EXPECT_EQ(std::string(e.what()).rfind("s.strokes:7: field 'op': solver pbd does not simulate tool strokes yet", 0), 0u)
      << e.what();
  uses.toolStroke = {};
  uses.velocity = FirstUse{"s.strokes", 4, "spin"};
  uses.fixedBody = FirstUse{"s.strokes", 5, "fixed"};
  EXPECT_NO_THROW(checkSupport(scene, uses, pbdToday()));
  SolverSupport rigidOnly;
  rigidOnly.kinds = {MaterialKind::kRigid};
  e = supportError(scene, uses, rigidOnly);
  EXPECT_EQ(e.line(), 4);
  EXPECT_EQ(e.field(), "spin");
  rigidOnly.initialMotion = true;
  e = supportError(scene, uses, rigidOnly);
  EXPECT_EQ(e.line(), 5);
  EXPECT_EQ(e.field(), "fixed");
}

// --- Mesh colliders ---

namespace {

// A scene "in" the source tree's scenes/ folder, so meshes/cube.obj resolves to a real file.
const std::string kScenes = std::string(PHYSKETCH_SOURCE_DIR) + "/scenes/";

SceneDesc colliderScene(const std::string& records) {
  return parseScene("physketch-scene 1\nstrokes s.strokes\n" + records, kScenes + "c.scene");
}

InputError colliderError(const std::string& records) {
  try {
    colliderScene(records);
  } catch (const InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected InputError for: " << records;
  return InputError("", 0, "", "");
}

}  // namespace

TEST(Collider, StaticAndKeyframedCollidersParse) {
  const SceneDesc s = colliderScene(
      "collider ramp meshes/cube.obj scale=0.5 rot=0,0,1,30 at=0,0.1,0 friction=0.8\n"  // 3
      "collider paddle meshes/cube.off\n"                                              // 4
      "keyframe paddle 1  0 0.2 0\n"                                                    // 5
      "keyframe paddle 3  2 0.2 0 rot=0,1,0,90\n");                                     // 6
  ASSERT_EQ(s.colliders.size(), 2u);
  const MeshCollider& ramp = s.colliders[0];
  EXPECT_EQ(ramp.path, kScenes + "meshes/cube.obj");
  EXPECT_EQ(ramp.line, 3);
  EXPECT_DOUBLE_EQ(ramp.scale, 0.5);
  ASSERT_TRUE(ramp.friction.has_value());
  EXPECT_DOUBLE_EQ(*ramp.friction, 0.8);
  EXPECT_TRUE(ramp.position.isApprox(Vec3(0, 0.1, 0)));
  const MeshCollider& paddle = s.colliders[1];
  EXPECT_FALSE(paddle.friction.has_value());
  ASSERT_EQ(paddle.keyframes.size(), 2u);
  EXPECT_EQ(paddle.keyframes[1].line, 6);
  // Halfway between keyframes: position halfway, rotation 45 degrees about y (slerp of 0 and 90).
  Mat3 r;
  Vec3 p;
  paddle.poseAt(2.0, r, p);
  EXPECT_TRUE(p.isApprox(Vec3(1, 0.2, 0), 1e-12)) << p.transpose();
  const double c = std::sqrt(0.5);
  Mat3 expected;
  expected << c, 0, c, 0, 1, 0, -c, 0, c;  // R_y(45 deg)
  EXPECT_TRUE(r.isApprox(expected, 1e-12)) << r;
  // Held at the first keyframe before it and at the last after it.
  paddle.poseAt(0.0, r, p);
  EXPECT_TRUE(p.isApprox(Vec3(0, 0.2, 0)));
  EXPECT_TRUE(r.isApprox(Mat3::Identity()));
  paddle.poseAt(10.0, r, p);
  EXPECT_TRUE(p.isApprox(Vec3(2, 0.2, 0)));
  // A static collider's pose is its at= and rot=.
  ramp.poseAt(5.0, r, p);
  EXPECT_TRUE(p.isApprox(Vec3(0, 0.1, 0)));
  EXPECT_NEAR(r(1, 0), 0.5, 1e-12);  // sin 30 deg: R_z(30) maps x to (cos 30, sin 30, 0)
}

TEST(Collider, EveryErrorNamesItsField) {
  struct Case {
    const char* records;
    int line;
    const char* field;
  };
  for (const Case& c : std::initializer_list<Case>{
           {"collider a meshes/nothing.obj\n", 3, "path"},
           {"collider a meshes/cube.stl\n", 3, "path"},
           {"collider a meshes/cube.obj scale=0\n", 3, "scale"},
           {"collider a meshes/cube.obj friction=3\n", 3, "friction"},
           {"collider a meshes/cube.obj rot=0,0,0,10\n", 3, "rot"},
           {"collider a meshes/cube.obj\ncollider a meshes/cube.off\n", 4, "name"},
           {"keyframe a 0 0 0 0\n", 3, "name"},
           {"collider a meshes/cube.obj\nkeyframe a 1 0 0 0\nkeyframe a 1 1 0 0\n", 5, "t"},
           {"collider a meshes/cube.obj\nkeyframe a -1 0 0 0\n", 4, "t"},
           {"collider a meshes/cube.obj\nkeyframe a 0 0 nan 0\n", 4, "y"},
           {"collider a meshes/cube.obj at=0,1,0\nkeyframe a 0 0 0 0\n", 3, "at"},
       }) {
    const InputError e = colliderError(c.records);
    EXPECT_EQ(e.line(), c.line) << c.records << " -> " << e.what();
    EXPECT_EQ(e.field(), c.field) << c.records << " -> " << e.what();
  }
  // Solver pbd does not simulate mesh colliders yet.
  const SceneDesc s = colliderScene("collider ramp meshes/cube.obj\n");
  const InputError e = supportError(s, {}, pbdToday());
  EXPECT_EQ(e.line(), 3);
  EXPECT_TRUE(mentions(e, "collider 'ramp': solver pbd (the default) does not simulate mesh colliders yet")) << e.what();
}

TEST(Scene, SolverIsPbdOrMpm) {
  EXPECT_EQ(parseScene(std::string(kGood) + "solver mpm\n", "x.scene").solver, SolverKind::kMpm);
  EXPECT_EQ(parseScene(std::string(kGood) + "solver mpm\n", "x.scene").solverLine, 10);
  EXPECT_EQ(sceneError("solver flip\n").field(), "name");
}

TEST(Scene, SubstepsAutoIsForSolverMpmOnly) {
  std::string text = kGood;
  text.replace(text.find("substeps 2"), 10, "substeps auto");
  const SceneDesc s = parseScene(text + "solver mpm\n", "x.scene");
  EXPECT_TRUE(s.substepsAuto);
  EXPECT_EQ(s.substepsLine, 5);
  EXPECT_FALSE(parseScene(std::string(kGood), "x.scene").substepsAuto);
  try {
    parseScene(text, "x.scene");  // solver pbd, the default
    FAIL() << "substeps auto accepted under pbd";
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 5);
    EXPECT_EQ(e.field(), "count");
    EXPECT_TRUE(mentions(e, "'substeps auto' needs solver mpm")) << e.what();
  }
  text.replace(text.find("substeps auto"), 13, "substeps often");
  try {
    parseScene(text + "solver mpm\n", "x.scene");
    FAIL() << "substeps often accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "count");
  }
}

// --- docs/formats.md reproduces the tables in code: they must not drift ---

namespace {

// The rows of the markdown table whose header starts with `header`, as trimmed cells with
// backticks removed and "\|" read as "|".
std::vector<std::vector<std::string>> markdownTable(const std::string& header) {
  std::ifstream in(std::string(PHYSKETCH_SOURCE_DIR) + "/docs/formats.md");
  EXPECT_TRUE(in.good()) << "docs/formats.md not found";
  std::vector<std::vector<std::string>> rows;
  std::string line;
  bool inTable = false;
  while (std::getline(in, line)) {
    if (!inTable) {
      inTable = line.rfind(header, 0) == 0;
      if (inTable) std::getline(in, line);  // the | --- | separator
      continue;
    }
    if (line.empty() || line[0] != '|') break;
    std::vector<std::string> cells;
    std::string cell;
    for (std::size_t i = 1; i < line.size(); ++i) {
      if (line[i] == '\\' && i + 1 < line.size() && line[i + 1] == '|') {
        cell += '|';
        ++i;
      } else if (line[i] == '|') {
        const auto b = cell.find_first_not_of(' '), e = cell.find_last_not_of(' ');
        cells.push_back(b == std::string::npos ? "" : cell.substr(b, e - b + 1));
        cell.clear();
      } else if (line[i] != '`') {
        cell += line[i];
      }
    }
    rows.push_back(cells);
  }
  EXPECT_FALSE(rows.empty()) << "no table headed '" << header << "' in docs/formats.md";
  return rows;
}

double toNumber(const std::string& s) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  EXPECT_TRUE(!s.empty() && *end == '\0') << "'" << s << "' is not a number";
  return v;
}

// "(0, 0.5)" -> range.
ParamRange toRange(const std::string& s) {
  ParamRange r;
  const auto comma = s.find(',');
  EXPECT_TRUE(s.size() > 4 && comma != std::string::npos) << s;
  if (s.size() <= 4 || comma == std::string::npos) return r;
  r.loOpen = s.front() == '(';
  r.hiOpen = s.back() == ')';
  r.lo = toNumber(s.substr(1, comma - 1));
  r.hi = toNumber(s.substr(comma + 2, s.size() - comma - 3));
  return r;
}

}  // namespace

TEST(Docs, MaterialParameterTableMatchesTheCode) {
  const auto rows = markdownTable("| kind | parameter | unit | default | range | solver |");
  const auto& table = materialParams();
  ASSERT_EQ(rows.size(), table.size()) << "docs/formats.md and core/material_table.cpp list different parameters";
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const auto& row = rows[i];
    const ParamSpec& p = table[i];
    const std::string where = "docs row " + std::to_string(i + 1) + " (" + p.kind + " " + p.key + ")";
    ASSERT_GE(row.size(), 6u) << where;
    EXPECT_EQ(row[0], p.kind) << where;
    EXPECT_EQ(row[1], p.key) << where;
    EXPECT_EQ(row[2], p.unit) << where;
    EXPECT_EQ(row[5], toString(p.solvers)) << where;
    if (p.type == ParamType::kChoice) {
      EXPECT_EQ(row[4], p.choices) << where;
      const std::string first = std::string(p.choices).substr(0, std::string(p.choices).find('|'));
      EXPECT_EQ(row[3], std::isnan(p.def) ? "—" : first) << where;
      continue;
    }
    const ParamRange r = toRange(row[4]);
    EXPECT_EQ(r.lo, p.range.lo) << where;
    EXPECT_EQ(r.hi, p.range.hi) << where;
    EXPECT_EQ(r.loOpen, p.range.loOpen) << where;
    EXPECT_EQ(r.hiOpen, p.range.hiOpen) << where;
    std::string expected;  // the default as the docs write it
    if (p.defaultFrom) expected = p.defaultFrom;
    else if (std::isnan(p.def)) expected = "—";
    if (!expected.empty()) {
      EXPECT_EQ(row[3], expected) << where;
    } else if (p.type == ParamType::kColor) {
      EXPECT_EQ(row[3], "0.7,0.7,0.7") << where;
    } else {
      EXPECT_EQ(toNumber(row[3]), p.def) << where;
    }
  }
  // And what makeMaterial fills is what the table says (defaults of every kind).
  for (int k = 0; k < kMaterialKindCount; ++k) {
    const auto kind = static_cast<MaterialKind>(k);
    Material m = makeMaterial(kind);
    for (const ParamSpec& p : table)
      if (p.type == ParamType::kNumber && !std::isnan(p.def) && findParam(kind, p.key) == &p) {
        EXPECT_EQ(p.field(m), p.def) << toString(kind) << " " << p.key;
      }
  }
}

TEST(Docs, KindsTableMatchesTheSolverMapping) {
  const auto rows = markdownTable("| kind | under pbd | under mpm |");
  ASSERT_EQ(rows.size(), static_cast<std::size_t>(kMaterialKindCount));
  for (int k = 0; k < kMaterialKindCount; ++k) {
    const auto kind = static_cast<MaterialKind>(k);
    const auto& row = rows[static_cast<std::size_t>(k)];
    ASSERT_GE(row.size(), 3u);
    EXPECT_EQ(row[0], toString(kind));
    for (int s = 0; s < kSolverKindCount; ++s) {
      const SolverModel m = solverModel(kind, static_cast<SolverKind>(s));
      const std::string cell = row[static_cast<std::size_t>(1 + s)];
      const std::string first = cell.substr(0, cell.find_first_of(" :,"));
      EXPECT_EQ(first, m.simulated ? toString(m.runsAs) : "error") << toString(kind) << ": " << cell;
    }
  }
}

TEST(Docs, TheSceneExampleParses) {
  // The first fenced block after the scene file's heading, read as if it sat in scenes/.
  std::ifstream in(std::string(PHYSKETCH_SOURCE_DIR) + "/docs/formats.md");
  std::string line, text;
  bool inSection = false, inBlock = false;
  while (std::getline(in, line)) {
    if (line.rfind("## Scene file", 0) == 0) inSection = true;
    else if (inSection && line.rfind("```", 0) == 0 && inBlock) break;
    else if (inSection && line.rfind("```", 0) == 0) inBlock = true;
    else if (inBlock) text += line + "\n";
  }
  ASSERT_FALSE(text.empty());
  const SceneDesc s = parseScene(text, kScenes + "doc.scene");
  EXPECT_EQ(s.materials.size(), 3u);
  EXPECT_EQ(s.colliders.size(), 2u);
  EXPECT_EQ(s.colliders[1].keyframes.size(), 2u);
}

TEST(Support, AParameterTheSolverDoesNotSimulateYetIsAnErrorNamingIt) {
  // A solver that runs a kind may still lack one of its parameters (paramsNotYet): a
  // material that sets it is refused at its record and field, not silently run without it.
  const SceneDesc scene = parseScene("physketch-scene 1\nstrokes s.strokes\nmaterial ball rigid restitution=0.5\n"
                                     "material brick rigid\n",
                                     "scenes/y.scene");
  SolverSupport noBounce = pbdToday();
  noBounce.paramsNotYet = {"restitution"};
  EXPECT_NO_THROW(checkSupport(scene, usesOfMaterials({{"brick", 2}}), noBounce));  // the default is not "set"
  const InputError e = supportError(scene, usesOfMaterials({{"ball", 3}}), noBounce);
  EXPECT_EQ(e.line(), 3);
  EXPECT_EQ(e.field(), "restitution");
  EXPECT_TRUE(mentions(e, "solver pbd does not simulate restitution yet")) << e.what();
  EXPECT_NO_THROW(checkSupport(scene, usesOfMaterials({{"ball", 3}}), pbdToday()));
}

TEST(Scene, ExpectRecordsParse) {
  const SceneDesc s = parseScene(std::string(kGood) +
                                     "expect freefall\n"
                                     "expect height top 0.25\n"
                                     "expect height stroke_3 -0.5\n",
                                 "dir/x.scene");
  ASSERT_EQ(s.expectations.size(), 3u);
  EXPECT_EQ(s.expectations[0].kind, Expectation::Kind::kFreefall);
  EXPECT_EQ(s.expectations[0].line, 10);
  EXPECT_EQ(s.expectations[1].kind, Expectation::Kind::kHeight);
  EXPECT_EQ(s.expectations[1].body, "top");
  EXPECT_DOUBLE_EQ(s.expectations[1].value, 0.25);
  EXPECT_EQ(s.expectations[2].body, "stroke 3");  // unnamed bodies are "stroke N"
  EXPECT_DOUBLE_EQ(s.expectations[2].value, -0.5);
  EXPECT_TRUE(parseScene(kGood, "dir/x.scene").expectations.empty());
  EXPECT_EQ(parseScene(std::string(kGood) + "expect rest\n", "x.scene").expectations[0].kind, Expectation::Kind::kRest);
  const SceneDesc d = parseScene(std::string(kGood) + "expect dam_break 0.1\nexpect runout\n", "x.scene");
  ASSERT_EQ(d.expectations.size(), 2u);
  EXPECT_EQ(d.expectations[0].kind, Expectation::Kind::kDamBreak);
  EXPECT_DOUBLE_EQ(d.expectations[0].value, 0.1);
  EXPECT_EQ(d.expectations[1].kind, Expectation::Kind::kRunout);
  EXPECT_EQ(parseScene(std::string(kGood) + "expect viscous_spread\n", "x.scene").expectations[0].kind,
            Expectation::Kind::kViscousSpread);
}

TEST(Scene, EveryBadExpectNamesLineAndField) {
  auto e = sceneError("expect orbit\n");
  EXPECT_EQ(e.line(), 10);
  EXPECT_EQ(e.field(), "kind");
  EXPECT_NE(std::string(e.what()).find("known: freefall, rest, height"), std::string::npos);
  e = sceneError("expect\n");
  EXPECT_EQ(e.field(), "kind");
  e = sceneError("expect height top\n");
  EXPECT_EQ(e.field(), "y");
  e = sceneError("expect height\n");
  EXPECT_EQ(e.field(), "body");
  e = sceneError("expect height top nan\n");
  EXPECT_EQ(e.field(), "y");
  e = sceneError("expect height top 0.2m\n");
  EXPECT_EQ(e.field(), "y");
  e = sceneError("expect freefall 3\n");
  EXPECT_EQ(e.field(), "#2");
  e = sceneError("expect dam_break\n");
  EXPECT_EQ(e.field(), "a");
  EXPECT_NE(std::string(e.what()).find("width A"), std::string::npos) << e.what();
  e = sceneError("expect dam_break 0\n");
  EXPECT_EQ(e.field(), "a");
  e = sceneError("expect dam_break -0.1\n");
  EXPECT_EQ(e.field(), "a");
  e = sceneError("expect dam_break nan\n");
  EXPECT_EQ(e.field(), "a");
  e = sceneError("expect dam_break 0.1 2\n");
  EXPECT_EQ(e.field(), "#3");
  e = sceneError("expect runout 1\n");
  EXPECT_EQ(e.field(), "#2");
  e = sceneError("expect viscous_spread 50\n");
  EXPECT_EQ(e.field(), "#2");
  e = sceneError("expect runout\nexpect runout\n");
  EXPECT_EQ(e.line(), 11);
  e = sceneError("expect height top 0.2 1\n");
  EXPECT_EQ(e.field(), "#4");
  e = sceneError("expect rest\nexpect rest\n");
  EXPECT_EQ(e.line(), 11);
  EXPECT_NE(std::string(e.what()).find("first on line 10"), std::string::npos);
  e = sceneError("expect height a 1\nexpect height a 2\n");
  EXPECT_EQ(e.line(), 11);
  EXPECT_EQ(e.field(), "body");
  e = sceneError("expect freefall\nexpect rest\n");
  EXPECT_EQ(e.line(), 11);
  EXPECT_NE(std::string(e.what()).find("give one"), std::string::npos);
}

TEST(Scene, WallsGiveEveryWallAKindAndSidesOverrideIt) {
  SceneDesc s = parseScene(std::string(kGood) + "walls slip y-=sticky z+=separate\ngrid_dx 1.5\n", "dir/x.scene");
  using W = SceneDesc::Wall;
  const W want[6] = {W::kSlip, W::kSlip, W::kSticky, W::kSlip, W::kSlip, W::kSeparate};
  for (int k = 0; k < 6; ++k) EXPECT_EQ(s.walls[k], want[k]) << k;
  EXPECT_EQ(s.wallsLine, 10);
  EXPECT_DOUBLE_EQ(s.gridDx, 1.5);
  s = parseScene(kGood, "dir/x.scene");  // defaults: separate everywhere, 2 spacings
  for (W w : s.walls) EXPECT_EQ(w, W::kSeparate);
  EXPECT_DOUBLE_EQ(s.gridDx, 2.0);
  EXPECT_EQ(sceneError("walls bouncy\n").field(), "kind");
  EXPECT_EQ(sceneError("walls slip y-=bouncy\n").field(), "kind");
  EXPECT_EQ(sceneError("walls slip q-=sticky\n").field(), "side");
  EXPECT_EQ(sceneError("walls slip x-=slip x-=sticky\n").field(), "side");
  EXPECT_EQ(sceneError("walls\n").field(), "kind");
  EXPECT_EQ(sceneError("grid_dx 0.5\n").field(), "spacings");
  EXPECT_EQ(sceneError("grid_dx nan\n").field(), "spacings");
  // cfl: the Courant number of 'substeps auto', in (0, 1].
  EXPECT_DOUBLE_EQ(parseScene(std::string(kGood) + "cfl 0.25\n", "dir/x.scene").cfl, 0.25);
  EXPECT_DOUBLE_EQ(s.cfl, 0.5);
  EXPECT_EQ(sceneError("cfl 0\n").field(), "C");
  EXPECT_EQ(sceneError("cfl 1.5\n").field(), "C");
  EXPECT_EQ(sceneError("cfl inf\n").field(), "C");
}

TEST(Support, WallsAndGridDxAreForSolverMpm) {
  const SceneDesc scene = parseScene(std::string(kGood) + "walls sticky\n", "dir/x.scene");
  SolverSupport pbd;
  pbd.solver = SolverKind::kPbd;
  pbd.kinds = {MaterialKind::kRigid};
  const InputError e = supportError(scene, usesOfMaterials({{"wood", 2}}), pbd);
  EXPECT_EQ(e.line(), 10);
  EXPECT_NE(std::string(e.what()).find("walls: solver pbd (the default) has no domain walls"), std::string::npos) << e.what();
  const SceneDesc cfl = parseScene(std::string(kGood) + "cfl 0.3\n", "dir/x.scene");
  const InputError c = supportError(cfl, usesOfMaterials({{"wood", 2}}), pbd);
  EXPECT_EQ(c.line(), 10);
  EXPECT_NE(std::string(c.what()).find("cfl: solver pbd (the default) has no domain walls"), std::string::npos) << c.what();
  const SceneDesc shift = parseScene(std::string(kGood) + "particle_shift 0.8\n", "dir/x.scene");
  const InputError sh = supportError(shift, usesOfMaterials({{"wood", 2}}), pbd);
  EXPECT_EQ(sh.line(), 10);
  EXPECT_NE(std::string(sh.what()).find("particle_shift: solver pbd (the default) has no domain walls"), std::string::npos)
      << sh.what();
}

// particle_shift (solver mpm): 0 (off) by default, a distance in particle spacings in [0, 1].
TEST(Scene, ParticleShiftIsOffByDefaultAndADistanceInSpacings) {
  EXPECT_EQ(parseScene(kGood, "dir/x.scene").particleShift, 0.0);
  const SceneDesc s = parseScene(std::string(kGood) + "particle_shift 0.8\n", "dir/x.scene");
  EXPECT_DOUBLE_EQ(s.particleShift, 0.8);
  EXPECT_EQ(s.particleShiftLine, 10);
  for (const char* bad : {"particle_shift -0.1\n", "particle_shift 1.5\n", "particle_shift nan\n", "particle_shift\n"})
    EXPECT_EQ(sceneError(bad).field(), "spacings") << bad;
}

// sleep: on by default (speed 0 = auto, 0.5 s); off, on, or SPEED [SECONDS], each number checked.
TEST(Scene, SleepIsOnByDefaultAndEveryBadValueNamesItsField) {
  const SceneDesc d = parseScene(kGood, "dir/x.scene");
  EXPECT_TRUE(d.sleep);
  EXPECT_EQ(d.sleepSpeed, 0.0);
  EXPECT_DOUBLE_EQ(d.sleepTime, 0.5);
  const SceneDesc off = parseScene(std::string(kGood) + "sleep off\n", "dir/x.scene");
  EXPECT_FALSE(off.sleep);
  EXPECT_EQ(off.sleepLine, 10);
  const SceneDesc set = parseScene(std::string(kGood) + "sleep 0.03 2\n", "dir/x.scene");
  EXPECT_TRUE(set.sleep);
  EXPECT_DOUBLE_EQ(set.sleepSpeed, 0.03);
  EXPECT_DOUBLE_EQ(set.sleepTime, 2.0);
  EXPECT_EQ(sceneError("sleep -0.1\n").field(), "speed");
  EXPECT_EQ(sceneError("sleep nan\n").field(), "speed");
  EXPECT_EQ(sceneError("sleep sometimes\n").field(), "speed");
  EXPECT_EQ(sceneError("sleep 11\n").field(), "speed");
  EXPECT_EQ(sceneError("sleep 0.02 0\n").field(), "seconds");
  EXPECT_EQ(sceneError("sleep 0.02 inf\n").field(), "seconds");
  EXPECT_EQ(sceneError("sleep off 2\n").field(), "seconds");
  EXPECT_EQ(sceneError("sleep\n").field(), "speed");
  EXPECT_EQ(sceneError("sleep off\nsleep on\n").field(), "record");
}

// warm_start F [AVERAGES]: off by default; F in [0, 0.9], AVERAGES 0..8 (4 by default).
TEST(Scene, WarmStartIsOffByDefaultAndEveryBadValueNamesItsField) {
  const SceneDesc d = parseScene(kGood, "dir/x.scene");
  EXPECT_EQ(d.warmStart, 0.0);
  EXPECT_EQ(d.warmSmoothing, 4);
  EXPECT_EQ(d.warmStartLine, 0);
  const SceneDesc set = parseScene(std::string(kGood) + "warm_start 0.6 3\n", "dir/x.scene");
  EXPECT_DOUBLE_EQ(set.warmStart, 0.6);
  EXPECT_EQ(set.warmSmoothing, 3);
  EXPECT_EQ(set.warmStartLine, 10);
  EXPECT_EQ(sceneError("warm_start 1\n").field(), "fraction");
  EXPECT_EQ(sceneError("warm_start -0.1\n").field(), "fraction");
  EXPECT_EQ(sceneError("warm_start nan\n").field(), "fraction");
  EXPECT_EQ(sceneError("warm_start\n").field(), "fraction");
  EXPECT_EQ(sceneError("warm_start 0.5 9\n").field(), "averages");
  EXPECT_EQ(sceneError("warm_start 0.5 1.5\n").field(), "averages");
  EXPECT_EQ(sceneError("warm_start 0.5 2 3\n").field(), "#3");
  EXPECT_EQ(sceneError("warm_start 0.5\nwarm_start 0.6\n").field(), "record");
}

namespace {
// A pbd-only record (at line 11, after `solver mpm` at line 10) is an error under mpm that
// names the record and why, and fine under pbd.
void expectPbdOnly(const std::string& record, const std::string& why, bool SolverSupport::*feature) {
  const SceneDesc scene = parseScene(std::string(kGood) + "solver mpm\n" + record + "\n", "dir/x.scene");
  SolverSupport mpm;
  mpm.solver = SolverKind::kMpm;
  mpm.kinds = {MaterialKind::kElastic};
  mpm.domainGrid = true;
  const InputError e = supportError(scene, usesOfMaterials({{"wood", 2}}), mpm);
  EXPECT_EQ(e.line(), 11) << record;
  EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
  SolverSupport pbd = mpm;
  pbd.solver = SolverKind::kPbd;
  pbd.kinds = {MaterialKind::kRigid};
  pbd.domainGrid = false;
  pbd.*feature = true;
  const SceneDesc p = parseScene(std::string(kGood) + record + "\n", "dir/x.scene");
  EXPECT_NO_THROW(checkSupport(p, usesOfMaterials({{"wood", 2}}), pbd)) << record;
}
}  // namespace

TEST(Support, WarmStartIsForSolverPbd) {
  expectPbdOnly("warm_start 0.5", "warm_start: solver mpm (line 10) has no density multipliers",
                &SolverSupport::fluidWarmStart);
}

TEST(Support, SleepIsForSolverPbd) {
  expectPbdOnly("sleep off", "sleep: solver mpm (line 10) has no bodies to put to sleep", &SolverSupport::sleeping);
}

// scale k (PhysGen3D §A.4): g' = k g; mass held, so density' = density / k^3; E' = E / k (the
// paper's rule), and the other stresses and the dynamic viscosity likewise; dimensionless
// parameters unchanged. Closed forms: E'/density' = k^2 E/density (wave speeds scale with
// length at the same time scale), and the self-weight sag density g H^2 / (2 E) scales by k.
TEST(Scene, ScaleScalesGravityDensityAndStresses) {
  const std::string mats =
      "material jelly elastic E=4e4 nu=0.3 density=1000\n"
      "material water fluid bulk_modulus=2e4 viscosity=0.001\n"
      "material clay plasticine yield_stress=1e4\n"
      "scale 0.5\n";
  const SceneDesc s = parseScene(std::string(kGood) + mats, "dir/x.scene");
  const double k = 0.5;
  EXPECT_EQ(s.scaleLine, 13);
  EXPECT_DOUBLE_EQ(s.gravity.y(), -9.81 * k);
  const Material &jelly = s.materials[1], &water = s.materials[2], &clay = s.materials[3];
  EXPECT_DOUBLE_EQ(jelly.density, 1000.0 / (k * k * k));
  EXPECT_DOUBLE_EQ(jelly.elastic.youngs, 4e4 / k);
  EXPECT_DOUBLE_EQ(jelly.elastic.poisson, 0.3);
  EXPECT_DOUBLE_EQ(water.fluid.bulkModulus, 2e4 / k);
  EXPECT_DOUBLE_EQ(water.fluid.viscosity, 0.001 / k);
  EXPECT_DOUBLE_EQ(clay.plasticine.yieldStress, 1e4 / k);
  const auto sag = [](const Material& m, double g, double H) { return m.density * g * H * H / (2.0 * m.elastic.youngs); };
  const Material& real = s.materialsUnscaled[1];
  EXPECT_NEAR(sag(jelly, k * 9.81, k * 0.1) / sag(real, 9.81, 0.1), k, 1e-12);
  EXPECT_NEAR((jelly.elastic.youngs / jelly.density) / (real.elastic.youngs / real.density), k * k, 1e-12);
  EXPECT_EQ(sceneError("scale 0\n").field(), "k");
  EXPECT_EQ(sceneError("scale -2\n").field(), "k");
}
