// Line-oriented, versioned text records: the common grammar of the stroke file
// and the scene file (docs/formats.md).
//
//   # comment until end of line
//   <magic> <version>            first record of the file
//   keyword field field ...      one record per line, fields split on spaces and tabs
//
// Lines end in LF or CR LF; a UTF-8 byte-order mark at the start is skipped; any other
// control character (a lone CR included) is an error naming its line.
// Every check reports file:line:field through InputError. Readers are bounded:
// a line over kMaxLineBytes or a file over kMaxFileBytes is an error, never an
// allocation of whatever size the file claims.
#pragma once

#include <cstdint>
#include <initializer_list>
#include <string>
#include <vector>

#include "core/math.h"

namespace physketch {

struct Record {
  int line = 0;                     // 1-based line number in the file
  std::vector<std::string> tokens;  // tokens[0] is the keyword
  const std::string& keyword() const { return tokens.front(); }
};

struct RecordFile {
  std::string path;  // as given by the user (used in messages)
  int version = 0;
  std::vector<Record> records;  // without the header record
};

constexpr std::size_t kMaxLineBytes = 4096;
constexpr std::uint64_t kMaxFileBytes = 256ull << 20;

// Reads and tokenizes `path`. The first record must be `magic version` with
// 1 <= version <= maxVersion.
RecordFile readRecordFile(const std::string& path, const std::string& magic, int maxVersion);
// Same, from text already in memory (tests, fuzzing). `path` is used for messages.
RecordFile parseRecordText(const std::string& text, const std::string& path, const std::string& magic,
                           int maxVersion);

// An option field of a record (after its positional fields): `key=value`, or a bare
// flag such as `fixed` (flag = true, value empty).
struct RecordOption {
  std::string key, value;
  bool flag = false;
};

// Splits a record into its positional tokens (kept in `positional`) and its options:
// `key=value` fields and bare flags (a word listed in `flags`, after the keyword).
// Options must come after all positional fields, each key must be one of `allowed`
// (or `flags`) and appear once; otherwise InputError names it. A flag is therefore a
// reserved word in the positional fields of the records that take it.
std::vector<RecordOption> splitOptions(const RecordFile& file, const Record& record, Record& positional,
                                       std::initializer_list<const char*> allowed,
                                       std::initializer_list<const char*> flags = {});
std::vector<RecordOption> splitOptions(const RecordFile& file, const Record& record, Record& positional,
                                       const std::vector<std::string>& allowed,
                                       const std::vector<std::string>& flags = {});

// Parses a comma-separated list of exactly `n` finite numbers (an option value such
// as `axis=0,1,0`). Throws InputError naming `field`.
std::vector<double> parseNumberList(const RecordFile& file, int line, const std::string& field,
                                    const std::string& text, std::size_t n);

// `x,y,z` with |v| <= maxNorm (an option such as `vel=0,1,0`). Throws InputError naming `field`.
Vec3 parseVec3(const RecordFile& file, int line, const std::string& field, const std::string& text,
               double maxNorm);
// `ax,ay,az,deg`: a rotation of deg degrees about the axis (need not be unit, not zero).
Mat3 parseRotation(const RecordFile& file, int line, const std::string& field, const std::string& text);

// Reads the fields of one record against a schema of field names (the keyword
// is not a field). Checks the field count up front: too few names the first
// missing field, too many names the extra one.
class FieldReader {
 public:
  FieldReader(const RecordFile& file, const Record& record, std::initializer_list<const char*> names,
              std::size_t minFields = SIZE_MAX);
  FieldReader(const RecordFile& file, const Record& record, std::vector<std::string> names,
              std::size_t minFields = SIZE_MAX);

  std::size_t count() const { return record_.tokens.size() - 1; }  // fields present
  const std::string& word(std::size_t i) const;
  double number(std::size_t i) const;                    // finite
  double positive(std::size_t i) const;                  // finite, > 0
  double nonNegative(std::size_t i) const;               // finite, >= 0
  double inRange(std::size_t i, double lo, double hi) const;  // finite, lo <= v <= hi
  long integer(std::size_t i, long lo, long hi) const;
  [[noreturn]] void fail(std::size_t i, const std::string& what) const;
  // An error about the record as a whole (misplaced, given twice): names the field 'record'.
  [[noreturn]] void failLine(const std::string& what) const;
  const std::string& name(std::size_t i) const { return names_.at(i); }
  int line() const { return record_.line; }

 private:
  const RecordFile& file_;
  const Record& record_;
  std::vector<std::string> names_;
};

}  // namespace physketch
