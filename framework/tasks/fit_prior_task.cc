// `soma fit_prior`: fits MoSh++'s Gaussian-mixture pose prior to the joint
// rotations of motion clips (the `task.sources` list of motion sources:
// procedural library, BVH, ASF/AMC, AMASS) retargeted onto the body, and
// writes it as HDF5 (gaussian_mixture.h) with the body, joints and sources
// as metadata. Every `holdout_every`-th clip of each source is held out and
// scored under the mixture and under a single Gaussian fitted the same way
// (metrics heldout_loglik, heldout_loglik_gaussian: mean log-density per
// pose), so the value of the mixture is measured.
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"
#include "framework/solve/gaussian_mixture.h"
#include "framework/solve/pose_prior.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

#include <cmath>

namespace soma {
namespace {

struct FitPriorOptions {
  std::string output = "pose_prior.h5";
  double frame_rate = 30.0;
  int frame_stride = 2;
  int holdout_every = 5;
  GmmFitOptions gmm;
  std::vector<ConfigNode> sources;  // motion source configs
};

Eigen::MatrixXd Concatenate(const std::vector<Eigen::MatrixXd>& blocks,
                            int rows) {
  Eigen::Index cols = 0;
  for (const Eigen::MatrixXd& b : blocks) cols += b.cols();
  Eigen::MatrixXd all(rows, cols);
  cols = 0;
  for (const Eigen::MatrixXd& b : blocks) {
    all.middleCols(cols, b.cols()) = b;
    cols += b.cols();
  }
  return all;
}

class FitPriorTask : public Task {
 public:
  explicit FitPriorTask(FitPriorOptions options)
      : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const BodyModel body = BuildBody(cfg, build);
    const int rows = 3 * (body.num_joints() - 1);
    std::vector<Eigen::MatrixXd> fit_blocks;
    std::vector<Eigen::MatrixXd> held_blocks;
    std::vector<std::string> sources;
    for (const ConfigNode& node : options_.sources) {
      const std::unique_ptr<MotionSource> source =
          Instantiate<MotionSource>(node, build);
      Rng rng =
          build.RootRng().Stream(fmt::format("fit_prior/{}", node.path()));
      const std::vector<PoseSequence> clips =
          source->Load(body, Split::kTrain, options_.frame_rate, rng);
      std::vector<PoseSequence> fit;
      std::vector<PoseSequence> held;
      for (size_t c = 0; c < clips.size(); ++c) {
        const bool hold = options_.holdout_every > 0 &&
                          c % options_.holdout_every ==
                              static_cast<size_t>(options_.holdout_every - 1);
        (hold ? held : fit).push_back(clips[c]);
      }
      fit_blocks.push_back(
          BodyPoseSamples(fit, body.num_joints(), options_.frame_stride));
      held_blocks.push_back(
          BodyPoseSamples(held, body.num_joints(), options_.frame_stride));
      const std::string target = internal::TargetKey(node);
      SOMA_LOG(INFO,
               "fit_prior: {}: {} clips ({} held out), {} + {} poses",
               target,
               clips.size(),
               held.size(),
               fit_blocks.back().cols(),
               held_blocks.back().cols());
      sources.push_back(fmt::format(
          "{}: {} clips, {} held out", target, clips.size(), held.size()));
    }
    const Eigen::MatrixXd samples = Concatenate(fit_blocks, rows);
    const Eigen::MatrixXd held_out = Concatenate(held_blocks, rows);

    GmmFitReport report;
    GaussianMixture gmm = FitGaussianMixture(samples, options_.gmm, &report);
    SOMA_LOG(INFO,
             "fit_prior: {} components on {} poses of {} dofs: {} EM "
             "iterations ({}), mean log-likelihood {:.2f}",
             options_.gmm.components,
             samples.cols(),
             rows,
             report.iterations,
             report.converged ? "converged" : "not converged",
             report.mean_log_likelihood);
    GmmFitOptions single = options_.gmm;
    single.components = 1;
    const GaussianMixture gaussian = FitGaussianMixture(samples, single);

    gmm.metadata["body"] = {body.name};
    gmm.metadata["joint_names"] = body.joint_names;
    gmm.metadata["sources"] = sources;
    gmm.metadata["fit"] = {
        fmt::format("{} poses, frame_rate {}, frame_stride {}, components {}, "
                    "min_stddev {}, seed {}, EM iterations {}",
                    samples.cols(),
                    options_.frame_rate,
                    options_.frame_stride,
                    options_.gmm.components,
                    options_.gmm.min_stddev,
                    options_.gmm.seed,
                    report.iterations)};
    std::filesystem::path output(options_.output);
    if (output.is_relative()) output = ctx.output_dir / output;
    WriteGaussianMixture(output, gmm);
    SOMA_LOG(INFO, "fit_prior: wrote {}", output.string());

    ctx.ReportMetric("poses", static_cast<double>(samples.cols()));
    ctx.ReportMetric("heldout_poses", static_cast<double>(held_out.cols()));
    ctx.ReportMetric("em_iterations", report.iterations);
    ctx.ReportMetric("train_loglik", report.mean_log_likelihood);
    ctx.ReportMetric("train_loglik_gaussian",
                     gaussian.LogDensity(samples).mean());
    if (held_out.cols() > 0) {
      ctx.ReportMetric("heldout_loglik", gmm.LogDensity(held_out).mean());
      ctx.ReportMetric("heldout_loglik_gaussian",
                       gaussian.LogDensity(held_out).mean());
    }
  }

 private:
  FitPriorOptions options_;
};

}  // namespace

void RegisterFitPriorTask(Registry<Task>& registry) {
  registry.Register("fit_prior", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    FitPriorOptions o;
    reader.Read("output", &o.output);
    reader.Read("frame_rate", &o.frame_rate);
    reader.Read("frame_stride", &o.frame_stride);
    reader.Read("holdout_every", &o.holdout_every);
    if (const ConfigNode* gmm = reader.Child("gmm")) {
      ConfigReader g(*gmm);
      g.Read("components", &o.gmm.components);
      g.Read("max_iterations", &o.gmm.max_iterations);
      g.Read("tolerance", &o.gmm.tolerance);
      g.Read("min_stddev", &o.gmm.min_stddev);
      g.Read("seed", &o.gmm.seed);
      g.Finish();
    }
    const ConfigNode* sources = reader.Child("sources");
    if (sources == nullptr || !sources->IsList() || sources->size() == 0) {
      throw ConfigError(
          "Invalid configuration. task.sources: expected a non-empty list of "
          "motion sources (configs/motion/ options)");
    }
    for (const ConfigNode& item : sources->items()) o.sources.push_back(item);
    reader.Finish();
    o.gmm.Validate();
    if (!(o.frame_rate > 0) || o.frame_stride < 1 || o.holdout_every < 0 ||
        o.holdout_every == 1) {
      throw ConfigError(fmt::format(
          "Invalid configuration. task.frame_rate/frame_stride/holdout_every "
          "= {}/{}/{}. Violated constraint: frame_rate > 0, frame_stride >= "
          "1, holdout_every = 0 or >= 2 (fit_prior_task.cc)",
          o.frame_rate,
          o.frame_stride,
          o.holdout_every));
    }
    return std::make_unique<FitPriorTask>(std::move(o));
  });
}

}  // namespace soma
