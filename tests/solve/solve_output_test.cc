#include "framework/solve/solve_output.h"

#include "framework/core/error.h"
#include "framework/io/hdf5_util.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

constexpr int kFrames = 4;
constexpr int kJoints = 2;
constexpr int kMarkers = 3;

/// A small solve output: 4 frames, 2 joints, 3 markers; frame 2 skipped
/// (NaN parameters and simulated markers), frame 1 not converged, one
/// marker missing in frame 3.
SolveOutput MakeOutput() {
  SolveOutput out;
  out.body = "procedural";
  out.joint_names = {"pelvis", "left_hip"};
  out.labels = {"C7", "CLAV", "LFHD"};
  out.frame_rate = 120.0;
  out.betas = Eigen::VectorXd::LinSpaced(5, -1.0, 1.0);
  out.markers_latent.setRandom(3, kMarkers);
  out.marker_offsets.setRandom(3, kMarkers);
  out.marker_vertex_ids = {11, 2048, 6999};
  out.stagei_frames = {0, 3};
  for (int t = 0; t < kFrames; ++t) {
    Eigen::VectorXd p =
        Eigen::VectorXd::LinSpaced(3 + 3 * kJoints, 0.1 * t, 0.1 * t + 1.0);
    // Values exactly representable in float32, so the round trip is exact.
    Eigen::Matrix3Xd obs =
        Eigen::Matrix3Xd::Constant(3, kMarkers, 0.25 * (t + 1));
    obs(1, 2) = -0.5;
    Eigen::Matrix3Xd sim = obs.array() + 0.125;
    SolveSummary summary;
    summary.frame = t;
    summary.termination = SolveTermination::kConverged;
    summary.rms_m = 1e-3 * (t + 1);
    if (t == 1) summary.termination = SolveTermination::kNoConvergence;
    if (t == 2) {
      p.setConstant(std::nan(""));
      sim.setConstant(std::nan(""));
      summary.termination = SolveTermination::kSkipped;
      summary.skipped_reason = "too_few_markers";
    }
    if (t == 3) obs.col(1).setConstant(std::nan(""));
    out.frame_params.push_back(p);
    out.observed.push_back(obs);
    out.simulated.push_back(sim);
    out.summaries.push_back(summary);
  }
  return out;
}

/// Element-wise equality that treats two NaNs as equal.
template <typename A, typename B>
bool SameValues(const A& a, const B& b) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) return false;
  for (Eigen::Index i = 0; i < a.size(); ++i) {
    const double x = a.data()[i], y = b.data()[i];
    if (!(x == y || (std::isnan(x) && std::isnan(y)))) return false;
  }
  return true;
}

TEST(SolveOutput, RoundTripsThroughHdf5) {
  const SolveOutput out = MakeOutput();
  const fs::path path = soma::testing::CreateTestDir() / "take_stageii.h5";
  WriteSolveOutput(path, out);
  const SolveOutput in = ReadSolveOutput(path);
  EXPECT_EQ(in.body, out.body);
  EXPECT_EQ(in.joint_names, out.joint_names);
  EXPECT_EQ(in.labels, out.labels);
  EXPECT_EQ(in.frame_rate, out.frame_rate);
  EXPECT_TRUE(SameValues(in.betas, out.betas));
  EXPECT_TRUE(SameValues(in.markers_latent, out.markers_latent));
  EXPECT_TRUE(SameValues(in.marker_offsets, out.marker_offsets));
  EXPECT_EQ(in.marker_vertex_ids, out.marker_vertex_ids);
  EXPECT_EQ(in.stagei_frames, out.stagei_frames);
  ASSERT_EQ(in.frame_params.size(), out.frame_params.size());
  ASSERT_EQ(in.observed.size(), out.observed.size());
  ASSERT_EQ(in.simulated.size(), out.simulated.size());
  ASSERT_EQ(in.summaries.size(), out.summaries.size());
  for (int t = 0; t < kFrames; ++t) {
    SCOPED_TRACE(t);
    EXPECT_TRUE(SameValues(in.frame_params[t], out.frame_params[t]));
    EXPECT_TRUE(SameValues(in.observed[t], out.observed[t]));
    EXPECT_TRUE(SameValues(in.simulated[t], out.simulated[t]));
    EXPECT_EQ(in.summaries[t].frame, t);
    EXPECT_EQ(in.summaries[t].termination, out.summaries[t].termination);
    if (out.summaries[t].usable()) {
      EXPECT_EQ(in.summaries[t].rms_m, out.summaries[t].rms_m);
    } else {
      EXPECT_TRUE(std::isnan(in.summaries[t].rms_m));
    }
  }
  EXPECT_TRUE(std::isnan(in.frame_params[2](0)));
  EXPECT_TRUE(std::isnan(in.observed[3](0, 1)));
  EXPECT_EQ(in.observed[3](1, 2), -0.5);

  // Written again, the read-back output reads back the same.
  const fs::path again = path.parent_path() / "again.h5";
  WriteSolveOutput(again, in);
  const SolveOutput twice = ReadSolveOutput(again);
  for (int t = 0; t < kFrames; ++t) {
    EXPECT_TRUE(SameValues(twice.frame_params[t], in.frame_params[t]));
    EXPECT_EQ(twice.summaries[t].termination, in.summaries[t].termination);
  }
}

/// Opens `path` for writing and runs `edit(file)` under the HDF5 lock.
template <typename Fn>
void EditHdf5(const fs::path& path, Fn&& edit) {
  std::lock_guard lock(hdf5::Hdf5Mutex());
  hdf5::Hid file = hdf5::Check(H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT),
                               H5Fclose,
                               "open " + path.string());
  edit(file.get());
  ASSERT_TRUE(file.Reset());
}

TEST(SolveOutput, BadFilesAreOneClearError) {
  const fs::path dir = soma::testing::CreateTestDir();
  using soma::testing::ErrorMessage;

  const fs::path missing = dir / "missing.h5";
  EXPECT_THAT(ErrorMessage<IoError>([&] { ReadSolveOutput(missing); }),
              HasSubstr(missing.string() + ": no such file"));

  soma::testing::WriteTextFile(dir, "text.h5", "not hdf5\n");
  EXPECT_THAT(ErrorMessage<IoError>([&] { ReadSolveOutput(dir / "text.h5"); }),
              HasSubstr("text.h5: not a valid soma solve output: not an HDF5"));

  const fs::path wrong_format = dir / "wrong_format.h5";
  WriteSolveOutput(wrong_format, MakeOutput());
  EditHdf5(wrong_format, [&](hid_t file) {
    hdf5::WriteStringAttribute(
        file, "format", "soma-dataset", wrong_format.string());
  });
  EXPECT_THAT(
      ErrorMessage<IoError>([&] { ReadSolveOutput(wrong_format); }),
      HasSubstr("wrong_format.h5: not a valid soma solve output: attribute "
                "'format' is 'soma-dataset', expected 'soma-solve'"));

  const fs::path no_poses = dir / "no_poses.h5";
  WriteSolveOutput(no_poses, MakeOutput());
  EditHdf5(no_poses, [&](hid_t file) {
    ASSERT_GE(H5Ldelete(file, "poses", H5P_DEFAULT), 0);
  });
  EXPECT_THAT(
      ErrorMessage<IoError>([&] { ReadSolveOutput(no_poses); }),
      HasSubstr("no_poses.h5: not a valid soma solve output: missing dataset "
                "'poses'"));

  // `poses` for 3 joints while joint_names names 2.
  const fs::path bad_shape = dir / "bad_shape.h5";
  WriteSolveOutput(bad_shape, MakeOutput());
  EditHdf5(bad_shape, [&](hid_t file) {
    ASSERT_GE(H5Ldelete(file, "poses", H5P_DEFAULT), 0);
    const hsize_t dims[2] = {kFrames, 9};
    hdf5::Hid space =
        hdf5::Check(H5Screate_simple(2, dims, nullptr), H5Sclose, "space");
    hdf5::Hid dataset = hdf5::Check(H5Dcreate2(file,
                                               "poses",
                                               H5T_IEEE_F64LE,
                                               space.get(),
                                               H5P_DEFAULT,
                                               H5P_DEFAULT,
                                               H5P_DEFAULT),
                                    H5Dclose,
                                    "poses");
  });
  EXPECT_THAT(ErrorMessage<IoError>([&] { ReadSolveOutput(bad_shape); }),
              HasSubstr("bad_shape.h5: not a valid soma solve output: dataset "
                        "'poses' is 4 x 9, expected 4 x 6"));

  // The intact file still reads (the edits above did not leak).
  const fs::path good = dir / "good.h5";
  WriteSolveOutput(good, MakeOutput());
  EXPECT_EQ(ReadSolveOutput(good).frame_params.size(), kFrames);
}

}  // namespace
}  // namespace soma
