// Where somalab's read-only resources live: the composed `configs/`, the
// bundled labelers in `models/` and the bundled capture in `data/`.
//
// The resource root is found without any path compiled into the binary, in
// this order:
//   1. `$SOMA_HOME`, if set (it must hold `configs/`);
//   2. from the running executable's directory upwards (at most 3 levels):
//      `<dir>/share/somalab` (an installed prefix: `<prefix>/bin/soma` finds
//      `<prefix>/share/somalab`), else `<dir>` itself when it holds both
//      `configs/` and `models/` (a source checkout: `build/soma` finds the
//      repository root above it).
// So a build tree, a copy of the binary beside a checkout and a
// `cmake --install` prefix all work, and moving an installed prefix as a
// whole keeps working.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace soma {

/// The absolute path of the running executable (`/proc/self/exe`); empty if
/// the platform cannot say.
std::filesystem::path ExecutablePath();

/// The candidate resource roots for an executable at `executable`, in the
/// order they are tried (without `$SOMA_HOME`).
std::vector<std::filesystem::path> ResourceRootCandidates(
    const std::filesystem::path& executable);

/// True if `dir` looks like a resource root (it holds `configs/`).
bool IsResourceRoot(const std::filesystem::path& dir);

/// The resource root as described above. Throws IoError naming every place
/// it looked (and `$SOMA_HOME` when that is set but holds no `configs/`).
std::filesystem::path FindResourceRoot();

/// `FindResourceRoot() / relative`.
std::filesystem::path ResourcePath(const std::filesystem::path& relative);

}  // namespace soma
