// physketch study: a run's error against the answer its scene declares (`expect`) or against a
// fine reference run. The norms are stated in docs/accuracy.md; all are in metres.
#include <algorithm>
#include <cmath>
#include <limits>

#include "apps/physketch/study.h"
#include "core/error.h"

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

double heightError(const Trajectory& tr, const Expectation& e, const std::string& scenePath) {
  std::string known;
  for (std::size_t b = 0; b < tr.names.size(); ++b) {
    if (tr.names[b] == e.body) return std::abs(tr.centres.back()[b].y() - e.value);
    std::string shown = tr.names[b];
    std::replace(shown.begin(), shown.end(), ' ', '_');
    known += (known.empty() ? "" : ", ") + shown;
  }
  throw InputError(scenePath, e.line, "body", "no body named '" + e.body + "' (bodies: " + known + ")");
}

double analyticError(const Trajectory& tr, const SceneDesc& scene) {
  double worst = 0.0;
  for (const Expectation& e : scene.expectations) {
    double err = 0.0;
    switch (e.kind) {
      case Expectation::Kind::kFreefall: err = freefallError(tr, scene.gravity, scene.groundY, scene.path, e.line); break;
      case Expectation::Kind::kRest: err = tr.maxDisplacement; break;
      case Expectation::Kind::kHeight: err = heightError(tr, e, scene.path); break;
    }
    if (std::isnan(err)) return err;
    worst = std::max(worst, err);
  }
  return worst;
}

double fineError(const Trajectory& run, const Trajectory& reference) {
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
