// The resource root (configs/, models/, data/) found from the executable's
// own location or $SOMA_HOME, never through a compiled-in source path.
#include "framework/core/resources.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>

namespace soma {
namespace {

namespace fs = std::filesystem;

/// Sets (or unsets) SOMA_HOME for the scope of one test.
class ScopedSomaHome {
 public:
  explicit ScopedSomaHome(const std::optional<std::string>& value) {
    if (const char* old = std::getenv("SOMA_HOME")) old_ = old;
    if (value) {
      setenv("SOMA_HOME", value->c_str(), 1);
    } else {
      unsetenv("SOMA_HOME");
    }
  }
  ~ScopedSomaHome() {
    if (old_) {
      setenv("SOMA_HOME", old_->c_str(), 1);
    } else {
      unsetenv("SOMA_HOME");
    }
  }

 private:
  std::optional<std::string> old_;
};

TEST(Resources, CandidatesGoUpFromTheExecutable) {
  const auto c = ResourceRootCandidates("/opt/p/bin/soma");
  ASSERT_GE(c.size(), 4u);
  EXPECT_EQ(c[0], fs::path("/opt/p/bin/share/somalab"));
  EXPECT_EQ(c[1], fs::path("/opt/p/bin"));
  EXPECT_EQ(c[2], fs::path("/opt/p/share/somalab"));  // an installed prefix
  EXPECT_EQ(c[3], fs::path("/opt/p"));                // a source checkout
  EXPECT_TRUE(ResourceRootCandidates("").empty());
}

TEST(Resources, SomaHomeWinsWhenItHoldsConfigs) {
  const fs::path dir = testing::CreateTestDir();
  fs::create_directories(dir / "configs");
  ScopedSomaHome home(dir.string());
  EXPECT_EQ(FindResourceRoot(), fs::absolute(dir).lexically_normal());
  EXPECT_EQ(ResourcePath("models"),
            fs::absolute(dir).lexically_normal() / "models");
}

TEST(Resources, SomaHomeWithoutConfigsIsAClearError) {
  const fs::path dir = testing::CreateTestDir();
  ScopedSomaHome home(dir.string());
  try {
    FindResourceRoot();
    FAIL() << "expected IoError";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("SOMA_HOME=" + dir.string()),
              std::string::npos)
        << e.what();
  }
}

TEST(Resources, TheTestBinaryFindsItsResources) {
  // build/tests/core_tests -> build/share/somalab, which the build tree links
  // to the checkout's configs/, models/, data/ and ablations/.
  ScopedSomaHome home(std::nullopt);
  const fs::path root = FindResourceRoot();
  EXPECT_TRUE(fs::is_regular_file(root / "configs" / "config.yaml")) << root;
  EXPECT_TRUE(fs::is_directory(root / "models")) << root;
}

}  // namespace
}  // namespace soma
