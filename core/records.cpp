#include "core/records.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "core/error.h"

namespace physketch {
namespace {

// True when s is well-formed UTF-8 without control characters other than tab/CR.
bool isCleanUtf8(const std::string& s) {
  const auto* p = reinterpret_cast<const unsigned char*>(s.data());
  const std::size_t n = s.size();
  std::size_t i = 0;
  while (i < n) {
    const unsigned char c = p[i];
    if (c < 0x80) {
      if ((c < 0x20 && c != '\t' && c != '\r') || c == 0x7f) return false;
      ++i;
      continue;
    }
    std::size_t extra;
    if (c >= 0xc2 && c <= 0xdf) extra = 1;
    else if (c >= 0xe0 && c <= 0xef) extra = 2;
    else if (c >= 0xf0 && c <= 0xf4) extra = 3;
    else return false;  // continuation byte or overlong/out-of-range lead byte
    if (n - i <= extra) return false;
    for (std::size_t k = 1; k <= extra; ++k)
      if ((p[i + k] & 0xc0) != 0x80) return false;
    i += extra + 1;
  }
  return true;
}

void tokenize(const std::string& line, std::vector<std::string>& out) {
  out.clear();
  std::size_t i = 0;
  const std::size_t n = line.size();
  while (i < n) {
    while (i < n && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r')) ++i;
    if (i >= n || line[i] == '#') break;
    std::size_t j = i;
    while (j < n && line[j] != ' ' && line[j] != '\t' && line[j] != '\r' && line[j] != '#') ++j;
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

class StreamLines final : public LineSource {
 public:
  explicit StreamLines(std::istream& in) : in_(in) {}
  bool next(std::string& line, bool& tooLong) override {
    line.clear();
    tooLong = false;
    if (!in_) return false;
    int c;
    bool any = false;
    while ((c = in_.get()) != EOF) {
      any = true;
      if (c == '\n') return true;
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
    if (tooLong)
      throw InputError(path, lineNo, "", "line longer than " + std::to_string(kMaxLineBytes) + " bytes");
    if (!isCleanUtf8(line))
      throw InputError(path, lineNo, "", "not UTF-8 text (binary data or control characters)");
    tokenize(line, tokens);
    if (tokens.empty()) continue;
    if (!haveHeader) {
      if (tokens[0] != magic)
        throw InputError(path, lineNo, "", "expected header '" + magic + " <version>', found '" + tokens[0] + "'");
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
  if (!haveHeader) throw InputError(path, 0, "", "empty file: expected header '" + magic + " <version>'");
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

std::vector<RecordOption> splitOptions(const RecordFile& file, const Record& record, Record& positional,
                                       std::initializer_list<const char*> allowed) {
  std::vector<RecordOption> options;
  positional.line = record.line;
  positional.tokens.clear();
  for (const std::string& tok : record.tokens) {
    const auto eq = tok.find('=');
    if (eq == std::string::npos || positional.tokens.empty()) {
      if (!options.empty())
        throw InputError(file.path, record.line, options.back().key,
                         "positional field '" + tok + "' after option '" + options.back().key + "='");
      positional.tokens.push_back(tok);
      continue;
    }
    RecordOption o{tok.substr(0, eq), tok.substr(eq + 1)};
    bool known = false;
    std::string list;
    for (const char* a : allowed) {
      known = known || o.key == a;
      list += (list.empty() ? "" : ", ") + std::string(a);
    }
    if (!known)
      throw InputError(file.path, record.line, o.key,
                       "unknown option '" + o.key + "' (" + record.keyword() + " takes: " +
                           (list.empty() ? std::string("none") : list) + ")");
    for (const auto& prev : options)
      if (prev.key == o.key) throw InputError(file.path, record.line, o.key, "option given twice");
    if (o.value.empty()) throw InputError(file.path, record.line, o.key, "option has no value");
    options.push_back(std::move(o));
  }
  return options;
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
    throw InputError(file_.path, record_.line, "",
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

void FieldReader::failLine(const std::string& what) const { throw InputError(file_.path, record_.line, "", what); }

}  // namespace physketch
