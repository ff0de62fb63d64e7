// Motion sources: where the poses that animate synthetic bodies come from.
// One interface for the procedural library (the embedded default) and for
// real clips (BVH, ASF/AMC, AMASS npz) retargeted onto the body; selected with
// `motion=<name>` (configs/motion/).
#pragma once

#include "framework/body/body_model.h"
#include "framework/core/random.h"
#include "framework/motion/pose_sequence.h"

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

enum class Split { kTrain, kVal, kTest };

std::string_view ToString(Split split);
/// "train", "val", "test"; ConfigError otherwise.
Split SplitFromString(std::string_view text);

/// Fractions of clips (files) assigned to validation and test; the rest
/// trains. A clip's split depends only on its name and the seed, so adding a
/// file never moves another one.
struct SplitFractions {
  double val = 0.1;
  double test = 0.1;
};

Split SplitOf(std::string_view clip_name,
              uint64_t seed,
              const SplitFractions& fractions);

class MotionSource {
 public:
  static constexpr std::string_view kRegistryName = "motion";
  virtual ~MotionSource() = default;

  /// The clips of `split`, retargeted to `body` (its mean shape) and
  /// resampled to `frame_rate`. Random choices draw from `rng`.
  virtual std::vector<PoseSequence> Load(const BodyModel& body,
                                         Split split,
                                         double frame_rate,
                                         Rng& rng) const = 0;
};

/// Registers the motion sources and the `motion` config group.
void RegisterMotionSources();

}  // namespace soma
