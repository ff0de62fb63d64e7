// The gtest main of the module test executables (soma_testing_main): no
// framework initialisation, so a module's tests link only that module and
// the modules below it. A test executable whose tests build components
// through the global registries adds the registrations of its own modules
// (tests/<module>/registrations.cc); the framework-level executables link
// soma_testing_framework_main instead (framework_main.cc).
#include <gtest/gtest.h>

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
