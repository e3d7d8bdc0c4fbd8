// The record grammar shared by the stroke and scene files: every error names file:line:field.
#include <gtest/gtest.h>

#include <string>

#include "core/error.h"
#include "core/records.h"

using namespace physketch;

namespace {

// Runs fn, expects an InputError, returns it.
template <class F>
InputError expectInputError(F&& fn) {
  try {
    fn();
  } catch (const InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected InputError";
  return InputError("", 0, "", "");
}

}  // namespace

TEST(Records, SkipsCommentsAndBlankLinesAndKeepsLineNumbers) {
  const auto f = parseRecordText("# c\nmagic 1\n\n  a 1 2 # trailing\n\tb\n", "x.txt", "magic", 1);
  ASSERT_EQ(f.records.size(), 2u);
  EXPECT_EQ(f.records[0].line, 4);
  EXPECT_EQ(f.records[0].tokens, (std::vector<std::string>{"a", "1", "2"}));
  EXPECT_EQ(f.records[1].line, 5);
  EXPECT_EQ(f.version, 1);
}

TEST(Records, HeaderErrors) {
  EXPECT_EQ(expectInputError([] { parseRecordText("", "e.txt", "magic", 1); }).line(), 1);
  auto e = expectInputError([] { parseRecordText("other 1\n", "e.txt", "magic", 1); });
  EXPECT_EQ(e.line(), 1);
  e = expectInputError([] { parseRecordText("\nmagic 2\n", "e.txt", "magic", 1); });
  EXPECT_EQ(e.line(), 2);
  EXPECT_EQ(e.field(), "version");
}

TEST(Records, RejectsBinaryAndOverlongLines) {
  std::string bin = "magic 1\nok 1\nbad \x01\x02\n";
  auto e = expectInputError([&] { parseRecordText(bin, "b.txt", "magic", 1); });
  EXPECT_EQ(e.line(), 3);
  EXPECT_NE(std::string(e.what()).find("UTF-8"), std::string::npos);
  std::string invalidUtf8 = "magic 1\nx \xc3\x28\n";
  EXPECT_EQ(expectInputError([&] { parseRecordText(invalidUtf8, "u.txt", "magic", 1); }).line(), 2);
  // Valid UTF-8 in a comment is fine.
  EXPECT_NO_THROW(parseRecordText("magic 1\n# caf\xc3\xa9\n", "u.txt", "magic", 1));
  std::string longLine = "magic 1\nx " + std::string(kMaxLineBytes + 10, 'a') + "\n";
  e = expectInputError([&] { parseRecordText(longLine, "l.txt", "magic", 1); });
  EXPECT_EQ(e.line(), 2);
  EXPECT_NE(std::string(e.what()).find("longer than"), std::string::npos);
}

TEST(Records, FieldReaderChecksCountAndValues) {
  const auto f = parseRecordText("magic 1\nrec 1.5 nan -2 x 7\nshort 1\n", "f.txt", "magic", 1);
  const Record& r = f.records[0];
  FieldReader fr(f, r, {"a", "b", "c", "d", "e"});
  EXPECT_DOUBLE_EQ(fr.number(0), 1.5);
  auto e = expectInputError([&] { fr.number(1); });
  EXPECT_EQ(e.field(), "b");
  EXPECT_EQ(e.line(), 2);
  EXPECT_EQ(std::string(e.what()).rfind("f.txt:2: field 'b':", 0), 0u) << e.what();
  EXPECT_EQ(expectInputError([&] { fr.positive(2); }).field(), "c");
  EXPECT_EQ(expectInputError([&] { fr.number(3); }).field(), "d");
  EXPECT_EQ(fr.integer(4, 0, 10), 7);
  EXPECT_EQ(expectInputError([&] { fr.integer(4, 0, 5); }).field(), "e");
  // Missing field names the first missing one; extra field names the token.
  e = expectInputError([&] { FieldReader(f, f.records[1], {"p", "q"}); });
  EXPECT_EQ(e.field(), "q");
  e = expectInputError([&] { FieldReader(f, r, {"a", "b"}); });
  EXPECT_NE(std::string(e.what()).find("extra field '-2'"), std::string::npos) << e.what();
}

TEST(Records, MissingFileIsAnInputError) {
  auto e = expectInputError([] { readRecordFile("/nonexistent/dir/x.strokes", "magic", 1); });
  EXPECT_EQ(e.file(), "/nonexistent/dir/x.strokes");
}

// --- Text conventions and errors that name a field (docs/formats.md, "Text conventions") ---

TEST(Records, EveryTextErrorNamesALineAndAField) {
  // Binary data: the line and the pseudo-field 'text'.
  auto e = expectInputError([] { parseRecordText("magic 1\nok\n\x7f" "ELF\x02\x01\n", "b.bin", "magic", 1); });
  EXPECT_EQ(e.line(), 3);
  EXPECT_EQ(e.field(), "text") << e.what();
  // A line of kMaxLineBytes + 1 bytes is refused, one of kMaxLineBytes is not.
  const std::string at = "x " + std::string(kMaxLineBytes - 2, 'a');
  EXPECT_NO_THROW(parseRecordText("magic 1\n" + at + "\n", "l.txt", "magic", 1));
  e = expectInputError([&] { parseRecordText("magic 1\n" + at + "a\n", "l.txt", "magic", 1); });
  EXPECT_EQ(e.line(), 2);
  EXPECT_EQ(e.field(), "text") << e.what();
  // An empty file (or one of comments only) names line 1 and the header's first field.
  for (const char* text : {"", "# only a comment\n\n"}) {
    e = expectInputError([&] { parseRecordText(text, "e.txt", "magic", 1); });
    EXPECT_EQ(e.line(), 1);
    EXPECT_EQ(e.field(), "format");
    EXPECT_NE(std::string(e.what()).find("empty file"), std::string::npos) << e.what();
  }
  e = expectInputError([] { parseRecordText("other 1\n", "e.txt", "magic", 1); });
  EXPECT_EQ(e.field(), "format");
  // An extra field is named by its position.
  const auto f = parseRecordText("magic 1\nrec 1 2 3\n", "f.txt", "magic", 1);
  e = expectInputError([&] { FieldReader(f, f.records[0], {"a", "b"}); });
  EXPECT_EQ(e.field(), "#3") << e.what();
}

TEST(Records, AcceptsAByteOrderMarkCrlfAndTabs) {
  const auto f = parseRecordText("\xEF\xBB\xBFmagic 1\r\na\t1  2\r\n\tb\r\n", "w.txt", "magic", 1);
  ASSERT_EQ(f.records.size(), 2u);
  EXPECT_EQ(f.records[0].tokens, (std::vector<std::string>{"a", "1", "2"}));
  EXPECT_EQ(f.records[1].tokens, (std::vector<std::string>{"b"}));
  // CRLF does not count towards the line limit.
  const std::string full = "x " + std::string(kMaxLineBytes - 2, 'a');
  EXPECT_NO_THROW(parseRecordText("magic 1\r\n" + full + "\r\n", "l.txt", "magic", 1));
  // A byte-order mark anywhere else is not skipped.
  EXPECT_THROW(parseRecordText("magic 1\n\xEF\xBB\xBFrec\n", "w.txt", "magic", 1), InputError);
}

TEST(Records, ALoneCarriageReturnIsAnErrorNamingItsLine) {
  for (const char* text : {"magic 1\na 1\rb 2\n", "magic 1\na 1\r\r\n", "magic 1\na 1\r"}) {
    auto e = expectInputError([&] { parseRecordText(text, "cr.txt", "magic", 1); });
    EXPECT_EQ(e.line(), 2) << text;
    EXPECT_EQ(e.field(), "text");
    EXPECT_NE(std::string(e.what()).find("carriage return"), std::string::npos) << e.what();
  }
}

TEST(Records, SplitOptionsTakesBareFlagsAfterThePositionalFields) {
  const auto f = parseRecordText("magic 1\nr a b k=1 fixed\nr a fixed b\nr a fixed fixed\nr a fixed=1\nr a hold\n",
                                 "o.txt", "magic", 1);
  Record pos;
  auto opts = splitOptions(f, f.records[0], pos, {"k"}, {"fixed"});
  EXPECT_EQ(pos.tokens, (std::vector<std::string>{"r", "a", "b"}));
  ASSERT_EQ(opts.size(), 2u);
  EXPECT_EQ(opts[1].key, "fixed");
  EXPECT_TRUE(opts[1].flag);
  EXPECT_FALSE(opts[0].flag);
  auto e = expectInputError([&] { splitOptions(f, f.records[1], pos, {"k"}, {"fixed"}); });
  EXPECT_EQ(e.field(), "fixed");  // a positional field after a flag
  EXPECT_EQ(expectInputError([&] { splitOptions(f, f.records[2], pos, {"k"}, {"fixed"}); }).field(), "fixed");
  e = expectInputError([&] { splitOptions(f, f.records[3], pos, {"k"}, {"fixed"}); });
  EXPECT_EQ(e.field(), "fixed");
  EXPECT_NE(std::string(e.what()).find("flag"), std::string::npos) << e.what();
  // A word that is not a flag stays positional.
  opts = splitOptions(f, f.records[4], pos, {"k"}, {"fixed"});
  EXPECT_EQ(pos.tokens.size(), 3u);
  EXPECT_TRUE(opts.empty());
}
