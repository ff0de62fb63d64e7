#include "framework/eval/body_metrics.h"

#include "framework/core/error.h"
#include "framework/solve/marker_model.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace soma {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Why frame `t` of `fit` cannot be compared; empty when it was solved.
std::string UnsolvedReason(const SolveOutput& fit, size_t t) {
  const SolveSummary& s = fit.summaries[t];
  if (s.termination == SolveTermination::kSkipped) return "skipped";
  if (s.termination == SolveTermination::kFailure) return "failed";
  if (!fit.frame_params[t].allFinite()) return "non_finite";
  return "";
}

/// ShapeError unless `fit` (called `role` in messages) belongs to `body`.
void CheckFit(const BodyModel& body,
              const SolveOutput& fit,
              const std::string& role) {
  if (fit.body != body.name) {
    throw ShapeError(fmt::format(
        "body metrics: the {} fit is of body '{}', the evaluation body is '{}' "
        "(select the body the fits were solved with)",
        role,
        fit.body,
        body.name));
  }
  if (static_cast<int>(fit.joint_names.size()) != body.num_joints()) {
    throw ShapeError(
        fmt::format("body metrics: the {} fit has {} joints, body '{}' has {}",
                    role,
                    fit.joint_names.size(),
                    body.name,
                    body.num_joints()));
  }
  if (fit.joint_names != body.joint_names) {
    throw ShapeError(fmt::format(
        "body metrics: the {} fit's joint names differ from body '{}''s",
        role,
        body.name));
  }
  if (fit.betas.size() > body.num_betas()) {
    throw ShapeError(
        fmt::format("body metrics: the {} fit has {} betas, body '{}' has {}",
                    role,
                    fit.betas.size(),
                    body.name,
                    body.num_betas()));
  }
  if (fit.summaries.size() != fit.frame_params.size()) {
    throw ShapeError(fmt::format(
        "body metrics: the {} fit has {} frame parameter vectors but {} "
        "per-frame summaries",
        role,
        fit.frame_params.size(),
        fit.summaries.size()));
  }
  const int size = FrameParamSize(body.num_joints());
  for (size_t t = 0; t < fit.frame_params.size(); ++t) {
    if (fit.frame_params[t].size() != size) {
      throw ShapeError(fmt::format(
          "body metrics: frame {} of the {} fit has {} parameters, expected "
          "{} (3 + 3J, J = {})",
          t,
          role,
          fit.frame_params[t].size(),
          size,
          body.num_joints()));
    }
  }
}

/// Mean of `values` over the compared frames; NaN when there are none.
double MeanOf(const std::vector<double>& values) {
  if (values.empty()) return kNaN;
  double sum = 0.0;
  for (double v : values) sum += v;
  return sum / static_cast<double>(values.size());
}

}  // namespace

void BodyMetricsOptions::Validate() const {
  if (pck_thresholds_mm.empty()) {
    throw ConfigError(
        "Invalid configuration. pck_thresholds_mm = []. Violated constraint: "
        "at least one threshold (body_metrics.cc)");
  }
  for (double t : pck_thresholds_mm) {
    if (!std::isfinite(t) || t <= 0.0) {
      throw ConfigError(
          fmt::format("Invalid configuration. pck_thresholds_mm = {}. Violated "
                      "constraint: every threshold > 0 mm (body_metrics.cc)",
                      t));
    }
  }
}

BodyMetrics ComputeBodyMetrics(const BodyModel& body,
                               const SolveOutput& reference,
                               const SolveOutput& candidate,
                               const BodyMetricsOptions& options) {
  options.Validate();
  CheckFit(body, reference, "reference");
  CheckFit(body, candidate, "candidate");
  if (reference.frame_params.size() != candidate.frame_params.size()) {
    throw ShapeError(fmt::format(
        "body metrics: the reference fit has {} frames, the candidate {} (fits "
        "of the same capture and frame range are needed)",
        reference.frame_params.size(),
        candidate.frame_params.size()));
  }
  const double rate_tol = 1e-9 * std::max(1.0, std::abs(reference.frame_rate));
  if (!(std::abs(reference.frame_rate - candidate.frame_rate) <= rate_tol)) {
    throw ShapeError(fmt::format(
        "body metrics: the reference fit is at {} Hz, the candidate at {} Hz",
        reference.frame_rate,
        candidate.frame_rate));
  }
  if (reference.betas.size() != candidate.betas.size()) {
    throw ShapeError(fmt::format(
        "body metrics: the reference fit has {} betas, the candidate {}",
        reference.betas.size(),
        candidate.betas.size()));
  }

  const int num_joints = body.num_joints();
  const Eigen::Matrix3Xd ref_rest =
      body.RestJoints(body.ShapedVertices(reference.betas));
  const Eigen::Matrix3Xd cand_rest =
      body.RestJoints(body.ShapedVertices(candidate.betas));
  const auto posed_joints = [&](const Eigen::Matrix3Xd& rest,
                                const BodyPose& pose) {
    const PosedSkeleton skeleton = PoseSkeleton(body, rest, pose);
    Eigen::Matrix3Xd joints(3, num_joints);
    for (int j = 0; j < num_joints; ++j) {
      joints.col(j) = skeleton.global[j].translation();
    }
    return joints;
  };

  BodyMetrics out;
  out.pck_thresholds_mm = options.pck_thresholds_mm;
  const size_t num_thresholds = options.pck_thresholds_mm.size();
  std::vector<double> v2v, joint_err;
  std::vector<std::vector<double>> pck(num_thresholds);
  out.frames.resize(reference.frame_params.size());
  for (size_t t = 0; t < out.frames.size(); ++t) {
    BodyFrameMetrics& frame = out.frames[t];
    frame.frame = static_cast<int>(t);
    const std::string ref_reason = UnsolvedReason(reference, t);
    const std::string cand_reason = UnsolvedReason(candidate, t);
    if (!ref_reason.empty()) frame.excluded_reason = "reference_" + ref_reason;
    if (!cand_reason.empty()) {
      if (!frame.excluded_reason.empty()) frame.excluded_reason += "+";
      frame.excluded_reason += "candidate_" + cand_reason;
    }
    if (!frame.compared()) {
      frame.v2v_mm = frame.joint_err_mm = frame.max_joint_err_mm = kNaN;
      frame.pck.assign(num_thresholds, kNaN);
      ++out.excluded_by_reason[frame.excluded_reason];
      continue;
    }
    const BodyPose ref_pose =
        UnpackFrameParams(reference.frame_params[t].data(), num_joints);
    const BodyPose cand_pose =
        UnpackFrameParams(candidate.frame_params[t].data(), num_joints);
    const Eigen::Matrix3Xd ref_vertices =
        PoseVertices(body, reference.betas, ref_pose);
    const Eigen::Matrix3Xd cand_vertices =
        PoseVertices(body, candidate.betas, cand_pose);
    frame.v2v_mm = 1e3 * (ref_vertices - cand_vertices).colwise().norm().mean();
    const Eigen::RowVectorXd joint_dist =
        1e3 *
        (posed_joints(ref_rest, ref_pose) - posed_joints(cand_rest, cand_pose))
            .colwise()
            .norm();
    frame.joint_err_mm = joint_dist.mean();
    frame.max_joint_err_mm = joint_dist.maxCoeff();
    frame.pck.resize(num_thresholds);
    for (size_t k = 0; k < num_thresholds; ++k) {
      const double tau = options.pck_thresholds_mm[k];
      const auto within = (joint_dist.array() < tau).count();
      frame.pck[k] = 100.0 * static_cast<double>(within) / num_joints;
      pck[k].push_back(frame.pck[k]);
    }
    v2v.push_back(frame.v2v_mm);
    joint_err.push_back(frame.joint_err_mm);
  }
  out.frames_total = static_cast<int>(out.frames.size());
  out.frames_compared = static_cast<int>(v2v.size());
  out.frames_excluded = out.frames_total - out.frames_compared;
  out.v2v_mm = MeanOf(v2v);
  out.joint_err_mm = MeanOf(joint_err);
  out.max_v2v_mm =
      v2v.empty() ? kNaN : *std::max_element(v2v.begin(), v2v.end());
  out.pck.resize(num_thresholds);
  for (size_t k = 0; k < num_thresholds; ++k) out.pck[k] = MeanOf(pck[k]);
  return out;
}

std::string PckMetricName(double threshold_mm) {
  return fmt::format("pck{:g}", threshold_mm);
}

std::string BodyMetrics::BriefReport() const {
  std::string excluded;
  for (const auto& [reason, count] : excluded_by_reason) {
    excluded +=
        fmt::format("{}{} {}", excluded.empty() ? "" : ", ", reason, count);
  }
  std::vector<std::string> names, values;
  for (size_t k = 0; k < pck_thresholds_mm.size(); ++k) {
    names.push_back(fmt::format("{:g}", pck_thresholds_mm[k]));
    values.push_back(fmt::format("{:.1f}", pck[k]));
  }
  return fmt::format(
      "body fit: {}/{} frames compared{}, V2V {:.2f} mm, joint error {:.2f} "
      "mm, PCK@{} mm {} %",
      frames_compared,
      frames_total,
      frames_excluded > 0
          ? fmt::format(" ({} excluded: {})", frames_excluded, excluded)
          : std::string(),
      v2v_mm,
      joint_err_mm,
      fmt::join(names, "/"),
      fmt::join(values, "/"));
}

std::string BodyMetricsToCsv(const BodyMetrics& metrics) {
  std::string csv =
      "frame,compared,excluded_reason,v2v_mm,joint_err_mm,max_joint_err_mm";
  for (double tau : metrics.pck_thresholds_mm) {
    csv += ',';
    csv += PckMetricName(tau);
  }
  csv += "\n";
  for (const BodyFrameMetrics& f : metrics.frames) {
    csv += fmt::format(
        "{},{},{}", f.frame, f.compared() ? 1 : 0, f.excluded_reason);
    if (f.compared()) {
      csv += fmt::format(",{:.6f},{:.6f},{:.6f}",
                         f.v2v_mm,
                         f.joint_err_mm,
                         f.max_joint_err_mm);
      for (double p : f.pck) csv += fmt::format(",{:.4f}", p);
    } else {
      csv += ",,,";
      for (size_t k = 0; k < f.pck.size(); ++k) csv += ",";
    }
    csv += "\n";
  }
  return csv;
}

}  // namespace soma
