// report.json: what a run did, in a form users and tests can check without decoding
// images (docs/formats.md, "Outputs").
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/physketch/prepare.h"
#include "apps/physketch/runtime.h"
#include "core/solver.h"

namespace physketch::app {

// Particles per material name (every material of the scene, 0 if unused), holes of cut
// cloths left out.
std::map<std::string, std::int64_t> particlesPerMaterial(const Prepared& p);
// The same per material kind (every kind the scene's materials have).
std::map<std::string, std::int64_t> particlesPerKind(const Prepared& p);
// Provenance of the sketch: particles per operation, per material and per body, and lint warnings.
nlohmann::json sketchJson(const Prepared& p);
nlohmann::json planJson(const std::vector<PlanEntry>& plan);
// frame: the frame the tripping step was computing (step / steps per frame + 1).
nlohmann::json guardJson(const GuardRecord& g, int stepsPerFrame);
int guardFrame(const GuardRecord& g, int stepsPerFrame);
// Every body's pose at one frame: [cx, cy, cz, qw, qx, qy, qz] (m; unit quaternion, rest -> world).
nlohmann::json posesJson(const Solver& solver);
nlohmann::json runtimeJson(const sketch::Sketch& sk, const RuntimeDriver& runtime);
// Time per pass: the solver's (per simulated frame) and the renderer's (per written frame).
// held: the solver's planAll() at the end of the run, for each pass's held_bytes.
nlohmann::json passesJson(const Profile& solver, const Profile* render, int framesWritten,
                          const std::vector<PlanEntry>& held);

// Bytes the run will hold per particle in the PBD solver and the sketch, plus the 151^3 grid.
double memoryEstimateMiB(std::size_t particles);

}  // namespace physketch::app
