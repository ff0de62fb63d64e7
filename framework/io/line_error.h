// The error of the line-oriented text readers (BVH, ASF/AMC): one line that
// starts with the file and line, "walk.bvh:12: expected 'OFFSET', got 'OFSET'";
// and file text quoted in such a line (C3D parameters, TRC cells).
#pragma once

#include "framework/core/error.h"

#include <fmt/format.h>

#include <cstddef>
#include <filesystem>
#include <string>
#include <string_view>
#include <utility>

namespace soma {

/// Throws IoError("<path>:<line>: <formatted message>").
template <typename... Args>
[[noreturn]] void ThrowAtLine(const std::filesystem::path& path,
                              int line,
                              fmt::format_string<Args...> format,
                              Args&&... args) {
  throw IoError(fmt::format("{}:{}: {}",
                            path.string(),
                            line,
                            fmt::format(format, std::forward<Args>(args)...)));
}

/// `text` quoted for a one-line error message: its first `max_bytes` bytes,
/// control and non-ASCII bytes written as \xNN, and "..." when cut, so that
/// a binary or multi-line field cannot break the message's line.
inline std::string ForMessage(std::string_view text, size_t max_bytes = 60) {
  std::string out;
  for (size_t i = 0; i < text.size() && i < max_bytes; ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if (c < 0x20 || c >= 0x7f) {
      out += fmt::format("\\x{:02x}", c);
    } else {
      out.push_back(static_cast<char>(c));
    }
  }
  if (text.size() > max_bytes) out += "...";
  return out;
}

}  // namespace soma
