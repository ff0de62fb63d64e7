// `soma stream` (issue #26): live labelling. Frames come from a source — a
// C3D take replayed at its capture rate or as fast as possible, or a TCP
// client speaking the frame protocol (framework/stream/frame_protocol.h) —
// and every frame is labelled as it arrives: the labeler's per-frame labels,
// stabilised by the online tracklet vote (framework/stream/online_tracklets.h),
// final when emitted. Labels go back over the socket (TCP, one label packet
// per frame) and into a labelled C3D.
//
//   soma stream take.c3d                                 # replay at capture
//   rate soma stream take.c3d task.c3d.realtime=false         # as fast as
//   possible soma stream task.source=tcp task.tcp.port=7301 task.model=hdm05
//   soma stream take.c3d task.gt=<corrupt run>/<take>.h5 # + SOMA's metrics
//
// Backlog: when a frame is still waiting after the current one is labelled,
// `catch_up` labels every frame in order (latency grows until it drains);
// `drop` labels only the newest waiting frame and emits the skipped ones as
// dropped (all null; flag in the label packet). Frames whose latency exceeds
// `budget_ms` are counted late.
//
// Outputs in the run directory (written when the stream ends, also after an
// error such as a client disconnecting mid-frame, and every `flush_every_s`
// seconds if set: complete up to the last full frame, atomically):
//  - `<stem>_labeled.c3d`: the final (online) labels, `soma label`'s layout;
//  - `<stem>_per_frame.c3d`: the per-frame labels of the same frames;
//  - `latency.csv`: per frame: number, points, forward ms, solve ms,
//    latency ms (arrival -> labels emitted), body latency ms (arrival ->
//    body solved; the body is solved after the labels are sent), dropped;
//  - with `task.solve.enabled`: `<stem>_stageii.h5` and
//    `<stem>_solve_summary.csv`, the online body (framework/stream/
//    online_body.h: stage I on the first `calibration_frames`, then stage II
//    per frame, warm-started, `max_solver_time_ms` per solve);
//  - `summary.md`; metrics: frames, frames_dropped, frames_late,
//    latency_{p50,p99,max}_ms, label_{p50,p99}_ms, with the body
//    body_frames, body_mean_rms_mm, solve_{p50,p99}_ms,
//    body_latency_{p50,p99,max}_ms, and with `gt`
//    acc/f1 of both outputs (SOMA's metrics, the `eval` task).
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/timer.h"
#include "framework/model/labeler.h"
#include "framework/model/torch_utils.h"
#include "framework/registry/registry.h"
#include "framework/solve/body_solver.h"
#include "framework/solve/solve_output.h"
#include "framework/stream/frame_source.h"
#include "framework/stream/online_body.h"
#include "framework/stream/stream_labeler.h"
#include "framework/stream/stream_recorder.h"
#include "framework/tasks/components.h"
#include "framework/tasks/label_layout.h"
#include "framework/tasks/task.h"
#include "framework/train/model_zoo.h"
#include "framework/train/trainer.h"

#include <fmt/format.h>

#include <filesystem>
#include <optional>
#include <sstream>

namespace soma {
namespace {

namespace fs = std::filesystem;

enum class BacklogPolicy { kCatchUp, kDrop };

struct StreamTaskOptions {
  std::string source = "c3d";  // c3d | tcp: which of the nodes below
  ConfigNode source_node;      // task.<source>, with name = source
  std::string checkpoint;      // empty: a bundled model
  std::string model = "auto";
  BacklogPolicy backlog = BacklogPolicy::kCatchUp;
  double budget_ms = 0.0;  // <= 0: one frame period of the source
  StreamLabelerOptions labeler;
  std::string gt;  // optional ground truth to score against
  std::string stem = "stream";
  int threads = 1;             // intra-op threads of the labeller
  double flush_every_s = 0.0;  // > 0: rewrite the outputs this often
  // The online body (task.solve): stage I on the first frames, then stage II
  // per frame with a Ceres time limit. Body, layout, solver options and pose
  // prior come from the `body`, `layout`, `solver`, `pose_prior` groups.
  bool solve = false;
  int calibration_frames = 240;
  std::string stagei_file;  // an earlier fit's _stageii.h5 (no calibration)
  bool background_stagei = true;    // stage I does not hold up the stream
  double max_solver_time_ms = 2.0;  // per stage II solve; <= 0: none
};

StreamTaskOptions DecodeStreamTaskOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  StreamTaskOptions options;
  reader.Read("source", &options.source);
  reader.Check("source",
               options.source == "c3d" || options.source == "tcp",
               "one of c3d, tcp");
  for (const char* key : {"c3d", "tcp"}) {
    const ConfigNode* child = reader.Child(key);
    if (key == options.source) {
      if (child == nullptr || !child->IsMap()) {
        throw ConfigError(fmt::format(
            "Invalid configuration. task.{} is missing: the options of the "
            "selected source",
            key));
      }
      // Decoded now for its errors (a missing path, an unknown key), and
      // built through the registry when the task runs.
      if (options.source == "c3d") {
        DecodeC3dReplayOptions(*child);
      } else {
        DecodeTcpSourceOptions(*child);
      }
      options.source_node = *child;
      options.source_node.Set("name", std::string(key));
    }
  }
  if (const ConfigNode* checkpoint = node.Find("checkpoint");
      checkpoint != nullptr && checkpoint->IsNull()) {
    reader.Ignore("checkpoint");
  } else {
    reader.Read("checkpoint", &options.checkpoint);
  }
  reader.Read("model", &options.model);
  std::string backlog = "catch_up";
  reader.Read("backlog", &backlog);
  reader.Check(
      "backlog", backlog == "catch_up" || backlog == "drop", "catch_up|drop");
  options.backlog =
      backlog == "drop" ? BacklogPolicy::kDrop : BacklogPolicy::kCatchUp;
  if (const ConfigNode* budget = node.Find("budget_ms");
      budget != nullptr && budget->IsNull()) {
    reader.Ignore("budget_ms");
  } else {
    reader.Read("budget_ms", &options.budget_ms);
  }
  reader.Read("tracklets", &options.labeler.tracklets);
  if (const ConfigNode* t = reader.Child("tracklet")) {
    ConfigReader tr(*t);
    OnlineTrackletOptions& o = options.labeler.tracklet;
    tr.Read("half_life", &o.half_life);
    tr.Read("swap_frames", &o.swap_frames);
    tr.Read("forget_after", &o.forget_after);
    std::string duplicates(ToString(o.duplicates));
    tr.Read("duplicates", &duplicates);
    o.duplicates = DuplicatePolicyFromString(duplicates);
    tr.Check("swap_frames", o.swap_frames >= 0, "swap_frames >= 0");
    tr.Finish();
  }
  if (const ConfigNode* inference = reader.Child("inference")) {
    ConfigReader in(*inference);
    in.Read("permute", &options.labeler.permute);
    in.Read("seed", &options.labeler.seed);
    in.Read("use_fast_path", &options.labeler.use_fast_path);
    in.Finish();
  }
  if (const ConfigNode* gt = node.Find("gt"); gt != nullptr && gt->IsNull()) {
    reader.Ignore("gt");
  } else {
    reader.Read("gt", &options.gt);
  }
  reader.Read("stem", &options.stem);
  reader.Read("threads", &options.threads);
  reader.Read("flush_every_s", &options.flush_every_s);
  reader.Check(
      "flush_every_s", options.flush_every_s >= 0, "flush_every_s >= 0");
  if (const ConfigNode* solve = reader.Child("solve")) {
    ConfigReader sr(*solve);
    sr.Read("enabled", &options.solve);
    sr.Read("calibration_frames", &options.calibration_frames);
    if (const ConfigNode* stagei = solve->Find("stagei");
        stagei != nullptr && stagei->IsNull()) {
      sr.Ignore("stagei");
    } else {
      sr.Read("stagei", &options.stagei_file);
    }
    sr.Read("max_solver_time_ms", &options.max_solver_time_ms);
    sr.Read("background", &options.background_stagei);
    sr.Check("calibration_frames",
             options.calibration_frames >= 1,
             "calibration_frames >= 1");
    sr.Finish();
  }
  reader.Check("threads", options.threads >= 1, "threads >= 1");
  reader.Finish();
  return options;
}

class StreamTask : public Task {
 public:
  explicit StreamTask(StreamTaskOptions options)
      : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    SetTorchThreads(options_.threads);
    BuildContext build(ctx.seed, ctx.output_dir.string());
    std::unique_ptr<FrameSource> source =
        Instantiate<FrameSource>(options_.source_node, build);
    std::string stem = options_.stem;
    if (options_.source == "c3d") {
      const std::string path = options_.source_node.at("path").AsString();
      stem = fs::path(path).stem().string();
      if (options_.checkpoint.empty()) {
        CaptureSummary capture = SummarizeCapture(path);
        capture.name = path;
        const BundledChoice choice =
            ChooseInstalledModel(capture, options_.model);
        SOMA_LOG(INFO, "stream: {}", choice.reason);
        options_.checkpoint = choice.model.checkpoint.string();
      }
    } else if (options_.checkpoint.empty()) {
      if (options_.model == "auto") {
        throw ConfigError(
            "Invalid configuration. task.model = auto. Violated constraint: "
            "a TCP stream has no capture to choose a model from; set "
            "task.model=<bundled model> or task.checkpoint=<file>");
      }
      options_.checkpoint =
          ChooseInstalledModel(CaptureSummary{}, options_.model)
              .model.checkpoint.string();
    }
    CheckpointInfo info = ReadCheckpointInfo(options_.checkpoint);
    Labeler model = LoadLabelerFromCheckpoint(options_.checkpoint);
    // A layout-conditioned checkpoint labels the layout given at label time
    // (`layout=...`, framework/tasks/label_layout.h), as in `soma label`;
    // the labeller snapshots it, so it is set first.
    if (const std::optional<LabelTimeLayout> label_layout =
            ResolveLabelTimeLayout(
                cfg, ctx.overrides, info, options_.checkpoint, model, build)) {
      model->SetLayout(label_layout->descriptors);
      info.labels = label_layout->labels;
    }
    StreamLabeler labeler(model.ptr(), options_.labeler);
    const int null = labeler.num_labels();

    // The online body: built before the stream starts (stage I waits for
    // the calibration frames).
    std::unique_ptr<BodyModel> body;
    std::unique_ptr<MarkerLayout> layout;
    std::unique_ptr<PosePrior> prior;
    std::unique_ptr<OnlineBodySolver> solver;
    if (options_.solve) {
      body = std::make_unique<BodyModel>(BuildBody(cfg, build));
      layout = std::make_unique<MarkerLayout>(BuildLayout(cfg, *body, build));
      prior = Instantiate<PosePriorSource>(cfg.at("pose_prior"), build)
                  ->Make(*body);
      OnlineBodyOptions body_options;
      body_options.calibration_frames = options_.calibration_frames;
      body_options.stagei_file = options_.stagei_file;
      body_options.background_stagei = options_.background_stagei;
      body_options.solve = DecodeBodySolveOptions(cfg.at("solver"));
      body_options.solve.stageii.solver.max_solver_time_s =
          std::max(0.0, options_.max_solver_time_ms * 1e-3);
      solver = std::make_unique<OnlineBodySolver>(
          *body, *layout, prior.get(), info.labels, body_options);
      if (!solver->absent_labels().empty()) {
        SOMA_LOG(WARNING,
                 "stream: layout labels the labeller cannot give (always "
                 "missing in the body fit): {}",
                 fmt::join(solver->absent_labels(), " "));
      }
    }

    source->Open(info.labels);
    const double budget_ms = options_.budget_ms > 0
                                 ? options_.budget_ms
                                 : 1000.0 / source->arrival_rate();
    const double metres_per_unit = source->metres_per_unit();
    SOMA_LOG(INFO,
             "stream: {} -> {} labels ({} path, {}), backlog {}, budget "
             "{:.2f} ms",
             source->Describe(),
             null,
             labeler.uses_fast_path() ? "fast" : "libtorch",
             options_.labeler.tracklets ? "online tracklets" : "per frame",
             options_.backlog == BacklogPolicy::kDrop ? "drop" : "catch_up",
             budget_ms);

    LabeledC3dRecorder online(
        info.labels, source->frame_rate(), source->units());
    LabeledC3dRecorder per_frame(
        info.labels, source->frame_rate(), source->units());
    LatencyStats latency, forward, solve_times, body_latency;
    int64_t body_solved = 0;
    double body_rms = 0.0;
    std::ostringstream csv;
    csv << "frame,number,points,label_ms,solve_ms,latency_ms,body_latency_ms,"
           "dropped\n";
    int64_t index = 0, dropped = 0, late = 0;
    Timer wall, since_log, since_flush;
    int64_t flushes = 0;
    const auto write_outputs = [&] {
      online.Write(ctx.output_dir / (stem + "_labeled.c3d"));
      per_frame.Write(ctx.output_dir / (stem + "_per_frame.c3d"));
      WriteFileAtomic(ctx.output_dir / "latency.csv", csv.str());
      if (solver != nullptr && solver->calibrated()) {
        SolveOutput fit = solver->output();
        fit.frame_rate = source->frame_rate();
        WriteSolveOutput(ctx.output_dir / (stem + "_stageii.h5"), fit);
        WriteFileAtomic(ctx.output_dir / (stem + "_solve_summary.csv"),
                        SolveSummariesToCsv(fit.summaries));
      }
    };
    const auto emit_dropped = [&](const StreamFrame& frame) {
      const std::vector<int> nulls(static_cast<size_t>(frame.num_points()),
                                   null);
      online.Append(frame, nulls);
      per_frame.Append(frame, nulls);
      if (solver != nullptr) solver->AddFrame(frame, nulls, metres_per_unit);
      LabelPacket packet;
      packet.number = frame.number;
      packet.flags = kLabelFlagDropped;
      source->Reply(packet);
      csv << fmt::format(
          "{},{},{},,,,,1\n", index, frame.number, frame.num_points());
      ++dropped;
      ++index;
    };
    try {
      StreamFrame frame, newer;
      while (source->Next(&frame)) {
        if (options_.backlog == BacklogPolicy::kDrop) {
          while (source->Ready() && source->Next(&newer)) {
            emit_dropped(frame);
            std::swap(frame, newer);
          }
        }
        const StreamLabels out = labeler.Label(frame, metres_per_unit, index);
        LabelPacket packet;
        packet.number = frame.number;
        packet.label_ids.resize(out.labels.size());
        for (size_t i = 0; i < out.labels.size(); ++i) {
          packet.label_ids[i] = out.labels[i] == null ? -1 : out.labels[i];
        }
        packet.confidences = out.confidence;
        const double ms = (SteadySeconds() - frame.arrival) * 1e3;
        packet.latency_ms = static_cast<float>(ms);
        source->Reply(packet);
        online.Append(frame, out.labels);
        per_frame.Append(frame, out.per_frame);
        latency.Add(ms);
        forward.Add(out.label_ms);
        late += ms > budget_ms;
        // The body after the labels are out: it delays the next frame, not
        // these labels.
        double solve_ms = 0.0, body_ms = 0.0;
        if (solver != nullptr) {
          Timer solve_timer;
          const SolveSummary fit =
              solver->AddFrame(frame, out.labels, metres_per_unit);
          solve_ms = solve_timer.ElapsedSeconds() * 1e3;
          body_ms = (SteadySeconds() - frame.arrival) * 1e3;
          if (fit.skipped_reason.empty()) {  // not calibrating, a solve
            solve_times.Add(solve_ms);
            body_latency.Add(body_ms);
          }
          body_solved += fit.usable();
          body_rms += fit.usable() ? fit.rms_m : 0.0;
        }
        csv << fmt::format("{},{},{},{:.4f},{:.4f},{:.4f},{:.4f},0\n",
                           index,
                           frame.number,
                           frame.num_points(),
                           out.label_ms,
                           solve_ms,
                           ms,
                           body_ms);
        ++index;
        if (options_.flush_every_s > 0 &&
            since_flush.ElapsedSeconds() >= options_.flush_every_s) {
          write_outputs();  // complete up to this frame, atomically
          since_flush.Restart();
          ++flushes;
        }
        if (since_log.ElapsedSeconds() > 10) {
          since_log.Restart();
          SOMA_LOG(INFO,
                   "stream: {} frames, latency p50 {:.2f} ms, p99 {:.2f} ms, "
                   "{} dropped, {} late",
                   index,
                   latency.Quantile(0.5),
                   latency.Quantile(0.99),
                   dropped,
                   late);
        }
      }
    } catch (const Error& e) {
      if (solver != nullptr) solver->Finish();
      write_outputs();
      SOMA_LOG(ERROR,
               "stream: stopped after {} complete frames; outputs written "
               "up to the last of them",
               index);
      throw;
    }
    if (solver != nullptr) solver->Finish();
    write_outputs();
    const double seconds = wall.ElapsedSeconds();

    ctx.ReportMetric("frames", static_cast<double>(index));
    ctx.ReportMetric("frames_labelled", static_cast<double>(latency.count()));
    ctx.ReportMetric("frames_dropped", static_cast<double>(dropped));
    ctx.ReportMetric("frames_late", static_cast<double>(late));
    ctx.ReportMetric("frames_per_s",
                     static_cast<double>(index) / std::max(seconds, 1e-9));
    ctx.ReportMetric("latency_p50_ms", latency.Quantile(0.5));
    ctx.ReportMetric("latency_p99_ms", latency.Quantile(0.99));
    ctx.ReportMetric("latency_max_ms", latency.Max());
    ctx.ReportMetric("label_p50_ms", forward.Quantile(0.5));
    ctx.ReportMetric("label_p99_ms", forward.Quantile(0.99));
    ctx.ReportMetric("swaps", static_cast<double>(labeler.voter().num_swaps()));
    ctx.ReportMetric("flushes", static_cast<double>(flushes));
    std::string body_line;
    if (solver != nullptr) {
      const double rms_mm =
          body_solved > 0 ? 1e3 * body_rms / static_cast<double>(body_solved)
                          : 0.0;
      ctx.ReportMetric("body_frames", static_cast<double>(body_solved));
      ctx.ReportMetric("body_mean_rms_mm", rms_mm);
      ctx.ReportMetric("solve_p50_ms", solve_times.Quantile(0.5));
      ctx.ReportMetric("solve_p99_ms", solve_times.Quantile(0.99));
      ctx.ReportMetric("body_latency_p50_ms", body_latency.Quantile(0.5));
      ctx.ReportMetric("body_latency_p99_ms", body_latency.Quantile(0.99));
      ctx.ReportMetric("body_latency_max_ms", body_latency.Max());
      body_line = fmt::format(
          "- **Body:** {} ({}); stage II solved {} frames, mean marker RMS "
          "{:.2f} mm, solve p50 {:.3f} ms p99 {:.3f} ms (limit {:g} ms per "
          "solve); arrival -> body p50 {:.3f} ms, p99 {:.3f} ms, max {:.3f} "
          "ms; `{}_stageii.h5`\n",
          solver->calibrated() ? "calibrated" : "not calibrated",
          options_.stagei_file.empty()
              ? fmt::format("stage I on the first {} frames: {}",
                            options_.calibration_frames,
                            solver->stagei_summary().BriefReport())
              : fmt::format("stage I from `{}`", options_.stagei_file),
          body_solved,
          rms_mm,
          solve_times.Quantile(0.5),
          solve_times.Quantile(0.99),
          options_.max_solver_time_ms,
          body_latency.Quantile(0.5),
          body_latency.Quantile(0.99),
          body_latency.Max(),
          stem);
    }

    std::string scores;
    if (!options_.gt.empty()) {
      for (const char* kind : {"labeled", "per_frame"}) {
        const fs::path dir = ctx.output_dir / fmt::format("eval_{}", kind);
        CreateDirectories(dir);
        RunContext sub;
        sub.output_dir = dir;
        sub.job_name = ctx.job_name;
        sub.seed = ctx.seed;
        sub.num_threads = ctx.num_threads;
        ConfigNode eval = ConfigNode::EmptyMap();
        eval.Set("name", "eval");
        eval.Set("gt", options_.gt);
        eval.Set(
            "rec",
            (ctx.output_dir / fmt::format("{}_{}.c3d", stem, kind)).string());
        BuildContext sub_build(sub.seed, dir.string());
        Instantiate<Task>(eval, sub_build)->Run(cfg, sub);
        const std::string name =
            std::string(kind) == "labeled" ? "online" : "per_frame";
        ctx.ReportMetric(name + "_acc", sub.metrics().at("acc_mean"));
        ctx.ReportMetric(name + "_f1", sub.metrics().at("f1_mean"));
        scores += fmt::format(
            "| {} | {:.2f} ± {:.2f}% | {:.2f} ± {:.2f}% | `eval_{}/` |\n",
            name,
            100 * sub.metrics().at("acc_mean"),
            100 * sub.metrics().at("acc_std"),
            100 * sub.metrics().at("f1_mean"),
            100 * sub.metrics().at("f1_std"),
            kind);
        SOMA_LOG(INFO,
                 "stream: {:<9} accuracy {:.2f} ± {:.2f}%, F1 {:.2f}%",
                 name,
                 100 * sub.metrics().at("acc_mean"),
                 100 * sub.metrics().at("acc_std"),
                 100 * sub.metrics().at("f1_mean"));
      }
    }
    std::string md = fmt::format(
        "# stream: {}\n\n"
        "- **Source:** {}\n- **Labeller:** `{}` ({} labels; {})\n"
        "- **Frames:** {} ({} labelled, {} dropped, backlog `{}`), {:.0f} "
        "frames/s over {:.1f} s\n"
        "- **Latency** (arrival -> labels emitted): p50 {:.3f} ms, p99 "
        "{:.3f} ms, max {:.3f} ms; {} frames over the {:.2f} ms budget\n"
        "- **Forward** (labeler alone): p50 {:.3f} ms, p99 {:.3f} ms\n"
        "- **Online tracklets:** half-life {:g} observations, swap after {} "
        "frames ({} swaps), duplicates `{}`\n",
        stem,
        source->Describe(),
        options_.checkpoint,
        null,
        options_.labeler.tracklets ? "online tracklets" : "per frame",
        index,
        latency.count(),
        dropped,
        options_.backlog == BacklogPolicy::kDrop ? "drop" : "catch_up",
        static_cast<double>(index) / std::max(seconds, 1e-9),
        seconds,
        latency.Quantile(0.5),
        latency.Quantile(0.99),
        latency.Max(),
        late,
        budget_ms,
        forward.Quantile(0.5),
        forward.Quantile(0.99),
        options_.labeler.tracklet.half_life,
        options_.labeler.tracklet.swap_frames,
        labeler.voter().num_swaps(),
        ToString(options_.labeler.tracklet.duplicates));
    md += body_line;
    if (!scores.empty()) {
      md += fmt::format(
          "\nScored against `{}` (SOMA's metrics, mean ± std over frames):\n\n"
          "| labels | accuracy | F1 | eval |\n|---|---|---|---|\n{}",
          options_.gt,
          scores);
    }
    WriteFileAtomic(ctx.output_dir / "summary.md", md);
    SOMA_LOG(INFO,
             "stream: {} frames ({} dropped, {} late), latency p50 {:.3f} ms "
             "p99 {:.3f} ms max {:.3f} ms; wrote {}_labeled.c3d, "
             "{}_per_frame.c3d, latency.csv, summary.md",
             index,
             dropped,
             late,
             latency.Quantile(0.5),
             latency.Quantile(0.99),
             latency.Max(),
             stem,
             stem);
  }

 private:
  StreamTaskOptions options_;
};

}  // namespace

void RegisterStreamTask(Registry<Task>& registry) {
  registry.Register("stream", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<StreamTask>(DecodeStreamTaskOptions(node));
  });
}

}  // namespace soma
