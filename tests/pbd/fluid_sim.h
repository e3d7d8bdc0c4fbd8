// A minimal PBF driver around pbd::FluidSolver for tests and bench/bench_pbf.cpp: the
// loop of Macklin & Müller 2013 Alg. 1 on free fluid particles in a box (predict,
// neighbour structure, density iterations, velocity update, velocity passes). The PBD
// world runs the same sequence with its other constraints in between; this helper stands
// in for it until the fluid is integrated there.
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <cstdint>
#include <vector>

#include "pbd/fluid.h"

namespace physketch::pbd::testing {

struct FluidSim {
  // Time per part of the substep, summed over steps (ms), for the benchmark only: wall
  // time, and the process's CPU time (all threads), which on a loaded machine excludes
  // the waits for a core.
  enum Part { kPredict, kNeighbors, kWarm, kLambda, kCorrection, kUpdate, kVelocity, kParts };
  static constexpr const char* kPartNames[kParts] = {"predict", "neighbors", "warm", "lambda", "correction", "update", "velocity"};
  struct Timing {
    double wall[kParts] = {};
    double cpu[kParts] = {};
  };

  FluidParams params;
  float dt = 1.0f / 60.0f;  // s per step
  int substeps = 1;
  int iterations = 8;
  float gravity = -9.81f;   // m/s^2 along y
  // Sound speed (m/s) of the density constraint's compliance: < 0 picks
  // FluidSolver::autoSoundSpeed each substep (the PBD world's default), 0 = none.
  float soundSpeed = -1.0f;
  FluidSolver::Kernel kernel = FluidSolver::Kernel::kAuto;

  std::vector<float> x, y, z, vx, vy, vz;  // positions (m), velocities (m/s), by id
  std::vector<float> w, rho0;              // inverse mass (1/kg), rest density (kg/m^3)
  std::vector<std::uint8_t> fluid;
  Timing timing;

  explicit FluidSim(const FluidParams& p) : params(p), solver_(p) {}

  std::size_t size() const { return x.size(); }

  // A block of nx * ny * nz fluid particles on the lattice of spacing 2r, its lowest
  // corner's particle centre at (x0, y0, z0) (m), rest density rho (kg/m^3).
  void addBlock(float x0, float y0, float z0, int nx, int ny, int nz, float rho) {
    const float d = 2.0f * params.particleRadius;
    const float m = rho * d * d * d;
    for (int k = 0; k < nz; ++k)
      for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
          x.push_back(x0 + d * float(i)), y.push_back(y0 + d * float(j)), z.push_back(z0 + d * float(k));
          vx.push_back(0), vy.push_back(0), vz.push_back(0);
          w.push_back(1.0f / m), rho0.push_back(rho), fluid.push_back(1);
        }
  }

  void step() {
    const float h = dt / float(substeps);
    const std::size_t n = size();
    px_.resize(n), py_.resize(n), pz_.resize(n);
    solver_.setKernel(kernel);
    for (int s = 0; s < substeps; ++s) {
      Stamp t = now();
      float lo = 1e30f, hi = -1e30f, v2 = 0.0f;  // the fluid's height and fastest speed, for c
      for (std::size_t i = 0; i < n; ++i) {  // predict (Alg. 1 lines 1-3)
        vy[i] += h * gravity;
        px_[i] = x[i] + h * vx[i], py_[i] = y[i] + h * vy[i], pz_[i] = z[i] + h * vz[i];
        if (!fluid[i]) continue;
        lo = std::min(lo, py_[i]), hi = std::max(hi, py_[i]);
        v2 = std::max(v2, (vx[i] * vx[i] + vy[i] * vy[i]) + vz[i] * vz[i]);
      }
      lap(t, kPredict);
      FluidInput in;
      in.count = n, in.x = px_.data(), in.y = py_.data(), in.z = pz_.data();
      in.invMass = w.data(), in.fluid = fluid.data(), in.restDensity = rho0.data();
      in.substep = h, in.iterations = iterations;
      if (soundSpeed < 0.0f)
        autoC_ = std::max(autoC_, FluidSolver::autoSoundSpeed(gravity, std::max(hi - lo, 0.0f) + 2.0f * params.particleRadius,
                                                              std::sqrt(v2)));
      in.soundSpeed = soundSpeed < 0.0f ? autoC_ : soundSpeed;
      if (solver_.params().warmStart > 0.0f && carried_.size() == n) in.carried = carried_.data();
      solver_.begin(in);
      lap(t, kNeighbors);
      if (solver_.warmStart()) solver_.applyCorrections();
      lap(t, kWarm);
      for (int it = 0; it < iterations; ++it) {
        solver_.lambdaPass();
        lap(t, kLambda);
        solver_.correctionPass();
        solver_.applyCorrections();
        lap(t, kCorrection);
      }
      if (solver_.params().warmStart > 0.0f) carried_.resize(n), solver_.multipliers(carried_.data());
      solver_.positions(px_.data(), py_.data(), pz_.data());
      for (std::size_t i = 0; i < n; ++i) {  // v = (p - x) / h (Alg. 1 line 21)
        vx[i] = (px_[i] - x[i]) / h, vy[i] = (py_[i] - y[i]) / h, vz[i] = (pz_[i] - z[i]) / h;
      }
      lap(t, kUpdate);
      solver_.velocityPasses(vx.data(), vy.data(), vz.data(), h);
      x.swap(px_), y.swap(py_), z.swap(pz_);  // x = p (line 23)
      lap(t, kVelocity);
    }
  }

  const FluidSolver& solver() const { return solver_; }
  FluidSolver& solver() { return solver_; }

 private:
  struct Stamp {
    std::chrono::steady_clock::time_point wall;
    double cpu;  // s
  };
  static Stamp now() {
    timespec c{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &c);
    return {std::chrono::steady_clock::now(), double(c.tv_sec) + 1e-9 * double(c.tv_nsec)};
  }
  void lap(Stamp& t, Part part) {
    const Stamp s = now();
    timing.wall[part] += std::chrono::duration<double, std::milli>(s.wall - t.wall).count();
    timing.cpu[part] += 1e3 * (s.cpu - t.cpu);
    t = s;
  }
  FluidSolver solver_;
  std::vector<float> px_, py_, pz_;
  std::vector<float> carried_;  // the last substep's multipliers (FluidParams::warmStart)
  float autoC_ = 0.0f;
};

}  // namespace physketch::pbd::testing
