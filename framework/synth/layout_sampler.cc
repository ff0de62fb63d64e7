#include "framework/synth/layout_sampler.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/random.h"

#include <fmt/format.h>

#include <algorithm>
#include <utility>

namespace soma {

void LayoutSamplerOptions::Validate() const {
  auto fail = [](std::string_view key,
                 const std::string& value,
                 std::string_view constraint) {
    throw ConfigError(
        fmt::format("Invalid configuration. layout_sampler.{} = {}. Violated "
                    "constraint: {}",
                    key,
                    value,
                    constraint));
  };
  if (layouts.empty()) fail("layouts", "[]", "at least one layout");
  if (max_labels <= 0) {
    fail("max_labels", std::to_string(max_labels), "max_labels > 0");
  }
  if (block_size <= 0) {
    fail("block_size", std::to_string(block_size), "block_size > 0");
  }
}

LayoutSamplerOptions DecodeLayoutSamplerOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  LayoutSamplerOptions options;
  std::string name;
  reader.Require("name", &name);
  reader.Check("name", name == "builtin", "name is builtin");
  reader.Read("layouts", &options.layouts);
  reader.Read("max_labels", &options.max_labels);
  reader.Read("shuffle_slots", &options.shuffle_slots);
  reader.Check("layouts", !options.layouts.empty(), "at least one layout");
  reader.Check("max_labels", options.max_labels > 0, "max_labels > 0");
  reader.Check("max_labels",
               options.max_labels <= 32767,
               "max_labels <= 32767 (int16 label ids)");
  reader.Finish();
  options.Validate();
  return options;
}

BuiltinLayoutSampler::BuiltinLayoutSampler(const BodyModel& body,
                                           LayoutSamplerOptions options)
    : options_(std::move(options)) {
  options_.Validate();
  const VertexDescriptors vertices = ComputeVertexDescriptors(body);
  descriptor_width_ = LabelDescriptorWidth(vertices.num_joints());
  for (const std::string& name : options_.layouts) {
    const bool is_file =
        name.size() > 5 && name.compare(name.size() - 5, 5, ".json") == 0;
    MarkerLayout layout = is_file ? LoadMarkerLayoutForBody(name, body)
                                  : MakeBuiltinLayout(body, name);
    if (layout.num_markers() > options_.max_labels) {
      throw ConfigError(fmt::format(
          "layout_sampler: layout '{}' has {} markers, more than the model's "
          "{} label slots (model max_labels)",
          name,
          layout.num_markers(),
          options_.max_labels));
    }
    row_offsets_.push_back(row_offsets_.empty()
                               ? 0
                               : row_offsets_.back() +
                                     layouts_.back().num_markers());
    descriptors_.push_back(LayoutDescriptors(vertices, layout));
    layouts_.push_back(std::move(layout));
  }
}

LayoutDraw BuiltinLayoutSampler::Draw(uint64_t seed, int64_t block) const {
  Rng rng = Rng(seed).Stream("layout").Stream(static_cast<uint64_t>(block));
  LayoutDraw draw;
  draw.layout = static_cast<int>(rng.UniformInt(0, num_layouts() - 1));
  if (options_.cycle_layouts) {
    draw.layout = static_cast<int>(block % num_layouts());
  }
  const int k = layouts_[draw.layout].num_markers();
  draw.slot_marker.assign(options_.max_labels, -1);
  if (options_.shuffle_slots) {
    const std::vector<int> order = rng.Permutation(k);
    for (int s = 0; s < k; ++s) draw.slot_marker[s] = order[s];
  } else {
    for (int s = 0; s < k; ++s) draw.slot_marker[s] = s;
  }
  return draw;
}

std::vector<std::string> BuiltinLayoutSampler::SlotLabels(
    const LayoutDraw& draw) const {
  std::vector<std::string> labels(draw.slot_marker.size());
  for (size_t s = 0; s < labels.size(); ++s) {
    if (draw.slot_marker[s] >= 0) {
      labels[s] = layouts_[draw.layout].markers[draw.slot_marker[s]].label;
    }
  }
  return labels;
}

Eigen::MatrixXf BuiltinLayoutSampler::SlotDescriptors(
    const LayoutDraw& draw) const {
  const Eigen::MatrixXf& q = descriptors_[draw.layout];
  Eigen::MatrixXf out = Eigen::MatrixXf::Zero(
      static_cast<Eigen::Index>(draw.slot_marker.size()), descriptor_width_);
  for (size_t s = 0; s < draw.slot_marker.size(); ++s) {
    if (draw.slot_marker[s] >= 0) {
      out.row(static_cast<Eigen::Index>(s)) = q.row(draw.slot_marker[s]);
    }
  }
  return out;
}

std::vector<uint8_t> BuiltinLayoutSampler::SlotMask(
    const LayoutDraw& draw) const {
  std::vector<uint8_t> mask(draw.slot_marker.size());
  for (size_t s = 0; s < mask.size(); ++s) {
    mask[s] = draw.slot_marker[s] >= 0 ? 1 : 0;
  }
  return mask;
}

SlotTable BuiltinLayoutSampler::BuildSlotTable() const {
  SlotTable table;
  table.width = descriptor_width_;
  table.layouts = options_.layouts;
  for (int k = 0; k < num_layouts(); ++k) {
    const Eigen::MatrixXf& q = descriptors_[k];
    for (Eigen::Index m = 0; m < q.rows(); ++m) {
      for (Eigen::Index c = 0; c < q.cols(); ++c) {
        table.rows.push_back(q(m, c));
      }
      table.names.push_back(layouts_[k].markers[m].label);
      table.row_layout.push_back(k);
    }
  }
  return table;
}

std::vector<int16_t> BuiltinLayoutSampler::SlotRows(
    const LayoutDraw& draw) const {
  std::vector<int16_t> rows(draw.slot_marker.size(), -1);
  for (size_t s = 0; s < rows.size(); ++s) {
    if (draw.slot_marker[s] >= 0) {
      rows[s] =
          static_cast<int16_t>(row_offsets_[draw.layout] + draw.slot_marker[s]);
    }
  }
  return rows;
}

int BuiltinLayoutSampler::max_layout_markers() const {
  int k = 0;
  for (const MarkerLayout& layout : layouts_) {
    k = std::max(k, layout.num_markers());
  }
  return k;
}

}  // namespace soma
