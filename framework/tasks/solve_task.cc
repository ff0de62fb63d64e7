// `soma solve task.input=<labelled.c3d>`: fits the body to a labelled
// capture (framework/solve: stage I shape + latent markers, stage II
// per-frame pose; options from the `solver` group, the prior from the
// `pose_prior` group) and writes, in the run directory,
//   <take>_stageii.h5          per-frame body parameters (solve_output.h)
//   <take>_solve_summary.csv   one row per frame (termination, costs,
//                              iterations, time, markers, rms, skip reason)
//   <take>_stagei.json         the fitted layout (MoSh++ "finetuned" layout:
//                              nearest canonical vertex of each latent marker)
//   <take>_stagei.csv          per-label vertex ids and distances
//   meshes/<take>_<frame>.ply  with task.mesh_every=k: the posed body of
//                              every k-th frame, observed markers green,
//                              simulated red
// and reports frames, converged/skipped/failed counts, RMS and frames/s.
#include "framework/body/mesh_export.h"
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/io/c3d.h"
#include "framework/registry/registry.h"
#include "framework/solve/body_solver.h"
#include "framework/solve/labelled_markers.h"
#include "framework/solve/layout_fit.h"
#include "framework/solve/marker_model.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

namespace soma {
namespace {

struct SolveTaskOptions {
  std::string input;
  int mesh_every = 0;  // 0: no meshes; k: every k-th solved frame
};

/// meshes/<stem>_<frame>.ply for every `every`-th usable frame of `output`:
/// the posed body with the observed (green) and simulated (red) markers.
int ExportMeshes(const BodyModel& body,
                 const SolveOutput& output,
                 int every,
                 const std::filesystem::path& dir,
                 const std::string& stem) {
  int written = 0;
  for (size_t i = 0; i < output.frame_params.size(); i += every) {
    if (!output.summaries[i].usable()) continue;
    const BodyPose pose =
        UnpackFrameParams(output.frame_params[i].data(), body.num_joints());
    ColoredPoints points;
    const Eigen::Matrix3Xd& obs = output.observed[i];
    const Eigen::Matrix3Xd& sim = output.simulated[i];
    points.positions.resize(3, obs.cols() + sim.cols());
    int n = 0;
    for (int m = 0; m < obs.cols(); ++m) {
      if (!obs.col(m).allFinite()) continue;
      points.positions.col(n++) = obs.col(m);
      points.colors.push_back(Rgb{40, 200, 60});
    }
    for (int m = 0; m < sim.cols(); ++m) {
      if (!sim.col(m).allFinite()) continue;
      points.positions.col(n++) = sim.col(m);
      points.colors.push_back(Rgb{220, 40, 40});
    }
    points.positions.conservativeResize(3, n);
    WritePly(
        dir / fmt::format("{}_{:05d}.ply", stem, output.summaries[i].frame),
        PoseVertices(body, output.betas, pose),
        body.faces,
        points);
    ++written;
  }
  return written;
}

class SolveTask : public Task {
 public:
  explicit SolveTask(SolveTaskOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const BodyModel body = BuildBody(cfg, build);
    const MarkerLayout layout = BuildLayout(cfg, body, build);
    const C3dData c3d = ReadC3d(options_.input);
    const LabelledMarkers markers = MatchToLayout(c3d, layout);
    const BodySolveOptions solver = DecodeBodySolveOptions(cfg.at("solver"));
    const std::unique_ptr<PosePrior> prior =
        Instantiate<PosePriorSource>(cfg.at("pose_prior"), build)->Make(body);
    SOMA_LOG(INFO,
             "solve: {}: {} frames at {} Hz, {} of {} layout labels present",
             options_.input,
             markers.num_frames(),
             markers.frame_rate,
             layout.num_markers() - markers.absent_labels.size(),
             layout.num_markers());
    if (!markers.unmatched_labels.empty()) {
      SOMA_LOG(WARNING,
               "solve: {} capture labels not in the layout, ignored: {}",
               markers.unmatched_labels.size(),
               fmt::join(markers.unmatched_labels, " "));
    }
    if (!markers.absent_labels.empty()) {
      SOMA_LOG(WARNING,
               "solve: layout labels absent from the capture: {}",
               fmt::join(markers.absent_labels, " "));
    }
    const BodySolveResult result =
        SolveBody(body, layout, markers, prior.get(), solver);

    const std::string stem =
        std::filesystem::path(options_.input).stem().string();
    WriteSolveOutput(ctx.output_dir / (stem + "_stageii.h5"), result.output);
    WriteFileAtomic(ctx.output_dir / (stem + "_solve_summary.csv"),
                    SolveSummariesToCsv(result.output.summaries));
    if (options_.mesh_every > 0) {
      const int meshes = ExportMeshes(body,
                                      result.output,
                                      options_.mesh_every,
                                      ctx.output_dir / "meshes",
                                      stem);
      SOMA_LOG(INFO, "solve: wrote {} meshes to meshes/", meshes);
    }
    LayoutFitResult fitted;
    fitted.layout = NearestVertexLayout(body,
                                        layout,
                                        result.stagei.betas,
                                        result.output.markers_latent,
                                        &fitted.normal_distances);
    fitted.residuals_m.assign(layout.num_markers(), std::nan(""));
    WriteMarkerLayout(fitted.layout, ctx.output_dir / (stem + "_stagei.json"));
    WriteFileAtomic(ctx.output_dir / (stem + "_stagei.csv"),
                    LayoutFitToCsv(fitted, layout));

    const SequenceSolveStats& s = result.stats;
    ctx.ReportMetric("frames", s.frames);
    ctx.ReportMetric("converged", s.converged);
    ctx.ReportMetric("no_convergence", s.no_convergence);
    ctx.ReportMetric("failed", s.failed);
    ctx.ReportMetric("skipped", s.skipped);
    ctx.ReportMetric("unmatched_labels",
                     static_cast<double>(markers.unmatched_labels.size()));
    ctx.ReportMetric("absent_labels",
                     static_cast<double>(markers.absent_labels.size()));
    ctx.ReportMetric("stagei_rms_mm", 1e3 * result.stagei.summary.rms_m);
    ctx.ReportMetric("stageii_mean_rms_mm", 1e3 * s.mean_rms_m);
    ctx.ReportMetric("stageii_max_rms_mm", 1e3 * s.max_rms_m);
    ctx.ReportMetric("stageii_frames_per_s", result.stageii_frames_per_s);
  }

 private:
  SolveTaskOptions options_;
};

}  // namespace

void RegisterSolveTask(Registry<Task>& registry) {
  registry.Register("solve", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    SolveTaskOptions options;
    reader.Require("input", &options.input);
    reader.Read("mesh_every", &options.mesh_every);
    reader.Check("mesh_every", options.mesh_every >= 0, "mesh_every >= 0");
    reader.Finish();
    return std::make_unique<SolveTask>(std::move(options));
  });
}

}  // namespace soma
