// `soma attention_span`: SOMA's Appendix A, the self-attention span per
// layer of trained labelers, in metres (framework/eval/attention_span.h).
//
//   soma attention_span 'task.checkpoints=[s0/best.pt,s1/best.pt]'
//
// For each checkpoint: the real labelled take `task.input` (default the
// HDM05 take) is passed through the network without noise, points ordered
// by the model's labels, on up to `max_frames` frames that have every model
// label (drawn with `seed`); per layer the attention weights are maxed over
// heads and averaged over frames (the paper's procedure), then weighted by
// the distances between the markers on the body (`body` group) in an A-pose
// (arms lowered by `arm_angle_deg` from the rest T-pose). The markers are
// placed by the layout each model was trained on (the `layout` group of its
// run's .hydra/config.yaml) when `use_training_layout` and that file exists,
// else by this run's `layout` group. Writes attention_span.md (per layer: the
// span of every model, mean +- std over models, and the paper's claim, "the
// span narrows with depth", checked per model), attention_span.csv and
// attention_span.png.
#include "framework/body/marker_layout.h"
#include "framework/config/decode.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/plot.h"
#include "framework/eval/attention_span.h"
#include "framework/io/c3d.h"
#include "framework/model/labeler.h"
#include "framework/model/mean_attention.h"
#include "framework/model/torch_utils.h"
#include "framework/registry/registry.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"
#include "framework/train/trainer.h"

#include <fmt/format.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <optional>
#include <sstream>

namespace soma {
namespace {

struct AttentionSpanOptions {
  std::vector<std::string> checkpoints;
  std::string input;
  int max_frames = 2000;
  uint64_t seed = 0;
  double arm_angle_deg = 45.0;
  int batch_size = 256;
  bool use_training_layout = true;
};

/// The `layout` group of the run that trained `checkpoint`, from
/// <run>/.hydra/config.yaml (`soma train` writes checkpoints to
/// <run>/checkpoints/), or nullopt when that file or its group is missing
/// (e.g. a checkpoint copied out of its run). `config` receives the file.
std::optional<ConfigNode> TrainingLayoutGroup(const std::string& checkpoint,
                                              std::filesystem::path* config) {
  *config = std::filesystem::path(checkpoint).parent_path().parent_path() /
            ".hydra" / "config.yaml";
  if (!std::filesystem::is_regular_file(*config)) return std::nullopt;
  const ConfigNode root = ParseYaml(ReadFile(*config), config->string());
  const ConfigNode* layout = root.Find("layout");
  if (layout == nullptr) return std::nullopt;
  return *layout;
}

/// SelectCompleteFrames as a `F x L x 3` float tensor.
torch::Tensor CompleteFrameTensor(const C3dData& c3d,
                                  const std::vector<std::string>& labels,
                                  const std::string& source,
                                  int max_frames,
                                  uint64_t seed) {
  CompleteFrames complete =
      SelectCompleteFrames(c3d, labels, source, max_frames, seed);
  return torch::from_blob(complete.points.data(),
                          {static_cast<int64_t>(complete.frames.size()),
                           static_cast<int64_t>(labels.size()),
                           3},
                          torch::kFloat)
      .clone();
}

class AttentionSpanTask : public Task {
 public:
  explicit AttentionSpanTask(AttentionSpanOptions options)
      : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    if (const ConfigNode* threads = cfg.Find("threads")) {
      SetTorchThreads(static_cast<int>(threads->AsInt()));
    }
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const BodyModel body = BuildBody(cfg, build);
    const C3dData c3d = ReadC3d(options_.input);

    // spans[model][layer]
    std::vector<std::vector<AttentionSpanLayer>> spans;
    std::vector<std::string> labels;
    std::vector<std::string> layouts;  // per model: which layout, and why
    int64_t frames_used = 0;
    double uniform_span_m = 0.0;
    for (const std::string& checkpoint : options_.checkpoints) {
      const CheckpointInfo info = ReadCheckpointInfo(checkpoint);
      if (!labels.empty() && info.labels != labels) {
        throw ConfigError(fmt::format(
            "attention_span: {} has other labels than {} (compare models "
            "of one layout)",
            checkpoint,
            options_.checkpoints.front()));
      }
      labels = info.labels;
      Labeler model = LoadLabelerFromCheckpoint(checkpoint);
      const torch::Tensor points = CompleteFrameTensor(
          c3d, labels, options_.input, options_.max_frames, options_.seed);
      frames_used = points.size(0);
      const MarkerLayout layout =
          ModelLayout(cfg, checkpoint, body, build, &layouts.emplace_back());
      const Eigen::MatrixXd distances = PairwiseDistances(
          APoseMarkers(body, layout, labels, options_.arm_angle_deg));
      spans.push_back(ComputeAttentionSpan(
          MeanAttention(*model, points, options_.batch_size), distances));
      // Reference: attention spread evenly over every marker.
      uniform_span_m =
          ComputeAttentionSpan(
              {Eigen::MatrixXd::Ones(distances.rows(), distances.cols())},
              distances)
              .front()
              .mean_m;
      std::string line;
      for (const AttentionSpanLayer& l : spans.back()) {
        line += fmt::format(" {:.3f}", l.mean_m);
      }
      SOMA_LOG(INFO,
               "attention_span: {}: {} frames, span per layer (m):{}",
               checkpoint,
               frames_used,
               line);
    }
    Write(spans, layouts, frames_used, uniform_span_m, ctx);
  }

 private:
  /// The layout that places the markers of `checkpoint`'s model: its
  /// training run's `layout` group if `use_training_layout` and the run's
  /// config exists, else this run's. `described` receives the choice, e.g.
  /// "`{name: file, path: a.json}` (the layout of <run>/.hydra/config.yaml)".
  MarkerLayout ModelLayout(const ConfigNode& cfg,
                           const std::string& checkpoint,
                           const BodyModel& body,
                           BuildContext& build,
                           std::string* described) const {
    std::filesystem::path config;
    std::optional<ConfigNode> trained;
    if (options_.use_training_layout) {
      trained = TrainingLayoutGroup(checkpoint, &config);
    }
    if (!trained) {
      const ConfigNode* group = cfg.Find("layout");
      *described = fmt::format("`{}` (this run's layout group{})",
                               group ? DumpFlow(*group) : "none",
                               options_.use_training_layout
                                   ? fmt::format(": no {}", config.string())
                                   : "");
      SOMA_LOG(INFO, "attention_span: {}: layout {}", checkpoint, *described);
      return BuildLayout(cfg, body, build);
    }
    *described = fmt::format(
        "`{}` (the layout of {})", DumpFlow(*trained), config.string());
    SOMA_LOG(INFO, "attention_span: {}: layout {}", checkpoint, *described);
    ConfigNode model_cfg = cfg;
    model_cfg.Set("layout", *trained);
    return BuildLayout(model_cfg, body, build);
  }

  void Write(const std::vector<std::vector<AttentionSpanLayer>>& spans,
             const std::vector<std::string>& layouts,
             int64_t frames_used,
             double uniform_span_m,
             RunContext& ctx) const {
    const size_t models = spans.size();
    const size_t layers = spans.front().size();
    std::ostringstream csv;
    csv << "model,checkpoint,layer,span_m,ci95_m\n";
    for (size_t m = 0; m < models; ++m) {
      if (spans[m].size() != layers) {
        throw ConfigError(
            "attention_span: the models have different numbers of layers");
      }
      for (size_t l = 0; l < layers; ++l) {
        csv << fmt::format("{},{},{},{:.6f},{:.6f}\n",
                           m,
                           options_.checkpoints[m],
                           l + 1,
                           spans[m][l].mean_m,
                           spans[m][l].ci95_m);
      }
    }
    WriteFileAtomic(ctx.output_dir / "attention_span.csv", csv.str());

    std::ostringstream md;
    md << "# Self-attention span per layer (SOMA Appendix A)\n\n";
    md << fmt::format(
        "Take `{}`, {} frames with every label, no noise; attention maxed "
        "over heads and averaged over frames; distances between the markers "
        "on the body in an A-pose (arms {} degrees below the T-pose). Span "
        "of a marker: attention-weighted mean distance to the others; a "
        "layer's span: the mean over markers (± its 95% interval over "
        "markers). Last column: mean ± sample std over the {} models.\n\n",
        options_.input,
        frames_used,
        options_.arm_angle_deg,
        models);
    md << "Marker layout of each model's distances:\n\n";
    for (size_t m = 0; m < models; ++m) {
      md << fmt::format("- model {}: {}\n", m, layouts[m]);
    }
    md << "\n| layer |";
    std::string rule = "|---|";
    for (size_t m = 0; m < models; ++m) {
      md << fmt::format(" model {} (m) |", m);
      rule += "---|";
    }
    md << " mean ± std (m) |\n" << rule << "---|\n";
    std::vector<PlotSeries> series(models);
    for (size_t l = 0; l < layers; ++l) {
      md << fmt::format("| {} |", l + 1);
      double sum = 0.0, sq = 0.0;
      for (size_t m = 0; m < models; ++m) {
        const double s = spans[m][l].mean_m;
        md << fmt::format(" {:.3f} ± {:.3f} |", s, spans[m][l].ci95_m);
        sum += s;
        sq += s * s;
        series[m].name = fmt::format("model {}", m);
        series[m].x.push_back(static_cast<double>(l + 1));
        series[m].y.push_back(s);
      }
      const double mean = sum / models;
      const double std =
          models > 1 ? std::sqrt(std::max(
                           0.0, (sq - models * mean * mean) / (models - 1)))
                     : 0.0;
      md << fmt::format(" {:.3f} ± {:.3f} |\n", mean, std);
      ctx.ReportMetric(fmt::format("span_layer{}_m", l + 1), mean);
    }
    int narrower = 0;
    for (size_t m = 0; m < models; ++m) {
      narrower += spans[m].back().mean_m < spans[m].front().mean_m ? 1 : 0;
    }
    md << fmt::format(
        "\nFor reference, attention spread evenly over all markers would "
        "give {:.3f} m.\n",
        uniform_span_m);
    md << fmt::format(
        "\nPaper's claim, \"the span narrows with depth\" (last layer "
        "narrower than the first): {} of {} models — {}.\n",
        narrower,
        models,
        narrower == static_cast<int>(models) ? "pass" : "fail");
    ctx.ReportMetric("models_narrowing", narrower);
    WriteFileAtomic(ctx.output_dir / "attention_span.md", md.str());
    PlotOptions plot;
    plot.title = "Self-attention span per layer";
    plot.x_label = "layer";
    plot.y_label = "span (m)";
    LinePlot(series, plot).WritePng(ctx.output_dir / "attention_span.png");
  }

  AttentionSpanOptions options_;
};

}  // namespace

void RegisterAttentionSpanTask(Registry<Task>& registry) {
  registry.Register(
      "attention_span", [](const ConfigNode& node, BuildContext&) {
        ConfigReader reader(node);
        AttentionSpanOptions o;
        reader.RequireOneOrMore("checkpoints", &o.checkpoints);
        reader.Require("input", &o.input);
        reader.Read("max_frames", &o.max_frames);
        reader.Read("seed", &o.seed);
        reader.Read("arm_angle_deg", &o.arm_angle_deg);
        reader.Read("batch_size", &o.batch_size);
        reader.Read("use_training_layout", &o.use_training_layout);
        reader.Check("checkpoints", !o.checkpoints.empty(), "one or more");
        reader.Check("max_frames", o.max_frames >= 1, "max_frames >= 1");
        reader.Check("batch_size", o.batch_size >= 1, "batch_size >= 1");
        reader.Finish();
        return std::make_unique<AttentionSpanTask>(std::move(o));
      });
}

}  // namespace soma
