#include "apps/physketch/report.h"

#include <map>

namespace physketch::app {

using nlohmann::json;

std::map<std::string, std::int64_t> particlesPerMaterial(const Prepared& p) {
  std::map<std::string, std::int64_t> n;
  for (const auto& m : p.scene.materials) n[m.name] = 0;
  const ParticleArrays& pa = p.sketch->particles;
  for (std::size_t i = 0; i < pa.size(); ++i)
    if (!phase::has(pa.phase[i], phase::kRemoved))  // not the holes of a cut cloth
      ++n[p.scene.materials[static_cast<std::size_t>(pa.material[i])].name];
  return n;
}

std::map<std::string, std::int64_t> particlesPerKind(const Prepared& p) {
  std::map<std::string, std::int64_t> n;
  for (const auto& m : p.scene.materials) n[toString(m.kind)] += 0;
  for (const auto& [name, count] : particlesPerMaterial(p))
    n[toString(p.scene.materials[static_cast<std::size_t>(findMaterial(p.scene.materials, name))].kind)] += count;
  return n;
}

json sketchJson(const Prepared& p) {
  const SceneDesc& sc = p.scene;
  const sketch::Sketch& sk = *p.sketch;
  json ops = json::array();
  for (const auto& o : sk.operations) {
    json j = {{"id", o.id},           {"line", o.line},       {"what", o.what},   {"active", o.active},
              {"created", o.created}, {"removed", o.removed}, {"moved", o.moved}, {"particles", o.remaining},
              {"stamps", o.stamps},   {"after_play", o.afterPlay}};
    j["material"] = o.material >= 0 ? json(sc.materials[static_cast<std::size_t>(o.material)].name) : json(nullptr);
    j["body"] = o.body >= 0 ? json(sk.bodyNames[static_cast<std::size_t>(o.body)]) : json(nullptr);
    ops.push_back(j);
  }
  const std::map<std::string, std::int64_t> perMaterial = particlesPerMaterial(p);
  json bodies = json::array();
  for (std::size_t b = 0; b < sk.bodies.size(); ++b) {
    const BodyRange& r = sk.bodies[b];
    json j = {{"name", sk.bodyNames[b]}, {"particles", r.count}, {"first", r.first}, {"layout", toString(r.layout)}};
    if (r.layout == BodyLayout::kLattice) j["rows"] = r.rows, j["cols"] = r.cols;
    if (r.layout != BodyLayout::kVoxels) j["radius_m"] = r.radius;
    bodies.push_back(j);
  }
  const std::int64_t live = sketch::liveParticles(sk.particles);
  return {{"particles", live},
          {"cloth_holes", static_cast<std::int64_t>(sk.particles.size()) - live},
          {"cap", sketch::kMaxParticles},
          {"play_time_s", p.strokes.playTime()},
          {"per_operation", ops},
          {"per_material", perMaterial},
          {"per_kind", particlesPerKind(p)},
          {"bodies", bodies},
          {"warnings", sk.warnings}};
}

json planJson(const std::vector<PlanEntry>& plan) {
  json a = json::array();
  for (const auto& p : plan)
    a.push_back({{"pass", p.name}, {"runs", p.runs}, {"per_step", p.perStep}, {"reason", p.reason}});
  return a;
}

int guardFrame(const GuardRecord& g, int stepsPerFrame) {
  return static_cast<int>(g.step / std::max(1, stepsPerFrame)) + 1;
}

json guardJson(const GuardRecord& g, int stepsPerFrame) {
  return {{"kind", toString(g.kind)}, {"frame", guardFrame(g, stepsPerFrame)}, {"pass", g.pass},         {"step", g.step},   {"substep", g.substep},
          {"particle", g.particle},   {"body", g.body},         {"stroke", g.stroke}, {"material", g.material},
          {"value", g.value},         {"bound", g.bound},       {"hint", g.hint},   {"message", g.message()}};
}

json posesJson(const Solver& solver) {
  json a = json::array();
  for (int b = 0; b < solver.bodyCount(); ++b) {
    const BodyPose p = solver.pose(b);
    a.push_back({p.centre.x(), p.centre.y(), p.centre.z(), p.rotation.w(), p.rotation.x(), p.rotation.y(),
                 p.rotation.z()});
  }
  return a;
}

json runtimeJson(const sketch::Sketch& sk, const RuntimeDriver& runtime) {
  json rt = json::array();
  for (std::size_t k = 0; k < sk.runtime.size(); ++k) {
    const auto& op = sk.runtime[k];
    const auto& st = runtime.stats()[k];
    static const char* kKinds[] = {"create", "remove", "move", "tool"};
    rt.push_back({{"op", op.op}, {"line", op.line}, {"kind", kKinds[static_cast<int>(op.kind)]},
                  {"start_s", op.start}, {"end_s", op.end}, {"started", st.started}, {"finished", st.finished},
                  {"body", st.body}, {"grabbed_bodies", st.grabbed}, {"removed_particles", st.removed}});
  }
  return rt;
}

json passesJson(const Profile& solver, const Profile* render, int written, const std::vector<PlanEntry>& held) {
  const double perFrame = written > 1 ? 1.0 / (written - 1) : 0.0;  // frame 0 is the sketch: no steps
  json passes = json::array();
  for (const auto& e : solver.entries()) {
    std::size_t bytes = 0;
    for (const PlanEntry& h : held)
      if (h.name == e.name) bytes = h.heldBytes;
    // Passes the scene did not need never ran: leave them out, unless they hold memory.
    if (e.calls > 0 || bytes > 0)
      passes.push_back({{"pass", e.name}, {"calls", e.calls}, {"total_ms", e.seconds * 1e3},
                        {"ms_per_frame", e.seconds * 1e3 * perFrame}, {"held_bytes", bytes}});
  }
  if (render) {
    const double perWritten = written > 0 ? 1.0 / written : 0.0;
    for (const auto& e : render->entries())
      if (e.calls > 0)
        passes.push_back({{"pass", "render." + e.name}, {"calls", e.calls}, {"total_ms", e.seconds * 1e3},
                          {"ms_per_frame", e.seconds * 1e3 * perWritten}});
  }
  return passes;
}

double memoryEstimateMiB(std::size_t particles) {
  const double perParticle = 4.0 * (3 + 3 + 1 + 1)  // ParticleArrays hot: x, v, mass, phase
                             + 4.0 + 2.0             // stroke, material
                             + 4.0 * 3 + 4.0         // solver: rest offsets, body member list
                             + 12.0;                 // grid cell per particle
  return (perParticle * double(particles) + 4.0 * double(sketch::kGridCells)) / (1024.0 * 1024.0);
}

}  // namespace physketch::app
