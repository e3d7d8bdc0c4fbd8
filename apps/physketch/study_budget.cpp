// run --budget MS: pick substeps and iterations (solver pbd) or the Courant number of 'substeps
// auto' (solver mpm) to fit a solver time per frame, from a short calibration on this machine (docs/accuracy.md, "A time budget").
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

BudgetChoice choose(BudgetChoice& out, double budgetMs) {
  const std::ptrdiff_t pick = chooseWithinBudget(out.candidates, budgetMs, out.fits);
  if (pick < 0) throw RuntimeError("--budget: every calibrated setting was stopped by the stability guard");
  const BudgetCandidate& c = out.candidates[std::size_t(pick)];
  out.setting = c.setting;
  out.predictedMs = c.msPerFrame;
  out.predictedError = c.error;
  return out;
}

// Runs out.reference and measures every stable candidate's error against it (the fine norm).
void measureErrors(BudgetChoice& out, const std::vector<Trajectory>& runs, const std::string& scenePath, int threads,
                   int maxFrames) {
  double refMs = 0.0;
  std::string refStatus;
  const Trajectory ref = calibrationRun(scenePath, out.reference, threads, maxFrames, refMs, refStatus);
  if (refStatus != "ok")
    throw RuntimeError("--budget: the reference run (" + settingText(out.reference) + ") was stopped: " + refStatus);
  for (std::size_t k = 0; k < out.candidates.size(); ++k)
    out.candidates[k].error = out.candidates[k].status == "ok" ? fineError(runs[k], ref)
                                                                : std::numeric_limits<double>::quiet_NaN();
}

// The smallest Courant number the study knob 'cfl' accepts (study_knobs.cpp).
constexpr double kMinCfl = 1e-3;

// MPM: the Courant number C of 'substeps auto' is the knob (the substep count follows dt <=
// C dx / c_p, so the time per frame grows about as 1/C). Runs C = 1, 1/2, 1/4, ... until a
// setting is over the budget, then the C interpolated between the last two (linear in 1/C) to
// fill it; the errors against a run at half the smallest C tried.
void calibrateMpm(BudgetChoice& out, const std::string& scenePath, double budgetMs, int threads, bool quiet,
                  int maxFrames) {
  std::vector<Trajectory> runs;
  const auto run = [&](double cfl) {
    BudgetCandidate c;
    c.setting = {{"cfl", cfl}};
    try {
      runs.push_back(calibrationRun(scenePath, c.setting, threads, maxFrames, c.msPerFrame, c.status));
    } catch (const RuntimeError& e) {  // more than 1000 substeps: too fine to run at all
      runs.emplace_back();
      c.msPerFrame = std::numeric_limits<double>::infinity();
      c.status = std::string("error: ") + e.what();
    }
    if (!quiet)
      std::cerr << "budget: " << settingText(c.setting) << ": " << c.msPerFrame << " ms per frame"
                << (c.status == "ok" ? "" : " (" + c.status + ")") << "\n";
    out.candidates.push_back(c);
    return c;
  };
  double lo = 0.0, msLo = 0.0, smallest = 1.0;
  for (double cfl = 1.0; cfl >= kMinCfl; cfl *= 0.5) {
    const BudgetCandidate c = run(cfl);
    smallest = cfl;
    if (c.status.rfind("error", 0) == 0) break;
    if (c.msPerFrame > budgetMs) {
      if (lo > 0.0 && c.msPerFrame > msLo) {
        const double f = (budgetMs - msLo) / (c.msPerFrame - msLo);
        const double fill = 1.0 / (1.0 / lo + f * (1.0 / cfl - 1.0 / lo));
        // Worth a run only when it differs from both ends by more than 5 %.
        if (fill < 0.95 * lo && fill > 1.05 * cfl) run(std::round(fill * 1e4) / 1e4);
      }
      break;
    }
    lo = cfl, msLo = c.msPerFrame;
  }
  out.reference = {{"cfl", std::max(kMinCfl, 0.5 * smallest)}};
  measureErrors(out, runs, scenePath, threads, maxFrames);
}

}  // namespace

BudgetChoice calibrateBudget(const std::string& scenePath, double budgetMs, int threads, bool quiet) {
  if (!(budgetMs > 0.0) || !std::isfinite(budgetMs))
    throw InputError("--budget", 0, "budget", "must be a positive number of milliseconds per frame");
  const Prepared p = prepare(scenePath, threads, /*forLint=*/true);
  const bool mpm = p.scene.solver == SolverKind::kMpm;
  if (mpm && !p.scene.substepsAuto)
    throw InputError(p.scene.path, p.scene.substepsLine, "substeps",
                     std::string("--budget picks the Courant number of 'substeps auto' for solver mpm; ") +
                         (p.scene.substepsLine > 0 ? "this record fixes the substep count" : "add the record 'substeps auto'"));
  const int frames = p.scene.frameCount();
  if (frames < 2) throw InputError(p.scene.path, 0, "duration", "--budget needs at least one simulated frame");
  BudgetChoice out;
  out.calibrationFrames = std::min(frames - 1, std::max(5, (frames - 1) / 5));
  const int maxFrames = out.calibrationFrames + 1;  // frame 0 and frames 1..K
  if (mpm) {
    calibrateMpm(out, scenePath, budgetMs, threads, quiet, maxFrames);
    return choose(out, budgetMs);
  }
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
  measureErrors(out, runs, scenePath, threads, maxFrames);
  return choose(out, budgetMs);
}

}  // namespace physketch::app
