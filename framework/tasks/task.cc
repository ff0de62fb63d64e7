#include "framework/tasks/task.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/registry/registry.h"

namespace soma {

// Each task registers itself from its own file.
void RegisterAttentionSpanTask(Registry<Task>& registry);
void RegisterCalibrateTask(Registry<Task>& registry);
void RegisterCorruptTask(Registry<Task>& registry);
void RegisterCoverageTask(Registry<Task>& registry);
void RegisterDemoTask(Registry<Task>& registry);
void RegisterEvalTask(Registry<Task>& registry);
void RegisterFitLayoutTask(Registry<Task>& registry);
void RegisterFitPriorTask(Registry<Task>& registry);
void RegisterInspectTask(Registry<Task>& registry);
void RegisterLabelTask(Registry<Task>& registry);
void RegisterLabelEvalTask(Registry<Task>& registry);
void RegisterNoiseBankTask(Registry<Task>& registry);
void RegisterRealismTask(Registry<Task>& registry);
void RegisterReproduceTask(Registry<Task>& registry);
void RegisterSolveTask(Registry<Task>& registry);
void RegisterStreamTask(Registry<Task>& registry);
void RegisterSynthTask(Registry<Task>& registry);
void RegisterTrainTask(Registry<Task>& registry);
void RegisterTrimTask(Registry<Task>& registry);
void RegisterViewTask(Registry<Task>& registry);

void RegisterTasks() {
  Registry<Task>& registry = GetRegistry<Task>();
  RegisterAttentionSpanTask(registry);
  RegisterCalibrateTask(registry);
  RegisterCorruptTask(registry);
  RegisterCoverageTask(registry);
  RegisterDemoTask(registry);
  RegisterEvalTask(registry);
  RegisterFitLayoutTask(registry);
  RegisterFitPriorTask(registry);
  RegisterInspectTask(registry);
  RegisterLabelTask(registry);
  RegisterLabelEvalTask(registry);
  RegisterNoiseBankTask(registry);
  RegisterRealismTask(registry);
  RegisterReproduceTask(registry);
  RegisterSolveTask(registry);
  RegisterStreamTask(registry);
  RegisterSynthTask(registry);
  RegisterTrainTask(registry);
  RegisterTrimTask(registry);
  RegisterViewTask(registry);
  RegisterConfigGroup<Task>("task");
}

void RunConfiguredTask(const ConfigNode& cfg, RunContext& ctx) {
  const ConfigNode* task_node = cfg.Find("task");
  if (task_node == nullptr) {
    throw ConfigError(
        "Invalid configuration. The config has no 'task' node; select one "
        "with task=<name> or a command (soma <command>)");
  }
  BuildContext build(ctx.seed, ctx.output_dir.string());
  std::unique_ptr<Task> task = Instantiate<Task>(*task_node, build);
  task->Run(cfg, ctx);
}

void ReadConfidenceKeys(const ConfigNode& node,
                        ConfigReader& reader,
                        double* min_confidence,
                        int* review_gap,
                        std::string* calibration) {
  reader.Read("min_confidence", min_confidence);
  reader.Check("min_confidence",
               *min_confidence >= 0 && *min_confidence <= 1,
               "0 <= min_confidence <= 1");
  reader.Read("review_gap", review_gap);
  reader.Check("review_gap", *review_gap >= 0, "review_gap >= 0");
  if (const ConfigNode* value = node.Find("calibration");
      value != nullptr && value->IsNull()) {
    reader.Ignore("calibration");
    *calibration = "none";
  } else {
    reader.Read("calibration", calibration);
  }
}

}  // namespace soma
