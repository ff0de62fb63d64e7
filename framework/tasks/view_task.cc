// `soma view`: one self-contained HTML page of a capture (issue #27) that
// opens from disk with no server and no network: the markers of every frame
// in 3D (three.js, bundled into the template), their labels, and optionally
// the ground truth and the labeller's confidences.
//
//   soma view take.c3d                                  # raw or labelled
//   soma view <label run>/<take>_labeled.c3d            # + its _labels.h5
//   soma view <label run>/<take>_labeled.c3d task.gt=<corrupt
//   run>/<setting>/<take>.h5
//
// writes `<run dir>/<stem>.html`. The page is the template
// viewer/soma_view.html of the resource root (built from viewer/src by
// viewer/build.mjs; README "Look at the labels") with the data of
// framework/view/view_data.h in place of its placeholder. Sticks join every
// marker to its `task.sticks` nearest markers of the `layout` group's layout
// on the `body` group's body at rest. Pages above `task.max_page_mb` show
// every k-th frame and say so.
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/core/timer.h"
#include "framework/registry/registry.h"
#include "framework/tasks/task.h"
#include "framework/tasks/view_page.h"

#include <fmt/format.h>

#include <filesystem>

namespace soma {
namespace {

namespace fs = std::filesystem;

struct ViewOptions {
  std::string input;
  std::string gt;                // "" = none
  std::string sidecar = "auto";  // auto, "" (none) or a path
  std::string template_path;     // "" = the resource root's
  double max_page_mb = 30.0;     // page size limit (MB = 1e6 bytes)
  int sticks = 2;                // neighbours per marker; 0 = no sticks
  double tolerance = 1e-8;       // ground-truth match, metres
  std::string solve;             // "" = no body
  int mesh_every = 0;            // 0 = as often as a third of the page allows
  int solve_start = 0;           // solve frame t = take frame start + stride t
  int solve_stride = 1;
};

class ViewTask : public Task {
 public:
  explicit ViewTask(ViewOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    Timer timer;
    ViewPageSettings settings;
    settings.inputs.capture = options_.input;
    settings.inputs.truth = options_.gt;
    settings.inputs.sidecar = options_.sidecar == "auto"
                                  ? FindSidecar(options_.input)
                                  : options_.sidecar;
    settings.inputs.tolerance = options_.tolerance;
    settings.max_page_mb = options_.max_page_mb;
    settings.sticks = options_.sticks;
    settings.template_path = options_.template_path;
    settings.solve = options_.solve;
    settings.mesh_every = options_.mesh_every;
    settings.solve_start = options_.solve_start;
    settings.solve_stride = options_.solve_stride;
    const fs::path out =
        ctx.output_dir / (fs::path(options_.input).stem().string() + ".html");
    const ViewPageResult page = WriteViewPage(cfg, settings, out, ctx);
    const ViewDataSummary& summary = page.summary;
    const ViewInputs& inputs = settings.inputs;
    SOMA_LOG(INFO,
             "view: {} frames ({} shown, every {}), {} points, {} labels, {} "
             "sticks{}{} -> {} ({:.1f} MB, {:.1f}s)",
             summary.take_frames,
             summary.shown_frames,
             summary.frame_step,
             summary.shown_points,
             page.num_labels,
             page.num_sticks,
             inputs.truth.empty() ? "" : ", ground truth " + inputs.truth,
             inputs.sidecar.empty() ? "" : ", confidences " + inputs.sidecar,
             out.string(),
             page.bytes / 1e6,
             timer.ElapsedSeconds());
    if (!inputs.truth.empty()) {
      const auto count = [&](PointStatus status) {
        return summary.status_counts[static_cast<size_t>(status)];
      };
      SOMA_LOG(INFO,
               "view: shown points against ground truth: {} correct, {} "
               "wrong, {} ghosts labelled as markers, {} missed, {} without "
               "ground truth",
               count(PointStatus::kCorrect),
               count(PointStatus::kWrong),
               count(PointStatus::kGhostAsMarker),
               count(PointStatus::kMissed),
               count(PointStatus::kNoTruth));
      ctx.ReportMetric("wrong",
                       static_cast<double>(count(PointStatus::kWrong)));
      ctx.ReportMetric("ghost_as_marker",
                       static_cast<double>(count(PointStatus::kGhostAsMarker)));
      ctx.ReportMetric("missed",
                       static_cast<double>(count(PointStatus::kMissed)));
    }
    ctx.ReportMetric("frames", summary.take_frames);
    ctx.ReportMetric("shown_frames", summary.shown_frames);
    ctx.ReportMetric("frame_step", summary.frame_step);
    ctx.ReportMetric("points", static_cast<double>(summary.shown_points));
    ctx.ReportMetric("page_mb", page.bytes / 1e6);
  }

 private:
  ViewOptions options_;
};

}  // namespace

void RegisterViewTask(Registry<Task>& registry) {
  registry.Register("view", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    ViewOptions options;
    reader.Require("input", &options.input);
    // Optional paths: null = none (the sidecar: none; the template: the
    // resource root's).
    auto read_path = [&](std::string_view key, std::string* out) {
      if (const ConfigNode* value = node.Find(key);
          value != nullptr && value->IsNull()) {
        reader.Ignore(key);
        out->clear();
      } else {
        reader.Read(key, out);
      }
    };
    read_path("gt", &options.gt);
    read_path("sidecar", &options.sidecar);
    read_path("template", &options.template_path);
    read_path("solve", &options.solve);
    reader.Read("mesh_every", &options.mesh_every);
    reader.Read("solve_start", &options.solve_start);
    reader.Read("solve_stride", &options.solve_stride);
    reader.Check("mesh_every", options.mesh_every >= 0, ">= 0 (0 = auto)");
    reader.Check("solve_start", options.solve_start >= 0, "a frame >= 0");
    reader.Check("solve_stride", options.solve_stride >= 1, ">= 1");
    reader.Read("max_page_mb", &options.max_page_mb);
    reader.Read("sticks", &options.sticks);
    reader.Read("tolerance", &options.tolerance);
    reader.Check("max_page_mb", options.max_page_mb > 0, "a positive size");
    reader.Check("sticks", options.sticks >= 0, "neighbours per marker >= 0");
    reader.Check("tolerance", options.tolerance >= 0, "metres >= 0");
    reader.Finish();
    return std::make_unique<ViewTask>(std::move(options));
  });
}

}  // namespace soma
