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
  /// (library, version) for libraries linked into this build.
  std::vector<std::pair<std::string, std::string>> libraries;
};

BuildInfo GetBuildInfo();

/// The host name ("" if unknown).
std::string HostName();

/// The processor's model name, e.g. "AMD EPYC 9B14" (the first "model name"
/// of /proc/cpuinfo; "" where there is none). Two hosts of one name can be
/// different machines, and floating-point results (BLAS kernels) and speed
/// follow the processor, so runs record it beside the host.
std::string CpuModel();

/// Current local time as ISO-8601 "2026-11-22T05:10:03".
std::string IsoNow();

}  // namespace soma
