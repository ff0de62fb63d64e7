#include "framework/config/yaml_io.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace soma {
namespace {

using testing::ErrorMessage;

struct TypingCase {
  std::string yaml;       // the scalar as written after `v: `
  ConfigNode::Type type;  // expected type
  ConfigNode expected;    // expected value (ignored for NaN)
};

const double kInf = std::numeric_limits<double>::infinity();

/// HYDRA.md section 1: OmegaConf (PyYAML SafeLoader, YAML 1.1) typing.
std::vector<TypingCase> TypingCases() {
  using T = ConfigNode::Type;
  return {
      // ints (YAML 1.1: octal, hex, binary, sexagesimal, underscores)
      {"017", T::kInt, ConfigNode(15)},
      {"1:20", T::kInt, ConfigNode(80)},
      {"0x1F", T::kInt, ConfigNode(31)},
      {"0b101", T::kInt, ConfigNode(5)},
      {"1_000", T::kInt, ConfigNode(1000)},
      {"42", T::kInt, ConfigNode(42)},
      {"-7", T::kInt, ConfigNode(-7)},
      {"+3", T::kInt, ConfigNode(3)},
      {"0", T::kInt, ConfigNode(0)},
      {"-0x10", T::kInt, ConfigNode(-16)},
      {"190:20:30", T::kInt, ConfigNode(190 * 3600 + 20 * 60 + 30)},
      // floats (OmegaConf adds `1e-3` without a dot)
      {"1e-3", T::kDouble, ConfigNode(0.001)},
      {"1.5", T::kDouble, ConfigNode(1.5)},
      {"1_000.5", T::kDouble, ConfigNode(1000.5)},
      {"1.", T::kDouble, ConfigNode(1.0)},
      {".5", T::kDouble, ConfigNode(0.5)},
      {"6.8523015e+5", T::kDouble, ConfigNode(685230.15)},
      {"1E3", T::kDouble, ConfigNode(1000.0)},
      {"-2.5e-2", T::kDouble, ConfigNode(-0.025)},
      {"1:30.5", T::kDouble, ConfigNode(90.5)},
      {".inf", T::kDouble, ConfigNode(kInf)},
      {"-.inf", T::kDouble, ConfigNode(-kInf)},
      {"+.Inf", T::kDouble, ConfigNode(kInf)},
      {".nan", T::kDouble, ConfigNode(std::nan(""))},
      {".NaN", T::kDouble, ConfigNode(std::nan(""))},
      // bools (YAML 1.1; y/n are strings)
      {"yes", T::kBool, ConfigNode(true)},
      {"Yes", T::kBool, ConfigNode(true)},
      {"NO", T::kBool, ConfigNode(false)},
      {"true", T::kBool, ConfigNode(true)},
      {"False", T::kBool, ConfigNode(false)},
      {"on", T::kBool, ConfigNode(true)},
      {"Off", T::kBool, ConfigNode(false)},
      {"OFF", T::kBool, ConfigNode(false)},
      {"y", T::kString, ConfigNode("y")},
      {"n", T::kString, ConfigNode("n")},
      {"tRue", T::kString, ConfigNode("tRue")},
      // null
      {"~", T::kNull, ConfigNode::Null()},
      {"null", T::kNull, ConfigNode::Null()},
      {"Null", T::kNull, ConfigNode::Null()},
      {"NULL", T::kNull, ConfigNode::Null()},
      {"", T::kNull, ConfigNode::Null()},
      // strings: quoted, timestamps, near-misses
      {"'1'", T::kString, ConfigNode("1")},
      {"\"true\"", T::kString, ConfigNode("true")},
      {"'null'", T::kString, ConfigNode("null")},
      {"2024-01-01", T::kString, ConfigNode("2024-01-01")},
      {"2001-12-14t21:59:43.10-05:00",
       T::kString,
       ConfigNode("2001-12-14t21:59:43.10-05:00")},
      {"0o17", T::kString, ConfigNode("0o17")},
      {"08", T::kString, ConfigNode("08")},
      {"inf", T::kString, ConfigNode("inf")},
      {"nan", T::kString, ConfigNode("nan")},
      {"1.2.3", T::kString, ConfigNode("1.2.3")},
      {"abc", T::kString, ConfigNode("abc")},
      {"hello world", T::kString, ConfigNode("hello world")},
      // special states
      {"???", T::kMissing, ConfigNode::Missing()},
      {"'\?\?\?'", T::kMissing, ConfigNode::Missing()},
      {"${a.b}", T::kInterpolation, ConfigNode::FromString("${a.b}")},
      {"'${a.b}'", T::kInterpolation, ConfigNode::FromString("${a.b}")},
      {"!!str 123", T::kString, ConfigNode("123")},
      {"!!str yes", T::kString, ConfigNode("yes")},
      {"!!int '7'", T::kInt, ConfigNode(7)},
      {"!!float 1", T::kDouble, ConfigNode(1.0)},
  };
}

TEST(ParseYaml, TypesScalarsLikeOmegaConf) {
  for (const TypingCase& c : TypingCases()) {
    SCOPED_TRACE("v: " + c.yaml);
    const ConfigNode root = ParseYaml("v: " + c.yaml + "\n", "test.yaml");
    ASSERT_TRUE(root.IsMap());
    const ConfigNode& value = root.at("v");
    EXPECT_EQ(value.type(), c.type)
        << ConfigNode::TypeName(value.type()) << " " << value.Describe();
    EXPECT_EQ(value, c.expected) << value.Describe();
  }
}

TEST(TypePlainScalar, MatchesTheTableForPlainScalars) {
  for (const TypingCase& c : TypingCases()) {
    if (c.yaml.find_first_of("'\"!") != std::string::npos) continue;
    SCOPED_TRACE(c.yaml);
    const ConfigNode value = TypePlainScalar(c.yaml);
    EXPECT_EQ(value.type(), c.type);
    EXPECT_EQ(value, c.expected);
  }
}

// PyYAML's bool and null resolvers match whole words in three spellings
// (lower, Capitalised, UPPER); anything else is a string.
TEST(TypePlainScalar, BoolAndNullWordsMatchExactly) {
  for (const char* word :
       {"yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON"}) {
    EXPECT_EQ(TypePlainScalar(word), ConfigNode(true)) << word;
  }
  for (const char* word :
       {"no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF"}) {
    EXPECT_EQ(TypePlainScalar(word), ConfigNode(false)) << word;
  }
  for (const char* word : {"", "~", "null", "Null", "NULL"}) {
    EXPECT_TRUE(TypePlainScalar(word).IsNull()) << word;
  }
  for (const char* word : {"yES",
                           "tRUE",
                           "oN",
                           "nULL",
                           "Nul",
                           "nulls",
                           "~~",
                           "yess",
                           "ye",
                           "o",
                           "y",
                           "n",
                           "truefalse",
                           "TRUE "}) {
    EXPECT_EQ(TypePlainScalar(word), ConfigNode(std::string(word))) << word;
  }
}

TEST(TypePlainScalar, KeepsTheOriginalText) {
  EXPECT_EQ(TypePlainScalar("1e-3").text(), "1e-3");
  EXPECT_EQ(TypePlainScalar("0x1F").text(), "0x1F");
  EXPECT_EQ(TypePlainScalar("yes").text(), "yes");
  EXPECT_EQ(TypePlainScalar("017").text(), "017");
}

TEST(ParseYaml, BlockScalarsAreStrings) {
  const ConfigNode root = ParseYaml("a: |\n  123\nb: >\n  true\n", "t.yaml");
  EXPECT_EQ(root.at("a").AsString(), "123\n");
  EXPECT_EQ(root.at("b").AsString(), "true\n");
}

TEST(ParseYaml, BuildsNestedTreesWithPathsAndLines) {
  const std::string text =
      "# comment\n"
      "db:\n"
      "  driver: mysql\n"
      "  ports: [3306, 3307]\n"
      "list:\n"
      "  - name: a\n"
      "  - name: b\n";
  const ConfigNode root = ParseYaml(text, "configs/db.yaml");
  EXPECT_EQ(root.Keys(), (std::vector<std::string>{"db", "list"}));
  const ConfigNode& driver = root.at("db").at("driver");
  EXPECT_EQ(driver.AsString(), "mysql");
  EXPECT_EQ(driver.path(), "db.driver");
  EXPECT_EQ(driver.source().ToString(), "configs/db.yaml:3");
  EXPECT_EQ(root.FindPath("db.ports[1]")->AsInt(), 3307);
  EXPECT_EQ(root.FindPath("db.ports[1]")->path(), "db.ports[1]");
  const ConfigNode& b = *root.FindPath("list[1].name");
  EXPECT_EQ(b.path(), "list[1].name");
  EXPECT_EQ(b.source().line, 7);
}

// Found by the config fuzzer (ASan: stack-use-after-scope): the converter
// held references into a yaml-cpp map iterator's temporary. Every block map
// reached it; this one is tests/fuzz/corpus/config/seed-cycle.yaml.
TEST(ParseYaml, MapEntriesKeepKeysValuesAndLines) {
  const ConfigNode root =
      ParseYaml("a: ${b}\nb: ${c}\nc: ${a}\nhydra:\n  job:\n    name: x${a}\n",
                "cycle.yaml");
  EXPECT_EQ(root.Keys(), (std::vector<std::string>{"a", "b", "c", "hydra"}));
  EXPECT_EQ(root.at("a").text(), "${b}");
  EXPECT_EQ(root.at("c").source().line, 3);
  const ConfigNode* name = root.FindPath("hydra.job.name");
  ASSERT_NE(name, nullptr);
  EXPECT_EQ(name->text(), "x${a}");
  EXPECT_EQ(name->source().line, 6);
}

TEST(ParseYaml, MalformedYamlIsOneLineConfigErrorWithLocation) {
  const std::string message = ErrorMessage<ConfigError>(
      [] { ParseYaml("a: 1\nb: [1, 2\nc: 3\n", "bad.yaml"); });
  EXPECT_EQ(message.rfind("bad.yaml:", 0), 0u) << message;
  EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  const std::string indent = ErrorMessage<ConfigError>(
      [] { ParseYaml("a:\n  b: 1\n c: 2\n", "bad2.yaml"); });
  EXPECT_EQ(indent.rfind("bad2.yaml:", 0), 0u) << indent;
}

TEST(ParseYaml, IntegerOverflowIsConfigErrorWithLocation) {
  const std::string message = ErrorMessage<ConfigError>(
      [] { ParseYaml("a: 1\nv: 99999999999999999999\n", "big.yaml"); });
  EXPECT_EQ(message.rfind("big.yaml:2: ", 0), 0u) << message;
  EXPECT_EQ(ParseYaml("v: -9223372036854775808\n", "min.yaml").at("v").AsInt(),
            std::numeric_limits<int64_t>::min());
}

TEST(ParseYaml, UnsupportedTagIsAnError) {
  EXPECT_THROW(ParseYaml("v: !custom x\n", "tag.yaml"), ConfigError);
  EXPECT_TRUE(ParseYaml("v: !!str null\n", "tag.yaml").at("v").IsString());
  EXPECT_TRUE(ParseYaml("v: !!null ''\n", "tag.yaml").at("v").IsNull());
}

TEST(ParseYaml, DuplicateKeysAreRejected) {
  const std::string message = ErrorMessage<ConfigError>(
      [] { ParseYaml("a: 1\nb: 2\na: 3\n", "dup.yaml"); });
  EXPECT_EQ(message, "dup.yaml:3: found duplicate key 'a'");
}

TEST(ParseYaml, MergeKeys) {
  const ConfigNode root = ParseYaml(
      "base: &base\n  a: 1\n  b: 2\nderived:\n  <<: *base\n  b: 3\n  c: 4\n",
      "merge.yaml");
  const ConfigNode& derived = root.at("derived");
  EXPECT_EQ(derived.Keys(), (std::vector<std::string>{"a", "b", "c"}));
  EXPECT_EQ(derived.at("b").AsInt(), 3);
  EXPECT_EQ(derived.at("a").path(), "derived.a");
}

// A config fuzzer finding (tests/fuzz/corpus/config/crash-9138...): an alias
// inside its own anchor's content made the node graph cyclic and the
// conversion overflowed the stack.
TEST(ParseYaml, RecursiveAliasIsAnErrorNotAStackOverflow) {
  const std::string in_map = ErrorMessage<ConfigError>(
      [] { ParseYaml("x: 1\na: &self\n  b: *self\n", "cycle.yaml"); });
  EXPECT_EQ(in_map.rfind("cycle.yaml:3: an alias refers to a node that ", 0),
            0u)
      << in_map;
  EXPECT_THROW(ParseYaml("a: &l [1, *l]\n", "cycle.yaml"), ConfigError);
  EXPECT_THROW(ParseYaml("a: &m\n  c:\n    d: [*m]\n", "cycle.yaml"),
               ConfigError);
  EXPECT_THROW(ParseYaml("a: &m\n  <<: *m\n", "cycle.yaml"), ConfigError);
  // The same node reached twice, but not inside itself, is fine.
  const ConfigNode shared =
      ParseYaml("a: &s {k: 1}\nb: [*s, *s]\nc: *s\n", "shared.yaml");
  EXPECT_EQ(shared.at("b").at(1).at("k").AsInt(), 1);
  EXPECT_EQ(shared.at("c").at("k").AsInt(), 1);
}

TEST(ParseYaml, EmptyDocumentIsNull) {
  EXPECT_TRUE(ParseYaml("", "empty.yaml").IsNull());
  EXPECT_TRUE(ParseYaml("# only a comment\n", "empty.yaml").IsNull());
}

TEST(LoadConfigFile, ReadsPackageDirectiveFromHeader) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(dir,
                         "global.yaml",
                         "# @package _global_\n"
                         "defaults:\n  - override /model: small\n");
  testing::WriteTextFile(dir,
                         "pkg.yaml",
                         "# A description.\n\n"
                         "#   @package   foo.bar  \n"
                         "x: 1\n");
  testing::WriteTextFile(dir, "late.yaml", "x: 1\n# @package _global_\n");
  testing::WriteTextFile(dir, "none.yaml", "x: 1\n");

  const ConfigFile global = LoadConfigFile(dir / "global.yaml");
  EXPECT_TRUE(global.has_package_directive);
  EXPECT_EQ(global.package, "_global_");
  EXPECT_EQ(global.path, (dir / "global.yaml").string());
  EXPECT_EQ(global.content.FindPath("defaults[0]")->Keys(),
            std::vector<std::string>{"override /model"});

  const ConfigFile pkg = LoadConfigFile(dir / "pkg.yaml");
  EXPECT_TRUE(pkg.has_package_directive);
  EXPECT_EQ(pkg.package, "foo.bar");

  EXPECT_FALSE(LoadConfigFile(dir / "late.yaml").has_package_directive);
  const ConfigFile none = LoadConfigFile(dir / "none.yaml");
  EXPECT_FALSE(none.has_package_directive);
  EXPECT_EQ(none.package, "");
  EXPECT_EQ(none.content.at("x").source().ToString(),
            (dir / "none.yaml").string() + ":1");
}

TEST(LoadConfigFile, EmptyFileIsAnEmptyMap) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(dir, "empty.yaml", "");
  testing::WriteTextFile(dir, "comments.yaml", "# @package _global_\n");
  const ConfigFile empty = LoadConfigFile(dir / "empty.yaml");
  EXPECT_TRUE(empty.content.IsMap());
  EXPECT_EQ(empty.content.size(), 0u);
  const ConfigFile comments = LoadConfigFile(dir / "comments.yaml");
  EXPECT_TRUE(comments.content.IsMap());
  EXPECT_EQ(comments.package, "_global_");
}

TEST(LoadConfigFile, TopLevelMustBeAMap) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(dir, "list.yaml", "- a\n- b\n");
  const std::string path = (dir / "list.yaml").string();
  EXPECT_EQ(ErrorMessage<ConfigError>([&] { LoadConfigFile(path); }),
            path + ": expected a map at the top level");
}

TEST(LoadConfigFile, MissingFileNamesThePath) {
  const auto dir = testing::CreateTestDir();
  const std::string path = (dir / "nope.yaml").string();
  const std::string message =
      ErrorMessage<ConfigError>([&] { LoadConfigFile(path); });
  EXPECT_NE(message.find(path), std::string::npos) << message;
}

TEST(DumpYaml, BlockStyleKeepsOrderAndOriginalText) {
  const std::string text =
      "name: app\n"
      "lr: 1e-3\n"
      "mask: 0x1F\n"
      "flag: yes\n"
      "nothing: null\n"
      "required: ???\n"
      "url: http://${server.host}:${server.port}/\n"
      "db:\n"
      "  driver: mysql\n"
      "  port: 3306\n"
      "empty_map: {}\n"
      "empty_list: []\n"
      "layers:\n"
      "- 1\n"
      "- 2\n"
      "items:\n"
      "- name: a\n"
      "  tags:\n"
      "  - x\n"
      "  - y\n"
      "- - 1\n"
      "  - 2\n"
      "- []\n";
  const ConfigNode root = ParseYaml(text, "in.yaml");
  EXPECT_EQ(DumpYaml(root), text);
}

TEST(DumpYaml, QuotesStringsThatWouldBeRetyped) {
  ConfigNode root;
  root.Set("one", ConfigNode::LiteralString("1"));
  root.Set("yes", ConfigNode::LiteralString("true"));
  root.Set("null_str", ConfigNode::LiteralString("null"));
  root.Set("empty", ConfigNode::LiteralString(""));
  root.Set("colon", ConfigNode::LiteralString("a: b"));
  root.Set("hash", ConfigNode::LiteralString("a #b"));
  root.Set("star", ConfigNode::LiteralString("*x"));
  root.Set("quote", ConfigNode::LiteralString("it's"));
  root.Set("lead", ConfigNode::LiteralString("'x'"));
  root.Set("date", ConfigNode::LiteralString("2024-01-01"));
  root.Set("float", ConfigNode::LiteralString("1e-3"));
  root.Set("newline", ConfigNode::LiteralString("a\nb"));
  root.Set("literal", ConfigNode::LiteralString("${not.interp}"));
  root.Set("missing_str", ConfigNode::LiteralString("-"));
  EXPECT_EQ(DumpYaml(root),
            "one: '1'\n"
            "'yes': 'true'\n"
            "null_str: 'null'\n"
            "empty: ''\n"
            "colon: 'a: b'\n"
            "hash: 'a #b'\n"
            "star: '*x'\n"
            "quote: it's\n"
            "lead: '''x'''\n"
            "date: 2024-01-01\n"
            "float: '1e-3'\n"
            "newline: \"a\\nb\"\n"
            "literal: \\${not.interp}\n"
            "missing_str: '-'\n");
}

// OmegaConf's to_yaml of a resolved config (Hydra's `--cfg job --resolve`)
// prints a string's value: a literal `${` is not escaped.
TEST(DumpYaml, UnescapedModeWritesStringValuesAsPyYamlDoes) {
  ConfigNode root;
  root.Set("literal", ConfigNode::LiteralString("${a}"));
  root.Set("inside", ConfigNode::LiteralString("x ${a} y"));
  root.Set("backslash", ConfigNode::LiteralString("\\${a}"));
  root.Set("one", ConfigNode::LiteralString("1"));
  root.Set("plain", ConfigNode::LiteralString("hello"));
  root.Set("n", 3);
  DumpOptions options;
  options.escape_interpolations = false;
  EXPECT_EQ(DumpYaml(root, options),
            "literal: ${a}\n"
            "inside: x ${a} y\n"
            "backslash: \\${a}\n"
            "one: '1'\n"
            "plain: hello\n"
            "n: 3\n");
  EXPECT_EQ(DumpYaml(root).rfind("literal: \\${a}\n", 0), 0u);
}

TEST(DumpYaml, RoundTripsAMixedTree) {
  ConfigNode root;
  root.Set("i", 42);
  root.Set("neg", -7);
  root.Set("d", 0.1);
  root.Set("tiny", 1e-20);
  root.Set("whole", 3.0);
  root.Set("inf", std::numeric_limits<double>::infinity());
  root.Set("nan", std::nan(""));
  root.Set("b", false);
  root.Set("n", ConfigNode::Null());
  root.Set("m", ConfigNode::Missing());
  root.Set("s", "plain text");
  root.Set("tricky", ConfigNode::LiteralString(" padded: #x "));
  root.Set("backslash", ConfigNode::LiteralString("\\${x} and \\\\${y}"));
  root.Set("interp", ConfigNode::FromString("${a.b}_${now:%Y-%m-%d}"));
  root.Set("bool_text", ConfigNode::LiteralString("Off"));
  root.Set("int_text", ConfigNode::LiteralString("0b11"));
  root.SetPath("nested.deeper.list", ConfigNode::EmptyList());
  ConfigNode& list = root.at("nested").at("deeper").at("list");
  list.Append(1);
  list.Append(ConfigNode::EmptyMap());
  ConfigNode inner;
  inner.Set("k", "v");
  inner.Set("l", ConfigNode::EmptyList());
  inner.at("l").Append("x");
  list.Append(inner);
  ConfigNode sub = ConfigNode::EmptyList();
  sub.Append(true);
  sub.Append(ConfigNode::LiteralString("true"));
  list.Append(sub);
  root.Set("empty_map", ConfigNode::EmptyMap());
  root.Set("empty_list", ConfigNode::EmptyList());

  const std::string dumped = DumpYaml(root);
  const ConfigNode parsed = ParseYaml(dumped, "dumped.yaml");
  EXPECT_EQ(parsed, root) << dumped;
  EXPECT_EQ(parsed.Keys(), root.Keys());
  EXPECT_EQ(DumpYaml(parsed), dumped);
}

// Found by the config fuzzer (tests/fuzz/corpus/config/): a key longer than
// YAML's 1024-character limit for implicit keys did not parse back.
TEST(DumpYaml, KeysOverTheImplicitKeyLimitAreExplicit) {
  const std::string limit(1024, 'k');
  const std::string longer(1025, 'k');
  const std::string quoted = " a: b # " + std::string(1100, 'q');
  ConfigNode root;
  root.Set(limit, 1);
  root.Set(longer, 2);
  root.Set(quoted, ConfigNode::Null());
  root.SetPath("nested.x", ConfigNode::EmptyMap());
  root.at("nested").at("x").Set(longer, ConfigNode::EmptyList());
  root.at("nested").at("x").at(longer).Append("item");
  root.at("nested").at("x").Set(limit, ConfigNode::EmptyMap());
  root.at("nested").at("x").at(limit).Set("k", "v");
  const std::string dumped = DumpYaml(root);
  EXPECT_EQ(dumped.rfind(limit + ": 1\n", 0), 0u);
  EXPECT_NE(dumped.find("? " + longer + "\n: 2\n"), std::string::npos);
  const ConfigNode parsed = ParseYaml(dumped, "dumped.yaml");
  EXPECT_EQ(parsed, root) << dumped;
  EXPECT_EQ(parsed.Keys(), root.Keys());
  EXPECT_EQ(DumpYaml(parsed), dumped);
}

// Found by the config fuzzer (tests/fuzz/corpus/config/): the key `<<` of
// a tagged scalar (`!name<<: {a}`) is not a merge key, but written plain it
// read back as one.
TEST(DumpYaml, QuotesAKeyNamedLikeTheMergeKey) {
  const ConfigNode root = ParseYaml("job:\n  !name<<: {a}\n", "t.yaml");
  ASSERT_TRUE(root.at("job").Has("<<"));
  const std::string dumped = DumpYaml(root);
  EXPECT_EQ(dumped, "job:\n  '<<':\n    a: null\n");
  EXPECT_EQ(ParseYaml(dumped, "dumped.yaml"), root);
}

// Found by an exploratory config-fuzzer session (tests/fuzz/corpus/config/):
// a first key starting with FE FF was written plain at the start of the
// document, where a YAML reader takes it for a UTF-16 byte-order mark.
TEST(DumpYaml, QuotesScalarsStartingWithByteOrderMarkBytes) {
  for (const std::string key :
       {"\xfe\xff\xff\xc9", "\xff\xfeab", "\xef\xbb\xbfk"}) {
    ConfigNode root;
    root.Set(key, "local");
    root.Set("b", key);
    const std::string dumped = DumpYaml(root);
    EXPECT_EQ(dumped.front(), '\'') << dumped;
    EXPECT_EQ(ParseYaml(dumped, "dumped.yaml"), root) << dumped;
  }
}

TEST(DumpYaml, ScalarsAndEmptyRoots) {
  EXPECT_EQ(DumpYaml(ConfigNode::EmptyMap()), "{}\n");
  EXPECT_EQ(DumpYaml(ConfigNode::EmptyList()), "[]\n");
  EXPECT_EQ(DumpYaml(ConfigNode(5)), "5\n");
  ConfigNode list;
  list.Append("a");
  list.Append(1);
  EXPECT_EQ(DumpYaml(list), "- a\n- 1\n");
}

TEST(DumpYaml, CustomIndent) {
  ConfigNode root;
  root.SetPath("a.b.c", 1);
  EXPECT_EQ(DumpYaml(root, DumpOptions{4}), "a:\n    b:\n        c: 1\n");
}

TEST(DumpFlow, CompactOneLine) {
  ConfigNode root;
  root.Set("a", 1);
  root.Set("b", ConfigNode::EmptyList());
  root.at("b").Append("x");
  root.at("b").Append(2.5);
  EXPECT_EQ(DumpFlow(root), "{a:1,b:[x,2.5]}");
  ConfigNode list;
  list.Append(1);
  list.Append(2);
  list.Append("a");
  EXPECT_EQ(DumpFlow(list), "[1,2,a]");
  EXPECT_EQ(DumpFlow(ConfigNode("abc")), "abc");
  EXPECT_EQ(DumpFlow(ConfigNode("a b/c")), "a b/c");
  EXPECT_EQ(DumpFlow(ConfigNode::LiteralString("1")), "'1'");
  EXPECT_EQ(DumpFlow(ConfigNode::LiteralString("True")), "'True'");
  EXPECT_EQ(DumpFlow(ConfigNode::LiteralString("a,b")), "'a,b'");
  EXPECT_EQ(DumpFlow(ConfigNode::LiteralString("")), "''");
  EXPECT_EQ(DumpFlow(ConfigNode::LiteralString("it's, ok")), "'it\\'s, ok'");
  EXPECT_EQ(DumpFlow(ConfigNode::Null()), "null");
  EXPECT_EQ(DumpFlow(ConfigNode::Missing()), "???");
  EXPECT_EQ(DumpFlow(ConfigNode(true)), "true");
  EXPECT_EQ(DumpFlow(ConfigNode(1e-5)), "1e-05");
  EXPECT_EQ(DumpFlow(ConfigNode::FromString("${a.b}")), "${a.b}");
  EXPECT_EQ(DumpFlow(ConfigNode::EmptyMap()), "{}");
  EXPECT_EQ(DumpFlow(TypePlainScalar("0x1F")), "31");
}

}  // namespace
}  // namespace soma
