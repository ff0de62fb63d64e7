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
#include "framework/registry/registry.h"
#include "framework/solve/body_solver.h"
#include "framework/solve/labelled_markers.h"
#include "framework/solve/layout_fit.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

namespace soma {
namespace {

struct FitLayoutOptions {
  std::string input;
  int frame = -1;
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
    const LabelledMarkers markers =
        MatchToLayout(ReadC3d(options_.input), initial);
    if (options_.frame >= markers.num_frames()) {
      throw ConfigError(fmt::format(
          "Invalid configuration. task.frame = {}. Violated constraint: "
          "frame < {} (the frames of {}), or -1",
          options_.frame,
          markers.num_frames(),
          options_.input));
    }
    const int frame =
        options_.frame >= 0 ? options_.frame : MostCompleteFrame(markers);
    if (!markers.unmatched_labels.empty()) {
      SOMA_LOG(WARNING,
               "fit_layout: {} capture labels not in the layout, ignored: {}",
               markers.unmatched_labels.size(),
               fmt::join(markers.unmatched_labels, " "));
    }
    const LayoutFitResult fit = FitLayoutToFrame(body,
                                                 initial,
                                                 markers,
                                                 frame,
                                                 prior.get(),
                                                 solver.stagei,
                                                 solver.stageii);
    SOMA_LOG(INFO,
             "fit_layout: frame {} of {}: {} of {} layout markers, fit RMS "
             "{:.2f} mm ({}), written layout re-posed RMS {:.2f} mm",
             frame,
             options_.input,
             fit.markers_used,
             initial.num_markers(),
             1e3 * fit.rms_m,
             fit.fit.summary.BriefReport(),
             1e3 * fit.layout_rms_m);
    const std::string stem =
        std::filesystem::path(options_.input).stem().string();
    WriteMarkerLayout(fit.layout, ctx.output_dir / (stem + "_layout.json"));
    WriteFileAtomic(ctx.output_dir / (stem + "_layout.csv"),
                    LayoutFitToCsv(fit, initial));
    ctx.ReportMetric("frame", frame);
    ctx.ReportMetric("markers_used", fit.markers_used);
    ctx.ReportMetric("fit_rms_mm", 1e3 * fit.rms_m);
    ctx.ReportMetric("layout_rms_mm", 1e3 * fit.layout_rms_m);
    ctx.ReportMetric("unmatched_labels",
                     static_cast<double>(markers.unmatched_labels.size()));
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
    reader.Finish();
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
