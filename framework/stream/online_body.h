// The online body of `soma stream` (issue #26 item 3): stage I on a
// calibration segment (the first frames of the stream, labelled online) or
// from a file (an earlier fit's `_stageii.h5`), then stage II on every later
// frame as it arrives, warm-started from the previous frame, within the
// per-solve time limit of `stageii.solver.max_solver_time_s`.
//
// Stage I takes ~0.5-1 s. Run in the background (the default), it does not
// hold up the stream: the frames that arrive meanwhile are labelled as usual
// and get no body ("calibrating"); stage II starts with the first frame
// after stage I is done. Run in the foreground, the frame that completes the
// calibration waits for it, and so do the frames queued behind it.
#pragma once

#include "framework/solve/body_solver.h"
#include "framework/solve/marker_model.h"
#include "framework/solve/solve_output.h"
#include "framework/solve/stage_i.h"
#include "framework/solve/stage_ii.h"
#include "framework/stream/frame.h"

#include <future>
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
  /// Stage I on a thread of its own, so that the stream does not wait for
  /// it (the frames meanwhile get no body); false: on the calling thread.
  bool background_stagei = true;
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
  /// the calibration segment and, with background_stagei, until stage I is
  /// done (otherwise the frame that completes the segment runs stage I and
  /// its latency includes it); skipped ("no_body") for every frame if stage
  /// I failed.
  SolveSummary AddFrame(const StreamFrame& frame,
                        std::span<const int> labels,
                        double metres_per_unit);
  /// Waits for a stage I still running in the background (at the end of a
  /// stream, before output() is written). A no-op otherwise.
  void Finish();

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
  // Stage I's outcome: `error` empty on success.
  struct Calibration {
    StageIResult stagei;
    std::vector<int> picked;
    std::string error;
  };
  // Stage I on `frames`; sets model_'s shape and touches nothing else, so it
  // can run on another thread while AddFrame only reads marker_of_ and
  // num_markers_.
  Calibration RunStageI(const std::vector<Eigen::Matrix3Xd>& frames);
  void StartCalibration();                     // the segment is complete
  void FinishCalibration(Calibration result);  // the solver starts
  void LoadStageI(const std::string& path);

  const BodyModel& body_;
  const PosePrior* prior_;
  OnlineBodyOptions options_;
  std::vector<int> marker_of_;  // label id -> layout marker (-1: none)
  std::vector<double> distances_;
  std::vector<std::string> absent_;
  int num_markers_ = 0;  // model_.num_markers(), read without model_
  MarkerModel model_;
  std::unique_ptr<StageIISolver> solver_;
  bool failed_ = false;
  std::vector<Eigen::Matrix3Xd> calibration_;
  int calibration_size_ = 0;         // frames given to stage I
  std::future<Calibration> stagei_;  // valid while stage I runs
  SolveSummary stagei_summary_;
  SolveOutput output_;
};

}  // namespace soma
