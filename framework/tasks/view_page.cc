#include "framework/tasks/view_page.h"

#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/resources.h"
#include "framework/registry/registry.h"
#include "framework/tasks/components.h"

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
