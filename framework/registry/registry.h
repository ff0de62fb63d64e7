// The component registry: the only way components are built from configs.
//
// One `Registry<Base>` per swappable kind (task, noise module, normalization,
// ...). Each module registers its built-ins explicitly in a `RegisterXxx()`
// function called from `RegisterBuiltins()` (framework.cc) under
// `InitFramework()`'s call_once; nothing self-registers from static
// initialisers (the linker drops those from static archives; STYLE.md). After
// InitFramework() the registries are frozen: registering throws.
//
// A config node selects an implementation by `_target_` (Hydra) or `name`
// (SOMA-style configs: `name: sinkhorn`):
//
//   auto norm = Instantiate<Normalization>(cfg.at("normalization"), ctx);
//
// Nested maps with their own `_target_` are instantiated first (depth first)
// and handed to the parent's creator through `ctx.Child<T>("key")`, unless the
// parent says `_recursive_: false`.
#pragma once

#include "framework/config/node.h"
#include "framework/core/error.h"
#include "framework/core/random.h"

#include <fmt/format.h>

#include <any>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <typeindex>
#include <vector>

namespace soma {

/// What a creator gets besides its config node.
class BuildContext {
 public:
  BuildContext() = default;
  BuildContext(uint64_t seed, std::string output_dir)
      : seed_(seed), output_dir_(std::move(output_dir)) {}

  /// Root seed of the run; components derive named sub-streams from it.
  uint64_t seed() const { return seed_; }
  Rng RootRng() const { return Rng(seed_); }
  /// The run's output directory ("" when not inside a run).
  const std::string& output_dir() const { return output_dir_; }

  /// The already-built nested component at `key` of the node being
  /// instantiated. Throws ConfigError if absent or of another type.
  template <typename T>
  std::shared_ptr<T> Child(std::string_view key) const;
  bool HasChild(std::string_view key) const {
    return children_.find(std::string(key)) != children_.end();
  }

  // Used by Instantiate().
  void SetChild(std::string key, std::any object, std::string path) {
    children_[std::move(key)] = Entry{std::move(object), std::move(path)};
  }
  void ClearChildren() { children_.clear(); }

 private:
  struct Entry {
    std::any object;  // std::shared_ptr<Base>
    std::string path;
  };
  uint64_t seed_ = 0;
  std::string output_dir_;
  std::map<std::string, Entry> children_;
};

namespace internal {

/// Process-wide registry bookkeeping: the frozen flag and the type-erased
/// index of every key (for nested `_target_` instantiation and for the
/// config-group walk test).
struct AnyCreator {
  std::string kind;  // registry name, e.g. "noise"
  std::function<std::any(const ConfigNode&, BuildContext&)> create;
};

void ThrowIfFrozen(std::string_view kind, std::string_view key);
void IndexCreator(std::string key, AnyCreator creator);
/// All registries that have `key`.
std::vector<const AnyCreator*> FindCreators(std::string_view key);

/// The registry key of `node`: `_target_`, else `name`; "" if neither.
std::string TargetKey(const ConfigNode& node);
/// `node` minus `_target_`, `_args_`, `_recursive_`, `_partial_`,
/// `_convert_` (and `name` when it was the key), with call-site overrides
/// merged in.
ConfigNode CreatorNode(const ConfigNode& node, const ConfigNode& overrides);
/// Builds the nested `_target_` children of `node` into `ctx`.
void BuildChildren(const ConfigNode& node, BuildContext& ctx);

[[noreturn]] void ThrowUnknownKey(std::string_view kind,
                                  std::string_view key,
                                  std::string_view path,
                                  const std::vector<std::string>& keys);

}  // namespace internal

template <typename Base>
class Registry {
 public:
  using Creator =
      std::function<std::unique_ptr<Base>(const ConfigNode&, BuildContext&)>;

  /// `global` registries (from GetRegistry) freeze with the framework; a
  /// local registry (tests, tools) never freezes.
  explicit Registry(std::string kind, bool global = false)
      : kind_(std::move(kind)), global_(global) {}
  Registry(const Registry&) = delete;
  Registry& operator=(const Registry&) = delete;

  /// The kind shown in messages ("task", "noise", ...).
  const std::string& kind() const { return kind_; }

  /// Registers `creator` under `key`; throws InternalError on a duplicate key
  /// or after the registries were frozen.
  void Register(std::string key, Creator creator) {
    if (global_) internal::ThrowIfFrozen(kind_, key);
    if (creators_.count(key) != 0) {
      throw InternalError(
          fmt::format("Duplicate registration of {} '{}'", kind_, key));
    }
    creators_.emplace(key, creator);
    if (!global_) return;
    internal::IndexCreator(
        key,
        internal::AnyCreator{
            kind_, [creator](const ConfigNode& node, BuildContext& ctx) {
              return std::any(std::shared_ptr<Base>(creator(node, ctx)));
            }});
  }

  bool Has(std::string_view key) const {
    return creators_.find(key) != creators_.end();
  }

  /// Sorted keys.
  std::vector<std::string> Keys() const {
    std::vector<std::string> keys;
    for (const auto& [key, creator] : creators_) keys.push_back(key);
    return keys;
  }

  /// Creates `key` from `node` (already stripped of `_target_` etc.). Unknown
  /// key: ConfigError naming `node.path()` and listing Keys().
  std::unique_ptr<Base> Create(std::string_view key,
                               const ConfigNode& node,
                               BuildContext& ctx) const {
    auto it = creators_.find(key);
    if (it == creators_.end()) {
      internal::ThrowUnknownKey(kind_, key, node.path(), Keys());
    }
    return it->second(node, ctx);
  }

 private:
  std::string kind_;
  bool global_ = false;
  std::map<std::string, Creator, std::less<>> creators_;
};

/// The registry of `Base`. `Base` declares its kind:
///   static constexpr std::string_view kRegistryName = "task";
template <typename Base>
Registry<Base>& GetRegistry() {
  static Registry<Base> registry{std::string(Base::kRegistryName),
                                 /*global=*/true};
  return registry;
}

/// Builds the component selected by `node` (a map with `_target_` or
/// `name`). `overrides` (a map, may be null) is merged into a copy first
/// (Hydra's call-site overrides).
template <typename Base>
std::unique_ptr<Base> Instantiate(const ConfigNode& node,
                                  BuildContext& ctx,
                                  const ConfigNode& overrides = ConfigNode()) {
  const Registry<Base>& registry = GetRegistry<Base>();
  if (!node.IsMap()) {
    throw ConfigError(fmt::format(
        "Invalid configuration. {} = {}. Expected a map with '_target_' (or "
        "'name') naming a registered {}; registered: {}{}",
        node.path().empty() ? "<root>" : node.path(),
        node.Describe(),
        registry.kind(),
        fmt::join(registry.Keys(), ", "),
        node.source().file.empty() ? ""
                                   : " (" + node.source().ToString() + ")"));
  }
  const std::string key = internal::TargetKey(node);
  if (key.empty()) {
    throw ConfigError(fmt::format(
        "Invalid configuration. {} has no '_target_' (or 'name') key naming "
        "the {} to build; registered: {}",
        node.path().empty() ? "<root>" : node.path(),
        registry.kind(),
        fmt::join(registry.Keys(), ", ")));
  }
  if (!registry.Has(key)) {
    internal::ThrowUnknownKey(
        registry.kind(), key, node.path(), registry.Keys());
  }
  const ConfigNode stripped = internal::CreatorNode(node, overrides);
  BuildContext child_ctx = ctx;
  child_ctx.ClearChildren();
  const ConfigNode* recursive = node.Find("_recursive_");
  if (recursive == nullptr || recursive->AsBool()) {
    internal::BuildChildren(stripped, child_ctx);
  }
  return registry.Create(key, stripped, child_ctx);
}

/// `_partial_`-style factory: a function that builds the component later,
/// with extra call-site overrides.
template <typename Base>
std::function<std::unique_ptr<Base>(const ConfigNode&)> InstantiatePartial(
    const ConfigNode& node, const BuildContext& ctx) {
  return [node, ctx](const ConfigNode& overrides) {
    BuildContext local = ctx;
    return Instantiate<Base>(node, local, overrides);
  };
}

template <typename T>
std::shared_ptr<T> BuildContext::Child(std::string_view key) const {
  auto it = children_.find(std::string(key));
  if (it == children_.end()) {
    throw ConfigError(fmt::format(
        "Missing nested component '{}' (a map with '_target_' was expected "
        "there)",
        key));
  }
  if (const auto* ptr = std::any_cast<std::shared_ptr<T>>(&it->second.object)) {
    return *ptr;
  }
  throw ConfigError(
      fmt::format("Invalid configuration. {}: the nested component is not a {}",
                  it->second.path,
                  T::kRegistryName));
}

/// Config groups whose options are components: group name -> a function
/// that instantiates an option's node (used by `soma --info components` and
/// the test that builds every option of every group under configs/).
void RegisterConfigGroup(
    std::string group,
    std::string kind,
    std::function<void(const ConfigNode&, BuildContext&)> build);

template <typename Base>
void RegisterConfigGroup(std::string group) {
  RegisterConfigGroup(std::move(group),
                      std::string(Base::kRegistryName),
                      [](const ConfigNode& node, BuildContext& ctx) {
                        Instantiate<Base>(node, ctx);
                      });
}

struct ConfigGroupBuilder {
  std::string kind;
  std::function<void(const ConfigNode&, BuildContext&)> build;
};
/// group -> builder, sorted by group.
const std::map<std::string, ConfigGroupBuilder>& ConfigGroupBuilders();

/// Freezes every registry (called at the end of InitFramework()).
void FreezeRegistries();
bool RegistriesFrozen();

}  // namespace soma
