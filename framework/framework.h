// Framework initialisation: the one place that sees every module.
#pragma once

namespace soma {

/// Registers every built-in component, config group and resolver, then
/// freezes the registries. Idempotent and thread-safe (std::call_once).
void InitFramework();

/// Called by InitFramework(): every module's Register*() function.
void RegisterBuiltins();

}  // namespace soma
