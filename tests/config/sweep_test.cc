#include "framework/config/sweep.h"

#include "framework/config/compose.h"
#include "framework/config/node.h"
#include "framework/config/override.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace soma {
namespace {

using Jobs = std::vector<std::vector<std::string>>;

// A config dir with the `experiment` and `db` groups.
std::filesystem::path MakeConfigDir() {
  const std::filesystem::path dir = testing::CreateTestDir();
  testing::WriteTextFile(dir, "config.yaml", "defaults:\n  - db: mysql\n");
  testing::WriteTextFile(dir, "db/mysql.yaml", "driver: mysql\n");
  testing::WriteTextFile(dir, "db/postgresql.yaml", "driver: postgresql\n");
  testing::WriteTextFile(dir, "db/sqlite.yaml", "driver: sqlite\n");
  testing::WriteTextFile(
      dir, "experiment/nglite.yaml", "# @package _global_\nx: 2\n");
  testing::WriteTextFile(
      dir, "experiment/aplite.yaml", "# @package _global_\nx: 1\n");
  testing::WriteTextFile(dir, "server/db/a.yaml", "k: 1\n");
  testing::WriteTextFile(dir, "server/db/b.yaml", "k: 2\n");
  return dir;
}

// A sweep-level root holding `hydra.sweeper.params`.
ConfigNode RootWithParams(
    std::vector<std::pair<std::string, ConfigNode>> params) {
  ConfigNode p = ConfigNode::EmptyMap();
  for (auto& [key, value] : params) p.Set(key, std::move(value));
  ConfigNode sweeper = ConfigNode::EmptyMap();
  sweeper.Set("params", std::move(p));
  ConfigNode hydra = ConfigNode::EmptyMap();
  hydra.Set("sweeper", std::move(sweeper));
  ConfigNode root = ConfigNode::EmptyMap();
  root.Set("hydra", std::move(hydra));
  return root;
}

class SweepTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = MakeConfigDir(); }

  Jobs Expand(const std::vector<std::string>& cli,
              const ConfigNode& root = ConfigNode::EmptyMap()) const {
    const ConfigRepository repo({dir_.string()});
    return ExpandSweep(root, ParseOverrides(cli), repo);
  }

  std::string ErrorOf(const std::vector<std::string>& cli,
                      const ConfigNode& root = ConfigNode::EmptyMap()) const {
    try {
      Expand(cli, root);
    } catch (const ConfigError& e) {
      return e.what();
    }
    ADD_FAILURE() << "no ConfigError";
    return "";
  }

  std::filesystem::path dir_;
};

TEST_F(SweepTest, CartesianProductLastKeyFastest) {
  EXPECT_EQ(
      Expand({"a=1,2", "b=x,y"}),
      (Jobs{{"a=1", "b=x"}, {"a=1", "b=y"}, {"a=2", "b=x"}, {"a=2", "b=y"}}));
}

TEST_F(SweepTest, NoOverridesIsOneEmptyJob) {
  EXPECT_EQ(Expand({}), (Jobs{{}}));
}

TEST_F(SweepTest, NonSweepOverridesAreSingleValuesKeptVerbatim) {
  EXPECT_EQ(Expand({"c=  z  ", "a=1,2", "+d.e=[1, 2]", "~f"}),
            (Jobs{{"c=  z  ", "a=1", "+d.e=[1, 2]", "~f"},
                  {"c=  z  ", "a=2", "+d.e=[1, 2]", "~f"}}));
}

TEST_F(SweepTest, RepeatedKeyKeepsFirstPositionAndLastValue) {
  EXPECT_EQ(Expand({"a=1,2", "b=y", "a=9"}), (Jobs{{"a=9", "b=y"}}));
  EXPECT_EQ(
      Expand({"a=1", "b=x,y", "a=3,4"}),
      (Jobs{{"a=3", "b=x"}, {"a=3", "b=y"}, {"a=4", "b=x"}, {"a=4", "b=y"}}));
  // Prefix and package are part of the key.
  EXPECT_EQ(Expand({"db=mysql", "+db@src=sqlite"}),
            (Jobs{{"db=mysql", "+db@src=sqlite"}}));
}

TEST_F(SweepTest, RangeSweeps) {
  EXPECT_EQ(Expand({"a=range(5)"}),
            (Jobs{{"a=0"}, {"a=1"}, {"a=2"}, {"a=3"}, {"a=4"}}));
  EXPECT_EQ(Expand({"a=range(-5,step=-1)"}),
            (Jobs{{"a=0"}, {"a=-1"}, {"a=-2"}, {"a=-3"}, {"a=-4"}}));
  // Hydra (extended.md): range(0,10,3.3) -> 0.0,3.3,6.6,9.9.
  EXPECT_EQ(Expand({"a=range(0,10,3.3)"}),
            (Jobs{{"a=0.0"}, {"a=3.3"}, {"a=6.6"}, {"a=9.9"}}));
  EXPECT_EQ(
      Expand({"a=range(0.3,0,-0.1)"}),
      (Jobs{{"a=0.3"}, {"a=0.19999999999999998"}, {"a=0.09999999999999998"}}));
}

TEST_F(SweepTest, JobOverridesReparseToTheSweptValues) {
  // Quoted elements keep their quotes, as written (Hydra's
  // QuotedString.with_quotes()).
  const Jobs jobs = Expand({"a=\"x,y\",z,'1',''", "b=[1,2],[3]", "c={k:v}"});
  EXPECT_EQ(jobs,
            (Jobs{{"a=\"x,y\"", "b=[1,2]", "c={k:v}"},
                  {"a=\"x,y\"", "b=[3]", "c={k:v}"},
                  {"a=z", "b=[1,2]", "c={k:v}"},
                  {"a=z", "b=[3]", "c={k:v}"},
                  {"a='1'", "b=[1,2]", "c={k:v}"},
                  {"a='1'", "b=[3]", "c={k:v}"},
                  {"a=''", "b=[1,2]", "c={k:v}"},
                  {"a=''", "b=[3]", "c={k:v}"}}));
  const std::vector<ConfigNode> a_values = {ConfigNode::FromString("x,y"),
                                            ConfigNode::FromString("z"),
                                            ConfigNode::FromString("1"),
                                            ConfigNode::FromString("")};
  for (size_t i = 0; i < jobs.size(); ++i) {
    const Override o = ParseOverride(jobs[i][0]);
    ASSERT_FALSE(o.IsSweep());
    EXPECT_EQ(*o.value, a_values[i / 2]);
  }
}

// Hydra writes a swept value that needs quotes into the job's
// .hydra/overrides.yaml as written: b='hello world', not b=hello world.
TEST_F(SweepTest, QuotedSweepValuesKeepTheirQuotes) {
  EXPECT_EQ(Expand({"b='hello world',x"}),
            (Jobs{{"b='hello world'"}, {"b=x"}}));
  EXPECT_EQ(Expand({"b=choice(\"hello world\",'it\\'s')"}),
            (Jobs{{"b=\"hello world\""}, {"b='it\\'s'"}}));
  // sort() reorders; each value keeps its own text.
  EXPECT_EQ(Expand({"b=sort('z z',a,'b')"}),
            (Jobs{{"b=a"}, {"b='b'"}, {"b='z z'"}}));
  // A non-sweep override in a multirun is kept as written.
  EXPECT_EQ(Expand({"b='hello world'", "a=1,2"}),
            (Jobs{{"b='hello world'", "a=1"}, {"b='hello world'", "a=2"}}));
  // A cast value has no source quotes; strings that would re-parse as
  // another type are single-quoted (Hydra would write b=1 here).
  EXPECT_EQ(Expand({"b=str(choice('1',2))"}), (Jobs{{"b='1'"}, {"b='2'"}}));
}

TEST_F(SweepTest, PrefixAndPackageInJobOverrides) {
  EXPECT_EQ(Expand({"+server/db@src=a,b"}),
            (Jobs{{"+server/db@src=a"}, {"+server/db@src=b"}}));
  EXPECT_EQ(Expand({"~x=1,2"}), (Jobs{{"~x=1"}, {"~x=2"}}));
  EXPECT_EQ(Expand({"++x.y=choice(1)"}), (Jobs{{"++x.y=1"}}));
}

TEST_F(SweepTest, GlobOverGroupOptions) {
  EXPECT_EQ(Expand({"+experiment=glob(*)"}),
            (Jobs{{"+experiment=aplite"}, {"+experiment=nglite"}}));
  EXPECT_EQ(Expand({"+experiment=glob(*,exclude=ng*)"}),
            (Jobs{{"+experiment=aplite"}}));
  EXPECT_EQ(
      Expand({"db=glob([m*,p*],exclude=[mysql])", "+experiment=glob(a*)"}),
      (Jobs{{"db=postgresql", "+experiment=aplite"}}));
  EXPECT_EQ(Expand({"db=sort(glob(*),reverse=true)"}),
            (Jobs{{"db=sqlite"}, {"db=postgresql"}, {"db=mysql"}}));
  EXPECT_EQ(Expand({"server/db@src=glob(*)"}),
            (Jobs{{"server/db@src=a"}, {"server/db@src=b"}}));
  EXPECT_NE(
      ErrorOf({"nogroup=glob(*)"}).find("'nogroup' is not a config group"),
      std::string::npos);
  EXPECT_NE(ErrorOf({"db=glob(zz*)"}).find("has no values"), std::string::npos);
}

TEST_F(SweepTest, SortAndShuffle) {
  EXPECT_EQ(Expand({"a=sort(3,1,2)"}), (Jobs{{"a=1"}, {"a=2"}, {"a=3"}}));
  EXPECT_EQ(Expand({"a=sort(3,1,2,reverse=true)"}),
            (Jobs{{"a=3"}, {"a=2"}, {"a=1"}}));
  const Jobs shuffled = Expand({"a=shuffle(range(6),seed=11)"});
  EXPECT_EQ(shuffled, Expand({"a=shuffle(range(6),seed=11)"}));
  Jobs expected;
  for (const int i : Rng(11).Permutation(6)) {
    expected.push_back({"a=" + std::to_string(i)});
  }
  EXPECT_EQ(shuffled, expected);
}

TEST_F(SweepTest, SweeperParamsComeFirstAndCliReplacesThem) {
  const ConfigNode root =
      RootWithParams({{"db", ConfigNode::FromString("mysql,postgresql")},
                      {"lr", ConfigNode::FromString("range(1,3)")},
                      {"seed", ConfigNode(7)}});
  EXPECT_EQ(Expand({}, root),
            (Jobs{{"db=mysql", "lr=1", "seed=7"},
                  {"db=mysql", "lr=2", "seed=7"},
                  {"db=postgresql", "lr=1", "seed=7"},
                  {"db=postgresql", "lr=2", "seed=7"}}));
  // The CLI replaces a config param key by key (keeping its position) and
  // appends new keys.
  EXPECT_EQ(Expand({"b=x,y", "lr=0.5"}, root),
            (Jobs{{"db=mysql", "lr=0.5", "seed=7", "b=x"},
                  {"db=mysql", "lr=0.5", "seed=7", "b=y"},
                  {"db=postgresql", "lr=0.5", "seed=7", "b=x"},
                  {"db=postgresql", "lr=0.5", "seed=7", "b=y"}}));
  EXPECT_EQ(
      Expand({"db=sqlite", "lr=range(3,5)"}, root),
      (Jobs{{"db=sqlite", "lr=3", "seed=7"}, {"db=sqlite", "lr=4", "seed=7"}}));
}

TEST_F(SweepTest, SweeperParamsMayBeAbsentNullOrEmpty) {
  EXPECT_EQ(Expand({"a=1,2"}, ConfigNode()), (Jobs{{"a=1"}, {"a=2"}}));
  EXPECT_EQ(Expand({"a=1,2"}, RootWithParams({})), (Jobs{{"a=1"}, {"a=2"}}));
  ConfigNode null_params = RootWithParams({});
  null_params.at("hydra").at("sweeper").Set("params", ConfigNode::Null());
  EXPECT_EQ(Expand({"a=1,2"}, null_params), (Jobs{{"a=1"}, {"a=2"}}));
}

TEST_F(SweepTest, BadSweeperParamsNameTheirOrigin) {
  const ConfigNode root =
      RootWithParams({{"db", ConfigNode::FromString("[mysql")}});
  EXPECT_NE(ErrorOf({}, root).find("hydra.sweeper.params"), std::string::npos);
}

TEST_F(SweepTest, SweepingOverHydraIsAnError) {
  EXPECT_EQ(ErrorOf({"a=1,2", "hydra.job.chdir=true,false"}),
            "Sweeping over Hydra's configuration is not supported : "
            "'hydra.job.chdir=true,false'");
  EXPECT_NE(ErrorOf({"hydra/launcher=a,b"}).find("not supported"),
            std::string::npos);
  // A plain hydra override is part of every job.
  EXPECT_EQ(Expand({"hydra.job.chdir=false", "a=1,2"}),
            (Jobs{{"hydra.job.chdir=false", "a=1"},
                  {"hydra.job.chdir=false", "a=2"}}));
}

TEST_F(SweepTest, EmptySweepIsAnError) {
  EXPECT_NE(ErrorOf({"a=range(3,1)"}).find("'a=range(3,1)' has no values"),
            std::string::npos);
}

}  // namespace
}  // namespace soma
