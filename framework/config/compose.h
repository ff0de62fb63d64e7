// Hydra-style composition (HYDRA.md sections 2-4 and 7): config search path,
// config groups, defaults lists, packages, CLI overrides and the `hydra` node.
#pragma once

#include "framework/config/config_repository.h"
#include "framework/config/interpolation.h"
#include "framework/config/node.h"
#include "framework/config/override.h"

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

enum class RunMode { kRun, kMultirun };

std::string_view ToString(RunMode mode);  // "RUN" / "MULTIRUN"

struct ComposeRequest {
  /// Primary config dir first, then `--config-dir` entries. `hydra.searchpath`
  /// of the primary config is appended during composition.
  std::vector<std::string> search_path;
  /// Primary config name without `.yaml` (may be empty: no primary config).
  std::string config_name = "config";
  /// Parsed CLI overrides in command-line order. In kRun mode a sweep is a
  /// ConfigError ("Ambiguous value for argument ..."); in kMultirun the
  /// caller composes each job with non-sweep overrides only, or composes the
  /// sweep-level config with `allow_sweeps = true` (sweep overrides are then
  /// skipped and only recorded in hydra.overrides.task).
  std::vector<Override> overrides;
  RunMode mode = RunMode::kRun;
  bool allow_sweeps = false;
  std::string job_name = "soma";
};

/// One entry of the final defaults list (`--info defaults`).
struct DefaultsListEntry {
  std::string config_path;  // "db/mysql", "config", or "_self_" owner
  std::string package;      // "" for the global package
  std::string parent;       // config that listed it ("" for the primary)
  bool is_self = false;     // the `_self_` of `config_path`
  std::string group;        // "db" ("" for non-group configs)
  std::string option;       // "mysql"
};

struct ComposeResult {
  /// The composed tree *including* the `hydra` node (hydra.runtime.choices,
  /// hydra.overrides.*, hydra.job.name, hydra.mode, hydra.runtime.
  /// config_sources, and the built-in hydra defaults: run.dir, sweep.dir,
  /// sweep.subdir, output_subdir, job.chdir, launcher.n_jobs,
  /// sweeper.params, searchpath). Struct mode is on.
  ConfigNode root;
  std::vector<DefaultsListEntry> defaults;
  /// group@package (or group) -> selected option, in defaults-list order
  /// ("null" for a null selection; option lists are not choices, as in
  /// Hydra). hydra.runtime.choices holds the same with null nodes.
  std::vector<std::pair<std::string, std::string>> choices;
  /// The search path actually used (incl. hydra.searchpath entries).
  std::vector<std::string> search_path;
};

/// Composes a configuration. Throws ConfigError with Hydra's wording for
/// every error listed in HYDRA.md section 3 and 4.
ComposeResult Compose(const ComposeRequest& request);

/// The task config: the composed root without the `hydra` node.
ConfigNode TaskConfig(const ConfigNode& composed_root);

/// `--info defaults` text (one line per final defaults-list entry).
std::string FormatDefaultsList(const ComposeResult& result);

/// The built-in `hydra` node defaults, as a root map with the single key
/// `hydra` (merged before every config file): run/sweep dirs, output_subdir,
/// mode RUN, job (name and id `???` until composition fills them),
/// launcher.n_jobs, sweeper.params, empty overrides/choices, runtime.cwd and
/// runtime.version. Instantiates nothing.
ConfigNode HydraDefaults();

}  // namespace soma
