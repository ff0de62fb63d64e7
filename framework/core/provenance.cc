#include "framework/core/provenance.h"

#include "framework/core/build_git.h"
#include "framework/core/build_info.h"

#include <fmt/format.h>

#include <array>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <memory>
#include <unistd.h>

namespace soma {
namespace {

/// Runs a shell command; returns (exit status, stdout). Never throws.
std::pair<int, std::string> RunCommand(const std::string& command) {
  std::string output;
  FILE* pipe = ::popen(command.c_str(), "r");
  if (pipe == nullptr) return {-1, ""};
  std::array<char, 4096> buffer;
  size_t n;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0) {
    output.append(buffer.data(), n);
  }
  const int status = ::pclose(pipe);
  return {status, output};
}

std::string Trim(std::string s) {
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
  return s;
}

std::string ShellQuote(const std::string& s) {
  std::string out = "'";
  for (char c : s) {
    if (c == '\'') {
      out += "'\\''";
    } else {
      out += c;
    }
  }
  return out + "'";
}

}  // namespace

GitState QueryGit(const std::string& source_dir) {
  GitState state;
  const std::string dir = source_dir.empty() ? SOMA_SOURCE_DIR : source_dir;
  const std::string git = "git -C " + ShellQuote(dir) + " ";
  auto [status, sha] = RunCommand(git + "rev-parse HEAD 2>/dev/null");
  if (status != 0) {
    // A checkout without commits still counts as a repository.
    auto [inside, out] =
        RunCommand(git + "rev-parse --is-inside-work-tree 2>/dev/null");
    if (inside != 0) return state;
    state.available = true;
    state.dirty = true;
    return state;
  }
  state.available = true;
  state.sha = Trim(sha);
  auto [st, porcelain] =
      RunCommand(git + "status --porcelain --untracked-files=no 2>/dev/null");
  state.dirty = st == 0 && !Trim(porcelain).empty();
  if (state.dirty) {
    state.diff = RunCommand(git + "diff HEAD 2>/dev/null").second;
  }
  return state;
}

BuildInfo GetBuildInfo() {
  BuildInfo info;
  info.version = SOMA_VERSION_STRING;
  info.compiler = SOMA_CXX_COMPILER;
  info.build_type = SOMA_BUILD_TYPE;
  info.git_commit = SOMA_BUILD_GIT_COMMIT;
  const std::pair<const char*, const char*> libs[] = {
      {"fmt", SOMA_FMT_VERSION},
      {"yaml-cpp", SOMA_YAML_CPP_VERSION},
      {"libtorch", SOMA_TORCH_VERSION},
      {"eigen", SOMA_EIGEN_VERSION},
      {"ceres", SOMA_CERES_VERSION},
      {"hdf5", SOMA_HDF5_VERSION},
  };
  for (const auto& [name, version] : libs) {
    if (version[0] != '\0') info.libraries.emplace_back(name, version);
  }
  return info;
}

std::string CommitLabel(const GitState& git) {
  if (!git.available || git.sha.empty()) return "unknown";
  return git.sha + (git.dirty ? "-dirty" : "");
}

std::string BuildCommitMismatch(const std::string& build_commit,
                                const GitState& checkout) {
  const std::string at = CommitLabel(checkout);
  if (build_commit == "unknown" || build_commit.empty() || at == "unknown" ||
      build_commit == at) {
    return "";
  }
  return fmt::format(
      "this binary was compiled at commit {} but the checkout is at {}; the "
      "code that runs is the binary's (hydra.runtime.provenance.build_commit)",
      build_commit,
      at);
}

std::string HostName() {
  char buffer[256] = {0};
  if (::gethostname(buffer, sizeof(buffer) - 1) != 0) return "";
  return buffer;
}

std::string CpuModel() {
  std::ifstream in("/proc/cpuinfo");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("model name", 0) != 0) continue;
    const size_t colon = line.find(':');
    if (colon == std::string::npos) continue;
    std::string name = line.substr(colon + 1);
    name.erase(0, name.find_first_not_of(" \t"));
    return Trim(name);
  }
  return "";
}

std::string IsoNow() {
  const std::time_t now = std::time(nullptr);
  std::tm local{};
  localtime_r(&now, &local);
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%dT%H:%M:%S", &local);
  return buffer;
}

}  // namespace soma
