#include "framework/core/resources.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <cstdlib>
#include <system_error>

namespace soma {
namespace fs = std::filesystem;

namespace {

constexpr int kMaxLevelsUp = 3;

bool IsDirectory(const fs::path& dir) {
  std::error_code ec;
  return fs::is_directory(dir, ec);
}

/// A source checkout: configs/ and models/ side by side.
bool IsSourceTree(const fs::path& dir) {
  return IsDirectory(dir / "configs") && IsDirectory(dir / "models");
}

}  // namespace

fs::path ExecutablePath() {
  std::error_code ec;
  fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (ec) return {};
  return exe;
}

bool IsResourceRoot(const fs::path& dir) {
  return IsDirectory(dir / "configs");
}

std::vector<fs::path> ResourceRootCandidates(const fs::path& executable) {
  std::vector<fs::path> out;
  if (executable.empty()) return out;
  fs::path dir = executable.parent_path();
  for (int level = 0; level <= kMaxLevelsUp && !dir.empty(); ++level) {
    out.push_back(dir / "share" / "somalab");
    out.push_back(dir);
    if (dir == dir.parent_path()) break;
    dir = dir.parent_path();
  }
  return out;
}

fs::path FindResourceRoot() {
  if (const char* home = std::getenv("SOMA_HOME"); home && *home) {
    if (!IsResourceRoot(home)) {
      throw IoError(fmt::format(
          "SOMA_HOME={}: expected a somalab resource root holding configs/ "
          "(an install's share/somalab or a source checkout)",
          home));
    }
    return fs::absolute(home).lexically_normal();
  }
  const fs::path exe = ExecutablePath();
  std::string tried;
  for (const fs::path& dir : ResourceRootCandidates(exe)) {
    // An installed share/somalab is a resource root by itself; a plain
    // directory counts only as a source tree (configs/ and models/), so that
    // an unrelated configs/ next to a copied binary is not picked up.
    const bool installed = dir.filename() == "somalab";
    if (installed ? IsResourceRoot(dir) : IsSourceTree(dir)) {
      return dir.lexically_normal();
    }
    tried += (tried.empty() ? "" : ", ") + dir.string();
  }
  throw IoError(fmt::format(
      "cannot find somalab's resources (configs/, models/, data/) from the "
      "executable {}; looked in: {}. Set SOMA_HOME to an install's "
      "share/somalab or to a source checkout",
      exe.empty() ? std::string("(unknown)") : exe.string(),
      tried.empty() ? std::string("nothing") : tried));
}

fs::path ResourcePath(const fs::path& relative) {
  return FindResourceRoot() / relative;
}

}  // namespace soma
