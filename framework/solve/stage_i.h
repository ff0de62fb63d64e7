// Stage I of MoSh++ (REFERENCE.md 7.3): body shape and latent marker
// placement from a few frames (12 by default), with per-frame poses.
// Each frame is initialised by a rigid Kabsch alignment of the rest-pose
// markers; then annealing rounds with factor a (1, 1/2, 1/4, 1/8) minimise
//   data  (sim - obs) x (data_weight / a) * marker_norm / #latent markers,
//   poseB prior per frame x prior_weight * a,
//   init  (o_m - o_m^0) x init_weight * a  (offsets stay near the layout's
//         vertex + normal * distance; our version of MoSh's latent-marker
//         init term, expressed in the offset from the marker vertex),
//   beta  betas x beta_weight * a,
//   surf  (n_m . o_m - d_m) x surface_weight (the marker keeps its distance
//         from the skin along the rest normal n_m at beta = 0; MoSh++ uses
//         the signed point-to-mesh distance).
// Free: per-frame t + pose (toes fixed unless optimize_toes), betas,
// offsets.
#pragma once

#include "framework/body/body_model.h"
#include "framework/solve/cost_functions.h"
#include "framework/solve/marker_model.h"
#include "framework/solve/pose_prior.h"
#include "framework/solve/solve_summary.h"
#include "framework/solve/stage_ii.h"

#include <Eigen/Core>

#include <cstdint>
#include <vector>

namespace soma {

struct StageIOptions {
  int num_frames = 12;
  /// Fraction of the layout's markers a picked frame must have; relaxed by
  /// 0.01 steps down to min_available_floor if too few frames qualify
  /// (MoSh++'s `random` picker after `random_strict`).
  double min_available = 1.0;
  double min_available_floor = 0.5;
  uint64_t seed = 100;  // frame picking
  std::vector<double> annealing = {1.0, 0.5, 0.25, 0.125};
  double data_weight = 75.0;
  double marker_norm = 46.0;
  double prior_weight = 3.0;
  double init_weight = 300.0;
  double beta_weight = 10.0;
  double surface_weight = 10000.0;
  bool optimize_betas = true;
  bool optimize_toes = false;
  /// data_term / data_loss / data_loss_scale / noise_sigma_min (see
  /// DataTermOptions). noise_aware in stage I: one sigma_m per marker shared
  /// by all stage-I frames, optimised jointly with shape and poses in every
  /// annealing round but the first (started at data_loss_scale, kept across
  /// rounds).
  DataTermOptions data;
  SolverOptions solver = {.linear_solver = "dense_schur"};
  void Validate() const;
};

struct StageIResult {
  Eigen::VectorXd betas;
  Eigen::Matrix3Xd offsets;                   // 3 x M, rest frame
  std::vector<int> frames;                    // input frame indices used
  std::vector<Eigen::VectorXd> frame_params;  // per used frame
  std::vector<SolveSummary> rounds;           // one per annealing round
  /// Noise-aware data term: the per-marker sigma_m (metres, M); empty for
  /// the standard term.
  Eigen::VectorXd noise_sigmas;
  /// All rounds accumulated; rms_m over every observed marker of every
  /// frame; markers_used counts marker observations.
  SolveSummary summary;
};

/// Picks options.num_frames frames (fewer if the sequence is shorter) with
/// at least min_available of the markers observed, at random (seeded);
/// frames are returned in increasing order. Throws Error if no frame has
/// min_available_floor of the markers ("not enough frames" names the best
/// fraction found).
std::vector<int> PickStageIFrames(const std::vector<Eigen::Matrix3Xd>& frames,
                                  const StageIOptions& options);

/// Runs stage I on `frames` (observed 3 x M each, NaN = missing; all of
/// them are used). `distances` are the layout's distances from the skin
/// (M). The model's shape is set to the result. `prior` may be null.
/// Throws ShapeError for inconsistent sizes and Error for a frame with
/// fewer than 3 observed markers.
StageIResult SolveStageI(const BodyModel& body,
                         MarkerModel* model,
                         const std::vector<double>& distances,
                         const std::vector<Eigen::Matrix3Xd>& frames,
                         const PosePrior* prior,
                         const StageIOptions& options);

}  // namespace soma
