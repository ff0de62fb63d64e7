// RunHydraApp: the command-line application around a task (HYDRA.md sections
// 8 and 11): flags, composition, run and multirun modes, output directories
// with `.hydra/{config,hydra,overrides}.yaml`, per-job log files, provenance,
// the resumable job ledger, seed aggregation and the parallel launcher.
#pragma once

#include "framework/config/node.h"

#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// What a task gets besides its config.
class RunContext {
 public:
  /// The job's output directory (hydra.runtime.output_dir); exists.
  std::filesystem::path output_dir;
  /// hydra.job.name and hydra.job.num (0 in run mode).
  std::string job_name = "soma";
  int job_num = 0;
  /// The job's task overrides, verbatim.
  std::vector<std::string> overrides;
  /// The resolved `hydra` node of this job.
  ConfigNode hydra;
  /// The root seed (`seed` of the task config, 0 if absent).
  uint64_t seed = 0;
  /// Threads this job may use (`threads` of the task config, or the
  /// launcher's share).
  int num_threads = 1;

  /// Records a final metric of the job; written to `<output_dir>/metrics.yaml`
  /// and into the sweep ledger and summary tables.
  void ReportMetric(const std::string& name, double value) {
    metrics_[name] = value;
  }
  const std::map<std::string, double>& metrics() const { return metrics_; }

 private:
  std::map<std::string, double> metrics_;
};

/// A task: receives the task config (the composed tree without `hydra`, with
/// interpolations resolved and `???` left missing) and the run context.
using TaskFn = std::function<void(const ConfigNode& task_cfg, RunContext& ctx)>;

/// Parses argv, composes, runs the task once (run mode) or over the sweep
/// (`-m`), writes output directories, catches every soma::Error, logs it as
/// one line and returns the exit code (0 ok, 1 error, 2 usage error).
int RunHydraApp(int argc,
                char** argv,
                std::string_view default_config_dir,
                std::string_view default_config_name,
                const TaskFn& task);

/// Same, with the arguments as a vector (argv[0] excluded).
int RunHydraApp(const std::vector<std::string>& args,
                std::string_view default_config_dir,
                std::string_view default_config_name,
                const TaskFn& task);

}  // namespace soma
