// The synthesizer (REFERENCE 3.2-3.5): body + shape prior + motion + marker
// layouts -> clean labelled superset markers -> noise pipeline -> padded,
// permuted, labelled point-cloud frames.
//
// Frame i of a stream depends only on (seed, i): generation is
// embarrassingly parallel, any range can be regenerated (resume), and the
// same seed gives byte-identical frames at any thread count.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"
#include "framework/config/node.h"
#include "framework/io/mocap_dataset.h"
#include "framework/motion/pose_sequence.h"
#include "framework/synth/layout_sampler.h"
#include "framework/synth/noise.h"

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace soma {

/// Options of the clean-frame synthesis (config group keys under `synth:`).
struct SynthesisOptions {
  /// n-ring of each label's vertex from which its vertex is drawn
  /// (REFERENCE 3.3); 0 = the layouts' own vertices only.
  int marker_ring = 1;
  /// Frames that share one random placement draw (REFERENCE: 32).
  int placement_block = 32;
  /// A random rotation U(-pi, pi) about the vertical axis per frame.
  bool random_rotation = true;
  /// Scale of the betas prior draw (N(0, 1) * beta_stddev * shape_scale).
  double shape_scale = 1.0;
  /// Frame rate the motion clips are resampled to (Hz; REFERENCE 3.2: ~30).
  /// Used by BuildSynthesizer when loading the motion source.
  double frame_rate = 30.0;
  /// Training layouts merged into the superset: built-in layout names
  /// (cmu41, pig39, soma53, superset89) or layout JSON paths. Empty = the
  /// config's `layout` group. Used by BuildSynthesizer.
  std::vector<std::string> layouts;
  /// A layout per placement block for a layout-conditioned labeller
  /// (`synth.layout_sampler`, config group synth/layout_sampler; unset =
  /// today's superset frames). See Synthesizer.
  std::optional<LayoutSamplerOptions> layout_sampler;
  void Validate() const;  // ConfigError on violation
};

/// Decodes the `synth:` config node (unknown keys are errors) and validates.
SynthesisOptions DecodeSynthesisOptions(const ConfigNode& node);

class Synthesizer {
 public:
  /// `layouts`: the training layouts (>= 1); their superset (MergeLayouts)
  /// defines the L labels. Each frame uses one layout chosen uniformly.
  ///
  /// With `options.layout_sampler` the frames are for a layout-conditioned
  /// labeller instead (docs/any_layout_design.md, "The data"): `layouts` is
  /// ignored, a LayoutSampler draws one of its layouts per placement
  /// block (Draw(seed, block)), the block's markers are that layout's
  /// (each from its n-ring, as above), and a frame's labels are slot
  /// indices of the draw (L = max_labels slots, null = L). N = the largest
  /// sampled layout's marker count + ghost slots (frames of smaller layouts
  /// are padded with missing points). The frames carry the draw in
  /// LabeledFrames::slots (rows of slot_table()). superset() is then the
  /// merge of the sampled layouts (for information).
  /// `motions`: >= 1 non-empty sequences. ConfigError/ShapeError on bad
  /// input.
  Synthesizer(const BodyModel& body,
              std::vector<MarkerLayout> layouts,
              std::vector<PoseSequence> motions,
              NoisePipeline noise,
              const SynthesisOptions& options = {});
  ~Synthesizer();
  Synthesizer(Synthesizer&&) noexcept;
  Synthesizer& operator=(Synthesizer&&) noexcept;

  /// Superset labels (id order) and sizes: N = L + ghost slots.
  const std::vector<std::string>& labels() const;
  int num_labels() const;
  int num_points() const;
  const MarkerLayout& superset() const;
  const NoisePipeline& noise() const;
  const SynthesisOptions& options() const;
  /// Number of training layouts and whether label l belongs to layout k.
  int num_layouts() const;
  bool LayoutHasLabel(int layout, int label) const;
  /// Total motion frames sampled from (uniformly) and their frame rate.
  int64_t num_motion_frames() const;
  double frame_rate() const;
  /// Distinct candidate marker positions (vertex, skin distance) over all
  /// labels: the markers computed per frame.
  int num_candidate_markers() const;
  /// The sampled layouts' slot descriptors (null without a layout sampler).
  const SlotTable* slot_table() const;
  /// The layout sampler (null without one).
  const LayoutSampler* layout_sampler() const;

  /// Frames [first, first + count) of the stream `seed` into `out` (resized
  /// to `count` frames of num_points()). Uses `threads` worker threads;
  /// results do not depend on `threads`.
  void Generate(uint64_t seed,
                int64_t first,
                int64_t count,
                LabeledFrames* out,
                int threads = 1) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace soma
