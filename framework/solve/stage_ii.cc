#include "framework/solve/stage_ii.h"

#include "framework/core/error.h"
#include "framework/core/timer.h"
#include "framework/solve/cost_functions.h"
#include "framework/solve/kabsch.h"

#include <ceres/manifold.h>
#include <ceres/problem.h>
#include <fmt/format.h>

#include <cmath>
#include <limits>

namespace soma {
namespace {

ConfigError InvalidOption(std::string_view key,
                          const std::string& value,
                          std::string_view constraint) {
  return ConfigError(fmt::format(
      "Invalid configuration. {} = {}. Violated constraint: {} (stage_ii.cc)",
      key,
      value,
      constraint));
}

}  // namespace

void SolverOptions::Validate() const {
  if (trust_region != "levenberg_marquardt" && trust_region != "dogleg") {
    throw InvalidOption(
        "solver.trust_region", trust_region, "levenberg_marquardt | dogleg");
  }
  if (linear_solver != "dense_qr" && linear_solver != "dense_normal_cholesky" &&
      linear_solver != "sparse_normal_cholesky" &&
      linear_solver != "dense_schur") {
    throw InvalidOption(
        "solver.linear_solver",
        linear_solver,
        "dense_qr | dense_normal_cholesky | sparse_normal_cholesky | "
        "dense_schur");
  }
  if (max_iterations < 1) {
    throw InvalidOption("solver.max_iterations",
                        std::to_string(max_iterations),
                        "max_iterations >= 1");
  }
  if (!(function_tolerance >= 0) || !(parameter_tolerance >= 0) ||
      !(gradient_tolerance >= 0)) {
    throw InvalidOption("solver.*_tolerance", "negative", "tolerances >= 0");
  }
  if (num_threads < 1) {
    throw InvalidOption(
        "solver.num_threads", std::to_string(num_threads), "num_threads >= 1");
  }
  if (!(max_solver_time_s >= 0)) {
    throw InvalidOption("solver.max_solver_time_s",
                        std::to_string(max_solver_time_s),
                        "max_solver_time_s >= 0");
  }
}

void StageIIOptions::Validate() const {
  if (!(data_weight > 0) || !(marker_norm > 0)) {
    throw InvalidOption("stageii.data_weight",
                        std::to_string(data_weight),
                        "data_weight > 0 and marker_norm > 0");
  }
  if (!(prior_weight >= 0) || !(missing_prior_gain >= 0) ||
      !(velocity_weight >= 0)) {
    throw InvalidOption("stageii.prior_weight",
                        std::to_string(prior_weight),
                        "prior, missing-gain and velocity weights >= 0");
  }
  if (first_frame_prior_scales.empty()) {
    throw InvalidOption(
        "stageii.first_frame_prior_scales", "[]", "at least one scale");
  }
  if (min_markers < 3) {
    throw InvalidOption("stageii.min_markers",
                        std::to_string(min_markers),
                        "min_markers >= 3 (rigid initialisation)");
  }
  if (max_gap < 0) {
    throw InvalidOption(
        "stageii.max_gap", std::to_string(max_gap), "max_gap >= 0");
  }
  data.Validate("stageii");
  solver.Validate();
}

ceres::Solver::Options ToCeresOptions(const SolverOptions& options) {
  options.Validate();
  ceres::Solver::Options ceres_options;
  ceres_options.trust_region_strategy_type = options.trust_region == "dogleg"
                                                 ? ceres::DOGLEG
                                                 : ceres::LEVENBERG_MARQUARDT;
  if (options.linear_solver == "dense_qr") {
    ceres_options.linear_solver_type = ceres::DENSE_QR;
  } else if (options.linear_solver == "dense_normal_cholesky") {
    ceres_options.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
  } else if (options.linear_solver == "sparse_normal_cholesky") {
    ceres_options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  } else {
    ceres_options.linear_solver_type = ceres::DENSE_SCHUR;
  }
  ceres_options.max_num_iterations = options.max_iterations;
  ceres_options.function_tolerance = options.function_tolerance;
  ceres_options.parameter_tolerance = options.parameter_tolerance;
  ceres_options.gradient_tolerance = options.gradient_tolerance;
  ceres_options.num_threads = options.num_threads;
  if (options.max_solver_time_s > 0) {
    ceres_options.max_solver_time_in_seconds = options.max_solver_time_s;
  }
  ceres_options.logging_type = ceres::SILENT;
  ceres_options.minimizer_progress_to_stdout = false;
  std::string error;
  SOMA_CHECK(ceres_options.IsValid(&error)) << error;
  return ceres_options;
}

std::vector<int> FixedFrameEntries(int num_joints, bool optimize_toes) {
  std::vector<int> fixed;
  if (!optimize_toes && num_joints >= kNumCoreJoints) {
    for (int joint :
         {static_cast<int>(kLeftFoot), static_cast<int>(kRightFoot)}) {
      for (int c = 0; c < 3; ++c) fixed.push_back(3 + 3 * joint + c);
    }
  }
  return fixed;
}

std::vector<int> ObservedMarkers(const Eigen::Matrix3Xd& observed) {
  std::vector<int> markers;
  for (int m = 0; m < observed.cols(); ++m) {
    if (observed.col(m).allFinite()) markers.push_back(m);
  }
  return markers;
}

StageIISolver::StageIISolver(const MarkerModel* model,
                             const PosePrior* prior,
                             StageIIOptions options)
    : model_(model), prior_(prior), options_(std::move(options)) {
  options_.Validate();
  if (prior_ != nullptr && prior_->num_dofs() != model_->frame_size() - 6) {
    throw ShapeError(fmt::format(
        "StageIISolver: pose prior has {} dofs, the body pose {} (prior built "
        "for another body?)",
        prior_->num_dofs(),
        model_->frame_size() - 6));
  }
  fixed_indices_ =
      FixedFrameEntries(model_->num_joints(), options_.optimize_toes);
}

void StageIISolver::Reset() {
  history_.clear();
  noise_sigmas_.resize(0);
  gap_ = 0;
}

Eigen::VectorXd RigidInitFrame(const MarkerModel& model,
                               const std::vector<int>& markers,
                               const Eigen::Matrix3Xd& observed) {
  Eigen::VectorXd params = Eigen::VectorXd::Zero(model.frame_size());
  Eigen::Matrix3Xd rest;
  model.Evaluate(params.data(), markers, &rest, nullptr);
  Eigen::Matrix3Xd target(3, markers.size());
  for (size_t i = 0; i < markers.size(); ++i) {
    target.col(i) = observed.col(markers[i]);
  }
  const Eigen::Isometry3d align = KabschAlign(rest, target);
  const Eigen::AngleAxisd aa(align.linear());
  params.segment<3>(3) = aa.angle() * aa.axis();
  // p = R (x - r0) + r0 + t must equal R x + s: t = s - r0 + R r0.
  const Eigen::Vector3d r0 = model.RestJoints(model.betas()).col(0);
  params.head<3>() = align.translation() - r0 + align.linear() * r0;
  return params;
}

SolveSummary StageIISolver::RunSolve(const std::vector<int>& markers,
                                     const Eigen::Matrix3Xd& observed,
                                     double prior_scale,
                                     bool velocity,
                                     bool free_sigma,
                                     Eigen::VectorXd* params) {
  const int num_markers = model_->num_markers();
  const int used = static_cast<int>(markers.size());
  const int missing = num_markers - used;
  Eigen::Matrix3Xd obs(3, used);
  for (int i = 0; i < used; ++i) obs.col(i) = observed.col(markers[i]);

  ceres::Problem problem;
  double* x = params->data();
  const double weight = options_.data_weight * options_.marker_norm / used;
  const DataTermOptions& data = options_.data;
  std::vector<double> log_sigma;
  if (data.noise_aware()) {
    // One block per marker with its own log sigma (Noise-in Bias-out Eq. 6).
    // Warm start from the previous frame's sigmas (data_loss_scale for a
    // marker without one); held constant while the pose is still far off
    // (all but the last of the first frame's prior scales).
    log_sigma.assign(used, std::log(data.data_loss_scale));
    if (noise_sigmas_.size() == num_markers) {
      for (int i = 0; i < used; ++i) {
        const double sigma = noise_sigmas_(markers[i]);
        if (std::isfinite(sigma)) {
          log_sigma[i] = std::log(std::max(sigma, data.noise_sigma_min));
        }
      }
    }
    for (int i = 0; i < used; ++i) {
      problem.AddResidualBlock(
          new NoiseAwareMarkerCost(
              new MarkerDataCost(model_, {markers[i]}, obs.col(i), weight),
              weight,
              data.data_loss_scale,
              data.noise_sigma_min),
          nullptr,
          x,
          &log_sigma[i]);
      problem.SetParameterLowerBound(
          &log_sigma[i], 0, std::log(data.noise_sigma_min));
      if (!free_sigma) problem.SetParameterBlockConstant(&log_sigma[i]);
    }
  } else if (data.data_loss != "squared") {
    // The robust loss acts per marker: one residual block each.
    for (int i = 0; i < used; ++i) {
      problem.AddResidualBlock(
          new MarkerDataCost(model_, {markers[i]}, obs.col(i), weight),
          MakeDataLoss(data, weight),
          x);
    }
  } else {
    problem.AddResidualBlock(
        new MarkerDataCost(model_, markers, obs, weight), nullptr, x);
  }
  if (prior_ != nullptr && options_.prior_weight > 0) {
    const double c = 1.0 + options_.missing_prior_gain * missing /
                               static_cast<double>(num_markers);
    problem.AddResidualBlock(
        new PosePriorCost(prior_,
                          model_->frame_size(),
                          options_.prior_weight * c * prior_scale),
        nullptr,
        x);
  }
  if (velocity && history_.size() >= 2 && options_.velocity_weight > 0) {
    problem.AddResidualBlock(
        MakePoseVelocityCost(2.0 * history_[0] - history_[1],
                             options_.velocity_weight),
        nullptr,
        x);
  }
  if (!fixed_indices_.empty()) {
    problem.SetManifold(
        x, new ceres::SubsetManifold(model_->frame_size(), fixed_indices_));
  }
  const ceres::Solver::Options ceres_options = ToCeresOptions(options_.solver);
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(ceres_options, &problem, &ceres_summary);

  SolveSummary summary = FromCeresSummary(ceres_summary);
  if (data.noise_aware()) {
    noise_sigmas_ = Eigen::VectorXd::Constant(
        num_markers, std::numeric_limits<double>::quiet_NaN());
    for (int i = 0; i < used; ++i) {
      noise_sigmas_(markers[i]) = std::exp(log_sigma[i]);
    }
  }
  if (!params->allFinite()) {
    summary.termination = SolveTermination::kFailure;
    summary.message = "non-finite parameters after the solve";
  }
  return summary;
}

SolveSummary StageIISolver::SolveFrame(int frame_index,
                                       const Eigen::Matrix3Xd& observed,
                                       Eigen::VectorXd* params) {
  if (observed.cols() != model_->num_markers()) {
    throw ShapeError(fmt::format(
        "StageIISolver: frame {} has {} marker columns, the layout {}",
        frame_index,
        observed.cols(),
        model_->num_markers()));
  }
  const Timer timer;
  const std::vector<int> markers = ObservedMarkers(observed);
  SolveSummary summary;
  summary.frame = frame_index;
  summary.markers_used = static_cast<int>(markers.size());
  summary.markers_missing = model_->num_markers() - summary.markers_used;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (summary.markers_used < options_.min_markers) {
    summary.termination = SolveTermination::kSkipped;
    summary.skipped_reason = "too_few_markers";
    summary.message = fmt::format("{} observed markers < min_markers {}",
                                  summary.markers_used,
                                  options_.min_markers);
    *params = Eigen::VectorXd::Constant(model_->frame_size(), nan);
    ++gap_;
    if (gap_ > options_.max_gap) history_.clear();
    // A gap breaks the constant-velocity extrapolation.
    if (history_.size() > 1) history_.resize(1);
    summary.time_s = timer.ElapsedSeconds();
    return summary;
  }
  SolveSummary total;
  if (history_.empty()) {
    *params = RigidInitFrame(*model_, markers, observed);
    noise_sigmas_.resize(0);
    const std::vector<double>& scales = options_.first_frame_prior_scales;
    for (size_t k = 0; k < scales.size(); ++k) {
      total.Accumulate(RunSolve(
          markers, observed, scales[k], false, k + 1 == scales.size(), params));
      if (!total.usable()) break;
    }
  } else {
    *params = history_[0];
    total.Accumulate(RunSolve(markers, observed, 1.0, true, true, params));
  }
  summary.termination = total.termination;
  summary.message = total.message;
  summary.initial_cost = total.initial_cost;
  summary.final_cost = total.final_cost;
  summary.iterations = total.iterations;
  summary.solves = total.solves;
  if (summary.usable()) {
    Eigen::Matrix3Xd sim;
    model_->Evaluate(params->data(), markers, &sim, nullptr);
    double sq = 0.0;
    for (int i = 0; i < summary.markers_used; ++i) {
      sq += (sim.col(i) - observed.col(markers[i])).squaredNorm();
    }
    summary.rms_m = std::sqrt(sq / summary.markers_used);
    history_.insert(history_.begin(), *params);
    if (history_.size() > 2) history_.resize(2);
    gap_ = 0;
  } else {
    *params = Eigen::VectorXd::Constant(model_->frame_size(), nan);
    history_.clear();
  }
  summary.time_s = timer.ElapsedSeconds();
  return summary;
}

}  // namespace soma
