// Helpers shared by the parts of Hydra-style composition (compose.cc,
// config_repository.cc, defaults_tree.cc, value_override.cc). Not part of
// the public config API.
#pragma once

#include "framework/config/node.h"

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace soma {
namespace internal {

/// The option name Hydra uses for a mandatory choice (`db: ???`).
inline constexpr std::string_view kMissingOption = "???";

/// `items` joined with `sep`.
std::string Join(const std::vector<std::string>& items, std::string_view sep);

/// `text` with every occurrence of `from` replaced by `to` (no-op for an
/// empty `from`).
std::string ReplaceAll(std::string text,
                       std::string_view from,
                       std::string_view to);

/// `path` without one leading '/' (absolute group paths are root-relative).
std::string StripLeadingSlash(std::string_view path);

/// Rejects `..` components and backslashes in config and group paths: a
/// ConfigError naming `path`.
void ValidateConfigPath(std::string_view path);

/// The string of a string or interpolation node; nullopt for anything else.
std::optional<std::string> StringOf(const ConfigNode& node);

}  // namespace internal
}  // namespace soma
