#include "framework/core/error.h"

#include <gtest/gtest.h>

#include <string>

namespace soma {
namespace {

TEST(SomaCheck, PassingCheckDoesNothing) {
  EXPECT_NO_THROW({ SOMA_CHECK(1 + 1 == 2) << "never shown"; });
}

TEST(SomaCheck, FailingCheckThrowsWithFileLineAndMessage) {
  try {
    const int x = 3;
    SOMA_CHECK_LT(x, 2) << "x must be small";
    FAIL() << "expected InternalError";
  } catch (const InternalError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("error_test.cc:"), std::string::npos) << what;
    EXPECT_NE(what.find("Check failed: (x) < (2)"), std::string::npos) << what;
    EXPECT_NE(what.find("3 vs 2"), std::string::npos) << what;
    EXPECT_NE(what.find("x must be small"), std::string::npos) << what;
  }
}

TEST(SomaCheck, TypedCheckThrowsTheGivenType) {
  EXPECT_THROW({ SOMA_CHECK_T(IoError, false) << "bad file"; }, IoError);
}

TEST(ErrorHierarchy, AllDeriveFromError) {
  EXPECT_THROW(throw ConfigError("x"), Error);
  EXPECT_THROW(throw MissingMandatoryValue("x"), ConfigError);
  EXPECT_THROW(throw ShapeError("x"), Error);
  EXPECT_THROW(throw IoError("x"), Error);
}

}  // namespace
}  // namespace soma
