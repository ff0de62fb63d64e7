// End-to-end `soma reproduce` with the real binary: a two-variant, two-seed
// spec with tiny models on a 120-frame cut of the real HDM05 take. Checks the
// table, the ledger, resuming (a second run runs nothing) and bad input.
#include "framework/config/ledger.h"
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/io/c3d.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "tests/integration/soma_command.h"
#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::Not;

constexpr char kSpec[] = R"(
name: mini
title: "Mini reproduction"
seeds: 2
tests:
  short: {label: "HDM05 cut", take: c3d/short.c3d, setting: OC_05_G_03_BT_00}
variants:
  - {name: base, label: "Base", paper: {short: {acc: 95.5, f1: 94.66}}}
  - {name: lsm, label: "Log-Softmax", overrides: [normalization=log_softmax]}
  - {name: bank, skip: "needs the solver"}
claims:
  - {text: "Sinkhorn beats Log-Softmax", test: short, better: base, worse: lsm}
differences: ["tiny models"]
)";

/// The first `frames` frames of a real take.
void WriteCut(const fs::path& from, int frames, const fs::path& to) {
  C3dData c3d = ReadC3d(from);
  c3d.num_frames = frames;
  c3d.points.conservativeResize(frames, c3d.points.cols());
  c3d.residuals.conservativeResize(frames, c3d.residuals.cols());
  c3d.valid.conservativeResize(frames, c3d.valid.cols());
  fs::create_directories(to.parent_path());
  WriteC3d(to, c3d);
}

/// The one ledger directory of reproduction `name` under `root`,
/// `<name>-<hash of the budget>`.
fs::path LedgerDir(const fs::path& root, const std::string& name) {
  std::vector<fs::path> dirs;
  for (const auto& entry : fs::directory_iterator(root)) {
    if (entry.path().filename().string().rfind(name + "-", 0) == 0) {
      dirs.push_back(entry.path());
    }
  }
  EXPECT_EQ(dirs.size(), 1u) << root.string();
  return dirs.empty() ? root / name : dirs[0];
}

/// Tiny models: 1 epoch of 64 frames, d_model 10, one layer.
constexpr char kTinyBudget[] =
    "task.budget=[\"scale=cpu\",\"train.max_epochs=1\","
    "\"train.train_frames=64\",\"train.val_frames=32\","
    "\"train.batch_size=32\",\"model.d_model=10\",\"model.hidden=16\","
    "\"model.backbone.num_layers=1\"]";

/// `soma reproduce <name>` on `dir`'s ablations/ and data/ with tiny models;
/// the run dir is the last argument.
std::vector<std::string> TinyReproduceArgs(const fs::path& dir,
                                           const std::string& name) {
  return {"reproduce",
          name,
          "task.ablations_dir=" + (dir / "ablations").string(),
          "task.root=" + (dir / "root").string(),
          "task.results_dir=" + (dir / "results").string(),
          "task.data_dir=" + (dir / "data").string(),
          std::string(kTinyBudget),
          "task.jobs=2",
          "hydra.run.dir=" + (dir / "run").string()};
}

TEST(ReproduceTask, RunsTrainsEvaluatesAndResumes) {
  const fs::path dir = testing::CreateTestDir();
  WriteCut(testing::SharedDataDir() / "c3d/HDM_mm_01-02_03_120.c3d",
           120,
           dir / "data/c3d/short.c3d");
  testing::WriteTextFile(dir, "ablations/mini.yaml", kSpec);
  const std::vector<std::string> args = TinyReproduceArgs(dir, "mini");
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(dir, args, &err), 0) << err;

  const std::string md = ReadFile(dir / "results/mini.md");
  EXPECT_THAT(md, Not(HasSubstr("PARTIAL")));
  EXPECT_THAT(md, HasSubstr("| Base | HDM05 cut | "));
  EXPECT_THAT(md, HasSubstr("(2/2 seeds)"));
  EXPECT_THAT(md, HasSubstr("| Log-Softmax | HDM05 cut | "));
  EXPECT_THAT(md, HasSubstr("| bank | HDM05 cut | skipped |"));
  EXPECT_THAT(md, HasSubstr("Sinkhorn beats Log-Softmax (base − lsm > 0)"));
  const std::string csv = ReadFile(dir / "results/mini.csv");
  EXPECT_THAT(
      csv,
      HasSubstr("mini,base,Base,short,HDM05 cut,OC_05_G_03_BT_00,per-frame,"
                "acc,2,2,"));
  EXPECT_THAT(csv, HasSubstr(",95.50,,done,"));
  EXPECT_THAT(ReadFile(dir / "results/mini_claims.csv"),
              HasSubstr("mini,Sinkhorn beats Log-Softmax,base − lsm > 0,"
                        "greater,acc,base,short,lsm,short,,"));
  // The per-seed values behind each mean: 2 seeds of base on the one test.
  EXPECT_THAT(ReadFile(dir / "results/mini_seeds.csv"),
              HasSubstr("mini,base,short,acc,1,"));
  const fs::path ledger_dir = LedgerDir(dir / "root", "mini");
  const Ledger ledger = Ledger::Load(ledger_dir);
  ASSERT_EQ(ledger.entries().size(), 4u);
  for (const LedgerEntry& e : ledger.entries()) {
    EXPECT_EQ(e.status, JobStatus::kDone) << e.dir;
    EXPECT_GT(e.metrics.at("short/acc_mean"), 0.0) << e.dir;
    EXPECT_LE(e.metrics.at("short/acc_mean"), 1.0) << e.dir;
  }
  EXPECT_TRUE(fs::exists(ledger_dir / "commands.sh"));
  // While models trained, the table went to the ledger directory (outside
  // the tracked tree, so later trainings record a clean checkout), and
  // results/ got the same table once, at the end.
  const fs::path progress = ledger_dir / "report/mini.md";
  ASSERT_TRUE(fs::exists(progress));
  EXPECT_EQ(ReadFile(progress), md);
  EXPECT_THAT(ReadFile(dir / "run/soma.log"),
              HasSubstr("the table so far is rewritten after every model in " +
                        (ledger_dir / "report").string()));

  // Resuming: every command is done, nothing runs again.
  const auto stamp =
      fs::last_write_time(fs::path(ledger.entries()[0].dir) / "metrics.yaml");
  ASSERT_EQ(testing::RunSomaTask(dir, args, &err), 0) << err;
  EXPECT_THAT(ReadFile(dir / "run/soma.log"), HasSubstr("(0 commands to run)"));
  EXPECT_EQ(
      fs::last_write_time(fs::path(ledger.entries()[0].dir) / "metrics.yaml"),
      stamp);

  // An unknown spec is one line naming the available ones.
  std::vector<std::string> bad = args;
  bad[1] = "table9";
  EXPECT_EQ(testing::RunSomaTask(dir, bad, &err), 1);
  EXPECT_THAT(err, HasSubstr("table9.yaml: no such ablation spec. Available"));
  EXPECT_THAT(err, HasSubstr(": mini"));
}

// Table 4's machinery: a subset-layout model (layout.exclude), a take with
// markers removed (corrupt_overrides), unknown labels scored as null
// (eval_overrides), and the rows that need no new training run first.
TEST(ReproduceTask, SubsetLayoutsAndRowsRunSeparately) {
  const fs::path dir = testing::CreateTestDir();
  WriteCut(testing::SharedDataDir() / "c3d/HDM_mm_01-02_03_120.c3d",
           60,
           dir / "data/c3d/short.c3d");
  testing::WriteTextFile(dir, "ablations/layouts.yaml", R"(
name: layouts
title: "Layouts"
seeds: 1
tests:
  full: {take: c3d/short.c3d, setting: OC_05_G_03_BT_00,
         eval_overrides: [task.unknown_gt_labels=ghost]}
  fewer: {take: c3d/short.c3d, setting: OC_05_G_03_BT_00,
          corrupt_overrides: ["layout.exclude=[RBAC,LSHN]"]}
variants:
  - {name: base}
  - {name: subset, overrides: ["layout.exclude=[RBAC,LSHN]"]}
claims: []
)");
  std::vector<std::string> args = TinyReproduceArgs(dir, "layouts");
  args.insert(args.end() - 1, "task.variants=[base]");
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(dir, args, &err), 0) << err;
  EXPECT_THAT(ReadFile(dir / "results/layouts.md"), HasSubstr("PARTIAL"));
  Ledger ledger = Ledger::Load(LedgerDir(dir / "root", "layouts"));
  ASSERT_EQ(ledger.entries().size(), 2u);
  EXPECT_EQ(ledger.entries()[0].status, JobStatus::kDone);
  EXPECT_EQ(ledger.entries()[1].status, JobStatus::kPending);

  args[args.size() - 2] = "task.variants=[nope]";
  EXPECT_NE(testing::RunSomaTask(dir, args, &err), 0);
  EXPECT_THAT(err, HasSubstr("task.variants: 'nope' is not a variant"));

  args.erase(args.end() - 2);  // every variant
  ASSERT_EQ(testing::RunSomaTask(dir, args, &err), 0) << err;
  EXPECT_THAT(ReadFile(dir / "results/layouts.md"), Not(HasSubstr("PARTIAL")));
  ledger = Ledger::Load(LedgerDir(dir / "root", "layouts"));
  const LedgerEntry& subset = ledger.entries()[1];
  ASSERT_EQ(subset.status, JobStatus::kDone) << subset.error;
  // The subset model knows 39 labels: its output has 39 label columns, and
  // the 2 markers it lacks were scored as null on the full take.
  const fs::path tests = fs::path(subset.dir) / "tests";
  std::vector<double> unknown;  // per test
  for (const auto& test : fs::directory_iterator(tests)) {
    const fs::path labelled = test.path() / "label/short_labeled.c3d";
    ASSERT_TRUE(fs::exists(labelled)) << labelled;
    const C3dData out = ReadC3d(labelled);
    EXPECT_EQ(std::count_if(out.labels.begin(),
                            out.labels.end(),
                            [](const std::string& l) { return l[0] != '*'; }),
              39);
    const ConfigNode m =
        ParseYaml(ReadFile(test.path() / "eval/metrics.yaml"), "metrics.yaml");
    unknown.push_back(m.at("unknown_gt_labels").AsDouble());
  }
  std::sort(unknown.begin(), unknown.end());
  EXPECT_EQ(unknown, (std::vector<double>{0.0, 2.0}));  // fewer, full
}

}  // namespace
}  // namespace soma
