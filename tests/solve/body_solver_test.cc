#include "framework/solve/body_solver.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/io/hdf5_util.h"
#include "framework/motion/procedural_motion.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

LabelledMarkers SyntheticCapture(const MarkerLayout& layout, int num_frames) {
  const BodyModel& body = ProceduralBody();
  std::vector<int> vids;
  std::vector<double> dist;
  for (const auto& m : layout.markers) {
    vids.push_back(m.vertex_ids[0]);
    dist.push_back(m.distance_from_skin);
  }
  Rng rng(31);
  Eigen::VectorXd betas(body.num_betas());
  for (int b = 0; b < betas.size(); ++b) betas(b) = 0.7 * rng.Normal();
  MarkerModel truth(body, vids);
  truth.SetShape(betas, NormalOffsets(body, betas, vids, dist));
  Rng clip_rng = rng.Stream("clip");
  const PoseSequence clip = GenerateProceduralMotion(
      "walk", body, ProceduralMotionOptions{}, clip_rng);
  LabelledMarkers capture;
  capture.labels = layout.Labels();
  capture.frame_rate = clip.frame_rate;
  for (int t = 0; t < num_frames; ++t) {
    const Eigen::VectorXd f = PackFrameParams(clip.frames[t]);
    Eigen::Matrix3Xd p;
    truth.Evaluate(f.data(), {}, &p, nullptr);
    if (t % 5 == 1) p.col(t % layout.num_markers()).setConstant(NAN);
    if (t == 7) p.setConstant(NAN);  // an empty frame: skipped
    capture.frames.push_back(p);
  }
  return capture;
}

TEST(BodySolver, SolvesASyntheticCaptureAndWritesTheOutput) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const LabelledMarkers capture = SyntheticCapture(layout, 30);
  BodySolveOptions options;
  options.stagei.num_frames = 4;
  const GaussianPosePrior prior =
      GaussianPosePrior::ZeroMean(body.num_joints(), 0.6);
  const BodySolveResult result =
      SolveBody(body, layout, capture, &prior, options);
  EXPECT_EQ(result.stats.frames, 30);
  EXPECT_EQ(result.stats.skipped, 1);
  EXPECT_EQ(result.output.summaries[7].skipped_reason, "too_few_markers");
  EXPECT_EQ(result.stats.failed, 0);
  EXPECT_LT(result.stats.max_rms_m, 3e-3);
  std::printf("body solver synthetic: %s, stage II %.0f frames/s\n",
              result.stats.BriefReport().c_str(),
              result.stageii_frames_per_s);
  const auto path = soma::testing::CreateTestDir() / "solve.h5";
  WriteSolveOutput(path, result.output);
  EXPECT_TRUE(std::filesystem::exists(path));
  {
    // Shapes of the per-frame arrays, read back with the HDF5 C API.
    std::lock_guard lock(hdf5::Hdf5Mutex());
    hdf5::Hid file = hdf5::Check(
        H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose, "open");
    const auto dims = [&](const char* name) {
      hdf5::Hid d =
          hdf5::Check(H5Dopen2(file.get(), name, H5P_DEFAULT), H5Dclose, name);
      hdf5::Hid space = hdf5::Check(H5Dget_space(d.get()), H5Sclose, name);
      std::vector<hsize_t> out(H5Sget_simple_extent_ndims(space.get()));
      H5Sget_simple_extent_dims(space.get(), out.data(), nullptr);
      return out;
    };
    EXPECT_EQ(dims("poses"), (std::vector<hsize_t>{30, 72}));
    EXPECT_EQ(dims("trans"), (std::vector<hsize_t>{30, 3}));
    EXPECT_EQ(dims("markers_sim"), (std::vector<hsize_t>{30, 41, 3}));
    EXPECT_EQ(dims("betas"), (std::vector<hsize_t>{12}));
    EXPECT_EQ(hdf5::ReadStringAttribute(file.get(), "format", "bad: "),
              "soma-solve");
  }
  const std::string csv = SolveSummariesToCsv(result.output.summaries);
  EXPECT_NE(csv.find("SKIPPED"), std::string::npos);

  // Two stage II threads: two chunks, same frames and quality.
  options.threads = 2;
  const BodySolveResult parallel =
      SolveBody(body, layout, capture, &prior, options);
  EXPECT_EQ(parallel.stats.frames, 30);
  EXPECT_EQ(parallel.stats.skipped, 1);
  EXPECT_LT(parallel.stats.max_rms_m, 3e-3);
  for (int t = 0; t < 30; ++t) {
    EXPECT_EQ(parallel.output.summaries[t].frame, t);
  }
}

TEST(BodySolver, DecodesOptionsAndRejectsBadOnes) {
  const ConfigNode node = ParseYaml(
      "stride: 2\nceres: {max_iterations: 20}\n"
      "stagei: {num_frames: 5}\nstageii: {velocity_weight: 1.0}\n",
      "test");
  const BodySolveOptions o = DecodeBodySolveOptions(node);
  EXPECT_EQ(o.stride, 2);
  EXPECT_EQ(o.stageii.solver.max_iterations, 20);
  EXPECT_EQ(o.stagei.solver.max_iterations, 20);
  EXPECT_EQ(o.stagei.num_frames, 5);
  EXPECT_EQ(o.stageii.velocity_weight, 1.0);
  EXPECT_THROW(DecodeBodySolveOptions(ParseYaml("nope: 1\n", "test")),
               ConfigError);
  // The pose prior is its own component (configs/pose_prior/), not a key.
  EXPECT_THROW(DecodeBodySolveOptions(ParseYaml("pose_prior: gmm\n", "test")),
               ConfigError);
  EXPECT_THROW(
      DecodeBodySolveOptions(ParseYaml("stageii: {min_markers: 1}\n", "test")),
      ConfigError);
}

TEST(BodySolver, LayoutMismatchIsAnError) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  LabelledMarkers capture;
  capture.labels = {"A", "B"};
  capture.frames = {Eigen::Matrix3Xd::Zero(3, 2)};
  EXPECT_THROW(SolveBody(body, layout, capture, nullptr, BodySolveOptions{}),
               ShapeError);
}

}  // namespace
}  // namespace soma
