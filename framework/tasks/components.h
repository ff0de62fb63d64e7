// Building the components a task needs from the task config (all through
// the registry): the body, the marker layout, the motion source.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"
#include "framework/config/node.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"
#include "framework/synth/noise.h"
#include "framework/synth/synthesizer.h"

#include <memory>
#include <string>
#include <vector>

namespace soma {

/// `cfg.body` built through Registry<BodySource>. ConfigError if absent.
BodyModel BuildBody(const ConfigNode& cfg, BuildContext& ctx);
/// `cfg.layout` on `body`.
MarkerLayout BuildLayout(const ConfigNode& cfg,
                         const BodyModel& body,
                         BuildContext& ctx);
/// The canonical labels of `cfg.layout` in label-id order, without a body
/// (LayoutSource::Labels).
std::vector<std::string> BuildLayoutLabels(const ConfigNode& cfg,
                                           BuildContext& ctx);
/// `cfg.motion`.
std::unique_ptr<MotionSource> BuildMotionSource(const ConfigNode& cfg,
                                                BuildContext& ctx);

/// `cfg.noise` ({modules: [...]}); no `noise` node = no noise.
NoisePipeline BuildNoise(const ConfigNode& cfg, BuildContext& ctx);

/// The synthesizer of a task config: `cfg.body`; the training layouts
/// (`cfg.synth.layouts`: built-in names or layout JSON paths, or else
/// `cfg.layout`); the clips of `split` from `cfg.motion` resampled to
/// `cfg.synth.frame_rate` (random choices from Rng(ctx.seed()).Stream
/// ("motion")); the noise pipeline `cfg.noise`; the options `cfg.synth`
/// (defaults if absent).
Synthesizer BuildSynthesizer(const ConfigNode& cfg,
                             Split split,
                             BuildContext& ctx);

}  // namespace soma
