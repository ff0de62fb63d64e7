// Multirun sweep expansion (HYDRA.md section 8): sweep keys from
// `hydra.sweeper.params` followed by the CLI (CLI replaces config params key by
// key), non-sweep overrides as single-value lists, cartesian product with the
// last key varying fastest. A repeated key keeps its first position and last
// value. Sweeping over `hydra.*` is an error.
#pragma once

#include "framework/config/compose.h"
#include "framework/config/node.h"
#include "framework/config/override.h"

#include <string>
#include <vector>

namespace soma {

/// Returns one override list per job, in job order (hydra.job.num = index).
/// `sweep_root` is the sweep-level composed root (for hydra.sweeper.params);
/// `repo` expands glob() over group options.
std::vector<std::vector<std::string>> ExpandSweep(
    const ConfigNode& sweep_root,
    const std::vector<Override>& cli,
    const ConfigRepository& repo);

}  // namespace soma
