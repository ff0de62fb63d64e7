// The result file of `soma solve` (MoSh++'s stage-II pkl, as HDF5):
//   /trans           F x 3 float64, root translation (metres; NaN: skipped)
//   /poses           F x 3J float64, axis-angle per joint (root first)
//   /betas           B float64
//   /markers_latent  M x 3 float64, latent markers on the canonical body
//   /marker_offsets  M x 3 float64, offset from each marker vertex
//   /markers_vids    M int32, the marker vertex ids
//   /markers_obs     F x M x 3 float32, observed (NaN = missing)
//   /markers_sim     F x M x 3 float32, simulated
//   /termination     F int32 (0 converged, 1 no convergence, 2 failure,
//                    3 skipped), /rms F float64 (metres), /stagei_frames
// attributes: format "soma-solve", labels, joint_names, body, frame_rate,
// num_frames; written atomically. ReadSolveOutput reads it back.
#pragma once

#include "framework/solve/solve_summary.h"

#include <Eigen/Core>

#include <filesystem>
#include <string>
#include <vector>

namespace soma {

struct SolveOutput {
  std::string body;
  std::vector<std::string> joint_names;
  std::vector<std::string> labels;
  double frame_rate = 0.0;
  Eigen::VectorXd betas;
  Eigen::Matrix3Xd markers_latent;
  Eigen::Matrix3Xd marker_offsets;
  std::vector<int> marker_vertex_ids;
  std::vector<int> stagei_frames;
  std::vector<Eigen::VectorXd> frame_params;  // per frame, 3 + 3J
  std::vector<Eigen::Matrix3Xd> observed;     // per frame, 3 x M
  std::vector<Eigen::Matrix3Xd> simulated;    // per frame, 3 x M
  std::vector<SolveSummary> summaries;        // per frame
};

/// Writes `output` to `path` (HDF5, atomically). Throws IoError/ShapeError.
void WriteSolveOutput(const std::filesystem::path& path,
                      const SolveOutput& output);

/// Reads a file written by WriteSolveOutput (the inverse; observed and
/// simulated markers come back as float32 values). Per-frame summaries carry
/// what the file stores: `frame` (the index in the file; the solve's
/// start/stride are not stored), `termination` and `rms_m` (NaN for frames
/// that are not usable); the other summary fields keep their defaults.
/// Throws IoError ("<file>: ...") for a missing or non-HDF5 file, a `format`
/// attribute other than "soma-solve", a missing dataset / attribute, or a
/// dataset whose shape disagrees with the attributes (e.g. `poses` not
/// F x 3J with F = num_frames, J = |joint_names|), naming the dataset.
SolveOutput ReadSolveOutput(const std::filesystem::path& path);

}  // namespace soma
