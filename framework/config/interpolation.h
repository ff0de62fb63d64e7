// Interpolation and resolvers (HYDRA.md section 6).
//
// `${a.b}` absolute, `${.x}` sibling, `${..x}` parent's sibling, `${a[0]}` and
// nested `${plans[${sel}]}`; resolvers `${name:arg1,arg2}` whose arguments may
// themselves contain interpolations; `\${` is a literal. A whole-value
// interpolation keeps the referenced node's type (a map reference yields the
// sub-tree); a string with embedded interpolations becomes a string.
// Resolution is lazy (Select) or whole-tree (Resolve); cycles are reported with
// the chain of keys.
#pragma once

#include "framework/config/node.h"

#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

class ResolverRegistry;

/// What a resolver sees when it is called.
struct ResolverCall {
  const ConfigNode* root = nullptr;  // the tree being resolved
  std::string_view node_path;        // path of the node being resolved
  const ResolverRegistry* registry = nullptr;
};

/// A resolver gets its arguments already resolved (each a ConfigNode:
/// strings, numbers, ... typed like override primitives) and returns a node.
using ResolverFn = std::function<ConfigNode(const std::vector<ConfigNode>& args,
                                            const ResolverCall& call)>;

/// Name -> resolver. Registering a duplicate name throws ConfigError.
/// Built-ins (RegisterBuiltinResolvers): `now` (strftime, cached per pattern
/// per registry so a run directory is stable), `oc.env` (always a string),
/// `oc.select`, `oc.decode` (parses a string as a resolver argument),
/// `oc.create` (a dict/list, or a YAML string, as a config node),
/// `oc.deprecated` (the value at another key, with a warning),
/// `oc.dict.keys` / `oc.dict.values` (of the dict at a key), `hydra` (reads
/// `hydra.<path>` of the root), `hydra_override_dirname`.
class ResolverRegistry {
 public:
  ResolverRegistry();  // with the built-in resolvers

  void Register(std::string name, ResolverFn fn);
  bool Has(std::string_view name) const;
  const ResolverFn& Get(std::string_view name) const;
  std::vector<std::string> Names() const;

  /// Cache used by `now`: the first call with a pattern fixes its value.
  std::string CachedNow(const std::string& pattern) const;

 private:
  std::map<std::string, ResolverFn, std::less<>> resolvers_;
  mutable std::mutex now_mutex_;
  mutable std::map<std::string, std::string> now_cache_;
};

/// Returns the node at `dotted` (relative to `root`) with interpolations in
/// it resolved (recursively for containers). `???` values are returned as
/// Missing nodes (typed access then raises MissingMandatoryValue with the full
/// path). Throws InterpolationKeyError / ConfigError (cycles: "Interpolation
/// cycle: a -> b -> a").
ConfigNode Select(const ConfigNode& root,
                  std::string_view dotted,
                  const ResolverRegistry& resolvers);

/// Resolves every interpolation of the tree (OmegaConf.resolve); missing
/// values stay Missing. The returned tree has the same paths and sources.
ConfigNode Resolve(const ConfigNode& root, const ResolverRegistry& resolvers);

/// Resolves one string that may contain interpolations, in the context of
/// `root` with `node_path` as the location of the string (for relative keys).
ConfigNode ResolveString(const ConfigNode& root,
                         std::string_view text,
                         std::string_view node_path,
                         const ResolverRegistry& resolvers);

/// True if `text` contains an unescaped `${`.
bool HasInterpolation(std::string_view text);

/// The process-wide default registry (built-ins + user resolvers registered
/// from InitFramework()). Like the component registries, it is frozen after
/// initialisation except for the `now` cache.
ResolverRegistry& DefaultResolvers();

}  // namespace soma
