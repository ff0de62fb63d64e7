// `soma label_eval` (the default task, README command 1): a labeller
// evaluated on a real capture the way SOMA evaluates it.
//
//   soma                                  the bundled CMU clip, a bundled model
//   soma label_eval task.input=take.c3d   any labelled take
//   soma label_eval ... task.checkpoint=<run>/checkpoints/best.pt
//   soma label_eval ... task.setting=OC_00_G_03_BT_00
//
// 1. The labeller: `task.checkpoint`, else the bundled model whose labels
//    match the take's (framework/train/model_zoo.h).
// 2. The take, restricted to the labeller's labels, is corrupted by
//    `task.setting` (REFERENCE.md 3.6; the root seed drives it) into
//    `<setting>/<take>.c3d` and its ground truth `<setting>/<take>.h5`.
// 3. It is labelled per frame and by tracklet, and each labelling is scored
//    (REFERENCE.md 4): these are the `label` and `eval` tasks, built through
//    the registry and run in `per_frame/` and `tracklet/`.
// 4. `summary.md` and the log give accuracy and F1 (mean ± std over frames)
//    of both modes and the labelling rate; metrics.yaml has them as
//    `per_frame_acc`, `per_frame_f1`, `tracklet_acc`, `tracklet_f1`,
//    `frames_per_s`.
// 5. Confidence (issue #25 item 4): from each mode's `_labels.h5` and the
//    ground truth, `reliability.csv`/`.png` (the probability of each
//    point's label before task.min_confidence against whether it is right,
//    15 equal-width bins; series `raw`: the raw Sinkhorn rows, `T=<t>`: the
//    rows renormalised at the temperature of the checkpoint's
//    calibration.yaml, 1 without one) and `precision_coverage.csv`/`.png`
//    (over thresholds: of the real labels the labelling assigned, the share
//    kept (coverage) and the share of those right (precision)); metrics
//    `<mode>_ece` (at T), `<mode>_ece_raw`, `<mode>_coverage_at_precision`
//    (the largest coverage at precision >= task.target_precision) and
//    `<mode>_threshold_at_precision`, and a table in summary.md.
#include "framework/body/marker_layout.h"
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/timer.h"
#include "framework/eval/calibration.h"
#include "framework/io/c3d.h"
#include "framework/io/mocap_dataset.h"
#include "framework/registry/registry.h"
#include "framework/synth/corruption.h"
#include "framework/tasks/label_layout.h"
#include "framework/tasks/task.h"
#include "framework/train/model_zoo.h"
#include "framework/train/trainer.h"

#include <fmt/format.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <set>

namespace soma {
namespace {

namespace fs = std::filesystem;

struct LabelEvalOptions {
  std::string input;
  std::string setting = "OC_05_G_03_BT_00";
  std::string checkpoint;  // empty: a bundled model
  std::string model = "auto";
  std::string name_map;              // "" or their_name: our_name (YAML)
  double min_confidence = 0.0;       // handed to the label task
  int review_gap = 0;                // handed to the label task
  std::string calibration = "auto";  // handed to the label task
  double target_precision = 0.995;   // for the coverage at this precision
  int num_bins = 15;                 // reliability diagram bins
  ConfigNode inference;              // handed to the label task as it is
};

LabelEvalOptions DecodeLabelEvalOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  LabelEvalOptions options;
  reader.Require("input", &options.input);
  reader.Read("setting", &options.setting);
  if (const ConfigNode* checkpoint = node.Find("checkpoint");
      checkpoint != nullptr && checkpoint->IsNull()) {
    reader.Ignore("checkpoint");
  } else {
    reader.Read("checkpoint", &options.checkpoint);
  }
  reader.Read("model", &options.model);
  reader.Read("name_map", &options.name_map);
  ReadConfidenceKeys(node,
                     reader,
                     &options.min_confidence,
                     &options.review_gap,
                     &options.calibration);
  reader.Read("target_precision", &options.target_precision);
  reader.Check("target_precision",
               options.target_precision > 0 && options.target_precision <= 1,
               "0 < target_precision <= 1");
  reader.Read("num_bins", &options.num_bins);
  reader.Check("num_bins", options.num_bins >= 1, "num_bins >= 1");
  if (const ConfigNode* inference = reader.Child("inference")) {
    options.inference = *inference;
  }
  reader.Finish();
  ParseCorruptionSettingName(options.setting);  // throws naming it
  return options;
}

/// How far one labelling's confidences can be trusted.
struct ConfidenceResult {
  double temperature = 1.0;
  Reliability uncalibrated;  // the raw Sinkhorn rows
  Reliability calibrated;    // renormalised at the labelling's temperature
  CoveragePoint at_precision;
  int64_t predictions = 0;  // real labels assigned before min_confidence
};

/// The results of one labelling mode.
struct ModeResult {
  std::string mode;  // per_frame | tracklet
  std::map<std::string, double> metrics;
  fs::path dir;
  ConfidenceResult confidence;
};

/// Scores the confidences of a `soma label` sidecar against the ground truth
/// of the corrupted take it labelled (the sidecar's `column` is the take's
/// column, whose per-frame ground-truth id `truth` holds), and writes the
/// reliability and precision/coverage CSVs and PNGs into `dir`.
ConfidenceResult AnalyzeConfidence(const fs::path& sidecar,
                                   const LabeledSequence& truth,
                                   const std::string& mode,
                                   const LabelEvalOptions& options,
                                   const fs::path& dir) {
  const DatasetReader reader(sidecar);
  const int T = static_cast<int>(reader.num_frames());
  const int P = reader.info().num_points;
  const int L = reader.info().num_labels();
  if (T != truth.num_frames() || L != truth.null_label()) {
    throw InternalError(
        fmt::format("{}: {} frames and {} labels, the ground truth {} and {}",
                    sidecar.string(),
                    T,
                    L,
                    truth.num_frames(),
                    truth.null_label()));
  }
  const std::vector<float> column = reader.ReadPointArray("column");
  const std::vector<float> proposed = reader.ReadPointArray("proposed_label");
  const std::vector<float> calibrated =
      reader.ReadPointArray("proposed_confidence");
  const std::vector<float> uncalibrated =
      reader.ReadPointArray("uncalibrated_confidence");
  ConfidenceResult r;
  if (auto it = reader.info().attributes.find("temperature");
      it != reader.info().attributes.end()) {
    r.temperature = std::stod(it->second);
  }
  std::vector<double> conf_t1, conf_t;
  std::vector<bool> correct;
  std::vector<ThresholdedPrediction> predictions;
  for (int t = 0; t < T; ++t) {
    const int16_t* gt = truth.frames.frame_labels(t);
    for (int p = 0; p < P; ++p) {
      const size_t i = static_cast<size_t>(t) * P + p;
      if (column[i] < 0) continue;  // padding
      const int id = static_cast<int>(proposed[i]);
      const bool ok = id == gt[static_cast<int>(column[i])];
      conf_t1.push_back(uncalibrated[i]);
      conf_t.push_back(calibrated[i]);
      correct.push_back(ok);
      if (id < L) predictions.push_back({calibrated[i], ok});
    }
  }
  r.uncalibrated = ComputeReliability(conf_t1, correct, options.num_bins);
  r.calibrated = ComputeReliability(conf_t, correct, options.num_bins);
  r.at_precision = CoverageAtPrecision(predictions, options.target_precision);
  r.predictions = static_cast<int64_t>(predictions.size());
  const std::vector<NamedReliability> diagrams = {
      {"raw", r.uncalibrated},
      {fmt::format("T={:.3f}", r.temperature), r.calibrated}};
  WriteFileAtomic(dir / "reliability.csv", ReliabilityCsv(diagrams));
  WriteReliabilityPng(
      diagrams, fmt::format("{}: reliability", mode), dir / "reliability.png");
  const std::vector<CoveragePoint> curve =
      PrecisionCoverageCurve(predictions, DefaultThresholds());
  WriteFileAtomic(dir / "precision_coverage.csv", PrecisionCoverageCsv(curve));
  WritePrecisionCoveragePng(curve,
                            options.target_precision,
                            fmt::format("{}: precision/coverage", mode),
                            dir / "precision_coverage.png");
  return r;
}

class LabelEvalTask : public Task {
 public:
  explicit LabelEvalTask(LabelEvalOptions options)
      : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    Timer total;
    if (!fs::exists(options_.input)) {
      throw IoError(
          fmt::format("task.input={}: no such file (a labelled "
                      "C3D take)",
                      options_.input));
    }
    // The take under our names (task.name_map): a renamed copy, read from
    // here on.
    std::string input = options_.input;
    MarkerNameMap name_map;
    if (!options_.name_map.empty()) {
      name_map = ReadMarkerNameMap(options_.name_map);
      C3dData c3d = ReadC3d(input);
      c3d.labels = name_map.Apply(c3d.labels);
      const fs::path renamed = ctx.output_dir / "renamed";
      CreateDirectories(renamed);
      input = (renamed / fs::path(input).filename()).string();
      WriteC3d(input, c3d);
      SOMA_LOG(INFO,
               "label_eval: {} names mapped by {}: {}",
               name_map.entries.size(),
               options_.name_map,
               input);
    }
    // 1. The labeller.
    std::string checkpoint = options_.checkpoint;
    std::string labeller = checkpoint;
    if (checkpoint.empty()) {
      const BundledChoice choice =
          ChooseInstalledModel(SummarizeCapture(input), options_.model);
      SOMA_LOG(INFO, "label_eval: {}", choice.reason);
      checkpoint = choice.model.checkpoint.string();
      labeller = fmt::format("bundled model `{}` ({})",
                             choice.model.name,
                             choice.model.description);
    }
    CheckpointInfo info = ReadCheckpointInfo(checkpoint);
    {
      // A layout given at label time (framework/tasks/label_layout.h): the
      // labeller's labels are that layout's (checked here, applied by the
      // label sub-tasks).
      BuildContext build(ctx.seed, ctx.output_dir.string());
      const std::optional<LabelTimeLayout> layout =
          ResolveLabelTimeLayout(cfg,
                                 ctx.overrides,
                                 info,
                                 checkpoint,
                                 LoadLabelerFromCheckpoint(checkpoint),
                                 build);
      if (layout.has_value()) info.labels = layout->labels;
    }
    if (!name_map.empty()) {
      CheckMarkerNameMap(name_map, info.labels, "the labeller");
    }

    // 2. The take, corrupted by the paper's protocol. Its markers are read
    // under the labeller's labels' canonical names (a layout file may name
    // a marker by an alias of the take's name, e.g. LASI for LFWT), as
    // `soma corrupt` reads them.
    std::vector<std::string> canonical;
    for (const std::string& label : info.labels) {
      canonical.push_back(CanonicalMarkerLabel(label));
    }
    const LabeledSequence clean = ReadLabeledC3d(input, canonical);
    {
      // The take's columns carry the canonical names they were read under.
      const std::set<std::string> present(clean.column_names.begin(),
                                          clean.column_names.end());
      std::vector<std::string> lacking;
      for (size_t i = 0; i < canonical.size(); ++i) {
        if (present.count(canonical[i]) == 0) {
          lacking.push_back(info.labels[i]);
        }
      }
      if (!lacking.empty()) {
        SOMA_LOG(WARNING,
                 "label_eval: {} of the labeller's {} labels are not in {}: {}",
                 lacking.size(),
                 info.labels.size(),
                 options_.input,
                 fmt::join(lacking, " "));
      }
    }
    const CorruptionSetting setting =
        ParseCorruptionSettingName(options_.setting);
    if (const std::string reason = CorruptionSkipReason(clean, setting);
        !reason.empty()) {
      throw ConfigError(
          fmt::format("task.setting={}: {}", options_.setting, reason));
    }
    CorruptionSummary corruption;
    const LabeledSequence corrupted =
        CorruptSequence(clean, setting, ctx.seed, &corruption);
    const fs::path corrupt_dir = ctx.output_dir / options_.setting;
    CreateDirectories(corrupt_dir);
    WriteCorruptedSequence(
        corrupted, corrupt_dir / clean.name, options_.setting, ctx.seed);
    const fs::path corrupted_c3d = corrupt_dir / (clean.name + ".c3d");
    const fs::path ground_truth = corrupt_dir / (clean.name + ".h5");
    SOMA_LOG(INFO,
             "label_eval: {} — {} frames, {} labels; {}: missing {:.1f}% -> "
             "{:.1f}%, {:.2f} ghosts/frame",
             clean.name,
             clean.num_frames(),
             clean.num_columns(),
             options_.setting,
             100 * corruption.missing_before,
             100 * corruption.missing_after,
             corruption.ghosts_per_frame);

    // 3. Label and score, per frame and by tracklet.
    std::vector<ModeResult> results;
    for (const bool tracklet : {false, true}) {
      ModeResult r;
      r.mode = tracklet ? "tracklet" : "per_frame";
      r.dir = ctx.output_dir / r.mode;
      CreateDirectories(r.dir);
      RunContext sub = SubContext(ctx, r.dir);
      ConfigNode label = ConfigNode::EmptyMap();
      label.Set("name", "label");
      label.Set("input", corrupted_c3d.string());
      label.Set("checkpoint", checkpoint);
      label.Set("tracklet", tracklet);
      label.Set("min_confidence", options_.min_confidence);
      label.Set("review_gap", options_.review_gap);
      label.Set("calibration", options_.calibration);
      if (options_.inference.IsMap())
        label.Set("inference", options_.inference);
      RunSubTask(label, cfg, sub);
      const double fps = sub.metrics().at("frames_per_s");
      ConfigNode eval = ConfigNode::EmptyMap();
      eval.Set("name", "eval");
      eval.Set("gt", ground_truth.string());
      eval.Set("rec", (r.dir / (clean.name + "_labeled.c3d")).string());
      RunSubTask(eval, cfg, sub);
      r.metrics = sub.metrics();
      r.metrics["frames_per_s"] = fps;
      r.confidence = AnalyzeConfidence(r.dir / (clean.name + "_labels.h5"),
                                       corrupted,
                                       r.mode,
                                       options_,
                                       r.dir);
      results.push_back(std::move(r));
    }

    // 4. Summary.
    const ModeResult& frame = results[0];
    const ModeResult& track = results[1];
    for (const ModeResult& r : results) {
      ctx.ReportMetric(r.mode + "_acc", r.metrics.at("acc_mean"));
      ctx.ReportMetric(r.mode + "_f1", r.metrics.at("f1_mean"));
      const ConfidenceResult& c = r.confidence;
      ctx.ReportMetric(r.mode + "_ece", c.calibrated.ece);
      ctx.ReportMetric(r.mode + "_ece_raw", c.uncalibrated.ece);
      ctx.ReportMetric(r.mode + "_coverage_at_precision",
                       c.at_precision.coverage);
      ctx.ReportMetric(r.mode + "_threshold_at_precision",
                       std::isfinite(c.at_precision.threshold)
                           ? c.at_precision.threshold
                           : 1.0);
    }
    ctx.ReportMetric("temperature", frame.confidence.temperature);
    ctx.ReportMetric("frames", clean.num_frames());
    ctx.ReportMetric("frames_per_s", frame.metrics.at("frames_per_s"));
    std::string confidence_md = fmt::format(
        "\n## Confidence\n\nTemperature {:.4f} ({}). Calibration: each "
        "point's label before `task.min_confidence` (= {}) against the "
        "ground truth, {} equal-width bins (`reliability.csv`, "
        "`reliability.png` in each mode's directory). Coverage: of the real "
        "labels the labelling assigned, the share at or above a threshold; "
        "precision: the share of those that are right "
        "(`precision_coverage.csv`, `.png`).\n\n"
        "| mode | accuracy (pooled over points) | mean confidence | ECE (raw "
        "Sinkhorn rows) | ECE (T) | "
        "coverage at >= {:.1f}% precision | at threshold |\n"
        "|---|---|---|---|---|---|---|\n",
        frame.confidence.temperature,
        frame.confidence.temperature == 1.0 ? "no calibration.yaml applied"
                                            : "the checkpoint's "
                                              "calibration.yaml",
        options_.min_confidence,
        options_.num_bins,
        100 * options_.target_precision);
    for (const ModeResult& r : results) {
      const ConfidenceResult& c = r.confidence;
      confidence_md += fmt::format(
          "| {} | {:.2f}% | {:.4f} | {:.4f} | {:.4f} | {:.2f}% of {} | {} "
          "|\n",
          r.mode,
          100 * c.calibrated.accuracy,
          c.calibrated.mean_confidence,
          c.uncalibrated.ece,
          c.calibrated.ece,
          100 * c.at_precision.coverage,
          c.predictions,
          std::isfinite(c.at_precision.threshold)
              ? fmt::format("{:.4f}", c.at_precision.threshold)
              : std::string("none reaches it"));
    }
    const std::string md = fmt::format(
        "# label_eval: {}\n\n"
        "- **Take:** `{}` ({} frames at {:g} Hz, {} labels of the "
        "labeller)\n"
        "- **Corruption:** `{}` (seed {}): missing points {:.1f}% -> "
        "{:.1f}%, {:.2f} ghost points per frame; `{}/`\n"
        "- **Labeller:** {} — `{}`\n\n"
        "| mode | accuracy (mean ± std over frames) | F1 (mean ± std) | "
        "labelling rate | outputs |\n|---|---|---|---|---|\n"
        "| per frame | {:.2f} ± {:.2f}% | {:.2f} ± {:.2f}% | {:.0f} frames/s "
        "| `per_frame/` |\n"
        "| tracklet | {:.2f} ± {:.2f}% | {:.2f} ± {:.2f}% | {:.0f} frames/s "
        "| `tracklet/` |\n\n"
        "Metrics: SOMA's (REFERENCE.md 4): exact-coordinate matching, micro "
        "accuracy, macro F1 including null. Each mode's directory has the "
        "labelled C3D, `eval.md`, `confusion.png`, `per_frame.csv` and "
        "`class_report.csv`. Wall time {:.1f} s.\n",
        clean.name,
        options_.input,
        clean.num_frames(),
        clean.frame_rate,
        clean.num_columns(),
        options_.setting,
        ctx.seed,
        100 * corruption.missing_before,
        100 * corruption.missing_after,
        corruption.ghosts_per_frame,
        options_.setting,
        labeller,
        checkpoint,
        100 * frame.metrics.at("acc_mean"),
        100 * frame.metrics.at("acc_std"),
        100 * frame.metrics.at("f1_mean"),
        100 * frame.metrics.at("f1_std"),
        frame.metrics.at("frames_per_s"),
        100 * track.metrics.at("acc_mean"),
        100 * track.metrics.at("acc_std"),
        100 * track.metrics.at("f1_mean"),
        100 * track.metrics.at("f1_std"),
        track.metrics.at("frames_per_s"),
        total.ElapsedSeconds());
    WriteFileAtomic(ctx.output_dir / "summary.md", md + confidence_md);
    for (const ModeResult& r : results) {
      SOMA_LOG(INFO,
               "label_eval: {:<9} accuracy {:.2f} ± {:.2f}%, F1 {:.2f} ± "
               "{:.2f}% over {} frames, {:.0f} frames/s",
               r.mode,
               100 * r.metrics.at("acc_mean"),
               100 * r.metrics.at("acc_std"),
               100 * r.metrics.at("f1_mean"),
               100 * r.metrics.at("f1_std"),
               clean.num_frames(),
               r.metrics.at("frames_per_s"));
      SOMA_LOG(INFO,
               "label_eval: {:<9} ECE {:.4f} (raw rows: {:.4f}); coverage "
               "{:.2f}% at >= {:.1f}% precision",
               r.mode,
               r.confidence.calibrated.ece,
               r.confidence.uncalibrated.ece,
               100 * r.confidence.at_precision.coverage,
               100 * options_.target_precision);
    }
    SOMA_LOG(INFO,
             "label_eval: outputs in {} (summary.md; per_frame/ and "
             "tracklet/: labelled C3D, eval.md, confusion.png)",
             ctx.output_dir.string());
  }

 private:
  static RunContext SubContext(const RunContext& ctx, const fs::path& dir) {
    RunContext sub;
    sub.output_dir = dir;
    sub.job_name = ctx.job_name;
    sub.job_num = ctx.job_num;
    sub.hydra = ctx.hydra;
    sub.overrides = ctx.overrides;
    sub.seed = ctx.seed;
    sub.num_threads = ctx.num_threads;
    return sub;
  }

  /// Builds a task from `node` through the registry and runs it.
  static void RunSubTask(const ConfigNode& node,
                         const ConfigNode& cfg,
                         RunContext& sub) {
    BuildContext build(sub.seed, sub.output_dir.string());
    Instantiate<Task>(node, build)->Run(cfg, sub);
  }

  LabelEvalOptions options_;
};

}  // namespace

void RegisterLabelEvalTask(Registry<Task>& registry) {
  registry.Register("label_eval", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<LabelEvalTask>(DecodeLabelEvalOptions(node));
  });
}

}  // namespace soma
