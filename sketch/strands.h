// Ropes and cloth: creates whose material kind is `rope` or `cloth` are not voxels but
// a chain or a lattice of particles at the particle spacing h (docs/formats.md, "Ropes
// and cloth"). This header has the geometry (pure functions of a stroke) and the store
// that keeps them while the operations are replayed, where removes and moves act on them
// by position.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/material.h"
#include "core/particles.h"
#include "sketch/grid.h"
#include "sketch/solids.h"
#include "sketch/strokes.h"

namespace physketch::sketch {

// How a create of a material kind is laid out: rope -> kChain, cloth -> kLattice, every
// other kind -> kVoxels.
BodyLayout layoutOf(MaterialKind kind);

// A point of a stroke's centreline.
struct PathPoint {
  Vec3 position;  // m
  int line = 0;   // line of the sample that ends the path segment it lies on (for errors)
};

// The centreline of a stroke resampled at spacing h: the polyline through its samples (the
// line the Eq. 6-7 stamps lie on) walked from the first sample, each next point the first
// one along the polyline at straight-line distance exactly h from the last (so every
// neighbour distance is h, on bends too); at the end one more point h further, towards
// the last sample, when that sample is at least h/2 away. A straight path of length L
// gives round(L/h) + 1 points, as Eq. 6-7 does. A single sample gives one point.
std::vector<PathPoint> centreline(const Stroke& stroke, double h);

// A rope or cloth as drawn: node positions in layout order.
struct StrandShape {
  BodyLayout layout = BodyLayout::kChain;
  std::int32_t rows = 0, cols = 0;  // kLattice: rows along the path, cols across; kChain: rows = nodes, cols = 1
  float radius = 0.0f;              // contact and render radius (m), see BodyRange::radius
  std::vector<Vec3> nodes;          // m, row-major for a lattice
  std::vector<int> lines;           // per node: the sample line it comes from (for errors)
};

// The chain or lattice a create stroke of `kind` (rope or cloth) makes, before any mirror:
// - rope: the centreline, one particle across; radius = half the brush size.
// - cloth: a disc brush with orient=fixed sweeps the diameter that is perpendicular to
//   the path and lies in the disc's plane (w = axis x tangent, normalized): row r is the
//   centreline point P_r, col c the node P_r + (c - (cols-1)/2) h w_r, cols =
//   round(size/h) + 1; radius = half the disc's thickness (`length`, default one voxel).
// Pressure does not change a rope's radius or a cloth's width (one cross-section).
// Throws InputError (path:line:field) for a primitive or a stamp of a rope or cloth
// material ('material'), a cloth brush that is not a disc ('brush'), a cloth disc with
// orient=follow ('orient'), a cloth path that runs along the disc's axis ('axis') or has
// no length ('samples').
StrandShape strandOf(const Operation& op, MaterialKind kind, double h, const std::string& path);

// The mirror image of a shape across a plane (the exact plane: nodes are not voxel centres).
StrandShape mirrored(const StrandShape& shape, const Mirror& mirror);

// The ropes and cloths of the sketch while the operations before play are replayed: each
// created shape (one per mirror copy) is a piece; removes kill nodes, moves translate
// what hangs together (a span). Nodes keep their index in their piece, so a piece keeps
// its layout.
class Strands {
 public:
  struct Piece {
    int op = 0;
    std::int16_t material = -1;
    BodyLayout layout = BodyLayout::kChain;
    std::int32_t rows = 0, cols = 0;
    float radius = 0.0f;
    std::int32_t first = 0, count = 0;  // nodes [first, first + count)
  };

  void add(int op, std::int16_t material, const StrandShape& shape);
  bool empty() const { return pieces_.empty(); }
  const std::vector<Piece>& pieces() const { return pieces_; }
  const std::vector<Vec3>& positions() const { return pos_; }
  bool alive(std::int32_t node) const { return alive_[static_cast<std::size_t>(node)] != 0; }

  // Alg. 2 by position: kills every live node for which inside(position) holds. Returns how many.
  template <class Inside>
  std::int64_t removeWhere(Inside&& inside) {
    std::int64_t n = 0;
    for (std::size_t i = 0; i < pos_.size(); ++i)
      if (alive_[i] && inside(pos_[i])) alive_[i] = 0, ++n;
    return n;
  }
  // Nodes [first, end) that hang together: a whole lattice, or a run of live nodes of a chain
  // (the chains a remove cut it into are bodies of their own).
  struct Span {
    std::int32_t first, end;
    bool operator==(const Span& o) const { return first == o.first && end == o.end; }
  };
  // The spans with a live node for which inside(position) holds, in node order.
  template <class Inside>
  std::vector<Span> spansWhere(Inside&& inside) const {
    std::vector<Span> out;
    for (const Piece& p : pieces_) {
      const std::int32_t end = p.first + p.count;
      for (std::int32_t i = p.first; i < end; ++i) {
        if (!alive(i) || !inside(pos_[static_cast<std::size_t>(i)])) continue;
        if (p.layout == BodyLayout::kLattice) {
          out.push_back({p.first, end});
          break;
        }
        std::int32_t a = i, b = i + 1;
        while (a > p.first && alive(a - 1)) --a;
        while (b < end && alive(b)) ++b;
        out.push_back({a, b});
        i = b;  // the run is taken; look on past it
      }
    }
    return out;
  }
  // Moves the nodes of a span by `offset` (m).
  void translate(const Span& span, const Vec3& offset);
  std::int32_t aliveIn(const Span& span) const;

 private:
  std::vector<Piece> pieces_;
  std::vector<Vec3> pos_;
  std::vector<std::uint8_t> alive_;
};

// The bodies one piece leaves after removes: a chain splits into its runs of live nodes,
// largest first (ties: path order), each a kChain; a lattice stays one kLattice cropped to
// the rows and cols that still hold a live node, its dead nodes inside kept as holes.
// Empty when nothing is left.
struct StrandBody {
  std::int32_t firstNode = 0;  // for a chain: nodes [firstNode, firstNode + rows) of the store
  BodyLayout layout = BodyLayout::kChain;
  std::int32_t rows = 0, cols = 0;  // a chain: rows nodes, cols = 1
  std::int32_t row0 = 0, col0 = 0;  // a lattice: its first row and col in the piece
};
std::vector<StrandBody> bodiesOf(const Strands& strands, const Strands::Piece& piece);

}  // namespace physketch::sketch
