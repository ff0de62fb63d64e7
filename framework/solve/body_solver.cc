#include "framework/solve/body_solver.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/core/timer.h"

#include <fmt/format.h>

#include <algorithm>
#include <exception>
#include <thread>

namespace soma {
namespace {

/// The data-term keys shared by `stagei` and `stageii` (DataTermOptions).
void ReadDataTermOptions(ConfigReader& reader, DataTermOptions* data) {
  reader.Read("data_term", &data->data_term);
  reader.Read("data_loss", &data->data_loss);
  reader.Read("data_loss_scale", &data->data_loss_scale);
  reader.Read("noise_sigma_min", &data->noise_sigma_min);
}

void DecodeSolver(const ConfigNode& node, SolverOptions* o) {
  ConfigReader r(node);
  r.Read("trust_region", &o->trust_region);
  r.Read("linear_solver", &o->linear_solver);
  r.Read("max_iterations", &o->max_iterations);
  r.Read("max_solver_time_s", &o->max_solver_time_s);
  r.Read("function_tolerance", &o->function_tolerance);
  r.Read("parameter_tolerance", &o->parameter_tolerance);
  r.Read("gradient_tolerance", &o->gradient_tolerance);
  r.Read("num_threads", &o->num_threads);
  r.Finish();
}

}  // namespace

void BodySolveOptions::Validate() const {
  if (threads < 1 || threads > 256) {
    throw ConfigError(fmt::format(
        "Invalid configuration. solver.threads = {}. Violated constraint: "
        "1 <= threads <= 256 (body_solver.cc)",
        threads));
  }
  if (start < 0 || stride < 1 || (end >= 0 && end <= start)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. solver.start/end/stride = {}/{}/{}. Violated "
        "constraint: start >= 0, end = -1 or end > start, stride >= 1 "
        "(body_solver.cc)",
        start,
        end,
        stride));
  }
  stagei.Validate();
  stageii.Validate();
}

BodySolveOptions DecodeBodySolveOptions(const ConfigNode& node) {
  BodySolveOptions o;
  ConfigReader r(node);
  r.Read("start", &o.start);
  r.Read("end", &o.end);
  r.Read("stride", &o.stride);
  r.Read("threads", &o.threads);
  if (const ConfigNode* c = r.Child("ceres")) {
    DecodeSolver(*c, &o.stageii.solver);
    const std::string linear = o.stagei.solver.linear_solver;
    DecodeSolver(*c, &o.stagei.solver);
    // Stage I couples frames through the shape: keep its Schur solver
    // (dense_schur) when the stage II default dense_qr is given.
    if (o.stagei.solver.linear_solver == "dense_qr") {
      o.stagei.solver.linear_solver = linear;
    }
  }
  if (const ConfigNode* c = r.Child("stagei")) {
    ConfigReader s(*c);
    StageIOptions& x = o.stagei;
    s.Read("num_frames", &x.num_frames);
    s.Read("min_available", &x.min_available);
    s.Read("min_available_floor", &x.min_available_floor);
    s.Read("seed", &x.seed);
    s.Read("annealing", &x.annealing);
    s.Read("data_weight", &x.data_weight);
    s.Read("marker_norm", &x.marker_norm);
    s.Read("prior_weight", &x.prior_weight);
    s.Read("init_weight", &x.init_weight);
    s.Read("beta_weight", &x.beta_weight);
    s.Read("surface_weight", &x.surface_weight);
    s.Read("optimize_betas", &x.optimize_betas);
    s.Read("optimize_toes", &x.optimize_toes);
    ReadDataTermOptions(s, &x.data);
    s.Finish();
  }
  if (const ConfigNode* c = r.Child("stageii")) {
    ConfigReader s(*c);
    StageIIOptions& x = o.stageii;
    s.Read("data_weight", &x.data_weight);
    s.Read("marker_norm", &x.marker_norm);
    s.Read("prior_weight", &x.prior_weight);
    s.Read("missing_prior_gain", &x.missing_prior_gain);
    s.Read("velocity_weight", &x.velocity_weight);
    s.Read("first_frame_prior_scales", &x.first_frame_prior_scales);
    s.Read("min_markers", &x.min_markers);
    s.Read("max_gap", &x.max_gap);
    s.Read("optimize_toes", &x.optimize_toes);
    ReadDataTermOptions(s, &x.data);
    s.Finish();
  }
  r.Finish();
  o.Validate();
  return o;
}

BodySolveResult SolveBody(const BodyModel& body,
                          const MarkerLayout& layout,
                          const LabelledMarkers& markers,
                          const PosePrior* prior,
                          const BodySolveOptions& options) {
  options.Validate();
  if (static_cast<int>(markers.labels.size()) != layout.num_markers()) {
    throw ShapeError("SolveBody: markers were matched to another layout");
  }
  if (markers.num_frames() == 0) throw Error("SolveBody: no frames");
  const auto [vids, distances] = MarkerVertices(layout);
  MarkerModel model(body, vids);

  BodySolveResult result;
  const std::vector<int> picked =
      PickStageIFrames(markers.frames, options.stagei);
  std::vector<Eigen::Matrix3Xd> stagei_frames;
  stagei_frames.reserve(picked.size());
  for (int f : picked) stagei_frames.push_back(markers.frames[f]);
  result.stagei = SolveStageI(
      body, &model, distances, stagei_frames, prior, options.stagei);
  result.stagei.frames = picked;
  SOMA_LOG(INFO,
           "solve: stage I on {} frames: {}",
           picked.size(),
           result.stagei.summary.BriefReport());
  if (result.stagei.noise_sigmas.size() > 0) {
    const Eigen::VectorXd& sigma = result.stagei.noise_sigmas;
    SOMA_LOG(
        INFO,
        "solve: stage I noise-aware sigma_m: median {:.1f} mm, max "
        "{:.1f} mm",
        1e3 *
            [&] {
              std::vector<double> v(sigma.data(), sigma.data() + sigma.size());
              std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
              return v[v.size() / 2];
            }(),
        1e3 * sigma.maxCoeff());
  }
  if (!result.stagei.summary.usable()) {
    throw Error(fmt::format("solve: stage I failed: {}",
                            result.stagei.summary.message));
  }

  SolveOutput& out = result.output;
  out.body = body.name;
  out.joint_names = body.joint_names;
  out.labels = markers.labels;
  out.frame_rate = markers.frame_rate / options.stride;
  out.betas = result.stagei.betas;
  out.markers_latent = model.latent_markers();
  out.marker_offsets = model.offsets();
  out.marker_vertex_ids = vids;
  out.stagei_frames = picked;

  const int end = options.end < 0 ? markers.num_frames()
                                  : std::min(options.end, markers.num_frames());
  std::vector<int> frames;
  for (int t = options.start; t < end; t += options.stride) frames.push_back(t);
  const int count = static_cast<int>(frames.size());
  out.frame_params.resize(count);
  out.observed.resize(count);
  out.simulated.resize(count);
  out.summaries.resize(count);
  const Timer timer;
  // Contiguous chunks, one StageIISolver (warm-start history) each.
  const auto solve_chunk = [&](int begin, int stop) {
    StageIISolver solver(&model, prior, options.stageii);
    for (int i = begin; i < stop; ++i) {
      const int t = frames[i];
      Eigen::VectorXd params;
      SolveSummary summary = solver.SolveFrame(t, markers.frames[t], &params);
      Eigen::Matrix3Xd sim =
          Eigen::Matrix3Xd::Constant(3, model.num_markers(), std::nan(""));
      if (summary.usable()) model.Evaluate(params.data(), {}, &sim, nullptr);
      if (summary.termination != SolveTermination::kConverged) {
        SOMA_LOG(DEBUG, "solve: {}", summary.BriefReport());
      }
      out.frame_params[i] = std::move(params);
      out.observed[i] = markers.frames[t];
      out.simulated[i] = std::move(sim);
      out.summaries[i] = std::move(summary);
    }
  };
  const int threads = std::max(1, std::min(options.threads, count));
  if (threads == 1) {
    solve_chunk(0, count);
  } else {
    std::vector<std::thread> workers;
    std::vector<std::exception_ptr> errors(threads);
    for (int k = 0; k < threads; ++k) {
      const int begin = static_cast<int>(int64_t{count} * k / threads);
      const int stop = static_cast<int>(int64_t{count} * (k + 1) / threads);
      workers.emplace_back([&, k, begin, stop] {
        try {
          solve_chunk(begin, stop);
        } catch (...) {
          errors[k] = std::current_exception();
        }
      });
    }
    for (std::thread& w : workers) w.join();
    for (const std::exception_ptr& e : errors) {
      if (e) std::rethrow_exception(e);
    }
  }
  const double seconds = timer.ElapsedSeconds();
  result.stats = Summarize(out.summaries);
  result.stageii_frames_per_s =
      seconds > 0 ? out.summaries.size() / seconds : 0.0;
  SOMA_LOG(INFO,
           "solve: stage II {} ({:.0f} frames/s)",
           result.stats.BriefReport(),
           result.stageii_frames_per_s);
  return result;
}

}  // namespace soma
