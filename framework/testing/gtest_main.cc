// The gtest main of every test executable: initialises the framework once
// (registries, resolvers) like the `soma` executable does.
#include "framework/framework.h"

#include <gtest/gtest.h>

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  soma::InitFramework();
  return RUN_ALL_TESTS();
}
