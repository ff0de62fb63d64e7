#include "framework/tasks/components.h"

#include "framework/body/body_source.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/core/timer.h"

#include <fmt/format.h>

namespace soma {
namespace {

const ConfigNode& Require(const ConfigNode& cfg, std::string_view group) {
  const ConfigNode* node = cfg.Find(group);
  if (node == nullptr || node->IsNull()) {
    throw ConfigError(
        fmt::format("Invalid configuration. This task needs '{}': select one "
                    "with {}=<option> (or "
                    "+{}=<option>); see soma --help",
                    group,
                    group,
                    group));
  }
  return *node;
}

}  // namespace

BodyModel BuildBody(const ConfigNode& cfg, BuildContext& ctx) {
  Timer timer;
  BodyModel body = Instantiate<BodySource>(Require(cfg, "body"), ctx)->Build();
  SOMA_LOG(INFO,
           "body '{}': {} vertices, {} faces, {} joints, {} betas ({:.2f}s)",
           body.name,
           body.num_vertices(),
           body.num_faces(),
           body.num_joints(),
           body.num_betas(),
           timer.ElapsedSeconds());
  return body;
}

MarkerLayout BuildLayout(const ConfigNode& cfg,
                         const BodyModel& body,
                         BuildContext& ctx) {
  MarkerLayout layout =
      Instantiate<LayoutSource>(Require(cfg, "layout"), ctx)->Build(body);
  SOMA_LOG(INFO, "layout: {} markers on '{}'", layout.num_markers(), body.name);
  return layout;
}

std::unique_ptr<MotionSource> BuildMotionSource(const ConfigNode& cfg,
                                                BuildContext& ctx) {
  return Instantiate<MotionSource>(Require(cfg, "motion"), ctx);
}

}  // namespace soma
