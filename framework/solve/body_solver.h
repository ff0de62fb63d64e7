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

/// Decodes `node` (the `solver` config group, configs/solver/: keys
/// stagei {...}, stageii {...}, ceres {...} shared by both stages, start,
/// end, stride, threads). Unknown keys are errors. The pose prior is its
/// own component (`pose_prior` group, PosePriorSource).
BodySolveOptions DecodeBodySolveOptions(const ConfigNode& node);

struct BodySolveResult {
  StageIResult stagei;
  SolveOutput output;
  SequenceSolveStats stats;
  double stageii_frames_per_s = 0.0;
};

/// Runs stage I and stage II on `markers` (matched to `layout`) with the
/// pose prior `prior` (may be null: no prior).
BodySolveResult SolveBody(const BodyModel& body,
                          const MarkerLayout& layout,
                          const LabelledMarkers& markers,
                          const PosePrior* prior,
                          const BodySolveOptions& options);

}  // namespace soma
