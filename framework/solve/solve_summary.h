// What one solve reports (STYLE: non-convergence is data, not an exception):
// the termination, costs, iterations, time, markers used and, for a skipped
// frame, why. Written per frame to summary CSVs and logged.
#pragma once

#include <ceres/solver.h>
#include <ceres/types.h>

#include <string>
#include <string_view>
#include <vector>

namespace soma {

enum class SolveTermination {
  kConverged,      // a Ceres convergence criterion was met
  kNoConvergence,  // iteration or time limit reached; the result is usable
  kFailure,        // the solver failed (numerical problem); result unusable
  kSkipped,        // not solved (see skipped_reason)
};
std::string_view ToString(SolveTermination termination);
/// Maps a Ceres termination type.
SolveTermination FromCeres(ceres::TerminationType type);

struct SolveSummary;
/// One Ceres solve as a SolveSummary (termination, message, costs,
/// iterations, time; solves = 1; the marker fields are left to the caller).
SolveSummary FromCeresSummary(const ceres::Solver::Summary& summary);

struct SolveSummary {
  int frame = -1;  // frame index in the input (-1: not a per-frame solve)
  SolveTermination termination = SolveTermination::kSkipped;
  std::string message;  // Ceres' message, or the skip reason in words
  double initial_cost = 0.0;
  double final_cost = 0.0;
  int iterations = 0;  // summed over the solves of this frame
  int solves = 0;      // Ceres solves run (annealing rounds, warm-up)
  double time_s = 0.0;
  int markers_used = 0;        // observed markers fitted
  int markers_missing = 0;     // layout markers absent in this frame (NaN)
  double rms_m = 0.0;          // RMS distance simulated - observed, metres
  std::string skipped_reason;  // e.g. "too_few_markers"; empty if solved

  bool usable() const {
    return termination == SolveTermination::kConverged ||
           termination == SolveTermination::kNoConvergence;
  }
  /// One line: "frame 12: CONVERGED cost 3.1e-2 -> 1.2e-4, 6 it, 0.4 ms,
  /// 41 markers, rms 4.1 mm".
  std::string BriefReport() const;
  /// Adds another solve of the same frame (costs: first initial, last
  /// final; iterations and time summed; termination of the last).
  void Accumulate(const SolveSummary& next);
};

/// Counts of a sequence of per-frame summaries.
struct SequenceSolveStats {
  int frames = 0;
  int converged = 0;
  int no_convergence = 0;
  int failed = 0;
  int skipped = 0;
  double mean_rms_m = 0.0;  // over usable frames
  double max_rms_m = 0.0;
  double total_time_s = 0.0;
  std::string BriefReport() const;
};
SequenceSolveStats Summarize(const std::vector<SolveSummary>& summaries);

/// CSV: frame,termination,initial_cost,final_cost,iterations,solves,time_s,
/// markers_used,markers_missing,rms_mm,skipped_reason,message.
std::string SolveSummariesToCsv(const std::vector<SolveSummary>& summaries);

}  // namespace soma
