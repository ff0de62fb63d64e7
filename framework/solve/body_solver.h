// BodySolver: the whole MoSh-style fit of one labelled capture — stage I on
// picked frames (shape + latent markers), then stage II over a frame range
// with warm starts — and its per-frame output and summaries.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"
#include "framework/config/node.h"
#include "framework/solve/labelled_markers.h"
#include "framework/solve/pose_prior.h"
#include "framework/solve/solve_output.h"
#include "framework/solve/stage_i.h"
#include "framework/solve/stage_ii.h"

#include <memory>
#include <string>

namespace soma {

struct BodySolveOptions {
  /// "procedural" (Gaussian fitted to the procedural motion library),
  /// "zero_mean" (isotropic, prior_stddev) or "none".
  std::string pose_prior = "procedural";
  double prior_stddev = 0.6;  // radians, zero_mean only
  ProceduralPosePriorOptions procedural_prior;
  StageIOptions stagei;
  StageIIOptions stageii;
  int start = 0;   // first frame of stage II
  int end = -1;    // one past the last (-1: all)
  int stride = 1;  // every n-th frame
  /// Stage II threads: the frame range is cut into this many contiguous
  /// chunks solved in parallel, each starting with a rigid initialisation
  /// (so results differ slightly from threads = 1 at chunk starts).
  int threads = 1;
  void Validate() const;
};

/// Decodes `node` (the `solver` node of configs/task/solve.yaml: keys
/// pose_prior, prior_stddev, stagei {...}, stageii {...}, ceres {...}
/// shared by both stages, start, end, stride). Unknown keys are errors.
BodySolveOptions DecodeBodySolveOptions(const ConfigNode& node);

/// The pose prior `options.pose_prior` for `body` (null for "none").
std::unique_ptr<PosePrior> MakePosePrior(const BodyModel& body,
                                         const BodySolveOptions& options);

struct BodySolveResult {
  StageIResult stagei;
  SolveOutput output;
  SequenceSolveStats stats;
  double stageii_frames_per_s = 0.0;
};

/// Runs stage I and stage II on `markers` (matched to `layout`).
BodySolveResult SolveBody(const BodyModel& body,
                          const MarkerLayout& layout,
                          const LabelledMarkers& markers,
                          const BodySolveOptions& options);

}  // namespace soma
