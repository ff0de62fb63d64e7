#include "framework/io/hdf5_util.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <mutex>
#include <string>
#include <vector>

namespace soma::hdf5 {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

/// The IoError message of `f()`, or "" if it does not throw one.
template <typename F>
std::string IoErrorOf(F f) {
  try {
    f();
  } catch (const IoError& error) {
    return error.what();
  }
  return "";
}

TEST(Hdf5Util, AttributesRoundTrip) {
  const std::string file = (testing::CreateTestDir() / "attrs.h5").string();
  std::lock_guard lock(Hdf5Mutex());
  {
    const Hid h5 =
        Check(H5Fcreate(file.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT),
              H5Fclose,
              "create");
    WriteStringAttribute(h5.get(), "name", "first", file);
    WriteStringAttribute(h5.get(), "name", "überschrieben", file);  // replaces
    WriteStringArrayAttribute(h5.get(), "labels", {"a", "", "ccc"}, file);
    WriteStringArrayAttribute(h5.get(), "none", {}, file);
    WriteNumberAttribute<int32_t>(h5.get(), "i32", -7, file);
    WriteNumberAttribute<int64_t>(h5.get(), "i64", int64_t{1} << 40, file);
    WriteNumberAttribute<uint64_t>(h5.get(), "u64", ~uint64_t{0}, file);
    WriteNumberAttribute<double>(h5.get(), "f64", 0.25, file);
  }
  const Hid h5 = Check(
      H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose, "open");
  const std::string bad = InvalidFilePrefix(file, "test file");
  EXPECT_EQ(ReadStringAttribute(h5.get(), "name", bad), "überschrieben");
  EXPECT_THAT(ReadStringArrayAttribute(h5.get(), "labels", bad),
              ElementsAre("a", "", "ccc"));
  EXPECT_TRUE(ReadStringArrayAttribute(h5.get(), "none", bad).empty());
  EXPECT_THAT(ReadStringArrayAttribute(h5.get(), "name", bad),
              ElementsAre("überschrieben"));
  EXPECT_EQ(ReadNumberAttribute<int32_t>(h5.get(), "i32", bad), -7);
  EXPECT_EQ(ReadNumberAttribute<int64_t>(h5.get(), "i64", bad),
            int64_t{1} << 40);
  EXPECT_EQ(ReadNumberAttribute<uint64_t>(h5.get(), "u64", bad), ~uint64_t{0});
  EXPECT_EQ(ReadNumberAttribute<double>(h5.get(), "f64", bad), 0.25);
  EXPECT_EQ(ReadNumberAttribute<int64_t>(h5.get(), "i32", bad), -7);

  // Errors name the file and the attribute.
  EXPECT_EQ(IoErrorOf([&] { ReadStringAttribute(h5.get(), "nope", bad); }),
            file + ": not a valid test file: missing attribute 'nope'");
  EXPECT_THAT(IoErrorOf([&] { ReadStringAttribute(h5.get(), "i32", bad); }),
              HasSubstr("attribute 'i32' is not a string"));
  EXPECT_THAT(IoErrorOf([&] { ReadStringAttribute(h5.get(), "labels", bad); }),
              HasSubstr("attribute 'labels' is not a single string"));
  EXPECT_THAT(
      IoErrorOf([&] { ReadNumberAttribute<int32_t>(h5.get(), "name", bad); }),
      HasSubstr(file + ": not a valid test file: attribute 'name' is not a "
                       "number"));
  // Writing into a read-only file fails with the file and attribute named.
  EXPECT_EQ(IoErrorOf([&] { WriteStringAttribute(h5.get(), "x", "y", file); }),
            file + ": cannot create attribute 'x'");
}

TEST(Hdf5Util, CheckThrowsIoError) {
  std::lock_guard lock(Hdf5Mutex());
  EXPECT_THROW(Check(H5I_INVALID_HID, H5Fclose, "what"), IoError);
  EXPECT_THROW(CheckStatus(-1, "what"), IoError);
  EXPECT_NO_THROW(CheckStatus(0, "what"));
  Hid type = VlenStringType();
  EXPECT_TRUE(type.valid());
  Hid moved = std::move(type);
  EXPECT_FALSE(type.valid());  // NOLINT(bugprone-use-after-move)
  EXPECT_TRUE(moved.Reset());
  EXPECT_FALSE(moved.valid());
}

}  // namespace
}  // namespace soma::hdf5
