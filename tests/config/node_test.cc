#include "framework/config/node.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace soma {
namespace {

/// Runs `fn` and returns the message of the exception of type E it throws.
using testing::ErrorMessage;

ConfigNode MakeTrainConfig() {
  ConfigNode root = ConfigNode::EmptyMap();
  root.SetPath("train.batch_size", ConfigNode::Missing());
  root.SetPath("train.lr", 0.001);
  root.SetPath("model.num_layers", ConfigNode::LiteralString("abc"));
  root.SetPath("model.name", "transformer");
  return root;
}

TEST(ConfigNode, DefaultIsNull) {
  const ConfigNode node;
  EXPECT_TRUE(node.IsNull());
  EXPECT_TRUE(node.IsScalar());
  EXPECT_FALSE(node.IsContainer());
  EXPECT_EQ(node.size(), 0u);
  EXPECT_EQ(node.path(), "");
}

TEST(ConfigNode, ScalarConstructors) {
  EXPECT_TRUE(ConfigNode(true).AsBool());
  EXPECT_EQ(ConfigNode(42).AsInt(), 42);
  EXPECT_EQ(ConfigNode(int64_t{1} << 40).AsInt(), int64_t{1} << 40);
  EXPECT_DOUBLE_EQ(ConfigNode(0.5).AsDouble(), 0.5);
  EXPECT_EQ(ConfigNode("abc").AsString(), "abc");
  EXPECT_EQ(ConfigNode(std::string("abc")).AsString(), "abc");
  EXPECT_EQ(ConfigNode(std::string_view("abc")).AsString(), "abc");
  EXPECT_EQ(ConfigNode(42).text(), "42");
  EXPECT_EQ(ConfigNode(0.1).text(), "0.1");
  EXPECT_EQ(ConfigNode(false).text(), "false");
}

TEST(ConfigNode, AsDoubleAcceptsInt) {
  EXPECT_DOUBLE_EQ(ConfigNode(3).AsDouble(), 3.0);
}

TEST(ConfigNode, TypeMismatchNamesPathValueTypeAndSource) {
  ConfigNode root = MakeTrainConfig();
  root.at("model").at("num_layers").set_source({"configs/model/x.yaml", 3});
  const std::string message = ErrorMessage<ConfigError>(
      [&] { root.at("model").at("num_layers").AsInt(); });
  EXPECT_EQ(message,
            "Invalid configuration. model.num_layers = 'abc'. Expected type "
            "int (configs/model/x.yaml:3)");
  EXPECT_THROW(ConfigNode(1).AsString(), ConfigError);
  EXPECT_THROW(ConfigNode(1.5).AsInt(), ConfigError);
  EXPECT_THROW(ConfigNode("true").AsBool(), ConfigError);
}

TEST(ConfigNode, MissingThrowsMissingMandatoryValueWithFullPath) {
  const ConfigNode root = MakeTrainConfig();
  const ConfigNode& batch = root.at("train").at("batch_size");
  EXPECT_TRUE(batch.IsMissing());
  const std::string message =
      ErrorMessage<MissingMandatoryValue>([&] { batch.AsInt(); });
  EXPECT_EQ(message.rfind("MissingMandatoryValue: train.batch_size", 0), 0u)
      << message;
  EXPECT_THROW(batch.AsString(), MissingMandatoryValue);
  EXPECT_THROW(batch.AsDouble(), MissingMandatoryValue);
  EXPECT_THROW(batch.AsBool(), MissingMandatoryValue);
}

TEST(ConfigNode, MissingMessageIncludesSourceWhenKnown) {
  ConfigNode root = MakeTrainConfig();
  root.at("train").at("batch_size").set_source({"configs/train.yaml", 7});
  EXPECT_EQ(ErrorMessage<MissingMandatoryValue>(
                [&] { root.at("train").at("batch_size").AsInt(); }),
            "MissingMandatoryValue: train.batch_size (configs/train.yaml:7)");
}

TEST(ConfigNode, ReadingAnUnresolvedInterpolationThrows) {
  const ConfigNode node = ConfigNode::FromString("${a}");
  EXPECT_THROW(node.AsString(), ConfigError);
  EXPECT_THROW(node.AsInt(), ConfigError);
}

TEST(ConfigNode, FromStringDetectsInterpolationsAndEscapes) {
  EXPECT_TRUE(ConfigNode::FromString("${a.b}").IsInterpolation());
  EXPECT_TRUE(ConfigNode::FromString("x_${a}_y").IsInterpolation());
  EXPECT_TRUE(ConfigNode::FromString("${oc.env:HOME}").IsInterpolation());
  EXPECT_TRUE(ConfigNode::FromString("plain").IsString());
  EXPECT_TRUE(ConfigNode::FromString("$a {b}").IsString());
  EXPECT_TRUE(ConfigNode::FromString("???").IsMissing());

  const ConfigNode escaped = ConfigNode::FromString("\\${foo}");
  ASSERT_TRUE(escaped.IsString());
  EXPECT_EQ(escaped.text(), "\\${foo}");
  EXPECT_EQ(escaped.AsString(), "${foo}");

  // An escaped backslash before `${` leaves a real interpolation.
  EXPECT_TRUE(ConfigNode::FromString("\\\\${foo}").IsInterpolation());
  const ConfigNode odd = ConfigNode::FromString("\\\\\\${foo}");
  ASSERT_TRUE(odd.IsString());
  EXPECT_EQ(odd.AsString(), "\\${foo}");
  // Backslashes elsewhere are kept verbatim.
  EXPECT_EQ(ConfigNode::FromString("C:\\dir\\x").AsString(), "C:\\dir\\x");
}

TEST(ConfigNode, LiteralStringIsNeverAnInterpolation) {
  const ConfigNode node = ConfigNode::LiteralString("${x} and ???");
  ASSERT_TRUE(node.IsString());
  EXPECT_EQ(node.AsString(), "${x} and ???");
  EXPECT_EQ(node.text(), "\\${x} and ???");
  EXPECT_EQ(ConfigNode::FromString(node.text()), node);
  EXPECT_TRUE(ConfigNode::LiteralString("???").IsString());
}

TEST(ConfigNode, CopiesAreDeep) {
  ConfigNode original = MakeTrainConfig();
  ConfigNode copy = original;
  copy.at("train").Set("lr", 0.5);
  copy.at("model").Erase("name");
  EXPECT_DOUBLE_EQ(original.at("train").at("lr").AsDouble(), 0.001);
  EXPECT_TRUE(original.at("model").Has("name"));
  ConfigNode assigned;
  assigned = original;
  assigned.at("train").Set("lr", 0.7);
  EXPECT_DOUBLE_EQ(original.at("train").at("lr").AsDouble(), 0.001);
}

TEST(ConfigNode, MapKeepsInsertionOrderAndReplacesInPlace) {
  ConfigNode map;
  map.Set("z", 1);
  map.Set("a", 2);
  map.Set("m", 3);
  map.Set("a", 20);
  EXPECT_TRUE(map.IsMap());
  EXPECT_EQ(map.Keys(), (std::vector<std::string>{"z", "a", "m"}));
  EXPECT_EQ(map.at("a").AsInt(), 20);
  EXPECT_TRUE(map.Erase("z"));
  EXPECT_FALSE(map.Erase("z"));
  EXPECT_EQ(map.Keys(), (std::vector<std::string>{"a", "m"}));
  EXPECT_EQ(map.entries().size(), 2u);
  EXPECT_EQ(map.Find("nope"), nullptr);
}

TEST(ConfigNode, AtOnAbsentKeyNamesFullPath) {
  ConfigNode root = MakeTrainConfig();
  const std::string message =
      ErrorMessage<ConfigError>([&] { root.at("train").at("epochs"); });
  EXPECT_NE(message.find("train.epochs"), std::string::npos) << message;
  EXPECT_THROW(root.at("train").at("lr").at("x"), ConfigError);
}

TEST(ConfigNode, ListAccess) {
  ConfigNode list;
  list.Append(1);
  list.Append("two");
  EXPECT_TRUE(list.IsList());
  EXPECT_EQ(list.size(), 2u);
  EXPECT_EQ(list.at(size_t{1}).AsString(), "two");
  EXPECT_THROW(list.at(size_t{2}), ConfigError);
  EXPECT_EQ(list.items().size(), 2u);
  EXPECT_TRUE(ConfigNode(1).items().empty());
  EXPECT_TRUE(ConfigNode(1).entries().empty());
  EXPECT_THROW(ConfigNode(1).Append(2), ConfigError);
  EXPECT_THROW(ConfigNode(1).Set("a", 2), ConfigError);
}

TEST(ConfigNode, PathsAreMaintainedOnInsertion) {
  ConfigNode root;
  ConfigNode b = ConfigNode::EmptyList();
  b.Append(0);
  b.Append(1);
  ConfigNode item;
  item.Set("c", 5);
  b.Append(item);
  ConfigNode a;
  a.Set("b", b);
  root.Set("a", a);
  EXPECT_EQ(root.path(), "");
  EXPECT_EQ(root.at("a").path(), "a");
  EXPECT_EQ(root.at("a").at("b").path(), "a.b");
  EXPECT_EQ(root.at("a").at("b").at(size_t{2}).path(), "a.b[2]");
  EXPECT_EQ(root.at("a").at("b").at(size_t{2}).at("c").path(), "a.b[2].c");

  // Moving a subtree elsewhere re-bases it.
  ConfigNode other;
  other.Set("x", root.at("a"));
  EXPECT_EQ(other.at("x").at("b").at(size_t{2}).at("c").path(), "x.b[2].c");
  ConfigNode copy = root.at("a").at("b");
  copy.SetPath(std::string("y"));
  EXPECT_EQ(copy.at(size_t{0}).path(), "y[0]");
}

TEST(ConfigNode, AssignKeepsPathAndStructMode) {
  ConfigNode root = MakeTrainConfig();
  root.set_struct_mode(true);
  ConfigNode value;
  value.Set("inner", 1);
  root.FindPath("train.lr")->Assign(value);
  EXPECT_EQ(root.at("train").at("lr").path(), "train.lr");
  EXPECT_EQ(root.at("train").at("lr").at("inner").path(), "train.lr.inner");
  ConfigNode replacement = ConfigNode::EmptyMap();
  root.Assign(replacement);
  EXPECT_TRUE(root.struct_mode());
}

TEST(ConfigNode, StructModeIsKeptOnCopy) {
  ConfigNode root = MakeTrainConfig();
  root.set_struct_mode(true);
  const ConfigNode copy = root;
  EXPECT_TRUE(copy.struct_mode());
}

TEST(ConfigNode, FindPathSupportsDotsBracketsAndNumericSegments) {
  ConfigNode root;
  root.SetPath("a.b", ConfigNode::EmptyList());
  root.at("a").at("b").Append("x");
  root.at("a").at("b").Append("y");
  root.SetPath("a.c.d", 4);
  EXPECT_EQ(root.FindPath("a.c.d")->AsInt(), 4);
  EXPECT_EQ(root.FindPath("a.b[1]")->AsString(), "y");
  EXPECT_EQ(root.FindPath("a.b.0")->AsString(), "x");
  EXPECT_EQ(root.FindPath("a.b[2]"), nullptr);
  EXPECT_EQ(root.FindPath("a.nope"), nullptr);
  EXPECT_EQ(root.FindPath("a.c.d.e"), nullptr);
  EXPECT_EQ(root.FindPath(""), &root);
}

TEST(ConfigNode, SetPathCreatesIntermediateMaps) {
  ConfigNode root;
  ConfigNode& set = root.SetPath("db.connection.port", 3306);
  EXPECT_EQ(set.path(), "db.connection.port");
  EXPECT_EQ(root.FindPath("db.connection.port")->AsInt(), 3306);
  root.SetPath("db.connection.port", 5432);
  EXPECT_EQ(root.FindPath("db.connection.port")->AsInt(), 5432);
  root.SetPath("list", ConfigNode::EmptyList());
  root.at("list").Append(1);
  root.SetPath("list[0]", 7);
  root.SetPath("list.1", 8);
  EXPECT_EQ(root.at("list").size(), 2u);
  EXPECT_EQ(root.FindPath("list[1]")->path(), "list[1]");
  EXPECT_THROW(root.SetPath("list[5]", 1), ConfigError);
  EXPECT_THROW(root.SetPath("db.connection.port.x", 1), ConfigError);
}

TEST(ConfigNode, ErasePath) {
  ConfigNode root;
  root.SetPath("a.b", 1);
  root.SetPath("a.c", 2);
  root.SetPath("l", ConfigNode::EmptyList());
  for (int i = 0; i < 3; ++i) root.at("l").Append(i);
  EXPECT_TRUE(root.ErasePath("a.b"));
  EXPECT_FALSE(root.ErasePath("a.b"));
  EXPECT_FALSE(root.ErasePath("x.y"));
  EXPECT_TRUE(root.ErasePath("l[0]"));
  ASSERT_EQ(root.at("l").size(), 2u);
  EXPECT_EQ(root.at("l").at(size_t{0}).AsInt(), 1);
  EXPECT_EQ(root.at("l").at(size_t{0}).path(), "l[0]");
  EXPECT_EQ(root.at("l").at(size_t{1}).path(), "l[1]");
}

TEST(ConfigNode, SplitKeyPath) {
  using V = std::vector<std::string>;
  EXPECT_EQ(SplitKeyPath(""), V{});
  EXPECT_EQ(SplitKeyPath("a"), V{"a"});
  EXPECT_EQ(SplitKeyPath("a.b[2].c"), (V{"a", "b", "2", "c"}));
  EXPECT_EQ(SplitKeyPath("a.b.2.c"), (V{"a", "b", "2", "c"}));
  EXPECT_EQ(SplitKeyPath("a[0][1]"), (V{"a", "0", "1"}));
  EXPECT_EQ(SplitKeyPath("[3]"), V{"3"});
  EXPECT_EQ(SplitKeyPath("plans[key]"), (V{"plans", "key"}));
  for (const char* bad : {"a..b", ".a", "a.", "a[0", "a]", "a[]", "a[0]b"}) {
    EXPECT_THROW(SplitKeyPath(bad), ConfigError) << bad;
  }
}

TEST(ConfigNode, JoinKeyPath) {
  EXPECT_EQ(JoinKeyPath("", "a"), "a");
  EXPECT_EQ(JoinKeyPath("a", "b"), "a.b");
  EXPECT_EQ(JoinKeyPath("a.b[2]", "c"), "a.b[2].c");
}

TEST(ConfigNode, EqualityIsDeepAndIgnoresMetadata) {
  ConfigNode a;
  a.Set("x", 1);
  a.Set("y", "s");
  ConfigNode b;
  b.Set("y", "s");
  b.Set("x", 1);
  b.at("x").set_source({"f.yaml", 2});
  EXPECT_EQ(a, b);  // key order and sources do not matter
  b.Set("x", 1.0);
  EXPECT_NE(a, b);  // int 1 != float 1.0
  EXPECT_EQ(ConfigNode(std::nan("")), ConfigNode(std::nan("")));
  EXPECT_EQ(ConfigNode::Missing(), ConfigNode::Missing());
  EXPECT_NE(ConfigNode::Missing(), ConfigNode::Null());
  EXPECT_NE(ConfigNode::FromString("${a}"), ConfigNode::LiteralString("${a}"));
}

TEST(ConfigNode, Describe) {
  EXPECT_EQ(ConfigNode(1).Describe(), "1");
  EXPECT_EQ(ConfigNode(0.5).Describe(), "0.5");
  EXPECT_EQ(ConfigNode(true).Describe(), "true");
  EXPECT_EQ(ConfigNode::Null().Describe(), "null");
  EXPECT_EQ(ConfigNode("abc").Describe(), "'abc'");
  EXPECT_EQ(ConfigNode::Missing().Describe(), "???");
  EXPECT_EQ(ConfigNode::FromString("${a.b}").Describe(), "${a.b}");
  EXPECT_EQ(MakeTrainConfig().Describe(), "{...}");
  EXPECT_EQ(ConfigNode::EmptyMap().Describe(), "{}");
  EXPECT_EQ(ConfigNode::EmptyList().Describe(), "[]");
  EXPECT_EQ(ConfigNode::LiteralString("a\nb").Describe(), "'a\\nb'");
}

TEST(ConfigNode, TypeName) {
  EXPECT_EQ(ConfigNode::TypeName(ConfigNode::Type::kInt), "int");
  EXPECT_EQ(ConfigNode::TypeName(ConfigNode::Type::kDouble), "float");
  EXPECT_EQ(ConfigNode::TypeName(ConfigNode::Type::kString), "str");
  EXPECT_EQ(ConfigNode::TypeName(ConfigNode::Type::kBool), "bool");
  EXPECT_EQ(ConfigNode::TypeName(ConfigNode::Type::kNull), "None");
  EXPECT_EQ(ConfigNode::TypeName(ConfigNode::Type::kList), "list");
  EXPECT_EQ(ConfigNode::TypeName(ConfigNode::Type::kMap), "dict");
  EXPECT_EQ(ConfigNode::TypeName(ConfigNode::Type::kMissing), "missing");
  EXPECT_EQ(ConfigNode::TypeName(ConfigNode::Type::kInterpolation),
            "interpolation");
}

TEST(ConfigNode, SetSourceRecursiveFillsOnlyUnknownSources) {
  ConfigNode root = MakeTrainConfig();
  root.at("train").at("lr").set_source({"a.yaml", 4});
  root.SetSourceRecursive({"b.yaml", 0});
  EXPECT_EQ(root.at("train").at("lr").source().ToString(), "a.yaml:4");
  EXPECT_EQ(root.at("model").at("name").source().ToString(), "b.yaml");
  EXPECT_EQ(SourceLocation{}.ToString(), "");
}

TEST(FormatDouble, MatchesPythonRepr) {
  const std::vector<std::pair<double, std::string>> cases = {
      {0.1, "0.1"},
      {1.0, "1.0"},
      {-2.5, "-2.5"},
      {0.001, "0.001"},
      {0.0001, "0.0001"},
      {1e-05, "1e-05"},
      {1.5e-07, "1.5e-07"},
      {123456789.0, "123456789.0"},
      {1e15, "1000000000000000.0"},
      {1e16, "1e+16"},
      {1.25e20, "1.25e+20"},
      {0.0, "0.0"},
      {-0.0, "-0.0"},
      {1.0 / 3.0, "0.3333333333333333"},
      {std::numeric_limits<double>::infinity(), "inf"},
      {-std::numeric_limits<double>::infinity(), "-inf"},
      {std::nan(""), "nan"},
  };
  for (const auto& [value, expected] : cases) {
    EXPECT_EQ(FormatDouble(value), expected);
  }
}

TEST(MergeInto, MapsMergeRecursivelyKeepingTargetOrder) {
  ConfigNode target;
  target.SetPath("db.driver", "mysql");
  target.SetPath("db.timeout", 10);
  target.SetPath("name", "app");
  ConfigNode source;
  source.SetPath("db.timeout", 20);
  source.SetPath("db.user", "root");
  source.SetPath("extra", true);
  MergeInto(target, source);
  EXPECT_EQ(target.Keys(), (std::vector<std::string>{"db", "name", "extra"}));
  EXPECT_EQ(target.at("db").Keys(),
            (std::vector<std::string>{"driver", "timeout", "user"}));
  EXPECT_EQ(target.FindPath("db.timeout")->AsInt(), 20);
  EXPECT_EQ(target.FindPath("db.user")->path(), "db.user");
  EXPECT_TRUE(target.at("extra").AsBool());
}

TEST(MergeInto, ListsAndScalarsReplace) {
  ConfigNode target;
  target.SetPath("l", ConfigNode::EmptyList());
  target.at("l").Append(1);
  target.at("l").Append(2);
  ConfigNode source;
  source.SetPath("l", ConfigNode::EmptyList());
  source.at("l").Append(3);
  MergeInto(target, source);
  ASSERT_EQ(target.at("l").size(), 1u);
  EXPECT_EQ(target.at("l").at(size_t{0}).AsInt(), 3);
  EXPECT_EQ(target.at("l").at(size_t{0}).path(), "l[0]");
}

TEST(MergeInto, MissingSourceDoesNotClobber) {
  ConfigNode target;
  target.Set("a", 1);
  target.Set("b", ConfigNode::Null());
  ConfigNode source;
  source.Set("a", ConfigNode::Missing());
  source.Set("b", ConfigNode::Missing());
  source.Set("c", ConfigNode::Missing());
  MergeInto(target, source);
  EXPECT_EQ(target.at("a").AsInt(), 1);
  EXPECT_TRUE(target.at("b").IsNull());
  EXPECT_TRUE(target.at("c").IsMissing());
}

TEST(MergeInto, ConcreteValueReplacesMissing) {
  ConfigNode target;
  target.Set("a", ConfigNode::Missing());
  ConfigNode source;
  source.Set("a", 5);
  MergeInto(target, source);
  EXPECT_EQ(target.at("a").AsInt(), 5);
}

TEST(MergeInto, MapReplacesScalarAndScalarReplacesMap) {
  ConfigNode target;
  target.Set("a", 1);
  target.SetPath("b.c", 2);
  ConfigNode source;
  source.SetPath("a.x", 1);
  source.Set("b", ConfigNode::Null());
  MergeInto(target, source);
  EXPECT_EQ(target.FindPath("a.x")->AsInt(), 1);
  EXPECT_EQ(target.FindPath("a.x")->path(), "a.x");
  EXPECT_TRUE(target.at("b").IsNull());
}

}  // namespace
}  // namespace soma
