// End-to-end body-fit metrics (issue #8 item 6): two `soma solve` fits of
// the CMU take, compared by `soma eval` through the `soma` binary.
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "tests/integration/soma_command.h"
#include <cmath>
#include <filesystem>
#include <string>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

ConfigNode Metrics(const fs::path& run_dir) {
  return ParseYaml(ReadFile(run_dir / "metrics.yaml"), "metrics.yaml");
}

TEST(EvalTask, BodyFitMetricsOfTwoSolves) {
  const auto dir = testing::CreateTestDir();
  const std::string take =
      (testing::SharedDataDir() / "c3d" / "cmu_01_01.c3d").string();
  std::string err;
  // Two fits that differ only in the stage I frames (seed).
  for (const char* seed : {"100", "7"}) {
    ASSERT_EQ(testing::RunSomaTask(dir,
                                   {"solve",
                                    "task.input=" + take,
                                    std::string("hydra.run.dir=solve_") + seed,
                                    "solver.end=20",
                                    std::string("solver.stagei.seed=") + seed},
                                   &err),
              0)
        << err;
  }
  const std::string a = (dir / "solve_100/cmu_01_01_stageii.h5").string();
  const std::string b = (dir / "solve_7/cmu_01_01_stageii.h5").string();

  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"eval",
                                  "hydra.run.dir=same",
                                  "task.body_fit_gt=" + a,
                                  "task.body_fit_rec=" + a},
                                 &err),
            0)
      << err;
  const ConfigNode same = Metrics(dir / "same");
  EXPECT_EQ(same.at("body_frames").AsDouble(), 20);
  EXPECT_EQ(same.at("v2v_mm").AsDouble(), 0.0);
  EXPECT_EQ(same.at("joint_err_mm").AsDouble(), 0.0);
  EXPECT_EQ(same.at("pck10").AsDouble(), 100.0);

  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"eval",
                                  "hydra.run.dir=diff",
                                  "task.body_fit_gt=" + a,
                                  "task.body_fit_rec=" + b},
                                 &err),
            0)
      << err;
  const ConfigNode diff = Metrics(dir / "diff");
  EXPECT_EQ(diff.at("body_frames").AsDouble(), 20);
  const double v2v = diff.at("v2v_mm").AsDouble();
  EXPECT_GT(v2v, 0.0);
  EXPECT_LT(v2v, 100.0);  // the same capture: centimetres, not metres
  EXPECT_GT(diff.at("joint_err_mm").AsDouble(), 0.0);
  EXPECT_LE(diff.at("pck10").AsDouble(), diff.at("pck30").AsDouble());
  EXPECT_LE(diff.at("pck30").AsDouble(), diff.at("pck70").AsDouble());
  EXPECT_EQ(diff.Find("acc_mean"), nullptr);  // no labelling without gt/rec
  const std::string csv = ReadFile(dir / "diff/body_metrics.csv");
  EXPECT_THAT(csv, HasSubstr("frame,compared,excluded_reason,v2v_mm"));
  EXPECT_THAT(ReadFile(dir / "diff/eval.md"), HasSubstr("Body-fit evaluation"));

  // One fit alone is a one-line configuration error.
  EXPECT_NE(
      testing::RunSomaTask(
          dir, {"eval", "hydra.run.dir=bad", "task.body_fit_gt=" + a}, &err),
      0);
  EXPECT_THAT(err,
              HasSubstr("body_fit_gt and body_fit_rec are given together"));
}

}  // namespace
}  // namespace soma
