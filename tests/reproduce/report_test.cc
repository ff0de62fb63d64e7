#include "framework/reproduce/report.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <sstream>

namespace soma {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

AblationSpec Spec() {
  return ParseAblationSpec(ParseYaml(R"(
name: demo
title: "Demo table"
seeds: 3
differences:
  - "procedural body"
  - {text: "default layout", unless_budget_sets: layout}
tests:
  t0: {label: "zero", take: a.c3d, setting: OCE_00_G_00_BT_00}
  t5: {label: "five", take: a.c3d, setting: OCE_05_G_00_BT_00}
variants:
  - name: base
    paper: {t0: {acc: 98.0, acc_std: 1.5}, t5: {acc: 97.0}}
  - name: weak
    paper: {t0: {acc: 90.0}}
  - name: todo
  - name: no_bank
    skip: "needs the solver"
claims:
  - {text: "base beats weak", test: t0, better: base, worse: weak}
  - {text: "weak beats base", test: t0, better: weak, worse: base}
  - {text: "robust", test: t0, worse_test: t5, kind: close, tolerance: 2.0,
     better: base, worse: base}
  - {text: "todo beats weak", test: t0, better: todo, worse: weak,
     paper_gap: 1.0, paper_note: "Fig. 9", origin: ours}
)",
                                     "demo.yaml"),
                           "demo.yaml");
}

// The spec the claim outcomes point into: it outlives every test's outcomes
// (CheckClaims refuses a temporary; ASan found a test reading the claims of
// a destroyed spec).
const AblationSpec& TheSpec() {
  static const AblationSpec* spec = new AblationSpec(Spec());
  return *spec;
}

CellResult Cell(std::string variant,
                std::string test,
                std::vector<double> means,
                std::vector<double> frame_stds = {}) {
  CellResult cell;
  cell.variant = std::move(variant);
  cell.test = std::move(test);
  cell.metric = "acc";
  cell.seed_means = std::move(means);
  cell.seed_frame_stds = frame_stds.empty()
                             ? std::vector<double>(cell.seed_means.size(), 5.0)
                             : std::move(frame_stds);
  cell.seeds_planned = 3;
  for (size_t k = 0; k < cell.seed_means.size(); ++k) {
    cell.seeds.push_back(static_cast<int>(k));
  }
  return cell;
}

/// The lines of a CSV file after its header, which goes to `header`.
std::vector<std::string> CsvRows(const std::filesystem::path& path,
                                 std::string* header) {
  std::istringstream csv(ReadFile(path));
  std::getline(csv, *header);
  std::vector<std::string> rows;
  for (std::string line; std::getline(csv, line);) rows.push_back(line);
  return rows;
}

std::vector<CellResult> Cells() {
  return {Cell("base", "t0", {96.0, 97.0, 98.0}, {4.0, 5.0, 6.0}),
          Cell("base", "t5", {95.0, 95.5, 96.5}),
          Cell("weak", "t0", {90.0}),
          Cell("todo", "t0", {})};
}

TEST(ReportTest, CellStatisticsOverSeeds) {
  const CellResult cell = Cells()[0];
  EXPECT_DOUBLE_EQ(*cell.Mean(), 97.0);
  EXPECT_DOUBLE_EQ(*cell.SeedStd(), 1.0);  // sample std (ddof 1)
  EXPECT_DOUBLE_EQ(*cell.FrameStd(), 5.0);
  EXPECT_FALSE(Cells()[2].SeedStd());  // one seed: no spread
  EXPECT_FALSE(Cells()[3].Mean());
}

TEST(ReportTest, ClaimsAreCheckedWithTheirGaps) {
  const AblationSpec spec = Spec();
  const std::vector<ClaimOutcome> out = CheckClaims(spec, Cells());
  ASSERT_EQ(out.size(), 4u);
  EXPECT_EQ(out[0].verdict, "pass");
  EXPECT_DOUBLE_EQ(*out[0].gap, 7.0);
  EXPECT_DOUBLE_EQ(*out[0].paper_gap, 8.0);  // from the paper values
  // weak has one seed: it borrows base's seed std (1.0).
  EXPECT_NEAR(*out[0].gap_se, std::sqrt(1.0 / 3 + 1.0 / 1), 1e-12);
  EXPECT_EQ(out[1].verdict, "fail");
  EXPECT_DOUBLE_EQ(*out[1].gap, -7.0);
  // Across tests: 97.0 (t0) vs 95.667 (t5), |gap| <= 2.
  EXPECT_EQ(out[2].verdict, "pass");
  EXPECT_NEAR(*out[2].gap, 97.0 - 95.0 - 2.0 / 3.0, 1e-12);
  EXPECT_DOUBLE_EQ(*out[2].paper_gap, 1.0);
  // The same models on two tests: the paired s.e. of the per-seed
  // differences {1.0, 1.5, 1.5}: std 0.2887 / sqrt(3).
  EXPECT_TRUE(out[2].paired);
  EXPECT_NEAR(*out[2].gap_se, std::sqrt(1.0 / 12.0) / std::sqrt(3.0), 1e-12);
  EXPECT_FALSE(out[0].paired);
  EXPECT_EQ(out[3].verdict, "not run");
  EXPECT_DOUBLE_EQ(*out[3].paper_gap, 1.0);
}

// A claim on a row the reproduction does not train (skip, or
// skip_if_budget_sets under this budget) is "skipped", not pending.
TEST(ReportTest, ClaimsOnASkippedRowAreSkippedNotPending) {
  AblationSpec spec = Spec();
  AblationClaim claim = spec.claims[0];
  claim.text = "no_bank beats base";
  claim.better = "no_bank";
  spec.claims = {claim, spec.claims[3]};
  const std::vector<ClaimOutcome> out = CheckClaims(spec, Cells());
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].verdict, "skipped");
  EXPECT_EQ(out[1].verdict, "not run");
  EXPECT_EQ(CountClaims(out, "paper").skipped, 1);
  EXPECT_THAT(ClaimsSummary(out), HasSubstr("0 fail, 1 skipped;"));
  EXPECT_THAT(ClaimsSummary(out), HasSubstr("0 fail, 1 not run;"));
}

TEST(ReportTest, CloseClaimFailsOutsideItsTolerance) {
  std::vector<CellResult> cells = Cells();
  cells[1] = Cell("base", "t5", {90.0, 91.0, 92.0});
  const ClaimOutcome out = CheckClaims(TheSpec(), cells)[2];
  EXPECT_EQ(out.verdict, "fail");
  // Every seed differs by 6: the paired s.e. is 0, the fail is resolved.
  EXPECT_FALSE(out.within_noise);
}

// kind not_behind: `worse` may be ahead of `better` by any margin, and at
// most `tolerance` points behind it.
TEST(ReportTest, NotBehindClaimPassesAheadAndWithinItsTolerance) {
  const AblationSpec spec = ParseAblationSpec(ParseYaml(R"(
name: target
title: "Target"
seeds: 2
tests:
  t0: {label: "zero", take: a.c3d, setting: OCE_00_G_00_BT_00}
variants:
  - name: own
  - name: shared
claims:
  - {text: "shared within 2 of own", test: t0, kind: not_behind,
     tolerance: 2.0, better: own, worse: shared, origin: ours}
)",
                                                        "target.yaml"),
                                              "target.yaml");
  EXPECT_EQ(ClaimRule(spec.claims[0]), "own − shared ≤ 2.0");
  auto outcome = [&](std::vector<double> own, std::vector<double> shared) {
    const std::vector<CellResult> cells = {Cell("own", "t0", std::move(own)),
                                           Cell("shared", "t0", shared)};
    return CheckClaims(spec, cells)[0];
  };
  // 6 points ahead: a close claim would fail, this one passes.
  ClaimOutcome out = outcome({90.0, 90.0}, {96.0, 96.0});
  EXPECT_EQ(out.verdict, "pass");
  EXPECT_DOUBLE_EQ(*out.gap, -6.0);
  EXPECT_FALSE(out.within_noise);
  out = outcome({90.0, 90.0}, {88.5, 88.5});  // 1.5 behind
  EXPECT_EQ(out.verdict, "pass");
  out = outcome({90.0, 90.0}, {85.0, 85.0});  // 5 behind
  EXPECT_EQ(out.verdict, "fail");
  EXPECT_FALSE(out.within_noise);
  // 2.5 behind, seeds spread by 2: 0.5 from the boundary, within noise.
  out = outcome({89.0, 91.0}, {86.5, 88.5});
  EXPECT_EQ(out.verdict, "fail");
  EXPECT_TRUE(out.within_noise);
}

TEST(ReportTest, VerdictsNearTheirBoundaryAreWithinSeedNoise) {
  std::vector<CellResult> cells = Cells();
  // Close claim: gap 3 against tolerance 2; per-seed differences {5, 2, 2}
  // give a paired s.e. of 1, so the boundary is 1 s.e. away.
  cells[1] = Cell("base", "t5", {91.0, 95.0, 96.0});
  // Greater claim: gap 0.5 with s.e. sqrt(1/3 + 1) = 1.15.
  cells[2] = Cell("weak", "t0", {96.5});
  const std::vector<ClaimOutcome> out = CheckClaims(TheSpec(), cells);
  EXPECT_EQ(out[2].verdict, "fail");
  EXPECT_NEAR(*out[2].gap_se, 1.0, 1e-12);
  EXPECT_TRUE(out[2].within_noise);
  EXPECT_EQ(out[0].verdict, "pass");
  EXPECT_TRUE(out[0].within_noise);
  EXPECT_FALSE(CheckClaims(TheSpec(), Cells())[0].within_noise);  // gap 7
  EXPECT_FALSE(CheckClaims(TheSpec(), Cells())[2].within_noise);
  EXPECT_FALSE(out[3].within_noise);  // not run

  const auto dir = testing::CreateTestDir();
  WriteResultsMarkdown(Spec(), cells, ReportContext{}, dir / "demo.md");
  const std::string md = ReadFile(dir / "demo.md");
  EXPECT_THAT(md, HasSubstr("**fail** (within seed noise)"));
  EXPECT_THAT(md, HasSubstr("**pass** (within seed noise)"));
  // The close rule's bars are escaped, else they would split the cell.
  EXPECT_THAT(md, HasSubstr("(\\|base@t0 − base@t5\\| ≤ 2.0)"));
}

TEST(ReportTest, PairedStandardErrorOnlyOverSharedSeeds) {
  std::vector<CellResult> cells = Cells();
  // t5 has seeds 0 and 2 only: two shared seeds, differences 1.0 and 1.5.
  cells[1] = Cell("base", "t5", {95.0, 96.5});
  cells[1].seeds = {0, 2};
  const ClaimOutcome out = CheckClaims(TheSpec(), cells)[2];
  EXPECT_TRUE(out.paired);
  EXPECT_NEAR(*out.gap_se, std::sqrt(0.125) / std::sqrt(2.0), 1e-12);
  // One shared seed: back to the unpaired estimate.
  cells[1] = Cell("base", "t5", {95.0});
  cells[1].seeds = {2};
  EXPECT_FALSE(CheckClaims(TheSpec(), cells)[2].paired);
}

TEST(ReportTest, ClaimsCsvHasOneRowPerClaimWithItsVerdict) {
  const auto dir = testing::CreateTestDir();
  WriteClaimsCsv(Spec(), Cells(), dir / "demo_claims.csv");
  std::string header;
  const std::vector<std::string> rows =
      CsvRows(dir / "demo_claims.csv", &header);
  EXPECT_EQ(header,
            "table,claim,rule,kind,metric,better,better_test,worse,worse_test,"
            "tolerance,paper_gap,gap,gap_se,paired,verdict,within_noise,"
            "paper_note,origin");
  ASSERT_EQ(rows.size(), 4u);
  EXPECT_EQ(rows[0],
            "demo,base beats weak,base − weak > 0,greater,acc,base,t0,weak,t0,,"
            "8.00,7.00,1.15,0,pass,0,,paper");
  EXPECT_EQ(rows[2],
            "demo,robust,|base@t0 − base@t5| ≤ 2.0,close,acc,base,t0,base,t5,"
            "2.00,1.00,1.33,0.17,1,pass,0,,paper");
  // Not run: no gap, no s.e., no noise flag; the paper's gap and note stay.
  EXPECT_EQ(rows[3],
            "demo,todo beats weak,todo − weak > 0,greater,acc,todo,t0,weak,t0,,"
            "1.00,,,,not run,,Fig. 9,ours");
}

TEST(ReportTest, ClaimsAreCountedByWhoseTheyAre) {
  std::vector<CellResult> cells = Cells();
  const std::vector<ClaimOutcome> outcomes = CheckClaims(TheSpec(), cells);
  const ClaimCounts paper = CountClaims(outcomes, "paper");
  EXPECT_EQ(paper.claims, 3);
  EXPECT_EQ(paper.pass, 2);
  EXPECT_EQ(paper.fail, 1);
  EXPECT_EQ(CountClaims(outcomes, "ours").not_run, 1);
  EXPECT_EQ(CountClaims(outcomes, "duplicate").claims, 0);
  EXPECT_EQ(ClaimsSummary(outcomes),
            "4 claims: 3 of the paper's own (2 pass, 1 fail; 0 within seed "
            "noise), 1 of ours (not in the paper) (0 pass, 0 fail, 1 not "
            "run; 0 within seed noise)");
  const auto dir = testing::CreateTestDir();
  WriteResultsMarkdown(Spec(), cells, ReportContext{}, dir / "demo.md");
  const std::string md = ReadFile(dir / "demo.md");
  EXPECT_THAT(md, HasSubstr(ClaimsSummary(outcomes)));
  EXPECT_THAT(md, HasSubstr("| todo beats weak [ours] (todo − weak > 0)"));
}

TEST(ReportTest, AnUnknownClaimOriginIsRejected) {
  EXPECT_THROW(ParseAblationSpec(ParseYaml(R"(
name: x
title: x
tests: {t: {label: t, take: a.c3d, setting: OC_00_G_00_BT_00}}
variants: [{name: a}, {name: b}]
claims: [{text: c, test: t, better: a, worse: b, origin: mine}]
)",
                                           "x.yaml"),
                                 "x.yaml"),
               ConfigError);
}

TEST(ReportTest, SeedsCsvHasEveryFinishedSeed) {
  const std::vector<CellResult> cells = Cells();
  const auto dir = testing::CreateTestDir();
  WriteSeedsCsv(Spec(), cells, dir / "demo_seeds.csv");
  std::string header;
  const std::vector<std::string> rows =
      CsvRows(dir / "demo_seeds.csv", &header);
  EXPECT_EQ(header, "table,variant,test,metric,seed,value,std_frames");
  ASSERT_GE(rows.size(), 3u);
  EXPECT_EQ(rows[0], "demo,base,t0,acc,0,96.0000,4.0000");
  EXPECT_EQ(rows[2], "demo,base,t0,acc,2,98.0000,6.0000");
  // Every row of the table's cells, one per seed.
  size_t expected = 0;
  for (const CellResult& cell : cells) expected += cell.seed_means.size();
  EXPECT_EQ(rows.size(), expected);
}

TEST(ReportTest, AReportFromADirtyTreeSaysSoOnTop) {
  const auto dir = testing::CreateTestDir();
  ReportContext context;
  context.commit = "abc123def456-dirty";
  WriteResultsMarkdown(Spec(), Cells(), context, dir / "dirty.md");
  const std::string md = ReadFile(dir / "dirty.md");
  EXPECT_EQ(md.find(kDirtyTreeMark), md.find("\n\n") + 2);
  EXPECT_THAT(md, HasSubstr("(commit abc123def456-dirty)"));
  context.commit = "abc123def456";
  WriteResultsMarkdown(Spec(), Cells(), context, dir / "clean.md");
  EXPECT_THAT(ReadFile(dir / "clean.md"), Not(HasSubstr(kDirtyTreeMark)));
}

TEST(ReportTest, TheSeedsRowSaysHowManySeedsThisRunPlanned) {
  const auto dir = testing::CreateTestDir();
  ReportContext context;
  WriteResultsMarkdown(Spec(), Cells(), context, dir / "spec.md");
  EXPECT_THAT(ReadFile(dir / "spec.md"),
              HasSubstr("| seeds | 3 training seeds per variant |"));
  context.seeds = 1;  // task.seeds=1
  WriteResultsMarkdown(Spec(), Cells(), context, dir / "one.md");
  EXPECT_THAT(ReadFile(dir / "one.md"),
              HasSubstr("| seeds | 1 training seeds per variant (task.seeds; "
                        "the spec plans 3) |"));
}

TEST(ReportTest, CsvHasOneRowPerVariantTestAndMetricWithStatus) {
  const auto dir = testing::CreateTestDir();
  WriteResultsCsv(Spec(), Cells(), dir / "demo.csv");
  std::string header;
  const std::vector<std::string> rows = CsvRows(dir / "demo.csv", &header);
  EXPECT_EQ(header,
            "table,variant,variant_label,test,test_label,setting,mode,metric,"
            "seeds_done,seeds_planned,mean,std_seeds,std_frames,paper,"
            "paper_std,status,note");
  ASSERT_EQ(rows.size(), 4u * 2u * 2u);
  EXPECT_EQ(rows[0],
            "demo,base,base,t0,zero,OCE_00_G_00_BT_00,per-frame,acc,3,3,"
            "97.00,1.00,5.00,98.00,1.50,done,");
  EXPECT_EQ(rows[1],
            "demo,base,base,t0,zero,OCE_00_G_00_BT_00,per-frame,f1,0,0,,,,,,"
            "not run,");
  EXPECT_EQ(rows[4],
            "demo,weak,weak,t0,zero,OCE_00_G_00_BT_00,per-frame,acc,1,3,"
            "90.00,,5.00,90.00,,partial,");
  EXPECT_THAT(rows[12], HasSubstr(",skipped,needs the solver"));
}

TEST(ReportTest, MarkdownMarksPartialTablesAndShowsClaims) {
  const auto dir = testing::CreateTestDir();
  ReportContext context;
  context.command = "soma reproduce demo";
  context.commit = "abc123";
  context.models_done = 4;
  context.models_planned = 9;
  context.compute_s = 5400;
  context.budget = {"scale=cpu"};
  context.machine = "vm, CPU B (2 hardware threads)";
  context.trained_on = {"vm, CPU A: 3 models", "vm, CPU not recorded: 1 model"};
  WriteResultsMarkdown(Spec(), Cells(), context, dir / "demo.md");
  const std::string md = ReadFile(dir / "demo.md");
  EXPECT_THAT(md,
              HasSubstr("| trained on | vm, CPU A: 3 models; vm, CPU not "
                        "recorded: 1 model |\n| report written on | vm, CPU B "
                        "(2 hardware threads) |"));
  EXPECT_THAT(md, HasSubstr("**PARTIAL: 4 of 9 trainings finished.**"));
  EXPECT_THAT(md, HasSubstr("`soma reproduce demo`"));
  EXPECT_THAT(md, HasSubstr("1 h 30 min"));
  EXPECT_THAT(md,
              HasSubstr("| base | zero | 97.00 ± 1.00 (3/3 seeds) | 5.00 | "
                        "98.00 ± 1.50 |"));
  EXPECT_THAT(md, HasSubstr("| weak | five | not run |"));
  EXPECT_THAT(md, HasSubstr("| no_bank | zero | skipped |"));
  EXPECT_THAT(md, HasSubstr("- **no_bank**: needs the solver"));
  EXPECT_THAT(md, HasSubstr("| +8.00 | +7.00 ± 1.15 (s.e.) | **pass** |"));
  EXPECT_THAT(md,
              HasSubstr("| +1.00 | +1.33 ± 0.17 (paired s.e.) | **pass** |"));
  EXPECT_THAT(md, HasSubstr("**fail**"));
  EXPECT_THAT(md, HasSubstr("base@t0 − base@t5"));
  EXPECT_THAT(md, HasSubstr("+1.00 (Fig. 9) | — | **not run** |"));
  EXPECT_THAT(md, HasSubstr("- procedural body"));
  EXPECT_THAT(md, HasSubstr("- default layout"));

  // A difference the budget undoes is not printed.
  ReportContext fitted = context;
  fitted.budget = {"scale=cpu", "layout=file"};
  WriteResultsMarkdown(Spec(), Cells(), fitted, dir / "fitted.md");
  EXPECT_THAT(ReadFile(dir / "fitted.md"), HasSubstr("- procedural body"));
  EXPECT_THAT(ReadFile(dir / "fitted.md"), Not(HasSubstr("default layout")));

  context.models_done = 9;
  WriteResultsMarkdown(Spec(), Cells(), context, dir / "demo.md");
  EXPECT_THAT(ReadFile(dir / "demo.md"), Not(HasSubstr("PARTIAL")));
}

}  // namespace
}  // namespace soma
