// Layouts per placement block for the layout-conditioned labeller (issue #25
// item 1, docs/any_layout_design.md "The data"): which marker layout a block
// of frames is synthesised with, and the label slots the model gets for it.
//
// LayoutSampler draws, per block of `block_size` frames, one layout of
//   - the listed layouts (built-in names or layout JSON paths), uniformly, and
//   - a pool of `random_layouts` random surface layouts (MakeRandomLayout:
//     30-70 markers on distinct vertices anywhere on the body's skin but the
//     soles), built once from `random_seed`, so that the model learns labels
//     as places on the body rather than the names of a few marker sets, and
//   - `perturbed_layouts` perturbed copies of the listed layouts in the same
//     pool (MakePerturbedLayout: each marker kept with probability
//     `perturb_keep` and moved to a random vertex of its `perturb_rings`-ring),
//     the way a lab's marker set differs from the textbook one: a subset,
//     each marker a few centimetres off.
// With both, a block takes the pool with probability `random_share`. The
// layout's markers fill the first K of L_max slots in a random order (the
// model must not learn the order of a layout), the rest are padded.
// Config group synth/layout_sampler: builtin (listed layouts only), mixed
// (listed + pool), random (pool only).
//
// A draw depends only on (seed, block): Rng(seed).Stream("layout").Stream(
// block); without a pool the draws are those of the first version (a
// uniform layout, then the slot permutation). The Synthesizer draws one per
// placement block when SynthesisOptions::layout_sampler is set; the frames
// carry the draw as rows of SlotTable() (LabeledFrames::slots), whose
// `layouts` are the listed layouts plus one group "random" for the pool.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"
#include "framework/body/vertex_descriptors.h"
#include "framework/config/node.h"
#include "framework/core/random.h"
#include "framework/io/mocap_dataset.h"

#include <Eigen/Core>

#include <algorithm>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// Where MakePerturbedLayout moves a kept marker within its `rings`-ring.
enum class PerturbDraw {
  kVertex,  // a uniform vertex of the ring (the marker's own included)
  kRing,    // a uniform ring distance r in [0, rings], then a uniform vertex
            // at exactly r rings
};

/// Options of the layout samplers.
struct LayoutSamplerOptions {
  /// Built-in layout names (cmu41, pig39, soma53, superset89) or layout JSON
  /// paths.
  std::vector<std::string> layouts = {"cmu41", "pig39", "soma53"};
  int max_labels = 96;  // L_max, label slots per frame
  /// Random surface layouts in the pool (0: none).
  int random_layouts = 0;
  int random_min_markers = 30;  // markers of a random layout, uniform in
  int random_max_markers = 70;  // [min, max]
  /// Least distance between two markers of a random layout, metres, on the
  /// rest body (real layouts: 4-10 cm between neighbours).
  double random_min_spacing = 0.04;
  /// Probability that a block takes a layout of the pool (random and
  /// perturbed) when there are listed layouts too.
  double random_share = 0.5;
  uint64_t random_seed = 0;  // seed of the pool (not of the draws)
  /// Perturbed copies of the listed layouts in the pool (0: none).
  int perturbed_layouts = 0;
  /// Probability that a perturbed copy keeps a marker of its listed layout.
  double perturb_keep = 0.8;
  /// A kept marker moves to a uniform vertex of its n-ring (itself included).
  int perturb_rings = 3;
  /// How far a kept marker moves (MakePerturbedLayout): kVertex, to a uniform
  /// vertex of its perturb_rings-ring (the first version; as the rings grow
  /// outwards, most markers move nearly perturb_rings rings), or kRing, to a
  /// uniform vertex at a uniform ring distance in [0, perturb_rings] (as many
  /// markers near their place as far from it).
  PerturbDraw perturb_draw = PerturbDraw::kVertex;
  int block_size = 32;        // frames per placement block (REFERENCE 3.3)
  bool shuffle_slots = true;  // random slot order per block
  /// Block b gets group b mod G (the listed layouts, then the pool as one
  /// group whose member is drawn) instead of a uniform draw (validation:
  /// every group gets an equal share of a fixed set of frames).
  bool cycle_layouts = false;
  void Validate() const;  // ConfigError on violation
};

/// Decodes a `synth.layout_sampler` node (`name`: builtin, mixed or random;
/// `layouts`, `max_labels`, `shuffle_slots`, `random_layouts`,
/// `random_markers: [min, max]`, `random_min_spacing`, `random_share`,
/// `random_seed`, `perturbed_layouts`, `perturb_keep`, `perturb_rings`,
/// `perturb_draw` (vertex or ring);
/// unknown keys and other names are ConfigErrors). The block
/// size is the synthesizer's placement block.
LayoutSamplerOptions DecodeLayoutSamplerOptions(const ConfigNode& node);

/// A layout of `num_markers` markers on distinct vertices of `body`, drawn
/// uniformly over the skin's area (a face by area, then its corner nearest a
/// uniform point of the face), none on a face whose rest normal points
/// down (the soles: cos < -0.7 with up), no two closer than `min_spacing`
/// metres on the rest body. Markers are of type "body" at
/// kDefaultDistanceFromSkin, labelled "<prefix>_00", "<prefix>_01", ...
/// ConfigError when the skin cannot hold that many markers that far apart.
MarkerLayout MakeRandomLayout(const BodyModel& body,
                              int num_markers,
                              double min_spacing,
                              std::string_view prefix,
                              Rng* rng);

/// A perturbed copy of `layout`: each marker kept with probability `keep` (at
/// least one is), moved within the `rings`-ring of its first vertex (the
/// vertex itself included) to a vertex that no other marker of the copy
/// holds, drawn as `draw` says (kRing: when every vertex at the drawn
/// distance is taken, a free one of the whole ring), its type and skin
/// distance kept, labelled "<prefix>_<label>"; a marker whose whole ring is
/// taken is dropped. `neighbours` is VertexNeighbours of the mesh the
/// layout's vertex ids index.
MarkerLayout MakePerturbedLayout(
    const MarkerLayout& layout,
    const std::vector<std::vector<int>>& neighbours,
    double keep,
    int rings,
    std::string_view prefix,
    Rng* rng,
    PerturbDraw draw = PerturbDraw::kVertex);

/// One block's layout and the order of its markers in the slots.
struct LayoutDraw {
  /// Index into layout(): the listed layouts, then the pool (the random
  /// layouts, then the perturbed ones).
  int layout = 0;
  /// Slot -> marker index in that layout, -1 for a padded slot (L_max).
  std::vector<int> slot_marker;
  bool operator==(const LayoutDraw& other) const = default;
};

class LayoutSampler {
 public:
  /// Builds the listed layouts and the random pool on `body` and their
  /// descriptors. ConfigError naming the layout when it has more markers
  /// than `max_labels` (the model is too small for it) or cannot be built.
  LayoutSampler(const BodyModel& body, LayoutSamplerOptions options);

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
  /// The descriptors of every marker of every layout (layout k's marker m
  /// is row row_offset(k) + m), their labels and groups (group(k)).
  SlotTable BuildSlotTable() const;
  int row_offset(int k) const { return row_offsets_[k]; }
  /// Row of SlotTable() of every slot of `draw` (-1 for a padded slot).
  std::vector<int16_t> SlotRows(const LayoutDraw& draw) const;
  /// The most markers of a listed layout.
  int max_layout_markers() const;

  /// Listed layouts and the pool's.
  int num_layouts() const { return static_cast<int>(layouts_.size()); }
  int num_listed() const { return static_cast<int>(options_.layouts.size()); }
  /// Group of layout k: k for a listed layout, num_listed() for the pool.
  int group(int k) const { return std::min(k, num_listed()); }
  const MarkerLayout& layout(int k) const { return layouts_[k]; }
  int descriptor_width() const { return descriptor_width_; }
  const LayoutSamplerOptions& options() const { return options_; }

 private:
  /// Appends `layout`, its descriptors and its first slot-table row.
  void AddLayout(const VertexDescriptors& vertices, MarkerLayout layout);

  LayoutSamplerOptions options_;
  std::vector<MarkerLayout> layouts_;
  std::vector<Eigen::MatrixXf> descriptors_;  // per layout, K x Q
  std::vector<int> row_offsets_;              // per layout, into the table
  int descriptor_width_ = 0;
};

}  // namespace soma
