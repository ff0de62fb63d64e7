// model_tests: the registrations InitFramework() makes for the modules this
// executable links (body, motion, model), in its order, once before the first
// test, then the registries are frozen as after InitFramework(). A gtest
// environment added from the executable's own object file (a static library
// would drop it); the rest of the framework is not linked
// (tests/CMakeLists.txt).
#include "framework/body/body_source.h"
#include "framework/model/register.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"

#include <gtest/gtest.h>

#include <mutex>

namespace soma {
namespace {

class Registrations : public ::testing::Environment {
 public:
  void SetUp() override {
    static std::once_flag once;
    std::call_once(once, [] {
      RegisterBodySources();
      RegisterMotionSources();
      RegisterModelComponents();
      FreezeRegistries();
    });
  }
};

[[maybe_unused]] ::testing::Environment* const kRegistrations =
    ::testing::AddGlobalTestEnvironment(new Registrations);

}  // namespace
}  // namespace soma
