// Building the components a task needs from the task config (all through
// the registry): the body, the marker layout, the motion source.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"
#include "framework/config/node.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"

#include <memory>

namespace soma {

/// `cfg.body` built through Registry<BodySource>. ConfigError if absent.
BodyModel BuildBody(const ConfigNode& cfg, BuildContext& ctx);
/// `cfg.layout` on `body`.
MarkerLayout BuildLayout(const ConfigNode& cfg,
                         const BodyModel& body,
                         BuildContext& ctx);
/// `cfg.motion`.
std::unique_ptr<MotionSource> BuildMotionSource(const ConfigNode& cfg,
                                                BuildContext& ctx);

}  // namespace soma
