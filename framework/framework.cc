#include "framework/framework.h"

#include "framework/body/body_source.h"
#include "framework/config/interpolation.h"
#include "framework/core/random.h"
#include "framework/core/resources.h"
#include "framework/model/register.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"
#include "framework/solve/pose_prior.h"
#include "framework/stream/frame_source.h"
#include "framework/synth/register.h"
#include "framework/tasks/task.h"
#include "framework/train/register.h"

#include <fmt/format.h>

#include <algorithm>
#include <filesystem>
#include <mutex>

namespace soma {
namespace {

/// `${soma.sweep_id:}`: a short stable id of a multirun (primary config name
/// and its task overrides, sorted), so that re-running the same `-m` command
/// lands in the same sweep directory and resumes from its ledger.
ConfigNode SweepIdResolver(const std::vector<ConfigNode>& args,
                           const ResolverCall& call) {
  std::vector<std::string> parts;
  if (const ConfigNode* name = call.root->FindPath("hydra.job.config_name");
      name && name->IsString()) {
    parts.push_back("cn=" + name->AsString());
  }
  if (const ConfigNode* task = call.root->FindPath("hydra.overrides.task");
      task && task->IsList()) {
    std::vector<std::string> overrides;
    for (const ConfigNode& item : task->items())
      overrides.push_back(item.text());
    std::sort(overrides.begin(), overrides.end());
    parts.insert(parts.end(), overrides.begin(), overrides.end());
  }
  const std::string joined = fmt::format("{}", fmt::join(parts, "\n"));
  return ConfigNode::LiteralString(
      fmt::format("{:016x}", Fnv1a64(joined)).substr(0, 10));
}

/// `${soma.home:}`: the resource root (configs/, models/, data/) found from
/// the executable's location or $SOMA_HOME (framework/core/resources.h).
/// `${soma.home:data/x.c3d}` joins a relative path to it.
ConfigNode HomeResolver(const std::vector<ConfigNode>& args,
                        const ResolverCall&) {
  std::filesystem::path path = FindResourceRoot();
  for (const ConfigNode& arg : args) {
    if (arg.IsScalar() && !arg.IsNull() && !arg.text().empty()) {
      path /= arg.text();
    }
  }
  return ConfigNode::LiteralString(path.string());
}

}  // namespace

void RegisterBuiltins() {
  DefaultResolvers().Register("soma.sweep_id", SweepIdResolver);
  DefaultResolvers().Register("soma.home", HomeResolver);
  RegisterBodySources();
  RegisterMotionSources();
  RegisterPosePriors();
  RegisterSynthComponents();
  RegisterModelComponents();
  RegisterTrainComponents();
  RegisterFrameSources();
  RegisterTasks();
}

void InitFramework() {
  static std::once_flag once;
  std::call_once(once, [] {
    RegisterBuiltins();
    FreezeRegistries();
  });
}

}  // namespace soma
