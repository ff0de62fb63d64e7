#include "framework/config/compose_internal.h"

#include "framework/core/error.h"

#include <fmt/format.h>

namespace soma {
namespace internal {

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

/// The string of a string or interpolation node.
std::optional<std::string> StringOf(const ConfigNode& node) {
  if (node.IsString()) return node.AsString();
  if (node.IsInterpolation()) return node.text();
  return std::nullopt;
}

}  // namespace internal
}  // namespace soma
