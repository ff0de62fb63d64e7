// Stage II of MoSh++ (REFERENCE.md 7.4): per-frame pose with betas and
// latent markers fixed. Per frame, over the observed markers:
//   data  (sim - obs) x data_weight * marker_norm / #observed,
//   poseB prior x prior_weight * c, c = 1 + missing_prior_gain * #missing /
//         #markers (more missing markers -> stronger prior),
//   velo  (pose - (2 p_{t-1} - p_{t-2})) x velocity_weight, from the third
//         solved frame on (constant-velocity extrapolation of the rotations).
// The first frame (and the first after a gap of skipped frames longer than
// max_gap) is initialised by a rigid Kabsch alignment of the rest-pose
// markers, then solved with the prior weight scaled by 10, 5, 1; later
// frames are warm-started from the previous solution. Toe rotations stay
// fixed unless optimize_toes. Frames with fewer than min_markers observed
// markers are skipped (their SolveSummary says why, parameters are NaN).
#pragma once

#include "framework/solve/cost_functions.h"
#include "framework/solve/marker_model.h"
#include "framework/solve/pose_prior.h"
#include "framework/solve/solve_summary.h"

#include <Eigen/Core>
#include <ceres/solver.h>

#include <string>
#include <vector>

namespace soma {

/// Ceres options shared by both stages.
struct SolverOptions {
  std::string trust_region = "levenberg_marquardt";  // or "dogleg"
  std::string linear_solver = "dense_qr";  // dense_qr, dense_normal_cholesky
  int max_iterations = 100;
  double function_tolerance = 1e-6;  // relative cost decrease to stop
  double parameter_tolerance = 1e-8;
  double gradient_tolerance = 1e-10;
  int num_threads = 1;
  /// > 0: wall-clock limit of one Ceres solve, seconds (Ceres
  /// max_solver_time_in_seconds; a per-frame budget for live solving: the
  /// solve stops with NO_CONVERGENCE and its usable iterate); 0: none.
  double max_solver_time_s = 0.0;
  void Validate() const;  // ConfigError naming the option
};

struct StageIIOptions {
  double data_weight = 400.0;  // x marker_norm / #observed (per residual)
  double marker_norm = 46.0;
  double prior_weight = 1.6;
  double missing_prior_gain = 2.5;
  double velocity_weight = 2.5;
  std::vector<double> first_frame_prior_scales = {10.0, 5.0, 1.0};
  int min_markers = 3;  // fewer observed markers: the frame is skipped
  int max_gap = 10;     // skipped frames after which we re-initialise
  bool optimize_toes = false;
  /// data_term / data_loss / data_loss_scale / noise_sigma_min (see
  /// DataTermOptions). noise_aware in stage II: sigma_m per observed marker,
  /// optimised jointly with the pose in every frame's solve (the paper's
  /// second stage optimises theta and sigma), warm-started from the previous
  /// frame's sigmas (data_loss_scale at a (re)start, held fixed there until
  /// the last of the first-frame prior scales). With one observation per
  /// sigma this amounts to a log-type robust loss, ~ log max(|r_m|,
  /// sigma_min).
  DataTermOptions data;
  SolverOptions solver;
  void Validate() const;
};

class StageIISolver {
 public:
  /// `model` (with its shape set) and `prior` must outlive the solver.
  StageIISolver(const MarkerModel* model,
                const PosePrior* prior,
                StageIIOptions options);

  /// Fits frame `frame_index` to `observed` (3 x M in the model's marker
  /// order; NaN/inf columns are missing). `params` gets the frame vector
  /// (NaN when skipped or failed). Throws ShapeError if `observed` does not
  /// have M columns.
  SolveSummary SolveFrame(int frame_index,
                          const Eigen::Matrix3Xd& observed,
                          Eigen::VectorXd* params);

  /// Noise-aware data term: sigma_m (metres, M) of the last solved frame,
  /// NaN for unobserved markers; empty for the standard term.
  const Eigen::VectorXd& noise_sigmas() const { return noise_sigmas_; }

  /// Forgets the warm-start history (the next frame is initialised rigidly).
  void Reset();

 private:
  SolveSummary RunSolve(const std::vector<int>& markers,
                        const Eigen::Matrix3Xd& observed,
                        double prior_scale,
                        bool velocity,
                        bool free_sigma,
                        Eigen::VectorXd* params);

  const MarkerModel* model_;
  const PosePrior* prior_;
  StageIIOptions options_;
  std::vector<int> fixed_indices_;        // frame-vector entries held constant
  std::vector<Eigen::VectorXd> history_;  // last solved frames, newest first
  int gap_ = 0;  // skipped frames since the last solved one
  Eigen::VectorXd noise_sigmas_;
};

/// Fixed entries of a frame vector: the toe rotations (joints 10, 11 of a
/// body with the core joints) unless optimize_toes.
std::vector<int> FixedFrameEntries(int num_joints, bool optimize_toes);

/// Ceres options for SolverOptions (silent logging); checked with IsValid.
ceres::Solver::Options ToCeresOptions(const SolverOptions& options);

/// The rigid initialisation of a frame: the rest pose of `model` (its
/// current shape) with the root rotation and translation of the Kabsch
/// alignment of the markers `markers` to their columns of `observed`.
Eigen::VectorXd RigidInitFrame(const MarkerModel& model,
                               const std::vector<int>& markers,
                               const Eigen::Matrix3Xd& observed);

/// Observed marker columns (finite) of `observed`.
std::vector<int> ObservedMarkers(const Eigen::Matrix3Xd& observed);

}  // namespace soma
