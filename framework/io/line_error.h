// The error of the line-oriented text readers (BVH, ASF/AMC): one line that
// starts with the file and line, "walk.bvh:12: expected 'OFFSET', got 'OFSET'".
#pragma once

#include "framework/core/error.h"

#include <fmt/format.h>

#include <filesystem>
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

}  // namespace soma
