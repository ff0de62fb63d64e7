// Noise modules and noise pipelines (REFERENCE.md 3.4-3.5; Noise-in Bias-out
// appendix C): the corruptions applied to one frame of clean superset markers
// before it becomes a training sample.
//
// A pipeline is an ordered list of modules composed from config
// (`configs/noise/*.yaml`):
//
//   modules:
//     - {name: occlusion, probability: 1.0, max_count: 5}
//     - {name: ghosts, probability: 1.0, distribution: spherical_gaussian,
//        max_count: 3}
//     - {name: permutation}
//
// Every entry names a registered NoiseModule (`Registry<NoiseModule>`, kind
// "noise_module") and may give an application `probability` in [0, 1]
// (default 1); the other keys are the module's own typed options. Each stage
// draws from its own random sub-stream of the frame's stream (named after the
// module; `ghosts`, `ghosts/2` for a repeated module), so adding a stage never
// changes what another stage draws.
//
// Adding a module = one class deriving NoiseModule + one Register() line in
// noise_modules.cc + one YAML under configs/noise/ + a test.
#pragma once

#include "framework/core/random.h"
#include "framework/registry/registry.h"

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// One frame in the pipeline's working form (REFERENCE.md 3.5 steps 1-6).
/// Before any permutation, point i < L is the marker of label i (superset
/// order) and points L..N-1 are the ghost slots. A point is missing iff it is
/// exactly (0, 0, 0); missing points and ghosts carry the null label L.
struct MarkerFrame {
  int num_labels = 0;           // L
  std::vector<float> points;    // N x 3, metres, world
  std::vector<int16_t> labels;  // N label ids, null = L

  /// L labels and N = L + `num_ghost_slots` points, all missing (null).
  void Reset(int num_labels, int num_ghost_slots);

  int num_points() const { return static_cast<int>(labels.size()); }
  int16_t null_label() const { return static_cast<int16_t>(num_labels); }
  float* point(int i) { return points.data() + 3 * static_cast<size_t>(i); }
  const float* point(int i) const {
    return points.data() + 3 * static_cast<size_t>(i);
  }
  /// Not (0, 0, 0).
  bool IsPresent(int i) const {
    const float* p = point(i);
    return p[0] != 0.0f || p[1] != 0.0f || p[2] != 0.0f;
  }
  /// A labelled marker that is present ("available" in REFERENCE.md 3.5).
  bool IsAvailableMarker(int i) const {
    return labels[i] != null_label() && IsPresent(i);
  }
  /// Sets point i to (x, y, z) with label `label`.
  void Set(int i, float x, float y, float z, int16_t label);
  /// Makes point i missing: (0, 0, 0), null label.
  void Remove(int i);
  /// Number of available markers.
  int NumAvailableMarkers() const;
  /// Labels every missing point null (REFERENCE.md 3.5 step 5).
  void NullMissing();
};

/// A corruption of one frame. Implementations are immutable after
/// construction (Apply is const and called from many threads).
class NoiseModule {
 public:
  static constexpr std::string_view kRegistryName = "noise_module";
  virtual ~NoiseModule() = default;

  /// Ghost slots this module writes (its maximum ghost count; 0 for modules
  /// that only move or remove markers).
  virtual int num_ghost_slots() const { return 0; }
  /// Checks the module against the superset labels (L = labels.size());
  /// ConfigError naming the option (e.g. more occlusions than markers, a
  /// residual bank of another superset).
  virtual void Validate(const std::vector<std::string>& /*labels*/) const {}
  /// Corrupts `frame`. `ghost_begin` is the first of this module's
  /// num_ghost_slots() point indices. Draws only from `rng`.
  virtual void Apply(MarkerFrame* frame, int ghost_begin, Rng& rng) const = 0;
};

/// An ordered list of noise modules with application probabilities.
class NoisePipeline {
 public:
  NoisePipeline();
  ~NoisePipeline();
  NoisePipeline(NoisePipeline&&) noexcept;
  NoisePipeline& operator=(NoisePipeline&&) noexcept;

  /// Appends a stage. `name` is the module's registry name (used for its
  /// random sub-stream and in messages). ConfigError for a probability
  /// outside [0, 1]; InternalError if a stage follows `permutation` (which
  /// must be last: later stages would see shuffled slots).
  void Add(std::string name,
           double probability,
           std::unique_ptr<NoiseModule> module);

  int num_stages() const;
  /// Module names in order.
  std::vector<std::string> stage_names() const;
  double probability(int stage) const;
  const NoiseModule& module(int stage) const;

  /// Sum of the ghost modules' maximum counts: frames have N = L + this
  /// points.
  int num_ghost_slots() const;

  /// Checks every module against the superset labels (ConfigError).
  void Validate(const std::vector<std::string>& labels) const;

  /// Runs the stages in order on `frame` (Reset to L + num_ghost_slots()
  /// points; ShapeError otherwise), each with probability p using the
  /// sub-stream of `rng` named after the stage, then NullMissing(). `rng` is
  /// only used as a seed source (its state is not advanced). ConfigError if
  /// a module does not fit L (more occlusions than markers).
  void Apply(MarkerFrame* frame, const Rng& rng) const;

  /// One line: "occlusion(p=1) -> ghosts(p=1) -> permutation(p=1)".
  std::string Describe() const;

 private:
  struct Stage;
  std::vector<Stage> stages_;
};

/// Builds the pipeline of a `noise:` config node: `{modules: [...]}` (a null
/// node or an empty list = no noise). Unknown module names list the
/// registered ones; unknown keys and bad options are ConfigErrors with the
/// key path.
NoisePipeline BuildNoisePipeline(const ConfigNode& noise_cfg,
                                 BuildContext& ctx);

/// Registers the built-in noise modules (noise_modules.cc).
void RegisterNoiseModules();

}  // namespace soma
