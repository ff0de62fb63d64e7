// End-to-end runs of the issue-#8 commands through the `soma` binary:
// fit_prior -> solve with the GMM prior, fit_layout, and their one-line
// errors.
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include "tests/integration/soma_command.h"
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;

ConfigNode Metrics(const fs::path& run_dir) {
  return ParseYaml(ReadFile(run_dir / "metrics.yaml"), "metrics.yaml");
}

std::string CmuTake() {
  return (testing::SharedDataDir() / "c3d" / "cmu_01_01.c3d").string();
}

TEST(SolveTasks, FitPriorThenSolveWithTheGmmPrior) {
  // The prior's real-motion sources and the MakeHuman body read
  // SOMA_SHARED_DATA.
  ASSERT_EQ(setenv("SOMA_SHARED_DATA", testing::SharedDataDir().c_str(), 1), 0);
  const auto dir = testing::CreateTestDir();
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"fit_prior",
                                  "hydra.run.dir=prior",
                                  "task.gmm.components=4",
                                  "task.sources.0.clips_per_type=2"},
                                 &err),
            0)
      << err;
  ASSERT_TRUE(fs::exists(dir / "prior/pose_prior.h5"));
  const ConfigNode prior = Metrics(dir / "prior");
  EXPECT_GT(prior.at("poses").AsDouble(), 1000);
  EXPECT_GT(prior.at("heldout_poses").AsDouble(), 0);
  EXPECT_TRUE(std::isfinite(prior.at("heldout_loglik").AsDouble()));

  const std::string path = (dir / "prior/pose_prior.h5").string();
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"solve",
                                  CmuTake(),
                                  "hydra.run.dir=solve",
                                  "solver.end=20",
                                  "task.mesh_every=10",
                                  "pose_prior=gmm",
                                  "pose_prior.path=" + path},
                                 &err),
            0)
      << err;
  const ConfigNode solve = Metrics(dir / "solve");
  EXPECT_EQ(solve.at("frames").AsDouble(), 20);
  EXPECT_EQ(solve.at("failed").AsDouble(), 0);
  EXPECT_LT(solve.at("stageii_mean_rms_mm").AsDouble(), 20.0);
  EXPECT_TRUE(fs::exists(dir / "solve/cmu_01_01_stageii.h5"));
  // Meshes of frames 0 and 10 (every 10th), none of frame 5.
  EXPECT_TRUE(fs::exists(dir / "solve/meshes/cmu_01_01_00000.ply"));
  EXPECT_TRUE(fs::exists(dir / "solve/meshes/cmu_01_01_00010.ply"));
  EXPECT_FALSE(fs::exists(dir / "solve/meshes/cmu_01_01_00005.ply"));

  // The fit's residuals as a real-noise bank (SOMA's AMASS noise model).
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"noise_bank",
                 "hydra.run.dir=bank",
                 "task.fits=" + (dir / "solve/cmu_01_01_stageii.h5").string()},
                &err),
            0)
      << err;
  const ConfigNode bank = Metrics(dir / "bank");
  EXPECT_EQ(bank.at("frames").AsDouble(), 20);
  EXPECT_EQ(bank.at("rows").AsDouble(), 20);  // every label seen every frame
  EXPECT_EQ(bank.at("labels_observed").AsDouble(), 41);
  EXPECT_GT(bank.at("median_residual_mm").AsDouble(), 0.1);
  EXPECT_LT(bank.at("median_residual_mm").AsDouble(), 20.0);
  EXPECT_TRUE(fs::exists(dir / "bank/noise_bank.h5"));

  // A missing prior file: one line naming it, non-zero exit.
  EXPECT_NE(testing::RunSomaTask(dir,
                                 {"solve",
                                  CmuTake(),
                                  "hydra.run.dir=bad",
                                  "solver.end=5",
                                  "pose_prior=gmm",
                                  "pose_prior.path=absent.h5"},
                                 &err),
            0);
  EXPECT_NE(err.find("absent.h5"), std::string::npos) << err;
  // The prior of another body: the joint mismatch is named.
  EXPECT_NE(testing::RunSomaTask(dir,
                                 {"solve",
                                  CmuTake(),
                                  "hydra.run.dir=bad2",
                                  "solver.end=5",
                                  "body=makehuman",
                                  "pose_prior=gmm",
                                  "pose_prior.path=" + path},
                                 &err),
            0);
  EXPECT_NE(err.find("fitted for body 'procedural'"), std::string::npos) << err;
}

TEST(SolveTasks, FitLayoutFromTheMostCompleteFrame) {
  const auto dir = testing::CreateTestDir();
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(
                dir, {"fit_layout", CmuTake(), "hydra.run.dir=out"}, &err),
            0)
      << err;
  EXPECT_TRUE(fs::exists(dir / "out/cmu_01_01_layout.json"));
  EXPECT_TRUE(fs::exists(dir / "out/cmu_01_01_layout.csv"));
  const ConfigNode m = Metrics(dir / "out");
  EXPECT_EQ(m.at("markers_used").AsDouble(), 41);
  EXPECT_LT(m.at("fit_rms_mm").AsDouble(), 20.0);     // issue #8 target
  EXPECT_LT(m.at("layout_rms_mm").AsDouble(), 20.0);  // the written layout
  // The fitted layout is a layout: it can be used to fit again.
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"fit_layout",
                 CmuTake(),
                 "hydra.run.dir=again",
                 "layout=file",
                 "layout.allow_unknown_labels=true",  // RBAC-1 is placed too
                 "layout.path=" + (dir / "out/cmu_01_01_layout.json").string()},
                &err),
            0)
      << err;
  // A frame past the end: a one-line configuration error.
  EXPECT_NE(
      testing::RunSomaTask(
          dir,
          {"fit_layout", CmuTake(), "hydra.run.dir=bad", "task.frame=999999"},
          &err),
      0);
  EXPECT_NE(err.find("task.frame"), std::string::npos) << err;
}

}  // namespace
}  // namespace soma
