#include "framework/testing/testing.h"

#include "framework/core/build_info.h"
#include "framework/core/error.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <functional>
#include <mutex>
#include <unistd.h>
#include <utility>

namespace soma::testing {

std::filesystem::path CreateTestDir() {
  const ::testing::TestInfo* info =
      ::testing::UnitTest::GetInstance()->current_test_info();
  std::string name =
      info ? fmt::format("{}.{}", info->test_suite_name(), info->name())
           : std::string("no_test");
  for (char& c : name) {
    if (c == '/') c = '_';
  }
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    "somalab_tests" /
                                    fmt::format("{}.{}", name, ::getpid());
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

std::filesystem::path SourceDir() {
  if (const char* env = std::getenv("SOMA_SOURCE_DIR")) return env;
  return SOMA_SOURCE_DIR;
}

std::filesystem::path SharedDataDir() {
  return SourceDir().parent_path() / "shared" / "data";
}

void WriteTextFile(const std::filesystem::path& dir,
                   const std::string& relative,
                   const std::string& contents) {
  const std::filesystem::path path = dir / relative;
  std::filesystem::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary);
  SOMA_CHECK(static_cast<bool>(out)) << "cannot write " << path.string();
  out << contents;
}

namespace {

class SetUpOnce : public ::testing::Environment {
 public:
  explicit SetUpOnce(std::function<void()> set_up)
      : set_up_(std::move(set_up)) {}
  void SetUp() override { std::call_once(once_, set_up_); }

 private:
  std::function<void()> set_up_;
  std::once_flag once_;
};

}  // namespace

::testing::Environment* AddSetUpOnce(std::function<void()> set_up) {
  return ::testing::AddGlobalTestEnvironment(new SetUpOnce(std::move(set_up)));
}

}  // namespace soma::testing
