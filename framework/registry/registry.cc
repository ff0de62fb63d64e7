#include "framework/registry/registry.h"

#include <mutex>

namespace soma {
namespace {

struct RegistryState {
  std::mutex mutex;
  bool frozen = false;
  std::multimap<std::string, internal::AnyCreator, std::less<>> index;
  std::map<std::string, ConfigGroupBuilder> groups;
};

RegistryState& State() {
  static RegistryState state;  // Registry bookkeeping, frozen after init.
  return state;
}

constexpr std::string_view kReservedKeys[] = {
    "_target_", "_args_", "_recursive_", "_partial_", "_convert_"};

}  // namespace

namespace internal {

void ThrowIfFrozen(std::string_view kind, std::string_view key) {
  if (State().frozen) {
    throw InternalError(
        fmt::format("Cannot register {} '{}': the registries are frozen after "
                    "InitFramework(); register it from a Register*() function",
                    kind,
                    key));
  }
}

void IndexCreator(std::string key, AnyCreator creator) {
  RegistryState& state = State();
  std::lock_guard<std::mutex> lock(state.mutex);
  state.index.emplace(std::move(key), std::move(creator));
}

std::vector<const AnyCreator*> FindCreators(std::string_view key) {
  RegistryState& state = State();
  std::vector<const AnyCreator*> found;
  auto [begin, end] = state.index.equal_range(key);
  for (auto it = begin; it != end; ++it) found.push_back(&it->second);
  return found;
}

std::string TargetKey(const ConfigNode& node) {
  if (const ConfigNode* target = node.Find("_target_")) {
    return target->AsString();
  }
  if (const ConfigNode* name = node.Find("name"); name && name->IsString()) {
    return name->AsString();
  }
  return "";
}

ConfigNode CreatorNode(const ConfigNode& node, const ConfigNode& overrides) {
  ConfigNode out = node;
  const bool key_from_name = node.Find("_target_") == nullptr;
  for (std::string_view reserved : kReservedKeys) out.Erase(reserved);
  if (key_from_name) out.Erase("name");
  if (overrides.IsMap()) MergeInto(out, overrides);
  return out;
}

void BuildChildren(const ConfigNode& node, BuildContext& ctx) {
  for (const auto& [key, child] : node.entries()) {
    if (!child.IsMap() || child.Find("_target_") == nullptr) continue;
    const std::string target = child.at("_target_").AsString();
    const std::vector<const AnyCreator*> creators = FindCreators(target);
    if (creators.empty()) {
      throw ConfigError(fmt::format(
          "Invalid configuration. {}._target_ = {}: no registered component "
          "has that name",
          child.path(),
          target));
    }
    if (creators.size() > 1) {
      throw ConfigError(fmt::format(
          "Invalid configuration. {}._target_ = {} is ambiguous ({} and {} "
          "both register it)",
          child.path(),
          target,
          creators[0]->kind,
          creators[1]->kind));
    }
    BuildContext grandchild_ctx = ctx;
    grandchild_ctx.ClearChildren();
    const ConfigNode stripped = CreatorNode(child, ConfigNode());
    const ConfigNode* recursive = child.Find("_recursive_");
    if (recursive == nullptr || recursive->AsBool()) {
      BuildChildren(stripped, grandchild_ctx);
    }
    ctx.SetChild(
        key, creators[0]->create(stripped, grandchild_ctx), child.path());
  }
}

void ThrowUnknownKey(std::string_view kind,
                     std::string_view key,
                     std::string_view path,
                     const std::vector<std::string>& keys) {
  throw ConfigError(fmt::format(
      "Invalid configuration. {} = {}. Violated constraint: a registered {} "
      "name. Registered {} names: {}",
      path.empty() ? "<root>" : path,
      key,
      kind,
      kind,
      fmt::join(keys, ", ")));
}

}  // namespace internal

void RegisterConfigGroup(
    std::string group,
    std::string kind,
    std::function<void(const ConfigNode&, BuildContext&)> build) {
  internal::ThrowIfFrozen("config group", group);
  RegistryState& state = State();
  std::lock_guard<std::mutex> lock(state.mutex);
  if (state.groups.count(group) != 0) {
    throw InternalError(
        fmt::format("Duplicate registration of config group '{}'", group));
  }
  state.groups.emplace(std::move(group),
                       ConfigGroupBuilder{std::move(kind), std::move(build)});
}

const std::map<std::string, ConfigGroupBuilder>& ConfigGroupBuilders() {
  return State().groups;
}

void FreezeRegistries() {
  RegistryState& state = State();
  std::lock_guard<std::mutex> lock(state.mutex);
  state.frozen = true;
}

bool RegistriesFrozen() { return State().frozen; }

}  // namespace soma
