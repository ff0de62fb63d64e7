#include "framework/tasks/label_layout.h"

#include "framework/body/marker_layout.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/model/label_encoder.h"
#include "framework/tasks/components.h"

#include <fmt/format.h>

#include <algorithm>

namespace soma {
namespace {

/// The built-in layout's name (`layout:` of a `name: builtin` node), the
/// path of a `name: file` node, else the source's name.
std::string LayoutName(const ConfigNode* layout) {
  if (layout == nullptr || !layout->IsMap()) return "?";
  const ConfigNode* name = layout->Find("name");
  for (const char* key : {"layout", "path"}) {
    if (const ConfigNode* value = layout->Find(key);
        value != nullptr && value->IsScalar() && !value->IsNull()) {
      return value->text();
    }
  }
  return name != nullptr && name->IsScalar() ? name->text() : "?";
}

/// The composed config the checkpoint was trained with (null if unreadable).
std::optional<ConfigNode> TrainingConfig(const CheckpointInfo& info) {
  if (info.config_yaml.empty()) return std::nullopt;
  try {
    return ParseYaml(info.config_yaml, "checkpoint config");
  } catch (const Error&) {
    return std::nullopt;
  }
}

}  // namespace

bool OverridesLayout(const std::vector<std::string>& overrides) {
  for (std::string o : overrides) {
    while (!o.empty() && (o[0] == '+' || o[0] == '~')) o.erase(0, 1);
    if (o.rfind("layout=", 0) == 0 || o.rfind("layout.", 0) == 0) return true;
  }
  return false;
}

std::optional<LabelTimeLayout> ResolveLabelTimeLayout(
    const ConfigNode& cfg,
    const std::vector<std::string>& overrides,
    const CheckpointInfo& info,
    const std::string& checkpoint,
    const Labeler& model,
    BuildContext& build) {
  const bool given = OverridesLayout(overrides);
  const bool sampled = info.model_config.Find("layout_sampler") != nullptr;
  const std::optional<ConfigNode> trained = TrainingConfig(info);
  const std::string name = LayoutName(cfg.Find("layout"));
  if (!model->conditioned()) {
    if (!given) return std::nullopt;
    std::vector<std::string> labels = BuildLayoutLabels(cfg, build);
    std::vector<std::string> trained_labels;
    for (const std::string& l : info.labels) {
      trained_labels.push_back(CanonicalMarkerLabel(l));
    }
    std::sort(labels.begin(), labels.end());
    std::sort(trained_labels.begin(), trained_labels.end());
    if (labels != trained_labels) {
      throw ConfigError(fmt::format(
          "label: layout '{}' ({} labels) differs from the layout '{}' ({} "
          "labels) that checkpoint {} was trained on; a fixed-head labeller "
          "labels only its trained layout (train model=soma_any_layout to "
          "label other layouts)",
          name,
          labels.size(),
          trained.has_value() ? LayoutName(trained->Find("layout")) : "?",
          info.labels.size(),
          checkpoint));
    }
    return std::nullopt;
  }
  if (!given && !sampled) return std::nullopt;
  // The slots on the body the checkpoint was trained with.
  const BodyModel body = trained.has_value() && trained->Find("body")
                             ? BuildBody(*trained, build)
                             : BuildBody(cfg, build);
  const MarkerLayout layout = BuildLayout(cfg, body, build);
  const int64_t slots = model->num_labels();
  if (layout.num_markers() > slots) {
    throw ConfigError(fmt::format(
        "label: layout '{}' has {} labels, more than the {} label slots of "
        "checkpoint {}: the model is too small for this layout (train it "
        "with synth.layout_sampler.max_labels >= {})",
        name,
        layout.num_markers(),
        slots,
        checkpoint,
        layout.num_markers()));
  }
  LabelTimeLayout out;
  out.name = name;
  out.labels = layout.Labels();
  out.descriptors =
      LayoutSlotDescriptors(body, layout, model->descriptor_width());
  SOMA_LOG(INFO,
           "label: layout '{}' ({} labels, {}) on the checkpoint's body '{}', "
           "for a layout-conditioned model with {} label slots",
           name,
           layout.num_markers(),
           given ? "given at label time"
                 : "the config's layout: the model was trained on sampled "
                   "layouts",
           body.name,
           slots);
  return out;
}

}  // namespace soma
