#include "framework/config/sweep.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstddef>
#include <utility>

namespace soma {
namespace {

// More jobs than this is almost certainly a mistake (and would exhaust
// memory while expanding).
constexpr size_t kMaxJobs = 1000000;

std::string_view Prefix(OverrideType type) {
  switch (type) {
    case OverrideType::kChange:
      return "";
    case OverrideType::kAdd:
      return "+";
    case OverrideType::kForceAdd:
      return "++";
    case OverrideType::kDelete:
      return "~";
  }
  return "";
}

/// `[prefix]key[@package]`: what identifies a sweep dimension (Hydra's
/// Override.get_key_element()).
std::string KeyElement(const Override& o) {
  return std::string(Prefix(o.type)) + o.KeyWithPackage();
}

/// Hydra's Override.is_hydra_override().
bool IsHydraKey(const std::string& key) {
  return key.rfind("hydra.", 0) == 0 || key.rfind("hydra/", 0) == 0;
}

/// `hydra.sweeper.params` (key -> sweep in override syntax), or nullptr.
const ConfigNode* SweeperParams(const ConfigNode& root) {
  const ConfigNode* node = &root;
  for (const char* key : {"hydra", "sweeper", "params"}) {
    if (!node->IsMap()) return nullptr;
    node = node->Find(key);
    if (node == nullptr) return nullptr;
  }
  return node;
}

std::vector<Override> ConfigParams(const ConfigNode& root) {
  std::vector<Override> params;
  const ConfigNode* node = SweeperParams(root);
  if (node == nullptr || node->IsNull()) return params;
  if (!node->IsMap()) {
    throw ConfigError(
        fmt::format("hydra.sweeper.params must be a map of key: sweep, got {}",
                    node->Describe()));
  }
  for (const auto& [key, value] : node->entries()) {
    const std::string text = (value.IsString() || value.IsInterpolation())
                                 ? value.text()
                                 : FormatOverrideValue(value);
    try {
      params.push_back(ParseOverride(fmt::format("{}={}", key, text)));
    } catch (const ConfigError& e) {
      throw ConfigError(fmt::format("In hydra.sweeper.params: {}", e.what()));
    }
  }
  return params;
}

/// The override strings of one sweep dimension.
std::vector<std::string> DimensionValues(const Override& o,
                                         const ConfigRepository& repo) {
  if (!o.IsSweep()) return {o.input};
  if (IsHydraKey(o.key)) {
    throw ConfigError(fmt::format(
        "Sweeping over Hydra's configuration is not supported : '{}'",
        o.input));
  }
  std::vector<std::string> options;
  if (o.sweep->kind == SweepSpec::Kind::kGlob) {
    if (!repo.IsGroup(o.key)) {
      throw ConfigError(fmt::format(
          "Cannot expand '{}': glob() sweeps over the options of a config "
          "group and '{}' is not a config group",
          o.input,
          o.key));
    }
    options = repo.Options(o.key);
  }
  const std::vector<std::string> values = SweepValueStrings(*o.sweep, options);
  if (values.empty()) {
    throw ConfigError(
        fmt::format("The sweep '{}' has no values (no job to run)", o.input));
  }
  const std::string key = KeyElement(o);
  std::vector<std::string> out;
  out.reserve(values.size());
  for (const std::string& v : values)
    out.push_back(fmt::format("{}={}", key, v));
  return out;
}

}  // namespace

std::vector<std::vector<std::string>> ExpandSweep(
    const ConfigNode& sweep_root,
    const std::vector<Override>& cli,
    const ConfigRepository& repo) {
  std::vector<Override> overrides = ConfigParams(sweep_root);
  overrides.insert(overrides.end(), cli.begin(), cli.end());

  // Ordered by first occurrence of each key; a later override with the same
  // key replaces the values (Hydra's OrderedDict in BasicSweeper).
  std::vector<std::pair<std::string, std::vector<std::string>>> dimensions;
  for (const Override& o : overrides) {
    std::vector<std::string> values = DimensionValues(o, repo);
    const std::string key = KeyElement(o);
    const auto existing =
        std::find_if(dimensions.begin(), dimensions.end(), [&](const auto& d) {
          return d.first == key;
        });
    if (existing != dimensions.end()) {
      existing->second = std::move(values);
    } else {
      dimensions.emplace_back(key, std::move(values));
    }
  }

  size_t total = 1;
  for (const auto& [key, values] : dimensions) {
    total *= values.size();
    if (total > kMaxJobs) {
      throw ConfigError(
          fmt::format("The sweep has more than {} jobs", kMaxJobs));
    }
  }

  // Cartesian product, last dimension varying fastest (itertools.product).
  std::vector<std::vector<std::string>> jobs;
  jobs.reserve(total);
  std::vector<size_t> index(dimensions.size(), 0);
  for (size_t n = 0; n < total; ++n) {
    std::vector<std::string> job;
    job.reserve(dimensions.size());
    for (size_t d = 0; d < dimensions.size(); ++d) {
      job.push_back(dimensions[d].second[index[d]]);
    }
    jobs.push_back(std::move(job));
    for (size_t d = dimensions.size(); d-- > 0;) {
      if (++index[d] < dimensions[d].second.size()) break;
      index[d] = 0;
    }
  }
  return jobs;
}

}  // namespace soma
