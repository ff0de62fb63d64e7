// Hydra-style composition. The defaults-tree algorithm mirrors Hydra 1.3
// (`hydra/_internal/defaults_list.py`, `core/default_element.py`,
// `_internal/config_loader_impl.py`): children are expanded in reverse order
// so that `override` entries of later configs apply to group defaults chosen
// earlier, the first registered override of a key wins (CLI first, then the
// later configs), and the final defaults list is a DFS walk of the tree.
#include "framework/config/compose.h"

#include "framework/config/yaml_io.h"
#include "framework/core/build_info.h"
#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <memory>
#include <regex>
#include <set>
#include <system_error>
#include <utility>

namespace soma {
namespace {

namespace fs = std::filesystem;

constexpr std::string_view kGlobal = "_global_";
constexpr std::string_view kSelf = "_self_";
constexpr std::string_view kMissingOption = "???";
constexpr std::string_view kDummyConfig = "_dummy_empty_config_";
constexpr std::string_view kCommandLine = "<command line>";

std::string Join(const std::vector<std::string>& items, std::string_view sep) {
  std::string out;
  for (size_t i = 0; i < items.size(); ++i) {
    if (i > 0) out += sep;
    out += items[i];
  }
  return out;
}

std::string ReplaceAll(std::string text,
                       std::string_view from,
                       std::string_view to) {
  if (from.empty()) return text;
  size_t pos = 0;
  while ((pos = text.find(from, pos)) != std::string::npos) {
    text.replace(pos, from.size(), to);
    pos += to.size();
  }
  return text;
}

std::string StripLeadingSlash(std::string_view path) {
  return std::string(path.starts_with('/') ? path.substr(1) : path);
}

/// True if `text` contains a `${` not preceded by a backslash.
bool ContainsInterpolation(std::string_view text) {
  for (size_t pos = text.find("${"); pos != std::string_view::npos;
       pos = text.find("${", pos + 1)) {
    if (pos == 0 || text[pos - 1] != '\\') return true;
  }
  return false;
}

/// Rejects `..` components and backslashes in config and group paths.
void ValidateConfigPath(std::string_view path) {
  if (path.find('\\') != std::string_view::npos) {
    throw ConfigError(fmt::format(
        "Invalid config path '{}': a backslash is not allowed, use '/' as "
        "the separator",
        path));
  }
  size_t start = 0;
  while (start <= path.size()) {
    size_t end = path.find('/', start);
    if (end == std::string_view::npos) end = path.size();
    if (path.substr(start, end - start) == "..") {
      throw ConfigError(
          fmt::format("Invalid config path '{}': '..' is not allowed", path));
    }
    start = end + 1;
  }
}

/// Strips a `file://` prefix; any other scheme is an error.
std::string StripFileScheme(const std::string& entry) {
  constexpr std::string_view kFileScheme = "file://";
  if (entry.starts_with(kFileScheme)) {
    return entry.substr(kFileScheme.size());
  }
  if (entry.find("://") != std::string::npos) {
    throw ConfigError(fmt::format(
        "Unsupported config search path entry '{}': only directories and "
        "file:// entries are supported",
        entry));
  }
  return entry;
}

fs::path ResolveRoot(const std::string& entry) {
  std::string path = StripFileScheme(entry);
  if (path.empty()) path = ".";
  fs::path resolved = fs::absolute(fs::path(path)).lexically_normal();
  if (!resolved.has_filename() && resolved.has_parent_path() &&
      resolved != resolved.root_path()) {
    resolved = resolved.parent_path();
  }
  return resolved;
}

bool IsHydraKey(std::string_view key) {
  return key == "hydra" || key.starts_with("hydra.") ||
         key.starts_with("hydra/");
}

/// The text after the first '=' of an override as written.
std::string OverrideValueText(const Override& o) {
  const size_t eq = o.input.find('=');
  return eq == std::string::npos ? std::string() : o.input.substr(eq + 1);
}

/// The string of a string or interpolation node.
std::optional<std::string> StringOf(const ConfigNode& node) {
  if (node.IsString()) return node.AsString();
  if (node.IsInterpolation()) return node.text();
  return std::nullopt;
}

std::string PythonTypeName(const ConfigNode& node) {
  if (node.IsNull()) return "NoneType";
  return std::string(ConfigNode::TypeName(node.type()));
}

// ---------------------------------------------------------------------------
// Defaults-list elements (Hydra's ConfigDefault / GroupDefault).

/// The option of a group default: a name, null, or a list of names.
struct OptionValue {
  enum class Kind { kNull, kName, kList };
  Kind kind = Kind::kNull;
  std::string name;
  std::vector<std::string> list;

  std::string Describe() const {
    switch (kind) {
      case Kind::kNull:
        return "null";
      case Kind::kName:
        return name;
      case Kind::kList:
        return "[" + Join(list, ", ") + "]";
    }
    return "";
  }
};

struct Element {
  bool is_group = false;
  bool primary = false;
  bool dummy = false;  // the empty primary used when there is no config name
  // A ConfigDefault created from an item of an option list (`site: [a, b]`).
  bool list_item = false;
  std::string path;   // ConfigDefault: `server/apache`, `/db/mysql`, `_self_`
  std::string group;  // GroupDefault: `db`, `/db`
  OptionValue value;  // GroupDefault only
  std::optional<std::string> package;
  std::optional<std::string> package_header;
  bool optional = false;
  bool override = false;
  bool external_append = false;
  bool deleted = false;
  bool pending_interpolation = false;
  bool choice_registered = false;
  std::string parent_base_dir;
  std::string parent_package;

  bool IsSelf() const { return !is_group && path == kSelf; }
  bool IsOptions() const {
    return is_group && value.kind == OptionValue::Kind::kList;
  }

  std::optional<std::string> Name() const {
    if (is_group) {
      if (value.kind == OptionValue::Kind::kName) return value.name;
      return std::nullopt;
    }
    const size_t slash = path.rfind('/');
    return slash == std::string::npos ? path : path.substr(slash + 1);
  }

  std::string NameText() const {
    return is_group ? value.Describe() : Name().value_or("");
  }

  bool IsMissing() const { return Name() == std::string(kMissingOption); }

  bool IsInterpolation() const {
    if (is_group) {
      return value.kind == OptionValue::Kind::kName &&
             ContainsInterpolation(value.name);
    }
    return ContainsInterpolation(path);
  }

  std::string GroupPath() const {
    if (is_group) {
      const bool absolute = group.starts_with('/') || external_append;
      const std::string g = StripLeadingSlash(group);
      if (parent_base_dir.empty() || absolute) return g;
      return parent_base_dir + "/" + g;
    }
    const bool absolute = path.starts_with('/');
    const std::string p = StripLeadingSlash(path);
    const size_t slash = p.rfind('/');
    const std::string g = slash == std::string::npos ? "" : p.substr(0, slash);
    if (absolute || parent_base_dir.empty()) return g;
    if (g.empty()) return parent_base_dir;
    return parent_base_dir + "/" + g;
  }

  std::string ConfigPath() const {
    if (dummy) return std::string(kDummyConfig);
    if (is_group) return GroupPath() + "/" + Name().value_or("null");
    const bool absolute = path.starts_with('/');
    const std::string p = StripLeadingSlash(path);
    if (absolute || parent_base_dir.empty()) return p;
    return parent_base_dir + "/" + p;
  }

  std::string DefaultPackage() const {
    return ReplaceAll(GroupPath(), "/", ".");
  }

  std::string RelativeGroupPath() const {
    if (primary) return "";  // the primary config's package is global
    if (is_group) return StripLeadingSlash(group);
    const std::string p = StripLeadingSlash(path);
    const size_t slash = p.rfind('/');
    return slash == std::string::npos ? "" : p.substr(0, slash);
  }

  std::optional<std::string> Package(bool use_header) const {
    if (!package.has_value() && use_header) return package_header;
    return package;
  }

  std::string FinalPackage(bool use_header = true) const {
    const std::string parent =
        (is_group && external_append) ? std::string() : parent_package;
    const std::optional<std::string> pkg = Package(use_header);
    const std::string own =
        pkg.has_value() ? *pkg : ReplaceAll(RelativeGroupPath(), "/", ".");
    std::string ret;
    if (parent.empty()) {
      ret = own;
    } else if (own.empty()) {
      ret = parent;
    } else {
      ret = parent + "." + own;
    }
    const size_t global = ret.rfind(kGlobal);
    if (global == std::string::npos) return ret;
    const size_t start = global + kGlobal.size() + 1;
    return start >= ret.size() ? std::string() : ret.substr(start);
  }

  std::string OverrideKey() const {
    const std::string default_pkg = DefaultPackage();
    const std::string final_pkg = FinalPackage(/*use_header=*/false);
    std::string key = GroupPath();
    if (default_pkg != final_pkg) {
      key += "@" + (final_pkg.empty() ? std::string(kGlobal) : final_pkg);
    }
    return key;
  }

  void UpdateParent(const std::string& base_dir, const std::string& pkg) {
    parent_base_dir = base_dir;
    parent_package = pkg;
    if (package.has_value() && package->find("_group_") != std::string::npos) {
      package = std::string(kGlobal) + "." +
                ReplaceAll(*package, "_group_", DefaultPackage());
    }
  }

  void SetPackageHeader(std::string header) {
    if (header.empty() || header == "_group_") return;
    header = ReplaceAll(header, "_group_", DefaultPackage());
    header = ReplaceAll(header, "_name_", Name().value_or(""));
    if (header != kGlobal && !header.starts_with("_global_.")) {
      header = std::string(kGlobal) + "." + header;
    }
    package_header = header;
  }
};

Element SelfElement() {
  Element e;
  e.path = std::string(kSelf);
  return e;
}

struct TreeNode {
  Element node;
  TreeNode* parent = nullptr;
  std::vector<std::unique_ptr<TreeNode>> children;  // empty: a leaf
};

// ---------------------------------------------------------------------------
// Parsing a `defaults:` list.

struct GroupKey {
  std::string name;
  std::optional<std::string> package;
};

GroupKey SplitPackage(std::string_view config_path, std::string_view text) {
  GroupKey out;
  const size_t at = text.find('@');
  if (at == std::string_view::npos) {
    out.name = std::string(text);
    return out;
  }
  out.name = std::string(text.substr(0, at));
  std::string pkg(text.substr(at + 1));
  if (pkg.find(':') != std::string::npos) {
    throw ConfigError(fmt::format(
        "In '{}': package renames are not supported: '{}'", config_path, text));
  }
  if (pkg == "_here_") pkg.clear();
  out.package = pkg;
  return out;
}

std::vector<std::string> SplitWords(std::string_view text) {
  std::vector<std::string> words;
  size_t i = 0;
  while (i < text.size()) {
    while (i < text.size() && std::isspace(static_cast<unsigned char>(text[i])))
      ++i;
    size_t j = i;
    while (j < text.size() &&
           !std::isspace(static_cast<unsigned char>(text[j])))
      ++j;
    if (j > i) words.emplace_back(text.substr(i, j - i));
    i = j;
  }
  return words;
}

Element ParseGroupDefault(const std::string& config_path,
                          const std::string& key,
                          const ConfigNode& value,
                          std::optional<bool> legacy_optional) {
  Element e;
  e.is_group = true;
  std::vector<std::string> words = SplitWords(key);
  if (words.empty()) {
    throw ConfigError(fmt::format("In {}: Missing group name in defaults entry",
                                  config_path));
  }
  for (size_t i = 0; i + 1 < words.size(); ++i) {
    if (words[i] == "optional") {
      e.optional = true;
    } else if (words[i] == "override") {
      e.override = true;
    } else {
      throw ConfigError(
          fmt::format("In '{}': invalid defaults entry '{}': unknown keyword "
                      "'{}' (expected "
                      "'optional' or 'override')",
                      config_path,
                      key,
                      words[i]));
    }
  }
  if (!e.optional && legacy_optional.has_value()) e.optional = *legacy_optional;
  GroupKey gk = SplitPackage(config_path, words.back());
  if (StripLeadingSlash(gk.name).empty()) {
    throw ConfigError(
        fmt::format("In {}: Missing group name in '{}'", config_path, key));
  }
  ValidateConfigPath(gk.name);
  e.group = gk.name;
  e.package = gk.package;

  if (value.IsNull()) {
    e.value.kind = OptionValue::Kind::kNull;
  } else if (value.IsMissing()) {
    e.value.kind = OptionValue::Kind::kName;
    e.value.name = std::string(kMissingOption);
  } else if (std::optional<std::string> s = StringOf(value)) {
    e.value.kind = OptionValue::Kind::kName;
    e.value.name = *s;
  } else if (value.IsList()) {
    e.value.kind = OptionValue::Kind::kList;
    for (const ConfigNode& item : value.items()) {
      std::optional<std::string> s = StringOf(item);
      if (!s.has_value()) {
        throw ConfigError(fmt::format(
            "In '{}': Unsupported item value in defaults : {}, nested list "
            "items must be strings",
            config_path,
            PythonTypeName(item)));
      }
      e.value.list.push_back(*s);
    }
  } else {
    throw ConfigError(fmt::format(
        "In '{}': Unsupported item value in defaults : {}. Supported: string "
        "or list",
        config_path,
        PythonTypeName(value)));
  }
  return e;
}

std::vector<Element> ParseDefaultsList(const std::string& config_path,
                                       const ConfigNode& defaults) {
  if (!defaults.IsList()) {
    const std::string type =
        defaults.IsMap() ? "mapping" : PythonTypeName(defaults);
    throw ConfigError(fmt::format(
        "Invalid defaults list in '{}', defaults must be a list (got {})",
        config_path,
        type));
  }
  std::vector<Element> out;
  for (const ConfigNode& item : defaults.items()) {
    if (std::optional<std::string> text = StringOf(item)) {
      GroupKey gk = SplitPackage(config_path, *text);
      if (gk.name == kSelf && gk.package.has_value()) {
        throw ConfigError(fmt::format(
            "In '{}': _self_@PACKAGE is not supported", config_path));
      }
      if (StripLeadingSlash(gk.name).empty()) {
        throw ConfigError(fmt::format(
            "In '{}': empty config name in defaults list", config_path));
      }
      ValidateConfigPath(gk.name);
      Element e;
      e.path = gk.name;
      e.package = gk.package;
      out.push_back(std::move(e));
    } else if (item.IsMap()) {
      std::vector<std::pair<std::string, ConfigNode>> entries = item.entries();
      std::optional<bool> legacy_optional;
      if (entries.size() > 1) {
        for (auto it = entries.begin(); it != entries.end(); ++it) {
          if (it->first == "optional") {
            if (!it->second.IsBool()) {
              throw ConfigError(fmt::format(
                  "In '{}': 'optional' in a defaults entry must be a bool",
                  config_path));
            }
            legacy_optional = it->second.AsBool();
            entries.erase(it);
            break;
          }
        }
      }
      if (entries.size() > 1) {
        throw ConfigError(fmt::format("In {}: Too many keys in default item {}",
                                      config_path,
                                      DumpFlow(item)));
      }
      if (entries.empty()) {
        throw ConfigError(fmt::format(
            "In {}: Missing group name in {}", config_path, DumpFlow(item)));
      }
      out.push_back(ParseGroupDefault(
          config_path, entries[0].first, entries[0].second, legacy_optional));
    } else {
      throw ConfigError(
          fmt::format("In '{}': Unsupported type in defaults : {}",
                      config_path,
                      PythonTypeName(item)));
    }
  }
  return out;
}

// ---------------------------------------------------------------------------
// Loading configs (cached per config path).

struct LoadedConfig {
  ConfigNode content;  // without the `defaults` key
  std::vector<Element> defaults;
  std::optional<std::string> header;
  std::string file;
};

class ConfigLoader {
 public:
  explicit ConfigLoader(const ConfigRepository& repo) : repo_(repo) {}

  /// The loaded config or nullptr if no root has it.
  const LoadedConfig* Load(const std::string& config_path) {
    auto it = cache_.find(config_path);
    if (it != cache_.end()) return it->second.get();
    std::unique_ptr<LoadedConfig> loaded;
    if (std::optional<fs::path> file = repo_.Find(config_path)) {
      ConfigFile cf = LoadConfigFile(*file);
      loaded = std::make_unique<LoadedConfig>();
      loaded->file = file->string();
      if (cf.has_package_directive) loaded->header = cf.package;
      loaded->content = std::move(cf.content);
      if (!loaded->content.IsMap()) loaded->content = ConfigNode::EmptyMap();
      if (const ConfigNode* defaults = loaded->content.Find("defaults")) {
        loaded->defaults = ParseDefaultsList(config_path, *defaults);
        loaded->content.Erase("defaults");
      }
    }
    const LoadedConfig* result = loaded.get();
    cache_.emplace(config_path, std::move(loaded));
    return result;
  }

  bool Exists(const std::string& config_path) const {
    return repo_.Find(config_path).has_value();
  }

 private:
  const ConfigRepository& repo_;
  std::map<std::string, std::unique_ptr<LoadedConfig>> cache_;
};

// ---------------------------------------------------------------------------
// Defaults-list overrides (Hydra's `Overrides` class).

struct OverrideMeta {
  bool external = false;
  std::string containing_config;  // empty for CLI overrides
  std::string value_text;         // for the "+key=value" hint
  bool used = false;
};

struct Deletion {
  std::optional<std::string> name;
  bool used = false;
};

class DefaultsOverrides {
 public:
  DefaultsOverrides(const ConfigRepository& repo,
                    const std::vector<Override>& overrides) {
    for (const Override& o : overrides) {
      if (o.IsSweep()) continue;
      const bool is_group = IsGroupOverrideKey(repo, o.key);
      const bool is_dict = o.value.has_value() && o.value->IsMap();
      if (is_dict || !is_group) {
        config_overrides.push_back(&o);
        continue;
      }
      const std::string key = o.KeyWithPackage();
      if (o.type == OverrideType::kForceAdd) {
        throw ConfigError(fmt::format(
            "force-add of config groups is not supported: '{}'", o.input));
      }
      if (o.type == OverrideType::kDelete) {
        Deletion deletion;
        if (o.value.has_value() && !o.value->IsNull()) {
          std::optional<std::string> name = StringOf(*o.value);
          if (!name.has_value()) {
            throw ConfigError(fmt::format(
                "Config group override deletion value must be a string : '{}'",
                o.input));
          }
          deletion.name = *name;
        }
        if (!deletions_.contains(key)) deletion_order_.push_back(key);
        deletions_[key] = deletion;
        continue;
      }
      OptionValue value = ToOptionValue(o);
      if (o.type == OverrideType::kAdd) {
        Element e;
        e.is_group = true;
        e.group = o.key;
        if (!o.package.empty()) {
          e.package = o.package == "_here_" ? std::string() : o.package;
        }
        e.value = std::move(value);
        e.external_append = true;
        appends.push_back(std::move(e));
        append_inputs_.push_back(o.KeyWithPackage() + "=" +
                                 OverrideValueText(o));
        continue;
      }
      if (!choices_.contains(key)) choice_order_.push_back(key);
      choices_[key] = std::move(value);
      meta_[key] = OverrideMeta{.external = true,
                                .containing_config = "",
                                .value_text = OverrideValueText(o)};
    }
  }

  static bool IsGroupOverrideKey(const ConfigRepository& repo,
                                 const std::string& key) {
    if (key.find('/') != std::string::npos) ValidateConfigPath(key);
    if (key.find('\\') != std::string::npos) return false;
    return repo.IsGroup(key);
  }

  /// Registers a defaults-list `override` entry (first registration wins).
  void AddOverride(const std::string& parent_config_path,
                   const Element& element) {
    const std::string key = element.OverrideKey();
    if (choices_.contains(key)) return;
    choice_order_.push_back(key);
    choices_[key] = element.value;
    meta_[key] = OverrideMeta{.external = false,
                              .containing_config = parent_config_path,
                              .value_text = element.value.Describe()};
  }

  bool IsOverridden(const Element& element) const {
    return element.is_group && choices_.contains(element.OverrideKey());
  }

  void OverrideDefaultOption(Element& element) {
    const std::string key = element.OverrideKey();
    auto it = choices_.find(key);
    if (it == choices_.end()) return;
    element.value = it->second;
    meta_[key].used = true;
  }

  bool IsDeleted(const Element& element) const {
    if (!element.is_group) return false;
    auto it = deletions_.find(element.OverrideKey());
    if (it == deletions_.end()) return false;
    if (!it->second.name.has_value()) return true;
    return element.Name() == it->second.name;
  }

  void Delete(Element& element) {
    element.deleted = true;
    deletions_[element.OverrideKey()].used = true;
  }

  void SetKnownChoice(Element& element,
                      bool external_append_input,
                      const std::string& append_input) {
    if (!element.is_group) return;
    element.choice_registered = true;
    const std::string key = element.OverrideKey();
    const std::optional<std::string> name = element.Name();
    auto it = known_.find(key);
    if (it == known_.end()) {
      known_order_.push_back(key);
      known_[key] = name;
      if (external_append_input) appended_known_[key] = append_input;
    } else {
      auto appended = appended_known_.find(key);
      if (appended != appended_known_.end() || external_append_input) {
        const std::string input =
            appended != appended_known_.end() ? appended->second : append_input;
        throw ConfigError(
            fmt::format("Could not add '{}'. '{}' is already in the defaults "
                        "list.",
                        input,
                        key));
      }
      if (name != it->second) {
        throw ConfigError(fmt::format(
            "Multiple values for {}. To override a value use 'override {}: {}'",
            key,
            key,
            it->second.value_or("null")));
      }
    }
    known_per_group_[element.GroupPath()].insert(key);
  }

  /// Snapshot of the known choices for defaults-list interpolation.
  std::vector<std::pair<std::string, std::optional<std::string>>> KnownChoices()
      const {
    std::vector<std::pair<std::string, std::optional<std::string>>> out;
    for (const std::string& key : known_order_) {
      out.emplace_back(key, known_.at(key));
    }
    return out;
  }

  void EnsureOverridesUsed() const {
    for (const std::string& key : choice_order_) {
      const OverrideMeta& meta = meta_.at(key);
      if (meta.used) continue;
      const std::string group = key.substr(0, key.find('@'));
      std::vector<std::string> candidates;
      if (auto it = known_per_group_.find(group);
          it != known_per_group_.end()) {
        candidates.assign(it->second.begin(), it->second.end());
      }
      std::string msg = fmt::format(
          "Could not override '{}'. No match in the defaults list.", key);
      if (candidates.size() > 1) {
        msg += fmt::format(" Did you mean to override one of {}?",
                           Join(candidates, ", "));
      } else if (candidates.size() == 1) {
        msg += fmt::format(" Did you mean to override {}?", candidates[0]);
      }
      if (!meta.containing_config.empty()) {
        msg = fmt::format("In '{}': {}", meta.containing_config, msg);
      }
      if (meta.external) {
        msg += fmt::format(
            " To append to your default list use +{}={}", key, meta.value_text);
      }
      throw ConfigError(msg);
    }
  }

  void EnsureDeletionsUsed() const {
    for (const std::string& key : deletion_order_) {
      const Deletion& deletion = deletions_.at(key);
      if (deletion.used) continue;
      const std::string desc =
          deletion.name.has_value() ? key + "=" + *deletion.name : key;
      throw ConfigError(fmt::format(
          "Could not delete '{}'. No match in the defaults list", desc));
    }
  }

  /// `+group=opt` defaults appended to the primary defaults list.
  std::vector<Element> appends;
  /// Value overrides (everything that is not a defaults-list override).
  std::vector<const Override*> config_overrides;

  const std::string& AppendInput(size_t index) const {
    return append_inputs_.at(index);
  }

 private:
  static OptionValue ToOptionValue(const Override& o) {
    OptionValue value;
    if (!o.value.has_value()) {
      throw ConfigError(
          "Config group override must be a string or a list. Got NoneType");
    }
    const ConfigNode& node = *o.value;
    if (node.IsMissing()) {
      value.kind = OptionValue::Kind::kName;
      value.name = std::string(kMissingOption);
      return value;
    }
    if (std::optional<std::string> s = StringOf(node)) {
      value.kind = OptionValue::Kind::kName;
      value.name = *s;
      return value;
    }
    if (node.IsList()) {
      value.kind = OptionValue::Kind::kList;
      for (const ConfigNode& item : node.items()) {
        std::optional<std::string> s = StringOf(item);
        if (!s.has_value()) {
          throw ConfigError(fmt::format(
              "Config group override list items must be strings: '{}'",
              o.input));
        }
        value.list.push_back(*s);
      }
      return value;
    }
    throw ConfigError(
        fmt::format("Config group override must be a string or a list. Got {}",
                    PythonTypeName(node)));
  }

  std::vector<std::string> choice_order_;
  std::map<std::string, OptionValue> choices_;
  std::map<std::string, OverrideMeta> meta_;
  std::vector<std::string> append_inputs_;
  std::vector<std::string> known_order_;
  std::map<std::string, std::optional<std::string>> known_;
  std::map<std::string, std::string> appended_known_;
  std::map<std::string, std::set<std::string>> known_per_group_;
  std::vector<std::string> deletion_order_;
  std::map<std::string, Deletion> deletions_;
};

// ---------------------------------------------------------------------------
// Defaults-list interpolation: `${dataset}_${model}` against known choices.

std::string ResolveDefaultsInterpolation(
    const std::string& text,
    const std::vector<std::pair<std::string, std::optional<std::string>>>&
        known) {
  static const std::regex kPattern(R"(\$\{\s*([^{}]*?)\s*\})");
  std::string out;
  auto begin = std::sregex_iterator(text.begin(), text.end(), kPattern);
  size_t last = 0;
  for (auto it = begin; it != std::sregex_iterator(); ++it) {
    const std::smatch& match = *it;
    out += text.substr(last, match.position(0) - last);
    std::string key = match[1].str();
    while (!key.empty() && std::isspace(static_cast<unsigned char>(key.back())))
      key.pop_back();
    std::optional<std::string> replacement;
    for (const auto& [known_key, choice] : known) {
      if (known_key == key) {
        replacement = choice;
        break;
      }
    }
    out += replacement.has_value() ? *replacement : match.str(0);
    last = match.position(0) + match.length(0);
  }
  out += text.substr(last);
  if (out.find("${") != std::string::npos) {
    std::vector<std::string> keys;
    for (const auto& entry : known) keys.push_back(entry.first);
    if (keys.empty()) {
      throw ConfigError(
          fmt::format("Error resolving interpolation '{}'", text));
    }
    throw ConfigError(fmt::format(
        "Error resolving interpolation '{}', possible interpolation keys: {}",
        text,
        Join(keys, ", ")));
  }
  return out;
}

// ---------------------------------------------------------------------------
// The defaults tree.

class DefaultsTreeBuilder {
 public:
  DefaultsTreeBuilder(const ConfigRepository& repo,
                      ConfigLoader& loader,
                      DefaultsOverrides& overrides,
                      bool skip_missing)
      : repo_(repo),
        loader_(loader),
        overrides_(overrides),
        skip_missing_(skip_missing) {}

  void Expand(TreeNode& root, bool is_root_config, bool interpolated_subtree) {
    Element& parent = root.node;
    if (is_root_config) {
      parent.UpdateParent("", "");
      if (!parent.dummy && !loader_.Exists(parent.ConfigPath())) {
        ConfigNotFound(root);
      }
    }
    if (!parent.dummy && !parent.IsMissing() && parent.Name().has_value()) {
      const LoadedConfig* loaded = loader_.Load(parent.ConfigPath());
      if (loaded != nullptr && loaded->header.has_value()) {
        parent.SetPackageHeader(*loaded->header);
      }
    }

    if (overrides_.IsDeleted(parent)) {
      overrides_.Delete(parent);
      return;
    }
    overrides_.SetKnownChoice(parent,
                              parent.external_append,
                              append_input_.contains(&root)
                                  ? append_input_.at(&root)
                                  : std::string());
    if (!parent.Name().has_value()) return;
    if (CheckNotMissing(parent)) return;

    const LoadedConfig* loaded =
        parent.dummy ? &empty_ : loader_.Load(parent.ConfigPath());
    if (loaded == nullptr) {
      if (parent.optional) {
        parent.deleted = true;
        return;
      }
      ConfigNotFound(root);
    }

    std::vector<Element> defaults = loaded->defaults;
    const bool root_with_appends =
        is_root_config && !overrides_.appends.empty();
    if (!defaults.empty() || root_with_appends) {
      ValidateSelf(parent, defaults, root_with_appends);
    }
    size_t first_append = defaults.size();
    if (is_root_config) {
      defaults.insert(
          defaults.end(), overrides_.appends.begin(), overrides_.appends.end());
    }
    UpdateOverrides(defaults, parent, interpolated_subtree);

    const std::string base_dir = parent.GroupPath();
    const std::string parent_pkg = parent.FinalPackage();
    std::vector<std::unique_ptr<TreeNode>> children;  // reverse order
    for (size_t i = defaults.size(); i-- > 0;) {
      Element& d = defaults[i];
      if (d.IsSelf()) {
        children.push_back(MakeNode(d, &root));
        continue;
      }
      if (d.override) continue;
      d.UpdateParent(base_dir, parent_pkg);
      if (overrides_.IsOverridden(d)) overrides_.OverrideDefaultOption(d);

      if (d.IsOptions()) {
        for (size_t j = d.value.list.size(); j-- > 0;) {
          const std::string& item = d.value.list[j];
          if (item.find("${") != std::string::npos) {
            throw ConfigError(fmt::format(
                "In '{}': Defaults List interpolation is not supported in "
                "options list items",
                parent.ConfigPath()));
          }
          Element e;
          e.path = d.group + "/" + item;
          e.package = d.package;
          e.optional = d.optional;
          e.list_item = true;
          e.UpdateParent(base_dir, parent_pkg);
          children.push_back(MakeNode(e, &root));
          Expand(*children.back(), false, interpolated_subtree);
        }
        continue;
      }
      if (d.IsInterpolation()) {
        d.pending_interpolation = true;
        children.push_back(MakeNode(d, &root));
        continue;
      }
      children.push_back(MakeNode(d, &root));
      if (is_root_config && i >= first_append) {
        append_input_[children.back().get()] =
            overrides_.AppendInput(i - first_append);
      }
      Expand(*children.back(), false, interpolated_subtree);
    }

    // Deferred defaults-list interpolations, resolved against the choices
    // known after everything else at this level was expanded.
    const auto known = overrides_.KnownChoices();
    for (std::unique_ptr<TreeNode>& child : children) {
      Element& e = child->node;
      if (!e.pending_interpolation) continue;
      e.pending_interpolation = false;
      if (e.is_group) {
        e.value.name = ResolveDefaultsInterpolation(e.value.name, known);
      } else {
        const bool absolute = e.path.starts_with('/');
        const std::string resolved =
            ResolveDefaultsInterpolation(StripLeadingSlash(e.path), known);
        e.path = absolute ? "/" + StripLeadingSlash(resolved) : resolved;
      }
      e.UpdateParent(base_dir, parent_pkg);
      Expand(*child, false, /*interpolated_subtree=*/true);
    }

    std::reverse(children.begin(), children.end());
    root.children = std::move(children);
  }

 private:
  static std::unique_ptr<TreeNode> MakeNode(const Element& element,
                                            TreeNode* parent) {
    auto node = std::make_unique<TreeNode>();
    node->node = element;
    node->parent = parent;
    return node;
  }

  static void ValidateSelf(const Element& containing,
                           std::vector<Element>& defaults,
                           bool root_with_appends) {
    bool has_self = false;
    bool has_non_override = false;
    for (const Element& d : defaults) {
      if (!d.override) has_non_override = true;
      if (d.IsSelf()) {
        if (has_self) {
          throw ConfigError(fmt::format("Duplicate _self_ defined in {}",
                                        containing.ConfigPath()));
        }
        has_self = true;
      }
    }
    if ((!has_self && (has_non_override || root_with_appends)) ||
        defaults.empty()) {
      defaults.push_back(SelfElement());
    }
  }

  void UpdateOverrides(std::vector<Element>& defaults,
                       const Element& parent,
                       bool interpolated_subtree) {
    bool seen_override = false;
    std::optional<Element> last_override;
    const std::string base_dir = parent.GroupPath();
    const std::string parent_pkg = parent.FinalPackage();
    for (Element& d : defaults) {
      if (d.IsSelf()) continue;
      d.UpdateParent(base_dir, parent_pkg);
      if (seen_override && !(d.override || d.external_append)) {
        throw ConfigError(fmt::format(
            "In {}: Override '{} : {}' is defined before '{}: {}'. Overrides "
            "must be at the end of the defaults list",
            parent.ConfigPath(),
            last_override->OverrideKey(),
            last_override->NameText(),
            d.OverrideKey(),
            d.NameText()));
      }
      if (d.is_group && d.override) {
        seen_override = true;
        last_override = d;
        if (interpolated_subtree) {
          throw ConfigError(fmt::format(
              "{}: Default List Overrides are not allowed in the subtree of an "
              "in interpolated config group (override {}={}).",
              parent.ConfigPath(),
              d.OverrideKey(),
              d.NameText()));
        }
        overrides_.AddOverride(parent.ConfigPath(), d);
      }
    }
  }

  bool CheckNotMissing(const Element& element) const {
    if (!element.IsMissing()) return false;
    if (skip_missing_) return true;
    if (!element.is_group) {
      throw ConfigError(fmt::format(
          "Missing ConfigDefault is not supported : {}", element.ConfigPath()));
    }
    const std::string key = element.OverrideKey();
    std::string msg =
        fmt::format("You must specify '{}', e.g, {}=<OPTION>", key, key);
    const std::vector<std::string> options = repo_.Options(element.GroupPath());
    if (!options.empty()) {
      msg += fmt::format(". Available options: {}", Join(options, ", "));
    }
    throw ConfigError(msg);
  }

  [[noreturn]] void ConfigNotFound(const TreeNode& tree) const {
    const Element& e = tree.node;
    if (e.primary) {
      throw ConfigError(fmt::format(
          "Cannot find primary config '{}'. Check that it's in your config "
          "search path.",
          e.ConfigPath()));
    }
    std::string msg;
    if (e.is_group || e.list_item) {
      msg = fmt::format("Could not find '{}'", e.ConfigPath());
      const std::string group = e.GroupPath();
      const std::vector<std::string> options = repo_.Options(group);
      if (!options.empty()) {
        msg += fmt::format(
            ". Available options in '{}': {}", group, Join(options, ", "));
      }
    } else {
      msg = fmt::format("Could not load '{}'.", e.ConfigPath());
    }
    if (tree.parent != nullptr && !tree.parent->node.dummy) {
      msg = fmt::format("In '{}': {}", tree.parent->node.ConfigPath(), msg);
    }
    throw ConfigError(msg);
  }

  const ConfigRepository& repo_;
  ConfigLoader& loader_;
  DefaultsOverrides& overrides_;
  bool skip_missing_;
  LoadedConfig empty_{ConfigNode::EmptyMap(), {}, std::nullopt, ""};
  std::map<const TreeNode*, std::string> append_input_;
};

// ---------------------------------------------------------------------------
// Flattening the tree into the final defaults list.

struct ResultEntry {
  DefaultsListEntry entry;
  bool primary = false;
  std::string override_key;  // group defaults only
};

void CollectResult(const TreeNode* tree,
                   const Element& node,
                   std::vector<ResultEntry>& out) {
  if (node.deleted || node.IsMissing() || node.dummy) return;
  if (!node.Name().has_value()) return;
  ResultEntry r;
  const Element* owner = &node;
  if (node.IsSelf()) {
    owner = &tree->node;
    if (owner->dummy) return;
    r.entry.config_path = owner->ConfigPath();
    r.entry.is_self = true;
    r.entry.parent = (tree->parent != nullptr && !tree->parent->node.dummy)
                         ? tree->parent->node.ConfigPath()
                         : std::string();
    r.entry.package = owner->FinalPackage();
    r.primary = owner->primary;
  } else {
    r.entry.config_path = node.ConfigPath();
    r.entry.parent = (tree != nullptr && !tree->node.dummy)
                         ? tree->node.ConfigPath()
                         : std::string();
    r.entry.package = node.FinalPackage();
    if (node.is_group) r.override_key = node.OverrideKey();
    r.primary = node.primary;
  }
  if (owner->is_group || owner->list_item) {
    r.entry.group = owner->GroupPath();
    r.entry.option = owner->Name().value_or("");
  }
  out.push_back(std::move(r));
}

void WalkTree(const TreeNode& tree, std::vector<ResultEntry>& out) {
  if (tree.children.empty()) {
    CollectResult(tree.parent, tree.node, out);
    return;
  }
  for (const std::unique_ptr<TreeNode>& child : tree.children) {
    WalkTree(*child, out);
  }
}

/// Registered group choices in DFS (defaults-list) order.
void CollectChoices(const TreeNode& tree,
                    std::vector<std::pair<std::string, std::string>>& out,
                    std::map<std::string, std::optional<std::string>>& seen,
                    std::vector<std::string>& order) {
  const Element& e = tree.node;
  if (e.is_group && e.choice_registered) {
    const std::string key = e.OverrideKey();
    if (!seen.contains(key)) {
      seen[key] = e.Name();
      order.push_back(key);
      out.emplace_back(key, e.Name().value_or("null"));
    }
  }
  for (const std::unique_ptr<TreeNode>& child : tree.children) {
    CollectChoices(*child, out, seen, order);
  }
}

// ---------------------------------------------------------------------------
// Value overrides (struct-mode semantics of Hydra's
// `_apply_overrides_to_config`).

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

std::string OverrideDirname(const std::vector<const Override*>& overrides,
                            const std::string& kv_sep,
                            const std::string& item_sep,
                            const std::set<std::string>& exclude_keys) {
  std::vector<std::string> lines;
  for (const Override* o : overrides) {
    if (!exclude_keys.contains(o->key)) lines.push_back(o->input);
  }
  std::sort(lines.begin(), lines.end());
  return ReplaceAll(Join(lines, item_sep), "=", kv_sep);
}

std::string ScalarText(const ConfigNode* node, std::string fallback) {
  if (node == nullptr) return fallback;
  if (std::optional<std::string> s = StringOf(*node)) return *s;
  if (node->IsNull() || node->IsMissing() || node->IsContainer()) {
    return fallback;
  }
  return node->text();
}

/// The primary config name without a `.yaml` suffix ("" for none).
std::string PrimaryConfigName(const ComposeRequest& request) {
  std::string name = request.config_name;
  if (name.ends_with(".yaml")) name.resize(name.size() - 5);
  return name;
}

/// The search path from the primary config (or a CLI `hydra.searchpath=`).
std::vector<std::string> ReadHydraSearchPath(const ComposeRequest& request,
                                             const ConfigRepository& repo) {
  std::optional<ConfigNode> searchpath;
  ConfigNode context = ConfigNode::EmptyMap();
  for (const Override& o : request.overrides) {
    if (!o.IsSweep() && o.key == "hydra.searchpath" &&
        o.type != OverrideType::kDelete && o.value.has_value()) {
      searchpath = *o.value;
      break;
    }
  }
  const std::string config_name = PrimaryConfigName(request);
  if (!searchpath.has_value() && !config_name.empty()) {
    if (std::optional<fs::path> file = repo.Find(config_name)) {
      ConfigFile primary = LoadConfigFile(*file);
      if (const ConfigNode* sp = primary.content.FindPath("hydra.searchpath")) {
        searchpath = *sp;
      }
      context = std::move(primary.content);
    }
  }
  std::vector<std::string> out;
  if (!searchpath.has_value() || searchpath->IsNull() ||
      searchpath->IsMissing()) {
    return out;
  }
  const auto fail = [&]() {
    throw ConfigError(
        fmt::format("hydra.searchpath must be a list of strings. Got: {}",
                    DumpFlow(*searchpath)));
  };
  if (!searchpath->IsList()) fail();
  for (size_t i = 0; i < searchpath->size(); ++i) {
    const ConfigNode& item = searchpath->at(i);
    if (item.IsString()) {
      out.push_back(item.AsString());
    } else if (item.IsInterpolation()) {
      const ConfigNode resolved =
          ResolveString(context,
                        item.text(),
                        fmt::format("hydra.searchpath[{}]", i),
                        DefaultResolvers());
      if (!resolved.IsString()) fail();
      out.push_back(resolved.AsString());
    } else {
      fail();
    }
  }
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------
// ConfigRepository

ConfigRepository::ConfigRepository(std::vector<std::string> roots) {
  for (size_t i = 0; i < roots.size(); ++i) {
    const fs::path path = ResolveRoot(roots[i]);
    std::error_code ec;
    if (!fs::is_directory(path, ec)) {
      const std::string shown = StripFileScheme(roots[i]);
      if (i == 0) {
        throw ConfigError(
            fmt::format("Primary config directory not found: '{}'", shown));
      }
      throw ConfigError(
          fmt::format("Config search path entry not found: '{}'", shown));
    }
    roots_.push_back(path);
  }
}

bool ConfigRepository::IsGroup(std::string_view group) const {
  ValidateConfigPath(group);
  const std::string rel = StripLeadingSlash(group);
  if (rel.empty()) return false;
  std::error_code ec;
  for (const fs::path& root : roots_) {
    if (fs::is_directory(root / rel, ec)) return true;
  }
  return false;
}

std::vector<std::string> ConfigRepository::Options(
    std::string_view group) const {
  ValidateConfigPath(group);
  const std::string rel = StripLeadingSlash(group);
  std::set<std::string> options;
  for (const fs::path& root : roots_) {
    const fs::path dir = rel.empty() ? root : root / rel;
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) continue;
    for (const fs::directory_entry& entry : fs::directory_iterator(dir, ec)) {
      if (entry.is_regular_file(ec) && entry.path().extension() == ".yaml") {
        options.insert(entry.path().stem().string());
      }
    }
  }
  return {options.begin(), options.end()};
}

std::vector<std::string> ConfigRepository::Groups() const {
  std::set<std::string> groups;
  for (const fs::path& root : roots_) {
    std::error_code ec;
    fs::recursive_directory_iterator it(root, ec);
    for (; !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
      const fs::directory_entry& entry = *it;
      const std::string name = entry.path().filename().string();
      if (name.starts_with('.')) {
        if (entry.is_directory(ec)) it.disable_recursion_pending();
        continue;
      }
      if (entry.is_directory(ec)) {
        groups.insert(entry.path().lexically_relative(root).generic_string());
      }
    }
  }
  return {groups.begin(), groups.end()};
}

std::optional<std::filesystem::path> ConfigRepository::Find(
    std::string_view config_path) const {
  ValidateConfigPath(config_path);
  const std::string rel = StripLeadingSlash(config_path);
  if (rel.empty()) return std::nullopt;
  std::error_code ec;
  for (const fs::path& root : roots_) {
    const fs::path file = root / (rel + ".yaml");
    if (fs::is_regular_file(file, ec)) return file;
  }
  return std::nullopt;
}

std::string_view ToString(RunMode mode) {
  return mode == RunMode::kMultirun ? "MULTIRUN" : "RUN";
}

// ---------------------------------------------------------------------------
// The hydra node

ConfigNode HydraDefaults() {
  ConfigNode hydra = ConfigNode::EmptyMap();

  ConfigNode run = ConfigNode::EmptyMap();
  run.Set("dir",
          ConfigNode::FromString("outputs/${now:%Y-%m-%d}/${now:%H-%M-%S}"));
  hydra.Set("run", std::move(run));

  ConfigNode sweep = ConfigNode::EmptyMap();
  sweep.Set("dir",
            ConfigNode::FromString("multirun/${now:%Y-%m-%d}/${now:%H-%M-%S}"));
  sweep.Set("subdir", ConfigNode::FromString("${hydra.job.num}"));
  hydra.Set("sweep", std::move(sweep));

  hydra.Set("output_subdir", ConfigNode::FromString(".hydra"));
  hydra.Set("searchpath", ConfigNode::EmptyList());
  hydra.Set("mode",
            ConfigNode::FromString(std::string(ToString(RunMode::kRun))));

  ConfigNode job = ConfigNode::EmptyMap();
  job.Set("name", ConfigNode::Missing());
  job.Set("chdir", ConfigNode(false));
  job.Set("num", ConfigNode(0));
  job.Set("id", ConfigNode::Missing());
  job.Set("override_dirname", ConfigNode::LiteralString(""));
  job.Set("config_name", ConfigNode::Null());
  ConfigNode dirname = ConfigNode::EmptyMap();
  dirname.Set("kv_sep", ConfigNode::FromString("="));
  dirname.Set("item_sep", ConfigNode::FromString(","));
  dirname.Set("exclude_keys", ConfigNode::EmptyList());
  ConfigNode job_config = ConfigNode::EmptyMap();
  job_config.Set("override_dirname", std::move(dirname));
  job.Set("config", std::move(job_config));
  hydra.Set("job", std::move(job));

  ConfigNode launcher = ConfigNode::EmptyMap();
  launcher.Set("n_jobs", ConfigNode(1));
  hydra.Set("launcher", std::move(launcher));

  ConfigNode sweeper = ConfigNode::EmptyMap();
  sweeper.Set("params", ConfigNode::Null());
  hydra.Set("sweeper", std::move(sweeper));

  ConfigNode overrides = ConfigNode::EmptyMap();
  overrides.Set("hydra", ConfigNode::EmptyList());
  overrides.Set("task", ConfigNode::EmptyList());
  hydra.Set("overrides", std::move(overrides));

  ConfigNode runtime = ConfigNode::EmptyMap();
  runtime.Set("choices", ConfigNode::EmptyMap());
  runtime.Set("config_sources", ConfigNode::EmptyList());
  std::error_code ec;
  const fs::path cwd = fs::current_path(ec);
  runtime.Set("cwd", ConfigNode::LiteralString(ec ? "" : cwd.string()));
  runtime.Set("output_dir", ConfigNode::Missing());
  runtime.Set("version", ConfigNode::LiteralString(SOMA_VERSION_STRING));
  hydra.Set("runtime", std::move(runtime));

  hydra.Set("verbose", ConfigNode(false));

  ConfigNode root = ConfigNode::EmptyMap();
  root.Set("hydra", std::move(hydra));
  root.SetSourceRecursive(SourceLocation{"<hydra defaults>", 0});
  root.SetPath(std::string());
  return root;
}

// ---------------------------------------------------------------------------
// Compose

ComposeResult Compose(const ComposeRequest& request) {
  // 1. The search path: request roots, then the primary's hydra.searchpath.
  std::vector<std::string> roots = request.search_path;
  std::vector<std::string> providers(roots.size(), "command-line");
  if (!providers.empty()) providers[0] = "main";
  {
    const ConfigRepository base(request.search_path);
    for (std::string& entry : ReadHydraSearchPath(request, base)) {
      roots.push_back(std::move(entry));
      providers.push_back("hydra.searchpath");
    }
  }
  const ConfigRepository repo(roots);

  // 2. Sweeps are only legal in multirun.
  for (const Override& o : request.overrides) {
    if (!o.IsSweep()) continue;
    if (request.mode == RunMode::kRun) {
      throw ConfigError(fmt::format(
          "Ambiguous value for argument '{}'. 1. To use it as a list, use "
          "key=[value1,value2] 2. To use it as string, quote the value: "
          "key=\\'value1,value2\\' 3. To sweep over it, add --multirun to "
          "your command line",
          o.input));
    }
    if (IsHydraKey(o.key)) {
      throw ConfigError(fmt::format(
          "Sweeping over Hydra's configuration is not supported : '{}'",
          o.input));
    }
  }

  // 3. The defaults tree and the final defaults list.
  ConfigLoader loader(repo);
  DefaultsOverrides overrides(repo, request.overrides);
  const bool skip_missing =
      request.mode == RunMode::kMultirun && request.allow_sweeps;
  DefaultsTreeBuilder builder(repo, loader, overrides, skip_missing);
  const std::string config_name = PrimaryConfigName(request);
  TreeNode tree;
  tree.node.primary = true;
  if (config_name.empty()) {
    tree.node.dummy = true;
    tree.node.path = std::string(kDummyConfig);
  } else {
    ValidateConfigPath(config_name);
    tree.node.path = config_name;
  }
  builder.Expand(tree, /*is_root_config=*/true, /*interpolated_subtree=*/false);

  std::vector<ResultEntry> results;
  WalkTree(tree, results);
  {
    std::set<std::string> keys;
    for (const ResultEntry& r : results) {
      if (r.entry.is_self || r.override_key.empty()) continue;
      if (!keys.insert(r.override_key).second) {
        throw ConfigError(
            fmt::format("{} appears more than once in the final defaults list",
                        r.override_key));
      }
    }
  }
  overrides.EnsureOverridesUsed();
  overrides.EnsureDeletionsUsed();

  // 4. Merge: the hydra defaults first, then the files in defaults order.
  ConfigNode root = HydraDefaults();
  root.at("hydra").Set(
      "mode", ConfigNode::FromString(std::string(ToString(request.mode))));
  for (const ResultEntry& r : results) {
    const LoadedConfig* loaded = loader.Load(r.entry.config_path);
    if (loaded == nullptr) {
      throw InternalError(fmt::format("config '{}' vanished during composition",
                                      r.entry.config_path));
    }
    if (!r.primary && loaded->content.FindPath("hydra.searchpath") != nullptr) {
      throw ConfigError(fmt::format(
          "In '{}': Overriding hydra.searchpath is only supported from the "
          "primary config",
          r.entry.config_path));
    }
    if (r.entry.package.empty()) {
      MergeInto(root, loaded->content);
    } else {
      ConfigNode embedded = ConfigNode::EmptyMap();
      embedded.SetPath(r.entry.package, loaded->content);
      MergeInto(root, embedded);
    }
  }

  // 5./6. Value overrides in command-line order, after all group overrides.
  for (const Override* o : overrides.config_overrides) {
    ApplyValueOverride(root, *o);
  }

  // 7. The hydra node.
  ConfigNode& hydra = root.at("hydra");
  ComposeResult result;
  std::map<std::string, std::optional<std::string>> seen;
  std::vector<std::string> order;
  CollectChoices(tree, result.choices, seen, order);

  std::vector<const Override*> task_overrides;
  {
    ConfigNode* lists = hydra.Find("overrides");
    if (lists == nullptr || !lists->IsMap()) {
      lists = &hydra.Set("overrides", ConfigNode::EmptyMap());
    }
    for (const char* name : {"task", "hydra"}) {
      ConfigNode* list = lists->Find(name);
      if (list == nullptr || !list->IsList()) {
        lists->Set(name, ConfigNode::EmptyList());
      }
    }
    for (const Override& o : request.overrides) {
      ConfigNode entry = ConfigNode::LiteralString(o.input);
      if (IsHydraKey(o.key)) {
        lists->at("hydra").Append(std::move(entry));
      } else {
        lists->at("task").Append(std::move(entry));
        task_overrides.push_back(&o);
      }
    }
  }

  ConfigNode* runtime = hydra.Find("runtime");
  if (runtime == nullptr || !runtime->IsMap()) {
    runtime = &hydra.Set("runtime", ConfigNode::EmptyMap());
  }
  ConfigNode* choices = runtime->Find("choices");
  if (choices == nullptr || !choices->IsMap()) {
    choices = &runtime->Set("choices", ConfigNode::EmptyMap());
  }
  for (const std::string& key : order) {
    const std::optional<std::string>& choice = seen.at(key);
    if (!choice.has_value()) {
      choices->Set(key, ConfigNode::Null());
    } else if (*choice == kMissingOption) {
      choices->Set(key, ConfigNode::Missing());
    } else {
      choices->Set(key, ConfigNode::LiteralString(*choice));
    }
  }
  runtime->Set("version", ConfigNode::LiteralString(SOMA_VERSION_STRING));
  {
    std::error_code ec;
    const fs::path cwd = fs::current_path(ec);
    runtime->Set("cwd", ConfigNode::LiteralString(ec ? "" : cwd.string()));
  }
  ConfigNode sources = ConfigNode::EmptyList();
  for (size_t i = 0; i < repo.roots().size(); ++i) {
    ConfigNode source = ConfigNode::EmptyMap();
    source.Set("path", ConfigNode::LiteralString(repo.roots()[i].string()));
    source.Set("schema", ConfigNode::LiteralString("file"));
    source.Set("provider", ConfigNode::LiteralString(providers[i]));
    sources.Append(std::move(source));
  }
  runtime->Set("config_sources", std::move(sources));

  ConfigNode* job = hydra.Find("job");
  if (job == nullptr || !job->IsMap()) {
    job = &hydra.Set("job", ConfigNode::EmptyMap());
  }
  if (const ConfigNode* name = job->Find("name");
      name == nullptr || name->IsMissing() || name->IsNull()) {
    job->Set("name", ConfigNode::LiteralString(request.job_name));
  }
  if (request.mode == RunMode::kRun) {
    if (const ConfigNode* id = job->Find("id");
        id == nullptr || id->IsMissing()) {
      job->Set("id", ConfigNode::LiteralString("0"));
    }
  }
  job->Set("config_name",
           config_name.empty() ? ConfigNode::Null()
                               : ConfigNode::LiteralString(config_name));
  {
    const ConfigNode* dirname_cfg = job->FindPath("config.override_dirname");
    const std::string kv_sep =
        ScalarText(dirname_cfg ? dirname_cfg->Find("kv_sep") : nullptr, "=");
    const std::string item_sep =
        ScalarText(dirname_cfg ? dirname_cfg->Find("item_sep") : nullptr, ",");
    std::set<std::string> exclude;
    if (dirname_cfg != nullptr) {
      if (const ConfigNode* keys = dirname_cfg->Find("exclude_keys");
          keys != nullptr && keys->IsList()) {
        for (const ConfigNode& k : keys->items()) {
          exclude.insert(ScalarText(&k, ""));
        }
      }
    }
    job->Set("override_dirname",
             ConfigNode::LiteralString(
                 OverrideDirname(task_overrides, kv_sep, item_sep, exclude)));
  }

  root.SetPath(std::string());
  root.set_struct_mode(true);

  result.root = std::move(root);
  for (ResultEntry& r : results) result.defaults.push_back(std::move(r.entry));
  for (const fs::path& p : repo.roots())
    result.search_path.push_back(p.string());
  return result;
}

ConfigNode TaskConfig(const ConfigNode& composed_root) {
  ConfigNode task = ConfigNode::EmptyMap();
  if (composed_root.IsMap()) {
    for (const auto& [key, value] : composed_root.entries()) {
      if (key != "hydra") task.Set(key, value);
    }
  }
  task.set_source(composed_root.source());
  task.SetPath(std::string());
  task.set_struct_mode(composed_root.struct_mode());
  return task;
}

std::string FormatDefaultsList(const ComposeResult& result) {
  const std::string kPathHeader = "Config path";
  const std::string kPackageHeader = "Package";
  const std::string kSelfHeader = "_self_";
  const std::string kParentHeader = "Parent";
  size_t path_width = kPathHeader.size();
  size_t package_width = kPackageHeader.size();
  size_t parent_width = kParentHeader.size();
  const auto parent_of = [](const DefaultsListEntry& e) {
    return e.parent.empty() ? std::string("<root>") : e.parent;
  };
  for (const DefaultsListEntry& e : result.defaults) {
    path_width = std::max(path_width, e.config_path.size());
    package_width = std::max(package_width, e.package.size());
    parent_width = std::max(parent_width, parent_of(e).size());
  }
  const auto row = [&](std::string_view path,
                       std::string_view package,
                       std::string_view self,
                       std::string_view parent) {
    return fmt::format("| {:<{}} | {:<{}} | {:<{}} | {:<{}} |\n",
                       path,
                       path_width,
                       package,
                       package_width,
                       self,
                       kSelfHeader.size(),
                       parent,
                       parent_width);
  };
  const std::string header =
      row(kPathHeader, kPackageHeader, kSelfHeader, kParentHeader);
  const std::string rule(header.size() - 1, '-');
  std::string out = "Defaults List\n*************\n";
  out += header;
  out += rule + "\n";
  for (const DefaultsListEntry& e : result.defaults) {
    out += row(
        e.config_path, e.package, e.is_self ? "True" : "False", parent_of(e));
  }
  out += rule + "\n";
  return out;
}

}  // namespace soma
