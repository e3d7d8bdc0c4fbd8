#include "core/material.h"

namespace physketch {

const char* toString(MaterialKind kind) {
  switch (kind) {
    case MaterialKind::kRigid: return "rigid";
  }
  return "?";
}

bool parseMaterialKind(const std::string& name, MaterialKind& out) {
  if (name == "rigid") {
    out = MaterialKind::kRigid;
    return true;
  }
  return false;
}

int findMaterial(const std::vector<Material>& materials, const std::string& name) {
  for (std::size_t i = 0; i < materials.size(); ++i)
    if (materials[i].name == name) return static_cast<int>(i);
  return -1;
}

}  // namespace physketch
