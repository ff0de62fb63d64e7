#include "framework/solve/stage_i.h"

#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/core/timer.h"
#include "framework/solve/cost_functions.h"

#include <ceres/manifold.h>
#include <ceres/normal_prior.h>
#include <ceres/ordered_groups.h>
#include <ceres/problem.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>

namespace soma {

void StageIOptions::Validate() const {
  const auto bad = [](std::string_view key, double value, std::string_view c) {
    return ConfigError(fmt::format(
        "Invalid configuration. stagei.{} = {}. Violated constraint: {} "
        "(stage_i.cc)",
        key,
        value,
        c));
  };
  if (num_frames < 1) throw bad("num_frames", num_frames, "num_frames >= 1");
  if (!(min_available > 0 && min_available <= 1)) {
    throw bad("min_available", min_available, "0 < min_available <= 1");
  }
  if (!(min_available_floor > 0 && min_available_floor <= min_available)) {
    throw bad("min_available_floor",
              min_available_floor,
              "0 < min_available_floor <= min_available");
  }
  if (annealing.empty()) throw bad("annealing", 0, "at least one factor");
  for (double a : annealing) {
    if (!(a > 0)) throw bad("annealing", a, "factors > 0");
  }
  if (!(data_weight > 0) || !(marker_norm > 0)) {
    throw bad("data_weight", data_weight, "data_weight, marker_norm > 0");
  }
  if (!(prior_weight >= 0) || !(init_weight >= 0) || !(beta_weight >= 0) ||
      !(surface_weight >= 0)) {
    throw bad("prior_weight", prior_weight, "regulariser weights >= 0");
  }
  data.Validate("stagei");
  solver.Validate();
}

std::vector<int> PickStageIFrames(const std::vector<Eigen::Matrix3Xd>& frames,
                                  const StageIOptions& options) {
  options.Validate();
  std::vector<double> available(frames.size(), 0.0);
  double best = 0.0;
  for (size_t f = 0; f < frames.size(); ++f) {
    const int m = static_cast<int>(frames[f].cols());
    available[f] =
        m > 0 ? static_cast<double>(ObservedMarkers(frames[f]).size()) / m : 0;
    best = std::max(best, available[f]);
  }
  const int wanted =
      std::min<int>(options.num_frames, static_cast<int>(frames.size()));
  for (double threshold = options.min_available;
       threshold >= options.min_available_floor - 1e-9;
       threshold -= 0.01) {
    std::vector<int> candidates;
    for (size_t f = 0; f < frames.size(); ++f) {
      if (available[f] >= threshold - 1e-9) {
        candidates.push_back(static_cast<int>(f));
      }
    }
    if (static_cast<int>(candidates.size()) < wanted || candidates.empty()) {
      continue;
    }
    Rng rng(options.seed);
    const std::vector<int> pick = rng.SampleWithoutReplacement(
        static_cast<int>(candidates.size()), wanted);
    std::vector<int> out;
    out.reserve(pick.size());
    for (int i : pick) out.push_back(candidates[i]);
    std::sort(out.begin(), out.end());
    return out;
  }
  throw Error(fmt::format(
      "stage I: not enough frames: {} wanted with at least {:.0f}% of the "
      "markers; the best of {} frames has {:.0f}%",
      wanted,
      100 * options.min_available_floor,
      frames.size(),
      100 * best));
}

StageIResult SolveStageI(const BodyModel& body,
                         MarkerModel* model,
                         const std::vector<double>& distances,
                         const std::vector<Eigen::Matrix3Xd>& frames,
                         const PosePrior* prior,
                         const StageIOptions& options) {
  options.Validate();
  const Timer timer;
  const int num_markers = model->num_markers();
  const int num_betas = model->num_betas();
  const int frame_size = model->frame_size();
  if (static_cast<int>(distances.size()) != num_markers) {
    throw ShapeError(fmt::format(
        "stage I: {} distances for {} markers", distances.size(), num_markers));
  }
  if (frames.empty()) throw ShapeError("stage I: no frames");
  if (prior != nullptr && prior->num_dofs() != frame_size - 6) {
    throw ShapeError("stage I: pose prior built for another body");
  }
  std::vector<std::vector<int>> observed(frames.size());
  for (size_t f = 0; f < frames.size(); ++f) {
    if (frames[f].cols() != num_markers) {
      throw ShapeError(fmt::format("stage I: frame {} has {} markers, not {}",
                                   f,
                                   frames[f].cols(),
                                   num_markers));
    }
    observed[f] = ObservedMarkers(frames[f]);
    if (observed[f].size() < 3) {
      throw Error(
          fmt::format("stage I: frame {} has {} observed markers (needs >= 3)",
                      f,
                      observed[f].size()));
    }
  }

  // Initial shape: mean betas, offsets along the rest normals.
  StageIResult result;
  result.betas = Eigen::VectorXd::Zero(num_betas);
  const Eigen::Matrix3Xd initial_offsets =
      NormalOffsets(body, result.betas, model->vertex_ids(), distances);
  result.offsets = initial_offsets;
  model->SetShape(result.betas, result.offsets);
  for (size_t f = 0; f < frames.size(); ++f) {
    result.frame_params.push_back(
        RigidInitFrame(*model, observed[f], frames[f]));
  }
  // Surface term: n_m . o_m = d_m as A (o - b) with b = n_m d_m.
  const Eigen::Matrix3Xd unit_normals =
      NormalOffsets(body,
                    Eigen::VectorXd::Zero(num_betas),
                    model->vertex_ids(),
                    std::vector<double>(num_markers, 1.0));
  const std::vector<int> fixed =
      FixedFrameEntries(model->num_joints(), options.optimize_toes);
  const ceres::Solver::Options ceres_options = ToCeresOptions(options.solver);
  const DataTermOptions& data = options.data;
  std::vector<double> log_sigma(num_markers, std::log(data.data_loss_scale));

  for (size_t anneal_round = 0; anneal_round < options.annealing.size();
       ++anneal_round) {
    const double anneal = options.annealing[anneal_round];
    ceres::Problem problem;
    const double data_weight =
        options.data_weight / anneal * options.marker_norm / num_markers;
    double* betas = num_betas > 0 ? result.betas.data() : nullptr;
    for (size_t f = 0; f < frames.size(); ++f) {
      double* x = result.frame_params[f].data();
      Eigen::Matrix3Xd obs(3, observed[f].size());
      for (size_t i = 0; i < observed[f].size(); ++i) {
        obs.col(i) = frames[f].col(observed[f][i]);
      }
      if (num_betas == 0) {
        throw ShapeError("stage I: the body has no shape space");
      }
      // One residual block per marker: the normal equations stay sparse
      // (a marker couples its frame, the betas and only its own offset).
      for (size_t i = 0; i < observed[f].size(); ++i) {
        const int m = observed[f][i];
        auto* cost =
            new ShapeMarkerDataCost(model, {m}, obs.col(i), data_weight);
        if (data.noise_aware()) {
          problem.AddResidualBlock(
              new NoiseAwareMarkerCost(cost,
                                       data_weight,
                                       data.data_loss_scale,
                                       data.noise_sigma_min),
              nullptr,
              std::vector<double*>{
                  x, betas, result.offsets.col(m).data(), &log_sigma[m]});
          problem.SetParameterLowerBound(
              &log_sigma[m], 0, std::log(data.noise_sigma_min));
          // sigma stays at data_loss_scale in the first round (from the
          // rigid initialisation, large residuals are pose errors, not
          // noise) unless it is the only one.
          if (anneal_round == 0 && options.annealing.size() > 1) {
            problem.SetParameterBlockConstant(&log_sigma[m]);
          }
        } else {
          problem.AddResidualBlock(
              cost,
              MakeDataLoss(data, data_weight),
              std::vector<double*>{x, betas, result.offsets.col(m).data()});
        }
      }
      if (prior != nullptr && options.prior_weight > 0) {
        problem.AddResidualBlock(
            new PosePriorCost(prior, frame_size, options.prior_weight * anneal),
            nullptr,
            x);
      }
      if (!fixed.empty()) {
        problem.SetManifold(x, new ceres::SubsetManifold(frame_size, fixed));
      }
    }
    // init + surf per marker: A (o_m - o_m^0) with A = [w_init I; w_surf
    // n_m^T] (n_m . o_m^0 = d_m by construction).
    for (int m = 0; m < num_markers; ++m) {
      ceres::Matrix prior_a(4, 3);
      prior_a.topRows<3>() =
          ceres::Matrix::Identity(3, 3) * (options.init_weight * anneal);
      prior_a.row(3) = options.surface_weight * unit_normals.col(m).transpose();
      problem.AddResidualBlock(
          new ceres::NormalPrior(prior_a,
                                 ceres::Vector(initial_offsets.col(m))),
          nullptr,
          result.offsets.col(m).data());
    }
    problem.AddResidualBlock(
        new ceres::NormalPrior(ceres::Matrix::Identity(num_betas, num_betas) *
                                   (options.beta_weight * anneal),
                               ceres::Vector::Zero(num_betas)),
        nullptr,
        betas);
    if (!options.optimize_betas) problem.SetParameterBlockConstant(betas);

    // Schur elimination of the per-frame blocks (the shape blocks are few).
    ceres::Solver::Options round_options = ceres_options;
    auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
    for (Eigen::VectorXd& frame : result.frame_params) {
      ordering->AddElementToGroup(frame.data(), 0);
    }
    ordering->AddElementToGroup(betas, 1);
    for (int m = 0; m < num_markers; ++m) {
      ordering->AddElementToGroup(result.offsets.col(m).data(), 1);
      if (data.noise_aware() && problem.HasParameterBlock(&log_sigma[m])) {
        ordering->AddElementToGroup(&log_sigma[m], 1);
      }
    }
    round_options.linear_solver_ordering = ordering;
    ceres::Solver::Summary ceres_summary;
    ceres::Solve(round_options, &problem, &ceres_summary);
    const SolveSummary round = FromCeresSummary(ceres_summary);
    result.rounds.push_back(round);
    result.summary.Accumulate(round);
    if (!round.usable()) break;
  }

  if (data.noise_aware()) {
    result.noise_sigmas =
        Eigen::Map<const Eigen::VectorXd>(log_sigma.data(), num_markers)
            .array()
            .exp();
  }
  model->SetShape(result.betas, result.offsets);
  double sq = 0.0;
  int count = 0;
  for (size_t f = 0; f < frames.size(); ++f) {
    Eigen::Matrix3Xd sim;
    model->Evaluate(result.frame_params[f].data(), observed[f], &sim, nullptr);
    for (size_t i = 0; i < observed[f].size(); ++i) {
      sq += (sim.col(i) - frames[f].col(observed[f][i])).squaredNorm();
      ++count;
    }
  }
  result.summary.rms_m = std::sqrt(sq / count);
  result.summary.markers_used = count;
  result.summary.markers_missing =
      static_cast<int>(frames.size()) * num_markers - count;
  result.summary.time_s = timer.ElapsedSeconds();
  if (!result.betas.allFinite() || !result.offsets.allFinite()) {
    result.summary.termination = SolveTermination::kFailure;
    result.summary.message = "non-finite shape after stage I";
  }
  return result;
}

}  // namespace soma
