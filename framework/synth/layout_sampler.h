// Layouts per placement block for the layout-conditioned labeller (issue #25
// item 1, docs/any_layout_design.md "The data"): which marker layout a block
// of frames is synthesised with, and the label slots the model gets for it.
//
//   BuiltinLayoutSampler  one of the listed layouts (built-in names or layout
//                         JSON paths) per block of `block_size` frames, drawn
//                         uniformly; its markers fill the first K of L_max
//                         slots in a random order (the model must not learn
//                         the order of a layout), the rest are padded.
//
// A draw depends only on (seed, block): Rng(seed).Stream("layout").Stream(
// block). The Synthesizer draws one per placement block when
// SynthesisOptions::layout_sampler is set (config group
// synth/layout_sampler); the frames carry the draw as rows of SlotTable()
// (LabeledFrames::slots).
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"
#include "framework/body/vertex_descriptors.h"
#include "framework/config/node.h"
#include "framework/io/mocap_dataset.h"

#include <Eigen/Core>

#include <cstdint>
#include <string>
#include <vector>

namespace soma {

/// Options of the layout samplers.
struct LayoutSamplerOptions {
  /// Built-in layout names (cmu41, pig39, soma53, superset89) or layout JSON
  /// paths.
  std::vector<std::string> layouts = {"cmu41", "pig39", "soma53"};
  int max_labels = 96;        // L_max, label slots per frame
  int block_size = 32;        // frames per placement block (REFERENCE 3.3)
  bool shuffle_slots = true;  // random slot order per block
  /// Block b gets layout b mod K instead of a uniform draw (validation: every
  /// layout gets an equal share of a fixed set of frames).
  bool cycle_layouts = false;
  void Validate() const;  // ConfigError on violation
};

/// Decodes a `synth.layout_sampler` node (`name: builtin`, `layouts`,
/// `max_labels`, `shuffle_slots`; unknown keys and other names are
/// ConfigErrors). The block size is the synthesizer's placement block.
LayoutSamplerOptions DecodeLayoutSamplerOptions(const ConfigNode& node);

/// One block's layout and the order of its markers in the slots.
struct LayoutDraw {
  int layout = 0;  // index into LayoutSamplerOptions::layouts
  /// Slot -> marker index in that layout, -1 for a padded slot (L_max).
  std::vector<int> slot_marker;
  bool operator==(const LayoutDraw& other) const = default;
};

class BuiltinLayoutSampler {
 public:
  /// Builds the listed layouts on `body` and their descriptors. ConfigError
  /// naming the layout when it has more markers than `max_labels` (the model
  /// is too small for it) or cannot be built.
  BuiltinLayoutSampler(const BodyModel& body, LayoutSamplerOptions options);

  /// The draw of placement block `block` of stream `seed`.
  LayoutDraw Draw(uint64_t seed, int64_t block) const;
  /// The block of frame `frame`.
  int64_t BlockOf(int64_t frame) const { return frame / options_.block_size; }

  /// Label of every slot of `draw` ("" for a padded slot).
  std::vector<std::string> SlotLabels(const LayoutDraw& draw) const;
  /// Descriptors `L_max x Q` (padded rows zero) and mask (1 = label) of
  /// `draw`.
  Eigen::MatrixXf SlotDescriptors(const LayoutDraw& draw) const;
  std::vector<uint8_t> SlotMask(const LayoutDraw& draw) const;
  /// The descriptors of every marker of every listed layout (layout k's
  /// marker m is row row_offset(k) + m), their labels and layouts.
  SlotTable BuildSlotTable() const;
  int row_offset(int k) const { return row_offsets_[k]; }
  /// Row of SlotTable() of every slot of `draw` (-1 for a padded slot).
  std::vector<int16_t> SlotRows(const LayoutDraw& draw) const;
  /// The most markers of a listed layout.
  int max_layout_markers() const;

  int num_layouts() const { return static_cast<int>(layouts_.size()); }
  const MarkerLayout& layout(int k) const { return layouts_[k]; }
  int descriptor_width() const { return descriptor_width_; }
  const LayoutSamplerOptions& options() const { return options_; }

 private:
  LayoutSamplerOptions options_;
  std::vector<MarkerLayout> layouts_;
  std::vector<Eigen::MatrixXf> descriptors_;  // per layout, K x Q
  std::vector<int> row_offsets_;              // per layout, into the table
  int descriptor_width_ = 0;
};

}  // namespace soma
