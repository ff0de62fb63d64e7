// Calibrated confidence end to end (issue #25 item 4): `soma calibrate` on a
// tiny model, `soma label_eval` with task.min_confidence (the label task
// nulls exactly the low-confidence assignments and writes the review list),
// the reliability and precision/coverage reports, and bad input.
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/eval/calibration.h"
#include "framework/io/mocap_dataset.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "tests/integration/soma_command.h"
#include <algorithm>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

ConfigNode Metrics(const fs::path& run_dir) {
  return ParseYaml(ReadFile(run_dir / "metrics.yaml"), "metrics.yaml");
}

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

TEST(Confidence, CalibrateThenLabelEvalWithMinConfidence) {
  const fs::path dir = testing::CreateTestDir();
  std::string err;
  // The bundled cmu41 model, copied: calibration.yaml goes beside the copy.
  CreateDirectories(dir / "model");
  fs::copy_file(testing::SourceDir() / "models/cmu41/model.pt",
                dir / "model/model.pt");
  const fs::path checkpoint = dir / "model/model.pt";

  // calibrate on the first 64 frames of the training's validation set.
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"calibrate",
                                  "hydra.run.dir=calibrate",
                                  "task.checkpoint=" + checkpoint.string(),
                                  "task.frames=64"},
                                 &err),
            0)
      << err;
  const fs::path beside = checkpoint.parent_path() / kCalibrationFileName;
  ASSERT_TRUE(fs::exists(beside));
  EXPECT_TRUE(fs::exists(dir / "calibrate" / kCalibrationFileName));
  EXPECT_TRUE(fs::exists(dir / "calibrate/reliability.png"));
  const TemperatureCalibration calibration = ReadCalibration(beside);
  EXPECT_GT(calibration.temperature, 0.5);  // a trained model: near 1
  EXPECT_LT(calibration.temperature, 2.0);
  EXPECT_EQ(calibration.frames, 64);
  EXPECT_EQ(calibration.checkpoint, "model.pt");
  EXPECT_EQ(calibration.checkpoint_fnv1a64, FileFingerprint(checkpoint));
  EXPECT_LE(calibration.nll_after, calibration.nll_before + 1e-9);
  const ConfigNode cal_metrics = Metrics(dir / "calibrate");
  EXPECT_NEAR(cal_metrics.at("temperature").AsDouble(),
              calibration.temperature,
              1e-6 * calibration.temperature);
  EXPECT_GT(cal_metrics.at("accuracy").AsDouble(), 0.8);

  // The bundled hdm05 model was trained on a layout file that is not here
  // (results/layouts/hdm05.json): its layout.json beside the checkpoint is
  // used instead.
  ASSERT_EQ(
      testing::RunSomaTask(dir,
                           {"calibrate",
                            "hydra.run.dir=calibrate_hdm05",
                            "task.model=hdm05",
                            "task.frames=16",
                            "task.output=" + (dir / "hdm05.yaml").string()},
                           &err),
      0)
      << err;
  EXPECT_GT(ReadCalibration(dir / "hdm05.yaml").temperature, 0.0);
  // label_eval on the bundled clip, first without a threshold, then with
  // the median confidence of the real labels the tiny model assigned per
  // frame (so that some become null and some stay). The calibration is found
  // beside the checkpoint and handed to both labellings.
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"label_eval",
                                  "hydra.run.dir=eval0",
                                  "task.checkpoint=" + checkpoint.string()},
                                 &err),
            0)
      << err;
  double min_confidence = 0;
  {
    const DatasetReader sidecar(dir /
                                "eval0/per_frame/cmu_01_01_f0-599_labels.h5");
    const int L = sidecar.info().num_labels();
    const std::vector<float> proposed =
        sidecar.ReadPointArray("proposed_label");
    const std::vector<float> conf =
        sidecar.ReadPointArray("proposed_confidence");
    std::vector<float> real;
    for (size_t i = 0; i < proposed.size(); ++i) {
      if (proposed[i] < L) real.push_back(conf[i]);
    }
    ASSERT_GT(real.size(), 10u);
    std::nth_element(real.begin(), real.begin() + real.size() / 2, real.end());
    min_confidence = real[real.size() / 2];
  }
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"label_eval",
                 "hydra.run.dir=eval",
                 "task.checkpoint=" + checkpoint.string(),
                 fmt::format("task.min_confidence={}", min_confidence)},
                &err),
            0)
      << err;
  const ConfigNode metrics = Metrics(dir / "eval");
  EXPECT_NEAR(metrics.at("temperature").AsDouble(),
              calibration.temperature,
              1e-6 * calibration.temperature);
  for (const char* mode : {"per_frame", "tracklet"}) {
    const fs::path run = dir / "eval" / mode;
    for (const char* file : {"reliability.csv",
                             "reliability.png",
                             "precision_coverage.csv",
                             "precision_coverage.png",
                             "cmu_01_01_f0-599_review.csv"}) {
      EXPECT_TRUE(fs::exists(run / file)) << run / file;
    }
    const double ece = metrics.at(std::string(mode) + "_ece").AsDouble();
    EXPECT_GE(ece, 0.0);
    EXPECT_LE(ece, 1.0);
    const double coverage =
        metrics.at(std::string(mode) + "_coverage_at_precision").AsDouble();
    EXPECT_GE(coverage, 0.0);
    EXPECT_LE(coverage, 1.0);
    // 15 bins per diagram, before and after.
    EXPECT_EQ(Lines(ReadFile(run / "reliability.csv")).size(), 1u + 2 * 15);

    // Exactly the assignments below the threshold became null.
    const DatasetReader sidecar(run / "cmu_01_01_f0-599_labels.h5");
    const int L = sidecar.info().num_labels();
    const int P = sidecar.info().num_points;
    LabeledFrames frames;
    sidecar.Read(0, sidecar.num_frames(), &frames);
    const std::vector<float> proposed =
        sidecar.ReadPointArray("proposed_label");
    const std::vector<float> conf =
        sidecar.ReadPointArray("proposed_confidence");
    const std::vector<float> raw =
        sidecar.ReadPointArray("uncalibrated_confidence");
    const std::vector<float> column = sidecar.ReadPointArray("column");
    int nulled = 0, kept = 0;
    for (int64_t t = 0; t < sidecar.num_frames(); ++t) {
      for (int p = 0; p < P; ++p) {
        const size_t i = static_cast<size_t>(t) * P + p;
        if (column[i] < 0) continue;
        const int label = frames.frame_labels(t)[p];
        const int before = static_cast<int>(proposed[i]);
        EXPECT_GE(raw[i], 0.0f);
        if (before < L && conf[i] < min_confidence) {
          EXPECT_EQ(label, L) << "frame " << t << " point " << p;
          ++nulled;
        } else {
          EXPECT_EQ(label, before) << "frame " << t << " point " << p;
          kept += before < L;
        }
      }
    }
    EXPECT_GT(kept, 0);
    // The review list covers the nulled assignments (one row per run).
    const std::vector<std::string> review =
        Lines(ReadFile(run / "cmu_01_01_f0-599_review.csv"));
    ASSERT_FALSE(review.empty());
    EXPECT_EQ(review[0],
              "label,first_frame,last_frame,frames,low_frames,min_confidence");
    EXPECT_EQ(nulled > 0, review.size() > 1);
    EXPECT_LE(static_cast<int>(review.size()) - 1, nulled);
  }
  EXPECT_THAT(ReadFile(dir / "eval/summary.md"), HasSubstr("## Confidence"));

  // Bad input: one line naming the key.
  for (const char* task : {"label", "label_eval"}) {
    EXPECT_NE(
        testing::RunSomaTask(
            dir,
            {task,
             std::string("hydra.run.dir=bad_") + task,
             "task.input=" +
                 (testing::SourceDir() / "data/cmu_01_01_f0-599.c3d").string(),
             "task.checkpoint=" + checkpoint.string(),
             "task.min_confidence=1.5"},
            &err),
        0);
    EXPECT_THAT(err, HasSubstr("task.min_confidence = 1.5"));
    EXPECT_THAT(err, HasSubstr("0 <= min_confidence <= 1"));
  }
  // A calibration file that does not exist, given by path, is an error.
  EXPECT_NE(
      testing::RunSomaTask(
          dir,
          {"label",
           "hydra.run.dir=bad_calibration",
           "task.input=" +
               (testing::SourceDir() / "data/cmu_01_01_f0-599.c3d").string(),
           "task.checkpoint=" + checkpoint.string(),
           "task.calibration=" + (dir / "nope.yaml").string()},
          &err),
      0);
  EXPECT_THAT(err, HasSubstr("task.calibration="));
}

}  // namespace
}  // namespace soma
