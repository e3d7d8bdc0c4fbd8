#include "sketch/tilt_import.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <numeric>
#include <sstream>

#include "core/error.h"
#include "core/scene.h"
#include "sketch/voxelize.h"

namespace physketch::sketch {
namespace {

constexpr int kMaxMaterials = 64;
constexpr double kThinFactor = 2.02;  // thickened strokes are this many particle spacings wide (lint: < 2)

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

// A stroke ready to write: world positions (m), times (s), pressures, its size and material.
struct Out {
  int source = 0;  // index in the .tilt
  double size = 0.0;
  std::vector<Vec3> p;
  std::vector<double> t, pressure;
  int material = 0;
  std::string body;
};

// Colours to materials: 8-bit RGB, quantized more coarsely while more than kMaxMaterials remain.
std::vector<int> colourMaterials(const TiltSketch& sk, const std::vector<int>& used, std::vector<Vec3>& colours) {
  for (int step = 1;; step *= 2) {
    std::map<std::array<int, 3>, int> index;
    std::vector<int> of(used.size());
    colours.clear();
    for (std::size_t i = 0; i < used.size(); ++i) {
      const Vec3& c = sk.strokes[static_cast<std::size_t>(used[i])].color;
      std::array<int, 3> key{};
      for (int k = 0; k < 3; ++k) {
        const int v = std::clamp(static_cast<int>(std::lround(std::min(c[k], 1.0) * 255.0)), 0, 255);
        key[static_cast<std::size_t>(k)] = std::min(255, v / step * step + step / 2);
      }
      auto [it, added] = index.emplace(key, static_cast<int>(colours.size()));
      if (added) colours.emplace_back(key[0] / 255.0, key[1] / 255.0, key[2] / 255.0);
      of[i] = it->second;
    }
    if (static_cast<int>(colours.size()) <= kMaxMaterials) return of;
  }
}

std::string materialName(const Vec3& c) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "c_%02x%02x%02x", static_cast<int>(std::lround(c[0] * 255)),
                static_cast<int>(std::lround(c[1] * 255)), static_cast<int>(std::lround(c[2] * 255)));
  return buf;
}

struct UnionFind {
  std::vector<int> up;
  explicit UnionFind(int n) : up(static_cast<std::size_t>(n)) { std::iota(up.begin(), up.end(), 0); }
  int find(int a) {
    while (up[static_cast<std::size_t>(a)] != a) a = up[static_cast<std::size_t>(a)] = up[static_cast<std::size_t>(up[static_cast<std::size_t>(a)])];
    return a;
  }
  void join(int a, int b) {
    a = find(a), b = find(b);
    if (a != b) up[static_cast<std::size_t>(std::max(a, b))] = std::min(a, b);  // the smaller id is the root
  }
};

std::string strokesText(const std::vector<Out>& out, const std::vector<Vec3>& colours, const TiltImport& r,
                        const TiltImportOptions& o) {
  std::ostringstream s;
  s << "physketch-strokes 1\n"
    << "# Imported by `physketch import-tilt` from " << o.source << ": " << r.strokesWritten << " of "
    << r.strokesRead << " strokes, scale " << fmt("%.6g", r.scale) << " m per Tilt Brush metre, join "
    << toString(o.join) << ", thicken " << (o.thicken ? "on" : "off") << ".\n";
  for (const Out& st : out) {
    s << "stroke create sphere " << fmt("%.6f", st.size) << ' ' << materialName(colours[static_cast<std::size_t>(st.material)]);
    if (!st.body.empty()) s << " body=" << st.body;
    s << "    # tilt stroke " << st.source + 1 << '\n';
    for (std::size_t i = 0; i < st.p.size(); ++i) {
      s << "sample " << fmt("%.3f", st.t[i]) << ' ' << fmt("%.6f", st.p[i].x()) << ' ' << fmt("%.6f", st.p[i].y())
        << ' ' << fmt("%.6f", st.p[i].z());
      if (st.pressure[i] != 1.0) s << ' ' << fmt("%.4f", st.pressure[i]);
      s << '\n';
    }
  }
  return s.str();
}

std::string sceneText(const std::vector<Vec3>& colours, const TiltImportOptions& o) {
  const Vec3& c = o.workspaceCenter;
  const double w = o.workspaceSize, floor = c.y() - w / 2;
  const Vec3 target(c.x(), floor + 0.3 * w, c.z());
  const Vec3 eye = target + w * Vec3(1.3, 0.65, 1.5);
  std::ostringstream s;
  s << "physketch-scene 1\n"
    << "# Written by `physketch import-tilt` from " << o.source << " (docs/formats.md, \"Importing Open Brush sketches\").\n"
    << "strokes " << o.strokesName << "\n"
    << "workspace " << fmt("%.6g", c.x()) << ' ' << fmt("%.6g", c.y()) << ' ' << fmt("%.6g", c.z()) << ' '
    << fmt("%.6g", w) << "\n"
    << "solver pbd\nsubsteps 4\niterations 4\ngravity 0 -9.81 0\n"
    << "ground " << fmt("%.6g", floor) << "\nduration 3\nfps 30\n";
  for (const Vec3& col : colours)
    s << "material " << materialName(col) << " rigid density=" << fmt("%.6g", o.density) << " color="
      << fmt("%.4f", col[0]) << ',' << fmt("%.4f", col[1]) << ',' << fmt("%.4f", col[2]) << '\n';
  s << "camera " << fmt("%.4f", eye.x()) << ' ' << fmt("%.4f", eye.y()) << ' ' << fmt("%.4f", eye.z()) << "   "
    << fmt("%.4f", target.x()) << ' ' << fmt("%.4f", target.y()) << ' ' << fmt("%.4f", target.z()) << "   40\n"
    << "image 640 480\noutput frames report\n";
  return s.str();
}

}  // namespace

const char* toString(TiltJoin join) {
  switch (join) {
    case TiltJoin::kTouching: return "touching";
    case TiltJoin::kMaterial: return "material";
    case TiltJoin::kNone: return "none";
  }
  return "?";
}

bool parseTiltJoin(const std::string& word, TiltJoin& out) {
  for (TiltJoin j : {TiltJoin::kTouching, TiltJoin::kMaterial, TiltJoin::kNone})
    if (word == toString(j)) {
      out = j;
      return true;
    }
  return false;
}

namespace {

// The sketch with every stroke in the canvas frame: points and size through its layer's
// transform (Open Brush), canvas = t + R (s p); strokes on a layer index the metadata does
// not list stay as they are (Open Brush creates such a layer, untransformed).
TiltSketch throughLayers(const TiltSketch& in, TiltImport& r) {
  TiltSketch out = in;
  for (TiltStroke& st : out.strokes) {
    if (st.layer >= out.layers.size()) continue;
    const TiltLayer& l = out.layers[st.layer];
    if (l.translation.isZero(0.0) && l.rotation.coeffs() == Quat::Identity().coeffs() && l.scale == 1.0) continue;
    ++r.layerMoved;
    const Mat3 R = l.rotation.toRotationMatrix();
    for (TiltPoint& pt : st.points) pt.position = l.translation + R * (l.scale * pt.position);
    st.size *= l.scale;
  }
  return out;
}

}  // namespace

TiltImport importTilt(const TiltSketch& input, const TiltImportOptions& o) {
  const std::string& src = o.source;
  if (!(o.workspaceSize > 0 && o.workspaceSize <= 1000)) throw InputError(src, 0, "--workspace", "size must be in (0, 1000] m");
  if (!(o.fit > 0 && o.fit <= 0.98)) throw InputError(src, 0, "--fit", "must be in (0, 0.98]");
  if (!(o.scale >= 0 && std::isfinite(o.scale))) throw InputError(src, 0, "--scale", "must be > 0");
  if (!(o.density > 0 && o.density <= 1e5)) throw InputError(src, 0, "--density", "must be in (0, 1e5] kg/m^3");
  TiltImport r;
  const TiltSketch sk = throughLayers(input, r);
  r.strokesRead = static_cast<int>(sk.strokes.size());
  std::vector<int> used;
  for (int i = 0; i < r.strokesRead; ++i) {
    const TiltStroke& st = sk.strokes[static_cast<std::size_t>(i)];
    if (st.points.empty()) {
      ++r.skippedEmpty;
    } else if (st.layer < sk.layers.size() && !sk.layers[st.layer].visible && !o.hiddenLayers) {
      ++r.skippedHidden;
    } else {
      used.push_back(i);
      r.negativeScale += st.negativeScale ? 1 : 0;
      if (st.hasPressure)
        for (const TiltPoint& pt : st.points) r.pressureAboveOne += pt.pressure > 1.0 ? 1 : 0;
    }
  }
  if (used.empty())
    throw InputError(src, 0, "data.sketch",
                     r.skippedHidden ? "every stroke with points is on a hidden layer (--hidden-layers imports them)"
                                     : "the sketch has no stroke with points");

  // Frame and units: Tilt Brush decimetres, left-handed -> metres, right-handed (z flipped).
  auto toMetres = [](const Vec3& p) -> Vec3 { return Vec3(p.x(), p.y(), -p.z()) * 0.1; };
  Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
  for (int i : used) {
    const TiltStroke& st = sk.strokes[static_cast<std::size_t>(i)];
    const double rad = 0.05 * st.size;
    for (const TiltPoint& pt : st.points) {
      const Vec3 p = toMetres(pt.position);
      for (int k = 0; k < 3; ++k) {
        lo[k] = std::min(lo[k], p[k] - rad);
        hi[k] = std::max(hi[k], p[k] + rad);
      }
    }
  }
  const double extent = std::max((hi - lo).maxCoeff(), 1e-9);
  r.scale = o.scale > 0 ? o.scale : o.fit * o.workspaceSize / extent;
  const GridMapping mapping(o.workspaceCenter, o.workspaceSize);
  const double h = mapping.voxelSize(), floor = o.workspaceCenter.y() - o.workspaceSize / 2;
  const Vec3 mid = (lo + hi) / 2;
  const Vec3 offset(o.workspaceCenter.x() - r.scale * mid.x(), floor + h - r.scale * lo.y(),
                    o.workspaceCenter.z() - r.scale * mid.z());
  if (r.scale * extent > o.workspaceSize - 2 * h)
    throw InputError(src, 0, "--scale", "at scale " + fmt("%.6g", r.scale) + " the sketch spans " +
                                          fmt("%.4g", r.scale * extent) + " m, more than the " +
                                          fmt("%.4g", o.workspaceSize) + " m workspace: lower the scale, or fit it");

  std::vector<Vec3> colours;
  const std::vector<int> material = colourMaterials(sk, used, colours);
  r.materials = static_cast<int>(colours.size());

  // Times: seconds from the first timestamp of the sketch.
  std::uint32_t t0 = UINT32_MAX;
  for (int i : used)
    if (sk.strokes[static_cast<std::size_t>(i)].hasTimestamps)
      for (const TiltPoint& pt : sk.strokes[static_cast<std::size_t>(i)].points) t0 = std::min(t0, pt.timestampMs);

  std::vector<Out> out;
  double prevEnd = -1.0;
  for (std::size_t k = 0; k < used.size(); ++k) {
    const TiltStroke& st = sk.strokes[static_cast<std::size_t>(used[k])];
    Out w;
    w.source = used[k];
    w.material = material[k];
    const std::size_t n = st.points.size();
    w.p.resize(n), w.t.resize(n), w.pressure.resize(n);
    w.size = r.scale * 0.1 * st.size;
    double pmax = 0;
    for (std::size_t i = 0; i < n; ++i) {
      w.p[i] = r.scale * toMetres(st.points[i].position) + offset;
      w.pressure[i] = st.hasPressure ? 0.2 + 0.8 * std::min(st.points[i].pressure, 1.0) : 1.0;
      pmax = std::max(pmax, w.pressure[i]);
    }
    // Thicken: every sample at least kThinFactor h wide, the wider ones as drawn.
    const double minWidth = kThinFactor * h;
    bool thin = w.size <= 0;
    for (double p : w.pressure) thin = thin || w.size * p < minWidth;
    if (thin && (o.thicken || w.size <= 0)) {
      const double size = std::max(w.size * pmax, minWidth);
      for (double& p : w.pressure) p = std::min(1.0, std::max(w.size * p, minWidth) / size);
      w.size = size;
      ++r.thickened;
    }
    // Times: kept, made strictly increasing, the stroke delayed after the previous one.
    for (std::size_t i = 0; i < n; ++i) {
      if (st.hasTimestamps) w.t[i] = (st.points[i].timestampMs - t0) / 1000.0;
      else w.t[i] = (i == 0 ? std::max(prevEnd, 0.0) + 0.01 : w.t[i - 1] + 0.01);
      if (i > 0 && w.t[i] < w.t[i - 1] + 0.001) {
        w.t[i] = w.t[i - 1] + 0.001;
        ++r.pointsNudged;
      }
    }
    if (prevEnd >= 0 && w.t[0] < prevEnd + 0.001) {
      const double shift = prevEnd + 0.001 - w.t[0];
      for (double& t : w.t) t += shift;
      ++r.delayed;
    }
    // Printed to the ms: round here so that what is written is what was checked.
    for (double& t : w.t) t = std::round(t * 1000.0) / 1000.0;
    prevEnd = w.t.back();
    out.push_back(std::move(w));
  }
  r.strokesWritten = static_cast<int>(out.size());

  r.scene = sceneText(colours, o);
  const SceneDesc scene = parseScene(r.scene, src + " (the scene written with it)");
  const std::string written = src + " (the strokes written from it)";
  Sketch vox = voxelize(parseStrokes(strokesText(out, colours, r, o), written), mapping, scene.materials);
  r.particles = static_cast<std::int64_t>(vox.particles.size());

  // Bodies: union of strokes whose voxels touch (26-neighbours), per material when asked.
  UnionFind uf(static_cast<int>(out.size()));
  if (o.join != TiltJoin::kNone) {
    const auto& stroke = vox.particles.stroke;
    for (std::size_t i = 0; i < vox.cells.size(); ++i) {
      const Vec3i& c = vox.cells[i];
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const Vec3i d(dx, dy, dz);
            if (GridMapping::linear(d + Vec3i::Constant(1)) <= GridMapping::linear(Vec3i::Constant(1))) continue;
            const Vec3i nc = c + d;
            if (!GridMapping::inGrid(nc)) continue;
            const std::int32_t q = vox.grid.at(nc);
            if (q < 0) continue;
            const int a = stroke[i], b = stroke[static_cast<std::size_t>(q)];
            if (a == b) continue;
            if (o.join == TiltJoin::kMaterial && out[static_cast<std::size_t>(a)].material != out[static_cast<std::size_t>(b)].material)
              continue;
            uf.join(a, b);
          }
    }
  }
  // A body per component that holds particles (a stroke whose voxels were all taken makes none).
  std::vector<int> members(out.size(), 0);
  std::vector<char> holds(out.size(), 0);
  for (std::size_t k = 0; k < out.size(); ++k) {
    const auto root = static_cast<std::size_t>(uf.find(static_cast<int>(k)));
    ++members[root];
    if (vox.operations[k].remaining > 0) holds[root] = 1;
  }
  for (std::size_t k = 0; k < out.size(); ++k) {
    const int root = uf.find(static_cast<int>(k));
    if (root == static_cast<int>(k) && holds[k]) ++r.bodies;
    if (members[static_cast<std::size_t>(root)] > 1) out[k].body = "part_" + std::to_string(out[static_cast<std::size_t>(root)].source + 1);
  }
  r.strokes = strokesText(out, colours, r, o);
  return r;
}

}  // namespace physketch::sketch
