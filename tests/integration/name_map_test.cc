// task.name_map end to end (issue #25 item 2): a take whose markers are ours
// under other names is labelled and scored by label_eval, and laid out by
// fit_layout, exactly as the take under our names.
#include "framework/body/marker_layout.h"
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/io/c3d.h"
#include "framework/io/marker_labels.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "tests/integration/soma_command.h"
#include <filesystem>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;

ConfigNode Metrics(const fs::path& run_dir) {
  return ParseYaml(ReadFile(run_dir / "metrics.yaml"), "metrics.yaml");
}

/// The bundled CMU clip with every label renamed `Mk_<ours>` (same file
/// name: label_eval's corruption is seeded by the take's name), and the name
/// map back; returns the renamed take's path.
fs::path WriteRenamedTake(const fs::path& dir, fs::path* map_path) {
  C3dData c3d = ReadC3d(testing::SourceDir() / "data" / "cmu_01_01_f0-599.c3d");
  std::string yaml;
  for (std::string& label : c3d.labels) {
    const std::string ours(StripSubjectPrefix(label));
    if (ours.empty() || ours[0] == '*' || ours == "RBAC-1") continue;
    label = "Mk_" + ours;
    yaml += fmt::format("{}: {}\n", label, ours);
  }
  fs::create_directories(dir / "renamed");
  const fs::path take = dir / "renamed" / "cmu_01_01_f0-599.c3d";
  WriteC3d(take, c3d);
  *map_path = dir / "names.yaml";
  WriteFileAtomic(*map_path, yaml);
  return take;
}

TEST(NameMap, LabelEvalScoresARenamedTakeAsTheOriginal) {
  const fs::path dir = testing::CreateTestDir();
  fs::path map;
  const fs::path take = WriteRenamedTake(dir, &map);
  std::string err;
  // Without the map nothing matches a bundled model: a one-line error.
  EXPECT_NE(
      testing::RunSomaTask(
          dir, {"task.input=" + take.string(), "hydra.run.dir=without"}, &err),
      0);
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"task.input=" + take.string(),
                                  "task.name_map=" + map.string(),
                                  "hydra.run.dir=mapped"},
                                 &err),
            0)
      << err;
  ASSERT_EQ(testing::RunSomaTask(dir, {"hydra.run.dir=original"}, &err), 0)
      << err;
  const ConfigNode mapped = Metrics(dir / "mapped");
  const ConfigNode original = Metrics(dir / "original");
  EXPECT_EQ(mapped.at("frames").AsDouble(), 600);
  EXPECT_DOUBLE_EQ(mapped.at("per_frame_acc").AsDouble(),
                   original.at("per_frame_acc").AsDouble());
  EXPECT_DOUBLE_EQ(mapped.at("tracklet_acc").AsDouble(),
                   original.at("tracklet_acc").AsDouble());
  // A target the labeller does not have: one line naming file and key.
  WriteFileAtomic(dir / "bad.yaml", ReadFile(map) + "Mk_Forehead: FOREHEAD\n");
  EXPECT_NE(
      testing::RunSomaTask(dir,
                           {"task.input=" + take.string(),
                            "task.name_map=" + (dir / "bad.yaml").string(),
                            "hydra.run.dir=bad"},
                           &err),
      0);
  EXPECT_NE(err.find("bad.yaml: Mk_Forehead: FOREHEAD is not a label of the "
                     "labeller"),
            std::string::npos)
      << err;
}

TEST(NameMap, FitLayoutWritesTheCapturesNames) {
  const fs::path dir = testing::CreateTestDir();
  fs::path map;
  const fs::path take = WriteRenamedTake(dir, &map);
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"fit_layout",
                                  take.string(),
                                  "task.name_map=" + map.string(),
                                  "hydra.run.dir=out"},
                                 &err),
            0)
      << err;
  const ConfigNode m = Metrics(dir / "out");
  EXPECT_EQ(m.at("recognised").AsDouble(), 41);
  const MarkerLayout layout =
      ReadMarkerLayout(dir / "out/cmu_01_01_f0-599_layout.json");
  EXPECT_GE(layout.FindLabel("Mk_LFHD"), 0);
  EXPECT_LT(layout.FindLabel("LFHD"), 0);
}

TEST(NameMap, LabelPicksTheModelThroughTheMap) {
  const fs::path dir = testing::CreateTestDir();
  fs::path map;
  const fs::path take = WriteRenamedTake(dir, &map);
  std::string err;
  // Without the map no bundled model names the capture's labels.
  EXPECT_NE(testing::RunSomaTask(
                dir, {"label", take.string(), "hydra.run.dir=without"}, &err),
            0);
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"label",
                                  take.string(),
                                  "task.name_map=" + map.string(),
                                  "hydra.run.dir=mapped"},
                                 &err),
            0)
      << err;
  EXPECT_NE(ReadFile(dir / "mapped/soma.log").find("bundled model 'cmu41'"),
            std::string::npos);
}

}  // namespace
}  // namespace soma
