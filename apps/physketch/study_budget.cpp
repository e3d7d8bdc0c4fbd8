// run --budget MS: pick substeps and iterations to fit a solver time per frame, from a short
// calibration on this machine (docs/accuracy.md, "A time budget").
#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>

#include "apps/physketch/prepare.h"
#include "apps/physketch/study.h"
#include "core/error.h"

namespace physketch::app {

std::ptrdiff_t chooseWithinBudget(const std::vector<BudgetCandidate>& c, double budgetMs, bool& fits) {
  std::ptrdiff_t best = -1, fastest = -1;
  for (std::size_t k = 0; k < c.size(); ++k) {
    if (c[k].status != "ok" || !std::isfinite(c[k].error)) continue;
    const auto i = static_cast<std::ptrdiff_t>(k);
    if (fastest < 0 || c[k].msPerFrame < c[std::size_t(fastest)].msPerFrame) fastest = i;
    if (c[k].msPerFrame <= budgetMs && (best < 0 || c[k].error < c[std::size_t(best)].error)) best = i;
  }
  fits = best >= 0;
  return fits ? best : fastest;
}

namespace {

Setting makeSetting(int substeps, int iterations) {
  return {{"iterations", double(iterations)}, {"substeps", double(substeps)}};
}

}  // namespace

BudgetChoice calibrateBudget(const std::string& scenePath, double budgetMs, int threads, bool quiet) {
  if (!(budgetMs > 0.0) || !std::isfinite(budgetMs))
    throw InputError("--budget", 0, "budget", "must be a positive number of milliseconds per frame");
  const Prepared p = prepare(scenePath, threads, /*forLint=*/true);
  if (p.scene.solver != SolverKind::kPbd)
    throw InputError(p.scene.path, p.scene.solverLine, "solver",
                     "--budget picks substeps and iterations for solver pbd; MPM's CFL knob is not available yet");
  const int frames = p.scene.frameCount();
  if (frames < 2) throw InputError(p.scene.path, 0, "duration", "--budget needs at least one simulated frame");
  BudgetChoice out;
  out.calibrationFrames = std::min(frames - 1, std::max(5, (frames - 1) / 5));
  const int maxFrames = out.calibrationFrames + 1;  // frame 0 and frames 1..K
  std::vector<Trajectory> runs;
  const auto run = [&](int substeps, int iterations) {
    BudgetCandidate c;
    c.setting = makeSetting(substeps, iterations);
    runs.push_back(calibrationRun(scenePath, c.setting, threads, maxFrames, c.msPerFrame, c.status));
    if (!quiet)
      std::cerr << "budget: " << settingText(c.setting) << ": " << c.msPerFrame << " ms per frame"
                << (c.status == "ok" ? "" : " (" + c.status + ")") << "\n";
    out.candidates.push_back(c);
    return c.msPerFrame;
  };
  constexpr int kMaxSubsteps = 256;
  int mostSubsteps = 1;
  for (int iterations : {1, 2, 4}) {
    int lo = 0;
    double msLo = 0.0;
    for (int s = 1; s <= kMaxSubsteps; s *= 2) {
      const double ms = run(s, iterations);
      mostSubsteps = std::max(mostSubsteps, s);
      if (ms > budgetMs) {
        // Fill the budget: the substeps between the last fitting count and this one, assuming
        // the time grows linearly in between.
        if (lo > 0 && s > lo + 1) {
          const int fill = lo + int(std::floor((budgetMs - msLo) / (ms - msLo) * double(s - lo)));
          if (fill > lo && fill < s) run(fill, iterations);
        }
        break;
      }
      lo = s, msLo = ms;
    }
  }
  // The reference: finer than every candidate.
  out.reference = makeSetting(std::min(2 * mostSubsteps, 1000), 4);
  double refMs = 0.0;
  std::string refStatus;
  const Trajectory ref = calibrationRun(scenePath, out.reference, threads, maxFrames, refMs, refStatus);
  if (refStatus != "ok")
    throw RuntimeError("--budget: the reference run (" + settingText(out.reference) + ") was stopped: " + refStatus);
  for (std::size_t k = 0; k < out.candidates.size(); ++k)
    out.candidates[k].error = out.candidates[k].status == "ok" ? fineError(runs[k], ref)
                                                                : std::numeric_limits<double>::quiet_NaN();
  const std::ptrdiff_t pick = chooseWithinBudget(out.candidates, budgetMs, out.fits);
  if (pick < 0) throw RuntimeError("--budget: every calibrated setting was stopped by the stability guard");
  const BudgetCandidate& c = out.candidates[std::size_t(pick)];
  out.setting = c.setting;
  out.predictedMs = c.msPerFrame;
  out.predictedError = c.error;
  return out;
}

}  // namespace physketch::app
