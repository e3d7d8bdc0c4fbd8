// MLS-MPM solver (placeholder). Filled by its own issue: elastic (fixed-corotated,
// neo-Hookean), plasticity (Drucker-Prager, von Mises, clamp), weakly compressible
// fluid, slip/sticky boundaries (VR-Doh supplement, PhyVR). Depends on core only;
// never includes pbd/.
#pragma once

namespace physketch::mpm {

// True once the solver exists; the CLI rejects 'solver mpm' until then.
constexpr bool kAvailable = false;

}  // namespace physketch::mpm
