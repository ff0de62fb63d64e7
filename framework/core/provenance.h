// Provenance of a run: the code version (git SHA, dirty flag and diff), the
// build (compiler, build type, library versions), the host and its CPU.
// Recorded in every run directory's `.hydra/hydra.yaml` (HYDRA.md section 11).
#pragma once

#include <string>
#include <utility>
#include <vector>

namespace soma {

struct GitState {
  bool available = false;  // false outside a git checkout or without git
  std::string sha;         // HEAD commit, "" if none
  bool dirty = false;      // uncommitted changes to tracked files
  std::string diff;        // `git diff HEAD` when dirty
};

/// Queries git in `source_dir` (SOMA_SOURCE_DIR by default). Never throws.
GitState QueryGit(const std::string& source_dir = "");

struct BuildInfo {
  std::string version;     // somalab version
  std::string compiler;    // "GNU 12.2.0"
  std::string build_type;  // "Release"
  /// The commit the binary was compiled at, "<sha>" or "<sha>-dirty"
  /// (uncommitted changes to tracked files at build time), "unknown" outside
  /// a git checkout. Recorded at every build (cmake/BuildGit.cmake).
  std::string git_commit;
  /// (library, version) for libraries linked into this build.
  std::vector<std::pair<std::string, std::string>> libraries;
};

BuildInfo GetBuildInfo();

/// "<sha>" or "<sha>-dirty" for a checkout's state, "unknown" without git.
std::string CommitLabel(const GitState& git);

/// A warning when a binary compiled at `build_commit` runs in a checkout at
/// another commit (e.g. a copy of the binary kept for a long sweep while the
/// checkout moves on): the run's code is then the binary's, not the
/// checkout's. "" when they agree or either is unknown.
std::string BuildCommitMismatch(const std::string& build_commit,
                                const GitState& checkout);

/// The host name ("" if unknown).
std::string HostName();

/// The processor's model name, e.g. "Intel(R) Xeon(R) Processor" (the first
/// "model name" of /proc/cpuinfo; "" where there is none). Two hosts of one
/// name can be different machines, and floating-point results (BLAS kernels)
/// and speed follow the processor, so runs record it beside the host.
std::string CpuModel();

/// Current local time as ISO-8601 "2026-11-22T05:10:03".
std::string IsoNow();

}  // namespace soma
