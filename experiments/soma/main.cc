// The `soma` executable: parse, compose, dispatch. All work happens in
// framework/; see README.md for the commands.
//
//   soma                        the default task on the default config
//   soma <command> [overrides]  a task (train, label, ...) = task=<command>
//   soma reproduce <name>       a paper table from ablations/<name>.yaml
//   soma solve <take.c3d>       fit the body to a labelled capture
//   soma -m a=1,2 b=x,y         a Hydra-style multirun sweep
//   soma sweep status|cancel D  a SLURM sweep's jobs (hydra/launcher=slurm)
#include "framework/config/app.h"
#include "framework/config/slurm_launcher.h"
#include "framework/core/error.h"
#include "framework/core/resources.h"
#include "framework/framework.h"
#include "framework/registry/registry.h"
#include "framework/tasks/task.h"

#include <algorithm>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

int main(int argc, char** argv) {
  soma::InitFramework();
  std::vector<std::string> args(argv + 1, argv + argc);
  if (!args.empty() && args.front() == "sweep") {
    return soma::RunSweepCommand({args.begin() + 1, args.end()});
  }
  // `soma <command> ...` selects the task config group option <command>.
  if (!args.empty() && soma::GetRegistry<soma::Task>().Has(args.front())) {
    // A command's main input may be given positionally:
    // `soma reproduce table5`, `soma solve take.c3d`, `soma label take.c3d`,
    // `soma fit_layout take.c3d`, `soma calibrate cmu41`.
    static const std::map<std::string, std::string> kPositional = {
        {"reproduce", "ablation"},
        {"calibrate", "model"},
        {"solve", "input"},
        {"label", "input"},
        {"fit_layout", "input"},
        {"label_eval", "input"},
        {"stream", "c3d.path"},
        {"trim", "input"},
        {"view", "input"}};
    const auto positional = kPositional.find(args.front());
    if (positional != kPositional.end() && args.size() > 1 &&
        args[1].find('=') == std::string::npos && args[1].front() != '-') {
      args[1] = "task." + positional->second + "=" + args[1];
    }
    args.front() = "task=" + args.front();
  }
  // The configs/ of the resource root, found from this executable's own
  // location or $SOMA_HOME (framework/core/resources.h); -cp/-cd still
  // choose another primary config directory.
  std::string config_dir;
  try {
    config_dir = (soma::FindResourceRoot() / "configs").string();
  } catch (const soma::Error& e) {
    const bool config_path_given =
        std::any_of(args.begin(), args.end(), [](const std::string& a) {
          return a == "-cp" || a == "-cd" || a.rfind("--config-path", 0) == 0 ||
                 a.rfind("--config-dir", 0) == 0;
        });
    if (!config_path_given) {
      std::fprintf(stderr, "Error: %s\n", e.what());
      return 1;
    }
    config_dir = "configs";
  }
  return soma::RunHydraApp(args, config_dir, "config", soma::RunConfiguredTask);
}
