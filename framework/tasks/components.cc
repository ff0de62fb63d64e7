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

std::vector<std::string> BuildLayoutLabels(const ConfigNode& cfg,
                                           BuildContext& ctx) {
  return Instantiate<LayoutSource>(Require(cfg, "layout"), ctx)->Labels();
}

std::unique_ptr<MotionSource> BuildMotionSource(const ConfigNode& cfg,
                                                BuildContext& ctx) {
  return Instantiate<MotionSource>(Require(cfg, "motion"), ctx);
}

NoisePipeline BuildNoise(const ConfigNode& cfg, BuildContext& ctx) {
  const ConfigNode* node = cfg.Find("noise");
  NoisePipeline noise =
      node == nullptr ? NoisePipeline() : BuildNoisePipeline(*node, ctx);
  SOMA_LOG(INFO,
           "noise: {} ({} ghost slots)",
           noise.Describe(),
           noise.num_ghost_slots());
  return noise;
}

Synthesizer BuildSynthesizer(const ConfigNode& cfg,
                             Split split,
                             BuildContext& ctx) {
  const ConfigNode* synth = cfg.Find("synth");
  SynthesisOptions options =
      synth == nullptr ? SynthesisOptions() : DecodeSynthesisOptions(*synth);
  if (options.layout_sampler.has_value() && split != Split::kTrain) {
    // Validation and test frames give every sampled layout an equal share.
    options.layout_sampler->cycle_layouts = true;
  }
  const BodyModel body = BuildBody(cfg, ctx);
  std::vector<MarkerLayout> layouts;
  if (options.layouts.empty()) {
    layouts.push_back(BuildLayout(cfg, body, ctx));
  } else {
    for (const std::string& name : options.layouts) {
      const bool is_file =
          name.size() > 5 && name.compare(name.size() - 5, 5, ".json") == 0;
      layouts.push_back(is_file ? LoadMarkerLayoutForBody(name, body)
                                : MakeBuiltinLayout(body, name));
    }
  }
  Timer timer;
  Rng rng = Rng(ctx.seed()).Stream("motion");
  std::vector<PoseSequence> clips =
      BuildMotionSource(cfg, ctx)->Load(body, split, options.frame_rate, rng);
  int64_t frames = 0;
  for (const PoseSequence& clip : clips) frames += clip.num_frames();
  SOMA_LOG(INFO,
           "motion ({}): {} clips, {} frames at {} Hz ({:.1f}s)",
           ToString(split),
           clips.size(),
           frames,
           options.frame_rate,
           timer.ElapsedSeconds());
  NoisePipeline noise = BuildNoise(cfg, ctx);
  Synthesizer synthesizer(
      body, std::move(layouts), std::move(clips), std::move(noise), options);
  if (synthesizer.slot_table() != nullptr) {
    SOMA_LOG(INFO,
             "synthesizer ({}): a layout per placement block of {} ({}), {} "
             "label slots, N = {} points, {} candidate marker positions",
             ToString(split),
             options.placement_block,
             options.layout_sampler->cycle_layouts ? "in turn" : "uniform",
             synthesizer.num_labels(),
             synthesizer.num_points(),
             synthesizer.num_candidate_markers());
    return synthesizer;
  }
  SOMA_LOG(INFO,
           "synthesizer: {} layout(s), superset L = {}, N = {} points, {} "
           "candidate marker positions",
           synthesizer.num_layouts(),
           synthesizer.num_labels(),
           synthesizer.num_points(),
           synthesizer.num_candidate_markers());
  return synthesizer;
}

}  // namespace soma
