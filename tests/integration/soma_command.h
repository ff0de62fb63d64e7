// Runs the `soma` binary built with the tests (SOMA_BINARY) as a user would.
#pragma once

#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <cstdlib>
#include <filesystem>
#include <string>
#include <sys/wait.h>
#include <vector>

namespace soma::testing {

/// `soma <args> -cp <source>/configs` in `cwd`; returns the exit status and
/// the command's stderr in `*err`.
inline int RunSomaTask(const std::filesystem::path& cwd,
                       const std::vector<std::string>& args,
                       std::string* err) {
  std::string command = "cd '" + cwd.string() + "' && '" + SOMA_BINARY + "'";
  for (const std::string& a : args) command += " '" + a + "'";
  command += " -cp '" + (SourceDir() / "configs").string() + "' 2> stderr.txt";
  const int status = std::system(command.c_str());
  *err = ReadFile(cwd / "stderr.txt");
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace soma::testing
