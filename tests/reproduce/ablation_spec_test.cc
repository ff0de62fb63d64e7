#include "framework/reproduce/ablation_spec.h"

#include "framework/config/compose.h"
#include "framework/config/override.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

namespace soma {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

constexpr char kSpec[] = R"(
name: demo
title: "Demo table"
paper_ref: "SOMA Table 5"
seeds: 2
differences:
  - "smaller model"
  - {text: "cmu41 layout", unless_budget_sets: layout}
  - {text: "fitted layout", if_budget_sets: layout}
tests:
  hdm05: {label: "HDM05", take: c3d/a.c3d, setting: OC_05_G_03_BT_00}
  occ5: {take: c3d/a.c3d, setting: OCE_05_G_00_BT_00, tracklet: true,
         corrupt_overrides: ["layout.exclude=[RBAC,LSHN]"],
         eval_overrides: [task.unknown_gt_labels=ghost],
         label_overrides: [layout=pig39]}
variants:
  - name: base
    label: "Base"
    paper: {hdm05: {acc: 95.5, acc_std: 5.33, f1: 94.66}}
  - name: log_softmax
    overrides: [normalization=log_softmax]
  - name: no_real
    skip: "needs the solver"
  - name: target_layout
    overrides: [layout=file, layout.path=x.json]
    skip_if_budget_sets: layout
claims:
  - {text: "Sinkhorn helps", test: hdm05, better: base, worse: log_softmax}
  - {text: "robust", test: hdm05, worse_test: occ5, kind: close,
     tolerance: 2.0, better: base, worse: base, paper_gap: 0.7}
)";

AblationSpec Parse(const std::string& yaml) {
  return ParseAblationSpec(ParseYaml(yaml, "demo.yaml"), "demo.yaml");
}

/// kSpec with `from` replaced by `to` (which must occur).
std::string Edit(const std::string& from, const std::string& to) {
  std::string s = kSpec;
  const size_t at = s.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  return s.replace(at, from.size(), to);
}

TEST(AblationSpecTest, ParsesEveryField) {
  const AblationSpec spec = Parse(kSpec);
  EXPECT_EQ(spec.name, "demo");
  EXPECT_EQ(spec.seeds, 2);
  ASSERT_EQ(spec.differences.size(), 3u);
  EXPECT_EQ(spec.differences[0].text, "smaller model");
  EXPECT_EQ(spec.differences[1].unless_budget_sets, "layout");
  EXPECT_EQ(spec.differences[2].if_budget_sets, "layout");
  ASSERT_EQ(spec.tests.size(), 2u);
  EXPECT_EQ(spec.Test("hdm05").setting, "OC_05_G_03_BT_00");
  EXPECT_FALSE(spec.Test("hdm05").tracklet);
  EXPECT_EQ(spec.Test("occ5").label, "occ5");  // defaults to the name
  EXPECT_TRUE(spec.Test("occ5").tracklet);
  EXPECT_TRUE(spec.Test("hdm05").corrupt_overrides.empty());
  EXPECT_THAT(spec.Test("occ5").corrupt_overrides,
              ElementsAre("layout.exclude=[RBAC,LSHN]"));
  EXPECT_THAT(spec.Test("occ5").eval_overrides,
              ElementsAre("task.unknown_gt_labels=ghost"));
  EXPECT_THAT(spec.Test("occ5").label_overrides, ElementsAre("layout=pig39"));
  EXPECT_TRUE(spec.Test("hdm05").label_overrides.empty());
  ASSERT_EQ(spec.variants.size(), 4u);
  EXPECT_THAT(spec.Variant("log_softmax").overrides,
              ElementsAre("normalization=log_softmax"));
  EXPECT_EQ(spec.Variant("no_real").skip, "needs the solver");
  EXPECT_EQ(spec.Variant("target_layout").skip_if_budget_sets, "layout");
  EXPECT_TRUE(spec.Variant("target_layout").skip.empty());
  EXPECT_TRUE(spec.Variant("base").tests.empty());
  EXPECT_TRUE(spec.Variant("base").Evaluates("occ5"));
  AblationVariant only_occ5;
  only_occ5.tests = {"occ5"};
  EXPECT_TRUE(only_occ5.Evaluates("occ5"));
  EXPECT_FALSE(only_occ5.Evaluates("hdm05"));
  const PaperValue& acc = spec.Variant("base").paper.at("hdm05").at("acc");
  EXPECT_DOUBLE_EQ(acc.mean, 95.5);
  EXPECT_DOUBLE_EQ(*acc.std, 5.33);
  EXPECT_FALSE(spec.Variant("base").paper.at("hdm05").at("f1").std);
  ASSERT_EQ(spec.claims.size(), 2u);
  EXPECT_EQ(spec.claims[0].better_test, "hdm05");
  EXPECT_EQ(spec.claims[0].kind, "greater");
  EXPECT_EQ(spec.claims[1].worse_test, "occ5");
  EXPECT_DOUBLE_EQ(*spec.claims[1].paper_gap, 0.7);
}

TEST(AblationSpecTest, ConditionalDifferencesFollowTheBudget) {
  const AblationSpec spec = Parse(kSpec);
  const auto texts = [&](const std::vector<std::string>& budget) {
    std::vector<std::string> out;
    for (const AblationDifference& d : spec.differences) {
      if (d.AppliesTo(budget)) out.push_back(d.text);
    }
    return out;
  };
  EXPECT_THAT(texts({"scale=cpu", "train.max_epochs=20"}),
              ElementsAre("smaller model", "cmu41 layout"));
  EXPECT_THAT(texts({"scale=cpu", "layout=file", "layout.path=x.json"}),
              ElementsAre("smaller model", "fitted layout"));
  EXPECT_THAT(texts({"layout.exclude=[RBAC]"}),
              ElementsAre("smaller model", "fitted layout"));
  // Only the key itself: `layouts=...` or `layout_seed=...` do not set it.
  EXPECT_THAT(texts({"layouts=[a]", "layout_seed=3"}),
              ElementsAre("smaller model", "cmu41 layout"));
}

// A row that varies what the budget fixes for every row would train the
// same models as another row: it is skipped, with the reason.
TEST(AblationSpecTest, RowsVaryingWhatTheBudgetSetsAreSkipped) {
  const AblationSpec quick = ApplyBudget(Parse(kSpec), {"scale=cpu"});
  EXPECT_TRUE(quick.Variant("target_layout").skip.empty());
  const AblationSpec fitted =
      ApplyBudget(Parse(kSpec), {"scale=cpu", "layout.path=y.json"});
  EXPECT_THAT(fitted.Variant("target_layout").skip,
              HasSubstr("task.budget sets `layout`"));
  EXPECT_TRUE(fitted.Variant("base").skip.empty());
  EXPECT_EQ(fitted.Variant("no_real").skip, "needs the solver");
}

TEST(AblationSpecTest, BadSpecsAreOneLineConfigErrors) {
  struct Case {
    std::string from, to, message;
  };
  const std::vector<Case> cases = {
      {"seeds: 2", "seeds: 2\nrows: 3", "unknown key 'rows'"},
      {"seeds: 2", "seeds: 0", "seeds >= 1"},
      {"name: log_softmax", "name: base", "variant 'base' is defined twice"},
      {"name: log_softmax", "name: Log-Softmax", "an identifier"},
      {"worse: log_softmax}", "worse: nope}", "a variant name"},
      {"test: hdm05, better: base, worse: log_softmax",
       "test: hdm06, better: base, worse: log_softmax",
       "a test of this spec"},
      {"paper: {hdm05:", "paper: {hdm06:", "a test of this spec"},
      {"tolerance: 2.0,", "", "needs a tolerance"},
      {"kind: close", "kind: less", "greater, close or not_behind"},
      {"acc: 95.5, acc_std: 5.33, f1: 94.66",
       "acc: 95.5, f1_std: 5.33",
       "f1_std needs f1"},
      {"setting: OCE_05_G_00_BT_00, ", "", "Missing key"},
      {"overrides: [normalization=log_softmax]",
       "overrides: [normalization=log_softmax]\n    tests: [occ6]",
       "names of tests of this spec"},
      {"overrides: [normalization=log_softmax]",
       "overrides: [normalization=log_softmax]\n    tests: [occ5]",
       "claim 'Sinkhorn helps' reads variant 'log_softmax' on test 'hdm05', "
       "which that variant's tests leave out"},
      {"label: \"Base\"",
       "label: \"Base\"\n    tests: [occ5]",
       "a test this variant is evaluated on"},
      {"if_budget_sets: layout}",
       "if_budget_sets: layout, unless_budget_sets: scale}",
       "at most one of if_budget_sets and unless_budget_sets"},
      {"if_budget_sets: layout}", "if_budget: layout}", "unknown key"},
      {"differences:", "differences: 3\nx:", "a list of strings"},
  };
  for (const Case& c : cases) {
    const std::string message =
        testing::ErrorMessage<ConfigError>([&] { Parse(Edit(c.from, c.to)); });
    EXPECT_THAT(message, HasSubstr(c.message)) << c.to;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  }
}

TEST(AblationSpecTest, LoadChecksTheFileNameAndListsAvailableSpecs) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(dir, "demo.yaml", kSpec);
  testing::WriteTextFile(dir, "other.yaml", kSpec);
  EXPECT_EQ(LoadAblationSpec("demo", dir).name, "demo");
  EXPECT_EQ(LoadAblationSpec((dir / "demo.yaml").string(), "/nowhere").name,
            "demo");
  EXPECT_THAT(testing::ErrorMessage<ConfigError>(
                  [&] { LoadAblationSpec("other", dir); }),
              HasSubstr("name 'demo' differs from the file name 'other'"));
  EXPECT_THAT(
      testing::ErrorMessage<IoError>([&] { LoadAblationSpec("table9", dir); }),
      HasSubstr("no such ablation spec. Available in " + dir.string() +
                ": demo, other"));
}

TEST(AblationSpecTest, EveryShippedSpecIsValid) {
  const auto dir = testing::SourceDir() / "ablations";
  const std::vector<std::string> names = ListAblationSpecs(dir);
  for (const char* required : {"table1",
                               "table2",
                               "table3",
                               "table4",
                               "table5",
                               "fig_c1",
                               "fig_c2",
                               "fig_c3"}) {
    EXPECT_THAT(names, ::testing::Contains(required));
  }
  for (const std::string& name : names) {
    const AblationSpec spec = LoadAblationSpec(name, dir);
    EXPECT_GE(spec.seeds, 3) << name << ": the issue asks for >= 3 seeds";
    EXPECT_FALSE(spec.differences.empty())
        << name << " must state how it differs from the paper";
    EXPECT_FALSE(spec.claims.empty()) << name;
  }
}

// Every override of a shipped spec composes with the task it is passed to, so
// a misspelt key fails here, not hours into a reproduction.
TEST(AblationSpecTest, EveryShippedOverrideComposesWithItsTask) {
  const auto compose = [](const std::string& task,
                          const std::vector<std::string>& overrides) {
    ComposeRequest request;
    request.search_path = {(testing::SourceDir() / "configs").string()};
    std::vector<std::string> args = {"task=" + task};
    args.insert(args.end(), overrides.begin(), overrides.end());
    request.overrides = ParseOverrides(args);
    return TaskConfig(Compose(request).root);
  };
  // The composition error, or "" when the overrides compose.
  const auto error = [&](const std::string& task,
                         const std::vector<std::string>& overrides) {
    try {
      compose(task, overrides);
      return std::string();
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
  };
  const ConfigNode reproduce = compose("reproduce", {});
  std::vector<std::string> budget;
  for (const ConfigNode& item : reproduce.at("task").at("budget").items()) {
    budget.push_back(item.AsString());
  }
  ASSERT_FALSE(budget.empty());
  const auto dir = testing::SourceDir() / "ablations";
  for (const std::string& name : ListAblationSpecs(dir)) {
    const AblationSpec spec = LoadAblationSpec(name, dir);
    for (const AblationVariant& variant : spec.variants) {
      std::vector<std::string> overrides = budget;
      overrides.insert(
          overrides.end(), variant.overrides.begin(), variant.overrides.end());
      EXPECT_EQ(error("train", overrides), "")
          << name << ", variant " << variant.name;
    }
    for (const AblationTest& test : spec.tests) {
      EXPECT_EQ(error("corrupt", test.corrupt_overrides), "")
          << name << ", test " << test.name;
      EXPECT_EQ(error("eval", test.eval_overrides), "")
          << name << ", test " << test.name;
      EXPECT_EQ(error("label", test.label_overrides), "")
          << name << ", test " << test.name;
    }
  }
  // The check can fail: a misspelt key does not compose.
  EXPECT_THAT(error("train", {"synth.marker_rings=0"}),
              HasSubstr("synth.marker_rings"));
}

}  // namespace
}  // namespace soma
