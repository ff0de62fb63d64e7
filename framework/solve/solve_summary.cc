#include "framework/solve/solve_summary.h"

#include <fmt/format.h>

#include <algorithm>
#include <sstream>

namespace soma {

std::string_view ToString(SolveTermination termination) {
  switch (termination) {
    case SolveTermination::kConverged:
      return "CONVERGED";
    case SolveTermination::kNoConvergence:
      return "NO_CONVERGENCE";
    case SolveTermination::kFailure:
      return "FAILURE";
    case SolveTermination::kSkipped:
      return "SKIPPED";
  }
  return "UNKNOWN";
}

SolveTermination FromCeres(ceres::TerminationType type) {
  switch (type) {
    case ceres::CONVERGENCE:
      return SolveTermination::kConverged;
    case ceres::NO_CONVERGENCE:
      return SolveTermination::kNoConvergence;
    default:
      return SolveTermination::kFailure;
  }
}

SolveSummary FromCeresSummary(const ceres::Solver::Summary& summary) {
  SolveSummary out;
  out.termination = FromCeres(summary.termination_type);
  out.message = summary.message;
  out.initial_cost = summary.initial_cost;
  out.final_cost = summary.final_cost;
  out.iterations = static_cast<int>(summary.iterations.size()) - 1;
  out.solves = 1;
  out.time_s = summary.total_time_in_seconds;
  return out;
}

std::string SolveSummary::BriefReport() const {
  if (termination == SolveTermination::kSkipped) {
    return fmt::format("frame {}: SKIPPED ({}): {}, {} markers",
                       frame,
                       skipped_reason,
                       message,
                       markers_used);
  }
  return fmt::format(
      "frame {}: {} cost {:.3e} -> {:.3e}, {} it, {:.2f} ms, {} markers "
      "({} missing), rms {:.1f} mm",
      frame,
      ToString(termination),
      initial_cost,
      final_cost,
      iterations,
      1e3 * time_s,
      markers_used,
      markers_missing,
      1e3 * rms_m);
}

void SolveSummary::Accumulate(const SolveSummary& next) {
  if (solves == 0) initial_cost = next.initial_cost;
  final_cost = next.final_cost;
  iterations += next.iterations;
  solves += next.solves;
  time_s += next.time_s;
  termination = next.termination;
  message = next.message;
}

std::string SequenceSolveStats::BriefReport() const {
  return fmt::format(
      "{} frames: {} converged, {} not converged, {} failed, {} skipped; "
      "rms mean {:.1f} mm, max {:.1f} mm; {:.2f} s",
      frames,
      converged,
      no_convergence,
      failed,
      skipped,
      1e3 * mean_rms_m,
      1e3 * max_rms_m,
      total_time_s);
}

SequenceSolveStats Summarize(const std::vector<SolveSummary>& summaries) {
  SequenceSolveStats stats;
  int usable = 0;
  for (const SolveSummary& s : summaries) {
    ++stats.frames;
    stats.total_time_s += s.time_s;
    switch (s.termination) {
      case SolveTermination::kConverged:
        ++stats.converged;
        break;
      case SolveTermination::kNoConvergence:
        ++stats.no_convergence;
        break;
      case SolveTermination::kFailure:
        ++stats.failed;
        break;
      case SolveTermination::kSkipped:
        ++stats.skipped;
        break;
    }
    if (s.usable()) {
      ++usable;
      stats.mean_rms_m += s.rms_m;
      stats.max_rms_m = std::max(stats.max_rms_m, s.rms_m);
    }
  }
  if (usable > 0) stats.mean_rms_m /= usable;
  return stats;
}

std::string SolveSummariesToCsv(const std::vector<SolveSummary>& summaries) {
  std::ostringstream csv;
  csv << "frame,termination,initial_cost,final_cost,iterations,solves,time_s,"
         "markers_used,markers_missing,rms_mm,skipped_reason,message\n";
  for (const SolveSummary& s : summaries) {
    std::string message = s.message;
    std::replace(message.begin(), message.end(), '"', '\'');
    std::replace(message.begin(), message.end(), '\n', ' ');
    csv << fmt::format(
        "{},{},{:.6g},{:.6g},{},{},{:.6f},{},{},{:.3f},{},\"{}\"\n",
        s.frame,
        ToString(s.termination),
        s.initial_cost,
        s.final_cost,
        s.iterations,
        s.solves,
        s.time_s,
        s.markers_used,
        s.markers_missing,
        1e3 * s.rms_m,
        s.skipped_reason,
        message);
  }
  return csv.str();
}

}  // namespace soma
