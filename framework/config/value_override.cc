#include "framework/config/value_override.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <string>
#include <utility>
#include <vector>

namespace soma {
namespace {

constexpr std::string_view kCommandLine = "<command line>";

ConfigNode* Child(ConfigNode& node, const std::string& segment) {
  if (node.IsMap()) return node.Find(segment);
  if (node.IsList()) {
    if (segment.empty() || segment.size() > 18 ||
        !std::all_of(segment.begin(), segment.end(), [](char c) {
          return std::isdigit(static_cast<unsigned char>(c));
        })) {
      return nullptr;
    }
    const size_t index = std::stoull(segment);
    if (index >= node.size()) return nullptr;
    return &node.at(index);
  }
  return nullptr;
}

ConfigNode* FindNode(ConfigNode& root, const std::vector<std::string>& segs) {
  ConfigNode* node = &root;
  for (const std::string& seg : segs) {
    node = Child(*node, seg);
    if (node == nullptr) return nullptr;
  }
  return node;
}

/// Sets `segs` below `root`, creating maps for missing or scalar
/// intermediates (OmegaConf.update with force_add).
void ForceSet(ConfigNode& root,
              const std::vector<std::string>& segs,
              ConfigNode value,
              const Override& o) {
  ConfigNode* node = &root;
  for (size_t i = 0; i + 1 < segs.size(); ++i) {
    ConfigNode* next = Child(*node, segs[i]);
    if (next == nullptr || !next->IsContainer()) {
      if (node->IsList()) {
        throw ConfigError(
            fmt::format("Error merging override {}: no index '{}' in list '{}'",
                        o.input,
                        segs[i],
                        node->path()));
      }
      if (!node->IsMap() && !node->IsNull()) {
        throw ConfigError(
            fmt::format("Error merging override {}: '{}' is not a container",
                        o.input,
                        node->path()));
      }
      next = &node->Set(segs[i], ConfigNode::EmptyMap());
    }
    node = next;
  }
  const std::string& last = segs.back();
  if (node->IsList()) {
    ConfigNode* slot = Child(*node, last);
    if (slot == nullptr) {
      throw ConfigError(fmt::format(
          "Error merging override {}: index '{}' is out of range for '{}' "
          "(size {})",
          o.input,
          last,
          node->path(),
          node->size()));
    }
    *slot = std::move(value);
    return;
  }
  if (!node->IsMap() && !node->IsNull()) {
    throw ConfigError(
        fmt::format("Error merging override {}: '{}' is not a container",
                    o.input,
                    node->path()));
  }
  node->Set(last, std::move(value));
}

/// True if every key of `value` (recursively through maps present on both
/// sides) exists in `target`: a dict merge in struct mode adds no keys.
bool MergeAddsNoKeys(const ConfigNode& target, const ConfigNode& value) {
  if (!target.IsMap() || !value.IsMap()) return true;
  for (const auto& [key, child] : value.entries()) {
    const ConfigNode* existing = target.Find(key);
    if (existing == nullptr) return false;
    if (!MergeAddsNoKeys(*existing, child)) return false;
  }
  return true;
}

bool ValuesEqual(const ConfigNode& a, const ConfigNode& b) {
  if (a == b) return true;
  const bool a_num = a.IsInt() || a.IsDouble();
  const bool b_num = b.IsInt() || b.IsDouble();
  if (a_num && b_num) return a.AsDouble() == b.AsDouble();
  return false;
}

}  // namespace

void ApplyValueOverride(ConfigNode& root, const Override& o) {
  if (!o.package.empty()) {
    throw ConfigError(fmt::format(
        "Override {} looks like a config group override, but config group "
        "'{}' does not exist.",
        o.input,
        o.key));
  }
  const std::vector<std::string> segs = SplitKeyPath(o.key);
  if (segs.empty()) {
    throw ConfigError(fmt::format("Invalid override key in '{}'", o.input));
  }
  ConfigNode value;
  if (o.value.has_value()) {
    value = *o.value;
    value.SetSourceRecursive(SourceLocation{std::string(kCommandLine), 0});
  }
  ConfigNode* existing = FindNode(root, segs);

  switch (o.type) {
    case OverrideType::kDelete: {
      if (existing == nullptr) {
        throw ConfigError(fmt::format(
            "Could not delete from config. '{}' does not exist.", o.key));
      }
      if (o.value.has_value() && !ValuesEqual(*existing, *o.value)) {
        throw ConfigError(fmt::format(
            "Could not delete from config. The value of '{}' is {} and not {}.",
            o.key,
            DumpFlow(*existing),
            DumpFlow(*o.value)));
      }
      ConfigNode* parent = FindNode(
          root, std::vector<std::string>(segs.begin(), segs.end() - 1));
      if (parent->IsMap()) {
        parent->Erase(segs.back());
      } else {
        auto& items = parent->mutable_items();
        items.erase(items.begin() +
                    static_cast<std::ptrdiff_t>(std::stoull(segs.back())));
      }
      return;
    }
    case OverrideType::kAdd: {
      if (existing == nullptr || existing->IsNull() || existing->IsMissing()) {
        ForceSet(root, segs, std::move(value), o);
      } else if (value.IsContainer()) {
        if (existing->IsMap() && value.IsMap()) {
          MergeInto(*existing, value);
        } else {
          *existing = std::move(value);
        }
      } else {
        throw ConfigError(fmt::format(
            "Could not append to config. An item is already at '{}'. Either "
            "remove + prefix: '{}' or add a second + to add or override '{}': "
            "'+{}'",
            o.key,
            o.input.substr(1),
            o.key,
            o.input));
      }
      return;
    }
    case OverrideType::kForceAdd: {
      if (existing != nullptr && existing->IsMap() && value.IsMap()) {
        MergeInto(*existing, value);
      } else {
        ForceSet(root, segs, std::move(value), o);
      }
      return;
    }
    case OverrideType::kChange: {
      if (existing == nullptr || (existing->IsMap() && value.IsMap() &&
                                  !MergeAddsNoKeys(*existing, value))) {
        throw ConfigError(fmt::format(
            "Could not override '{}'. To append to your config use +{}",
            o.key,
            o.input));
      }
      if (existing->IsMap() && value.IsMap()) {
        MergeInto(*existing, value);
      } else {
        *existing = std::move(value);
      }
      return;
    }
  }
}

}  // namespace soma
