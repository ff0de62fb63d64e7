// The defaults tree of Hydra-style composition. The algorithm mirrors Hydra 1.3
// (`hydra/_internal/defaults_list.py`, `core/default_element.py`,
// `_internal/config_loader_impl.py`): children are expanded in reverse order
// so that `override` entries of later configs apply to group defaults chosen
// earlier, the first registered override of a key wins (CLI first, then the
// later configs), and the final defaults list is a DFS walk of the tree.
#include "framework/config/defaults_tree.h"

#include "framework/config/compose_internal.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <map>
#include <memory>
#include <regex>
#include <set>
#include <utility>

namespace soma {
namespace internal {
namespace {

namespace fs = std::filesystem;

constexpr std::string_view kGlobal = "_global_";
constexpr std::string_view kSelf = "_self_";
constexpr std::string_view kDummyConfig = "_dummy_empty_config_";

/// True if `text` contains a `${` not preceded by a backslash.
bool ContainsInterpolation(std::string_view text) {
  for (size_t pos = text.find("${"); pos != std::string_view::npos;
       pos = text.find("${", pos + 1)) {
    if (pos == 0 || text[pos - 1] != '\\') return true;
  }
  return false;
}

/// The text after the first '=' of an override as written.
std::string OverrideValueText(const Override& o) {
  const size_t eq = o.input.find('=');
  return eq == std::string::npos ? std::string() : o.input.substr(eq + 1);
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
      std::string g = StripLeadingSlash(group);
      if (parent_base_dir.empty() || absolute) return g;
      return parent_base_dir + "/" + g;
    }
    const bool absolute = path.starts_with('/');
    const std::string p = StripLeadingSlash(path);
    const size_t slash = p.rfind('/');
    std::string g = slash == std::string::npos ? "" : p.substr(0, slash);
    if (absolute || parent_base_dir.empty()) return g;
    if (g.empty()) return parent_base_dir;
    return parent_base_dir + "/" + g;
  }

  std::string ConfigPath() const {
    if (dummy) return std::string(kDummyConfig);
    if (is_group) return GroupPath() + "/" + Name().value_or("null");
    const bool absolute = path.starts_with('/');
    std::string p = StripLeadingSlash(path);
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
      loaded = FromFile(config_path, LoadConfigFile(*file));
    }
    const LoadedConfig* result = loaded.get();
    cache_.emplace(config_path, std::move(loaded));
    return result;
  }

  /// Makes `file`, already read from the repository, what Load(config_path)
  /// returns.
  void Add(const std::string& config_path, ConfigFile file) {
    cache_[config_path] = FromFile(config_path, std::move(file));
  }

  bool Exists(const std::string& config_path) const {
    return repo_.Find(config_path).has_value();
  }

 private:
  static std::unique_ptr<LoadedConfig> FromFile(const std::string& config_path,
                                                ConfigFile cf) {
    auto loaded = std::make_unique<LoadedConfig>();
    loaded->file = std::move(cf.path);
    if (cf.has_package_directive) loaded->header = cf.package;
    loaded->content = std::move(cf.content);
    if (!loaded->content.IsMap()) loaded->content = ConfigNode::EmptyMap();
    if (const ConfigNode* defaults = loaded->content.Find("defaults")) {
      loaded->defaults = ParseDefaultsList(config_path, *defaults);
      loaded->content.Erase("defaults");
    }
    return loaded;
  }

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
    keys.reserve(known.size());
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
    if (!parent.dummy) CheckNotItsOwnAncestor(root);

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
  // A config whose defaults list leads back to itself (`a` lists `b`, `b`
  // lists `a`, or a config lists itself) would expand forever: Hydra's own
  // report of it (hydra#1828, for 1.1) is a RecursionError, this tree's was
  // a stack overflow (a config fuzzer finding). The error names the chain.
  static void CheckNotItsOwnAncestor(const TreeNode& node) {
    const std::string path = node.node.ConfigPath();
    for (const TreeNode* up = node.parent; up != nullptr && !up->node.dummy;
         up = up->parent) {
      if (up->node.ConfigPath() != path) continue;
      std::vector<std::string> chain = {path};
      for (const TreeNode* n = node.parent; n != up; n = n->parent) {
        chain.push_back(n->node.ConfigPath());
      }
      chain.push_back(path);
      std::reverse(chain.begin(), chain.end());
      throw ConfigError(
          fmt::format("Circular defaults list: '{}' includes itself ({})",
                      path,
                      fmt::join(chain, " -> ")));
    }
  }

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

}  // namespace

DefaultsListResult BuildDefaultsList(const ConfigRepository& repo,
                                     const std::vector<Override>& overrides,
                                     const std::string& config_name,
                                     bool skip_missing,
                                     const ConfigFile* primary_file) {
  ConfigLoader loader(repo);
  DefaultsOverrides defaults_overrides(repo, overrides);
  DefaultsTreeBuilder builder(repo, loader, defaults_overrides, skip_missing);
  TreeNode tree;
  tree.node.primary = true;
  if (config_name.empty()) {
    tree.node.dummy = true;
    tree.node.path = std::string(kDummyConfig);
  } else {
    ValidateConfigPath(config_name);
    tree.node.path = config_name;
    if (primary_file != nullptr)
      loader.Add(tree.node.ConfigPath(), *primary_file);
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
  defaults_overrides.EnsureOverridesUsed();
  defaults_overrides.EnsureDeletionsUsed();

  DefaultsListResult out;
  for (ResultEntry& r : results) {
    const LoadedConfig* loaded = loader.Load(r.entry.config_path);
    if (loaded == nullptr) {
      throw InternalError(fmt::format("config '{}' vanished during composition",
                                      r.entry.config_path));
    }
    out.defaults.push_back(
        ResolvedDefault{std::move(r.entry), r.primary, loaded->content});
  }
  std::map<std::string, std::optional<std::string>> seen;
  std::vector<std::string> order;
  CollectChoices(tree, out.choices, seen, order);
  for (const std::string& key : order) {
    out.choice_values.emplace_back(key, seen.at(key));
  }
  out.value_overrides = std::move(defaults_overrides.config_overrides);
  return out;
}

}  // namespace internal
}  // namespace soma
