// The online body of `soma stream` (issue #26 item 3): stage I on a
// calibration segment (the first frames of the stream, labelled online) or
// from a file (an earlier fit's `_stageii.h5`), then stage II on every later
// frame as it arrives, warm-started from the previous frame, within the
// per-solve time limit of `stageii.solver.max_solver_time_s`.
#pragma once

#include "framework/solve/body_solver.h"
#include "framework/solve/marker_model.h"
#include "framework/solve/solve_output.h"
#include "framework/solve/stage_ii.h"
#include "framework/stream/frame.h"

#include <memory>
#include <span>
#include <string>
#include <vector>

namespace soma {

/// Options of OnlineBodySolver.
struct OnlineBodyOptions {
  /// Frames of the stream's start used for stage I (labelled online; stage I
  /// picks its frames among them, BodySolveOptions::stagei).
  int calibration_frames = 240;
  /// Instead of a calibration: the stage I result of an earlier fit of the
  /// same subject, a `soma solve` or `soma stream` `<take>_stageii.h5`
  /// (its betas and marker offsets; same body and layout). Empty: none.
  std::string stagei_file;
  /// Stage I and II options (start/end/stride/threads are not used).
  BodySolveOptions solve;
  void Validate() const;  // ConfigError on violation
};

/// Feeds labelled frames in order; solves each one after the calibration.
class OnlineBodySolver {
 public:
  /// `labels`: the labeller's label names (ids of AddFrame's labels; null =
  /// labels.size()), matched to `layout` by canonical name. `body`, `layout`
  /// and `prior` (may be null) must outlive the solver. With a stagei_file,
  /// IoError if it cannot be read or was fitted with another body/layout.
  OnlineBodySolver(const BodyModel& body,
                   const MarkerLayout& layout,
                   const PosePrior* prior,
                   const std::vector<std::string>& labels,
                   OnlineBodyOptions options);
  ~OnlineBodySolver();

  /// One labelled frame; coordinates are `metres_per_unit` metres per unit.
  /// Returns the frame's stage II summary: skipped ("calibrating") during
  /// the calibration segment — the frame that completes it runs stage I
  /// (its latency includes it) — and for every frame if stage I failed.
  SolveSummary AddFrame(const StreamFrame& frame,
                        std::span<const int> labels,
                        double metres_per_unit);

  bool calibrated() const { return solver_ != nullptr; }
  /// Stage I's summary (default-constructed before the calibration).
  const SolveSummary& stagei_summary() const { return stagei_summary_; }
  /// The fits so far (one entry per frame given), for WriteSolveOutput.
  const SolveOutput& output() const { return output_; }
  /// Layout labels the labeller cannot give (always missing).
  const std::vector<std::string>& absent_labels() const { return absent_; }

 private:
  Eigen::Matrix3Xd Observed(const StreamFrame& frame,
                            std::span<const int> labels,
                            double metres_per_unit) const;
  void Calibrate();
  void LoadStageI(const std::string& path);

  const BodyModel& body_;
  const PosePrior* prior_;
  OnlineBodyOptions options_;
  std::vector<int> marker_of_;  // label id -> layout marker (-1: none)
  std::vector<double> distances_;
  std::vector<std::string> absent_;
  MarkerModel model_;
  std::unique_ptr<StageIISolver> solver_;
  bool failed_ = false;
  std::vector<Eigen::Matrix3Xd> calibration_;
  SolveSummary stagei_summary_;
  SolveOutput output_;
};

}  // namespace soma
