// The layout a labelling task labels with (issue #25 item 1,
// docs/any_layout_design.md): a layout-conditioned checkpoint
// (model=soma_any_layout) labels the layout of the config's `layout` group
// when the user gives one (`layout=pig39`, `layout=file layout.path=x.json`)
// or when it was trained on sampled layouts (synth/layout_sampler: it holds
// no layout of its own); otherwise the checkpoint's own layout. The label
// slots are computed on the body the checkpoint was trained with.
#pragma once

#include "framework/config/node.h"
#include "framework/model/labeler.h"
#include "framework/registry/registry.h"
#include "framework/train/trainer.h"

#include <optional>
#include <string>
#include <vector>

namespace soma {

/// A layout given at label time, as the labeller's label slots.
struct LabelTimeLayout {
  std::string name;                 // "pig39", or the layout file's path
  std::vector<std::string> labels;  // K marker labels, slot order
  torch::Tensor descriptors;        // K x Q, for LabelerImpl::SetLayout
};

/// True when the task overrides name the `layout` group or its keys.
bool OverridesLayout(const std::vector<std::string>& overrides);

/// The layout checkpoint `checkpoint` (its `info`, its loaded `model`)
/// labels with when it is not its own; nullopt = the checkpoint's labels.
/// ConfigError, one line, for a layout with more labels than a conditioned
/// model's label slots (naming both counts), and for a given layout that
/// differs from a fixed-head model's trained layout (naming both).
std::optional<LabelTimeLayout> ResolveLabelTimeLayout(
    const ConfigNode& cfg,
    const std::vector<std::string>& overrides,
    const CheckpointInfo& info,
    const std::string& checkpoint,
    const Labeler& model,
    BuildContext& build);

}  // namespace soma
