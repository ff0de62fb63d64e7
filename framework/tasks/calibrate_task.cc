// `soma calibrate`: fits the temperature T of a trained labeler's assignment
// probabilities on synthetic validation frames (issue #25 item 4; Guo et al.
// 2017 temperature scaling; framework/eval/calibration.h says where T
// enters: softmax(log p / T) per point row, after Sinkhorn, so labels never
// change).
//
//   soma calibrate task.model=cmu41          # a bundled model ->
//   models/cmu41/calibration.yaml soma calibrate
//   task.checkpoint=<run>/checkpoints/best.pt soma calibrate ...
//   task.output=elsewhere/calibration.yaml
//
// The frames are the training run's own validation set, rebuilt from the
// config stored in the checkpoint: the same body, layout, motion split
// (val), noise and synthesis options, the same seed stream
// (Rng(seed).Stream("data/val")) and, unless task.frames says otherwise, the
// same number of frames (train.val_frames). A layout file the stored config
// names by a path that does not exist here is taken from `layout.json`
// beside the checkpoint (bundled models carry theirs); `task.overrides`
// edits the stored config otherwise (`[layout.path=...]`).
//
// Per frame the labeler (the label task's FrameLabeler: permutation, fast
// path) gives every point a distribution over the L labels and null (a
// layout-conditioned model trained on sampled layouts: over the frame's own
// label slots, padded ones included, as `soma label` applies T), over
// every non-padding point (ghosts' true label: null).
//
// task.objective=nll (default) fits T by the least mean negative
// log-likelihood of the true labels, ece by the least expected calibration
// error of the given labels' confidences (FitTemperatureByEce): the NLL
// also weighs how little probability a wrong label left to the right one,
// and can soften confidences that a reliability diagram shows were right.
//
// Outputs: `calibration.yaml` (the run directory, and task.output: auto =
// beside the checkpoint, where `soma label` finds it), `reliability.csv` and
// `reliability.png` (on the fitting frames: the raw Sinkhorn rows, the rows
// renormalised (T = 1) and temperature scaled), metrics temperature,
// nll_before/after, ece_raw, ece_before (T = 1), ece_after.
#include "framework/config/decode.h"
#include "framework/config/override.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/provenance.h"
#include "framework/core/random.h"
#include "framework/core/timer.h"
#include "framework/eval/calibration.h"
#include "framework/model/inference.h"
#include "framework/model/label_encoder.h"
#include "framework/model/labeler.h"
#include "framework/model/torch_utils.h"
#include "framework/registry/registry.h"
#include "framework/synth/synthesizer.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"
#include "framework/train/batch_source.h"
#include "framework/train/model_zoo.h"
#include "framework/train/trainer.h"

#include <ATen/ATen.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace soma {
namespace {

namespace fs = std::filesystem;

struct CalibrateOptions {
  std::string checkpoint;  // empty: the bundled model `model`
  std::string model;       // a bundled model's name
  int64_t frames = 0;      // 0: the training's train.val_frames
  std::string output = "auto";
  std::vector<std::string> overrides;  // edits of the stored training config
  int num_bins = 15;
  /// What T minimises: nll (Guo et al.) or ece (FitTemperatureByEce).
  std::string objective = "nll";
  InferenceOptions inference;
};

/// Point `n` of a frame's `xyz` is (0,0,0): padding or an occluded marker.
bool IsMissing(const float* xyz, int n) {
  const float* p = xyz + 3 * static_cast<ptrdiff_t>(n);
  return p[0] == 0 && p[1] == 0 && p[2] == 0;
}

/// The checkpoint's stored training config with `overrides` applied and a
/// missing layout file replaced by `layout.json` beside the checkpoint.
ConfigNode TrainingConfig(const CheckpointInfo& info,
                          const fs::path& checkpoint,
                          const std::vector<std::string>& overrides) {
  if (info.config_yaml.empty()) {
    throw ConfigError(fmt::format(
        "task.checkpoint={}: the checkpoint stores no training config, so "
        "its validation frames cannot be rebuilt",
        checkpoint.string()));
  }
  ConfigNode cfg = ParseYaml(info.config_yaml, checkpoint.string());
  for (const std::string& text : overrides) {
    const Override o = ParseOverride(text);
    ConfigNode* node = cfg.FindPath(o.key);
    if (o.type != OverrideType::kChange || !o.value || node == nullptr) {
      throw ConfigError(fmt::format(
          "task.overrides: '{}' must be key=value for a key of the stored "
          "training config",
          text));
    }
    node->Assign(*o.value);
  }
  if (ConfigNode* layout = cfg.Find("layout"); layout != nullptr) {
    const ConfigNode* name = layout->Find("name");
    ConfigNode* path = layout->Find("path");
    if (name != nullptr && name->IsString() && name->AsString() == "file" &&
        path != nullptr && path->IsString() && !fs::exists(path->AsString())) {
      const fs::path beside = checkpoint.parent_path() / "layout.json";
      if (!fs::exists(beside)) {
        throw ConfigError(
            fmt::format("the training layout {} does not exist and there is no "
                        "layout.json beside {}: give it with "
                        "task.overrides=[layout.path=<file>]",
                        path->AsString(),
                        checkpoint.string()));
      }
      SOMA_LOG(INFO,
               "calibrate: training layout {} not found; using {}",
               path->AsString(),
               beside.string());
      path->Assign(ConfigNode::LiteralString(beside.string()));
    }
  }
  return cfg;
}

class CalibrateTask : public Task {
 public:
  explicit CalibrateTask(CalibrateOptions options)
      : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    Timer timer;
    if (const ConfigNode* threads = cfg.Find("threads")) {
      SetTorchThreads(static_cast<int>(threads->AsInt()));
    }
    std::string checkpoint = options_.checkpoint;
    if (checkpoint.empty() &&
        (options_.model.empty() || options_.model == "auto")) {
      throw ConfigError(
          "Invalid configuration. task.checkpoint = null, task.model = "
          "null. Violated constraint: a checkpoint, or task.model naming a "
          "bundled model (soma calibrate cmu41)");
    }
    if (checkpoint.empty()) {
      const BundledChoice choice =
          ChooseInstalledModel(CaptureSummary{}, options_.model);
      SOMA_LOG(INFO, "calibrate: {}", choice.reason);
      checkpoint = choice.model.checkpoint.string();
    }
    const CheckpointInfo info = ReadCheckpointInfo(checkpoint);
    const ConfigNode train_cfg =
        TrainingConfig(info, checkpoint, options_.overrides);
    const uint64_t seed = static_cast<uint64_t>(train_cfg.at("seed").AsInt());
    const int64_t frames =
        options_.frames > 0
            ? options_.frames
            : DecodeTrainerOptions(train_cfg.at("train")).val_frames;

    // The training's validation frames.
    BuildContext build(seed, ctx.output_dir.string());
    const Synthesizer synth = BuildSynthesizer(train_cfg, Split::kVal, build);
    const SynthBatchSource source(synth,
                                  SynthBatchSource::Mode::kFixed,
                                  Rng(seed).Stream("data/val").seed(),
                                  frames,
                                  std::max(1, ctx.num_threads));
    if (source.labels() != info.labels) {
      throw ConfigError(fmt::format(
          "calibrate: the rebuilt validation layout has {} labels, the "
          "checkpoint {} has {} (other names or order): the stored "
          "training config does not describe this model",
          source.labels().size(),
          checkpoint,
          info.labels.size()));
    }
    LabeledFrames data;
    source.Read(0, 0, frames, &data);
    const int N = data.num_points;
    const int L = static_cast<int>(info.labels.size());
    const at::Tensor points =
        at::from_blob(data.points.data(), {frames, N, 3}, at::kFloat).clone();
    SOMA_LOG(INFO,
             "calibrate: {} synthetic validation frames ({} points per "
             "frame, seed {}) made in {:.1f} s",
             frames,
             N,
             seed,
             timer.ElapsedSeconds());

    // The labeler's distributions; a layout-conditioned model trained on
    // sampled layouts labels each frame against its own sampled layout's
    // slots, as its validation did.
    Labeler model = LoadLabelerFromCheckpoint(checkpoint);
    const FrameLabeler labeler(model.ptr(), options_.inference);
    LabelSlots slots;
    if (data.num_slots > 0) {
      slots = GatherLabelSlots(data, *source.slot_table());
      SOMA_LOG(INFO,
               "calibrate: the frames carry their sampled layouts ({} label "
               "slots each); each frame is labelled against its own",
               data.num_slots);
    }
    const FrameLabels out =
        labeler.Label(points, 0, data.num_slots > 0 ? &slots : nullptr);
    const at::Tensor probs = out.label_confidence.contiguous();
    auto p = probs.accessor<float, 3>();
    auto ids = out.label_ids.accessor<int64_t, 2>();
    std::vector<float> log_probs;
    std::vector<int> targets;
    std::vector<double> conf_raw;
    std::vector<int> chosen;
    std::vector<bool> correct;
    for (int64_t t = 0; t < frames; ++t) {
      const float* xyz = data.frame_points(t);
      const int16_t* gt = data.frame_labels(t);
      for (int n = 0; n < N; ++n) {
        if (IsMissing(xyz, n)) continue;  // padding / occluded
        for (int c = 0; c <= L; ++c) {
          log_probs.push_back(static_cast<float>(
              std::log(std::max<double>(p[t][n][c], kMinProbability))));
        }
        const int target = std::clamp<int>(gt[n], 0, L);
        targets.push_back(target);
        conf_raw.push_back(p[t][n][ids[t][n]]);
        chosen.push_back(static_cast<int>(ids[t][n]));
        correct.push_back(ids[t][n] == target);
      }
    }
    const TemperatureFit fit =
        options_.objective == "ece"
            ? FitTemperatureByEce(
                  log_probs, targets, chosen, L + 1, options_.num_bins)
            : FitTemperature(log_probs, targets, L + 1);
    if (fit.at_bound) {
      SOMA_LOG(WARNING,
               "calibrate: the temperature {:.3f} is at the edge of the "
               "search interval",
               fit.temperature);
    }
    // Reliability of the raw Sinkhorn rows (conf_raw), of the rows
    // renormalised (T = 1) and temperature scaled, on the same points.
    std::vector<double> conf_t1(conf_raw.size()), conf_after(conf_raw.size());
    {
      std::vector<float> row(L + 1);
      size_t i = 0;
      for (int64_t t = 0; t < frames; ++t) {
        const float* xyz = data.frame_points(t);
        for (int n = 0; n < N; ++n) {
          if (IsMissing(xyz, n)) continue;
          for (int c = 0; c <= L; ++c) row[c] = p[t][n][c];
          ApplyTemperature(row.data(), 1, L + 1, 1.0);
          conf_t1[i] = row[ids[t][n]];
          for (int c = 0; c <= L; ++c) row[c] = p[t][n][c];
          ApplyTemperature(row.data(), 1, L + 1, fit.temperature);
          conf_after[i++] = row[ids[t][n]];
        }
      }
    }
    const Reliability raw =
        ComputeReliability(conf_raw, correct, options_.num_bins);
    const Reliability before =
        ComputeReliability(conf_t1, correct, options_.num_bins);
    const Reliability after =
        ComputeReliability(conf_after, correct, options_.num_bins);

    TemperatureCalibration c;
    c.temperature = fit.temperature;
    c.checkpoint = fs::path(checkpoint).filename().string();
    c.checkpoint_fnv1a64 = FileFingerprint(checkpoint);
    c.fitted_on = fmt::format(
        "{} synthetic validation frames of the training config (seed {}, "
        "data/val stream), {} points, least {}",
        frames,
        seed,
        targets.size(),
        options_.objective == "ece" ? "ECE" : "NLL");
    c.frames = frames;
    c.points = static_cast<int64_t>(targets.size());
    c.nll_before = fit.nll_before;
    c.nll_after = fit.nll_after;
    c.ece_raw = raw.ece;
    c.ece_before = before.ece;
    c.ece_after = after.ece;
    c.command =
        fmt::format("soma calibrate task.checkpoint={}{}{}",
                    checkpoint,
                    options_.frames > 0 ? fmt::format(" task.frames={}", frames)
                                        : std::string(),
                    options_.objective != "nll"
                        ? fmt::format(" task.objective={}", options_.objective)
                        : std::string());
    c.code_version = GetBuildInfo().version;
    WriteCalibration(ctx.output_dir / kCalibrationFileName, c);
    const fs::path output =
        options_.output == "auto"
            ? fs::path(checkpoint).parent_path() / kCalibrationFileName
            : fs::path(options_.output);
    if (!output.parent_path().empty()) CreateDirectories(output.parent_path());
    WriteCalibration(output, c);

    const std::vector<NamedReliability> diagrams = {
        {"raw", raw},
        {"T=1", before},
        {fmt::format("T={:.3f}", fit.temperature), after}};
    WriteFileAtomic(ctx.output_dir / "reliability.csv",
                    ReliabilityCsv(diagrams));
    WriteReliabilityPng(diagrams,
                        "synthetic validation: reliability",
                        ctx.output_dir / "reliability.png");

    ctx.ReportMetric("temperature", fit.temperature);
    ctx.ReportMetric("nll_before", fit.nll_before);
    ctx.ReportMetric("nll_after", fit.nll_after);
    ctx.ReportMetric("ece_raw", raw.ece);
    ctx.ReportMetric("ece_before", before.ece);
    ctx.ReportMetric("ece_after", after.ece);
    ctx.ReportMetric("points", static_cast<double>(targets.size()));
    ctx.ReportMetric("accuracy", before.accuracy);
    SOMA_LOG(INFO,
             "calibrate: T = {:.4f} over {} points of {} frames: NLL {:.4f} "
             "-> {:.4f}, ECE {:.4f} (raw Sinkhorn rows) -> {:.4f} (rows "
             "renormalised) -> {:.4f} (accuracy {:.2f}%, unchanged); wrote "
             "{} ({:.1f} s)",
             fit.temperature,
             targets.size(),
             frames,
             fit.nll_before,
             fit.nll_after,
             raw.ece,
             before.ece,
             after.ece,
             100 * before.accuracy,
             output.string(),
             timer.ElapsedSeconds());
  }

 private:
  CalibrateOptions options_;
};

}  // namespace

void RegisterCalibrateTask(Registry<Task>& registry) {
  registry.Register("calibrate", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    CalibrateOptions options;
    if (const ConfigNode* checkpoint = node.Find("checkpoint");
        checkpoint != nullptr && checkpoint->IsNull()) {
      reader.Ignore("checkpoint");
    } else {
      reader.Read("checkpoint", &options.checkpoint);
    }
    if (const ConfigNode* model = node.Find("model");
        model != nullptr && model->IsNull()) {
      reader.Ignore("model");
    } else {
      reader.Read("model", &options.model);
    }
    if (const ConfigNode* frames = node.Find("frames");
        frames != nullptr && frames->IsNull()) {
      reader.Ignore("frames");
    } else {
      reader.Read("frames", &options.frames);
    }
    reader.Read("output", &options.output);
    reader.Read("overrides", &options.overrides);
    reader.Read("num_bins", &options.num_bins);
    reader.Read("objective", &options.objective);
    reader.Check("objective",
                 options.objective == "nll" || options.objective == "ece",
                 "objective is nll or ece");
    if (const ConfigNode* inference = reader.Child("inference")) {
      options.inference = DecodeInferenceOptions(*inference);
    }
    reader.Check("frames", options.frames >= 0, "frames >= 0 (0: as trained)");
    reader.Check("num_bins", options.num_bins >= 1, "num_bins >= 1");
    reader.Finish();
    return std::make_unique<CalibrateTask>(std::move(options));
  });
}

}  // namespace soma
