// Tasks: what one job of `soma` runs. `soma <command>` selects
// `task=<command>`; the task's options live under `task:` in the config.
#pragma once

#include "framework/config/app.h"
#include "framework/config/node.h"

#include <string>
#include <string_view>

namespace soma {

class ConfigReader;

/// A runnable job (demo now; synth, train, label, eval, solve as their
/// modules land). Implementations are thin: decode options, call the
/// framework, report metrics.
class Task {
 public:
  static constexpr std::string_view kRegistryName = "task";
  virtual ~Task() = default;

  /// `cfg` is the whole resolved task config (the task's own options are
  /// `cfg.at("task")`); write outputs under `ctx.output_dir`.
  virtual void Run(const ConfigNode& cfg, RunContext& ctx) = 0;
};

/// Registers the built-in tasks and the `task` config group.
void RegisterTasks();

/// The TaskFn of the `soma` executable: builds `cfg.task` through the
/// registry and runs it.
void RunConfiguredTask(const ConfigNode& cfg, RunContext& ctx);

/// Reads the confidence keys `label` and `label_eval` share from the task
/// node `node` (through its `reader`): `min_confidence` in [0, 1],
/// `review_gap` >= 0 and `calibration` (auto | none | a calibration.yaml; null
/// means none).
void ReadConfidenceKeys(const ConfigNode& node,
                        ConfigReader& reader,
                        double* min_confidence,
                        int* review_gap,
                        std::string* calibration);

}  // namespace soma
