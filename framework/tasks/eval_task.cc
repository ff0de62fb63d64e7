// `soma eval`: scores labelled mocap against ground truth with SOMA's exact
// metrics (framework/eval/labeling_metrics.h, REFERENCE.md section 4).
//
//   soma eval task.gt=<corrupted>.h5 task.rec=<labelled>.c3d
//   soma eval task.gt=<corrupted>.h5 'task.rec=[seed0.c3d,seed1.c3d]'
//
// Ground truth is either a `soma corrupt` output (the `.h5` ground truth with
// its `.c3d` beside it: points from the C3D, per-frame labels from the .h5)
// or a labelled C3D (one label per column). A labelled output is a C3D as
// `soma label` writes it: labelled columns plus null columns named `*<k>`.
// Points are compared by exact coordinates, so both must come from the same
// capture. With several outputs (e.g. models trained with different seeds)
// every output is scored and the mean +- std over outputs is reported too.
// Ground-truth labels an output cannot hold (not among its labelled columns,
// e.g. a model trained with `layout.exclude`) count as errors, or with
// `task.unknown_gt_labels=ghost` as null; `unknown_gt_labels` (a metric)
// counts them.
//
// Body-fit metrics (issue #8 item 6; framework/eval/body_metrics.h): given
// two `soma solve` outputs of the same capture, the fit from ground-truth
// labels and the fit from predicted labels,
//
//   soma eval task.body_fit_gt=<gt_run>/<take>_stageii.h5
//             task.body_fit_rec=<rec_run>/<take>_stageii.h5     (one line)
//
// eval builds the body from the `body` group (as `soma solve` does; use the
// same body), poses both fits on every frame both solved and reports V2V
// (`v2v_mm`), the joint position error (`joint_err_mm`), PCK at
// `task.pck_thresholds_mm` (`pck10`, `pck30`, `pck70` by default, percent of
// joints) and the frames compared (`body_frames`), and writes
// body_metrics.csv (per frame). Either pair may be given alone: `gt` + `rec`
// (labelling), `body_fit_gt` + `body_fit_rec` (body fits), or both.
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/progress.h"
#include "framework/eval/body_metrics.h"
#include "framework/eval/ground_truth.h"
#include "framework/eval/labeling_metrics.h"
#include "framework/registry/registry.h"
#include "framework/solve/solve_output.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"
#include "framework/tasks/view_page.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <set>
#include <sstream>
#include <tuple>

namespace soma {
namespace {

namespace fs = std::filesystem;

struct EvalOptions {
  std::string gt;  // empty: no labelling evaluation
  std::vector<std::string> rec;
  double tolerance = 1e-8;
  /// Ground-truth labels the labeller cannot output (not among the labelled
  /// columns of its output): "wrong" counts them as errors (a warning names
  /// them), "ghost" scores them as null (a subset-layout model on a
  /// superset capture, SOMA Table 4).
  std::string unknown_gt_labels = "wrong";
  /// Per output, a `soma view` page against the ground truth
  /// (view/<stem>.html) and eval.md's links to its `worst_frames` worst
  /// frames; view_max_page_mb as soma view's max_page_mb.
  bool view = true;
  int worst_frames = 5;
  double view_max_page_mb = 30.0;
  std::string body_fit_gt;  // empty: no body-fit metrics
  std::string body_fit_rec;
  BodyMetricsOptions body;

  bool labelling() const { return !gt.empty(); }
  bool body_fits() const { return !body_fit_gt.empty(); }
};

std::string Pm(const Summary& s) {
  return fmt::format("{:.4f} ± {:.4f}", s.mean, s.std);
}

class EvalTask : public Task {
 public:
  explicit EvalTask(EvalOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    std::string md;
    if (options_.labelling()) md += EvaluateLabelling(cfg, ctx);
    if (options_.body_fits()) md += EvaluateBodyFits(cfg, ctx);
    WriteFileAtomic(ctx.output_dir / "eval.md", md);
  }

 private:
  /// Scores the labelled outputs; returns the eval.md section.
  std::string EvaluateLabelling(const ConfigNode& cfg, RunContext& ctx) const {
    const ScoredSequence gt = ReadGroundTruth(options_.gt);
    const MatchTolerance tolerance{options_.tolerance};
    std::ostringstream per_frame;
    per_frame << "run,frame,pairs,accuracy,precision,recall,f1\n";
    std::vector<LabelPair> all_pairs;
    std::vector<LabelingEvaluator::Result> results;
    std::string worst_md;
    for (size_t r = 0; r < options_.rec.size(); ++r) {
      // (accuracy, frame, pairs) of the frames with pairs.
      std::vector<std::tuple<double, size_t, int64_t>> frame_accuracy;
      const ScoredSequence rec = ReadC3dSequence(options_.rec[r]);
      if (rec.frames.size() != gt.frames.size()) {
        throw IoError(
            fmt::format("{}: {} frames, but the ground truth {} has {}",
                        options_.rec[r],
                        rec.frames.size(),
                        options_.gt,
                        gt.frames.size()));
      }
      // The labels this labeller can output: its labelled columns.
      std::set<std::string> known(rec.column_labels.begin(),
                                  rec.column_labels.end());
      known.erase(std::string(kNullLabel));
      std::set<std::string> unknown;
      int64_t scored_as_null = 0;
      LabelingEvaluator evaluator;
      ProgressBar bar(static_cast<int64_t>(gt.frames.size()),
                      {.label = "eval", .unit = "frames"});
      for (size_t t = 0; t < gt.frames.size(); ++t) {
        auto pairs = MatchFrameLabels(gt.frames[t],
                                      gt.LabelsAt(t),
                                      rec.frames[t],
                                      rec.LabelsAt(t),
                                      tolerance);
        const std::set<std::string> frame_unknown =
            UnknownGroundTruthLabels(pairs, known);
        unknown.insert(frame_unknown.begin(), frame_unknown.end());
        if (options_.unknown_gt_labels == "ghost") {
          scored_as_null += ScoreLabelsAsNull(frame_unknown, &pairs);
        }
        if (!pairs.empty()) {
          const LabelingMetrics m = ComputeLabelingMetrics(pairs);
          frame_accuracy.emplace_back(m.accuracy, t, m.num_pairs);
          per_frame << fmt::format("{},{},{},{:.6f},{:.6f},{:.6f},{:.6f}\n",
                                   r,
                                   t,
                                   m.num_pairs,
                                   m.accuracy,
                                   m.precision,
                                   m.recall,
                                   m.f1);
        }
        evaluator.AddFrame(pairs);
        bar.Update();
      }
      bar.Finish();
      if (!unknown.empty() && options_.unknown_gt_labels == "ghost") {
        SOMA_LOG(INFO,
                 "eval: {} points labelled {} in the ground truth, which {} "
                 "cannot output, scored as null (task.unknown_gt_labels=ghost)",
                 scored_as_null,
                 fmt::join(unknown, " "),
                 options_.rec[r]);
      } else if (!unknown.empty()) {
        SOMA_LOG(WARNING,
                 "eval: the ground truth has labels {} that {} cannot output; "
                 "they count as errors (task.unknown_gt_labels=ghost scores "
                 "them as null)",
                 fmt::join(unknown, " "),
                 options_.rec[r]);
      }
      if (r == 0) {  // the first output's numbers are the job's metrics
        ctx.ReportMetric("unknown_gt_labels",
                         static_cast<double>(unknown.size()));
      }
      results.push_back(evaluator.Finish());
      if (options_.view) {
        worst_md += WorstFramesSection(cfg, r, frame_accuracy, ctx);
      }
      all_pairs.insert(all_pairs.end(),
                       evaluator.pooled_pairs().begin(),
                       evaluator.pooled_pairs().end());
    }
    WriteFileAtomic(ctx.output_dir / "per_frame.csv", per_frame.str());
    const LabelingMetrics pooled = ComputeLabelingMetrics(all_pairs);
    WriteClassReportCsv(pooled, ctx.output_dir / "class_report.csv");
    const ConfusionMatrix confusion = ComputeConfusionMatrix(all_pairs);
    WriteConfusionMatrixCsv(confusion, ctx.output_dir / "confusion.csv");
    WriteConfusionMatrixPng(confusion, ctx.output_dir / "confusion.png");
    std::string md = Report(results, pooled, ctx);
    if (!worst_md.empty()) {
      md += fmt::format(
          "## Worst frames\n\nPer output, the {} frames with the lowest "
          "accuracy (ties: the earlier frame). The links open the output's "
          "`soma view` page against this ground truth at that frame (red: "
          "wrong labels, orange: ghosts labelled as markers, rings: missed "
          "markers).\n\n",
          options_.worst_frames);
      md += worst_md + "\n";
    }
    return md;
  }

  /// Writes output r's `soma view` page (view/<stem>.html, view/<r>_<stem>
  /// .html with several outputs) and returns eval.md's lines for its worst
  /// frames.
  std::string WorstFramesSection(
      const ConfigNode& cfg,
      size_t r,
      std::vector<std::tuple<double, size_t, int64_t>> frame_accuracy,
      RunContext& ctx) const {
    const std::string stem = fs::path(options_.rec[r]).stem().string();
    const std::string name =
        options_.rec.size() > 1 ? fmt::format("{}_{}", r, stem) : stem;
    const fs::path relative = fs::path("view") / (name + ".html");
    ViewPageSettings settings;
    settings.inputs.capture = options_.rec[r];
    settings.inputs.truth = options_.gt;
    settings.inputs.sidecar = FindSidecar(options_.rec[r]);
    settings.inputs.tolerance = options_.tolerance;
    settings.max_page_mb = options_.view_max_page_mb;
    // The page is an aid: when it cannot be written (e.g. a layout the
    // sticks cannot be built from), the evaluation still succeeds and the
    // worst frames are listed without links.
    bool have_page = true;
    try {
      const ViewPageResult page =
          WriteViewPage(cfg, settings, ctx.output_dir / relative, ctx);
      SOMA_LOG(INFO,
               "eval: the soma view page of {} is {} ({:.1f} MB)",
               options_.rec[r],
               page.path.string(),
               page.bytes / 1e6);
    } catch (const Error& e) {
      have_page = false;
      SOMA_LOG(WARNING,
               "eval: no soma view page for {}: {}",
               options_.rec[r],
               e.what());
    }
    std::sort(frame_accuracy.begin(), frame_accuracy.end());
    std::string md =
        have_page ? fmt::format("`{}` ([page]({})):", stem, relative.string())
                  : fmt::format("`{}` (no page, see the log):", stem);
    int listed = 0;
    for (const auto& [accuracy, t, pairs] : frame_accuracy) {
      if (listed == options_.worst_frames || accuracy >= 1.0) break;
      const std::string frame =
          have_page
              ? fmt::format("[frame {}]({}#frame={})", t, relative.string(), t)
              : fmt::format("frame {}", t);
      md += fmt::format("{} {} {:.1f}% of {}",
                        listed == 0 ? "" : ";",
                        frame,
                        100.0 * accuracy,
                        pairs);
      ++listed;
    }
    if (listed == 0) md += " every frame 100%";
    return md + ".\n\n";
  }

  /// Compares the two body fits; returns the eval.md section.
  std::string EvaluateBodyFits(const ConfigNode& cfg, RunContext& ctx) const {
    const SolveOutput reference = ReadSolveOutput(options_.body_fit_gt);
    const SolveOutput candidate = ReadSolveOutput(options_.body_fit_rec);
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const BodyModel body = BuildBody(cfg, build);
    const BodyMetrics m =
        ComputeBodyMetrics(body, reference, candidate, options_.body);
    WriteFileAtomic(ctx.output_dir / "body_metrics.csv", BodyMetricsToCsv(m));
    if (m.frames_compared == 0) {
      SOMA_LOG(WARNING,
               "eval: the body fits {} and {} have no solved frame in common; "
               "the body metrics are NaN",
               options_.body_fit_gt,
               options_.body_fit_rec);
    }
    SOMA_LOG(INFO, "eval: {}", m.BriefReport());
    ctx.ReportMetric("v2v_mm", m.v2v_mm);
    ctx.ReportMetric("joint_err_mm", m.joint_err_mm);
    for (size_t k = 0; k < m.pck.size(); ++k) {
      ctx.ReportMetric(PckMetricName(m.pck_thresholds_mm[k]), m.pck[k]);
    }
    ctx.ReportMetric("body_frames", m.frames_compared);
    ctx.ReportMetric("body_frames_excluded", m.frames_excluded);

    std::string md = fmt::format(
        "# Body-fit evaluation\n\nReference (fit from ground-truth labels): "
        "`{}`\nCandidate (fit from predicted labels): `{}`\nBody: `{}`\n\n"
        "Means over the {} of {} frames both fits solved (body_metrics.csv "
        "has every frame). V2V: mean per-vertex distance of the posed meshes; "
        "joint error: mean per-joint distance; PCK: percent of joints closer "
        "than the threshold (Noise-in Bias-out Eq. 13).\n\n",
        options_.body_fit_gt,
        options_.body_fit_rec,
        body.name,
        m.frames_compared,
        m.frames_total);
    md += "| V2V (mm) | max frame V2V (mm) | joint error (mm) |";
    std::string rule = "|---|---|---|";
    std::string row = fmt::format(
        "| {:.2f} | {:.2f} | {:.2f} |", m.v2v_mm, m.max_v2v_mm, m.joint_err_mm);
    for (size_t k = 0; k < m.pck.size(); ++k) {
      md += fmt::format(" PCK@{:g} mm (%) |", m.pck_thresholds_mm[k]);
      rule += "---|";
      row += fmt::format(" {:.1f} |", m.pck[k]);
    }
    md += "\n" + rule + "\n" + row + "\n";
    if (m.frames_excluded > 0) {
      md += fmt::format("\nExcluded frames ({}):", m.frames_excluded);
      for (const auto& [reason, count] : m.excluded_by_reason) {
        md += fmt::format(" {} {};", reason, count);
      }
      md.back() = '.';
      md += "\n";
    }
    return md;
  }

  std::string Report(const std::vector<LabelingEvaluator::Result>& results,
                     const LabelingMetrics& pooled,
                     RunContext& ctx) const {
    std::ostringstream md;
    md << fmt::format("# Labelling evaluation\n\nGround truth: `{}`\n\n",
                      options_.gt);
    md << "Per output: per-frame metrics (REFERENCE.md 4.3), shown as mean ± "
          "std over frames (population std), and the median over frames; "
          "`pooled` = over all points of the sequence.\n\n";
    md << "| output | frames | accuracy (mean ± std) | median | F1 (mean ± "
          "std) | median | precision | recall | pooled acc | pooled F1 |\n"
          "|---|---|---|---|---|---|---|---|---|---|\n";
    for (size_t r = 0; r < results.size(); ++r) {
      const auto& x = results[r];
      md << fmt::format(
          "| `{}` | {} | {} | {:.4f} | {} | {:.4f} | {:.4f} | {:.4f} | {:.4f} "
          "| {:.4f} |\n",
          fs::path(options_.rec[r]).filename().string(),
          x.num_frames,
          Pm(x.accuracy),
          x.accuracy.median,
          Pm(x.f1),
          x.f1.median,
          x.precision.mean,
          x.recall.mean,
          x.pooled.accuracy,
          x.pooled.f1);
    }
    // The first output's numbers are the job's metrics; with several
    // outputs the across-output mean and std are reported as well.
    const auto& first = results.front();
    ctx.ReportMetric("acc_mean", first.accuracy.mean);
    ctx.ReportMetric("acc_median", first.accuracy.median);
    ctx.ReportMetric("acc_std", first.accuracy.std);
    ctx.ReportMetric("f1_mean", first.f1.mean);
    ctx.ReportMetric("f1_median", first.f1.median);
    ctx.ReportMetric("f1_std", first.f1.std);
    ctx.ReportMetric("prec_mean", first.precision.mean);
    ctx.ReportMetric("recall_mean", first.recall.mean);
    ctx.ReportMetric("acc_pooled", first.pooled.accuracy);
    ctx.ReportMetric("f1_pooled", first.pooled.f1);
    ctx.ReportMetric("num_frames", static_cast<double>(first.num_frames));
    if (results.size() > 1) {
      std::vector<double> acc, f1;
      for (const auto& x : results) {
        acc.push_back(x.accuracy.mean);
        f1.push_back(x.f1.mean);
      }
      const Summary a = Summarize(acc), f = Summarize(f1);
      md << fmt::format(
          "\nAcross the {} outputs (mean ± population std over outputs of "
          "their per-frame means): accuracy {}, F1 {}.\n",
          results.size(),
          Pm(a),
          Pm(f));
      ctx.ReportMetric("acc_mean_over_runs", a.mean);
      ctx.ReportMetric("acc_std_over_runs", a.std);
      ctx.ReportMetric("f1_mean_over_runs", f.mean);
      ctx.ReportMetric("f1_std_over_runs", f.std);
    }
    md << fmt::format(
        "\nAll outputs pooled: accuracy {:.4f}, macro F1 {:.4f} over {} "
        "points and {} classes (class_report.csv, confusion.csv, "
        "confusion.png).\n",
        pooled.accuracy,
        pooled.f1,
        pooled.num_pairs,
        pooled.classes.size());
    SOMA_LOG(INFO,
             "eval: accuracy {} F1 {} (mean ± std over {} frames)",
             Pm(first.accuracy),
             Pm(first.f1),
             first.num_frames);
    return md.str() + "\n";
  }

  EvalOptions options_;
};

}  // namespace

void RegisterEvalTask(Registry<Task>& registry) {
  registry.Register("eval", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    EvalOptions options;
    // Each pair is optional: absent, null or ??? mean "not given"; with
    // neither pair the missing `gt` is reported as a mandatory value.
    const auto given = [&](const char* key) {
      const ConfigNode* value = node.Find(key);
      if (value == nullptr || value->IsNull() || value->IsMissing()) {
        reader.Ignore(key);
        return false;
      }
      return true;
    };
    if (given("gt")) reader.Read("gt", &options.gt);
    if (given("rec")) reader.ReadOneOrMore("rec", &options.rec);
    if (given("body_fit_gt")) reader.Read("body_fit_gt", &options.body_fit_gt);
    if (given("body_fit_rec")) {
      reader.Read("body_fit_rec", &options.body_fit_rec);
    }
    if (!options.labelling() && !options.body_fits()) {
      throw MissingMandatoryValue(fmt::format(
          "MissingMandatoryValue: {}.gt (give task.gt and task.rec to score "
          "labels, or task.body_fit_gt and task.body_fit_rec to compare body "
          "fits)",
          node.path().empty() ? "task" : node.path()));
    }
    reader.Read("tolerance", &options.tolerance);
    reader.Read("unknown_gt_labels", &options.unknown_gt_labels);
    reader.Check("unknown_gt_labels",
                 options.unknown_gt_labels == "wrong" ||
                     options.unknown_gt_labels == "ghost",
                 "wrong or ghost");
    reader.Read("pck_thresholds_mm", &options.body.pck_thresholds_mm);
    reader.Read("view", &options.view);
    reader.Read("worst_frames", &options.worst_frames);
    reader.Read("view_max_page_mb", &options.view_max_page_mb);
    reader.Check("worst_frames", options.worst_frames >= 0, ">= 0");
    reader.Check("view_max_page_mb", options.view_max_page_mb > 0, "> 0");
    reader.Check("rec",
                 options.labelling() == !options.rec.empty(),
                 "at least one labelled output when gt is given, none "
                 "without gt");
    reader.Check("tolerance", options.tolerance >= 0, "tolerance >= 0");
    reader.Check("body_fit_rec",
                 options.body_fits() == !options.body_fit_rec.empty(),
                 "body_fit_gt and body_fit_rec are given together");
    reader.Check("pck_thresholds_mm",
                 !options.body.pck_thresholds_mm.empty() &&
                     std::all_of(options.body.pck_thresholds_mm.begin(),
                                 options.body.pck_thresholds_mm.end(),
                                 [](double t) { return t > 0; }),
                 "at least one threshold, each > 0 mm");
    reader.Finish();
    return std::make_unique<EvalTask>(std::move(options));
  });
}

}  // namespace soma
