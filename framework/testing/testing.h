// Test helpers shared by every test executable (soma_testing: a test-only
// library that links soma::core and GoogleTest, nothing above core).
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <functional>
#include <string>

namespace soma::testing {

/// A fresh empty directory unique to the running test:
/// `$TMPDIR/somalab_tests/<suite>.<test>.<pid>/`, removed at process start.
std::filesystem::path CreateTestDir();

/// The project root (SOMA_SOURCE_DIR from the environment or the build).
std::filesystem::path SourceDir();

/// `../shared/data` beside the project root.
std::filesystem::path SharedDataDir();

/// Writes `contents` to `dir/relative` (creating parent directories).
void WriteTextFile(const std::filesystem::path& dir,
                   const std::string& relative,
                   const std::string& contents);

/// Runs `fn`, which must throw `E`, and returns the exception's message (an
/// empty string and a test failure if it does not throw).
template <typename E, typename Fn>
std::string ErrorMessage(Fn&& fn) {
  try {
    fn();
  } catch (const E& error) {
    return error.what();
  }
  ADD_FAILURE() << "expected an exception";
  return "";
}

/// Adds a gtest environment that runs `set_up` once, before the first test
/// of the executable. For a test executable that builds components through
/// the global registries without the whole framework: `set_up` makes the
/// registrations InitFramework() makes for the modules it links, in its order,
/// and freezes the registries (tests/<module>/registrations.cc). Call it from
/// a namespace-scope initializer of the executable's own object file (a static
/// library would drop that object).
::testing::Environment* AddSetUpOnce(std::function<void()> set_up);

}  // namespace soma::testing
