#include "sketch/strands.h"

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "sketch/brush.h"

namespace physketch::sketch {

BodyLayout layoutOf(MaterialKind kind) {
  switch (kind) {
    case MaterialKind::kRope: return BodyLayout::kChain;
    case MaterialKind::kCloth: return BodyLayout::kLattice;
    default: return BodyLayout::kVoxels;
  }
}

std::vector<PathPoint> centreline(const Stroke& s, double h) {
  const std::vector<Sample>& sm = s.samples;
  std::vector<PathPoint> out;
  Vec3 cur = sm.front().position;
  out.push_back({cur, sm.front().line});
  std::size_t seg = 1;  // the current point lies on the segment sm[seg - 1] -> sm[seg]
  for (;;) {
    bool found = false;
    for (std::size_t j = seg; j < sm.size(); ++j) {
      const Vec3& b = sm[j].position;
      if ((b - cur).norm() < h) continue;  // the whole segment stays within h of cur
      // The segment leaves the sphere of radius h around cur: where, solving
      // |a + t d - cur|^2 = h^2 for its larger root (a lies inside the sphere).
      const Vec3 a = j == seg ? cur : sm[j - 1].position;
      const Vec3 d = b - a, f = a - cur;
      const double qa = d.squaredNorm(), qb = 2.0 * f.dot(d), qc = f.squaredNorm() - h * h;
      const double t = std::clamp((-qb + std::sqrt(std::max(0.0, qb * qb - 4.0 * qa * qc))) / (2.0 * qa), 0.0, 1.0);
      cur = a + t * d;
      out.push_back({cur, sm[j].line});
      seg = j;
      found = true;
      break;
    }
    if (!found) break;
  }
  // The end: Round(L/h) + 1 points on a straight path, as Eq. 6 counts them.
  const Vec3 rest = sm.back().position - cur;
  if (rest.norm() >= 0.5 * h) out.push_back({cur + h * rest.normalized(), sm.back().line});
  return out;
}

namespace {

// The direction of the path at centreline point k (central difference; one-sided at the ends).
Vec3 tangentAt(const std::vector<PathPoint>& pts, std::size_t k) {
  const std::size_t lo = k > 0 ? k - 1 : 0, hi = std::min(k + 1, pts.size() - 1);
  return (pts[hi].position - pts[lo].position).normalized();
}

StrandShape clothOf(const Operation& op, double h, const std::string& path) {
  const Stroke& s = op.stroke;
  if (s.brush != BrushShape::kDisc)
    throw InputError(path, op.line, "brush",
                     std::string("a cloth is the surface a disc sweeps: use brush 'disc', not '") + toString(s.brush) +
                         "'");
  if (s.orient == Orientation::kFollow)
    throw InputError(path, op.line, "orient",
                     "a cloth is swept by the disc's diameter across the path, but orient=follow turns the disc face-on "
                     "to the path; use orient=fixed with axis= the disc's normal");
  const std::vector<PathPoint> pts = centreline(s, h);
  if (pts.size() < 2)
    throw InputError(path, op.line, "samples",
                     "a cloth needs a path at least half a particle spacing (" + std::to_string(0.5 * h) + " m) long");
  StrandShape shape;
  shape.layout = BodyLayout::kLattice;
  shape.rows = static_cast<std::int32_t>(pts.size());
  shape.cols = static_cast<std::int32_t>(std::lround(s.size / h)) + 1;
  shape.radius = static_cast<float>(0.5 * (s.length > 0 ? s.length : h));
  shape.nodes.reserve(static_cast<std::size_t>(shape.rows) * static_cast<std::size_t>(shape.cols));
  for (std::size_t r = 0; r < pts.size(); ++r) {
    const Vec3 across = s.axis.cross(tangentAt(pts, r));
    // sin of the angle between path and axis: below 1e-3 the line across has no direction.
    if (across.norm() < 1e-3)
      throw InputError(path, pts[r].line, "axis",
                       "the path runs along the disc's axis here, so the disc sweeps no surface; a cloth's path must "
                       "cross the axis (the disc's normal)");
    const Vec3 w = across.normalized();
    for (std::int32_t c = 0; c < shape.cols; ++c) {
      shape.nodes.push_back(pts[r].position + (c - 0.5 * (shape.cols - 1)) * h * w);
      shape.lines.push_back(pts[r].line);
    }
  }
  return shape;
}

}  // namespace

StrandShape strandOf(const Operation& op, MaterialKind kind, double h, const std::string& path) {
  const char* what = kind == MaterialKind::kRope ? "rope" : "cloth";
  if (op.kind != Operation::Kind::kStroke)
    throw InputError(path, op.line, "material",
                     "material '" + op.material + "' is kind " + what + ": a " + what + " is drawn with a create " +
                         "stroke (its path), not with a " + (op.kind == Operation::Kind::kPrimitive ? "primitive" : "stamp"));
  if (kind == MaterialKind::kCloth) return clothOf(op, h, path);
  StrandShape shape;
  shape.layout = BodyLayout::kChain;
  shape.radius = static_cast<float>(0.5 * op.stroke.size);
  for (const PathPoint& p : centreline(op.stroke, h)) {
    shape.nodes.push_back(p.position);
    shape.lines.push_back(p.line);
  }
  shape.rows = static_cast<std::int32_t>(shape.nodes.size());
  shape.cols = 1;
  return shape;
}

StrandShape mirrored(const StrandShape& shape, const Mirror& mirror) {
  StrandShape m = shape;
  for (Vec3& p : m.nodes) p = mirrorPoint(p, mirror);
  return m;
}

void Strands::add(int op, std::int16_t material, const StrandShape& shape) {
  Piece p;
  p.op = op;
  p.material = material;
  p.layout = shape.layout;
  p.rows = shape.rows;
  p.cols = shape.cols;
  p.radius = shape.radius;
  p.first = static_cast<std::int32_t>(pos_.size());
  p.count = static_cast<std::int32_t>(shape.nodes.size());
  pieces_.push_back(p);
  pos_.insert(pos_.end(), shape.nodes.begin(), shape.nodes.end());
  alive_.insert(alive_.end(), shape.nodes.size(), 1);
}

void Strands::translate(const Span& span, const Vec3& offset) {
  for (std::int32_t i = span.first; i < span.end; ++i) pos_[static_cast<std::size_t>(i)] += offset;
}

std::int32_t Strands::aliveIn(const Span& span) const {
  std::int32_t n = 0;
  for (std::int32_t i = span.first; i < span.end; ++i) n += alive(i);
  return n;
}

std::vector<StrandBody> bodiesOf(const Strands& strands, const Strands::Piece& piece) {
  std::vector<StrandBody> out;
  if (piece.layout == BodyLayout::kLattice) {
    std::int32_t r0 = piece.rows, r1 = -1, c0 = piece.cols, c1 = -1;
    for (std::int32_t r = 0; r < piece.rows; ++r)
      for (std::int32_t c = 0; c < piece.cols; ++c)
        if (strands.alive(piece.first + r * piece.cols + c))
          r0 = std::min(r0, r), r1 = std::max(r1, r), c0 = std::min(c0, c), c1 = std::max(c1, c);
    if (r1 < 0) return out;
    StrandBody b;
    b.layout = BodyLayout::kLattice;
    b.firstNode = piece.first + r0 * piece.cols + c0;
    b.rows = r1 - r0 + 1, b.cols = c1 - c0 + 1, b.row0 = r0, b.col0 = c0;
    out.push_back(b);
    return out;
  }
  for (std::int32_t i = piece.first; i < piece.first + piece.count;) {
    if (!strands.alive(i)) {
      ++i;
      continue;
    }
    StrandBody b;
    b.firstNode = i;
    b.cols = 1;
    while (i < piece.first + piece.count && strands.alive(i)) ++i, ++b.rows;
    out.push_back(b);
  }
  std::stable_sort(out.begin(), out.end(), [](const StrandBody& a, const StrandBody& b) { return a.rows > b.rows; });
  return out;
}

}  // namespace physketch::sketch
