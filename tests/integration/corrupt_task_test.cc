// End-to-end run of `soma corrupt` (REFERENCE.md 3.6) on the real HDM05 take.
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/io/c3d.h"
#include "framework/io/mocap_dataset.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "tests/integration/soma_command.h"
#include <filesystem>
#include <string>
#include <sys/wait.h>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

TEST(CorruptTask, WritesCorruptedSetsWithGroundTruth) {
  const auto dir = testing::CreateTestDir();
  const std::string take =
      (testing::SharedDataDir() / "c3d/HDM_mm_01-02_03_120.c3d").string();
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"corrupt",
                 "hydra.run.dir=out",
                 "task.files=[" + take + "]",
                 "task.settings=[OC_05_G_03_BT_50,OCE_02_G_00_BT_00]"},
                &err),
            0)
      << err;
  const fs::path out = dir / "out";
  for (const char* setting : {"OC_05_G_03_BT_50", "OCE_02_G_00_BT_00"}) {
    const fs::path stem = out / setting / "HDM_mm_01-02_03_120";
    ASSERT_TRUE(fs::exists(stem.string() + ".c3d")) << stem;
    const C3dData c3d = ReadC3d(stem.string() + ".c3d");
    DatasetReader truth(stem.string() + ".h5");
    EXPECT_EQ(truth.num_frames(), c3d.num_frames);
    EXPECT_EQ(truth.info().num_points, c3d.num_points);
    EXPECT_EQ(truth.info().num_labels(), 41);
    EXPECT_EQ(truth.info().attributes.at("setting"), setting);
    EXPECT_EQ(c3d.labels.front(), "*000");
  }
  EXPECT_EQ(
      ReadC3d(out / "OC_05_G_03_BT_50/HDM_mm_01-02_03_120.c3d").num_points,
      41 + 3 + 50);
  const std::string csv = ReadFile(out / "corrupt.csv");
  EXPECT_THAT(csv, HasSubstr("OC_05_G_03_BT_50,HDM_mm_01-02_03_120,3990,94,"));
  const ConfigNode metrics =
      ParseYaml(ReadFile(out / "metrics.yaml"), "metrics.yaml");
  EXPECT_EQ(metrics.at("sets_written").AsDouble(), 2.0);
}

TEST(CorruptTask, BadSettingNameIsAConfigError) {
  const auto dir = testing::CreateTestDir();
  std::string err;
  EXPECT_NE(
      testing::RunSomaTask(
          dir, {"corrupt", "hydra.run.dir=out", "task.settings=[OC_5]"}, &err),
      0);
  EXPECT_THAT(err, HasSubstr("Invalid corruption setting name 'OC_5'"));
}

}  // namespace
}  // namespace soma
