// The material parameter table: every key a `material` record may set, per kind, with its
// unit, default, range and the solver that uses it. The scene parser validates and fills
// defaults from it, and docs/formats.md reproduces it ("Material parameters"); a unit test
// compares the two, so they cannot drift.
#pragma once

#include <string>
#include <vector>

#include "core/material.h"
#include "core/records.h"

namespace physketch {

enum class ParamType { kNumber, kColor, kChoice };

// Bit set of solvers that use a parameter.
enum SolverSet : unsigned { kUsedByPbd = 1u, kUsedByMpm = 2u, kUsedByBoth = 3u };
bool usedBy(unsigned solvers, SolverKind solver);
const char* toString(unsigned solvers);  // "pbd", "mpm", "both"

struct ParamRange {
  double lo = 0.0, hi = 0.0;
  bool loOpen = false, hiOpen = false;
  bool contains(double v) const;
  std::string text() const;  // "(0, 0.5)", "[0, 2]"
};

struct ParamSpec {
  const char* kind;   // a kind name, or "all" (every kind; a kind's own row overrides it)
  const char* key;
  ParamType type;
  const char* unit;   // "-" for dimensionless
  double def;         // kNumber: default; NaN with defaultFrom == nullptr: none
  const char* defaultFrom;  // non-null: the default is this other key's value
  ParamRange range;   // kNumber and each kColor channel
  const char* choices;  // kChoice: "a|b|c"; the first is the default unless def is NaN
  unsigned solvers;   // SolverSet
  double& (*field)(Material&);  // kNumber: where the value lives
};

// Rows in documentation order: "all" first, then kinds in enum order.
const std::vector<ParamSpec>& materialParams();
// The row for `key` of `kind`: the kind's own row, else the "all" row, else nullptr.
const ParamSpec* findParam(MaterialKind kind, const std::string& key);
// Kinds that have a row for `key` (own or "all"), e.g. "soft, elastic, sand" for messages.
std::string kindsWithParam(const std::string& key);

// A material of `kind` with the table's defaults.
Material makeMaterial(MaterialKind kind, const std::string& name = "");

// Parses a `material` record (docs/formats.md): `material NAME KIND key=value...`, or the
// short form of the first release, `material NAME KIND DENSITY FRICTION R G B`
// (static = dynamic friction = FRICTION). Throws InputError naming file:line:field.
Material parseMaterialRecord(const RecordFile& file, const Record& record);

// The material as `solver` runs it (solverModel): kind replaced by what runs, parameters
// carried over. rigid under mpm: elastic, E = 5e6 Pa (hard preset), the elastic defaults;
// soft under mpm: elastic with its E; elastic under pbd: soft with its E and the soft
// cluster defaults. Precondition: solverModel(m.kind, solver).simulated (checkSupport).
Material asRunBy(const Material& m, SolverKind solver);

}  // namespace physketch
