#include "framework/tasks/view_page.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/resources.h"
#include "framework/registry/registry.h"
#include "framework/solve/marker_model.h"
#include "framework/solve/solve_output.h"
#include "framework/tasks/components.h"

#include <fmt/format.h>

#include <cmath>

namespace soma {
namespace {

namespace fs = std::filesystem;

/// Sticks from the layout group on the body group's rest pose; none (and a
/// log line) when the layout shares no label with the capture.
std::vector<std::array<int, 2>> LayoutSticks(const ConfigNode& cfg,
                                             const ViewFrames& frames,
                                             int neighbours,
                                             RunContext& ctx) {
  if (frames.labels.empty() || neighbours <= 0) return {};
  BuildContext build(ctx.seed, ctx.output_dir.string());
  const BodyModel body = BuildBody(cfg, build);
  const MarkerLayout layout = BuildLayout(cfg, body, build);
  Eigen::Matrix3Xd rest(3, layout.num_markers());
  for (int m = 0; m < layout.num_markers(); ++m) {
    rest.col(m) = body.template_vertices.col(layout.markers[m].vertex_ids[0]);
  }
  auto sticks =
      NeighbourSticks(frames.labels, layout.Labels(), rest, neighbours);
  if (sticks.empty()) {
    SOMA_LOG(INFO,
             "view: the layout shares no label with {}; no sticks (choose one "
             "with layout=<name> or layout=file layout.path=...)",
             frames.source);
  }
  return sticks;
}

/// Observed markers of solve frame `t` that are points of take frame
/// `take_frame` (within 0.1 mm), and the observed markers in all.
std::pair<int, int> MatchObserved(const SolveOutput& fit,
                                  int t,
                                  const ViewFrames& frames,
                                  int take_frame) {
  int matched = 0, observed = 0;
  const Eigen::Matrix3Xd& obs = fit.observed[t];
  for (Eigen::Index m = 0; m < obs.cols(); ++m) {
    if (!obs.col(m).allFinite()) continue;
    ++observed;
    for (int64_t i = frames.offsets[take_frame];
         i < frames.offsets[take_frame + 1];
         ++i) {
      const Eigen::Vector3d x(frames.positions[3 * i],
                              frames.positions[3 * i + 1],
                              frames.positions[3 * i + 2]);
      if ((x - obs.col(m)).cwiseAbs().maxCoeff() <= 1e-4) {
        ++matched;
        break;
      }
    }
  }
  return {matched, observed};
}

/// The posed body of every mesh_every-th solved frame of settings.solve.
void AddMeshes(const ConfigNode& cfg,
               const ViewPageSettings& settings,
               int64_t mesh_budget_bytes,
               ViewFrames* frames,
               RunContext& ctx) {
  const SolveOutput fit = ReadSolveOutput(settings.solve);
  BuildContext build(ctx.seed, ctx.output_dir.string());
  const BodyModel body = BuildBody(cfg, build);
  if (body.name != fit.body) {
    throw ConfigError(fmt::format(
        "Invalid configuration. body = {}. Violated constraint: the body {} "
        "was fitted with ('{}'; select it with body=...)",
        body.name,
        settings.solve,
        fit.body));
  }
  const int J = body.num_joints();
  std::vector<int> solved;  // solve frames with a usable fit
  for (size_t t = 0; t < fit.frame_params.size(); ++t) {
    const SolveTermination termination = fit.summaries[t].termination;
    if ((termination == SolveTermination::kConverged ||
         termination == SolveTermination::kNoConvergence) &&
        fit.frame_params[t].size() == 3 + 3 * J &&
        fit.frame_params[t].allFinite()) {
      solved.push_back(static_cast<int>(t));
    }
  }
  auto take_frame = [&](int t) {
    return settings.solve_start + settings.solve_stride * t;
  };
  if (solved.empty()) {
    SOMA_LOG(WARNING, "view: {} has no solved frame; no body", settings.solve);
    return;
  }
  if (take_frame(solved.back()) >= frames->num_frames()) {
    throw IoError(
        fmt::format("{}: solve frame {} is take frame {} (task.solve_start={}, "
                    "task.solve_stride={}), but {} has {} frames",
                    settings.solve,
                    solved.back(),
                    take_frame(solved.back()),
                    settings.solve_start,
                    settings.solve_stride,
                    frames->source,
                    frames->num_frames()));
  }
  for (const int t : {solved.front(), solved.back()}) {
    const auto [matched, observed] =
        MatchObserved(fit, t, *frames, take_frame(t));
    if (observed > 0 && matched * 2 < observed) {
      throw IoError(fmt::format(
          "{}: the markers of solve frame {} are not the points of take frame "
          "{} of {} ({} of {} found): give task.solve_start and "
          "task.solve_stride (the solver.start and solver.stride of the "
          "solve), or the capture the solve fitted",
          settings.solve,
          t,
          take_frame(t),
          frames->source,
          matched,
          observed));
    }
  }
  const int step = settings.mesh_every > 0
                       ? settings.mesh_every
                       : ChooseMeshStep(body.num_vertices(),
                                        body.num_faces(),
                                        static_cast<int>(solved.size()),
                                        mesh_budget_bytes);
  if (step == 0) {
    SOMA_LOG(WARNING,
             "view: not even one body mesh fits a third of the page size "
             "limit; no body");
    return;
  }
  frames->mesh_faces.assign(body.faces.data(),
                            body.faces.data() + body.faces.size());
  for (size_t i = 0; i < solved.size(); i += step) {
    const int t = solved[i];
    const BodyPose pose = UnpackFrameParams(fit.frame_params[t].data(), J);
    const Eigen::Matrix3Xd v = PoseVertices(body, fit.betas, pose);
    std::vector<float> coords(v.size());
    for (Eigen::Index k = 0; k < v.size(); ++k) {
      coords[k] = static_cast<float>(v.data()[k]);
    }
    frames->mesh_frames.push_back(take_frame(t));
    frames->mesh_vertices.push_back(std::move(coords));
  }
  frames->mesh_step = step * settings.solve_stride;
  frames->mesh_source = settings.solve;
  SOMA_LOG(INFO,
           "view: body '{}' of {} on {} of {} solved frames (every {})",
           body.name,
           settings.solve,
           frames->mesh_frames.size(),
           solved.size(),
           step);
}

}  // namespace

ViewPageResult WriteViewPage(const ConfigNode& cfg,
                             const ViewPageSettings& settings,
                             const fs::path& out,
                             RunContext& ctx) {
  const fs::path template_path = settings.template_path.empty()
                                     ? ResourcePath("viewer/soma_view.html")
                                     : fs::path(settings.template_path);
  const std::string html = ReadFile(template_path);
  ViewFrames frames = ReadViewFrames(settings.inputs);
  frames.sticks = LayoutSticks(cfg, frames, settings.sticks, ctx);

  ViewPageOptions page;
  page.max_page_bytes = static_cast<int64_t>(settings.max_page_mb * 1e6);
  if (!settings.solve.empty()) {
    AddMeshes(cfg, settings, page.max_page_bytes / 3, &frames, ctx);
  }
  page.template_bytes = static_cast<int64_t>(html.size());
  ViewPageResult result;
  const std::string json = PackViewData(frames, page, &result.summary);
  const std::string filled =
      FillViewTemplate(html, json, template_path.string());
  if (!out.parent_path().empty()) CreateDirectories(out.parent_path());
  WriteFileAtomic(out, filled);
  result.path = out;
  result.num_labels = static_cast<int>(frames.labels.size());
  result.num_sticks = static_cast<int>(frames.sticks.size());
  result.bytes = static_cast<int64_t>(filled.size());
  if (!result.summary.note.empty()) {
    SOMA_LOG(WARNING, "view: {}: {}", out.string(), result.summary.note);
  }
  return result;
}

}  // namespace soma
