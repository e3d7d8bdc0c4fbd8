#include "core/records.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "core/error.h"

namespace physketch {
namespace {

constexpr std::size_t kClean = std::string::npos;

// Offset of the first byte that is not well-formed UTF-8 text, or kClean. Tab is the only
// control character allowed (a CR of a CR LF line end is removed before this check).
std::size_t firstBadByte(const std::string& s) {
  const auto* p = reinterpret_cast<const unsigned char*>(s.data());
  const std::size_t n = s.size();
  std::size_t i = 0;
  while (i < n) {
    const unsigned char c = p[i];
    if (c < 0x80) {
      if ((c < 0x20 && c != '\t') || c == 0x7f) return i;
      ++i;
      continue;
    }
    std::size_t extra;
    if (c >= 0xc2 && c <= 0xdf) extra = 1;
    else if (c >= 0xe0 && c <= 0xef) extra = 2;
    else if (c >= 0xf0 && c <= 0xf4) extra = 3;
    else return i;  // continuation byte or overlong/out-of-range lead byte
    if (n - i <= extra) return i;
    for (std::size_t k = 1; k <= extra; ++k)
      if ((p[i + k] & 0xc0) != 0x80) return i;
    i += extra + 1;
  }
  return kClean;
}

// Fields are separated by spaces and tabs; '#' starts a comment.
void tokenize(const std::string& line, std::vector<std::string>& out) {
  out.clear();
  std::size_t i = 0;
  const std::size_t n = line.size();
  while (i < n) {
    while (i < n && (line[i] == ' ' || line[i] == '\t')) ++i;
    if (i >= n || line[i] == '#') break;
    std::size_t j = i;
    while (j < n && line[j] != ' ' && line[j] != '\t' && line[j] != '#') ++j;
    out.emplace_back(line, i, j - i);
    i = j;
  }
}

class LineSource {
 public:
  virtual ~LineSource() = default;
  // Returns false at end of input. Sets tooLong when the line exceeded kMaxLineBytes.
  virtual bool next(std::string& line, bool& tooLong) = 0;
};

// Lines end in LF or CR LF (the CR is dropped); a UTF-8 byte-order mark at the very start
// of the input is skipped. Any other CR stays in the line, where the caller reports it.
class StreamLines final : public LineSource {
 public:
  explicit StreamLines(std::istream& in) : in_(in) {}
  bool next(std::string& line, bool& tooLong) override {
    line.clear();
    tooLong = false;
    if (!in_) return false;
    if (atStart_) {
      atStart_ = false;
      static const char kBom[] = "\xEF\xBB\xBF";
      int k = 0;
      while (k < 3 && in_.peek() == static_cast<unsigned char>(kBom[k])) {
        in_.get();
        ++k;
      }
      // A partial mark is data: put its bytes into the line, where the UTF-8 check sees them.
      line.assign(kBom, static_cast<std::size_t>(k < 3 ? k : 0));
    }
    int c;
    bool any = !line.empty();
    while ((c = in_.get()) != EOF) {
      any = true;
      if (c == '\n') return true;
      if (c == '\r' && in_.peek() == '\n') {
        in_.get();
        return true;
      }
      if (line.size() >= kMaxLineBytes) {
        tooLong = true;  // stop reading here: the caller reports and aborts
        return true;
      }
      line.push_back(static_cast<char>(c));
    }
    return any;
  }

 private:
  std::istream& in_;
  bool atStart_ = true;
};

RecordFile parseLines(LineSource& src, const std::string& path, const std::string& magic, int maxVersion) {
  RecordFile file;
  file.path = path;
  std::string line;
  bool tooLong = false;
  int lineNo = 0;
  bool haveHeader = false;
  std::vector<std::string> tokens;
  while (src.next(line, tooLong)) {
    ++lineNo;
    // Errors about the bytes of a line name the pseudo-field 'text' (docs/formats.md).
    if (tooLong)
      throw InputError(path, lineNo, "text", "line longer than " + std::to_string(kMaxLineBytes) + " bytes");
    const std::size_t cr = line.find('\r');
    if (cr != std::string::npos)
      throw InputError(path, lineNo, "text",
                       "carriage return (CR) inside the line at byte " + std::to_string(cr + 1) +
                           ": lines end in LF or CR LF");
    const std::size_t bom = line.find("\xEF\xBB\xBF");
    if (bom != std::string::npos)  // invisible in an editor: it would make a word look right and not match
      throw InputError(path, lineNo, "text",
                       "byte-order mark (U+FEFF) at byte " + std::to_string(bom + 1) +
                           ": only the very start of the file may hold one");
    const std::size_t bad = firstBadByte(line);
    if (bad != kClean) {
      char hex[8];
      std::snprintf(hex, sizeof hex, "0x%02x", static_cast<unsigned char>(line[bad]));
      throw InputError(path, lineNo, "text",
                       std::string("not UTF-8 text: byte ") + hex + " at byte " + std::to_string(bad + 1) +
                           " (binary data or a control character)");
    }
    tokenize(line, tokens);
    if (tokens.empty()) continue;
    if (!haveHeader) {
      if (tokens[0] != magic)
        throw InputError(path, lineNo, "format", "expected header '" + magic + " <version>', found '" + tokens[0] + "'");
      if (tokens.size() != 2) throw InputError(path, lineNo, "version", "header needs exactly one version number");
      char* end = nullptr;
      errno = 0;
      long v = std::strtol(tokens[1].c_str(), &end, 10);
      if (errno != 0 || *end != '\0' || v < 1 || v > maxVersion)
        throw InputError(path, lineNo, "version",
                         "unsupported version '" + tokens[1] + "' (this build reads 1.." + std::to_string(maxVersion) + ")");
      file.version = static_cast<int>(v);
      haveHeader = true;
      continue;
    }
    file.records.push_back(Record{lineNo, tokens});
  }
  // Line 1 of an empty file: where the header should be.
  if (!haveHeader)
    throw InputError(path, 1, "format", "empty file (no records): expected header '" + magic + " <version>'");
  return file;
}

}  // namespace

RecordFile readRecordFile(const std::string& path, const std::string& magic, int maxVersion) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, 0, "", "cannot open file");
  in.seekg(0, std::ios::end);
  const auto size = static_cast<std::uint64_t>(in.tellg());
  if (!in) throw InputError(path, 0, "", "cannot read file (is it a directory?)");
  if (size > kMaxFileBytes)
    throw InputError(path, 0, "", "file is " + std::to_string(size) + " bytes; the limit is " +
                                      std::to_string(kMaxFileBytes));
  in.seekg(0, std::ios::beg);
  StreamLines lines(in);
  return parseLines(lines, path, magic, maxVersion);
}

RecordFile parseRecordText(const std::string& text, const std::string& path, const std::string& magic,
                           int maxVersion) {
  std::istringstream in(text);
  StreamLines lines(in);
  return parseLines(lines, path, magic, maxVersion);
}

namespace {

std::string joinNames(const std::vector<std::string>& names) {
  std::string list;
  for (const auto& a : names) list += (list.empty() ? "" : ", ") + a;
  return list.empty() ? std::string("none") : list;
}

bool contains(const std::vector<std::string>& names, const std::string& s) {
  for (const auto& a : names)
    if (a == s) return true;
  return false;
}

}  // namespace

std::vector<RecordOption> splitOptions(const RecordFile& file, const Record& record, Record& positional,
                                       const std::vector<std::string>& allowed, const std::vector<std::string>& flags) {
  std::vector<RecordOption> options;
  positional.line = record.line;
  positional.tokens.clear();
  for (const std::string& tok : record.tokens) {
    const auto eq = tok.find('=');
    const bool isFlag = eq == std::string::npos && !positional.tokens.empty() && contains(flags, tok);
    if (!isFlag && (eq == std::string::npos || positional.tokens.empty())) {
      if (!options.empty())
        throw InputError(file.path, record.line, options.back().key,
                         "positional field '" + tok + "' after " +
                             (options.back().flag ? "flag '" + options.back().key + "'"
                                                  : "option '" + options.back().key + "='"));
      positional.tokens.push_back(tok);
      continue;
    }
    RecordOption o;
    o.flag = isFlag;
    o.key = isFlag ? tok : tok.substr(0, eq);
    if (!isFlag) o.value = tok.substr(eq + 1);
    if (!isFlag && contains(flags, o.key))
      throw InputError(file.path, record.line, o.key, "'" + o.key + "' is a flag: write it without '=' and a value");
    if (!isFlag && !contains(allowed, o.key))
      throw InputError(file.path, record.line, o.key,
                       "unknown option '" + o.key + "' (" + record.keyword() + " takes: " + joinNames(allowed) +
                           (flags.empty() ? "" : "; flags: " + joinNames(flags)) + ")");
    for (const auto& prev : options)
      if (prev.key == o.key)
        throw InputError(file.path, record.line, o.key, std::string(o.flag ? "flag" : "option") + " given twice");
    if (!isFlag && o.value.empty()) throw InputError(file.path, record.line, o.key, "option has no value");
    options.push_back(std::move(o));
  }
  return options;
}

std::vector<RecordOption> splitOptions(const RecordFile& file, const Record& record, Record& positional,
                                       std::initializer_list<const char*> allowed,
                                       std::initializer_list<const char*> flags) {
  return splitOptions(file, record, positional, std::vector<std::string>(allowed.begin(), allowed.end()),
                      std::vector<std::string>(flags.begin(), flags.end()));
}

std::vector<double> parseNumberList(const RecordFile& file, int line, const std::string& field, const std::string& text,
                                    std::size_t n) {
  std::vector<double> out;
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t comma = text.find(',', start);
    const std::string part = text.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    char* end = nullptr;
    errno = 0;
    const double v = std::strtod(part.c_str(), &end);
    if (part.empty() || end == part.c_str() || *end != '\0')
      throw InputError(file.path, line, field, "'" + part + "' is not a number (expected " + std::to_string(n) +
                                                   " comma-separated numbers)");
    if (!std::isfinite(v) || errno == ERANGE) throw InputError(file.path, line, field, "'" + part + "' is not finite");
    out.push_back(v);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  if (out.size() != n)
    throw InputError(file.path, line, field,
                     "expected " + std::to_string(n) + " comma-separated numbers, got " + std::to_string(out.size()));
  return out;
}

Vec3 parseVec3(const RecordFile& file, int line, const std::string& field, const std::string& text,
               double maxNorm) {
  const auto v = parseNumberList(file, line, field, text, 3);
  const Vec3 out(v[0], v[1], v[2]);
  if (!(out.norm() <= maxNorm)) {
    std::ostringstream os;
    os << "magnitude must be <= " << maxNorm << " (got " << out.norm() << ")";
    throw InputError(file.path, line, field, os.str());
  }
  return out;
}

Mat3 parseRotation(const RecordFile& file, int line, const std::string& field, const std::string& text) {
  const auto v = parseNumberList(file, line, field, text, 4);
  const Vec3 axis(v[0], v[1], v[2]);
  if (axis.norm() < 1e-12) throw InputError(file.path, line, field, "rotation axis is zero");
  return Eigen::AngleAxisd(v[3] * M_PI / 180.0, axis.normalized()).toRotationMatrix();
}

FieldReader::FieldReader(const RecordFile& file, const Record& record, std::initializer_list<const char*> names,
                         std::size_t minFields)
    : FieldReader(file, record, std::vector<std::string>(names.begin(), names.end()), minFields) {}

FieldReader::FieldReader(const RecordFile& file, const Record& record, std::vector<std::string> names,
                         std::size_t minFields)
    : file_(file), record_(record), names_(std::move(names)) {
  const std::size_t have = record.tokens.size() - 1;
  const std::size_t need = minFields == SIZE_MAX ? names_.size() : minFields;
  if (have < need) fail(have, "missing (" + record.keyword() + " needs " + std::to_string(need) + " fields)");
  if (have > names_.size())
    throw InputError(file_.path, record_.line, "#" + std::to_string(names_.size() + 1),
                     "extra field '" + record.tokens[names_.size() + 1] + "' (" + record.keyword() + " takes " +
                         std::to_string(names_.size()) + " fields)");
}

const std::string& FieldReader::word(std::size_t i) const { return record_.tokens.at(i + 1); }

double FieldReader::number(std::size_t i) const {
  const std::string& s = word(i);
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || *end != '\0') fail(i, "'" + s + "' is not a number");
  if (!std::isfinite(v) || errno == ERANGE) fail(i, "'" + s + "' is not a finite number");
  return v;
}

double FieldReader::positive(std::size_t i) const {
  const double v = number(i);
  if (!(v > 0)) fail(i, "must be > 0 (got " + word(i) + ")");
  return v;
}

double FieldReader::nonNegative(std::size_t i) const {
  const double v = number(i);
  if (!(v >= 0)) fail(i, "must be >= 0 (got " + word(i) + ")");
  return v;
}

double FieldReader::inRange(std::size_t i, double lo, double hi) const {
  const double v = number(i);
  if (!(v >= lo && v <= hi)) {
    std::ostringstream os;
    os << "must be in [" << lo << ", " << hi << "] (got " << word(i) << ")";
    fail(i, os.str());
  }
  return v;
}

long FieldReader::integer(std::size_t i, long lo, long hi) const {
  const std::string& s = word(i);
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(s.c_str(), &end, 10);
  if (end == s.c_str() || *end != '\0' || errno == ERANGE) fail(i, "'" + s + "' is not an integer");
  if (v < lo || v > hi)
    fail(i, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "] (got " + s + ")");
  return v;
}

void FieldReader::fail(std::size_t i, const std::string& what) const {
  const std::string field = i < names_.size() ? names_[i] : ("#" + std::to_string(i + 1));
  throw InputError(file_.path, record_.line, field, what);
}

void FieldReader::failLine(const std::string& what) const {
  throw InputError(file_.path, record_.line, "record", what);
}

}  // namespace physketch
