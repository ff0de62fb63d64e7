// `soma fit_layout task.input=<labelled.c3d>`: a marker layout from one
// labelled frame (framework/solve/layout_fit.h). Writes, in the run
// directory, <take>_layout.json (MoSh's layout format) and <take>_layout.csv
// (label, vertex, initial vertex, normal distance, residual), and reports
// markers_used, fit_rms_mm (stage I on the frame, free latent offsets) and
// layout_rms_mm (the written layout re-posed on the frame).
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/io/c3d.h"
#include "framework/io/marker_labels.h"
#include "framework/registry/registry.h"
#include "framework/solve/body_solver.h"
#include "framework/solve/labelled_markers.h"
#include "framework/solve/layout_fit.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <string_view>
#include <vector>

namespace soma {
namespace {

// Names the Plug-in Gait virtual points CaptureMarkerColumns left out: the
// model computed them, no camera saw them, so they get no place in a layout.
void LogVirtualPoints(const C3dData& c3d) {
  const std::vector<bool> is_virtual = PlugInGaitVirtualPoints(c3d.labels);
  std::vector<std::string_view> names;
  for (size_t k = 0; k < is_virtual.size(); ++k) {
    if (is_virtual[k]) names.push_back(StripSubjectPrefix(c3d.labels[k]));
  }
  if (names.empty()) return;
  SOMA_LOG(INFO,
           "fit_layout: {} of the capture's points are Plug-in Gait's virtual "
           "points (segment axes, centre of mass), model outputs rather than "
           "markers, and are left out: {}",
           names.size(),
           fmt::join(names, " "));
}

struct FitLayoutOptions {
  std::string input;
  int frame = -1;
  std::string name_map;  // "" or a YAML file their_name: our_name
  CaptureLayoutOptions layout;
};

class FitLayoutTask : public Task {
 public:
  explicit FitLayoutTask(FitLayoutOptions options)
      : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const BodyModel body = BuildBody(cfg, build);
    const MarkerLayout initial = BuildLayout(cfg, body, build);
    const BodySolveOptions solver = DecodeBodySolveOptions(cfg.at("solver"));
    const std::unique_ptr<PosePrior> prior =
        Instantiate<PosePriorSource>(cfg.at("pose_prior"), build)->Make(body);
    const C3dData c3d = ReadC3d(options_.input);
    std::vector<std::string> labels;
    std::vector<Eigen::Matrix3Xd> frames;
    CaptureMarkerColumns(c3d, &labels, &frames);
    LogVirtualPoints(c3d);
    if (labels.empty() || frames.empty()) {
      throw IoError(fmt::format(
          "{}: no labelled marker (of {} points, {} frames); fit_layout needs "
          "a labelled frame",
          options_.input,
          c3d.num_points,
          c3d.num_frames));
    }
    if (options_.frame >= static_cast<int>(frames.size())) {
      throw ConfigError(fmt::format(
          "Invalid configuration. task.frame = {}. Violated constraint: "
          "frame < {} (the frames of {}), or -1",
          options_.frame,
          frames.size(),
          options_.input));
    }
    std::vector<std::string> match_as;
    if (!options_.name_map.empty()) {
      const MarkerNameMap map = ReadMarkerNameMap(options_.name_map);
      CheckMarkerNameMap(map, initial.Labels(), "the layout");
      match_as = map.Apply(labels);
      SOMA_LOG(INFO,
               "fit_layout: name map {}: {} names",
               options_.name_map,
               map.entries.size());
    }
    const CaptureLayoutResult result = FitCaptureLayout(body,
                                                        initial,
                                                        labels,
                                                        match_as,
                                                        frames,
                                                        options_.frame,
                                                        prior.get(),
                                                        options_.layout,
                                                        solver.stagei,
                                                        solver.stageii);
    if (!result.absent_labels.empty()) {
      SOMA_LOG(WARNING,
               "fit_layout: {} layout labels are not in the capture: {}",
               result.absent_labels.size(),
               fmt::join(result.absent_labels, " "));
    }
    std::vector<std::string> not_placed;
    for (const CaptureLayoutMarker& m : result.markers) {
      if (m.placement == MarkerPlacement::kMissing) {
        not_placed.push_back(m.label + " (missing in the frame)");
      } else if (m.placement == MarkerPlacement::kTooFar) {
        not_placed.push_back(fmt::format("{} ({:.0f} mm from the body)",
                                         m.label,
                                         1e3 * std::abs(m.skin_distance_m)));
      } else if (m.placement == MarkerPlacement::kInside) {
        not_placed.push_back(fmt::format("{} ({:.0f} mm inside the body)",
                                         m.label,
                                         -1e3 * m.skin_distance_m));
      } else if (m.placement == MarkerPlacement::kDuplicate) {
        not_placed.push_back(m.label + " (a repeated label)");
      }
    }
    if (!not_placed.empty()) {
      SOMA_LOG(WARNING,
               "fit_layout: {} of {} markers could not be placed and are left "
               "out of the layout: {}",
               not_placed.size(),
               result.markers.size(),
               fmt::join(not_placed, ", "));
    }
    SOMA_LOG(INFO,
             "fit_layout: frame {} of {}: {} markers, {} recognised ({} "
             "fitted), {} placed in all; fit RMS {:.2f} mm ({}), written "
             "layout re-posed RMS {:.2f} mm ({:.2f} mm over the fitted ones)",
             result.frame,
             options_.input,
             result.markers.size(),
             result.recognised,
             result.fit.markers_used,
             result.placed,
             1e3 * result.fit.rms_m,
             result.fit.fit.summary.BriefReport(),
             1e3 * result.layout_rms_m,
             1e3 * result.fitted_layout_rms_m);
    const std::string stem =
        std::filesystem::path(options_.input).stem().string();
    WriteMarkerLayout(result.layout, ctx.output_dir / (stem + "_layout.json"));
    WriteFileAtomic(ctx.output_dir / (stem + "_layout.csv"),
                    CaptureLayoutToCsv(result));
    ctx.ReportMetric("frame", result.frame);
    ctx.ReportMetric("markers", static_cast<double>(result.markers.size()));
    ctx.ReportMetric("recognised", result.recognised);
    ctx.ReportMetric("markers_used", result.fit.markers_used);
    ctx.ReportMetric("placed", result.placed);
    ctx.ReportMetric("not_placed", result.not_placed);
    ctx.ReportMetric("fit_rms_mm", 1e3 * result.fit.rms_m);
    ctx.ReportMetric("layout_rms_mm", 1e3 * result.layout_rms_m);
    ctx.ReportMetric("fitted_layout_rms_mm", 1e3 * result.fitted_layout_rms_m);
    ctx.ReportMetric("absent_labels",
                     static_cast<double>(result.absent_labels.size()));
  }

 private:
  FitLayoutOptions options_;
};

}  // namespace

void RegisterFitLayoutTask(Registry<Task>& registry) {
  registry.Register("fit_layout", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    FitLayoutOptions options;
    reader.Require("input", &options.input);
    reader.Read("frame", &options.frame);
    reader.Read("name_map", &options.name_map);
    reader.Read("min_recognised", &options.layout.min_recognised);
    double max_skin_distance_mm = 1e3 * options.layout.max_skin_distance_m;
    reader.Read("max_skin_distance_mm", &max_skin_distance_mm);
    options.layout.max_skin_distance_m = 1e-3 * max_skin_distance_mm;
    double max_depth_mm = 1e3 * options.layout.max_depth_m;
    reader.Read("max_depth_mm", &max_depth_mm);
    options.layout.max_depth_m = 1e-3 * max_depth_mm;
    reader.Finish();
    options.layout.Validate();
    if (options.frame < -1) {
      throw ConfigError(fmt::format(
          "Invalid configuration. task.frame = {}. Violated constraint: "
          "frame >= 0, or -1 for the most complete frame",
          options.frame));
    }
    return std::make_unique<FitLayoutTask>(std::move(options));
  });
}

}  // namespace soma
