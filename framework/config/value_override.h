// Value overrides of Hydra-style composition (HYDRA.md section 5):
// `key=value`, `+key=value`, `++key=value` and `~key[=value]` applied to a
// composed tree with the struct-mode semantics of Hydra's
// `_apply_overrides_to_config`.
#pragma once

#include "framework/config/node.h"
#include "framework/config/override.h"

namespace soma {

/// Applies one value override (not a defaults-list override) to `root`.
/// kChange needs an existing key (a map value merges and may add no keys);
/// kAdd needs a free key (or merges a map into a map); kForceAdd sets or
/// merges, creating intermediate maps; kDelete removes a key (whose value
/// must equal the override's value when one is given). The new value's
/// source is `<command line>`. Throws ConfigError with Hydra's wording.
void ApplyValueOverride(ConfigNode& root, const Override& o);

}  // namespace soma
