// `soma label`: labels a raw C3D capture with a trained labeler
// (REFERENCE.md 5.2-5.6).
//
//   soma label task.input=take.c3d task.checkpoint=run/checkpoints/best.pt
//   soma label ... task.tracklet=true      # majority vote per trajectory
//   soma label take.c3d                    # a bundled model (models/)
//   soma label take.c3d task.model=hdm05   # that bundled model
//   soma label take.c3d task.min_confidence=0.9   # null below 0.9, review list
//
// Without a checkpoint the bundled model whose labels match the capture's
// is used (framework/train/model_zoo.h), and the log says which and why.
//
// Input labels are ignored: every valid point of every frame is a raw point.
// Per frame, the valid points are packed (P = most points in any frame), the
// labeler assigns each a label or null, and a label claimed by two points of
// a frame goes to null on both (5.4). Tracklet mode (5.5) then gives every
// input trajectory (C3D column) its most frequent per-frame prediction, null
// votes included, and applies the same-frame duplicate rule again.
//
// Confidence (issue #25 item 4; framework/eval/calibration.h). With a
// `calibration.yaml` fitted for the checkpoint (`soma calibrate`), found by
// `task.calibration` (auto: beside the checkpoint), every point's label
// distribution is temperature scaled, softmax(log p / T): the labels do not
// change, the confidences do. Without one T = 1, which still renormalises
// the rows (Sinkhorn leaves them summing to 0.8-1.03). Then an assigned real
// label whose probability is below `task.min_confidence` becomes null, and the
// frame ranges where that happened are listed per label in the review list.
//
// Outputs in the run directory:
//  - `<stem>_labeled.c3d`: the L labelled trajectories (model label order)
//    followed by the most null points of any frame as `*<k>` trajectories;
//    coordinates are the input's values in the input's units, bit for bit;
//  - `<stem>_labels.h5`: a soma dataset (docs/dataset_format.md): the packed
//    points (metres) and each point's final label id, plus the attributes
//    `source`, `checkpoint`, `mode` and per point, as extra datasets,
//    `confidence` (probability of the assigned class), `column` (input
//    trajectory index, -1 for padding), `proposed_label` (the label before
//    task.min_confidence), `proposed_confidence` (its probability, after
//    temperature scaling) and `uncalibrated_confidence` (its probability
//    in the raw Sinkhorn row: no renormalisation, no temperature);
//    attributes `temperature`, `min_confidence`;
//  - `<stem>_review.csv`: the review list, one row per label and run of
//    consecutive frames whose assignments fell below task.min_confidence
//    (runs at most task.review_gap frames apart merge):
//    `label,first_frame,last_frame,frames,low_frames,min_confidence` (frame
//    indices from 0, the first frame of the capture; the frames of the run
//    below the threshold; the lowest probability in it), sorted by first
//    frame; only the header when nothing fell below.
#include "framework/body/marker_layout.h"
#include "framework/config/decode.h"
#include "framework/core/csv.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/progress.h"
#include "framework/core/timer.h"
#include "framework/eval/calibration.h"
#include "framework/eval/tracklet_vote.h"
#include "framework/io/c3d.h"
#include "framework/io/mocap_dataset.h"
#include "framework/model/inference.h"
#include "framework/model/labeler.h"
#include "framework/model/torch_utils.h"
#include "framework/registry/registry.h"
#include "framework/tasks/label_layout.h"
#include "framework/tasks/task.h"
#include "framework/train/model_zoo.h"
#include "framework/train/trainer.h"

#include <ATen/ATen.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>

namespace soma {
namespace {

namespace fs = std::filesystem;

struct LabelOptions {
  std::string input;
  std::string checkpoint;      // empty: a bundled model
  std::string model = "auto";  // a bundled model's name, or auto
  std::string name_map;        // "" or their_name: our_name (YAML)
  bool tracklet = false;
  /// Assigned real labels below this probability become null (0 = off).
  double min_confidence = 0.0;
  /// Review-list ranges of a label at most this many frames apart merge.
  int review_gap = 0;
  /// auto | none | a calibration.yaml (ResolveCalibration).
  std::string calibration = "auto";
  InferenceOptions inference;
};

/// Valid input points packed per frame.
struct PackedPoints {
  int num_frames = 0;
  int max_points = 0;                     // P
  std::vector<std::vector<int>> columns;  // per frame: input column per point
};

bool IsPresent(const C3dData& c3d, int t, int k) {
  if (!c3d.valid(t, k)) return false;
  const Eigen::Vector3f p = c3d.Point(t, k);
  return p.allFinite() && !(p.array() == 0.0f).all();
}

// The present points of every frame but those of the columns flagged in
// `skip` (model outputs).
PackedPoints Pack(const C3dData& c3d, const std::vector<bool>& skip) {
  PackedPoints packed;
  packed.num_frames = c3d.num_frames;
  packed.columns.resize(c3d.num_frames);
  for (int t = 0; t < c3d.num_frames; ++t) {
    for (int k = 0; k < c3d.num_points; ++k) {
      if (!skip[k] && IsPresent(c3d, t, k)) packed.columns[t].push_back(k);
    }
    packed.max_points =
        std::max(packed.max_points, static_cast<int>(packed.columns[t].size()));
  }
  return packed;
}

/// REFERENCE 5.5 (TrackletLabels, eval/tracklet_vote.h): each input column
/// gets its most frequent prediction. `predicted` is T x P (int64); returns
/// the per-point labels of the packed layout, T x P.
at::Tensor TrackletLabelsOf(const at::Tensor& predicted,
                            const PackedPoints& packed,
                            int num_columns,
                            int64_t num_labels) {
  const at::Tensor contiguous = predicted.contiguous();
  const std::vector<int64_t> labels = TrackletLabels(
      {contiguous.data_ptr<int64_t>(), static_cast<size_t>(contiguous.numel())},
      contiguous.size(1),
      packed.columns,
      num_columns,
      num_labels);
  return at::tensor(labels, at::kLong).reshape(contiguous.sizes());
}

class LabelTask : public Task {
 public:
  explicit LabelTask(LabelOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    if (const ConfigNode* threads = cfg.Find("threads")) {
      SetTorchThreads(static_cast<int>(threads->AsInt()));
    }
    C3dData c3d = ReadC3d(options_.input);
    const MarkerNameMap name_map = options_.name_map.empty()
                                       ? MarkerNameMap{}
                                       : ReadMarkerNameMap(options_.name_map);
    c3d.labels = name_map.Apply(c3d.labels);
    if (options_.checkpoint.empty()) {
      CaptureSummary capture = SummarizeCapture(c3d);
      capture.name = options_.input;
      const BundledChoice choice =
          ChooseInstalledModel(capture, options_.model);
      SOMA_LOG(INFO, "label: {}", choice.reason);
      options_.checkpoint = choice.model.checkpoint.string();
    }
    CheckpointInfo info = ReadCheckpointInfo(options_.checkpoint);
    Labeler model = LoadLabelerFromCheckpoint(options_.checkpoint);
    // A layout-conditioned checkpoint labels a layout given at label time
    // (framework/tasks/label_layout.h): its labels replace the checkpoint's.
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const std::optional<LabelTimeLayout> layout = ResolveLabelTimeLayout(
        cfg, ctx.overrides, info, options_.checkpoint, model, build);
    const int64_t model_slots = model->num_labels();
    if (layout.has_value()) {
      model->SetLayout(layout->descriptors);
      info.labels = layout->labels;
    }
    if (!name_map.empty()) {
      CheckMarkerNameMap(name_map, info.labels, "the labeller");
    }
    const CalibrationChoice calibration =
        ResolveCalibration(options_.calibration, options_.checkpoint);
    SOMA_LOG(INFO, "label: {}", calibration.reason);
    const int64_t num_labels = static_cast<int64_t>(info.labels.size());

    if (c3d.num_frames == 0) {
      throw IoError(fmt::format("{}: the capture has no frames to label",
                                options_.input));
    }
    const double to_metres = c3d.MetresPerUnit();
    // Columns a capture program computed (Plug-in Gait's angles, forces,
    // virtual points) are no optical points: not labelled, not written.
    const std::vector<bool> outputs = ModelOutputColumns(c3d);
    if (const auto n = std::count(outputs.begin(), outputs.end(), true)) {
      SOMA_LOG(INFO,
               "label: {} of the capture's {} point columns are model outputs "
               "(POINT:ANGLES, FORCES ..., Plug-in Gait's virtual points), not "
               "markers: left out",
               n,
               c3d.num_points);
    }
    const PackedPoints packed = Pack(c3d, outputs);
    if (packed.max_points == 0) {
      throw IoError(fmt::format("{}: no valid point in any of its {} frames",
                                options_.input,
                                c3d.num_frames));
    }
    const int T = c3d.num_frames, P = packed.max_points;
    at::Tensor points = at::zeros({T, P, 3}, at::kFloat);
    {
      auto a = points.accessor<float, 3>();
      for (int t = 0; t < T; ++t) {
        for (size_t p = 0; p < packed.columns[t].size(); ++p) {
          const Eigen::Vector3f x = c3d.Point(t, packed.columns[t][p]);
          for (int i = 0; i < 3; ++i) {
            a[t][p][i] = static_cast<float>(x[i] * to_metres);
          }
        }
      }
    }

    // Label in chunks so that the progress bar moves on long captures.
    FrameLabeler labeler(model.ptr(), options_.inference);
    if (options_.inference.use_fast_path && !labeler.uses_fast_path()) {
      SOMA_LOG(INFO,
               "label: the model runs on libtorch (the fast inference path "
               "does not support it: FastLabeler::Supports, e.g. "
               "point-label attention layers)");
    }
    const int64_t chunk =
        std::max<int64_t>(options_.inference.batch_size, 1) * 8;
    std::vector<at::Tensor> ids, predicted, confidence;
    ProgressBar bar(T, {.label = "label", .unit = "frames"});
    Timer timer;
    for (int64_t t0 = 0; t0 < T; t0 += chunk) {
      const int64_t n = std::min<int64_t>(chunk, T - t0);
      const FrameLabels out = labeler.Label(points.narrow(0, t0, n));
      ids.push_back(out.label_ids);
      predicted.push_back(out.predicted_ids);
      confidence.push_back(out.label_confidence);
      bar.Update(n);
    }
    bar.Finish();
    const double seconds = timer.ElapsedSeconds();
    at::Tensor label_ids = at::cat(ids);
    at::Tensor predicted_ids = at::cat(predicted);
    at::Tensor probabilities = at::cat(confidence).contiguous();
    confidence.clear();
    if (num_labels < model_slots) {
      // The layout's K labels are the first K of the model's slots: the
      // padded slots (never assigned) go, null becomes K.
      auto to_layout = [&](const at::Tensor& id) {
        return at::where(id >= num_labels, at::full_like(id, num_labels), id);
      };
      label_ids = to_layout(label_ids);
      predicted_ids = to_layout(predicted_ids);
      probabilities = at::cat({probabilities.narrow(2, 0, num_labels),
                               probabilities.narrow(2, model_slots, 1)},
                              2)
                          .contiguous();
    }
    const at::Tensor valid = points.abs().sum(-1) > 0;
    if (options_.tracklet) {
      label_ids = ResolveDuplicateLabels(
          TrackletLabelsOf(predicted_ids, packed, c3d.num_points, num_labels),
          valid,
          num_labels);
    }
    auto probability_of = [](const at::Tensor& probs, const at::Tensor& ids) {
      return probs.gather(2, ids.unsqueeze(-1)).squeeze(-1);
    };
    Confidences conf;
    conf.proposed_ids = label_ids;
    conf.uncalibrated = probability_of(probabilities, label_ids);
    // Rows renormalised and temperature scaled (T = 1 without calibration),
    // in place.
    ApplyTemperature(probabilities.data_ptr<float>(),
                     int64_t{T} * P,
                     num_labels + 1,
                     calibration.temperature);
    conf.proposed = probability_of(probabilities, label_ids);
    conf.temperature = calibration.temperature;
    // task.min_confidence: low-confidence real labels become null.
    const at::Tensor below =
        (label_ids < num_labels) & (conf.proposed < options_.min_confidence);
    label_ids = label_ids.masked_fill(below, num_labels);
    const at::Tensor assigned_confidence =
        probability_of(probabilities, label_ids);

    const std::string stem = fs::path(options_.input).stem().string();
    WriteLabeledC3d(c3d,
                    packed,
                    label_ids,
                    info.labels,
                    ctx.output_dir / (stem + "_labeled.c3d"));
    WriteSidecar(points,
                 packed,
                 label_ids,
                 assigned_confidence,
                 conf,
                 info,
                 c3d,
                 ctx.output_dir / (stem + "_labels.h5"));
    const int num_ranges = WriteReviewList(
        conf, info.labels, ctx.output_dir / (stem + "_review.csv"));

    // Summary metrics: how much was labelled and how fast.
    const double fps = T / std::max(seconds, 1e-9);
    const int64_t num_points = valid.sum().item<int64_t>();
    const int64_t num_null =
        ((label_ids == num_labels) & valid).sum().item<int64_t>();
    ctx.ReportMetric("frames", T);
    ctx.ReportMetric("frames_per_s", fps);
    ctx.ReportMetric("points", static_cast<double>(num_points));
    ctx.ReportMetric("null_fraction",
                     num_points > 0 ? double(num_null) / num_points : 0.0);
    const int64_t num_below = below.sum().item<int64_t>();
    ctx.ReportMetric("below_min_confidence", static_cast<double>(num_below));
    ctx.ReportMetric("review_ranges", num_ranges);
    ctx.ReportMetric("temperature", calibration.temperature);
    if (options_.min_confidence > 0) {
      SOMA_LOG(INFO,
               "label: {} assignments below task.min_confidence={} became "
               "null; {} ranges to review in {}_review.csv",
               num_below,
               options_.min_confidence,
               num_ranges,
               stem);
    }
    SOMA_LOG(INFO,
             "label: {} frames x {} points, {:.0f} frames/s ({} mode), "
             "{:.1f}% null; wrote {}_labeled.c3d and {}_labels.h5",
             T,
             P,
             fps,
             options_.tracklet ? "tracklet" : "per-frame",
             num_points > 0 ? 100.0 * num_null / num_points : 0.0,
             stem,
             stem);
  }

 private:
  /// REFERENCE 5.4/5.6: L labelled columns then `*<k>` null columns.
  static void WriteLabeledC3d(const C3dData& in,
                              const PackedPoints& packed,
                              const at::Tensor& label_ids,
                              const std::vector<std::string>& labels,
                              const fs::path& path) {
    const int T = in.num_frames;
    const int L = static_cast<int>(labels.size());
    auto ids = label_ids.accessor<int64_t, 2>();
    int max_null = 0;
    for (int t = 0; t < T; ++t) {
      int n = 0;
      for (size_t p = 0; p < packed.columns[t].size(); ++p) n += ids[t][p] == L;
      max_null = std::max(max_null, n);
    }
    const int K = L + max_null;
    C3dData out;
    out.source = path.string();
    out.frame_rate = in.frame_rate;
    out.first_frame = in.first_frame;
    out.num_frames = T;
    out.num_points = K;
    out.units = in.units.empty() ? "mm" : in.units;
    out.labels = labels;
    for (int k = 0; k < max_null; ++k)
      out.labels.push_back(fmt::format("*{}", k));
    out.num_file_labels = K;
    out.points.setZero(T, 3 * int64_t{K});
    out.residuals.setConstant(T, K, -1.0f);
    out.valid.setConstant(T, K, false);
    for (int t = 0; t < T; ++t) {
      int next_null = L;
      for (size_t p = 0; p < packed.columns[t].size(); ++p) {
        const int64_t id = ids[t][p];
        const int column = id < L ? static_cast<int>(id) : next_null++;
        out.points.row(t).segment<3>(3 * int64_t{column}) =
            in.points.row(t).segment<3>(3 * int64_t{packed.columns[t][p]});
        out.residuals(t, column) = 0.0f;
        out.valid(t, column) = true;
      }
    }
    WriteC3d(path, out);
  }

  /// The labels before task.min_confidence and their probabilities
  /// (`T x P`).
  struct Confidences {
    at::Tensor proposed_ids;  // int64
    at::Tensor proposed;      // float, after temperature scaling
    at::Tensor uncalibrated;  // float, without it
    double temperature = 1.0;
  };

  /// `<stem>_review.csv`; returns the number of ranges.
  int WriteReviewList(const Confidences& conf,
                      const std::vector<std::string>& labels,
                      const fs::path& path) const {
    const int T = static_cast<int>(conf.proposed_ids.size(0));
    const int P = static_cast<int>(conf.proposed_ids.size(1));
    const at::Tensor ids = conf.proposed_ids.to(at::kInt).contiguous();
    const at::Tensor probs = conf.proposed.contiguous();
    const std::vector<ReviewRange> ranges = LowConfidenceRanges(
        std::vector<int>(ids.data_ptr<int>(),
                         ids.data_ptr<int>() + ids.numel()),
        std::vector<float>(probs.data_ptr<float>(),
                           probs.data_ptr<float>() + probs.numel()),
        T,
        P,
        static_cast<int>(labels.size()),
        options_.min_confidence,
        options_.review_gap);
    std::string csv =
        "label,first_frame,last_frame,frames,low_frames,min_confidence\n";
    for (const ReviewRange& r : ranges) {
      csv += fmt::format("{},{},{},{},{},{:.4f}\n",
                         CsvField(labels[r.label]),
                         r.first_frame,
                         r.last_frame,
                         r.last_frame - r.first_frame + 1,
                         r.low_frames,
                         r.min_confidence);
    }
    WriteFileAtomic(path, csv);
    return static_cast<int>(ranges.size());
  }

  void WriteSidecar(const at::Tensor& points,
                    const PackedPoints& packed,
                    const at::Tensor& label_ids,
                    const at::Tensor& confidence,
                    const Confidences& conf,
                    const CheckpointInfo& info,
                    const C3dData& c3d,
                    const fs::path& path) const {
    const int T = static_cast<int>(points.size(0));
    const int P = static_cast<int>(points.size(1));
    DatasetInfo meta;
    meta.labels = info.labels;
    meta.num_points = P;
    meta.frame_rate = c3d.frame_rate;
    meta.config_yaml = info.config_yaml;
    meta.attributes["source"] = options_.input;
    meta.attributes["checkpoint"] = options_.checkpoint;
    meta.attributes["mode"] = options_.tracklet ? "tracklet" : "per_frame";
    meta.attributes["temperature"] = fmt::format("{}", conf.temperature);
    meta.attributes["min_confidence"] =
        fmt::format("{}", options_.min_confidence);
    LabeledFrames frames;
    frames.Resize(T, P);
    const at::Tensor contiguous = points.contiguous();
    std::copy_n(contiguous.data_ptr<float>(),
                frames.points.size(),
                frames.points.data());
    auto ids = label_ids.accessor<int64_t, 2>();
    auto assigned = confidence.accessor<float, 2>();
    auto proposed_ids = conf.proposed_ids.accessor<int64_t, 2>();
    auto proposed = conf.proposed.accessor<float, 2>();
    auto uncalibrated = conf.uncalibrated.accessor<float, 2>();
    const size_t n = static_cast<size_t>(T) * P;
    std::vector<float> confidences(n, 0.0f);
    std::vector<float> columns(n, -1.0f);
    std::vector<float> proposed_labels(n, 0.0f);
    std::vector<float> proposed_confidences(n, 0.0f);
    std::vector<float> uncalibrated_confidences(n, 0.0f);
    for (int t = 0; t < T; ++t) {
      for (int p = 0; p < P; ++p) {
        frames.frame_labels(t)[p] = static_cast<int16_t>(ids[t][p]);
        const size_t i = static_cast<size_t>(t) * P + p;
        confidences[i] = assigned[t][p];
        proposed_labels[i] = static_cast<float>(proposed_ids[t][p]);
        proposed_confidences[i] = proposed[t][p];
        uncalibrated_confidences[i] = uncalibrated[t][p];
        if (p < static_cast<int>(packed.columns[t].size())) {
          columns[i] = static_cast<float>(packed.columns[t][p]);
        }
      }
    }
    DatasetWriter writer(path, meta);
    writer.Append(frames);
    writer.WritePointArray("confidence", confidences);
    writer.WritePointArray("column", columns);
    writer.WritePointArray("proposed_label", proposed_labels);
    writer.WritePointArray("proposed_confidence", proposed_confidences);
    writer.WritePointArray("uncalibrated_confidence", uncalibrated_confidences);
    writer.Close();
  }

  LabelOptions options_;
};

}  // namespace

void RegisterLabelTask(Registry<Task>& registry) {
  registry.Register("label", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    LabelOptions options;
    reader.Require("input", &options.input);
    if (const ConfigNode* checkpoint = node.Find("checkpoint");
        checkpoint != nullptr && checkpoint->IsNull()) {
      reader.Ignore("checkpoint");  // null: a bundled model
    } else {
      reader.Require("checkpoint", &options.checkpoint);
    }
    reader.Read("model", &options.model);
    reader.Read("name_map", &options.name_map);
    reader.Read("tracklet", &options.tracklet);
    ReadConfidenceKeys(node,
                       reader,
                       &options.min_confidence,
                       &options.review_gap,
                       &options.calibration);
    if (const ConfigNode* inference = reader.Child("inference")) {
      options.inference = DecodeInferenceOptions(*inference);
    }
    reader.Finish();
    return std::make_unique<LabelTask>(std::move(options));
  });
}

}  // namespace soma
