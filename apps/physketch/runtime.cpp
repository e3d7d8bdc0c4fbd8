#include "apps/physketch/runtime.h"

#include <algorithm>
#include <unordered_set>

namespace physketch::app {

using sketch::RuntimeOp;

void addToolMaterials(std::vector<Material>& materials, sketch::Sketch& sketch) {
  for (RuntimeOp& op : sketch.runtime) {
    if (op.kind != RuntimeOp::Kind::kTool) continue;
    Material m;
    m.name = "tool " + std::to_string(op.op);
    // friction=mu decides the tool's contacts; without it the touched material's own coefficients
    // do (docs/formats.md, "Tool strokes").
    if (op.friction) m.staticFriction = m.dynamicFriction = *op.friction;
    m.frictionRule = op.friction ? Material::FrictionRule::kOwn : Material::FrictionRule::kOther;
    m.color = {0.35f, 0.35f, 0.4f};
    const auto index = static_cast<std::int16_t>(materials.size());
    materials.push_back(m);
    for (auto& mat : op.particles.material) mat = index;
  }
}

RuntimeDriver::RuntimeDriver(const sketch::Sketch& sketch, Solver& solver)
    : sketch_(sketch),
      solver_(solver),
      restCells_(sketch.cells),
      stats_(sketch.runtime.size()),
      nextRemoval_(sketch.runtime.size(), 0),
      grabCentre_(sketch.runtime.size()) {}

Vec3 RuntimeDriver::brushAt(const RuntimeOp& op, double t) const {
  // The brush moves linearly between samples and rests at the ends.
  const auto& path = op.path;
  if (t <= path.front().first) return path.front().second;
  for (std::size_t k = 1; k < path.size(); ++k)
    if (t <= path[k].first) {
      const double a = (t - path[k - 1].first) / (path[k].first - path[k - 1].first);
      return path[k - 1].second + a * (path[k].second - path[k - 1].second);
    }
  return path.back().second;
}

std::vector<std::int32_t> RuntimeDriver::particlesInCells(const std::vector<Vec3i>& cells) const {
  std::unordered_set<std::int64_t> set;
  for (const auto& c : cells) set.insert(sketch::GridMapping::linear(c));
  std::vector<std::int32_t> out;
  const auto& p = solver_.particles();
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (!solver_.alive(static_cast<std::int32_t>(i))) continue;
    const Vec3i c = sketch_.mapping.discretize(Vec3(p.x[i], p.y[i], p.z[i]));
    if (sketch::GridMapping::inGrid(c) && set.count(sketch::GridMapping::linear(c)))
      out.push_back(static_cast<std::int32_t>(i));
  }
  return out;
}

// A tool: a kinematic body (infinite mass: it pushes and is not pushed back) from `start`,
// its centre of mass carried by the brush's displacement since the first sample, removed
// from the simulation after `end` (docs/formats.md, "Tool strokes").
void RuntimeDriver::driveTool(std::size_t k, double t0, double t1, std::vector<int>& reshaped) {
  const RuntimeOp& op = sketch_.runtime[k];
  OpStats& st = stats_[k];
  if (!st.started) {
    BodyRange shape;
    st.body = solver_.addBody(op.particles, shape, /*kinematic=*/true);
    restCells_.insert(restCells_.end(), op.cells.begin(), op.cells.end());
    grabCentre_[k].assign(1, solver_.pose(st.body).centre);
    reshaped.push_back(st.body);
    st.started = true;
  }
  if (t0 >= op.end) {
    const std::vector<std::int32_t> ids = solver_.bodyParticles(st.body);  // a copy: removal changes it
    for (int b : solver_.removeParticles(ids)) reshaped.push_back(b);
    st.finished = true;
    return;
  }
  solver_.setKinematicTarget(st.body, grabCentre_[k][0] + brushAt(op, std::min(t1, op.end)) - brushAt(op, op.start));
}

std::vector<int> RuntimeDriver::beforeStep() {
  const double t0 = solver_.time(), dt = solver_.dt(), t1 = t0 + dt;
  std::vector<int> reshaped;
  for (std::size_t k = 0; k < sketch_.runtime.size(); ++k) {
    const RuntimeOp& op = sketch_.runtime[k];
    OpStats& st = stats_[k];
    if (st.finished || op.start >= t1) continue;
    switch (op.kind) {
      case RuntimeOp::Kind::kCreate:
        if (!st.started) {
          // Static while being drawn (Phys-Sketch §4): kinematic until the stroke ends.
          BodyRange shape;
          shape.init = op.init;
          shape.layout = op.layout;
          shape.rows = op.rows;
          shape.cols = op.cols;
          shape.radius = op.radius;
          st.body = solver_.addBody(op.particles, shape, /*kinematic=*/op.end >= t1);
          restCells_.insert(restCells_.end(), op.cells.begin(), op.cells.end());
          reshaped.push_back(st.body);
          st.started = true;
          st.finished = op.end < t1;
        } else if (op.end < t1) {
          // Released where it was drawn, with its create's vel= and spin= (a thrown stroke).
          solver_.setMode(st.body, op.init.fixed ? BodyMode::kFixed : BodyMode::kDynamic);
          if (!op.init.fixed) solver_.setVelocity(st.body, op.init.velocity, op.init.spin);
          st.finished = true;
        }
        break;
      case RuntimeOp::Kind::kRemove: {
        st.started = true;
        std::vector<Vec3i> cells;
        while (nextRemoval_[k] < op.removals.size() && op.removals[nextRemoval_[k]].first < t1) {
          const auto& cs = op.removals[nextRemoval_[k]].second;
          cells.insert(cells.end(), cs.begin(), cs.end());
          ++nextRemoval_[k];
        }
        const auto ids = particlesInCells(cells);
        st.removed += static_cast<std::int64_t>(ids.size());
        for (int b : solver_.removeParticles(ids)) reshaped.push_back(b);
        st.finished = nextRemoval_[k] == op.removals.size();
        break;
      }
      case RuntimeOp::Kind::kMove:
        if (!st.started) {
          // Grab the bodies of the particles under the brush at its first sample.
          st.started = true;
          for (std::int32_t i : particlesInCells(op.grab)) {
            const int b = solver_.particles().group(static_cast<std::size_t>(i));
            if (b >= 0 && std::find(st.grabbed.begin(), st.grabbed.end(), b) == st.grabbed.end()) st.grabbed.push_back(b);
          }
          std::sort(st.grabbed.begin(), st.grabbed.end());
          for (int b : st.grabbed) {
            st.modes.push_back(solver_.mode(b));
            solver_.setMode(b, BodyMode::kKinematic);
            grabCentre_[k].push_back(solver_.pose(b).centre);
          }
        }
        if (t0 >= op.end) {
          // Released: the bodies keep the velocity of the brush's last motion.
          // A fixed body put down stays fixed where the brush left it.
          for (std::size_t g = 0; g < st.grabbed.size(); ++g)
            solver_.setMode(st.grabbed[g], st.modes[g] == BodyMode::kFixed ? BodyMode::kFixed : BodyMode::kDynamic);
          st.finished = true;
          break;
        }
        for (std::size_t g = 0; g < st.grabbed.size(); ++g)
          if (solver_.mode(st.grabbed[g]) == BodyMode::kKinematic)  // not emptied by a remove meanwhile
            solver_.setKinematicTarget(st.grabbed[g],
                                    grabCentre_[k][g] + brushAt(op, std::min(t1, op.end)) - brushAt(op, op.start));
        break;
      case RuntimeOp::Kind::kTool: driveTool(k, t0, t1, reshaped); break;
    }
  }
  std::sort(reshaped.begin(), reshaped.end());
  reshaped.erase(std::unique(reshaped.begin(), reshaped.end()), reshaped.end());
  return reshaped;
}

}  // namespace physketch::app
