// libFuzzer target for YAML loading and composition: the input is YAML text.
//   1. ParseYaml must return or throw soma::Error; a parsed node must survive
//      DumpYaml -> ParseYaml unchanged (yaml_io.h promises the round trip).
//   2. The text is the option `fuzz/input.yaml` of a small config tree (in a
//      temporary directory) that the primary `config.yaml` selects, and then
//      the primary config itself; each composition and the resolution of its
//      interpolations (Resolve) must return or throw soma::Error.
// Never crash, hang or over-allocate.
//
// Build: scripts/fuzz.sh config (clang, -fsanitize=fuzzer,address,undefined).
#include "framework/config/compose.h"
#include "framework/config/interpolation.h"
#include "framework/config/node.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <unistd.h>

namespace fs = std::filesystem;

namespace {

// A broken invariant is a finding: name it, then abort so libFuzzer saves
// the input.
void Fail(const char* condition, int line) {
  std::fprintf(
      stderr, "config_fuzzer.cc:%d: invariant broken: %s\n", line, condition);
  std::abort();
}
#define REQUIRE(condition) \
  ((condition) ? static_cast<void>(0) : Fail(#condition, __LINE__))

fs::path tree_root;  // NOLINT: set once by LLVMFuzzerInitialize
// SOMA_FUZZ_VERBOSE=1 prints the errors (to check what a seed reaches).
bool verbose = false;  // NOLINT: set once by LLVMFuzzerInitialize

void Report(const char* stage, const soma::Error& e) {
  if (verbose) std::fprintf(stderr, "[%s] %s\n", stage, e.what());
}

void WriteFile(const fs::path& path, std::string_view text) {
  fs::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  if (!out) {
    std::fprintf(stderr, "config_fuzzer: cannot write %s\n", path.c_str());
    std::abort();
  }
}

void RemoveTree() {
  std::error_code ec;
  if (!tree_root.empty()) fs::remove_all(tree_root, ec);
}

// Where the config tree lives: /dev/shm where it is a writable directory
// (tmpfs on Linux) unless TMPDIR says otherwise, else the temp directory.
// Each input rewrites two files of the tree and each composition opens and
// stats several: on a disk file system (ext4) opening with O_TRUNC and
// closing took ~9% of the fuzzer's CPU time (perf), on tmpfs half of that.
fs::path TreeParent() {
  std::error_code ec;
  const fs::path shm = "/dev/shm";
  if (std::getenv("TMPDIR") == nullptr && fs::is_directory(shm, ec) &&
      ::access(shm.c_str(), W_OK) == 0) {
    return shm;
  }
  return fs::temp_directory_path();
}

// The config tree: a primary config with a defaults list, two groups (one
// nested, with packages) and interpolations into the fuzzed option. Made
// once; each input rewrites only fuzz/input.yaml and primary.yaml.
void MakeTree() {
  std::string pattern = (TreeParent() / "soma_config_fuzz.XXXXXX");
  if (::mkdtemp(pattern.data()) == nullptr) {
    std::fprintf(stderr, "config_fuzzer: mkdtemp failed\n");
    std::abort();
  }
  tree_root = pattern;
  std::atexit(RemoveTree);
  WriteFile(tree_root / "config.yaml",
            "defaults:\n"
            "  - _self_\n"
            "  - db: mysql\n"
            "  - server/db@backend: sqlite\n"
            "  - optional extra: none\n"
            "  - fuzz: input\n"
            "app:\n"
            "  name: demo\n"
            "  url: ${db.host}:${db.port}\n"
            "  size: ${oc.select:fuzz.size,3}\n"
            "  job: ${hydra:job.name}\n"
            "seeds: [1, 2, 3]\n");
  WriteFile(tree_root / "db/mysql.yaml",
            "host: localhost\n"
            "port: 3306\n"
            "user: ${oc.env:SOMA_FUZZ_UNSET_VARIABLE,nobody}\n");
  WriteFile(tree_root / "db/postgres.yaml",
            "# @package _group_\n"
            "host: pg\n"
            "port: 5432\n"
            "tables: ???\n");
  WriteFile(tree_root / "server/db/sqlite.yaml",
            "defaults:\n"
            "  - /db@server: postgres\n"
            "  - _self_\n"
            "file: ${..app.name}.db\n");
  WriteFile(tree_root / "fuzz/other.yaml", "size: 1\nitems: [a, b]\n");
}

void Compose(const std::string& config_name) {
  soma::ComposeRequest request;
  request.search_path = {tree_root.string()};
  request.config_name = config_name;
  request.job_name = "fuzz";
  const soma::ComposeResult result = soma::Compose(request);
  (void)soma::FormatDefaultsList(result);
  // A fresh registry per input: `now` caches one value per pattern.
  const soma::ResolverRegistry resolvers;
  const soma::ConfigNode resolved = soma::Resolve(result.root, resolvers);
  (void)soma::DumpYaml(soma::TaskConfig(resolved));
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  soma::Logger::SetConsoleLevel(soma::LogLevel::kError);
  const char* v = std::getenv("SOMA_FUZZ_VERBOSE");
  verbose = v != nullptr && std::string_view(v) == "1";
  MakeTree();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  std::optional<soma::ConfigNode> node;
  try {
    node = soma::ParseYaml(text, "fuzz.yaml");
  } catch (const soma::Error& e) {
    Report("ParseYaml", e);
  }
  bool sets_searchpath = false;
  if (node.has_value()) {
    (void)soma::DumpFlow(*node);
    const std::string dumped = soma::DumpYaml(*node);
    std::optional<soma::ConfigNode> again;
    try {
      again = soma::ParseYaml(dumped, "dumped.yaml");
    } catch (const soma::Error& e) {
      std::fprintf(stderr,
                   "DumpYaml output does not parse: %s\n---\n%s---\n",
                   e.what(),
                   dumped.c_str());
      Fail("ParseYaml(DumpYaml(node)) succeeds", __LINE__);
    }
    if (*again != *node) {
      std::fprintf(
          stderr, "DumpYaml round trip differs:\n---\n%s---\n", dumped.c_str());
      Fail("ParseYaml(DumpYaml(node)) == node", __LINE__);
    }
    // hydra.searchpath would add arbitrary directories of this machine to
    // the search path: not composed as the primary config.
    sets_searchpath =
        node->IsMap() && node->FindPath("hydra.searchpath") != nullptr;
  }

  WriteFile(tree_root / "fuzz/input.yaml", text);
  try {
    Compose("config");
  } catch (const soma::Error& e) {
    Report("option", e);
  }
  if (!sets_searchpath) {
    WriteFile(tree_root / "primary.yaml", text);
    try {
      Compose("primary");
    } catch (const soma::Error& e) {
      Report("primary", e);
    }
  }
  return 0;
}
