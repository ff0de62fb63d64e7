#include "framework/config/override.h"

#include "framework/core/error.h"
#include "framework/core/random.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace soma {
namespace {

ConfigNode List(std::vector<ConfigNode> items) {
  ConfigNode list = ConfigNode::EmptyList();
  for (ConfigNode& item : items) list.Append(std::move(item));
  return list;
}

ConfigNode Map(const std::vector<std::pair<std::string, ConfigNode>>& entries) {
  ConfigNode map = ConfigNode::EmptyMap();
  for (auto& [key, value] : entries) map.Set(key, std::move(value));
  return map;
}

ConfigNode Str(const std::string& s) { return ConfigNode::FromString(s); }

// Parses `text` and returns its (non-sweep) value.
ConfigNode ValueOf(const std::string& text) {
  const Override o = ParseOverride(text);
  EXPECT_FALSE(o.IsSweep()) << text;
  EXPECT_TRUE(o.value.has_value()) << text;
  return o.value.value_or(ConfigNode());
}

std::string ErrorOf(const std::string& text) {
  try {
    ParseOverride(text);
  } catch (const ConfigError& e) {
    return e.what();
  }
  ADD_FAILURE() << "no ConfigError for " << text;
  return "";
}

TEST(OverrideParser, TypesPrimitivesLikeHydra) {
  const std::vector<std::pair<std::string, ConfigNode>> cases = {
      {"a=1", ConfigNode(1)},
      {"a=-20", ConfigNode(-20)},
      {"a=+7", ConfigNode(7)},
      {"a=0", ConfigNode(0)},
      {"a=1_000", ConfigNode(1000)},
      {"a=1.5", ConfigNode(1.5)},
      {"a=3.14", ConfigNode(3.14)},
      {"a=1e-3", ConfigNode(0.001)},
      {"a=-10e3", ConfigNode(-10000.0)},
      {"a=1.5e3", ConfigNode(1500.0)},
      {"a=.5", ConfigNode(0.5)},
      {"a=5.", ConfigNode(5.0)},
      {"a=1_000.5", ConfigNode(1000.5)},
      {"a=true", ConfigNode(true)},
      {"a=True", ConfigNode(true)},
      {"a=TRUE", ConfigNode(true)},
      {"a=false", ConfigNode(false)},
      {"a=FaLsE", ConfigNode(false)},
      {"a=null", ConfigNode::Null()},
      {"a=NULL", ConfigNode::Null()},
      // YAML 1.1 words are plain strings in the override grammar.
      {"a=yes", Str("yes")},
      {"a=no", Str("no")},
      {"a=on", Str("on")},
  };
  for (const auto& [input, expected] : cases) {
    EXPECT_EQ(ValueOf(input), expected) << input;
  }
  EXPECT_TRUE(std::isinf(ValueOf("a=inf").AsDouble()));
  EXPECT_GT(ValueOf("a=inf").AsDouble(), 0);
  EXPECT_TRUE(std::isinf(ValueOf("a=-inf").AsDouble()));
  EXPECT_LT(ValueOf("a=-inf").AsDouble(), 0);
  EXPECT_TRUE(std::isnan(ValueOf("a=nan").AsDouble()));
  EXPECT_TRUE(std::isinf(ValueOf("a=INF").AsDouble()));
}

TEST(OverrideParser, UnquotedStrings) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"a=abc", "abc"},
      {"a=  abc  ", "abc"},
      {"a=hello world", "hello world"},
      {"a=   hello world   ", "hello world"},
      {"a=foo-bar_10", "foo-bar_10"},
      {"a=/usr/local-x/file.txt", "/usr/local-x/file.txt"},
      {"a=a+b.c$d%e*f@g?h|i", "a+b.c$d%e*f@g?h|i"},
      {"a=01", "01"},
      {"a=0x1F", "0x1F"},
      {"a=1.2.3.4", "1.2.3.4"},
      {"a=1e", "1e"},
      {"a=infinity", "infinity"},
      {"a=true_x", "true_x"},
      {"a=nullable", "nullable"},
      {"a=-", "-"},
      {"a=b:c", "b:c"},
      {"a=C:\\path", "C:\\path"},
      {"a=café", "café"},
  };
  for (const auto& [input, expected] : cases) {
    const ConfigNode v = ValueOf(input);
    EXPECT_TRUE(v.IsString()) << input;
    EXPECT_EQ(v.text(), expected) << input;
  }
}

TEST(OverrideParser, EscapesInUnquotedValues) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"a=\\,", ","},
      {"a=a\\ b", "a b"},
      {"a=\\\\", "\\"},
      {"a=job\\{a\\=1\\,b\\=2\\,c\\=3\\}", "job{a=1,b=2,c=3}"},
      {"a=A\\[B", "A[B"},
      {"a=f\\(x\\)", "f(x)"},
      {"a=k\\:v", "k:v"},
      {"a=\\ padded\\ ", " padded "},
  };
  for (const auto& [input, expected] : cases) {
    const ConfigNode v = ValueOf(input);
    EXPECT_TRUE(v.IsString()) << input;
    EXPECT_EQ(v.text(), expected) << input;
  }
}

TEST(OverrideParser, QuotedValuesAreAlwaysStrings) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"a='abc'", "abc"},
      {"a=\"abc\"", "abc"},
      {"a='1'", "1"},
      {"a=\"true\"", "true"},
      {"a='null'", "null"},
      {"a=\"a,b\"", "a,b"},
      {"a='x=\"1,2\"'", "x=\"1,2\""},
      {"a='hello there'", "hello there"},
      {"a='  padded  '", "  padded  "},
      {"a='[1,2]'", "[1,2]"},
      {"a=\"{a:10}\"", "{a:10}"},
      {"a=''", ""},
      {"a='It\\'s'", "It's"},
      {"a=\"escaped \\\"double quote\\\"\"", "escaped \"double quote\""},
      {"a='escaped \\'single quote\\''", "escaped 'single quote'"},
      // Backslashes preceding a quote are escaped by doubling them.
      {"a='the path is C:\\\\\\'some folder\\'\\\\'",
       "the path is C:\\'some folder'\\"},
      {"a=\"the path is C:\\\\\\\"some folder\\\"\\\\\"",
       "the path is C:\\\"some folder\"\\"},
      {"a='C:\\dir\\file'", "C:\\dir\\file"},
      {"a=\"'single quoted string'\"", "'single quoted string'"},
      {"a='\"double quoted string\"'", "\"double quoted string\""},
  };
  for (const auto& [input, expected] : cases) {
    const ConfigNode v = ValueOf(input);
    EXPECT_TRUE(v.IsString()) << input;
    EXPECT_EQ(v.text(), expected) << input;
  }
}

TEST(OverrideParser, InterpolationsStayInterpolations) {
  for (const std::string input : {"a=${b}",
                                  "a=${oc.env:HOME,/tmp}",
                                  "a=x_${b}",
                                  "a='${b}'",
                                  "a=\"{a:10} ${xyz}\"",
                                  "a=${a}:${b}",
                                  "a=${foo:${bar}}"}) {
    const ConfigNode v = ValueOf(input);
    EXPECT_TRUE(v.IsInterpolation()) << input;
    EXPECT_EQ(v, ConfigNode::FromString(v.text())) << input;
  }
  EXPECT_EQ(ValueOf("a=${b}").text(), "${b}");
  EXPECT_EQ(ValueOf("a=${foo:${bar}}").text(), "${foo:${bar}}");
  EXPECT_EQ(ValueOf("a=\"{a:10} ${xyz}\"").text(), "{a:10} ${xyz}");
}

TEST(OverrideParser, ListsAndDicts) {
  EXPECT_EQ(ValueOf("a=[1,2]"), List({1, 2}));
  EXPECT_EQ(ValueOf("a=[]"), ConfigNode::EmptyList());
  EXPECT_EQ(ValueOf("a={}"), ConfigNode::EmptyMap());
  EXPECT_EQ(ValueOf("a=[a, b ,c]"), List({Str("a"), Str("b"), Str("c")}));
  EXPECT_EQ(ValueOf("a=[[1,2],[3]]"), List({List({1, 2}), List({3})}));
  EXPECT_EQ(ValueOf("a={x:1,y:[2]}"),
            Map({{"x", ConfigNode(1)}, {"y", List({2})}}));
  EXPECT_EQ(ValueOf("a={a: 10, b: {c: 30, d: abc}}"),
            Map({{"a", ConfigNode(10)},
                 {"b", Map({{"c", ConfigNode(30)}, {"d", Str("abc")}})}}));
  EXPECT_EQ(ValueOf("a=[a,[b,[c]]]"),
            List({Str("a"), List({Str("b"), List({Str("c")})})}));
  EXPECT_EQ(ValueOf("a=['a,b', \"c\"]"), List({Str("a,b"), Str("c")}));
  EXPECT_EQ(ValueOf("a=[1, true, null, 2.5]"),
            List({ConfigNode(1),
                  ConfigNode(true),
                  ConfigNode::Null(),
                  ConfigNode(2.5)}));
  EXPECT_EQ(ValueOf("a=[int(1.5),str(2)]"), List({ConfigNode(1), Str("2")}));
  // Dict values may contain colons; keys keep their text.
  EXPECT_EQ(ValueOf("a={url:http://x:80,1:one}"),
            Map({{"url", Str("http://x:80")}, {"1", Str("one")}}));
  // Duplicate dict keys: first position, last value (Python dict).
  EXPECT_EQ(ValueOf("a={x:1,y:2,x:3}"),
            Map({{"x", ConfigNode(3)}, {"y", ConfigNode(2)}}));
}

TEST(OverrideParser, OverrideTypesAndKeys) {
  Override o = ParseOverride("a.b.c=1");
  EXPECT_EQ(o.type, OverrideType::kChange);
  EXPECT_EQ(o.key, "a.b.c");
  EXPECT_EQ(o.package, "");
  EXPECT_EQ(o.input, "a.b.c=1");

  o = ParseOverride("+a=1");
  EXPECT_EQ(o.type, OverrideType::kAdd);
  EXPECT_EQ(o.key, "a");
  EXPECT_EQ(*o.value, ConfigNode(1));

  o = ParseOverride("++a.b=1");
  EXPECT_EQ(o.type, OverrideType::kForceAdd);
  EXPECT_EQ(o.key, "a.b");

  o = ParseOverride("~a");
  EXPECT_EQ(o.type, OverrideType::kDelete);
  EXPECT_EQ(o.key, "a");
  EXPECT_FALSE(o.value.has_value());
  EXPECT_FALSE(o.IsSweep());

  o = ParseOverride("~a=1");
  EXPECT_EQ(o.type, OverrideType::kDelete);
  EXPECT_EQ(*o.value, ConfigNode(1));

  o = ParseOverride("~server/db=mysql");
  EXPECT_EQ(o.type, OverrideType::kDelete);
  EXPECT_EQ(o.key, "server/db");
  EXPECT_EQ(*o.value, Str("mysql"));

  o = ParseOverride("a=");
  EXPECT_EQ(*o.value, Str(""));
  EXPECT_TRUE(o.value->IsString());
  o = ParseOverride("a=   ");
  EXPECT_EQ(*o.value, Str(""));
  o = ParseOverride("~a=");
  EXPECT_EQ(*o.value, Str(""));

  o = ParseOverride("server/db@src=sqlite");
  EXPECT_EQ(o.key, "server/db");
  EXPECT_EQ(o.package, "src");
  EXPECT_EQ(o.KeyWithPackage(), "server/db@src");
  EXPECT_EQ(*o.value, Str("sqlite"));

  o = ParseOverride("+db@backup.db=mysql");
  EXPECT_EQ(o.key, "db");
  EXPECT_EQ(o.package, "backup.db");

  o = ParseOverride("hydra/launcher=basic");
  EXPECT_EQ(o.key, "hydra/launcher");

  o = ParseOverride("list.0=x");
  EXPECT_EQ(o.key, "list.0");

  o = ParseOverride("foo-bar.baz_1=2");
  EXPECT_EQ(o.key, "foo-bar.baz_1");

  // An empty package is the global package.
  o = ParseOverride("db@=mysql");
  EXPECT_EQ(o.key, "db");
  EXPECT_EQ(o.package, "_global_");
}

TEST(OverrideParser, ChoiceSweeps) {
  Override o = ParseOverride("a=1,2");
  ASSERT_TRUE(o.IsSweep());
  EXPECT_FALSE(o.value.has_value());
  EXPECT_EQ(o.sweep->kind, SweepSpec::Kind::kChoice);
  EXPECT_EQ(o.sweep->values, (std::vector<ConfigNode>{1, 2}));

  o = ParseOverride("a=x , y");
  EXPECT_EQ(o.sweep->values, (std::vector<ConfigNode>{Str("x"), Str("y")}));

  o = ParseOverride("key=[a,b],[c,d]");
  ASSERT_TRUE(o.IsSweep());
  EXPECT_EQ(o.sweep->values,
            (std::vector<ConfigNode>{List({Str("a"), Str("b")}),
                                     List({Str("c"), Str("d")})}));

  o = ParseOverride("key=\"a,b\",\"c,d\"");
  EXPECT_EQ(o.sweep->values, (std::vector<ConfigNode>{Str("a,b"), Str("c,d")}));

  o = ParseOverride("key={a:10, b:20},{c:30,d:40}");
  ASSERT_EQ(o.sweep->values.size(), 2u);
  EXPECT_EQ(o.sweep->values[0],
            Map({{"a", ConfigNode(10)}, {"b", ConfigNode(20)}}));

  o = ParseOverride("a=choice(1,2)");
  EXPECT_EQ(o.sweep->kind, SweepSpec::Kind::kChoice);
  EXPECT_EQ(o.sweep->values, (std::vector<ConfigNode>{1, 2}));

  o = ParseOverride("db=choice(mysql,postgresql)");
  EXPECT_EQ(o.sweep->values,
            (std::vector<ConfigNode>{Str("mysql"), Str("postgresql")}));

  // A single-element choice is still a sweep; a list argument is one element.
  o = ParseOverride("a=choice([a,b])");
  ASSERT_TRUE(o.IsSweep());
  EXPECT_EQ(o.sweep->values,
            (std::vector<ConfigNode>{List({Str("a"), Str("b")})}));
  o = ParseOverride("a=choice([a,b],[c,d])");
  EXPECT_EQ(o.sweep->values.size(), 2u);

  o = ParseOverride("+db=mysql,postgresql");
  EXPECT_EQ(o.type, OverrideType::kAdd);
  EXPECT_TRUE(o.IsSweep());
}

std::vector<ConfigNode> RangeValues(const std::string& text) {
  const Override o = ParseOverride(text);
  EXPECT_TRUE(o.IsSweep()) << text;
  if (!o.IsSweep()) return {};
  EXPECT_EQ(o.sweep->kind, SweepSpec::Kind::kRange) << text;
  return SweepValues(*o.sweep);
}

TEST(OverrideParser, RangeSweeps) {
  EXPECT_EQ(RangeValues("a=range(5)"),
            (std::vector<ConfigNode>{0, 1, 2, 3, 4}));
  EXPECT_EQ(RangeValues("a=range(0,5)"),
            (std::vector<ConfigNode>{0, 1, 2, 3, 4}));
  EXPECT_EQ(RangeValues("a=range(1,3)"), (std::vector<ConfigNode>{1, 2}));
  EXPECT_EQ(RangeValues("a=range(0,5,2)"), (std::vector<ConfigNode>{0, 2, 4}));
  EXPECT_EQ(RangeValues("a=range(-5,step=-1)"),
            (std::vector<ConfigNode>{0, -1, -2, -3, -4}));
  EXPECT_EQ(RangeValues("a=range(5,0,-2)"), (std::vector<ConfigNode>{5, 3, 1}));
  EXPECT_EQ(RangeValues("a=range(start=1,stop=3)"),
            (std::vector<ConfigNode>{1, 2}));
  EXPECT_EQ(RangeValues("a=range(1.5,3)"), (std::vector<ConfigNode>{1.5, 2.5}));
  EXPECT_TRUE(RangeValues("a=range(3,1)").empty());

  // Ints stay ints; one float argument makes every value a float.
  for (const ConfigNode& v : RangeValues("a=range(0,3)")) {
    EXPECT_TRUE(v.IsInt());
  }
  EXPECT_EQ(RangeValues("a=range(0,3.0)"),
            (std::vector<ConfigNode>{0.0, 1.0, 2.0}));
  for (const ConfigNode& v : RangeValues("a=range(0,3.0)")) {
    EXPECT_TRUE(v.IsDouble());
  }
}

// Found by the override fuzzer (tests/fuzz/corpus/override/): a float range
// with a tiny step ran a million decimal additions before its error (a step
// below the 28-digit resolution never advances); the error is now immediate.
TEST(OverrideParser, OverlongFloatRangesFailAtOnce) {
  for (const char* text : {"a=range(0,5.,3.1e-33)",
                           "a=range(0,1,1e-7)",
                           "a=range(1e20,2e20,1e-10)",
                           "a=range(0,inf)",
                           "a=range(0,-inf,-0.5)"}) {
    const auto start = std::chrono::steady_clock::now();
    try {
      ParseOverride(text);
      ADD_FAILURE() << text << " parsed";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(
                    "more than the limit of 100000 for a float range"),
                std::string::npos)
          << e.what();
    }
    EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(1))
        << text;
  }
  // Long ranges under the limit still expand.
  const size_t n = RangeValues("a=range(0,1,2e-5)").size();
  EXPECT_GE(n, 49999u);
  EXPECT_LE(n, 50001u);
  // Found by CI's fixed-seed override fuzzer: 880,070 float values took
  // 10-34 s under the sanitizers; float ranges stop at 100,000 values.
  EXPECT_THROW(ParseOverride("a=range(880069.67)"), ConfigError);
  EXPECT_THROW(ParseOverride("a=range(0,100000.5)"), ConfigError);
  EXPECT_EQ(RangeValues("a=range(0,99999.5)").size(), 100000u);
  // Integer ranges keep the million.
  EXPECT_EQ(RangeValues("a=range(0,1000000)").size(), 1000000u);
  EXPECT_THROW(ParseOverride("a=range(0,1000001)"), ConfigError);
}

/// The message of the ConfigError that parsing `text` throws ("" if none).
std::string OverrideError(const std::string& text) {
  try {
    ParseOverride(text);
  } catch (const ConfigError& e) {
    return e.what();
  }
  ADD_FAILURE() << text << " parsed";
  return "";
}

// A range's length is computed before anything is expanded: the error names
// the override and gives the exact number of values of an int range (which
// expanding up to the limit could not know), also where it exceeds int64.
TEST(OverrideParser, RangeLengthCheckedBeforeExpanding) {
  using ::testing::HasSubstr;
  const std::string too_long = OverrideError("a=range(5777753)");
  EXPECT_THAT(too_long, HasSubstr("'a=range(5777753)'"));
  EXPECT_THAT(too_long,
              HasSubstr("range() produces 5777753 values, more than the limit "
                        "of 1000000"));
  EXPECT_THAT(OverrideError("a=range(0,-5777753,-1)"),
              HasSubstr("produces 5777753 values"));
  EXPECT_THAT(
      OverrideError("a=range(-9223372036854775807,9223372036854775807)"),
      HasSubstr("produces 18446744073709551614 values"));
  EXPECT_THAT(
      OverrideError("a=range(9223372036854775807,-9223372036854775807,-3)"),
      HasSubstr("produces 6148914691236517205 values"));
  // Steps whose multiples leave int64 on the way still give exact values.
  EXPECT_EQ(
      RangeValues("a=range(-9223372036854775807,9223372036854775807,"
                  "4611686018427387904)"),
      (std::vector<ConfigNode>{ConfigNode(int64_t{-9223372036854775807}),
                               ConfigNode(int64_t{-4611686018427387903}),
                               ConfigNode(int64_t{1}),
                               ConfigNode(int64_t{4611686018427387905})}));
}

TEST(OverrideParser, RangeLengthLimitIsExact) {
  // Int ranges: the limit (1,000,000 values) passes, one more fails; also
  // with a negative step and a step of 2.
  EXPECT_EQ(RangeValues("a=range(999999)").size(), 999999u);
  const std::vector<ConfigNode> down = RangeValues("a=range(0,-1000000,-1)");
  ASSERT_EQ(down.size(), 1000000u);
  EXPECT_EQ(down.front(), ConfigNode(int64_t{0}));
  EXPECT_EQ(down.back(), ConfigNode(int64_t{-999999}));
  EXPECT_THAT(OverrideError("a=range(1000001)"),
              ::testing::HasSubstr("produces 1000001 values"));
  EXPECT_THAT(OverrideError("a=range(0,-1000001,-1)"),
              ::testing::HasSubstr("produces 1000001 values"));
  EXPECT_EQ(RangeValues("a=range(0,2000000,2)").size(), 1000000u);
  EXPECT_THAT(OverrideError("a=range(0,2000001,2)"),
              ::testing::HasSubstr("produces 1000001 values"));
  // Float ranges: 100,000 values pass, 100,001 fail (in the expansion: the
  // up-front estimate leaves one value of slack, see CheckRange), more fail
  // before anything is expanded.
  EXPECT_EQ(RangeValues("a=range(0.0,99999.0)").size(), 99999u);
  const std::vector<ConfigNode> floats = RangeValues("a=range(0,-100000.0,-1)");
  ASSERT_EQ(floats.size(), 100000u);
  EXPECT_EQ(floats.back(), ConfigNode(-99999.0));
  EXPECT_EQ(RangeValues("a=range(0.0,100000.0)").size(), 100000u);
  EXPECT_THAT(OverrideError("a=range(0.0,100001.0)"),
              ::testing::HasSubstr(
                  "produces more than 100000 values, the limit for a float"));
  EXPECT_THAT(OverrideError("a=range(0.0,100002.0)"),
              ::testing::HasSubstr("produces about 100002 values, more than "
                                   "the limit of 100000 for a float range"));
  EXPECT_THAT(OverrideError("a=range(0,-100002.0,-1)"),
              ::testing::HasSubstr("produces about 100002 values"));
  EXPECT_THAT(OverrideError("a=range(0,1e300,1e-300)"),
              ::testing::HasSubstr("produces more than 1e308 values"));
  EXPECT_THAT(OverrideError("a=range(0,inf)"),
              ::testing::HasSubstr("produces unboundedly many values"));
}

/// The values of a float range as Hydra writes them into job overrides.
std::vector<std::string> FloatRangeTexts(const std::string& text) {
  std::vector<std::string> out;
  for (const ConfigNode& v : RangeValues(text)) {
    EXPECT_TRUE(v.IsDouble()) << text;
    out.push_back(FormatOverrideValue(v));
  }
  return out;
}

// Hydra 1.3's FloatRange builds decimal.Decimal from each float's exact value
// and accumulates in Python's decimal context (28 digits). The expected lists
// are what Python prints for
//   d = Decimal(start); while d < stop: out.append(repr(float(d))); d += step
TEST(OverrideParser, FloatRangesFollowHydrasDecimalArithmetic) {
  // extended.md: range(0,10,3.3) -> 0.0,3.3,6.6,9.9 (not 9.899999999999999).
  EXPECT_EQ(FloatRangeTexts("a=range(0,10,3.3)"),
            (std::vector<std::string>{"0.0", "3.3", "6.6", "9.9"}));
  EXPECT_EQ(FloatRangeTexts("a=range(0,10,2.5)"),
            (std::vector<std::string>{"0.0", "2.5", "5.0", "7.5"}));
  EXPECT_EQ(FloatRangeTexts("a=range(1e-5,5e-5,1e-5)"),
            (std::vector<std::string>{"1e-05", "2e-05", "3e-05", "4e-05"}));
  // The binary value of 0.1 is used, as in Hydra: 0.30000000000000004.
  EXPECT_EQ(FloatRangeTexts("a=range(0.1,1,0.1)"),
            (std::vector<std::string>{"0.1",
                                      "0.2",
                                      "0.30000000000000004",
                                      "0.4",
                                      "0.5",
                                      "0.6",
                                      "0.7000000000000001",
                                      "0.8",
                                      "0.9"}));
  EXPECT_EQ(FloatRangeTexts("a=range(1,2,0.1)").back(), "1.9000000000000001");
  // Negative steps.
  EXPECT_EQ(FloatRangeTexts("a=range(1.3,0,-0.5)"),
            (std::vector<std::string>{"1.3", "0.8", "0.30000000000000004"}));
  EXPECT_EQ(FloatRangeTexts("a=range(0,-0.5,-0.1)"),
            (std::vector<std::string>{"0.0", "-0.1", "-0.2", "-0.3", "-0.4"}));
  EXPECT_EQ(FloatRangeTexts("a=range(-1.5,step=-0.5)"),
            (std::vector<std::string>{"0.0", "-0.5", "-1.0"}));
  // Stop is exclusive also when a value lands on it exactly.
  EXPECT_EQ(FloatRangeTexts("a=range(0,1,0.25)"),
            (std::vector<std::string>{"0.0", "0.25", "0.5", "0.75"}));
  EXPECT_TRUE(RangeValues("a=range(1.0,0)").empty());
}

TEST(OverrideParser, GlobSweeps) {
  Override o = ParseOverride("+experiment=glob(*)");
  ASSERT_TRUE(o.IsSweep());
  EXPECT_EQ(o.sweep->kind, SweepSpec::Kind::kGlob);
  EXPECT_EQ(o.sweep->glob_include, (std::vector<std::string>{"*"}));
  EXPECT_TRUE(o.sweep->glob_exclude.empty());
  EXPECT_TRUE(o.sweep->values.empty());

  o = ParseOverride("schema=glob([s*,w*],exclude=school)");
  EXPECT_EQ(o.sweep->glob_include, (std::vector<std::string>{"s*", "w*"}));
  EXPECT_EQ(o.sweep->glob_exclude, (std::vector<std::string>{"school"}));

  o = ParseOverride("schema=glob(*, exclude=[x*, y*])");
  EXPECT_EQ(o.sweep->glob_exclude, (std::vector<std::string>{"x*", "y*"}));

  const std::vector<std::string> options = {"support", "school", "warehouse"};
  EXPECT_EQ(ExpandGlob(*ParseOverride("schema=glob(*)").sweep, options),
            (std::vector<std::string>{"school", "support", "warehouse"}));
  EXPECT_EQ(ExpandGlob(*ParseOverride("schema=glob(*,exclude=support)").sweep,
                       options),
            (std::vector<std::string>{"school", "warehouse"}));
  EXPECT_EQ(
      ExpandGlob(*ParseOverride("schema=glob([s*,w*],exclude=school)").sweep,
                 options),
      (std::vector<std::string>{"support", "warehouse"}));
  EXPECT_EQ(SweepValues(*ParseOverride("schema=glob(w*)").sweep, options),
            (std::vector<ConfigNode>{Str("warehouse")}));
  EXPECT_TRUE(
      ExpandGlob(*ParseOverride("schema=glob(zz*)").sweep, options).empty());
}

TEST(OverrideParser, SortAndShuffle) {
  Override o = ParseOverride("a=sort(3,1,2)");
  ASSERT_TRUE(o.IsSweep());
  EXPECT_TRUE(o.sweep->sort);
  EXPECT_FALSE(o.sweep->sort_reverse);
  EXPECT_EQ(SweepValues(*o.sweep), (std::vector<ConfigNode>{1, 2, 3}));

  o = ParseOverride("a=sort(3,1,2,reverse=true)");
  EXPECT_EQ(SweepValues(*o.sweep), (std::vector<ConfigNode>{3, 2, 1}));
  o = ParseOverride("a=sort(choice(b,c,a))");
  EXPECT_EQ(SweepValues(*o.sweep),
            (std::vector<ConfigNode>{Str("a"), Str("b"), Str("c")}));
  o = ParseOverride("a=sort(sweep=choice(1,3,2),reverse=true)");
  EXPECT_EQ(SweepValues(*o.sweep), (std::vector<ConfigNode>{3, 2, 1}));
  o = ParseOverride("a=sort(range(3),reverse=true)");
  EXPECT_EQ(SweepValues(*o.sweep), (std::vector<ConfigNode>{2, 1, 0}));

  EXPECT_EQ(ValueOf("a=sort([3,1,2])"), List({1, 2, 3}));
  EXPECT_EQ(ValueOf("a=sort(list=[3,1,2], reverse=true)"), List({3, 2, 1}));
  EXPECT_EQ(ValueOf("a=sort(1)"), ConfigNode(1));

  o = ParseOverride("a=shuffle(1,2,3,4,5,seed=7)");
  ASSERT_TRUE(o.IsSweep());
  EXPECT_TRUE(o.sweep->shuffle);
  EXPECT_EQ(o.sweep->shuffle_seed, std::optional<uint64_t>(7));
  const std::vector<ConfigNode> shuffled = SweepValues(*o.sweep);
  EXPECT_EQ(shuffled, SweepValues(*o.sweep));  // deterministic
  std::vector<ConfigNode> expected;
  for (const int index : Rng(7).Permutation(5))
    expected.emplace_back(index + 1);
  EXPECT_EQ(shuffled, expected);

  o = ParseOverride("a=shuffle(range(10))");
  EXPECT_TRUE(o.sweep->shuffle);
  EXPECT_FALSE(o.sweep->shuffle_seed.has_value());
  std::vector<ConfigNode> values = SweepValues(*o.sweep);
  ASSERT_EQ(values.size(), 10u);
  std::vector<bool> seen(10, false);
  for (const ConfigNode& v : values) seen[v.AsInt()] = true;
  EXPECT_EQ(std::count(seen.begin(), seen.end(), true), 10);

  const ConfigNode list = ValueOf("a=shuffle([a,b,c,d],seed=3)");
  ASSERT_TRUE(list.IsList());
  EXPECT_EQ(list.size(), 4u);
  EXPECT_EQ(list, ValueOf("a=shuffle(list=[a,b,c,d],seed=3)"));

  // Sorting a shuffled sweep sorts it.
  o = ParseOverride("a=sort(shuffle(3,1,2))");
  EXPECT_EQ(SweepValues(*o.sweep), (std::vector<ConfigNode>{1, 2, 3}));

  // sort() and shuffle() of a glob apply after expansion.
  o = ParseOverride("a=sort(glob(*),reverse=true)");
  EXPECT_EQ(SweepValues(*o.sweep, {"x", "z", "y"}),
            (std::vector<ConfigNode>{Str("z"), Str("y"), Str("x")}));

  // Values that cannot be compared.
  o = ParseOverride("a=sort(choice(1,a))");
  EXPECT_THROW(SweepValues(*o.sweep), ConfigError);
}

TEST(OverrideParser, Casts) {
  EXPECT_EQ(ValueOf("a=int(3.14)"), ConfigNode(3));
  EXPECT_EQ(ValueOf("a=int(-3.9)"), ConfigNode(-3));
  EXPECT_EQ(ValueOf("a=int(value=3.14)"), ConfigNode(3));
  EXPECT_EQ(ValueOf("a=int('10')"), ConfigNode(10));
  EXPECT_EQ(ValueOf("a=int(true)"), ConfigNode(1));
  EXPECT_EQ(ValueOf("a=float(10)"), ConfigNode(10.0));
  EXPECT_EQ(ValueOf("a=float('10.0')"), ConfigNode(10.0));
  EXPECT_EQ(ValueOf("a=float(false)"), ConfigNode(0.0));
  EXPECT_EQ(ValueOf("a=str(10)"), Str("10"));
  EXPECT_EQ(ValueOf("a=str(10.0)"), Str("10.0"));
  EXPECT_EQ(ValueOf("a=str(1e6)"), Str("1000000.0"));
  EXPECT_EQ(ValueOf("a=str(true)"), Str("true"));
  EXPECT_EQ(ValueOf("a=str(foo)"), Str("foo"));
  EXPECT_EQ(ValueOf("a=bool(1)"), ConfigNode(true));
  EXPECT_EQ(ValueOf("a=bool(0.0)"), ConfigNode(false));
  EXPECT_EQ(ValueOf("a=bool('False')"), ConfigNode(false));
  EXPECT_EQ(ValueOf("a=bool(\"true\")"), ConfigNode(true));
  EXPECT_EQ(ValueOf("a=str([1,2,3])"), List({Str("1"), Str("2"), Str("3")}));
  EXPECT_EQ(ValueOf("a=float([0,[1]])"), List({0.0, List({1.0})}));
  EXPECT_EQ(ValueOf("a=str({a:10})"), Map({{"a", Str("10")}}));
  EXPECT_EQ(ValueOf("a=bool([0,1,2])"), List({false, true, true}));
  EXPECT_EQ(ValueOf("a=int([])"), ConfigNode::EmptyList());

  Override o = ParseOverride("a=float(range(1,3))");
  EXPECT_EQ(SweepValues(*o.sweep), (std::vector<ConfigNode>{1.0, 2.0}));
  o = ParseOverride("a=int(range(1.0,3.0))");
  EXPECT_EQ(SweepValues(*o.sweep), (std::vector<ConfigNode>{1, 2}));
  o = ParseOverride("a=str(choice(0,1))");
  EXPECT_EQ(SweepValues(*o.sweep),
            (std::vector<ConfigNode>{Str("0"), Str("1")}));
  o = ParseOverride("a=bool(0,1)");
  EXPECT_EQ(SweepValues(*o.sweep), (std::vector<ConfigNode>{false, true}));

  for (const std::string bad : {"a=int(foo)",
                                "a=int(inf)",
                                "a=int(nan)",
                                "a=int('10.0')",
                                "a=int('')",
                                "a=float(foo)",
                                "a=bool(foo)",
                                "a=bool('')",
                                "a=int([a,1])",
                                "a=str(range(1,3))",
                                "a=bool(range(1,3))",
                                "a=int(1,value=2)",
                                "a=int()",
                                "a=int(null)",
                                "a=int(glob(*))"}) {
    EXPECT_THROW(ParseOverride(bad), ConfigError) << bad;
  }
}

TEST(OverrideParser, SyntaxErrorsNameTheOverrideAndColumn) {
  EXPECT_EQ(
      ErrorOf("a=[1,2"),
      "Error parsing override 'a=[1,2': missing ']' at '<EOF>' (column 7)");
  EXPECT_EQ(ErrorOf("a"),
            "Error parsing override 'a': missing '=' at '<EOF>' (column 2)");
  EXPECT_EQ(ErrorOf("=1"),
            "Error parsing override '=1': missing key at '=' (column 1)");
  EXPECT_EQ(
      ErrorOf("a={x:1"),
      "Error parsing override 'a={x:1': missing '}' at '<EOF>' (column 7)");
  EXPECT_EQ(
      ErrorOf("a=range(1"),
      "Error parsing override 'a=range(1': missing ')' at '<EOF>' (column 10)");
  EXPECT_NE(ErrorOf("db/../x=1").find("'..' is not allowed"),
            std::string::npos);
  EXPECT_NE(ErrorOf("db\\x=1").find("backslash"), std::string::npos);
  EXPECT_NE(ErrorOf("a='abc").find("missing closing quote"), std::string::npos);
  // ANTLR's wording, as Hydra prints it.
  EXPECT_NE(ErrorOf("a=b=c").find(
                "mismatched input '=' expecting {',', <EOF>} (column 4)"),
            std::string::npos);
  EXPECT_NE(ErrorOf("a=foo(1)").find("unknown function 'foo'"),
            std::string::npos);
  EXPECT_NE(ErrorOf("a=interval(0,1)")
                .find("BasicSweeper does not support INTERVAL_SWEEP"),
            std::string::npos);
  EXPECT_NE(ErrorOf("a=range(1,2,0)").find("step must not be zero"),
            std::string::npos);
  EXPECT_NE(ErrorOf("a=range(1,step=1,2)").find("positional argument follows"),
            std::string::npos);

  for (const std::string bad : {"a",
                                "=1",
                                "+=1",
                                "~",
                                "++",
                                "a b=1",
                                "a.=1",
                                ".a=1",
                                "a..b=1",
                                "db/../x=1",
                                "x\\y=1",
                                "0=1",
                                "a@b@c=1",
                                "a/=1",
                                "/a=1",
                                "a[0]=1",
                                "+~a=1",
                                "a=[1,2",
                                "a=[1,,2]",
                                "a={a}",
                                "a={a:1",
                                "a=,b",
                                "a=1,",
                                "a=(",
                                "a=)",
                                "a=#",
                                "a=x'y'",
                                "a='x'y",
                                "a=${}",
                                "a=${x",
                                "a=foo(1)",
                                "a=abc(",
                                "a=x y(1)",
                                "a=range(a)",
                                "a=range()",
                                "a=range(1,2,3,4)",
                                "a=range(1,start=2)",
                                "a=range(true)",
                                "a=1,range(3)",
                                "a=[range(3)]",
                                "a={x:choice(1,2)}",
                                "a=glob(1)",
                                "a=glob()",
                                "a=choice(a,b,x=1)",
                                "a=sort()",
                                "a=shuffle(1,seed=-1)",
                                "a=99999999999999999999",
                                "a='x' 'y'",
                                "a=[1] [2]",
                                "a=~x",
                                "a=range(stop=2)"}) {
    EXPECT_THROW(ParseOverride(bad), ConfigError) << bad;
  }
}

TEST(OverrideParser, ParseOverridesKeepsOrder) {
  const std::vector<Override> overrides = ParseOverrides({"b=1", "a=2", "~c"});
  ASSERT_EQ(overrides.size(), 3u);
  EXPECT_EQ(overrides[0].key, "b");
  EXPECT_EQ(overrides[1].key, "a");
  EXPECT_EQ(overrides[2].key, "c");
  EXPECT_THROW(ParseOverrides({"a=1", "b=[", "c=2"}), ConfigError);
}

TEST(FormatOverrideValue, RendersScalars) {
  EXPECT_EQ(FormatOverrideValue(ConfigNode(1)), "1");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(-20)), "-20");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(1.0)), "1.0");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(0.0)), "0.0");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(-0.5)), "-0.5");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(0.001)), "0.001");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(1e16)), "1e+16");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(1e-7)), "1e-07");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(0.1 + 0.2)), "0.30000000000000004");
  EXPECT_EQ(
      FormatOverrideValue(ConfigNode(std::numeric_limits<double>::infinity())),
      "inf");
  EXPECT_EQ(
      FormatOverrideValue(ConfigNode(-std::numeric_limits<double>::infinity())),
      "-inf");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(std::nan(""))), "nan");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(true)), "true");
  EXPECT_EQ(FormatOverrideValue(ConfigNode(false)), "false");
  EXPECT_EQ(FormatOverrideValue(ConfigNode::Null()), "null");
}

TEST(FormatOverrideValue, QuotesStringsOnlyWhenNeeded) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"abc", "abc"},
      {"hello world", "hello world"},
      {"/data/x-1.txt", "/data/x-1.txt"},
      {"", ""},
      {"1", "'1'"},
      {"1.5", "'1.5'"},
      {"true", "'true'"},
      {"False", "'False'"},
      {"null", "'null'"},
      {"inf", "'inf'"},
      {"a,b", "'a,b'"},
      {"[1]", "'[1]'"},
      {"{a:1}", "'{a:1}'"},
      {"f(x)", "'f(x)'"},
      {"a=b", "'a=b'"},
      {" padded ", "' padded '"},
      {"it's", "'it\\'s'"},
      {"say \"hi\"", "'say \"hi\"'"},
      {"C:\\dir\\", "C:\\dir\\"},
      {"x#y", "'x#y'"},
  };
  for (const auto& [text, expected] : cases) {
    EXPECT_EQ(FormatOverrideValue(ConfigNode::LiteralString(text)), expected)
        << text;
  }
  EXPECT_EQ(FormatOverrideValue(Str("${a.b}")), "${a.b}");
}

TEST(FormatOverrideValue, RendersContainers) {
  EXPECT_EQ(FormatOverrideValue(List({1, Str("a"), List({true})})),
            "[1,a,[true]]");
  EXPECT_EQ(FormatOverrideValue(ConfigNode::EmptyList()), "[]");
  EXPECT_EQ(FormatOverrideValue(ConfigNode::EmptyMap()), "{}");
  EXPECT_EQ(FormatOverrideValue(List({Str(""), Str("x,y")})), "['','x,y']");
  EXPECT_EQ(FormatOverrideValue(Map({{"a", ConfigNode(1)}, {"b", Str("x,y")}})),
            "{a:1,b:'x,y'}");
  EXPECT_EQ(FormatOverrideValue(Map({{"a b", ConfigNode(1)}})), "{a\\ b:1}");
}

TEST(FormatOverrideValue, RoundTripsThroughTheParser) {
  const std::vector<ConfigNode> values = {
      ConfigNode(0),
      ConfigNode(-7),
      ConfigNode(int64_t{9007199254740993}),
      ConfigNode(0.1),
      ConfigNode(-2.5e-12),
      ConfigNode(1e300),
      ConfigNode(123456789.125),
      ConfigNode(true),
      ConfigNode::Null(),
      Str("abc"),
      Str(""),
      Str("1_000"),
      Str("01"),
      Str("yes"),
      Str("a\\'b"),
      Str("\\"),
      Str("\\\\"),
      Str("'"),
      Str("\""),
      Str("x'"),
      Str("ends with \\"),
      Str("a, b"),
      Str("  padded  "),
      Str("tab\there"),
      Str("${a}"),
      Str("${a}, ${b}"),
      Str("key: value"),
      Str("~home"),
      List({Str(""), Str("a,b"), List({ConfigNode(1.0), Str("true")})}),
      Map({{"x", Str("[1]")}, {"y", Map({{"z", ConfigNode::Null()}})}}),
  };
  for (const ConfigNode& v : values) {
    const std::string text = "k=" + FormatOverrideValue(v);
    const Override o = ParseOverride(text);
    ASSERT_FALSE(o.IsSweep()) << text;
    ASSERT_TRUE(o.value.has_value()) << text;
    EXPECT_EQ(*o.value, v) << text;
  }
}

// Found by the override fuzzer (tests/fuzz/corpus/override/): `m=a\\,b` is
// the sweep `a\`, `b`; written back unquoted, `a\,b` was one string.
TEST(OverrideToString, QuotesElementsEndingInABackslash) {
  const Override o = ParseOverride("m=a\\\\,b");
  ASSERT_TRUE(o.IsSweep());
  ASSERT_EQ(o.sweep->values.size(), 2u);
  EXPECT_EQ(o.sweep->values[0].AsString(), "a\\");
  EXPECT_EQ(o.ToString(), "m='a\\\\',b");
  const Override again = ParseOverride(o.ToString());
  ASSERT_TRUE(again.IsSweep());
  EXPECT_EQ(again.sweep->values, o.sweep->values);
  EXPECT_EQ(FormatOverrideValue(List({Str("a\\"), Str("b")})), "['a\\\\',b]");
  EXPECT_EQ(FormatOverrideValue(Str("a\\")), "a\\");  // alone: no quotes
}

// Found by the override fuzzer (tests/fuzz/corpus/override/): the lexer
// copies `${...}` inside quotes verbatim, so a quote in it is not escaped.
TEST(OverrideToString, KeepsQuotesInsideInterpolationsOfQuotedStrings) {
  const Override o = ParseOverride(R"(c="x \"q' ${x[u' }")");
  ASSERT_TRUE(o.value.has_value());
  EXPECT_EQ(o.value->text(), "x \"q' ${x[u' }");
  EXPECT_EQ(o.ToString(), R"(c='x "q\' ${x[u' }')");
  const Override again = ParseOverride(o.ToString());
  ASSERT_TRUE(again.value.has_value());
  EXPECT_EQ(*again.value, *o.value);
}

// Found by an exploratory override-fuzzer session
// (tests/fuzz/corpus/override/): the string `${` (from the escaped `$\{`) opens
// no interpolation; quoted as
// `'${'` the lexer read an interpolation through the closing quote and the
// `}` after it. It is written unquoted with its braces escaped instead.
TEST(OverrideToString, WritesAnUnclosedInterpolationOpenerEscaped) {
  const Override o = ParseOverride(R"(d={a:$\{})");
  ASSERT_TRUE(o.value.has_value());
  EXPECT_EQ(o.value->at("a").text(), "${");
  EXPECT_EQ(o.ToString(), R"(d={a:$\{})");
  const Override again = ParseOverride(o.ToString());
  ASSERT_TRUE(again.value.has_value());
  EXPECT_EQ(*again.value, *o.value);
}

// Found by the CI run of the override fuzzer (tests/fuzz/corpus/override/):
// the escaped form of a string holding an unclosed `${` must keep its
// complete interpolations verbatim (`${x' }` contains a quote, which an
// unquoted value can only hold inside an interpolation); escaping their
// braces made it unparsable and the quoted fallback read `${c:'}` through
// the closing quote.
TEST(OverrideToString, EscapesAroundCompleteInterpolationsOfAnUnclosedOpener) {
  const Override o = ParseOverride(R"(d={a:\{i ${x' }:f$\{c:})");
  ASSERT_TRUE(o.value.has_value());
  EXPECT_EQ(o.value->at("a").text(), "{i ${x' }:f${c:");
  EXPECT_EQ(o.ToString(), R"(d={a:\{i\ ${x' }\:f$\{c\:})");
  const Override again = ParseOverride(o.ToString());
  ASSERT_TRUE(again.value.has_value());
  EXPECT_EQ(*again.value, *o.value);
}

TEST(OverrideToString, IsCanonical) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"a=1", "a=1"},
      {"+a=1", "+a=1"},
      {"++a.b=x", "++a.b=x"},
      {"~a", "~a"},
      {"~a=1", "~a=1"},
      {"a=", "a="},
      {"a=  abc  ", "a=abc"},
      {"a='1'", "a='1'"},
      {"a=\"a,b\"", "a='a,b'"},
      {"a=True", "a=true"},
      {"a=1_000", "a=1000"},
      {"a=1e-3", "a=0.001"},
      {"a=[1, 2]", "a=[1,2]"},
      {"a={x: 1}", "a={x:1}"},
      {"server/db@src=sqlite", "server/db@src=sqlite"},
      {"a=1,2", "a=1,2"},
      {"a=choice(1)", "a=choice(1)"},
      {"a='',x", "a='',x"},
      {"a=range(3)", "a=0,1,2"},
      {"a=sort(3,1,2)", "a=1,2,3"},
      {"a=glob(*,exclude=x*)", "a=glob([*],exclude=[x*])"},
      {"a=glob([a*,b*])", "a=glob([a*,b*])"},
      {"a=${b}", "a=${b}"},
  };
  for (const auto& [input, expected] : cases) {
    const Override o = ParseOverride(input);
    EXPECT_EQ(o.ToString(), expected) << input;
    EXPECT_EQ(o.input, input);
    // The canonical string parses to the same override.
    const Override again = ParseOverride(o.ToString());
    EXPECT_EQ(again.ToString(), o.ToString()) << input;
  }
  const Override shuffled = ParseOverride("a=shuffle(1,2,3,seed=4)");
  const Override again = ParseOverride(shuffled.ToString());
  EXPECT_EQ(SweepValues(*again.sweep), SweepValues(*shuffled.sweep));
}

}  // namespace
}  // namespace soma
