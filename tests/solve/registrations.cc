// solve_tests: the registrations InitFramework() makes for the modules this
// executable links (body, motion, solve), in its order, once before the first
// test, then the registries are frozen as after InitFramework(). A gtest
// environment added from the executable's own object file (a static library
// would drop it); the rest of the framework is not linked
// (tests/CMakeLists.txt).
#include "framework/body/body_source.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"
#include "framework/solve/pose_prior.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

namespace soma {
namespace {

[[maybe_unused]] ::testing::Environment* const kRegistrations =
    testing::AddSetUpOnce([] {
      RegisterBodySources();
      RegisterMotionSources();
      RegisterPosePriors();
      FreezeRegistries();
    });

}  // namespace
}  // namespace soma
