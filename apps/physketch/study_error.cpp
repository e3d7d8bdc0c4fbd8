// physketch study: a run's error against the answer its scene declares (`expect`) or against a
// fine reference run. The norms are stated in docs/accuracy.md; all are in metres.
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "apps/physketch/study.h"
#include "render/mesh_distance.h"
#include "core/error.h"
#include "core/solver.h"

namespace physketch::app {
namespace {

// Centre of body b on its free-fall parabola at time t (s): c0 + v0 t + g t^2 / 2; a body
// that is not dynamic stays where it was.
Vec3 parabola(const Trajectory& tr, std::size_t b, const Vec3& g, double t) {
  const Vec3& c0 = tr.centres.front()[b];
  if (!tr.dynamic0[b]) return c0;
  return c0 + tr.velocity0[b] * t + 0.5 * g * t * t;
}

// Whether body b, on its parabola, is clear of the ground and of every other body at time t:
// its bounding sphere stays more than one particle spacing away from them.
bool clearAt(const Trajectory& tr, std::size_t b, const Vec3& g, double groundY, double t) {
  const std::size_t n = tr.centres.front().size();
  const Vec3 c = parabola(tr, b, g, t);
  if (c.y() - tr.reach[b] - groundY <= tr.spacing) return false;
  for (std::size_t o = 0; o < n; ++o) {
    if (o == b) continue;
    if ((parabola(tr, o, g, t) - c).norm() - tr.reach[b] - tr.reach[o] <= tr.spacing) return false;
  }
  return true;
}

}  // namespace

std::vector<int> freefallWindow(const Trajectory& tr, const Vec3& gravity, double groundY) {
  const std::size_t bodies = tr.centres.empty() ? 0 : tr.centres.front().size();
  std::vector<int> window(bodies, 0);
  // Per frame interval: at 10 m/s relative speed and 30 fps a sample every 3.3 mm, half a spacing
  // of the default grid, so no approach slips between samples at the speeds rigid scenes see.
  constexpr int kSamples = 100;
  for (std::size_t b = 0; b < bodies; ++b) {
    if (!tr.dynamic0[b]) continue;
    bool clear = clearAt(tr, b, gravity, groundY, 0.0);
    for (std::size_t f = 1; clear && f < tr.t.size(); ++f) {
      for (int s = 1; clear && s <= kSamples; ++s)
        clear = clearAt(tr, b, gravity, groundY, tr.t[f - 1] + (tr.t[f] - tr.t[f - 1]) * s / kSamples);
      if (clear) window[b] = static_cast<int>(f);
    }
  }
  return window;
}

double freefallError(const Trajectory& tr, const Vec3& gravity, double groundY, const std::string& scenePath,
                     int expectLine) {
  const std::vector<int> window = freefallWindow(tr, gravity, groundY);
  double sum = 0.0;
  std::size_t count = 0;
  for (std::size_t b = 0; b < window.size(); ++b)
    for (int f = 1; f <= window[b] && std::size_t(f) < tr.centres.size(); ++f) {
      if (b >= tr.centres[std::size_t(f)].size()) continue;
      sum += (tr.centres[std::size_t(f)][b] - parabola(tr, b, gravity, tr.t[std::size_t(f)])).squaredNorm();
      ++count;
    }
  if (count == 0)
    throw InputError(scenePath, expectLine, "kind",
                     "expect freefall: no dynamic body falls freely for a whole frame (each starts within one "
                     "particle spacing of the ground or of another body, or there are no frames)");
  return std::sqrt(sum / double(count));
}

namespace {
// The index of the body an expect record names. Throws InputError listing the bodies.
std::size_t namedBody(const Trajectory& tr, const Expectation& e, const std::string& scenePath) {
  std::string known;
  for (std::size_t b = 0; b < tr.names.size(); ++b) {
    if (tr.names[b] == e.body) return b;
    std::string shown = tr.names[b];
    std::replace(shown.begin(), shown.end(), ' ', '_');
    known += (known.empty() ? "" : ", ") + shown;
  }
  throw InputError(scenePath, e.line, "body", "no body named '" + e.body + "' (bodies: " + known + ")");
}
}  // namespace

double heightError(const Trajectory& tr, const Expectation& e, const std::string& scenePath) {
  return std::abs(tr.centres.back()[namedBody(tr, e, scenePath)].y() - e.value);
}

std::vector<double> pendulumAngle(double theta0, double omega0, double gOverL, const std::vector<double>& times) {
  // RK4 on (theta, theta') with steps of at most 1e-4 s, stopping at each requested time.
  std::vector<double> out;
  double t = 0.0, th = theta0, w = omega0;
  for (double target : times) {
    while (t < target) {
      const double h = std::min(1e-4, target - t);
      auto acc = [gOverL](double a) { return -gOverL * std::sin(a); };
      const double k1t = w, k1w = acc(th);
      const double k2t = w + 0.5 * h * k1w, k2w = acc(th + 0.5 * h * k1t);
      const double k3t = w + 0.5 * h * k2w, k3w = acc(th + 0.5 * h * k2t);
      const double k4t = w + h * k3w, k4w = acc(th + h * k3t);
      th += h / 6.0 * (k1t + 2.0 * k2t + 2.0 * k3t + k4t);
      w += h / 6.0 * (k1w + 2.0 * k2w + 2.0 * k3w + k4w);
      t += h;
    }
    out.push_back(th);
  }
  return out;
}

double pendulumError(const Trajectory& tr, const Expectation& e, const Vec3& gravity, const std::string& scenePath) {
  const std::size_t b = namedBody(tr, e, scenePath);
  const double g = gravity.norm();
  if (!(g > 0.0)) throw InputError(scenePath, e.line, "kind", "expect pendulum needs gravity");
  if (!tr.dynamic0[b]) throw InputError(scenePath, e.line, "body", "body '" + e.body + "' is not dynamic at t = 0");
  const Vec3 r0 = tr.centres[0][b] - e.point;
  const double L = r0.norm();
  if (!(L > 0.0)) throw InputError(scenePath, e.line, "x", "the pivot is the body's centre: no pendulum");
  // The swing plane: down (along gravity) and the side the body starts on (any side when it
  // hangs straight down; its velocity then decides).
  const Vec3 down = gravity / g;
  Vec3 side = r0 - r0.dot(down) * down;
  if (side.norm() < 1e-9 * L) side = tr.velocity0[b] - tr.velocity0[b].dot(down) * down;
  if (side.norm() < 1e-12) side = down.unitOrthogonal();
  side.normalize();
  const double theta0 = std::atan2(r0.dot(side), r0.dot(down));
  const Vec3 tangent = std::cos(theta0) * side - std::sin(theta0) * down;
  const double omega0 = tr.velocity0[b].dot(tangent) / L;
  const std::vector<double> theta = pendulumAngle(theta0, omega0, g / L, tr.t);
  double sum = 0.0;
  std::size_t n = 0;
  for (std::size_t f = 1; f < tr.t.size(); ++f) {
    const Vec3 want = e.point + L * (std::sin(theta[f]) * side + std::cos(theta[f]) * down);
    sum += (tr.centres[f][b] - want).squaredNorm();
    ++n;
  }
  return n ? std::sqrt(sum / double(n)) : 0.0;
}

const std::vector<std::pair<double, double>>& martinMoyceFront() {
  // Martin & Moyce 1952 (Phil. Trans. R. Soc. A 244:312-324), n^2 = 2: T = t sqrt(2 g / a),
  // Z = front distance from the back wall / a. Transcribed in ../shared/data; a test checks
  // this copy against tests/pbd/data/martin-moyce-1952-front.csv.
  static const std::vector<std::pair<double, double>> rows = {
      {0.00, 1.00}, {0.41, 1.11}, {0.84, 1.22}, {1.19, 1.44}, {1.43, 1.67}, {1.63, 1.89},
      {1.82, 2.11}, {1.97, 2.33}, {2.20, 2.56}, {2.32, 2.78}, {2.50, 3.00}, {2.64, 3.22},
      {2.82, 3.44}, {2.96, 3.67}, {3.11, 3.89}, {3.33, 4.11}};
  return rows;
}

namespace {

// Gravity must point down y for the dam-break and run-out laws; returns |g|.
double downwardGravity(const Vec3& gravity, const Expectation& e, const std::string& scenePath) {
  const double g = gravity.norm();
  if (!(g > 0.0) || gravity.y() > -0.999 * g)
    throw InputError(scenePath, e.line, "kind",
                     std::string("expect ") + toString(e.kind) + " needs gravity pointing down y (the scene's is " +
                         fmt("%.3g", gravity.x()) + " " + fmt("%.3g", gravity.y()) + " " + fmt("%.3g", gravity.z()) + ")");
  return g;
}

bool hasParticles(const Trajectory& tr) { return tr.lo0.allFinite() && tr.hi0.allFinite() && !tr.front.empty(); }

}  // namespace

double damBreakError(const Trajectory& tr, const Expectation& e, const Vec3& gravity, const std::string& scenePath) {
  const double g = downwardGravity(gravity, e, scenePath), a = e.value, h = tr.spacing;
  if (!hasParticles(tr)) throw InputError(scenePath, e.line, "kind", "expect dam_break: no dynamic particle");
  const double wall = tr.lo0.x() - 0.5 * h, scale = std::sqrt(2.0 * g / a);
  std::vector<double> T, Z;
  for (std::size_t f = 0; f < tr.t.size() && f < tr.front.size(); ++f) {
    T.push_back(tr.t[f] * scale);
    Z.push_back((tr.front[f] + 0.5 * h - wall) / a);
  }
  for (std::size_t f = 1; f < T.size(); ++f)
    if (T[f] - T[f - 1] > 0.25)
      throw InputError(scenePath, e.line, "kind",
                       "expect dam_break: frames " + fmt("%.3g", T[f] - T[f - 1]) +
                           " apart in T are too sparse to follow the front; raise 'fps' to at least " +
                           fmt("%.3g", std::ceil(scale / 0.25)));
  double sum = 0.0;
  int n = 0;
  for (const auto& [t, z] : martinMoyceFront()) {
    if (t > 3.0 || T.empty() || t > T.back()) continue;
    const auto it = std::lower_bound(T.begin(), T.end(), t);
    const std::size_t j = std::size_t(std::max<std::ptrdiff_t>(1, it - T.begin()));
    const double w = T[j] > T[j - 1] ? (t - T[j - 1]) / (T[j] - T[j - 1]) : 0.0;
    const double zr = Z[j - 1] + w * (Z[j] - Z[j - 1]);
    sum += (zr - z) * (zr - z);
    ++n;
  }
  if (n < 3)
    throw InputError(scenePath, e.line, "kind",
                     "expect dam_break: the run covers " + std::to_string(n) +
                         " of Martin & Moyce's rows (at least 3 needed): make 'duration' at least " +
                         fmt("%.3g", 3.0 / scale) + " s (T = 3)");
  return a * std::sqrt(sum / n);
}

double lubeRunout(double aspect) {
  const auto low = [](double x) { return 1.2 * x; };
  const auto high = [](double x) { return 1.9 * std::pow(x, 2.0 / 3.0); };
  if (aspect <= 1.8) return low(aspect);
  if (aspect >= 2.8) return high(aspect);
  const double w = (aspect - 1.8) / (2.8 - 1.8);
  return (1.0 - w) * low(1.8) + w * high(2.8);
}

double runoutError(const Trajectory& tr, const Expectation& e, const Vec3& gravity, const std::string& scenePath) {
  downwardGravity(gravity, e, scenePath);
  if (!hasParticles(tr)) throw InputError(scenePath, e.line, "kind", "expect runout: no dynamic particle");
  const double h = tr.spacing;
  const double l0 = tr.hi0.x() - tr.lo0.x() + h, h0 = tr.hi0.y() - tr.lo0.y() + h;
  const double runout = tr.front.back() + 0.5 * h - (tr.lo0.x() - 0.5 * h) - l0;
  return std::abs(runout - l0 * lubeRunout(h0 / l0));
}

double huppertFront(double rho, double mu, double g, double volume, double t) {
  return 0.894 * std::pow(rho * g * volume * volume * volume * t / (3.0 * mu), 1.0 / 8.0);
}

double viscousSpreadError(const Trajectory& tr, const Expectation& e, const SceneDesc& scene) {
  const double g = downwardGravity(scene.gravity, e, scene.path), h = tr.spacing;
  if (!hasParticles(tr)) throw InputError(scene.path, e.line, "kind", "expect viscous_spread: no dynamic particle");
  const Material* fluid = nullptr;
  for (const Material& m : scene.materials)
    if (m.kind == MaterialKind::kFluid) {
      if (fluid)
        throw InputError(scene.path, e.line, "kind",
                         "expect viscous_spread needs one fluid material (it reads its density and viscosity); the scene "
                         "has '" + fluid->name + "' and '" + m.name + "'");
      fluid = &m;
    }
  if (!fluid || !(fluid->fluid.viscosity > 0.0))
    throw InputError(scene.path, e.line, "kind", "expect viscous_spread needs a fluid material with viscosity > 0");
  const double cx = 0.5 * (tr.lo0.x() + tr.hi0.x()), volume = double(tr.dynamic0Count) * h * h * h;
  const double half = tr.t.empty() ? 0.0 : 0.5 * tr.t.back();
  double sum = 0.0;
  int n = 0;
  for (std::size_t f = 0; f < tr.t.size() && f < tr.front.size(); ++f) {
    if (!(tr.t[f] > 0.0) || tr.t[f] < half) continue;
    const double r = tr.front[f] + 0.5 * h - cx;
    const double want = huppertFront(fluid->density, fluid->fluid.viscosity, g, volume, tr.t[f]);
    sum += (r - want) * (r - want);
    ++n;
  }
  if (n < 2)
    throw InputError(scene.path, e.line, "kind", "expect viscous_spread: the run has fewer than 2 frames in its second half");
  return std::sqrt(sum / n);
}

double hydrostaticPressure(double d, double rho0, double g, double bulk, double gamma) {
  const double x = rho0 * g * d / bulk;
  if (std::abs(gamma - 1.0) < 1e-9) return bulk * std::expm1(x);
  return bulk / gamma * (std::pow(1.0 + (gamma - 1.0) * x, gamma / (gamma - 1.0)) - 1.0);
}

double hydrostaticError(const Solver& solver, const SceneDesc& scene, double spacing) {
  const ParticleArrays& p = solver.particles();
  const double g = scene.gravity.norm(), h3 = spacing * spacing * spacing;
  double top = -std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < p.size(); ++i)
    if (std::isfinite(solver.pressure(std::int32_t(i)))) top = std::max(top, double(p.y[i]));
  if (!std::isfinite(top) || !(g > 0.0)) return std::numeric_limits<double>::quiet_NaN();
  top += 0.5 * spacing;
  double sum = 0.0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    const double pr = solver.pressure(std::int32_t(i));
    if (!std::isfinite(pr)) continue;
    const Material& m = scene.materials[std::size_t(p.material[i])];
    const double rho0 = double(p.mass[i]) / h3;
    const double exact = hydrostaticPressure(top - double(p.y[i]), rho0, g, m.fluid.bulkModulus, m.fluid.gamma);
    const double head = (pr - exact) / (rho0 * g);
    sum += head * head;
    ++n;
  }
  return std::sqrt(sum / double(n));
}

double hydrostaticRunError(const Trajectory& tr, const Expectation& e, const SceneDesc& scene) {
  if (!(scene.gravity.norm() > 0.0))
    throw InputError(scene.path, e.line, "kind", "expect hydrostatic needs gravity");
  if (tr.hydrostatic.empty() || !std::isfinite(tr.hydrostatic.back()))
    throw InputError(scene.path, e.line, "kind",
                     "expect hydrostatic: no particle has a pressure at the last frame (it needs a fluid material "
                     "under solver mpm, which keeps pressure as state; solver pbd does not)");
  return tr.hydrostatic.back();
}

double sphereError(const Trajectory& tr, const Expectation& e, const std::string& scenePath) {
  if (tr.surface.positions.empty())
    throw InputError(scenePath, e.line, "kind", "expect sphere: nothing was meshed at the last frame (no body left)");
  double sum = 0.0;
  for (const Vec3f& v : tr.surface.positions) {
    const double d = (v.cast<double>() - e.point).norm() - e.value;
    sum += d * d;
  }
  return std::sqrt(sum / double(tr.surface.positions.size()));
}

double analyticError(const Trajectory& tr, const SceneDesc& scene) {
  double worst = 0.0;
  for (const Expectation& e : scene.expectations) {
    double err = 0.0;
    switch (e.kind) {
      case Expectation::Kind::kFreefall: err = freefallError(tr, scene.gravity, scene.groundY, scene.path, e.line); break;
      case Expectation::Kind::kRest: err = tr.maxDisplacement; break;
      case Expectation::Kind::kHeight: err = heightError(tr, e, scene.path); break;
      case Expectation::Kind::kDamBreak: err = damBreakError(tr, e, scene.gravity, scene.path); break;
      case Expectation::Kind::kRunout: err = runoutError(tr, e, scene.gravity, scene.path); break;
      case Expectation::Kind::kHydrostatic: err = hydrostaticRunError(tr, e, scene); break;
      case Expectation::Kind::kPendulum: err = pendulumError(tr, e, scene.gravity, scene.path); break;
      case Expectation::Kind::kSphere: err = sphereError(tr, e, scene.path); break;
      case Expectation::Kind::kViscousSpread: err = viscousSpreadError(tr, e, scene); break;
    }
    if (std::isnan(err)) return err;
    worst = std::max(worst, err);
  }
  return worst;
}

double fineError(const Trajectory& run, const Trajectory& reference) {
  if (!run.surface.empty() || !reference.surface.empty()) {
    if (run.surface.empty() || reference.surface.empty()) return std::numeric_limits<double>::quiet_NaN();
    return render::rmsSurfaceDistance(run.surface, reference.surface);
  }
  if (run.centres.size() != reference.centres.size()) return std::numeric_limits<double>::quiet_NaN();
  double sum = 0.0;
  std::size_t count = 0;
  for (std::size_t f = 1; f < run.centres.size(); ++f) {
    const std::size_t n = std::min({run.centres[f].size(), reference.centres[f].size(), reference.dynamic0.size()});
    for (std::size_t b = 0; b < n; ++b) {
      if (!reference.dynamic0[b]) continue;
      sum += (run.centres[f][b] - reference.centres[f][b]).squaredNorm();
      ++count;
    }
  }
  return count ? std::sqrt(sum / double(count)) : 0.0;
}

}  // namespace physketch::app
