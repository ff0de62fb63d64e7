#include "framework/io/line_error.h"

#include "framework/core/error.h"

#include <gtest/gtest.h>

#include <string>
#include <string_view>

namespace soma {
namespace {

TEST(ForMessage, KeepsPrintableAsciiAsItIs) {
  EXPECT_EQ(ForMessage("POINT:LABELS"), "POINT:LABELS");
  EXPECT_EQ(ForMessage(""), "");
}

TEST(ForMessage, EscapesControlAndNonAsciiBytes) {
  using namespace std::string_view_literals;
  EXPECT_EQ(ForMessage("a\nb\tc\x7f"), "a\\x0ab\\x09c\\x7f");
  EXPECT_EQ(ForMessage("\xc3\xa9"), "\\xc3\\xa9");
  EXPECT_EQ(ForMessage("x\0y"sv), "x\\x00y");
}

TEST(ForMessage, CutsLongTextAtTheLimit) {
  const std::string sixty(60, 'a');
  EXPECT_EQ(ForMessage(sixty), sixty);
  EXPECT_EQ(ForMessage(sixty + "b"), sixty + "...");
  EXPECT_EQ(ForMessage("abcdef", 3), "abc...");
}

TEST(ThrowAtLine, NamesTheFileAndLine) {
  try {
    ThrowAtLine("walk.bvh", 12, "expected '{}', got '{}'", "OFFSET", "OFSET");
    FAIL() << "no throw";
  } catch (const IoError& e) {
    EXPECT_STREQ(e.what(), "walk.bvh:12: expected 'OFFSET', got 'OFSET'");
  }
}

}  // namespace
}  // namespace soma
