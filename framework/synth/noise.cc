#include "framework/synth/noise.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <map>

namespace soma {

// ---- MarkerFrame.

void MarkerFrame::Reset(int num_labels_in, int num_ghost_slots) {
  if (num_labels_in < 0 || num_ghost_slots < 0 ||
      num_labels_in + num_ghost_slots > 32767) {
    throw ShapeError(fmt::format(
        "MarkerFrame: {} labels + {} ghost slots (need >= 0 each, N <= 32767)",
        num_labels_in,
        num_ghost_slots));
  }
  num_labels = num_labels_in;
  const size_t n =
      static_cast<size_t>(num_labels_in) + static_cast<size_t>(num_ghost_slots);
  points.assign(3 * n, 0.0f);
  labels.assign(n, static_cast<int16_t>(num_labels_in));
}

void MarkerFrame::Set(int i, float x, float y, float z, int16_t label) {
  float* p = point(i);
  p[0] = x;
  p[1] = y;
  p[2] = z;
  labels[i] = label;
}

void MarkerFrame::Remove(int i) {
  float* p = point(i);
  p[0] = p[1] = p[2] = 0.0f;
  labels[i] = null_label();
}

int MarkerFrame::NumAvailableMarkers() const {
  int count = 0;
  for (int i = 0; i < num_points(); ++i) count += IsAvailableMarker(i) ? 1 : 0;
  return count;
}

void MarkerFrame::NullMissing() {
  for (int i = 0; i < num_points(); ++i) {
    if (!IsPresent(i)) labels[i] = null_label();
  }
}

// ---- NoisePipeline.

struct NoisePipeline::Stage {
  std::string name;
  std::string stream_name;  // name, or name/k for the k-th repeat
  double probability = 1.0;
  int ghost_offset = 0;  // first ghost slot relative to L
  std::unique_ptr<NoiseModule> module;
};

NoisePipeline::NoisePipeline() = default;
NoisePipeline::~NoisePipeline() = default;
NoisePipeline::NoisePipeline(NoisePipeline&&) noexcept = default;
NoisePipeline& NoisePipeline::operator=(NoisePipeline&&) noexcept = default;

void NoisePipeline::Add(std::string name,
                        double probability,
                        std::unique_ptr<NoiseModule> module) {
  if (module == nullptr) {
    throw InternalError(
        fmt::format("NoisePipeline: stage '{}' has no module", name));
  }
  if (!(probability >= 0.0 && probability <= 1.0)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. noise module '{}': probability = {}. Violated "
        "constraint: 0 <= probability <= 1",
        name,
        probability));
  }
  if (!stages_.empty() && stages_.back().name == "permutation") {
    throw ConfigError(fmt::format(
        "Invalid configuration. noise module '{}' follows 'permutation'; the "
        "permutation must be the last stage (later stages would see shuffled "
        "marker slots)",
        name));
  }
  int repeats = 0;
  for (const Stage& stage : stages_) repeats += stage.name == name ? 1 : 0;
  Stage stage;
  stage.stream_name =
      repeats == 0 ? name : fmt::format("{}/{}", name, repeats + 1);
  stage.name = std::move(name);
  stage.probability = probability;
  stage.ghost_offset = num_ghost_slots();
  stage.module = std::move(module);
  stages_.push_back(std::move(stage));
}

int NoisePipeline::num_stages() const {
  return static_cast<int>(stages_.size());
}

std::vector<std::string> NoisePipeline::stage_names() const {
  std::vector<std::string> names;
  for (const Stage& stage : stages_) names.push_back(stage.name);
  return names;
}

double NoisePipeline::probability(int stage) const {
  return stages_.at(stage).probability;
}

const NoiseModule& NoisePipeline::module(int stage) const {
  return *stages_.at(stage).module;
}

int NoisePipeline::num_ghost_slots() const {
  int slots = 0;
  for (const Stage& stage : stages_) slots += stage.module->num_ghost_slots();
  return slots;
}

void NoisePipeline::Validate(const std::vector<std::string>& labels) const {
  for (const Stage& stage : stages_) stage.module->Validate(labels);
}

void NoisePipeline::Apply(MarkerFrame* frame, const Rng& rng) const {
  const int expected = frame->num_labels + num_ghost_slots();
  if (frame->num_points() != expected ||
      static_cast<int>(frame->points.size()) != 3 * expected) {
    throw ShapeError(fmt::format(
        "NoisePipeline::Apply: the frame has {} points, expected L + ghost "
        "slots = {} + {}",
        frame->num_points(),
        frame->num_labels,
        num_ghost_slots()));
  }
  for (const Stage& stage : stages_) {
    Rng stage_rng = rng.Stream(stage.stream_name);
    // The application draw comes first, from the stage's own stream.
    if (!(stage_rng.Uniform() < stage.probability)) continue;
    stage.module->Apply(
        frame, frame->num_labels + stage.ghost_offset, stage_rng);
  }
  frame->NullMissing();
}

std::string NoisePipeline::Describe() const {
  if (stages_.empty()) return "(no noise)";
  std::vector<std::string> parts;
  for (const Stage& stage : stages_) {
    parts.push_back(
        fmt::format("{}(p={})", stage.name, FormatDouble(stage.probability)));
  }
  return fmt::format("{}", fmt::join(parts, " -> "));
}

// ---- Building from config.

NoisePipeline BuildNoisePipeline(const ConfigNode& noise_cfg,
                                 BuildContext& ctx) {
  NoisePipeline pipeline;
  if (noise_cfg.IsNull()) return pipeline;
  ConfigReader reader(noise_cfg);
  const ConfigNode* modules = reader.Child("modules");
  reader.Ignore("description");
  reader.Finish();
  if (modules == nullptr || modules->IsNull()) return pipeline;
  if (!modules->IsList()) {
    throw ConfigError(fmt::format(
        "Invalid configuration. {} = {}. Expected a list of noise modules "
        "({{name: <module>, probability: p, ...}}){}",
        modules->path(),
        modules->Describe(),
        modules->source().file.empty()
            ? ""
            : " (" + modules->source().ToString() + ")"));
  }
  for (const ConfigNode& item : modules->items()) {
    // A bare string is a module with default options: `- permutation`.
    ConfigNode entry = item;
    if (item.IsString()) {
      entry = ConfigNode::EmptyMap();
      entry.SetPath(item.path());
      entry.set_source(item.source());
      entry.Set("name", item);
    }
    double probability = 1.0;
    if (entry.IsMap()) {
      if (const ConfigNode* p = entry.Find("probability")) {
        probability = p->AsDouble();
        if (!(probability >= 0.0 && probability <= 1.0)) {
          throw ConfigError(fmt::format(
              "Invalid configuration. {} = {}. Violated constraint: 0 <= "
              "probability <= 1{}",
              p->path(),
              p->Describe(),
              p->source().file.empty() ? ""
                                       : " (" + p->source().ToString() + ")"));
        }
        entry.Erase("probability");
      }
    }
    std::unique_ptr<NoiseModule> module = Instantiate<NoiseModule>(entry, ctx);
    const std::string name = internal::TargetKey(entry);
    try {
      pipeline.Add(name, probability, std::move(module));
    } catch (const ConfigError& error) {
      throw ConfigError(fmt::format("{} ({})", error.what(), item.path()));
    }
  }
  return pipeline;
}

}  // namespace soma
