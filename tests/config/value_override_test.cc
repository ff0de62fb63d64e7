#include "framework/config/value_override.h"

#include "framework/config/override.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>

namespace soma {
namespace {

using ::testing::HasSubstr;
using ::testing::ThrowsMessage;

ConfigNode Tree() {
  return ParseYaml("db:\n  host: localhost\n  port: 3306\nlist: [1, 2, 3]\n",
                   "tree.yaml");
}

void Apply(ConfigNode& root, const std::string& text) {
  ApplyValueOverride(root, ParseOverride(text));
}

TEST(ApplyValueOverride, ChangeReplacesAnExistingValueFromTheCommandLine) {
  ConfigNode root = Tree();
  Apply(root, "db.port=5432");
  EXPECT_EQ(root.FindPath("db.port")->AsInt(), 5432);
  EXPECT_EQ(root.FindPath("db.port")->source().file, "<command line>");
  EXPECT_EQ(root.FindPath("db.host")->AsString(), "localhost");
  Apply(root, "list.1=7");
  EXPECT_EQ(root.FindPath("list")->at(1).AsInt(), 7);
}

TEST(ApplyValueOverride, ChangeOfAMissingKeyIsAnErrorThatSuggestsPlus) {
  ConfigNode root = Tree();
  EXPECT_THAT([&] { Apply(root, "db.user=root"); },
              ThrowsMessage<ConfigError>(HasSubstr(
                  "Could not override 'db.user'. To append to your config use "
                  "+db.user=root")));
  EXPECT_EQ(root.FindPath("db.user"), nullptr);
}

TEST(ApplyValueOverride, AddNeedsAFreeKeyAndForceAddCreatesIntermediates) {
  ConfigNode root = Tree();
  Apply(root, "+db.user=root");
  EXPECT_EQ(root.FindPath("db.user")->AsString(), "root");
  EXPECT_THROW(Apply(root, "+db.port=1"), ConfigError);
  Apply(root, "++db.port=1");
  EXPECT_EQ(root.FindPath("db.port")->AsInt(), 1);
  Apply(root, "++a.b.c=2");
  EXPECT_EQ(root.FindPath("a.b.c")->AsInt(), 2);
}

TEST(ApplyValueOverride, DeleteChecksTheValueWhenOneIsGiven) {
  ConfigNode root = Tree();
  EXPECT_THROW(Apply(root, "~db.port=1"), ConfigError);
  ASSERT_NE(root.FindPath("db.port"), nullptr);
  Apply(root, "~db.port=3306");
  EXPECT_EQ(root.FindPath("db.port"), nullptr);
  Apply(root, "~list.0");
  ASSERT_EQ(root.FindPath("list")->size(), 2u);
  EXPECT_EQ(root.FindPath("list")->at(0).AsInt(), 2);
  EXPECT_THROW(Apply(root, "~nope"), ConfigError);
}

}  // namespace
}  // namespace soma
