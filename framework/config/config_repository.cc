#include "framework/config/config_repository.h"

#include "framework/config/compose_internal.h"
#include "framework/core/error.h"

#include <fmt/format.h>

#include <set>
#include <system_error>

namespace soma {
namespace {

namespace fs = std::filesystem;

using internal::StripLeadingSlash;
using internal::ValidateConfigPath;

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

}  // namespace

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

}  // namespace soma
