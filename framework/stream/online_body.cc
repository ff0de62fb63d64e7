#include "framework/stream/online_body.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <filesystem>

namespace soma {

void OnlineBodyOptions::Validate() const {
  if (calibration_frames < 1) {
    throw ConfigError(fmt::format(
        "Invalid configuration. task.body.calibration_frames = {}. Violated "
        "constraint: calibration_frames >= 1",
        calibration_frames));
  }
  solve.Validate();
}

OnlineBodySolver::OnlineBodySolver(const BodyModel& body,
                                   const MarkerLayout& layout,
                                   const PosePrior* prior,
                                   const std::vector<std::string>& labels,
                                   OnlineBodyOptions options)
    : body_(body),
      prior_(prior),
      options_(std::move(options)),
      model_(body, MarkerVertices(layout).vertex_ids) {
  options_.Validate();
  num_markers_ = model_.num_markers();
  const LayoutMarkerVertices vertices = MarkerVertices(layout);
  distances_ = vertices.distances;
  std::vector<bool> covered(static_cast<size_t>(layout.num_markers()), false);
  marker_of_.reserve(labels.size());
  for (const std::string& label : labels) {
    const int m = layout.FindLabel(CanonicalMarkerLabel(label));
    marker_of_.push_back(m);
    if (m >= 0) covered[static_cast<size_t>(m)] = true;
  }
  const std::vector<std::string> layout_labels = layout.Labels();
  for (int m = 0; m < layout.num_markers(); ++m) {
    if (!covered[static_cast<size_t>(m)])
      absent_.push_back(layout_labels[static_cast<size_t>(m)]);
  }
  output_.body = body.name;
  output_.joint_names = body.joint_names;
  output_.labels = layout_labels;
  output_.marker_vertex_ids = vertices.vertex_ids;
  if (!options_.stagei_file.empty()) LoadStageI(options_.stagei_file);
}

void OnlineBodySolver::LoadStageI(const std::string& path) {
  const SolveOutput fit = ReadSolveOutput(path);
  if (fit.body != body_.name) {
    throw IoError(fmt::format(
        "{}: fitted on body '{}'; this stream's body is '{}' (task.solve."
        "stagei needs a fit of the same body and layout)",
        path,
        fit.body,
        body_.name));
  }
  if (fit.marker_vertex_ids != output_.marker_vertex_ids ||
      fit.labels != output_.labels) {
    throw IoError(fmt::format(
        "{}: fitted with another layout ({} markers; this stream's layout "
        "has {})",
        path,
        fit.labels.size(),
        output_.labels.size()));
  }
  if (fit.betas.size() != model_.num_betas() ||
      fit.marker_offsets.cols() != model_.num_markers()) {
    throw IoError(
        fmt::format("{}: {} betas and {} marker offsets; the body "
                    "has {} betas and {} markers",
                    path,
                    fit.betas.size(),
                    fit.marker_offsets.cols(),
                    model_.num_betas(),
                    model_.num_markers()));
  }
  model_.SetShape(fit.betas, fit.marker_offsets);
  output_.betas = fit.betas;
  output_.markers_latent = model_.latent_markers();
  output_.marker_offsets = model_.offsets();
  stagei_summary_ = SolveSummary{};
  stagei_summary_.termination = SolveTermination::kConverged;
  stagei_summary_.message = fmt::format("stage I from {}", path);
  solver_ =
      std::make_unique<StageIISolver>(&model_, prior_, options_.solve.stageii);
  SOMA_LOG(INFO,
           "stream: body from {} (stage I of an earlier fit; no calibration)",
           path);
}

OnlineBodySolver::~OnlineBodySolver() = default;

Eigen::Matrix3Xd OnlineBodySolver::Observed(const StreamFrame& frame,
                                            std::span<const int> labels,
                                            double metres_per_unit) const {
  Eigen::Matrix3Xd observed =
      Eigen::Matrix3Xd::Constant(3, num_markers_, std::nan(""));
  for (int i = 0; i < frame.num_points(); ++i) {
    const int l = labels[static_cast<size_t>(i)];
    if (l < 0 || l >= static_cast<int>(marker_of_.size()) ||
        !frame.IsPresent(i))
      continue;
    const int m = marker_of_[static_cast<size_t>(l)];
    if (m < 0) continue;
    for (int c = 0; c < 3; ++c) {
      observed(c, m) =
          frame.xyz[3 * static_cast<size_t>(i) + c] * metres_per_unit;
    }
  }
  return observed;
}

OnlineBodySolver::Calibration OnlineBodySolver::RunStageI(
    const std::vector<Eigen::Matrix3Xd>& frames) {
  Calibration result;
  try {
    result.picked = PickStageIFrames(frames, options_.solve.stagei);
    std::vector<Eigen::Matrix3Xd> picked;
    picked.reserve(result.picked.size());
    for (int f : result.picked)
      picked.push_back(frames[static_cast<size_t>(f)]);
    result.stagei = SolveStageI(
        body_, &model_, distances_, picked, prior_, options_.solve.stagei);
    if (!result.stagei.summary.usable()) {
      result.error =
          fmt::format("stage I failed: {}", result.stagei.summary.message);
    }
  } catch (const Error& e) {
    result.error = e.what();
  }
  return result;
}

void OnlineBodySolver::StartCalibration() {
  calibration_size_ = static_cast<int>(calibration_.size());
  if (!options_.background_stagei) {
    FinishCalibration(RunStageI(calibration_));
  } else {
    stagei_ = std::async(
        std::launch::async,
        [this](const std::vector<Eigen::Matrix3Xd>& frames) {
          return RunStageI(frames);
        },
        std::move(calibration_));
  }
  calibration_.clear();
  calibration_.shrink_to_fit();
}

void OnlineBodySolver::FinishCalibration(Calibration result) {
  stagei_summary_ = result.stagei.summary;
  if (!result.error.empty()) {
    failed_ = true;
    SOMA_LOG(ERROR,
             "stream: no body: stage I on the first {} frames failed ({}); "
             "labels continue",
             calibration_size_,
             result.error);
    return;
  }
  output_.betas = result.stagei.betas;
  output_.markers_latent = model_.latent_markers();
  output_.marker_offsets = model_.offsets();
  output_.stagei_frames = result.picked;
  solver_ =
      std::make_unique<StageIISolver>(&model_, prior_, options_.solve.stageii);
  SOMA_LOG(INFO,
           "stream: body calibrated on {} of the first {} frames{}: {}",
           result.picked.size(),
           calibration_size_,
           options_.background_stagei
               ? fmt::format(" (in the background; stage II from frame {})",
                             output_.summaries.size())
               : "",
           result.stagei.summary.BriefReport());
}

void OnlineBodySolver::Finish() {
  if (stagei_.valid()) FinishCalibration(stagei_.get());
}

SolveSummary OnlineBodySolver::AddFrame(const StreamFrame& frame,
                                        std::span<const int> labels,
                                        double metres_per_unit) {
  SOMA_CHECK_EQ(labels.size(), static_cast<size_t>(frame.num_points()));
  const int index = static_cast<int>(output_.summaries.size());
  Eigen::Matrix3Xd observed = Observed(frame, labels, metres_per_unit);
  SolveSummary summary;
  summary.frame = index;
  Eigen::VectorXd params =
      Eigen::VectorXd::Constant(3 + 3 * body_.num_joints(), std::nan(""));
  Eigen::Matrix3Xd simulated =
      Eigen::Matrix3Xd::Constant(3, num_markers_, std::nan(""));
  if (stagei_.valid() &&
      stagei_.wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
    FinishCalibration(stagei_.get());
  }
  if (stagei_.valid()) {
    summary.skipped_reason = "calibrating";
    summary.message = "waiting for stage I (in the background)";
  } else if (solver_ == nullptr && !failed_) {
    calibration_.push_back(observed);
    summary.skipped_reason = "calibrating";
    summary.message = "calibration segment (stage I)";
    if (static_cast<int>(calibration_.size()) >= options_.calibration_frames)
      StartCalibration();
  } else if (failed_) {
    summary.skipped_reason = "no_body";
    summary.message = "stage I failed";
  } else {
    summary = solver_->SolveFrame(index, observed, &params);
    if (summary.usable()) {
      model_.Evaluate(params.data(), {}, &simulated, nullptr);
    }
  }
  output_.frame_params.push_back(std::move(params));
  output_.observed.push_back(std::move(observed));
  output_.simulated.push_back(std::move(simulated));
  output_.summaries.push_back(summary);
  return summary;
}

}  // namespace soma
