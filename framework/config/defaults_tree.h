// The defaults tree of Hydra-style composition (HYDRA.md sections 3-4):
// parses `defaults:` lists, applies defaults-list overrides (`group=opt`,
// `+group=opt`, `~group`, `override` entries) and interpolations, and
// flattens the tree into the final defaults list that Compose() merges.
// Internal to the config module.
#pragma once

#include "framework/config/compose.h"
#include "framework/config/config_repository.h"
#include "framework/config/node.h"
#include "framework/config/override.h"
#include "framework/config/yaml_io.h"

#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace soma {
namespace internal {

/// One entry of the final defaults list and the config it merges.
struct ResolvedDefault {
  DefaultsListEntry entry;
  bool primary = false;  // the primary config (or its `_self_`)
  ConfigNode content;    // the config file's body without `defaults`
};

struct DefaultsListResult {
  /// The final defaults list, in merge order.
  std::vector<ResolvedDefault> defaults;
  /// group@package (or group) -> option in defaults-list order ("null" for a
  /// null selection): ComposeResult::choices.
  std::vector<std::pair<std::string, std::string>> choices;
  /// The same choices with a null selection as nullopt (and a missing one
  /// as "???"), for hydra.runtime.choices.
  std::vector<std::pair<std::string, std::optional<std::string>>> choice_values;
  /// The overrides that are not defaults-list overrides (value overrides),
  /// in command-line order; they point into `overrides` of the call.
  std::vector<const Override*> value_overrides;
};

/// Builds the defaults tree of the primary config `config_name` ("" for
/// none) from `repo`, with the defaults-list overrides among `overrides`
/// (sweeps are skipped), and returns the final defaults list. With
/// `skip_missing` a mandatory (`???`) choice left unset is dropped instead of
/// being an error (the sweep-level config of a multirun). Throws ConfigError
/// with Hydra's wording (a config that is not found, an override that
/// matches nothing, a group listed twice, ...).
/// `primary_file`, if given, is the primary config already read from `repo`
/// (Compose reads it first for hydra.searchpath): it is not read again.
DefaultsListResult BuildDefaultsList(const ConfigRepository& repo,
                                     const std::vector<Override>& overrides,
                                     const std::string& config_name,
                                     bool skip_missing,
                                     const ConfigFile* primary_file = nullptr);

}  // namespace internal
}  // namespace soma
