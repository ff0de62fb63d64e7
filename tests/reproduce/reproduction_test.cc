// The reproduction runner against a fake `soma` (a shell script that writes
// what each command would), so planning, resuming and failure handling are
// tested without training anything; tests/integration runs the real one.
#include "framework/reproduce/reproduction.h"

#include "framework/config/ledger.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <sstream>
#include <sys/stat.h>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

AblationSpec Spec() {
  return ParseAblationSpec(ParseYaml(R"(
name: demo
title: "Demo"
seeds: 2
tests:
  a: {take: c3d/take.c3d, setting: OC_05_G_03_BT_00}
  b: {take: c3d/take.c3d, setting: OC_05_G_03_BT_00, tracklet: true}
variants:
  - {name: base}
  - {name: lsm, overrides: [normalization=log_softmax]}
  - {name: bank, skip: "needs the solver"}
claims: []
)",
                                     "demo.yaml"),
                           "demo.yaml");
}

// Appends "<command> <run dir>" to $FAKE_CALLS, fails when the run dir
// contains $FAKE_FAIL, else writes the metrics the real command reports.
constexpr char kFakeSoma[] = R"(#!/bin/sh
cmd="$1"; dir=""
for a in "$@"; do case "$a" in hydra.run.dir=*) dir="${a#hydra.run.dir=}";; esac; done
mkdir -p "$dir"
echo "$cmd $dir" >> "$FAKE_CALLS"
if [ -n "$FAKE_FAIL" ] && case "$dir" in *"$FAKE_FAIL"*) true;; *) false;; esac; then
  echo "Could not find the checkpoint" > "$dir/error.txt"; exit 1
fi
case "$cmd" in
  train) printf 'val_acc: 0.9\nval_f1: 0.8\nepochs: 20\n' > "$dir/metrics.yaml";;
  eval) case "$dir" in
          *normalization*) printf 'acc_mean: 0.8\nacc_std: 0.1\nf1_mean: 0.7\nf1_std: 0.2\n' > "$dir/metrics.yaml";;
          *) printf 'acc_mean: 0.9\nacc_std: 0.05\nf1_mean: 0.85\nf1_std: 0.1\n' > "$dir/metrics.yaml";;
        esac;;
  *) printf 'ok: 1\n' > "$dir/metrics.yaml";;
esac
)";

class ReproductionTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::CreateTestDir();
    const fs::path fake = dir_ / "soma";
    WriteFileAtomic(fake, kFakeSoma);
    ::chmod(fake.c_str(), 0755);
    options_.executable = fake;
    options_.root = dir_ / "root";
    options_.data_dir = "/data";
    options_.budget = {"scale=cpu", "train.max_epochs=2"};
    options_.jobs = 2;
    ::setenv("FAKE_CALLS", (dir_ / "calls.txt").c_str(), 1);
    ::unsetenv("FAKE_FAIL");
  }
  void TearDown() override {
    ::unsetenv("FAKE_CALLS");
    ::unsetenv("FAKE_FAIL");
  }

  std::vector<std::string> Calls() const {
    std::vector<std::string> calls;
    if (!fs::exists(dir_ / "calls.txt")) return calls;
    std::istringstream in(ReadFile(dir_ / "calls.txt"));
    for (std::string line; std::getline(in, line);) calls.push_back(line);
    fs::remove(dir_ / "calls.txt");
    return calls;
  }

  fs::path dir_;
  ReproductionOptions options_;
};

TEST_F(ReproductionTest, PlanIsSeedMajorAndSharesModelsByOverrides) {
  const ReproductionPlan plan = PlanReproduction(Spec(), options_);
  EXPECT_EQ(plan.seeds, 2);
  ASSERT_EQ(plan.corrupt.size(), 1u);  // one take x setting for both tests
  EXPECT_THAT(plan.corrupt[0].argv,
              ElementsAre(options_.executable.string(),
                          "corrupt",
                          "task.files=[/data/c3d/take.c3d]",
                          "task.settings=[OC_05_G_03_BT_00]",
                          "seed=0",
                          ::testing::StartsWith("hydra.run.dir=")));
  ASSERT_EQ(plan.models.size(), 4u);  // the skipped variant is not planned
  EXPECT_EQ(plan.models[0].variant, "base");
  EXPECT_EQ(plan.models[1].variant, "lsm");
  EXPECT_EQ(plan.models[2].variant, "base");
  EXPECT_EQ(plan.models[2].seed, 1);
  EXPECT_THAT(plan.models[1].train_overrides,
              ElementsAre("scale=cpu",
                          "train.max_epochs=2",
                          "normalization=log_softmax",
                          "seed=0"));
  EXPECT_EQ(plan.models[0].dir.parent_path(), plan.models[2].dir.parent_path());
  EXPECT_NE(plan.models[0].dir.parent_path(), plan.models[1].dir.parent_path());
  // train + (label, eval) per test.
  ASSERT_EQ(plan.models[0].commands.size(), 5u);
  EXPECT_EQ(plan.models[0].commands[0].argv[1], "train");
  EXPECT_THAT(plan.models[0].commands[3].argv,
              ::testing::Contains("task.tracklet=true"));
  // A different budget trains different models.
  ReproductionOptions other = options_;
  other.budget = {"scale=cpu", "train.max_epochs=3"};
  EXPECT_NE(PlanReproduction(Spec(), other).models[0].dir, plan.models[0].dir);
  EXPECT_EQ(PlanReproduction(Spec(), options_).models[0].dir,
            plan.models[0].dir);
}

TEST_F(ReproductionTest, TrainingsShareTheCoresUnlessTheBudgetSetsThreads) {
  // Default: the preset's thread count (no override).
  EXPECT_THAT(
      PlanReproduction(Spec(), options_).models[0].commands[0].argv,
      ::testing::Not(::testing::Contains(::testing::StartsWith("threads="))));
  ReproductionOptions shared = options_;
  shared.train_threads = 1;
  const ReproductionPlan plan = PlanReproduction(Spec(), shared);
  EXPECT_THAT(plan.models[0].commands[0].argv,
              ::testing::Contains("threads=1"));
  // Not part of the model's key.
  EXPECT_EQ(plan.models[0].dir,
            PlanReproduction(Spec(), options_).models[0].dir);
  // A budget that sets threads (also as ++threads) wins.
  for (const std::string set : {"threads=2", "++threads=2"}) {
    ReproductionOptions pinned = shared;
    pinned.budget.push_back(set);
    const auto argv =
        PlanReproduction(Spec(), pinned).models[0].commands[0].argv;
    EXPECT_THAT(argv, ::testing::Contains(set));
    EXPECT_THAT(argv, ::testing::Not(::testing::Contains("threads=1"))) << set;
  }
}

TEST_F(ReproductionTest, EachBudgetKeepsItsOwnLedger) {
  const ReproductionPlan plan = PlanReproduction(Spec(), options_);
  EXPECT_EQ(plan.dir.parent_path(), options_.root);
  EXPECT_THAT(plan.dir.filename().string(), ::testing::StartsWith("demo-"));
  EXPECT_EQ(PlanReproduction(Spec(), options_).dir, plan.dir);
  ReproductionOptions other = options_;
  other.budget = {"scale=cpu", "train.max_epochs=3"};
  const ReproductionPlan other_plan = PlanReproduction(Spec(), other);
  ASSERT_NE(other_plan.dir, plan.dir);

  // Running the table under another budget leaves the first one's ledger
  // (its wall times and attempts) as it was.
  RunReproduction(plan, options_, false);
  const std::string ledger = ReadFile(plan.dir / "jobs.yaml");
  RunReproduction(other_plan, other, false);
  EXPECT_EQ(ReadFile(plan.dir / "jobs.yaml"), ledger);
  EXPECT_EQ(Ledger::Load(other_plan.dir).entries().size(), 4u);
}

TEST_F(ReproductionTest, AnUnkeyedLedgerOfThePlanIsAdoptedOnce) {
  const ReproductionPlan plan = PlanReproduction(Spec(), options_);
  // A ledger written where ledgers used to live, <root>/<name>.
  ReproductionPlan unkeyed = plan;
  unkeyed.dir = options_.root / "demo";
  RunReproduction(unkeyed, options_, false);
  Calls();
  const std::string ledger = ReadFile(unkeyed.dir / "jobs.yaml");

  // Not another budget's plan.
  ReproductionOptions other = options_;
  other.budget = {"scale=cpu", "train.max_epochs=3"};
  const ReproductionPlan other_plan = PlanReproduction(Spec(), other);
  EXPECT_FALSE(AdoptUnkeyedLedger(other_plan, unkeyed.dir));
  EXPECT_FALSE(fs::exists(other_plan.dir));

  ASSERT_TRUE(AdoptUnkeyedLedger(plan, unkeyed.dir));
  EXPECT_FALSE(fs::exists(unkeyed.dir));
  EXPECT_EQ(ReadFile(plan.dir / "jobs.yaml"), ledger);
  EXPECT_FALSE(AdoptUnkeyedLedger(plan, unkeyed.dir));
  // Everything is done: nothing runs, and the adopted records stay.
  EXPECT_EQ(RunReproduction(plan, options_, false).models_done, 4);
  EXPECT_TRUE(Calls().empty());
  EXPECT_EQ(Ledger::Load(plan.dir).entries()[0].attempts, 1);
}

TEST_F(ReproductionTest, TestOverridesReachTheirCommandsAndDirectories) {
  const AblationSpec spec = ParseAblationSpec(ParseYaml(R"(
name: layouts
title: "Layouts"
seeds: 1
tests:
  full: {take: c3d/take.c3d, setting: OC_05_G_03_BT_00,
         eval_overrides: [task.unknown_gt_labels=ghost]}
  fewer: {take: c3d/take.c3d, setting: OC_05_G_03_BT_00,
          corrupt_overrides: ["layout.exclude=[RBAC]"],
          label_overrides: [layout=pig39]}
variants:
  - {name: base}
  - {name: subset, overrides: ["layout.exclude=[RBAC]"], tests: [full]}
claims: []
)",
                                                        "layouts.yaml"),
                                              "layouts.yaml");
  const ReproductionPlan plan = PlanReproduction(spec, options_);
  // The same take and setting, corrupted twice: with and without RBAC.
  ASSERT_EQ(plan.corrupt.size(), 2u);
  EXPECT_NE(plan.corrupt[0].run_dir, plan.corrupt[1].run_dir);
  EXPECT_THAT(plan.corrupt[0].argv,
              ::testing::Not(::testing::Contains("layout.exclude=[RBAC]")));
  EXPECT_THAT(plan.corrupt[1].argv,
              ::testing::Contains("layout.exclude=[RBAC]"));
  EXPECT_EQ(plan.corrupt[1].argv.back().rfind("hydra.run.dir=", 0), 0u);
  ASSERT_EQ(plan.models.size(), 2u);
  // A variant with `tests` is labelled and evaluated only on those.
  EXPECT_EQ(plan.models[1].commands.size(), 3u);  // train, label, eval
  EXPECT_EQ(plan.models[1].eval_dirs.count("fewer"), 0u);
  EXPECT_EQ(CollectResults(spec, plan).size(), 3u * 2u);  // 3 cells x 2 metrics
  const auto& commands = plan.models[0].commands;
  ASSERT_EQ(commands.size(), 5u);  // train, (label, eval) x 2
  EXPECT_THAT(commands[2].argv,
              ::testing::Contains("task.unknown_gt_labels=ghost"));
  EXPECT_THAT(
      commands[4].argv,
      ::testing::Not(::testing::Contains("task.unknown_gt_labels=ghost")));
  EXPECT_THAT(commands[3].argv,
              ::testing::Contains(HasSubstr(plan.corrupt[1].run_dir.string())));
  // A label override reaches that test's `soma label` only, before its run
  // dir (the last argument).
  EXPECT_THAT(commands[3].argv, ::testing::Contains("layout=pig39"));
  EXPECT_EQ(commands[3].argv.back().rfind("hydra.run.dir=", 0), 0u);
  EXPECT_THAT(commands[1].argv,
              ::testing::Not(::testing::Contains("layout=pig39")));
  EXPECT_NE(plan.models[0].eval_dirs.at("full"),
            plan.models[0].eval_dirs.at("fewer"));
  // Tests without extra overrides keep their directory names (finished
  // evaluations of earlier tables stay valid).
  EXPECT_EQ(PlanReproduction(Spec(), options_).corrupt[0].run_dir.filename(),
            "take_OC_05_G_03_BT_00_seed0");
}

TEST_F(ReproductionTest, WorstFramesLinkIntoEachEvaluationsViewPage) {
  const AblationSpec spec = Spec();
  const ReproductionPlan plan = PlanReproduction(spec, options_);
  ASSERT_EQ(RunReproduction(plan, options_, false).models_done, 4);
  // base seed 0: test a has a page and three imperfect frames (and a second
  // output, run 1, that is not listed); test b is perfect, without a page.
  const fs::path a = plan.models[0].eval_dirs.at("a");
  WriteFileAtomic(a / "per_frame.csv",
                  "run,frame,pairs,accuracy,precision,recall,f1\n"
                  "0,0,4,1.000000,1,1,1\n"
                  "0,3,4,0.750000,1,1,1\n"
                  "0,7,4,0.500000,1,1,1\n"
                  "0,9,4,0.750000,1,1,1\n"
                  "1,5,4,0.000000,1,1,1\n");
  CreateDirectories(a / "view");
  WriteFileAtomic(a / "view/take_labeled.html", "<html></html>");
  WriteFileAtomic(plan.models[0].eval_dirs.at("b") / "per_frame.csv",
                  "run,frame,pairs,accuracy,precision,recall,f1\n"
                  "0,0,4,1.000000,1,1,1\n");
  const fs::path md_path = dir_ / "results" / "demo_worst_frames.md";
  CreateDirectories(md_path.parent_path());
  EXPECT_EQ(WriteWorstFramesMarkdown(spec, plan, 2, md_path), 4 * 2);
  const std::string md = ReadFile(md_path);
  const std::string page =
      fs::relative(a / "view/take_labeled.html", md_path.parent_path())
          .generic_string();
  EXPECT_EQ(page.rfind("../root/", 0), 0u) << page;  // relative to results/
  // The two worst of run 0, worst first; ties by frame.
  EXPECT_THAT(
      md,
      HasSubstr(fmt::format("| base | 0 | a | 90.00% | [7]({0}#frame=7) "
                            "50.0% of 4, [3]({0}#frame=3) 75.0% of 4 (",
                            page)));
  EXPECT_THAT(md, HasSubstr("| base | 0 | b | 90.00% | every frame 100% ("));
  EXPECT_THAT(md, HasSubstr("| lsm | 0 | a | 80.00% | no per_frame.csv ("));
  EXPECT_THAT(md, ::testing::Not(HasSubstr("#frame=5")));
}

TEST_F(ReproductionTest, OnlySelectedVariantsRunTheOthersStayPending) {
  const AblationSpec spec = Spec();
  const ReproductionPlan plan = PlanReproduction(spec, options_);
  ReproductionOptions only = options_;
  only.only_variants = {"lsm"};
  const ReproductionRun run = RunReproduction(plan, only, false);
  EXPECT_EQ(run.models_done, 2);
  for (const std::string& call : Calls()) {
    if (call.rfind("corrupt", 0) == 0) continue;
    EXPECT_THAT(call, HasSubstr("normalization"));
  }
  const Ledger ledger = Ledger::Load(plan.dir);
  EXPECT_EQ(ledger.entries()[0].status, JobStatus::kPending);
  EXPECT_EQ(ledger.entries()[1].status, JobStatus::kDone);
  // The next full run trains only what is left.
  EXPECT_EQ(RunReproduction(plan, options_, false).models_done, 4);
  EXPECT_EQ(Calls().size(), 2u * 5u);
}

TEST_F(ReproductionTest, RunsEverythingOnceThenResumesOnlyWhatIsMissing) {
  const AblationSpec spec = Spec();
  const ReproductionPlan plan = PlanReproduction(spec, options_);
  int finished = 0;
  const ReproductionRun run =
      RunReproduction(plan, options_, false, [&] { ++finished; });
  EXPECT_EQ(run.models_done, 4);
  EXPECT_EQ(run.models_failed, 0);
  EXPECT_EQ(finished, 4);
  EXPECT_EQ(Calls().size(), 1u + 4u * 5u);

  const std::vector<CellResult> cells = CollectResults(spec, plan);
  ASSERT_EQ(cells.size(), 3u * 2u * 2u);
  EXPECT_EQ(cells[0].variant, "base");
  EXPECT_EQ(cells[0].seeds_done(), 2);
  EXPECT_DOUBLE_EQ(*cells[0].Mean(), 90.0);
  EXPECT_DOUBLE_EQ(*cells[0].FrameStd(), 5.0);
  EXPECT_DOUBLE_EQ(*cells[5].Mean(), 70.0);  // lsm, test a, f1
  EXPECT_EQ(cells[8].seeds_done(), 0);       // skipped
  EXPECT_EQ(cells[8].seeds_planned, 0);

  const Ledger ledger = Ledger::Load(plan.dir);
  ASSERT_EQ(ledger.entries().size(), 4u);
  EXPECT_EQ(ledger.entries()[1].status, JobStatus::kDone);
  EXPECT_DOUBLE_EQ(ledger.entries()[1].metrics.at("a/acc_mean"), 0.8);
  EXPECT_DOUBLE_EQ(ledger.entries()[1].metrics.at("train/val_acc"), 0.9);

  // Nothing left: no command runs again.
  EXPECT_EQ(RunReproduction(plan, options_, false).models_done, 4);
  EXPECT_TRUE(Calls().empty());

  // A lost evaluation is redone alone.
  fs::remove(plan.models[3].eval_dirs.at("b") / "metrics.yaml");
  RunReproduction(plan, options_, false);
  const std::vector<std::string> calls = Calls();
  ASSERT_EQ(calls.size(), 1u);
  EXPECT_THAT(calls[0], HasSubstr("eval "));
}

TEST_F(ReproductionTest, TrainingMachinesCountTheProvenanceOfEachTraining) {
  const ReproductionPlan plan = PlanReproduction(Spec(), options_);
  EXPECT_TRUE(TrainingMachines(plan).empty());  // nothing trained yet
  RunReproduction(plan, options_, false);
  ASSERT_EQ(plan.models.size(), 4u);
  auto provenance = [&](int model, const std::string& fields) {
    fs::create_directories(plan.models[model].dir / ".hydra");
    WriteFileAtomic(plan.models[model].dir / ".hydra" / "hydra.yaml",
                    "hydra:\n  runtime:\n    provenance:\n" + fields);
  };
  provenance(0, "      host: vm\n      cpu: CPU A\n");
  provenance(1, "      host: vm\n      cpu: CPU A\n");
  provenance(2, "      host: vm\n      threads: 1\n");  // an older run
  EXPECT_THAT(TrainingMachines(plan),
              ElementsAre("vm, CPU A: 2 models",
                          "no provenance: 1 model",
                          "vm, CPU not recorded: 1 model"));
  fs::create_directories(plan.models[3].dir / ".hydra");
  WriteFileAtomic(plan.models[3].dir / ".hydra" / "hydra.yaml", "a: [b\n");
  EXPECT_THAT(TrainingMachines(plan),
              ElementsAre("vm, CPU A: 2 models",
                          "unreadable provenance: 1 model",
                          "vm, CPU not recorded: 1 model"));
  // A model whose training is not finished ran nowhere yet.
  fs::remove(plan.models[0].dir / "metrics.yaml");
  EXPECT_THAT(TrainingMachines(plan),
              ElementsAre("unreadable provenance: 1 model",
                          "vm, CPU A: 1 model",
                          "vm, CPU not recorded: 1 model"));
}

TEST_F(ReproductionTest, AFailedModelIsRecordedAndRetriedOnTheNextRun) {
  const ReproductionPlan plan = PlanReproduction(Spec(), options_);
  // Fail the label step of one model (only its dir contains this path).
  const fs::path failing = plan.models[1].commands[1].run_dir;
  ::setenv("FAKE_FAIL", failing.c_str(), 1);
  const ReproductionRun run = RunReproduction(plan, options_, false);
  EXPECT_EQ(run.models_done, 3);
  EXPECT_EQ(run.models_failed, 1);
  ASSERT_EQ(run.errors.size(), 1u);
  EXPECT_THAT(
      run.errors[0],
      HasSubstr("label lsm seed 0 on a: Could not find the checkpoint"));
  const Ledger ledger = Ledger::Load(plan.dir);
  EXPECT_EQ(ledger.entries()[1].status, JobStatus::kFailed);
  EXPECT_EQ(SummarizeLedger(plan).models_failed, 1);
  Calls();

  ::unsetenv("FAKE_FAIL");
  const ReproductionRun retry = RunReproduction(plan, options_, false);
  EXPECT_EQ(retry.models_done, 4);
  EXPECT_EQ(retry.models_failed, 0);
  // Only the failed model's remaining commands ran: its training was done.
  const std::vector<std::string> calls = Calls();
  EXPECT_EQ(calls.size(), 4u);
  EXPECT_EQ(Ledger::Load(plan.dir).entries()[1].attempts, 2);
}

TEST_F(ReproductionTest, AFailedCorruptionStopsTheReproduction) {
  const ReproductionPlan plan = PlanReproduction(Spec(), options_);
  ::setenv("FAKE_FAIL", "testdata", 1);
  EXPECT_THAT(testing::ErrorMessage<Error>(
                  [&] { RunReproduction(plan, options_, false); }),
              HasSubstr("corrupt c3d/take.c3d OC_05_G_03_BT_00: Could not "
                        "find the checkpoint"));
}

TEST_F(ReproductionTest, CommandsScriptListsEveryCommandQuoted) {
  const ReproductionPlan plan = PlanReproduction(Spec(), options_);
  WriteCommandsScript(plan, "/work dir");
  const std::string sh = ReadFile(plan.dir / "commands.sh");
  EXPECT_THAT(sh, HasSubstr("cd '/work dir'\n"));
  EXPECT_THAT(sh, HasSubstr("'task.files=[/data/c3d/take.c3d]'"));
  EXPECT_THAT(sh, HasSubstr("# lsm seed 1\n"));
  EXPECT_THAT(sh,
              HasSubstr(" train scale=cpu train.max_epochs=2 "
                        "normalization=log_softmax seed=1 hydra.run.dir="));
}

TEST(EstimateSecondsLeft, MedianModelTimeSharedBySlots) {
  // Unknown until a model has finished.
  EXPECT_LT(EstimateSecondsLeft({}, {10.0}, 3, 2), 0);
  // Median 100 s (an outlier does not move it); 4 queued models on 2 slots.
  EXPECT_DOUBLE_EQ(EstimateSecondsLeft({90.0, 100.0, 5000.0}, {}, 4, 2), 200);
  // Even count: the mean of the two middle times.
  EXPECT_DOUBLE_EQ(EstimateSecondsLeft({80.0, 120.0}, {}, 2, 2), 100);
  // A running model counts for what it has left, never less than 0; the
  // last slot to be free decides.
  EXPECT_DOUBLE_EQ(EstimateSecondsLeft({100.0}, {30.0, 150.0}, 0, 2), 70);
  EXPECT_DOUBLE_EQ(EstimateSecondsLeft({100.0}, {30.0, 150.0}, 1, 2), 100);
  EXPECT_DOUBLE_EQ(EstimateSecondsLeft({100.0}, {30.0}, 3, 2), 200);
  // One model left does not run faster with more slots.
  EXPECT_DOUBLE_EQ(EstimateSecondsLeft({100.0}, {}, 1, 4), 100);
  EXPECT_DOUBLE_EQ(EstimateSecondsLeft({100.0}, {}, 0, 2), 0);
}

TEST(TrainingCurves, OneRowPerEpochOfEveryStartedModel) {
  const fs::path dir = testing::CreateTestDir();
  ReproductionPlan plan;
  PlannedModel a;
  a.variant = "base";
  a.seed = 1;
  a.dir = dir / "a";
  PlannedModel b = a;
  b.variant = "weak";
  b.dir = dir / "b";  // not started: no metrics.csv
  plan.models = {a, b};
  CreateDirectories(a.dir);
  // `soma train`'s columns, in its order, with two more than the curves use.
  WriteFileAtomic(a.dir / "metrics.csv",
                  "epoch,step,train_loss,val_loss,val_acc,val_f1,lr\n"
                  "1,10,3.0,2.5,0.40,0.35,0.001\n"
                  "2,20,2.0,1.5,0.60,0.55,0.001\n");
  EXPECT_EQ(WriteTrainingCurvesCsv(plan, dir / "curves.csv"), 2);
  EXPECT_EQ(ReadFile(dir / "curves.csv"),
            "variant,seed,epoch,train_loss,val_loss,val_acc,val_f1\n"
            "base,1,1,3.0,2.5,0.40,0.35\n"
            "base,1,2,2.0,1.5,0.60,0.55\n");
  WriteFileAtomic(a.dir / "metrics.csv", "epoch,loss\n1,2\n");
  EXPECT_THROW(WriteTrainingCurvesCsv(plan, dir / "curves.csv"), IoError);
}

/// A command of a chain-script model: `bash -c SCRIPT` in `run_dir`.
PlannedCommand BashCommand(const std::string& name,
                           const fs::path& run_dir,
                           const std::string& script) {
  PlannedCommand c;
  c.name = name;
  c.run_dir = run_dir;
  c.argv = {"bash", "-c", script};
  return c;
}

/// Runs `script` with bash in `dir` (stdout/stderr to out.txt/err.txt);
/// returns its exit status.
int RunChain(const fs::path& dir, const std::string& script) {
  WriteFileAtomic(dir / "chain.sh", script);
  const std::string command = "cd '" + dir.string() +
                              "' && bash chain.sh >out.txt 2>err.txt; echo "
                              "$? > rc.txt";
  if (std::system(command.c_str()) != 0) return -1;
  return std::stoi(ReadFile(dir / "rc.txt"));
}

TEST(ModelChainScript, RunsUnfinishedCommandsInOrderAndStopsAtAFailure) {
  const fs::path dir = testing::CreateTestDir();
  PlannedModel model;
  model.dir = dir / "model";
  // Done already: skipped. Then one that succeeds, one that fails with an
  // error.txt, and one that must not run.
  fs::create_directories(dir / "model");
  WriteFileAtomic(dir / "model/metrics.yaml", "epochs: 1\n");
  model.commands = {
      BashCommand("train", dir / "model", "touch '" + dir.string() + "/ran0'"),
      BashCommand("label",
                  dir / "label",
                  "echo labelled; echo 'a: 1' > " +
                      (dir / "label/metrics.yaml").string()),
      BashCommand("eval",
                  dir / "eval",
                  "echo 'Bad input: x' > " + (dir / "eval/error.txt").string() +
                      "; exit 3"),
      BashCommand("never", dir / "never", "touch '" + dir.string() + "/ran3'")};
  EXPECT_EQ(RunChain(dir, ModelChainScript(model)), 3);
  EXPECT_FALSE(fs::exists(dir / "ran0"));
  EXPECT_EQ(ReadFile(dir / "label/stdout.txt"), "labelled\n");
  EXPECT_FALSE(fs::exists(dir / "ran3"));
  const std::string err = ReadFile(dir / "err.txt");
  EXPECT_THAT(err,
              HasSubstr("soma reproduce: eval failed: Bad input: x (log: " +
                        (dir / "eval/stdout.txt").string() + ")"));
  // One wall-time line per run.
  const std::string wall = ReadFile(dir / "model/slurm_wall_s");
  EXPECT_EQ(std::count(wall.begin(), wall.end(), '\n'), 1) << wall;

  // A command that exits 0 without metrics.yaml failed too; a re-run skips
  // the finished label command and removes the failed one's error.txt.
  model.commands[2] = BashCommand("eval", dir / "eval", "exit 0");
  EXPECT_EQ(RunChain(dir, ModelChainScript(model)), 1);
  EXPECT_FALSE(fs::exists(dir / "eval/error.txt"));
  EXPECT_THAT(ReadFile(dir / "err.txt"),
              HasSubstr("soma reproduce: eval failed: exit code 0"));
  EXPECT_THAT(ReadFile(dir / "out.txt"),
              HasSubstr("soma reproduce: label: done already"));
}

TEST(ModelChainScript, PassesSigusr1OnToTheRunningCommand) {
  const fs::path dir = testing::CreateTestDir();
  PlannedModel model;
  model.dir = dir / "model";
  model.commands = {
      BashCommand("train",
                  dir / "model",
                  "trap 'echo got USR1 > " + (dir / "usr1.txt").string() +
                      "; exit 138' USR1; touch " + (dir / "started").string() +
                      "; for i in $(seq 100); do sleep 0.1; done")};
  WriteFileAtomic(dir / "chain.sh", ModelChainScript(model));
  const std::string command =
      "cd '" + dir.string() +
      "' && (bash chain.sh >out.txt 2>err.txt & p=$!; for i in $(seq 100); do "
      "[ -f started ] && break; sleep 0.1; done; kill -USR1 $p; wait $p; echo "
      "$? > rc.txt)";
  ASSERT_EQ(std::system(command.c_str()), 0);
  EXPECT_EQ(ReadFile(dir / "rc.txt"), "138\n");
  EXPECT_EQ(ReadFile(dir / "usr1.txt"), "got USR1\n");
  EXPECT_THAT(ReadFile(dir / "err.txt"),
              HasSubstr("soma reproduce: train stopped by signal 10"));
}

}  // namespace
}  // namespace soma
