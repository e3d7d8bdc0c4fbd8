// Blocks of MPM particles for the tests: a box of lattice points at spacing h, one body.
#pragma once

#include <vector>

#include "core/material_table.h"
#include "core/particles.h"
#include "mpm/world.h"

namespace physketch::mpm::test {

// Appends a box of nx x ny x nz particles at spacing h with its lowest corner particle at
// `corner` (cell centres), as body `bodies.size()`.
inline void addBox(ParticleArrays& p, std::vector<BodyRange>& bodies, const Vec3& corner, int nx, int ny, int nz,
                   double h, std::int16_t material, const BodyInit& init = {}) {
  BodyRange br;
  br.first = static_cast<std::int32_t>(p.size());
  br.stroke = static_cast<std::int32_t>(bodies.size());
  br.init = init;
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j)
      for (int k = 0; k < nz; ++k)
        p.push(float(corner.x() + i * h), float(corner.y() + j * h), float(corner.z() + k * h), br.stroke, material);
  br.count = static_cast<std::int32_t>(p.size()) - br.first;
  bodies.push_back(br);
}

// A unit-cube domain at the origin, particle spacing h, dx = 2 h, substeps fixed.
inline MpmParams unitDomain(double h, int substeps, double dt = 1.0 / 60.0) {
  MpmParams q;
  q.dt = dt;
  q.substeps = substeps;
  q.spacing = h;
  q.domainMin = Vec3::Zero();
  q.domainSize = 1.0;
  q.groundY = 0.0;
  return q;
}

}  // namespace physketch::mpm::test
