#include "sketch/bodies.h"

#include <algorithm>
#include <map>
#include <utility>

#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include "core/error.h"
#include "sketch/brush.h"

namespace physketch::sketch {

BodyInit bodyInit(const Operation& op) {
  BodyInit init;
  init.velocity = op.velocity.value_or(Vec3::Zero());
  init.spin = op.spin.value_or(Vec3::Zero());
  init.fixed = op.fixed;
  return init;
}

BodyPlan planBodies(const StrokeFile& file) {
  BodyPlan plan;
  plan.bodyOfOp.assign(file.operations.size(), -1);
  std::map<std::string, int> byName;
  for (const Operation& op : file.operations) {
    if (!createsParticles(op)) continue;
    int b = static_cast<int>(plan.names.size());
    if (op.body.empty()) {
      plan.names.push_back("stroke " + std::to_string(op.id));
      plan.named.push_back(false);
      plan.init.push_back(bodyInit(op));
    } else {
      const auto [it, fresh] = byName.emplace(op.body, b);
      if (fresh) {
        plan.names.push_back(op.body);
        plan.named.push_back(true);
        plan.init.push_back(bodyInit(op));
      }
      b = it->second;
    }
    plan.bodyOfOp[static_cast<std::size_t>(op.id)] = b;
  }
  return plan;
}

std::vector<int> compactIntoBodies(const SketchCells& cells, const BodyPlan& plan, Sketch& sk) {
  const std::vector<std::int32_t>& protoCell = cells.cells();
  const std::size_t nPlanned = plan.names.size();
  // Particles grouped by body (in body order), in creation order within a body:
  // each body takes the runs of its operations in the order they were applied.
  // The runs are cut into pieces; counting the live particles of every piece fixes
  // where each piece writes, so the pieces are written in parallel and the result
  // does not depend on the threads. (A fresh output array costs a page fault per
  // 4 KiB, which two threads take twice as fast.)
  constexpr std::int32_t kPiece = 1 << 14;
  struct Piece {
    int op;
    std::int32_t first, end;  // particles [first, end) of protoCell
    std::size_t out = 0;      // live particles, then their first output index
  };
  std::vector<Piece> pieces;
  std::vector<std::size_t> firstPiece(nPlanned + 1, 0);  // the pieces of body b: [firstPiece[b], firstPiece[b+1])
  std::vector<std::vector<const OpRun*>> runsOf(nPlanned);
  for (const OpRun& run : cells.runs())
    runsOf[static_cast<std::size_t>(plan.bodyOfOp[static_cast<std::size_t>(run.op)])].push_back(&run);
  for (std::size_t b = 0; b < nPlanned; ++b) {
    firstPiece[b] = pieces.size();
    for (const OpRun* run : runsOf[b])
      for (std::int32_t f = run->first; f < run->end; f += kPiece) pieces.push_back({run->op, f, std::min(run->end, f + kPiece)});
  }
  firstPiece[nPlanned] = pieces.size();
  tbb::parallel_for(std::size_t(0), pieces.size(), [&](std::size_t p) {
    for (std::int32_t i = pieces[p].first; i < pieces[p].end; ++i) pieces[p].out += protoCell[static_cast<std::size_t>(i)] >= 0;
  });
  std::size_t total = 0;
  for (Piece& pc : pieces) {
    sk.operations[static_cast<std::size_t>(pc.op)].remaining += static_cast<std::int32_t>(pc.out);
    total += std::exchange(pc.out, total);
  }
  // At rest and prescribed: static while sketched (Phys-Sketch §4); the values of ParticleArrays::resize.
  ParticleArrays out;
  std::vector<Vec3i> outCells;
  tbb::parallel_invoke([&] { out.x.resize(total), out.vx.resize(total), out.mass.resize(total), out.stroke.resize(total); },
                       [&] { out.y.resize(total), out.vy.resize(total), out.phase.resize(total, phase::make(-1, phase::kPrescribed)),
                             out.material.resize(total); },
                       [&] { out.z.resize(total), out.vz.resize(total), outCells.resize(total); });
  out.resize(total);  // sizes any array the lines above do not name (none now; a no-op for the rest)
  tbb::parallel_for(std::size_t(0), pieces.size(), [&](std::size_t p) {
    const Piece& pc = pieces[p];
    const std::int16_t material = sk.operations[static_cast<std::size_t>(pc.op)].material;
    std::size_t j = pc.out;
    for (std::int32_t i = pc.first; i < pc.end; ++i) {
      const std::int32_t l = protoCell[static_cast<std::size_t>(i)];
      if (l < 0) continue;  // removed
      const Vec3i c = GridMapping::cellOf(l);
      const Vec3 q = sk.mapping.toWorld(c);  // Eq. 5: the particle sits at its voxel centre
      out.x[j] = static_cast<float>(q.x());
      out.y[j] = static_cast<float>(q.y());
      out.z[j] = static_cast<float>(q.z());
      out.stroke[j] = pc.op;
      out.material[j] = material;
      outCells[j] = c;
      // M with the final indices (removed particles' cells are empty already).
      if (i != static_cast<std::int32_t>(j)) sk.grid.set(c, static_cast<std::int32_t>(j));
      ++j;
    }
  });
  std::vector<std::int64_t> start(nPlanned + 1, static_cast<std::int64_t>(total));
  for (std::size_t b = 0; b < nPlanned; ++b)
    if (firstPiece[b] < pieces.size()) start[b] = static_cast<std::int64_t>(pieces[firstPiece[b]].out);
  for (std::size_t b = nPlanned; b-- > 0;)  // a body without pieces starts where the next one does
    if (firstPiece[b] == firstPiece[b + 1]) start[b] = start[b + 1];
  std::vector<int> newBody(nPlanned, -1), planned;
  for (std::size_t b = 0; b < nPlanned; ++b) {
    const std::int64_t c = start[b + 1] - start[b];
    if (c == 0) continue;
    newBody[b] = static_cast<int>(sk.bodies.size());
    BodyRange r;
    r.first = static_cast<std::int32_t>(start[b]);
    r.count = static_cast<std::int32_t>(c);
    r.stroke = out.stroke[static_cast<std::size_t>(start[b])];
    r.init = plan.init[b];
    sk.bodies.push_back(r);
    sk.bodyNames.push_back(plan.names[b]);
    planned.push_back(static_cast<int>(b));
  }
  for (auto& sum : sk.operations) {
    const int b = plan.bodyOfOp[static_cast<std::size_t>(sum.id)];
    sum.body = b >= 0 && !sum.afterPlay ? newBody[static_cast<std::size_t>(b)] : -1;
  }
  sk.particles = std::move(out);
  sk.cells = std::move(outCells);
  return planned;
}

namespace {

// The bodies of the sketch that a remove or a move touched: some particle of theirs
// was removed (by a remove, or replaced by a move) or carried by a move. Nothing
// else can disconnect a body.
std::vector<bool> touchedBodies(const SketchCells& cells, const BodyPlan& plan, const std::vector<int>& planned,
                                const Sketch& sk) {
  std::vector<int> bodyOfPlanned(plan.names.size(), -1);
  for (std::size_t b = 0; b < planned.size(); ++b)
    bodyOfPlanned[static_cast<std::size_t>(planned[b])] = static_cast<int>(b);
  std::vector<std::int64_t> created(sk.bodies.size(), 0);
  const std::vector<OpRun>& runs = cells.runs();
  auto bodyOfRun = [&](const OpRun& run) {
    return bodyOfPlanned[static_cast<std::size_t>(plan.bodyOfOp[static_cast<std::size_t>(run.op)])];
  };
  for (const OpRun& run : runs)
    if (const int b = bodyOfRun(run); b >= 0) created[static_cast<std::size_t>(b)] += run.end - run.first;
  std::vector<bool> touched(sk.bodies.size(), false);
  for (std::size_t b = 0; b < sk.bodies.size(); ++b) touched[b] = created[b] != sk.bodies[b].count;
  for (const std::int32_t p : cells.movedParticles()) {
    // The run holding p: runs are in creation order, so by their first particle.
    const auto it =
        std::upper_bound(runs.begin(), runs.end(), p, [](std::int32_t q, const OpRun& r) { return q < r.first; });
    if (const int b = bodyOfRun(*std::prev(it)); b >= 0) touched[static_cast<std::size_t>(b)] = true;
  }
  return touched;
}

// For each 26-connected component `comp` of a body's final cells (labels per live
// particle): does it hold a whole design piece? The design pieces are the components
// of the cells the body's particles were created in, removed ones included (they
// held the design together); one is whole when its live particles all lie in one
// final component.
std::vector<bool> holdsWholeDesignPiece(const SketchCells& cells, const BodyPlan& plan, int plannedBody,
                                        const std::vector<int>& comp, int nComp) {
  std::vector<Vec3i> born;
  std::vector<std::size_t> liveAt;  // index into `born` of each live particle, in output order
  for (const OpRun& run : cells.runs()) {
    if (plan.bodyOfOp[static_cast<std::size_t>(run.op)] != plannedBody) continue;
    for (std::int32_t p = run.first; p < run.end; ++p) {
      if (cells.cells()[static_cast<std::size_t>(p)] >= 0) liveAt.push_back(born.size());
      born.push_back(GridMapping::cellOf(cells.bornCell(p)));
    }
  }
  const std::vector<int> design = connectedComponents26(born);
  const int nDesign = *std::max_element(design.begin(), design.end()) + 1;
  std::vector<int> compOf(static_cast<std::size_t>(nDesign), -1);
  std::vector<bool> broken(static_cast<std::size_t>(nDesign), false);
  for (std::size_t j = 0; j < liveAt.size(); ++j) {
    const auto d = static_cast<std::size_t>(design[liveAt[j]]);
    if (compOf[d] < 0) compOf[d] = comp[j];
    else if (compOf[d] != comp[j]) broken[d] = true;
  }
  std::vector<bool> whole(static_cast<std::size_t>(nComp), false);
  for (std::size_t d = 0; d < compOf.size(); ++d)
    if (compOf[d] >= 0 && !broken[d]) whole[static_cast<std::size_t>(compOf[d])] = true;
  return whole;
}

// The body each particle of `body` goes to (0 = the one keeping the planned name),
// by the rule of splitCutBodies; empty when the body stays one.
std::vector<int> piecesOf(const SketchCells& cells, const BodyPlan& plan, int plannedBody, const BodyRange& body,
                          const Sketch& sk) {
  const std::vector<Vec3i> finalCells(sk.cells.begin() + body.first, sk.cells.begin() + body.first + body.count);
  const std::vector<int> comp = connectedComponents26(finalCells);
  const int nComp = *std::max_element(comp.begin(), comp.end()) + 1;
  if (nComp == 1) return {};
  const std::vector<bool> whole = holdsWholeDesignPiece(cells, plan, plannedBody, comp, nComp);
  // The fragments, largest first (ties: the component whose first cell comes first).
  std::vector<std::int32_t> size(static_cast<std::size_t>(nComp), 0);
  for (int c : comp) ++size[static_cast<std::size_t>(c)];
  std::vector<int> fragments;
  for (int c = 0; c < nComp; ++c)
    if (!whole[static_cast<std::size_t>(c)]) fragments.push_back(c);
  if (fragments.empty()) return {};  // every component holds a whole design piece: one body, as drawn
  std::stable_sort(fragments.begin(), fragments.end(), [&](int a, int b) {
    return size[static_cast<std::size_t>(a)] > size[static_cast<std::size_t>(b)];
  });
  const int first = fragments.size() < static_cast<std::size_t>(nComp) ? 1 : 0;  // 1: body 0 is the whole pieces
  std::vector<int> pieceOfComp(static_cast<std::size_t>(nComp), 0);
  for (std::size_t f = 0; f < fragments.size(); ++f)
    pieceOfComp[static_cast<std::size_t>(fragments[f])] = first + static_cast<int>(f);
  std::vector<int> piece(comp.size());
  for (std::size_t j = 0; j < comp.size(); ++j) piece[j] = pieceOfComp[static_cast<std::size_t>(comp[j])];
  return piece;
}

// Reorders the particles of `body` by piece (stably), keeping M in step.
void groupByPiece(const std::vector<int>& piece, const BodyRange& body, Sketch& sk) {
  const int n = *std::max_element(piece.begin(), piece.end()) + 1;
  std::vector<std::size_t> at(static_cast<std::size_t>(n) + 1, 0);
  for (int p : piece) ++at[static_cast<std::size_t>(p) + 1];
  for (std::size_t p = 1; p < at.size(); ++p) at[p] += at[p - 1];
  const auto first = static_cast<std::size_t>(body.first);
  std::vector<Vec3i> cellsOut(piece.size());
  std::vector<std::int32_t> strokeOut(piece.size());
  std::vector<std::int16_t> materialOut(piece.size());
  for (std::size_t j = 0; j < piece.size(); ++j) {
    const std::size_t k = at[static_cast<std::size_t>(piece[j])]++;
    cellsOut[k] = sk.cells[first + j];
    strokeOut[k] = sk.particles.stroke[first + j];
    materialOut[k] = sk.particles.material[first + j];
  }
  for (std::size_t k = 0; k < piece.size(); ++k) {
    const Vec3i& c = cellsOut[k];
    const Vec3 q = sk.mapping.toWorld(c);  // Eq. 5
    sk.cells[first + k] = c;
    sk.particles.x[first + k] = static_cast<float>(q.x());
    sk.particles.y[first + k] = static_cast<float>(q.y());
    sk.particles.z[first + k] = static_cast<float>(q.z());
    sk.particles.stroke[first + k] = strokeOut[k];
    sk.particles.material[first + k] = materialOut[k];
    sk.grid.set(c, static_cast<std::int32_t>(first + k));
  }
}

}  // namespace

std::vector<CutBody> splitCutBodies(const SketchCells& cells, const BodyPlan& plan, const std::vector<int>& planned,
                                    const StrokeFile& file, Sketch& sk) {
  const std::vector<bool> touched = touchedBodies(cells, plan, planned, sk);
  std::vector<CutBody> cuts;
  std::vector<BodyRange> bodies;
  std::vector<std::string> names;
  std::vector<int> firstOfOld(sk.bodies.size());
  for (std::size_t b = 0; b < sk.bodies.size(); ++b) {
    const BodyRange body = sk.bodies[b];
    firstOfOld[b] = static_cast<int>(bodies.size());
    const std::vector<int> piece = touched[b] ? piecesOf(cells, plan, planned[b], body, sk) : std::vector<int>{};
    if (piece.empty()) {
      bodies.push_back(body);
      names.push_back(sk.bodyNames[b]);
      continue;
    }
    groupByPiece(piece, body, sk);
    std::vector<std::int32_t> count(static_cast<std::size_t>(*std::max_element(piece.begin(), piece.end()) + 1), 0);
    for (int p : piece) ++count[static_cast<std::size_t>(p)];
    int line = 0;
    for (const Operation& op : file.operations)
      if (plan.bodyOfOp[static_cast<std::size_t>(op.id)] == planned[b]) {
        line = op.line;
        break;
      }
    cuts.push_back({static_cast<int>(bodies.size()), static_cast<int>(count.size()), line});
    std::int32_t first = body.first;
    for (std::size_t p = 0; p < count.size(); ++p) {
      BodyRange r;
      r.first = first;
      r.count = count[p];
      r.stroke = sk.particles.stroke[static_cast<std::size_t>(first)];
      r.init = body.init;  // a piece of a cut body starts as the body would have
      bodies.push_back(r);
      names.push_back(p == 0 ? sk.bodyNames[b] : sk.bodyNames[b] + " #" + std::to_string(p + 1));
      first += count[p];
    }
  }
  if (cuts.empty()) return cuts;
  // An operation's body: the first body holding its particles (the first piece of
  // its planned body when it has none left).
  for (auto& sum : sk.operations)
    if (sum.body >= 0) sum.body = firstOfOld[static_cast<std::size_t>(sum.body)];
  for (const CutBody& cut : cuts) {
    std::vector<bool> seen(sk.operations.size(), false);
    for (int b = cut.firstBody; b < cut.firstBody + cut.pieces; ++b) {
      const BodyRange& r = bodies[static_cast<std::size_t>(b)];
      for (std::int32_t i = r.first; i < r.first + r.count; ++i) {
        const auto op = static_cast<std::size_t>(sk.particles.stroke[static_cast<std::size_t>(i)]);
        if (!seen[op]) seen[op] = true, sk.operations[op].body = b;
      }
    }
  }
  sk.bodies = std::move(bodies);
  sk.bodyNames = std::move(names);
  return cuts;
}

}  // namespace physketch::sketch

namespace physketch::sketch {

void checkBodyKinds(const StrokeFile& file, const std::vector<Material>& materials) {
  const double play = file.playTime();
  struct FirstPart {
    int line;
    const Material* material;
  };
  std::map<std::string, FirstPart> first;
  for (int id : file.active) {
    const Operation& op = file.operations[static_cast<std::size_t>(id)];
    if (!createsParticles(op) || op.body.empty() || op.startTime() > play) continue;
    const int m = findMaterial(materials, op.material);
    if (m < 0) continue;
    const Material& mat = materials[static_cast<std::size_t>(m)];
    const auto [it, fresh] = first.emplace(op.body, FirstPart{op.line, &mat});
    if (fresh) continue;
    const Material& other = *it->second.material;
    const std::string here = "material '" + mat.name + "' is kind " + toString(mat.kind);
    const std::string there = "its part at line " + std::to_string(it->second.line) + " is kind " +
                              toString(other.kind) + " (material '" + other.name + "')";
    auto strand = [](const Material& x) { return layoutOf(x.kind) != BodyLayout::kVoxels; };
    if (strand(mat) || strand(other))
      throw InputError(file.path, op.line, "body",
                       "body '" + op.body + "': " + here + " and " + there +
                           ": a rope or a cloth is a body of its own (one chain, one lattice); drop body= or rename it");
    if (mat.kind != other.kind)
      throw InputError(file.path, op.line, "body",
                       "body '" + op.body + "' mixes kinds: " + here + " and " + there +
                           "; a named body is of one kind (rigid parts may mix rigid materials)");
  }
}

std::vector<CutBody> appendStrandBodies(const Strands& strands, const BodyPlan& plan, const StrokeFile& file,
                                        Sketch& sk) {
  std::vector<CutBody> cuts;
  const std::vector<Strands::Piece>& pieces = strands.pieces();
  ParticleArrays& out = sk.particles;
  for (std::size_t k = 0; k < pieces.size();) {
    // The pieces of one operation (its drawn shape and mirror copy) are consecutive.
    const int op = pieces[k].op;
    OperationSummary& sum = sk.operations[static_cast<std::size_t>(op)];
    const std::string& name = plan.names[static_cast<std::size_t>(plan.bodyOfOp[static_cast<std::size_t>(op)])];
    const int firstBody = static_cast<int>(sk.bodies.size());
    bool cut = false;
    for (; k < pieces.size() && pieces[k].op == op; ++k) {
      const Strands::Piece& piece = pieces[k];
      const std::vector<StrandBody> made = bodiesOf(strands, piece);
      cut = cut || made.size() > 1;
      for (const StrandBody& b : made) {
        BodyRange r;
        r.first = static_cast<std::int32_t>(out.size());
        r.count = b.rows * b.cols;
        r.stroke = op;
        r.init = plan.init[static_cast<std::size_t>(plan.bodyOfOp[static_cast<std::size_t>(op)])];
        r.layout = b.layout;
        r.rows = b.layout == BodyLayout::kLattice ? b.rows : 0;
        r.cols = b.layout == BodyLayout::kLattice ? b.cols : 0;
        r.radius = piece.radius;
        for (std::int32_t row = 0; row < b.rows; ++row)
          for (std::int32_t col = 0; col < b.cols; ++col) {
            const std::int32_t node = b.layout == BodyLayout::kLattice
                                          ? piece.first + (b.row0 + row) * piece.cols + b.col0 + col
                                          : b.firstNode + row;
            const Vec3& q = strands.positions()[static_cast<std::size_t>(node)];
            out.push(static_cast<float>(q.x()), static_cast<float>(q.y()), static_cast<float>(q.z()), op,
                     piece.material);
            // The cell of the position as stored (float), which is what the solver and the runtime see.
            sk.cells.push_back(sk.mapping.discretize(Vec3(out.x.back(), out.y.back(), out.z.back())));
            if (strands.alive(node)) ++sum.remaining;
            else out.phase.back() |= phase::kRemoved;  // a hole in a cut cloth
          }
        const int n = static_cast<int>(sk.bodies.size()) - firstBody;
        sk.bodies.push_back(r);
        sk.bodyNames.push_back(n == 0 ? name : name + " #" + std::to_string(n + 1));
      }
    }
    const int made = static_cast<int>(sk.bodies.size()) - firstBody;
    sum.body = made > 0 ? firstBody : -1;
    if (cut) cuts.push_back({firstBody, made, file.operations[static_cast<std::size_t>(op)].line});
  }
  return cuts;
}

namespace {

// out[j] = in[from[j]].
template <class T>
void gather(std::vector<T>& v, const std::vector<std::int32_t>& from) {
  std::vector<T> out(from.size());
  for (std::size_t j = 0; j < from.size(); ++j) out[j] = v[static_cast<std::size_t>(from[j])];
  v = std::move(out);
}

}  // namespace

void orderBodiesAsPlanned(const BodyPlan& plan, std::vector<CutBody>& cuts, Sketch& sk) {
  const std::size_t n = sk.bodies.size();
  // A body's planned body: that of the operation of its first particle (a cut piece's too).
  auto planned = [&](std::size_t b) { return plan.bodyOfOp[static_cast<std::size_t>(sk.bodies[b].stroke)]; };
  std::vector<std::size_t> order(n);
  for (std::size_t b = 0; b < n; ++b) order[b] = b;
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return planned(a) < planned(b); });
  bool same = true;
  for (std::size_t b = 0; b < n; ++b) same = same && order[b] == b;
  if (same) return;
  std::vector<std::int32_t> from;  // per new particle index: its old index
  from.reserve(sk.particles.size());
  std::vector<BodyRange> bodies;
  std::vector<std::string> names;
  std::vector<int> newIndex(n);
  for (std::size_t k = 0; k < n; ++k) {
    BodyRange r = sk.bodies[order[k]];
    newIndex[order[k]] = static_cast<int>(k);
    const std::int32_t first = static_cast<std::int32_t>(from.size());
    for (std::int32_t i = r.first; i < r.first + r.count; ++i) from.push_back(i);
    r.first = first;
    bodies.push_back(r);
    names.push_back(sk.bodyNames[order[k]]);
  }
  ParticleArrays& p = sk.particles;
  gather(p.x, from), gather(p.y, from), gather(p.z, from), gather(p.vx, from), gather(p.vy, from), gather(p.vz, from);
  gather(p.mass, from), gather(p.phase, from), gather(p.stroke, from), gather(p.material, from), gather(sk.cells, from);
  sk.bodies = std::move(bodies);
  sk.bodyNames = std::move(names);
  for (const BodyRange& r : sk.bodies)  // M with the new indices of the voxel particles
    if (r.layout == BodyLayout::kVoxels)
      for (std::int32_t i = r.first; i < r.first + r.count; ++i) sk.grid.set(sk.cells[static_cast<std::size_t>(i)], i);
  for (auto& sum : sk.operations)
    if (sum.body >= 0) sum.body = newIndex[static_cast<std::size_t>(sum.body)];
  for (CutBody& cut : cuts) cut.firstBody = newIndex[static_cast<std::size_t>(cut.firstBody)];
}

}  // namespace physketch::sketch
