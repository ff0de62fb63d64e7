#include "framework/body/json.h"

#include "framework/core/error.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace soma {
namespace {

std::string ErrorOf(std::string_view text) {
  try {
    ParseJson(text, "doc.json");
  } catch (const IoError& e) {
    return e.what();
  }
  return "";
}

TEST(Json, ParsesScalarsArraysAndObjects) {
  const JsonValue v = ParseJson(
      R"({"a": 1, "b": [true, false, null], "c": {"d": -2.5e-3, "e": "x"}, "f": []})");
  ASSERT_TRUE(v.is_object());
  EXPECT_EQ(v.size(), 4u);
  EXPECT_EQ(v.Find("a")->AsInt(), 1);
  EXPECT_TRUE(v.Find("a")->is_integer());
  const auto& b = v.Find("b")->AsArray();
  ASSERT_EQ(b.size(), 3u);
  EXPECT_TRUE(b[0].AsBool());
  EXPECT_FALSE(b[1].AsBool());
  EXPECT_TRUE(b[2].is_null());
  EXPECT_DOUBLE_EQ(v.Find("c")->Find("d")->AsNumber(), -2.5e-3);
  EXPECT_EQ(v.Find("c")->Find("e")->AsString(), "x");
  EXPECT_TRUE(v.Find("f")->is_array());
  EXPECT_EQ(v.Find("zzz"), nullptr);
}

TEST(Json, StringEscapesAndUnicode) {
  const JsonValue v = ParseJson(R"("q\"b\\s\/n\nt\tu\u00e9\ud83d\ude00")");
  EXPECT_EQ(v.AsString(), "q\"b\\s/n\nt\tu\xc3\xa9\xf0\x9f\x98\x80");
  // Round trip through the writer (control characters escaped, UTF-8 raw).
  const JsonValue w(std::string("a\"b\\c\n\x01\xc3\xa9"));
  EXPECT_EQ(WriteJson(w),
            R"("a\"b\\c\n\u0001)"
            "\xc3\xa9\"");
  EXPECT_EQ(ParseJson(WriteJson(w)), w);
}

TEST(Json, WriterSortsKeysIndentsAndFormatsNumbers) {
  JsonValue v = JsonValue::MakeObject();
  v.Set("zeta", JsonValue(3));
  v.Set("alpha",
        JsonValue::MakeArray(
            {JsonValue(0.0095), JsonValue(-7), JsonValue(1e21)}));
  v.Set("mid", JsonValue::MakeObject());
  EXPECT_EQ(WriteJson(v, 2),
            "{\n  \"alpha\": [\n    0.0095,\n    -7,\n    1e+21\n  ],\n  "
            "\"mid\": {},\n"
            "  \"zeta\": 3\n}");
  EXPECT_EQ(WriteJson(v, 0),
            R"({"alpha": [0.0095, -7, 1e+21], "mid": {}, "zeta": 3})");
  EXPECT_EQ(ParseJson(WriteJson(v)), v);
}

TEST(Json, RoundTripsDoublesExactly) {
  for (const double x :
       {0.1, 1.0 / 3.0, -1e-300, 123456789.123456789, 2.5e-7}) {
    EXPECT_EQ(ParseJson(WriteJson(JsonValue(x))).AsNumber(), x);
  }
}

TEST(Json, ReportsLineAndColumn) {
  EXPECT_NE(ErrorOf("{\n  \"a\": 1,\n  \"b\" 2\n}").find("doc.json:3:7:"),
            std::string::npos)
      << ErrorOf("{\n  \"a\": 1,\n  \"b\" 2\n}");
  EXPECT_NE(ErrorOf("[1, 2,]").find("doc.json:1:7:"), std::string::npos)
      << ErrorOf("[1, 2,]");
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
                          "{1: 2}"}) {
    EXPECT_THROW(ParseJson(bad, "doc.json"), IoError) << bad;
  }
  EXPECT_NE(ErrorOf("{\"a\": 1, \"a\": 2}").find("duplicate key"),
            std::string::npos);
}

TEST(Json, DepthLimit) {
  std::string deep(600, '[');
  deep += std::string(600, ']');
  EXPECT_THROW(ParseJson(deep), IoError);
  std::string ok(100, '[');
  ok += std::string(100, ']');
  EXPECT_NO_THROW(ParseJson(ok));
}

TEST(Json, PythonNonFiniteExtensions) {
  const JsonValue v = ParseJson("[NaN, Infinity, -Infinity]");
  EXPECT_TRUE(std::isnan(v.AsArray()[0].AsNumber()));
  EXPECT_EQ(v.AsArray()[1].AsNumber(), INFINITY);
  EXPECT_EQ(v.AsArray()[2].AsNumber(), -INFINITY);
  EXPECT_THROW(WriteJson(v), IoError);  // not representable in strict JSON
}

TEST(Json, TypeMismatchThrows) {
  const JsonValue v = ParseJson(R"({"a": 1.5})");
  EXPECT_THROW(v.AsArray(), IoError);
  EXPECT_THROW(v.Find("a")->AsString(), IoError);
  EXPECT_THROW(v.Find("a")->AsInt(), IoError);  // not integral
  EXPECT_FALSE(v.Find("a")->is_integer());
}

TEST(Json, SkipsByteOrderMark) {
  EXPECT_EQ(ParseJson("\xEF\xBB\xBF[1]").AsArray()[0].AsInt(), 1);
}

}  // namespace
}  // namespace soma
