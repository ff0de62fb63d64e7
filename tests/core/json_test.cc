#include "framework/core/json.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

namespace soma {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::Not;
using ::testing::ThrowsMessage;

std::string ErrorOf(std::string_view text) {
  try {
    ParseJson(text, "doc.json");
  } catch (const IoError& e) {
    return e.what();
  }
  return "";
}

TEST(Json, ParsesScalarsArraysAndObjects) {
  const Json v = ParseJson(
      R"({"a": 1, "b": [true, false, null], "c": {"d": -2.5e-3, "e": "x"}, "f": []})");
  ASSERT_TRUE(v.is_object());
  EXPECT_EQ(v.size(), 4u);
  EXPECT_EQ(JsonInt(*JsonFind(v, "a")), 1);
  EXPECT_TRUE(JsonIsInteger(*JsonFind(v, "a")));
  const auto& b = JsonArray(*JsonFind(v, "b"));
  ASSERT_EQ(b.size(), 3u);
  EXPECT_TRUE(JsonBool(b[0]));
  EXPECT_FALSE(JsonBool(b[1]));
  EXPECT_TRUE(b[2].is_null());
  EXPECT_DOUBLE_EQ(JsonNumber(*JsonFind(*JsonFind(v, "c"), "d")), -2.5e-3);
  EXPECT_EQ(JsonString(*JsonFind(*JsonFind(v, "c"), "e")), "x");
  EXPECT_TRUE(JsonFind(v, "f")->is_array());
  EXPECT_EQ(JsonFind(v, "zzz"), nullptr);
  EXPECT_EQ(JsonFind(b[0], "a"), nullptr);  // not an object
}

TEST(Json, StringEscapesAndUnicode) {
  const Json v = ParseJson(R"("q\"b\\s\/n\nt\tu\u00e9\ud83d\ude00")");
  EXPECT_EQ(JsonString(v), "q\"b\\s/n\nt\tu\xc3\xa9\xf0\x9f\x98\x80");
  // Round trip through the writer (control characters escaped, UTF-8 raw).
  const Json w(std::string("a\"b\\c\n\x01\xc3\xa9"));
  EXPECT_EQ(WriteJson(w),
            R"("a\"b\\c\n\u0001)"
            "\xc3\xa9\"");
  EXPECT_EQ(ParseJson(WriteJson(w)), w);
  // Invalid UTF-8 cannot be written.
  EXPECT_THAT([] { WriteJson(Json(std::string("bad \xff byte"))); },
              ThrowsMessage<IoError>(HasSubstr("Cannot write JSON")));
}

TEST(Json, WriterSortsKeysIndentsAndFormatsNumbers) {
  Json v = Json::object();
  v["zeta"] = 3;
  v["alpha"] = Json::array({0.0095, -7, 1e21, 0.0});
  v["mid"] = Json::object();
  EXPECT_EQ(WriteJson(v, 2),
            "{\n  \"alpha\": [\n    0.0095,\n    -7,\n    1e+21,\n    0.0\n"
            "  ],\n  \"mid\": {},\n  \"zeta\": 3\n}");
  EXPECT_EQ(WriteJson(v, 0),
            R"({"alpha":[0.0095,-7,1e+21,0.0],"mid":{},"zeta":3})");
  EXPECT_EQ(ParseJson(WriteJson(v)), v);
}

TEST(Json, RoundTripsDoublesExactly) {
  for (const double x :
       {0.1, 1.0 / 3.0, -1e-300, 123456789.123456789, 2.5e-7}) {
    EXPECT_EQ(JsonNumber(ParseJson(WriteJson(Json(x)))), x);
  }
}

TEST(Json, ReportsFileLineAndColumnOnOneLine) {
  const std::string missing_colon = ErrorOf("{\n  \"a\": 1,\n  \"b\" 2\n}");
  EXPECT_THAT(missing_colon, HasSubstr("doc.json:3:7: "));
  EXPECT_THAT(missing_colon, Not(HasSubstr("json.exception")));
  EXPECT_THAT(missing_colon, Not(HasSubstr("\n")));
  EXPECT_THAT(ErrorOf("[1, 2,]"), HasSubstr("doc.json:1:7: "));
}

TEST(Json, RejectsMalformedInput) {
  for (const char* bad : {"",
                          "{",
                          "[1 2]",
                          "{\"a\" 1}",
                          "{\"a\": 1,}",
                          "01",
                          "1.",
                          "-",
                          "+1",
                          "1e",
                          "tru",
                          "\"unterminated",
                          "\"bad \\x escape\"",
                          "\"\\ud800\"",
                          "{\"a\": 1, \"a\": 2}",
                          "[1] x",
                          "\"tab\there\"",
                          "{1: 2}",
                          "\"bad \xff utf-8\"",
                          "[NaN, Infinity]"}) {
    EXPECT_THAT([&] { ParseJson(bad, "doc.json"); },
                ThrowsMessage<IoError>(HasSubstr("doc.json")))
        << bad;
  }
  EXPECT_THAT(ErrorOf("{\"a\": 1, \"a\": 2}"),
              HasSubstr("doc.json: duplicate key \"a\""));
  // The same key in different objects is fine.
  EXPECT_NO_THROW(ParseJson(R"({"a": {"a": 1}, "b": {"a": 2}})"));
}

TEST(Json, ReadJsonFileNamesThePath) {
  const auto path = testing::CreateTestDir() / "broken.json";
  WriteFileAtomic(path, "{\"markersets\": [}\n");
  EXPECT_THAT([&] { ReadJsonFile(path); },
              ThrowsMessage<IoError>(HasSubstr(path.string() + ":1:17: ")));
  EXPECT_THAT([&] { ReadJsonFile(path.string() + ".missing"); },
              ThrowsMessage<IoError>(HasSubstr(".missing")));
}

TEST(Json, DepthLimit) {
  std::string deep(600, '[');
  deep += std::string(600, ']');
  EXPECT_THAT([&] { ParseJson(deep, "deep.json"); },
              ThrowsMessage<IoError>(HasSubstr("deep.json: nesting deeper")));
  std::string ok(100, '[');
  ok += std::string(100, ']');
  EXPECT_NO_THROW(ParseJson(ok));
}

TEST(Json, NonFiniteNumbersAreNotWritten) {
  for (const double x : {std::numeric_limits<double>::quiet_NaN(),
                         std::numeric_limits<double>::infinity()}) {
    Json v = Json::object();
    v["deep"] = Json::array({1, Json::object({{"x", x}})});
    EXPECT_THAT([&] { WriteJson(v); },
                ThrowsMessage<IoError>(HasSubstr("only finite numbers")));
  }
}

TEST(Json, TypeMismatchThrows) {
  const Json v = ParseJson(R"({"a": 1.5, "b": 2.0, "c": "s"})");
  EXPECT_THAT([&] { JsonArray(v); },
              ThrowsMessage<IoError>(
                  HasSubstr("JSON type mismatch: expected array, got object")));
  EXPECT_THROW(JsonString(*JsonFind(v, "a")), IoError);
  EXPECT_THROW(JsonInt(*JsonFind(v, "a")), IoError);  // not integral
  EXPECT_THROW(JsonNumber(*JsonFind(v, "c")), IoError);
  EXPECT_THROW(JsonBool(*JsonFind(v, "c")), IoError);
  EXPECT_THROW(JsonObject(*JsonFind(v, "c")), IoError);
  EXPECT_FALSE(JsonIsInteger(*JsonFind(v, "a")));
  EXPECT_TRUE(JsonIsInteger(*JsonFind(v, "b")));
  EXPECT_EQ(JsonInt(*JsonFind(v, "b")), 2);
}

TEST(Json, SkipsByteOrderMark) {
  EXPECT_EQ(JsonInt(JsonArray(ParseJson("\xEF\xBB\xBF[1]"))[0]), 1);
}

}  // namespace
}  // namespace soma
