// Hydra-style composition: the search path, the defaults list (built by
// defaults_tree.cc), the merge of the selected configs, value overrides
// (value_override.cc) and the `hydra` node.
#include "framework/config/compose.h"

#include "framework/config/compose_internal.h"
#include "framework/config/defaults_tree.h"
#include "framework/config/value_override.h"
#include "framework/config/yaml_io.h"
#include "framework/core/build_info.h"
#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <optional>
#include <set>
#include <system_error>
#include <utility>

namespace soma {
namespace {

namespace fs = std::filesystem;

using internal::Join;
using internal::ReplaceAll;
using internal::StringOf;

bool IsHydraKey(std::string_view key) {
  return key == "hydra" || key.starts_with("hydra.") ||
         key.starts_with("hydra/");
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
/// Sets `*primary_file` to the primary config file if it was read.
std::vector<std::string> ReadHydraSearchPath(
    const ComposeRequest& request,
    const ConfigRepository& repo,
    std::optional<ConfigFile>* primary_file) {
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
      *primary_file = LoadConfigFile(*file);
      const ConfigNode& content = (*primary_file)->content;
      if (const ConfigNode* sp = content.FindPath("hydra.searchpath")) {
        searchpath = *sp;
      }
      context = content;
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
  // The primary config file, read once: its hydra.searchpath extends the
  // search path, and the search path's first roots (where it was found)
  // still find it first.
  std::optional<ConfigFile> primary_file;
  {
    const ConfigRepository base(request.search_path);
    for (std::string& entry :
         ReadHydraSearchPath(request, base, &primary_file)) {
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
  const std::string config_name = PrimaryConfigName(request);
  const bool skip_missing =
      request.mode == RunMode::kMultirun && request.allow_sweeps;
  internal::DefaultsListResult defaults =
      internal::BuildDefaultsList(repo,
                                  request.overrides,
                                  config_name,
                                  skip_missing,
                                  primary_file ? &*primary_file : nullptr);

  // 4. Merge: the hydra defaults first, then the files in defaults order.
  ConfigNode root = HydraDefaults();
  root.at("hydra").Set(
      "mode", ConfigNode::FromString(std::string(ToString(request.mode))));
  for (const internal::ResolvedDefault& d : defaults.defaults) {
    if (!d.primary && d.content.FindPath("hydra.searchpath") != nullptr) {
      throw ConfigError(fmt::format(
          "In '{}': Overriding hydra.searchpath is only supported from the "
          "primary config",
          d.entry.config_path));
    }
    if (d.entry.package.empty()) {
      MergeInto(root, d.content);
    } else {
      ConfigNode embedded = ConfigNode::EmptyMap();
      embedded.SetPath(d.entry.package, d.content);
      MergeInto(root, embedded);
    }
  }

  // 5./6. Value overrides in command-line order, after all group overrides.
  for (const Override* o : defaults.value_overrides) {
    ApplyValueOverride(root, *o);
  }

  // 7. The hydra node.
  ConfigNode& hydra = root.at("hydra");
  ComposeResult result;
  result.choices = defaults.choices;

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
  for (const auto& [key, choice] : defaults.choice_values) {
    if (!choice.has_value()) {
      choices->Set(key, ConfigNode::Null());
    } else if (*choice == internal::kMissingOption) {
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
  for (internal::ResolvedDefault& d : defaults.defaults) {
    result.defaults.push_back(std::move(d.entry));
  }
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
