// The gtest main of the framework-level test executables
// (soma_testing_framework_main: integration_tests): initialises the framework
// once (registries, resolvers) like the `soma` executable does.
#include "framework/framework.h"

#include <gtest/gtest.h>

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  soma::InitFramework();
  return RUN_ALL_TESTS();
}
