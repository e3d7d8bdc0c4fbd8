// From the particles of a replayed sketch to rigid bodies: which operations form a
// body, the compaction that makes every body a contiguous particle range, and the
// cut of a body that a remove or a move broke into pieces (docs/formats.md, "Bodies").
#pragma once

#include <string>
#include <vector>

#include "core/material.h"
#include "sketch/sketch_cells.h"
#include "sketch/strands.h"
#include "sketch/strokes.h"
#include "sketch/voxelize.h"

namespace physketch::sketch {

// The bodies the operations were drawn as: named operations (body=NAME) share one,
// every other create is a body of its own. Bodies are numbered in the order of their
// first operation in the file.
struct BodyPlan {
  std::vector<int> bodyOfOp;       // per operation id; -1 for removes and moves
  std::vector<std::string> names;  // per planned body: NAME, or "stroke N"
  std::vector<bool> named;         // per planned body: from body=NAME
  std::vector<BodyInit> init;      // per planned body: vel=, spin=, fixed of its first operation
                                   // (every part of a named body carries the same: sketch/strokes.h)
};

// How a body starts, from the create options of an operation that made it.
BodyInit bodyInit(const Operation& op);
BodyPlan planBodies(const StrokeFile& file);

// The parts of a named body (body=NAME, operations in effect before play) are of one
// material kind: rigid parts may mix rigid materials, but a rigid part cannot join a
// soft, fluid, rope or cloth one (nor those each other), and a rope or a cloth is a body
// of its own (one chain, one lattice) that no other part can join. Throws InputError
// naming the line of the first part that breaks this and the field 'body'. Operations with
// an unknown material are left to the voxelizer's check.
void checkBodyKinds(const StrokeFile& file, const std::vector<Material>& materials);

// Compacts away removed particles and groups the rest by planned body (in body
// order; in creation order within a body), so every body is a contiguous range;
// writes sk.particles, sk.cells, M with the final indices, sk.bodies, sk.bodyNames,
// and each operation's `remaining` and `body`. Bodies without particles are left out.
// Returns the planned body of each body of sk.bodies.
std::vector<int> compactIntoBodies(const SketchCells& cells, const BodyPlan& plan, Sketch& sk);

// A body that removes or moves before play cut into several bodies.
struct CutBody {
  int firstBody;  // index into sk.bodies of its first piece
  int pieces;     // number of bodies it became
  int line;       // line of its first operation
};

// Splits every body that a remove or a move disconnected. A body's design pieces are
// the 26-connected components of the cells its particles were created in; a piece is
// whole while its remaining particles all lie in one 26-connected component of the
// body's final cells. The final components that hold a whole design piece stay one
// body (named as planned); every other final component (a fragment of a broken
// piece) becomes a body of its own, largest first (ties: the one whose first cell in
// z, y, x order comes first), named "NAME #2", "NAME #3", ...; when no design piece
// is whole, the largest fragment keeps the planned name. The pieces replace the body
// in sk.bodies, in that order, over the same particle range; particles keep their
// creation order within a piece.
// `planned` is what compactIntoBodies returned.
std::vector<CutBody> splitCutBodies(const SketchCells& cells, const BodyPlan& plan, const std::vector<int>& planned,
                                    const StrokeFile& file, Sketch& sk);

// Appends the bodies the ropes and cloths left (sketch/strands.h: bodiesOf) after the voxel
// bodies, in file order (orderBodiesAsPlanned then moves them to their places): their particles to sk.particles (holes of a cut cloth with
// phase::kRemoved) and sk.cells (the cell each position falls in; not in M), a BodyRange
// each with its layout and radius, and a name: an operation's first body has the planned
// name, its further ones (the mirror copy, the pieces of a cut rope) "NAME #2", ...
// Sets each such operation's `remaining` and `body`. Returns the operations whose rope a
// remove cut into more chains than it was drawn as, for lint.
std::vector<CutBody> appendStrandBodies(const Strands& strands, const BodyPlan& plan, const StrokeFile& file,
                                        Sketch& sk);

// Puts the bodies in the order of their planned bodies (stably: a cut body's pieces stay
// together, in their order), so rope and cloth bodies, appended last, take their place in
// file order; moves the particles with them and keeps M, the operations' bodies and `cuts`
// in step. Does nothing (no copy) when they are in order already.
void orderBodiesAsPlanned(const BodyPlan& plan, std::vector<CutBody>& cuts, Sketch& sk);

}  // namespace physketch::sketch
