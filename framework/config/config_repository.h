// The config search path of Hydra-style composition (HYDRA.md section 2):
// the roots that hold config groups (directories) and configs (`*.yaml`),
// and the lookup of a group's options and of a config file by its path.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// The config search path: roots scanned for group directories and configs.
/// Earlier roots win on name clashes.
class ConfigRepository {
 public:
  /// `roots` are directories (a `file://` prefix is stripped; relative paths
  /// are resolved against the CWD). A root that does not exist is a
  /// ConfigError naming it.
  explicit ConfigRepository(std::vector<std::string> roots);

  const std::vector<std::filesystem::path>& roots() const { return roots_; }
  /// True if any root has a directory `group` (e.g. "server/db").
  bool IsGroup(std::string_view group) const;
  /// Sorted option names (file stems of `*.yaml`) of a group over all roots.
  std::vector<std::string> Options(std::string_view group) const;
  /// Every group path (recursively, sorted), e.g. {"db", "server",
  /// "server/db"}.
  std::vector<std::string> Groups() const;
  /// The file for config path "group/option" or "name" (first root wins).
  std::optional<std::filesystem::path> Find(std::string_view config_path) const;

 private:
  std::vector<std::filesystem::path> roots_;
};

}  // namespace soma
