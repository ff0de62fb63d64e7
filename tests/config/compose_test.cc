// Conformance tests for composition (HYDRA.md sections 2-4, 7 and 10 items
// 1-5, 9, 12): the Hydra docs examples (your_first_app, defaults_list.md,
// overriding_packages.md, configuring_experiments.md, specializing_config.md)
// and every composition error with its exact text.
#include "framework/config/compose.h"

#include "framework/config/override.h"
#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::Pair;

using Files = std::map<std::string, std::string>;

/// Writes `files` (relative path -> content) under a fresh test directory.
fs::path MakeTree(const Files& files, const std::string& sub = "conf") {
  const fs::path dir = testing::CreateTestDir() / sub;
  fs::create_directories(dir);
  for (const auto& [path, content] : files) {
    testing::WriteTextFile(dir, path, content);
  }
  return dir;
}

ComposeRequest Request(const fs::path& dir,
                       const std::vector<std::string>& overrides = {},
                       const std::string& config_name = "config") {
  ComposeRequest request;
  request.search_path = {dir.string()};
  request.config_name = config_name;
  request.overrides = ParseOverrides(overrides);
  return request;
}

ComposeResult ComposeTree(const fs::path& dir,
                          const std::vector<std::string>& overrides = {},
                          const std::string& config_name = "config") {
  return Compose(Request(dir, overrides, config_name));
}

/// The message of the ConfigError thrown by composing, or "" if none.
std::string ComposeError(const ComposeRequest& request) {
  try {
    Compose(request);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

std::string ComposeError(const fs::path& dir,
                         const std::vector<std::string>& overrides = {},
                         const std::string& config_name = "config") {
  return ComposeError(Request(dir, overrides, config_name));
}

const ConfigNode& At(const ConfigNode& root, std::string_view path) {
  const ConfigNode* node = root.FindPath(path);
  if (node == nullptr) {
    throw InternalError("test: no node at '" + std::string(path) + "'");
  }
  return *node;
}

std::string Str(const ConfigNode& root, std::string_view path) {
  return At(root, path).AsString();
}

int64_t Int(const ConfigNode& root, std::string_view path) {
  return At(root, path).AsInt();
}

std::vector<std::string> Keys(const ConfigNode& node) { return node.Keys(); }

std::vector<std::string> StringList(const ConfigNode& node) {
  std::vector<std::string> out;
  for (const ConfigNode& item : node.items()) out.push_back(item.AsString());
  return out;
}

const Files kDbFiles = {
    {"db/mysql.yaml",
     "driver: mysql\nhost: localhost\nport: 3306\nuser: omry\npass: secret\n"},
    {"db/postgresql.yaml",
     "driver: postgresql\nuser: postgres_user\npass: drowssap\ntimeout: 10\n"},
};

Files WithDb(Files files) {
  files.insert(kDbFiles.begin(), kDbFiles.end());
  return files;
}

// ---------------------------------------------------------------------------
// 1. tutorials/basic/your_first_app

TEST(ComposeTutorial, AppendKeyToEmptyConfig) {
  const fs::path dir = MakeTree({{"config.yaml", ""}});
  const ComposeResult result = ComposeTree(dir, {"+db.driver=mysql"});
  const ConfigNode task = TaskConfig(result.root);
  EXPECT_THAT(Keys(task), ElementsAre("db"));
  EXPECT_EQ(Str(task, "db.driver"), "mysql");
}

TEST(ComposeTutorial, ChangingMissingKeyNeedsPlus) {
  const fs::path dir = MakeTree({{"config.yaml", ""}});
  EXPECT_EQ(ComposeError(dir, {"db.driver=mysql"}),
            "Could not override 'db.driver'. To append to your config use "
            "+db.driver=mysql");
}

TEST(ComposeTutorial, NoPrimaryConfigAppendsGroup) {
  const fs::path dir = MakeTree(kDbFiles);
  const ComposeResult result = ComposeTree(dir, {"+db=mysql"}, "");
  const ConfigNode task = TaskConfig(result.root);
  EXPECT_EQ(Str(task, "db.driver"), "mysql");
  EXPECT_THAT(result.choices, ElementsAre(Pair("db", "mysql")));
}

TEST(ComposeTutorial, SelectGroupOptionAndOverrideValue) {
  const fs::path dir =
      MakeTree(WithDb({{"config.yaml", "defaults:\n  - db: mysql\n"}}));
  const ComposeResult base = ComposeTree(dir);
  EXPECT_EQ(Str(base.root, "db.driver"), "mysql");
  EXPECT_EQ(Int(base.root, "db.port"), 3306);

  const ComposeResult result =
      ComposeTree(dir, {"db=postgresql", "db.timeout=20"});
  const ConfigNode task = TaskConfig(result.root);
  EXPECT_THAT(Keys(task.at("db")),
              ElementsAre("driver", "user", "pass", "timeout"));
  EXPECT_EQ(Str(task, "db.driver"), "postgresql");
  EXPECT_EQ(Int(task, "db.timeout"), 20);
}

TEST(ComposeTutorial, DeleteGroupLeavesEmptyConfig) {
  const fs::path dir =
      MakeTree(WithDb({{"config.yaml", "defaults:\n  - db: mysql\n"}}));
  const ComposeResult result = ComposeTree(dir, {"~db"});
  const ConfigNode task = TaskConfig(result.root);
  EXPECT_TRUE(task.IsMap());
  EXPECT_EQ(task.size(), 0u);
  EXPECT_TRUE(result.choices.empty());
}

TEST(ComposeTutorial, SelfLastByDefaultSoTheConfigWins) {
  const fs::path dir = MakeTree(WithDb(
      {{"config.yaml", "defaults:\n  - db: mysql\n\ndb:\n  host: backup\n"}}));
  const ConfigNode root = ComposeTree(dir).root;
  EXPECT_EQ(Str(root, "db.host"), "backup");
  EXPECT_EQ(Str(root, "db.driver"), "mysql");
  EXPECT_THAT(Keys(root.at("db")),
              ElementsAre("driver", "host", "port", "user", "pass"));
}

TEST(ComposeTutorial, SelfFirstSoTheGroupWins) {
  const fs::path dir = MakeTree(WithDb(
      {{"config.yaml",
        "defaults:\n  - _self_\n  - db: mysql\n\ndb:\n  host: backup\n"}}));
  const ConfigNode root = ComposeTree(dir).root;
  EXPECT_EQ(Str(root, "db.host"), "localhost");
  // The primary's content was merged first, so its key comes first.
  EXPECT_THAT(Keys(root.at("db")),
              ElementsAre("host", "driver", "port", "user", "pass"));
}

TEST(ComposeTutorial, ConfigInheritanceThroughNonGroupConfig) {
  const fs::path dir =
      MakeTree({{"agent.yaml", "name: ???\nage: ???\nagency: mi6\n"},
                {"bond.yaml",
                 "defaults:\n  - agent\n  - _self_\n\nname: Bond, James "
                 "Bond\nage: 7\n"}});
  const ConfigNode task = TaskConfig(ComposeTree(dir, {}, "bond").root);
  EXPECT_EQ(Str(task, "name"), "Bond, James Bond");
  EXPECT_EQ(Int(task, "age"), 7);
  EXPECT_EQ(Str(task, "agency"), "mi6");
}

TEST(ComposeTutorial, AppendedGroupMergesAfterPrimaryContent) {
  // `+db=mysql` is appended to the primary defaults list after the implicit
  // `_self_`, so the group wins over the primary's own keys.
  const fs::path dir =
      MakeTree(WithDb({{"config.yaml", "db:\n  host: backup\n"}}));
  const ComposeResult result = ComposeTree(dir, {"+db=mysql"});
  EXPECT_EQ(Str(result.root, "db.host"), "localhost");
  ASSERT_EQ(result.defaults.size(), 2u);
  EXPECT_EQ(result.defaults[0].config_path, "config");
  EXPECT_TRUE(result.defaults[0].is_self);
  EXPECT_EQ(result.defaults[1].config_path, "db/mysql");
  EXPECT_EQ(result.defaults[1].parent, "config");
}

TEST(ComposeTutorial, ConfigNameMayCarryYamlSuffix) {
  const fs::path dir =
      MakeTree(WithDb({{"config.yaml", "defaults:\n  - db: mysql\n"}}));
  const ComposeResult result = ComposeTree(dir, {}, "config.yaml");
  EXPECT_EQ(Str(result.root, "db.driver"), "mysql");
  EXPECT_EQ(Str(result.root, "hydra.job.config_name"), "config");
}

// ---------------------------------------------------------------------------
// 2. advanced/defaults_list.md

Files ServerFiles(const std::string& config) {
  return {{"config.yaml", config},
          {"server/apache.yaml", "defaults:\n  - db: mysql\n\nname: apache\n"},
          {"server/db/mysql.yaml", "name: mysql\n"},
          {"server/db/sqlite.yaml", "name: sqlite\n"}};
}

TEST(ComposeDefaultsList, NestedGroupDefaults) {
  const fs::path dir =
      MakeTree(ServerFiles("defaults:\n  - server/apache\n\ndebug: false\n"));
  const ComposeResult result = ComposeTree(dir);
  const ConfigNode task = TaskConfig(result.root);
  EXPECT_THAT(Keys(task), ElementsAre("server", "debug"));
  EXPECT_THAT(Keys(task.at("server")), ElementsAre("db", "name"));
  EXPECT_EQ(Str(task, "server.db.name"), "mysql");
  EXPECT_EQ(Str(task, "server.name"), "apache");
  EXPECT_FALSE(At(task, "debug").AsBool());
  EXPECT_THAT(result.choices, ElementsAre(Pair("server/db", "mysql")));

  ASSERT_EQ(result.defaults.size(), 3u);
  EXPECT_EQ(result.defaults[0].config_path, "server/db/mysql");
  EXPECT_EQ(result.defaults[0].package, "server.db");
  EXPECT_EQ(result.defaults[0].parent, "server/apache");
  EXPECT_FALSE(result.defaults[0].is_self);
  EXPECT_EQ(result.defaults[0].group, "server/db");
  EXPECT_EQ(result.defaults[0].option, "mysql");
  EXPECT_EQ(result.defaults[1].config_path, "server/apache");
  EXPECT_EQ(result.defaults[1].package, "server");
  EXPECT_EQ(result.defaults[1].parent, "config");
  EXPECT_TRUE(result.defaults[1].is_self);
  EXPECT_EQ(result.defaults[2].config_path, "config");
  EXPECT_EQ(result.defaults[2].package, "");
  EXPECT_EQ(result.defaults[2].parent, "");
  EXPECT_TRUE(result.defaults[2].is_self);

  const std::string text = FormatDefaultsList(result);
  EXPECT_THAT(text, HasSubstr("Defaults List\n*************\n"));
  EXPECT_THAT(text,
              HasSubstr("| Config path     | Package   | _self_ | "
                        "Parent        |"));
  EXPECT_THAT(text,
              HasSubstr("| server/db/mysql | server.db | False  | "
                        "server/apache |"));
  EXPECT_THAT(text,
              HasSubstr("| server/apache   | server    | True   | "
                        "config        |"));
  EXPECT_THAT(text,
              HasSubstr("| config          |           | True   | "
                        "<root>        |"));
}

TEST(ComposeDefaultsList, OverrideEntryReplacesNestedChoice) {
  const fs::path dir = MakeTree(ServerFiles(
      "defaults:\n  - server/apache\n  - override server/db: sqlite\n\n"
      "debug: false\n"));
  const ComposeResult result = ComposeTree(dir);
  EXPECT_EQ(Str(result.root, "server.db.name"), "sqlite");
  EXPECT_THAT(result.choices, ElementsAre(Pair("server/db", "sqlite")));
}

TEST(ComposeDefaultsList, CommandLineSelectsNestedGroup) {
  const fs::path dir =
      MakeTree(ServerFiles("defaults:\n  - server/apache\n\ndebug: false\n"));
  EXPECT_EQ(Str(ComposeTree(dir, {"server/db=sqlite"}).root, "server.db.name"),
            "sqlite");
}

TEST(ComposeDefaultsList, CommandLineWinsOverOverrideEntry) {
  const fs::path dir = MakeTree(ServerFiles(
      "defaults:\n  - server/apache\n  - override server/db: sqlite\n"));
  EXPECT_EQ(Str(ComposeTree(dir, {"server/db=mysql"}).root, "server.db.name"),
            "mysql");
}

TEST(ComposeDefaultsList, LastOverrideInDepthFirstOrderWins) {
  Files files =
      WithDb({{"config.yaml", "defaults:\n  - db: mysql\n  - a\n  - b\n"},
              {"a.yaml", "defaults:\n  - override db: sqlite\n"},
              {"b.yaml", "defaults:\n  - override db: postgresql\n"},
              {"db/sqlite.yaml", "driver: sqlite\n"}});
  const fs::path dir = MakeTree(files);
  EXPECT_EQ(Str(ComposeTree(dir).root, "db.driver"), "postgresql");
}

TEST(ComposeDefaultsList, OverrideWithoutMatchIsAnError) {
  const fs::path dir =
      MakeTree(ServerFiles("defaults:\n  - override server/db: sqlite\n"));
  EXPECT_EQ(ComposeError(dir),
            "In 'config': Could not override 'server/db'. No match in the "
            "defaults list.");
}

TEST(ComposeDefaultsList, OverrideBeforeDefaultIsAnError) {
  const fs::path dir = MakeTree(WithDb(
      {{"config.yaml", "defaults:\n  - override db: mysql\n  - db: mysql\n"}}));
  EXPECT_EQ(ComposeError(dir),
            "In config: Override 'db : mysql' is defined before 'db: mysql'. "
            "Overrides must be at the end of the defaults list");
}

TEST(ComposeDefaultsList, SameGroupTwiceIsAnError) {
  const fs::path dir = MakeTree(WithDb(
      {{"config.yaml", "defaults:\n  - db: mysql\n  - db: postgresql\n"}}));
  EXPECT_EQ(ComposeError(dir),
            "Multiple values for db. To override a value use 'override db: "
            "postgresql'");
}

TEST(ComposeDefaultsList, UnknownOptionListsAvailableOptions) {
  const fs::path dir =
      MakeTree(WithDb({{"config.yaml", "defaults:\n  - db: oracle\n"}}));
  EXPECT_EQ(ComposeError(dir),
            "In 'config': Could not find 'db/oracle'. Available options in "
            "'db': mysql, postgresql");
  const fs::path dir2 =
      MakeTree(WithDb({{"config.yaml", "defaults:\n  - db: mysql\n"}}), "c2");
  EXPECT_EQ(ComposeError(dir2, {"db=oracle"}),
            "In 'config': Could not find 'db/oracle'. Available options in "
            "'db': mysql, postgresql");
}

TEST(ComposeDefaultsList, MissingNonGroupConfigIsAnError) {
  const fs::path dir =
      MakeTree({{"config.yaml", "defaults:\n  - base_mysql\n"}});
  EXPECT_EQ(ComposeError(dir), "In 'config': Could not load 'base_mysql'.");
}

// Hydra 1.1 raised a RecursionError here (hydra#1828); a config fuzzer input
// (tests/fuzz/corpus/config/crash-ff39...) overflowed this stack.
TEST(ComposeDefaultsList, CircularDefaultsListIsAnError) {
  const fs::path self =
      MakeTree({{"config.yaml", "defaults:\n  - config\n"}}, "self");
  EXPECT_EQ(ComposeError(self),
            "Circular defaults list: 'config' includes itself "
            "(config -> config)");
  const fs::path loop = MakeTree({{"config.yaml", "defaults:\n  - db: a\n"},
                                  {"db/a.yaml", "defaults:\n  - b\n"},
                                  {"db/b.yaml", "defaults:\n  - /db/a\n"}},
                                 "loop");
  EXPECT_EQ(ComposeError(loop),
            "Circular defaults list: 'db/a' includes itself "
            "(db/a -> db/b -> db/a)");
  // The same config in two branches is no cycle.
  const ComposeResult twice = ComposeTree(
      MakeTree({{"config.yaml", "defaults:\n  - a\n  - b\n  - _self_\n"},
                {"a.yaml", "defaults:\n  - common\n  - _self_\nx: 1\n"},
                {"b.yaml", "defaults:\n  - common\n  - _self_\ny: 2\n"},
                {"common.yaml", "c: 3\n"}},
               "twice"));
  EXPECT_EQ(Int(twice.root, "c"), 3);
  EXPECT_EQ(Int(twice.root, "y"), 2);
}

TEST(ComposeDefaultsList, OptionalMissingOptionIsSkipped) {
  const fs::path dir = MakeTree(
      WithDb({{"config.yaml",
               "defaults:\n  - db: mysql\n  - optional db_extra: fast\n"},
              {"db_extra/slow.yaml", "slow: true\n"}}));
  const ComposeResult result = ComposeTree(dir);
  EXPECT_THAT(Keys(TaskConfig(result.root)), ElementsAre("db"));
}

TEST(ComposeDefaultsList, NullOptionSelectsNothing) {
  const fs::path dir =
      MakeTree(WithDb({{"config.yaml", "defaults:\n  - db: null\n"}}));
  const ComposeResult result = ComposeTree(dir);
  EXPECT_EQ(TaskConfig(result.root).size(), 0u);
  EXPECT_TRUE(At(result.root, "hydra.runtime.choices").at("db").IsNull());
  EXPECT_THAT(result.choices, ElementsAre(Pair("db", "null")));
  // The placeholder can be filled from the command line.
  EXPECT_EQ(Str(ComposeTree(dir, {"db=mysql"}).root, "db.driver"), "mysql");
}

TEST(ComposeDefaultsList, MandatoryOptionMustBeSpecified) {
  const fs::path dir =
      MakeTree(WithDb({{"config.yaml", "defaults:\n  - db: ???\n"}}));
  EXPECT_EQ(ComposeError(dir),
            "You must specify 'db', e.g, db=<OPTION>. Available options: "
            "mysql, postgresql");
  EXPECT_EQ(Str(ComposeTree(dir, {"db=postgresql"}).root, "db.driver"),
            "postgresql");
  EXPECT_EQ(ComposeError(dir, {"db=???"}),
            "You must specify 'db', e.g, db=<OPTION>. Available options: "
            "mysql, postgresql");
  // The sweep-level multirun config skips it (each job then specifies it).
  ComposeRequest request = Request(dir, {"db=mysql,postgresql"});
  request.mode = RunMode::kMultirun;
  request.allow_sweeps = true;
  const ComposeResult sweep = Compose(request);
  EXPECT_EQ(TaskConfig(sweep.root).size(), 0u);
  EXPECT_THAT(StringList(At(sweep.root, "hydra.overrides.task")),
              ElementsAre("db=mysql,postgresql"));
}

TEST(ComposeDefaultsList, NonGroupConfigCannotBeDeletedFromCommandLine) {
  const fs::path dir =
      MakeTree(ServerFiles("defaults:\n  - server/apache\n\ndebug: false\n"));
  EXPECT_EQ(ComposeError(dir, {"~server/apache"}),
            "Could not delete from config. 'server/apache' does not exist.");
}

TEST(ComposeDefaultsList, OptionListComposesEveryOption) {
  const fs::path dir = MakeTree(
      {{"config.yaml", "defaults:\n  - server: apache\n"},
       {"server/apache.yaml",
        "defaults:\n  - site: [fb, google]\n  - _self_\n\nname: apache\n"},
       {"server/site/fb.yaml", "fb:\n  url: facebook.com\n"},
       {"server/site/google.yaml", "google:\n  url: google.com\n"},
       {"server/site/amazon.yaml", "amazon:\n  url: amazon.com\n"}});
  const ConfigNode root = ComposeTree(dir).root;
  EXPECT_THAT(Keys(At(root, "server.site")), ElementsAre("fb", "google"));
  EXPECT_EQ(Str(root, "server.name"), "apache");

  const ComposeResult replaced =
      ComposeTree(dir, {"server/site=[google,amazon]"});
  EXPECT_THAT(Keys(At(replaced.root, "server.site")),
              ElementsAre("google", "amazon"));
  ASSERT_EQ(replaced.defaults.size(), 4u);
  EXPECT_EQ(replaced.defaults[0].config_path, "server/site/google");
  EXPECT_EQ(replaced.defaults[0].group, "server/site");
  EXPECT_EQ(replaced.defaults[0].option, "google");
  EXPECT_EQ(replaced.defaults[1].config_path, "server/site/amazon");
}

TEST(ComposeDefaultsList, AbsoluteConfigPathWithHerePackage) {
  const fs::path dir = MakeTree(
      {{"config.yaml", "defaults:\n  - server: apache\n"},
       {"server/apache.yaml",
        "defaults:\n  - /schema/base@_here_\n  - _self_\n\nname: apache\n"},
       {"schema/base.yaml", "port: 80\nname: ???\n"}});
  const ConfigNode root = ComposeTree(dir).root;
  EXPECT_EQ(Int(root, "server.port"), 80);
  EXPECT_EQ(Str(root, "server.name"), "apache");
}

TEST(ComposeDefaultsList, RejectsParentDirectoryAndBackslash) {
  const fs::path dir =
      MakeTree({{"config.yaml", "defaults:\n  - ../secret\n"}});
  EXPECT_EQ(ComposeError(dir),
            "Invalid config path '../secret': '..' is not allowed");
  const fs::path dir2 =
      MakeTree({{"config.yaml", "defaults:\n  - 'db\\mysql'\n"}}, "c2");
  EXPECT_THAT(ComposeError(dir2),
              HasSubstr("Invalid config path 'db\\mysql': a backslash is not "
                        "allowed"));
}

TEST(ComposeDefaultsList, DuplicateSelfIsAnError) {
  const fs::path dir =
      MakeTree({{"config.yaml", "defaults:\n  - _self_\n  - _self_\n"}});
  EXPECT_EQ(ComposeError(dir), "Duplicate _self_ defined in config");
}

TEST(ComposeDefaultsList, DefaultsMustBeAList) {
  const fs::path dir = MakeTree({{"config.yaml", "defaults:\n  db: mysql\n"}});
  EXPECT_EQ(ComposeError(dir),
            "Invalid defaults list in 'config', defaults must be a list (got "
            "mapping)");
}

// ---------------------------------------------------------------------------
// 3. advanced/overriding_packages.md

TEST(ComposePackages, PackageOnConfigEntryRelocatesSubtree) {
  const fs::path dir =
      MakeTree(ServerFiles("defaults:\n  - server/apache@admin\n"));
  const ComposeResult result = ComposeTree(dir);
  const ConfigNode task = TaskConfig(result.root);
  EXPECT_THAT(Keys(task), ElementsAre("admin"));
  EXPECT_EQ(Str(task, "admin.name"), "apache");
  EXPECT_EQ(Str(task, "admin.db.name"), "mysql");
  // The nested group keeps its group path but gets a non-default package.
  EXPECT_THAT(result.choices, ElementsAre(Pair("server/db@admin.db", "mysql")));
  EXPECT_EQ(Str(ComposeTree(dir, {"server/db@admin.db=sqlite"}).root,
                "admin.db.name"),
            "sqlite");
}

TEST(ComposePackages, SameGroupTwiceUnderDifferentPackages) {
  const fs::path dir = MakeTree(WithDb(
      {{"config.yaml", "defaults:\n  - db@src: mysql\n  - db@dst: mysql\n"}}));
  const ComposeResult result = ComposeTree(dir);
  EXPECT_EQ(Str(result.root, "src.driver"), "mysql");
  EXPECT_EQ(Str(result.root, "dst.driver"), "mysql");
  EXPECT_THAT(result.choices,
              ElementsAre(Pair("db@src", "mysql"), Pair("db@dst", "mysql")));

  const ComposeResult changed = ComposeTree(dir, {"db@src=postgresql"});
  EXPECT_EQ(Str(changed.root, "src.driver"), "postgresql");
  EXPECT_EQ(Str(changed.root, "dst.driver"), "mysql");
  EXPECT_EQ(Str(changed.root, "hydra.runtime.choices.db@src"), "postgresql");
}

TEST(ComposePackages, NestedGroupTwiceUnderPackages) {
  const fs::path dir = MakeTree(
      {{"config.yaml",
        "defaults:\n  - server/db@src: mysql\n  - server/db@dst: mysql\n"},
       {"server/db/mysql.yaml", "name: mysql\n"},
       {"server/db/sqlite.yaml", "name: sqlite\n"}});
  const ConfigNode root = ComposeTree(dir, {"server/db@src=sqlite"}).root;
  EXPECT_EQ(Str(root, "src.name"), "sqlite");
  EXPECT_EQ(Str(root, "dst.name"), "mysql");
}

TEST(ComposePackages, UnmatchedGroupSuggestsPackages) {
  const fs::path dir = MakeTree(WithDb(
      {{"config.yaml", "defaults:\n  - db@src: mysql\n  - db@dst: mysql\n"}}));
  EXPECT_EQ(ComposeError(dir, {"db=postgresql"}),
            "Could not override 'db'. No match in the defaults list. Did you "
            "mean to override one of db@dst, db@src? To append to your default "
            "list use +db=postgresql");
  const fs::path dir2 = MakeTree(
      WithDb({{"config.yaml", "defaults:\n  - db@src: mysql\n"}}), "c2");
  EXPECT_EQ(ComposeError(dir2, {"db=postgresql"}),
            "Could not override 'db'. No match in the defaults list. Did you "
            "mean to override db@src? To append to your default list use "
            "+db=postgresql");
}

TEST(ComposePackages, PackageDirectiveIsAbsolute) {
  const fs::path dir = MakeTree(
      {{"config.yaml", "defaults:\n  - server: apache\n"},
       {"server/apache.yaml", "defaults:\n  - db: mysql\n\nname: apache\n"},
       {"server/db/mysql.yaml", "# @package foo.bar\nhost: localhost\n"}});
  const ComposeResult result = ComposeTree(dir);
  const ConfigNode task = TaskConfig(result.root);
  EXPECT_EQ(Str(task, "foo.bar.host"), "localhost");
  EXPECT_EQ(Str(task, "server.name"), "apache");
  EXPECT_EQ(task.at("server").Find("db"), nullptr);
  // The override key does not depend on the directive.
  EXPECT_THAT(
      result.choices,
      ElementsAre(Pair("server", "apache"), Pair("server/db", "mysql")));
  EXPECT_EQ(result.defaults[0].package, "foo.bar");
}

TEST(ComposePackages, GlobalPackageInDefaultsEntry) {
  const fs::path dir = MakeTree(
      WithDb({{"config.yaml", "defaults:\n  - db@_global_: mysql\n"}}));
  const ComposeResult result = ComposeTree(dir);
  EXPECT_EQ(Str(result.root, "driver"), "mysql");
  EXPECT_THAT(result.choices, ElementsAre(Pair("db@_global_", "mysql")));
}

TEST(ComposePackages, GroupPackageKeywordIsAbsolute) {
  const fs::path dir =
      MakeTree({{"config.yaml", "defaults:\n  - server: apache\n"},
                {"server/apache.yaml",
                 "defaults:\n  - db@_group_: mysql\n\nname: apache\n"},
                {"server/db/mysql.yaml", "name: mysql\n"}});
  const ConfigNode root = ComposeTree(dir).root;
  EXPECT_EQ(Str(root, "server.db.name"), "mysql");
}

TEST(ComposePackages, AppendWithPackage) {
  const fs::path dir = MakeTree(WithDb({{"config.yaml", "x: 1\n"}}));
  const ComposeResult result = ComposeTree(dir, {"+db@backup=mysql"});
  EXPECT_EQ(Str(result.root, "backup.driver"), "mysql");
  EXPECT_THAT(result.choices, ElementsAre(Pair("db@backup", "mysql")));
}

// ---------------------------------------------------------------------------
// 4. patterns/configuring_experiments.md

Files ExperimentFiles() {
  return {
      {"config.yaml", "defaults:\n  - db: mysql\n  - server: apache\n"},
      {"db/mysql.yaml", "name: mysql\n"},
      {"db/sqlite.yaml", "name: sqlite\n"},
      {"db/postgresql.yaml", "name: postgresql\n"},
      {"server/apache.yaml", "name: apache\nport: 80\n"},
      {"server/nginx.yaml", "name: nginx\nport: 80\n"},
      {"experiment/aplite.yaml",
       "# @package _global_\ndefaults:\n  - override /db: sqlite\n"
       "  - override /server: apache\n\nserver:\n  port: 8080\n"},
      {"experiment/nglite.yaml",
       "# @package _global_\ndefaults:\n  - override /db: sqlite\n"
       "  - override /server: nginx\n\nserver:\n  port: 8080\n"},
  };
}

TEST(ComposeExperiments, AppendExperimentWithAbsoluteOverrides) {
  const fs::path dir = MakeTree(ExperimentFiles());
  const ComposeResult aplite = ComposeTree(dir, {"+experiment=aplite"});
  const ConfigNode task = TaskConfig(aplite.root);
  EXPECT_THAT(Keys(task), ElementsAre("db", "server"));
  EXPECT_EQ(Str(task, "db.name"), "sqlite");
  EXPECT_EQ(Str(task, "server.name"), "apache");
  EXPECT_EQ(Int(task, "server.port"), 8080);
  EXPECT_THAT(aplite.choices,
              ElementsAre(Pair("db", "sqlite"),
                          Pair("server", "apache"),
                          Pair("experiment", "aplite")));

  const ConfigNode nglite = ComposeTree(dir, {"+experiment=nglite"}).root;
  EXPECT_EQ(Str(nglite, "db.name"), "sqlite");
  EXPECT_EQ(Str(nglite, "server.name"), "nginx");
  EXPECT_EQ(Int(nglite, "server.port"), 8080);
}

TEST(ComposeExperiments, CommandLineWinsOverExperiment) {
  const fs::path dir = MakeTree(ExperimentFiles());
  const ConfigNode root =
      ComposeTree(dir, {"+experiment=aplite", "db=postgresql"}).root;
  EXPECT_EQ(Str(root, "db.name"), "postgresql");
  // CLI position does not matter for group overrides.
  const ConfigNode root2 =
      ComposeTree(dir, {"db=postgresql", "+experiment=aplite"}).root;
  EXPECT_EQ(Str(root2, "db.name"), "postgresql");
}

TEST(ComposeExperiments, AddingSelectedGroupIsAnError) {
  const fs::path dir = MakeTree(ExperimentFiles());
  EXPECT_EQ(ComposeError(dir, {"+db=sqlite"}),
            "Could not add 'db=sqlite'. 'db' is already in the defaults list.");
  EXPECT_EQ(ComposeError(dir, {"+db=mysql"}),
            "Could not add 'db=mysql'. 'db' is already in the defaults list.");
}

TEST(ComposeExperiments, OverrideWithoutPlusIsAnError) {
  const fs::path dir = MakeTree(ExperimentFiles());
  EXPECT_EQ(ComposeError(dir, {"experiment=aplite"}),
            "Could not override 'experiment'. No match in the defaults list. "
            "To append to your default list use +experiment=aplite");
}

TEST(ComposeExperiments, ForceAddOfGroupIsAnError) {
  const fs::path dir = MakeTree(ExperimentFiles());
  EXPECT_EQ(ComposeError(dir, {"++db=sqlite"}),
            "force-add of config groups is not supported: '++db=sqlite'");
}

TEST(ComposeExperiments, DeleteGroupErrors) {
  const fs::path dir = MakeTree(ExperimentFiles());
  EXPECT_EQ(ComposeError(dir, {"~experiment"}),
            "Could not delete 'experiment'. No match in the defaults list");
  EXPECT_EQ(ComposeError(dir, {"~db=sqlite"}),
            "Could not delete 'db=sqlite'. No match in the defaults list");
  const ConfigNode root = ComposeTree(dir, {"~db=mysql"}).root;
  EXPECT_EQ(root.Find("db"), nullptr);
}

TEST(ComposeExperiments, NullGroupValueIsAnError) {
  const fs::path dir = MakeTree(ExperimentFiles());
  EXPECT_EQ(ComposeError(dir, {"db=null"}),
            "Config group override must be a string or a list. Got NoneType");
}

// ---------------------------------------------------------------------------
// 5. patterns/specializing_config.md

Files SpecializingFiles() {
  return {
      {"config.yaml",
       "defaults:\n  - dataset: imagenet\n  - model: alexnet\n"
       "  - optional dataset_model: ${dataset}_${model}\n"},
      {"dataset/imagenet.yaml", "name: imagenet\npath: /datasets/imagenet\n"},
      {"dataset/cifar10.yaml", "name: cifar10\npath: /datasets/cifar10\n"},
      {"model/alexnet.yaml", "num_layers: 7\nwidth: 1024\n"},
      {"model/resnet.yaml", "num_layers: 50\nwidth: 2048\n"},
      {"dataset_model/cifar10_alexnet.yaml",
       "# @package _global_\nmodel:\n  num_layers: 5\n"}};
}

TEST(ComposeSpecializing, InterpolatedOptionalMiss) {
  const fs::path dir = MakeTree(SpecializingFiles());
  const ComposeResult result = ComposeTree(dir);
  EXPECT_EQ(Int(result.root, "model.num_layers"), 7);
  EXPECT_EQ(result.defaults.size(), 3u);
  EXPECT_EQ(Str(result.root, "hydra.runtime.choices.dataset_model"),
            "imagenet_alexnet");
}

TEST(ComposeSpecializing, InterpolatedOptionalHit) {
  const fs::path dir = MakeTree(SpecializingFiles());
  const ComposeResult result = ComposeTree(dir, {"dataset=cifar10"});
  EXPECT_EQ(Int(result.root, "model.num_layers"), 5);
  EXPECT_EQ(Int(result.root, "model.width"), 1024);
  ASSERT_EQ(result.defaults.size(), 4u);
  EXPECT_EQ(result.defaults[2].config_path, "dataset_model/cifar10_alexnet");
  EXPECT_EQ(result.defaults[2].package, "");
  // Another model: no specialization.
  EXPECT_EQ(Int(ComposeTree(dir, {"dataset=cifar10", "model=resnet"}).root,
                "model.num_layers"),
            50);
}

TEST(ComposeSpecializing, UnknownInterpolationKeyIsAnError) {
  const fs::path dir = MakeTree(
      {{"config.yaml",
        "defaults:\n  - dataset: imagenet\n  - optional combo: ${nope}\n"},
       {"dataset/imagenet.yaml", "name: imagenet\n"}});
  EXPECT_EQ(ComposeError(dir),
            "Error resolving interpolation '${nope}', possible interpolation "
            "keys: dataset");
}

// ---------------------------------------------------------------------------
// 9. Struct mode and value overrides.

const Files kValueFiles = {
    {"config.yaml",
     "a: 1\nnested:\n  x: 1\n  y: [1, 2]\nnothing: null\nmandatory: ???\n"
     "items: [10, 20, 30]\nname: abc\n"}};

TEST(ComposeStructMode, RootIsInStructMode) {
  const fs::path dir = MakeTree(kValueFiles);
  const ComposeResult result = ComposeTree(dir);
  EXPECT_TRUE(result.root.struct_mode());
  const ConfigNode task = TaskConfig(result.root);
  EXPECT_TRUE(task.struct_mode());
  EXPECT_EQ(task.Find("hydra"), nullptr);
  EXPECT_NE(result.root.Find("hydra"), nullptr);
}

TEST(ComposeStructMode, ChangeNeedsExistingKey) {
  const fs::path dir = MakeTree(kValueFiles);
  EXPECT_EQ(ComposeError(dir, {"b=2"}),
            "Could not override 'b'. To append to your config use +b=2");
  EXPECT_EQ(ComposeError(dir, {"nested.z=2"}),
            "Could not override 'nested.z'. To append to your config use "
            "+nested.z=2");
  EXPECT_EQ(Int(ComposeTree(dir, {"a=2"}).root, "a"), 2);
}

TEST(ComposeStructMode, AppendNeedsAbsentKey) {
  const fs::path dir = MakeTree(kValueFiles);
  EXPECT_EQ(ComposeError(dir, {"+a=2"}),
            "Could not append to config. An item is already at 'a'. Either "
            "remove + prefix: 'a=2' or add a second + to add or override 'a': "
            "'++a=2'");
  const ConfigNode root = ComposeTree(dir, {"+b=2", "+nested.z=3"}).root;
  EXPECT_EQ(Int(root, "b"), 2);
  EXPECT_EQ(Int(root, "nested.z"), 3);
}

TEST(ComposeStructMode, AppendOnNullOrMissingIsAllowed) {
  const fs::path dir = MakeTree(kValueFiles);
  const ConfigNode root =
      ComposeTree(dir, {"+nothing=5", "+mandatory=abc"}).root;
  EXPECT_EQ(Int(root, "nothing"), 5);
  EXPECT_EQ(Str(root, "mandatory"), "abc");
}

TEST(ComposeStructMode, AppendDictMergesIntoExistingMap) {
  const fs::path dir = MakeTree(kValueFiles);
  const ConfigNode root = ComposeTree(dir, {"+nested={z: 3}"}).root;
  EXPECT_THAT(Keys(root.at("nested")), ElementsAre("x", "y", "z"));
  EXPECT_EQ(Int(root, "nested.z"), 3);
}

TEST(ComposeStructMode, ForceAddWorksBothWays) {
  const fs::path dir = MakeTree(kValueFiles);
  const ConfigNode root = ComposeTree(dir, {"++a=3", "++b.c=4"}).root;
  EXPECT_EQ(Int(root, "a"), 3);
  EXPECT_EQ(Int(root, "b.c"), 4);
}

TEST(ComposeStructMode, DictValueMergesListValueReplaces) {
  const fs::path dir = MakeTree(kValueFiles);
  const ConfigNode root = ComposeTree(dir, {"nested={x: 5}", "items=[7]"}).root;
  EXPECT_THAT(Keys(root.at("nested")), ElementsAre("x", "y"));
  EXPECT_EQ(Int(root, "nested.x"), 5);
  ASSERT_EQ(At(root, "items").size(), 1u);
  EXPECT_EQ(Int(root, "items.0"), 7);
  // A dict merge in struct mode cannot add keys.
  EXPECT_EQ(ComposeError(dir, {"nested={z: 5}"}),
            "Could not override 'nested'. To append to your config use "
            "+nested={z: 5}");
}

TEST(ComposeStructMode, DeleteKeys) {
  const fs::path dir = MakeTree(kValueFiles);
  const ConfigNode root =
      ComposeTree(dir, {"~a", "~nested.y", "~name=abc"}).root;
  EXPECT_EQ(root.Find("a"), nullptr);
  EXPECT_THAT(Keys(root.at("nested")), ElementsAre("x"));
  EXPECT_EQ(root.Find("name"), nullptr);
  EXPECT_EQ(ComposeError(dir, {"~b"}),
            "Could not delete from config. 'b' does not exist.");
  EXPECT_EQ(ComposeError(dir, {"~a=2"}),
            "Could not delete from config. The value of 'a' is 1 and not 2.");
}

TEST(ComposeStructMode, EmptyValueListIndexAndInterpolation) {
  const fs::path dir = MakeTree(kValueFiles);
  const ConfigNode root =
      ComposeTree(dir, {"name=", "items.1=5", "a=${nested.x}"}).root;
  EXPECT_EQ(Str(root, "name"), "");
  EXPECT_EQ(Int(root, "items.1"), 5);
  EXPECT_EQ(At(root, "items").size(), 3u);
  EXPECT_TRUE(At(root, "a").IsInterpolation());
  EXPECT_EQ(At(root, "a").text(), "${nested.x}");
  EXPECT_EQ(At(root, "items[1]").path(), "items[1]");
}

TEST(ComposeStructMode, ValueOverridesApplyAfterGroupOverrides) {
  const fs::path dir =
      MakeTree(WithDb({{"config.yaml", "defaults:\n  - db: mysql\n"}}));
  // timeout exists only in postgresql: it must be set after the group switch.
  const ConfigNode root =
      ComposeTree(dir, {"db.timeout=30", "db=postgresql"}).root;
  EXPECT_EQ(Str(root, "db.driver"), "postgresql");
  EXPECT_EQ(Int(root, "db.timeout"), 30);
}

TEST(ComposeStructMode, ValueOverridesApplyInCommandLineOrder) {
  const fs::path dir = MakeTree(kValueFiles);
  EXPECT_EQ(Int(ComposeTree(dir, {"a=2", "a=3"}).root, "a"), 3);
  EXPECT_EQ(ComposeError(dir, {"~a", "a=3"}),
            "Could not override 'a'. To append to your config use +a=3");
}

TEST(ComposeStructMode, DictOverrideOfGroupKeyIsAValueOverride) {
  const fs::path dir =
      MakeTree(WithDb({{"config.yaml", "defaults:\n  - db: mysql\n"}}));
  const ConfigNode root = ComposeTree(dir, {"db={port: 1}"}).root;
  EXPECT_EQ(Str(root, "db.driver"), "mysql");
  EXPECT_EQ(Int(root, "db.port"), 1);
}

TEST(ComposeStructMode, SweepInRunModeIsAmbiguous) {
  const fs::path dir = MakeTree(kValueFiles);
  // Hydra 1.3's three suggestions, on one line.
  EXPECT_EQ(ComposeError(dir, {"a=1,2"}),
            "Ambiguous value for argument 'a=1,2'. 1. To use it as a list, use "
            "key=[value1,value2] 2. To use it as string, quote the value: "
            "key=\\'value1,value2\\' 3. To sweep over it, add --multirun to "
            "your command line");
}

TEST(ComposeStructMode, SweepsAreSkippedAtSweepLevel) {
  const fs::path dir = MakeTree(kValueFiles);
  ComposeRequest request = Request(dir, {"a=5,6", "name=x"});
  request.mode = RunMode::kMultirun;
  request.allow_sweeps = true;
  const ComposeResult result = Compose(request);
  EXPECT_EQ(Int(result.root, "a"), 1);
  EXPECT_EQ(Str(result.root, "name"), "x");
  EXPECT_EQ(Str(result.root, "hydra.mode"), "MULTIRUN");
  EXPECT_THAT(StringList(At(result.root, "hydra.overrides.task")),
              ElementsAre("a=5,6", "name=x"));

  ComposeRequest hydra_sweep = Request(dir, {"hydra.launcher.n_jobs=1,2"});
  hydra_sweep.mode = RunMode::kMultirun;
  hydra_sweep.allow_sweeps = true;
  EXPECT_EQ(ComposeError(hydra_sweep),
            "Sweeping over Hydra's configuration is not supported : "
            "'hydra.launcher.n_jobs=1,2'");
}

// ---------------------------------------------------------------------------
// 12. SOMA-style training config with mandatory values.

TEST(ComposeSoma, MandatoryValuesComposeAndStayMissing) {
  const fs::path dir =
      MakeTree({{"config.yaml",
                 "defaults:\n  - model: transformer\n  - _self_\n\nseed: 0\n"
                 "train:\n  batch_size: ???\n  lr: 1e-3\n  epochs: 10\n"
                 "data:\n  root: ${oc.env:SOMA_DATA,/data}\n  id: ???\n"},
                {"model/transformer.yaml", "layers: 6\nwidth: ???\n"}});
  const ComposeResult result = ComposeTree(dir, {"train.epochs=3"});
  const ConfigNode task = TaskConfig(result.root);
  EXPECT_TRUE(At(task, "train.batch_size").IsMissing());
  EXPECT_TRUE(At(task, "data.id").IsMissing());
  EXPECT_TRUE(At(task, "model.width").IsMissing());
  EXPECT_TRUE(At(task, "data.root").IsInterpolation());
  EXPECT_EQ(Int(task, "train.epochs"), 3);
  EXPECT_THROW(At(task, "train.batch_size").AsInt(), MissingMandatoryValue);
  // A mandatory value set from the command line.
  EXPECT_EQ(
      Int(ComposeTree(dir, {"train.batch_size=32"}).root, "train.batch_size"),
      32);
}

// ---------------------------------------------------------------------------
// Search path.

TEST(ComposeSearchPath, PrimaryDirectoryNotFound) {
  ComposeRequest request;
  request.search_path = {"/nonexistent/somalab/conf"};
  EXPECT_EQ(ComposeError(request),
            "Primary config directory not found: '/nonexistent/somalab/conf'");
  const fs::path dir = MakeTree({{"config.yaml", ""}});
  request.search_path = {dir.string(), "file:///nonexistent/extra"};
  EXPECT_EQ(ComposeError(request),
            "Config search path entry not found: '/nonexistent/extra'");
}

TEST(ComposeSearchPath, PrimaryConfigNotFound) {
  const fs::path dir = MakeTree({{"config.yaml", ""}});
  EXPECT_EQ(ComposeError(dir, {}, "missing"),
            "Cannot find primary config 'missing'. Check that it's in your "
            "config search path.");
}

TEST(ComposeSearchPath, HydraSearchPathAddsRoot) {
  const fs::path base = testing::CreateTestDir();
  testing::WriteTextFile(base, "extra/db/mysql.yaml", "driver: mysql\n");
  testing::WriteTextFile(
      base,
      "conf/config.yaml",
      "defaults:\n  - db: mysql\n\nhydra:\n  searchpath:\n    - file://" +
          (base / "extra").string() + "\n");
  const ComposeResult result = ComposeTree(base / "conf");
  EXPECT_EQ(Str(result.root, "db.driver"), "mysql");
  ASSERT_EQ(result.search_path.size(), 2u);
  EXPECT_EQ(result.search_path[1], (base / "extra").string());
  const ConfigNode& sources = At(result.root, "hydra.runtime.config_sources");
  ASSERT_EQ(sources.size(), 2u);
  EXPECT_EQ(Str(sources.at(size_t{0}), "provider"), "main");
  EXPECT_EQ(Str(sources.at(size_t{1}), "provider"), "hydra.searchpath");
  EXPECT_EQ(Str(sources.at(size_t{1}), "schema"), "file");
  EXPECT_EQ(Str(sources.at(size_t{1}), "path"), (base / "extra").string());
}

TEST(ComposeSearchPath, EarlierRootWins) {
  const fs::path base = testing::CreateTestDir();
  testing::WriteTextFile(base, "a/config.yaml", "defaults:\n  - db: mysql\n");
  testing::WriteTextFile(base, "a/db/mysql.yaml", "driver: from_a\n");
  testing::WriteTextFile(base, "b/db/mysql.yaml", "driver: from_b\n");
  testing::WriteTextFile(base, "b/db/sqlite.yaml", "driver: sqlite\n");
  ComposeRequest request;
  request.search_path = {(base / "a").string(), (base / "b").string()};
  const ComposeResult result = Compose(request);
  EXPECT_EQ(Str(result.root, "db.driver"), "from_a");
  request.overrides = ParseOverrides({"db=sqlite"});
  EXPECT_EQ(Str(Compose(request).root, "db.driver"), "sqlite");

  const ConfigRepository repo(request.search_path);
  EXPECT_THAT(repo.Options("db"), ElementsAre("mysql", "sqlite"));
  EXPECT_EQ(repo.Find("db/mysql"), base / "a" / "db" / "mysql.yaml");
  EXPECT_TRUE(repo.IsGroup("db"));
  EXPECT_FALSE(repo.IsGroup("db/mysql"));
  EXPECT_FALSE(repo.Find("db/oracle").has_value());
}

TEST(ComposeSearchPath, NonPrimaryConfigCannotSetSearchPath) {
  const fs::path dir = MakeTree(
      {{"config.yaml", "defaults:\n  - db: mysql\n"},
       {"db/mysql.yaml", "driver: mysql\nhydra:\n  searchpath: [file://.]\n"}});
  EXPECT_EQ(ComposeError(dir),
            "In 'db/mysql': Overriding hydra.searchpath is only supported from "
            "the primary config");
}

TEST(ComposeRepository, GroupsAreRecursive) {
  const fs::path dir = MakeTree(ServerFiles(""));
  testing::WriteTextFile(dir, "db/mysql.yaml", "x: 1\n");
  const ConfigRepository repo({dir.string()});
  EXPECT_THAT(repo.Groups(), ElementsAre("db", "server", "server/db"));
  EXPECT_THAT(repo.Options("server/db"), ElementsAre("mysql", "sqlite"));
  EXPECT_THROW(repo.Find("../x"), ConfigError);
}

// ---------------------------------------------------------------------------
// The hydra node.

TEST(ComposeHydraNode, ContentAfterComposition) {
  const fs::path dir = MakeTree(
      WithDb({{"config.yaml", "defaults:\n  - db: mysql\n\nseed: 1\n"}}));
  ComposeRequest request = Request(
      dir, {"db=postgresql", "seed=2", "hydra.run.dir=out/x", "+extra=1"});
  request.job_name = "my_app";
  const ComposeResult result = Compose(request);
  const ConfigNode& hydra = result.root.at("hydra");
  EXPECT_EQ(Str(hydra, "mode"), "RUN");
  EXPECT_EQ(Str(hydra, "job.name"), "my_app");
  EXPECT_EQ(Str(hydra, "job.config_name"), "config");
  EXPECT_EQ(Str(hydra, "job.id"), "0");
  EXPECT_EQ(Int(hydra, "job.num"), 0);
  EXPECT_FALSE(At(hydra, "job.chdir").AsBool());
  EXPECT_EQ(Str(hydra, "run.dir"), "out/x");
  EXPECT_TRUE(At(hydra, "sweep.dir").IsInterpolation());
  EXPECT_EQ(At(hydra, "sweep.subdir").text(), "${hydra.job.num}");
  EXPECT_EQ(Str(hydra, "output_subdir"), ".hydra");
  EXPECT_EQ(Int(hydra, "launcher.n_jobs"), 1);
  EXPECT_TRUE(At(hydra, "sweeper.params").IsNull());
  EXPECT_TRUE(At(hydra, "runtime.output_dir").IsMissing());
  EXPECT_EQ(Str(hydra, "runtime.cwd"), fs::current_path().string());
  EXPECT_FALSE(Str(hydra, "runtime.version").empty());
  EXPECT_THAT(StringList(At(hydra, "overrides.task")),
              ElementsAre("db=postgresql", "seed=2", "+extra=1"));
  EXPECT_THAT(StringList(At(hydra, "overrides.hydra")),
              ElementsAre("hydra.run.dir=out/x"));
  EXPECT_EQ(Str(hydra, "runtime.choices.db"), "postgresql");
  EXPECT_EQ(Str(hydra, "job.override_dirname"),
            "+extra=1,db=postgresql,seed=2");
  EXPECT_EQ(Int(result.root, "seed"), 2);
  EXPECT_EQ(Int(result.root, "extra"), 1);
}

TEST(ComposeHydraNode, PrimaryConfigCustomizesHydra) {
  const fs::path dir = MakeTree(
      {{"config.yaml",
        "seed: 1\nlr: 0.1\nhydra:\n  run:\n    dir: results/runs/x\n  job:\n"
        "    name: custom\n    config:\n      override_dirname:\n"
        "        kv_sep: ':'\n        item_sep: _\n        exclude_keys: "
        "[seed]\n"}});
  ComposeRequest request = Request(dir, {"seed=3", "lr=0.2"});
  request.mode = RunMode::kMultirun;
  const ComposeResult result = Compose(request);
  EXPECT_EQ(Str(result.root, "hydra.run.dir"), "results/runs/x");
  EXPECT_EQ(Str(result.root, "hydra.job.name"), "custom");
  EXPECT_EQ(Str(result.root, "hydra.mode"), "MULTIRUN");
  EXPECT_TRUE(At(result.root, "hydra.job.id").IsMissing());
  EXPECT_EQ(Str(result.root, "hydra.job.override_dirname"), "lr:0.2");
}

TEST(ComposeHydraNode, DefaultsAreMergedFirst) {
  const ConfigNode defaults = HydraDefaults();
  EXPECT_THAT(Keys(defaults), ElementsAre("hydra"));
  EXPECT_EQ(At(defaults, "hydra.run.dir").text(),
            "outputs/${now:%Y-%m-%d}/${now:%H-%M-%S}");
  EXPECT_EQ(At(defaults, "hydra.sweep.dir").text(),
            "multirun/${now:%Y-%m-%d}/${now:%H-%M-%S}");
  EXPECT_EQ(Str(defaults, "hydra.mode"), "RUN");
  EXPECT_EQ(Str(defaults, "hydra.job.config.override_dirname.kv_sep"), "=");
  EXPECT_EQ(Str(defaults, "hydra.job.config.override_dirname.item_sep"), ",");
  EXPECT_EQ(ToString(RunMode::kMultirun), "MULTIRUN");
}

TEST(ComposeHydraNode, HydraKeysNeedPlusToAdd) {
  const fs::path dir = MakeTree({{"config.yaml", ""}});
  EXPECT_EQ(ComposeError(dir, {"hydra.foo=1"}),
            "Could not override 'hydra.foo'. To append to your config use "
            "+hydra.foo=1");
}

}  // namespace
}  // namespace soma
