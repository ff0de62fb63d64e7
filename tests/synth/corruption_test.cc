#include "framework/synth/corruption.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/io/c3d.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <set>

namespace soma {
namespace {

using ::testing::HasSubstr;

const LabeledSequence& Hdm05() {
  static const LabeledSequence sequence =
      ReadLabeledC3d(testing::SharedDataDir() / "c3d/HDM_mm_01-02_03_120.c3d",
                     BuiltinLayoutLabels("cmu41"));
  return sequence;
}

bool IsZero(const float* xyz) {
  return xyz[0] == 0.0f && xyz[1] == 0.0f && xyz[2] == 0.0f;
}

/// Non-null labels of frame t.
int CountLabelled(const LabeledSequence& s, int64_t t) {
  int count = 0;
  for (int k = 0; k < s.num_columns(); ++k) {
    count += s.frames.frame_labels(t)[k] != s.null_label();
  }
  return count;
}

/// The invariants every corrupted sequence has: each ground-truth label at
/// most once per frame; zero points are null; a labelled point is exactly
/// the clean point of that label.
void ExpectConsistentWithClean(const LabeledSequence& clean,
                               const LabeledSequence& out) {
  ASSERT_EQ(out.num_frames(), clean.num_frames());
  ASSERT_EQ(out.label_names, clean.label_names);
  std::vector<int> column_of_label(clean.label_names.size(), -1);
  for (int k = 0; k < clean.num_columns(); ++k) {
    const auto it = std::find(clean.label_names.begin(),
                              clean.label_names.end(),
                              clean.column_names[k]);
    column_of_label[it - clean.label_names.begin()] = k;
  }
  int failures = 0;
  for (int64_t t = 0; t < out.num_frames() && failures < 5; ++t) {
    std::set<int> seen;
    for (int k = 0; k < out.num_columns(); ++k) {
      const float* xyz = out.frames.frame_points(t) + 3 * k;
      const int label = out.frames.frame_labels(t)[k];
      if (IsZero(xyz) && label != out.null_label()) {
        ADD_FAILURE() << "zero point labelled " << label << " at " << t;
        ++failures;
      }
      if (label == out.null_label()) continue;
      if (!seen.insert(label).second) {
        ADD_FAILURE() << "label " << label << " twice in frame " << t;
        ++failures;
      }
      const float* expected =
          clean.frames.frame_points(t) + 3 * column_of_label[label];
      if (!std::equal(xyz, xyz + 3, expected)) {
        ADD_FAILURE() << "label " << label << " moved at frame " << t;
        ++failures;
      }
    }
  }
}

TEST(Corruption, SettingNames) {
  EXPECT_EQ(CorruptionSettingName({5, false, 3, 0}), "OC_05_G_03_BT_00");
  EXPECT_EQ(CorruptionSettingName({5, true, 0, 50}), "OCE_05_G_00_BT_50");
  EXPECT_EQ(CorruptionSettingName({0, false, 60, 100}), "OC_00_G_60_BT_100");
  for (const CorruptionSetting& s : std::vector<CorruptionSetting>{
           {5, false, 3, 0}, {1, true, 0, 0}, {0, false, 60, 100}}) {
    EXPECT_EQ(ParseCorruptionSettingName(CorruptionSettingName(s)), s);
  }
  EXPECT_THAT(testing::ErrorMessage<ConfigError>(
                  [] { ParseCorruptionSettingName("OC_5_G_3"); }),
              HasSubstr("expected OC_xx_G_xx_BT_xx"));
}

TEST(Corruption, ReadsHdm05RestrictedToTheLayout) {
  const LabeledSequence& s = Hdm05();
  EXPECT_EQ(s.num_frames(), 3990);
  EXPECT_EQ(s.frame_rate, 120.0);
  EXPECT_EQ(s.num_columns(), 41);  // the 3 `*` copies are dropped
  EXPECT_EQ(s.label_names, BuiltinLayoutLabels("cmu41"));
  EXPECT_EQ(s.column_names, BuiltinLayoutLabels("cmu41"));
  // Metres, and label id = column where present.
  float max_abs = 0.0f;
  for (int64_t t = 0; t < s.num_frames(); t += 10) {
    for (int k = 0; k < s.num_columns(); ++k) {
      const float* xyz = s.frames.frame_points(t) + 3 * k;
      for (int a = 0; a < 3; ++a) max_abs = std::max(max_abs, std::abs(xyz[a]));
      EXPECT_EQ(s.frames.frame_labels(t)[k], IsZero(xyz) ? s.null_label() : k);
    }
  }
  EXPECT_GT(max_abs, 0.5f);
  EXPECT_LT(max_abs, 10.0f);
  EXPECT_THROW(ReadLabeledC3d(testing::SharedDataDir() / "c3d/nope.c3d",
                              BuiltinLayoutLabels("cmu41")),
               IoError);
  EXPECT_THAT(testing::ErrorMessage<IoError>([] {
                ReadLabeledC3d(
                    testing::SharedDataDir() / "c3d/phasespace_sample.c3d",
                    BuiltinLayoutLabels("cmu41"));
              }),
              HasSubstr("none of its 40 point labels is in the layout"));
}

TEST(Corruption, NoCorruptionKeepsEveryPoint) {
  const LabeledSequence& clean = Hdm05();
  CorruptionSummary summary;
  const LabeledSequence out =
      CorruptSequence(clean, {0, false, 0, 0}, 100, &summary);
  EXPECT_EQ(out.num_columns(), clean.num_columns());
  EXPECT_EQ(out.column_names.front(), "*000");
  EXPECT_EQ(out.column_names.back(), "*040");
  ExpectConsistentWithClean(clean, out);
  for (int64_t t = 0; t < clean.num_frames(); ++t) {
    ASSERT_EQ(CountLabelled(out, t), CountLabelled(clean, t));
  }
  EXPECT_EQ(summary.missing_before, summary.missing_after);
  // A permutation happened (same for all frames).
  EXPECT_NE(
      out.frames.frame_labels(0)[0] * 1000 + out.frames.frame_labels(0)[1],
      0 * 1000 + 1);
}

TEST(Corruption, UpToOcclusionsPerFrame) {
  const LabeledSequence& clean = Hdm05();
  const LabeledSequence out = CorruptSequence(clean, {5, false, 0, 0}, 7);
  ASSERT_EQ(out.num_columns(), clean.num_columns());
  ExpectConsistentWithClean(clean, out);
  std::vector<int> histogram(6, 0);
  int64_t full_frames = 0;
  for (int64_t t = 0; t < clean.num_frames(); ++t) {
    const int drop = CountLabelled(clean, t) - CountLabelled(out, t);
    ASSERT_GE(drop, 0);
    ASSERT_LE(drop, 4) << "k ~ U{0..OC-1}: at most 4 at frame " << t;
    if (CountLabelled(clean, t) == clean.num_columns()) {
      ++histogram[drop];  // no occluded column was missing already
      ++full_frames;
    }
  }
  ASSERT_GT(full_frames, 1000);
  // Each k in 0..4 has probability 1/5.
  for (int k = 0; k <= 4; ++k) {
    EXPECT_NEAR(histogram[k] / static_cast<double>(full_frames), 0.2, 0.04)
        << k;
  }
  EXPECT_EQ(histogram[5], 0);
}

TEST(Corruption, ExactOcclusions) {
  const LabeledSequence& clean = Hdm05();
  const LabeledSequence out = CorruptSequence(clean, {5, true, 0, 0}, 7);
  ExpectConsistentWithClean(clean, out);
  for (int64_t t = 0; t < clean.num_frames(); ++t) {
    const int drop = CountLabelled(clean, t) - CountLabelled(out, t);
    ASSERT_LE(drop, 5);
    if (CountLabelled(clean, t) == clean.num_columns()) {
      ASSERT_EQ(drop, 5);
    }
  }
}

TEST(Corruption, GhostsAroundTheMedian) {
  const LabeledSequence& clean = Hdm05();
  const int g = 3;
  const LabeledSequence out = CorruptSequence(clean, {0, false, g, 0}, 11);
  ASSERT_EQ(out.num_columns(), clean.num_columns() + g);
  ExpectConsistentWithClean(clean, out);
  int64_t ghosts = 0;
  double offset[3] = {0, 0, 0};
  for (int64_t t = 0; t < out.num_frames(); ++t) {
    int in_frame = 0;
    std::vector<float> values[3];
    for (int k = 0; k < clean.num_columns(); ++k) {
      for (int a = 0; a < 3; ++a) {
        values[a].push_back(clean.frames.frame_points(t)[3 * k + a]);
      }
    }
    float median[3];
    for (int a = 0; a < 3; ++a) {
      std::sort(values[a].begin(), values[a].end());
      median[a] = values[a][(values[a].size() - 1) / 2];
    }
    for (int k = 0; k < out.num_columns(); ++k) {
      const float* xyz = out.frames.frame_points(t) + 3 * k;
      if (IsZero(xyz) || out.frames.frame_labels(t)[k] != out.null_label())
        continue;
      ++in_frame;
      for (int a = 0; a < 3; ++a) offset[a] += xyz[a] - median[a];
    }
    ASSERT_LE(in_frame, g) << t;
    ghosts += in_frame;
  }
  // Up-to rejection keeps a ghost with probability (1 - 1/(3G))^G.
  const double expected = g * std::pow(1.0 - 1.0 / (3.0 * g), g);
  EXPECT_NEAR(ghosts / static_cast<double>(out.num_frames()), expected, 0.1);
  for (double o : offset) EXPECT_LT(std::abs(o / ghosts), 0.05) << o / ghosts;
}

TEST(Corruption, BrokenTrajectoriesAddColumns) {
  const LabeledSequence& clean = Hdm05();
  CorruptionSummary summary;
  const LabeledSequence out =
      CorruptSequence(clean, {5, false, 3, 50}, 100, &summary);
  EXPECT_EQ(summary.cuts, 50);
  ASSERT_EQ(out.num_columns(), clean.num_columns() + 3 + 50);
  EXPECT_EQ(out.column_names.back(), "*093");
  ExpectConsistentWithClean(clean, out);
  // Every appended column is empty before its cut and starts labelled.
  for (int k = clean.num_columns() + 3; k < out.num_columns(); ++k) {
    int64_t first = 0;
    while (first < out.num_frames() &&
           IsZero(out.frames.frame_points(first) + 3 * k)) {
      ++first;
    }
    EXPECT_GE(first, 2) << k;
    EXPECT_LE(first, out.num_frames() - 2) << k;
  }
}

TEST(Corruption, DeterministicPerSeed) {
  const LabeledSequence& clean = Hdm05();
  const CorruptionSetting setting{5, false, 3, 50};
  const LabeledSequence a = CorruptSequence(clean, setting, 100);
  const LabeledSequence b = CorruptSequence(clean, setting, 100);
  const LabeledSequence c = CorruptSequence(clean, setting, 101);
  EXPECT_EQ(a.frames.points, b.frames.points);
  EXPECT_EQ(a.frames.labels, b.frames.labels);
  EXPECT_NE(a.frames.labels, c.frames.labels);
}

TEST(Corruption, MatchesItsGoldenHash) {
  // Pinned across builds: the HDM05 take corrupted with OC 5, G 3, BT 50
  // from seed 100 hashes to the value below (FNV-1a over the points' and
  // labels' bytes). A change of the protocol, the ghost sampling or the
  // order of RNG draws shows here; update the value only on purpose.
  const LabeledSequence out = CorruptSequence(Hdm05(), {5, false, 3, 50}, 100);
  const std::string_view points(
      reinterpret_cast<const char*>(out.frames.points.data()),
      sizeof(float) * out.frames.points.size());
  const std::string_view labels(
      reinterpret_cast<const char*>(out.frames.labels.data()),
      sizeof(int16_t) * out.frames.labels.size());
  EXPECT_EQ(Fnv1a64(labels, Fnv1a64(points)), 8740788725824444723u);
}

TEST(Corruption, ShortSequencesAreSkipped) {
  LabeledSequence short_take = Hdm05();
  short_take.frames.Resize(10, short_take.num_columns());
  EXPECT_EQ(CorruptionSkipReason(short_take, {5, false, 3, 0}), "");
  const std::string reason = CorruptionSkipReason(short_take, {5, false, 3, 5});
  EXPECT_THAT(reason, HasSubstr("10 frames < 3 x BT = 15 frames"));
  EXPECT_THAT(reason, HasSubstr("OC_05_G_03_BT_05"));
  EXPECT_THROW(CorruptSequence(short_take, {5, false, 3, 5}, 1), ShapeError);
  EXPECT_THAT(CorruptionSkipReason(short_take, {50, true, 0, 0}),
              HasSubstr("50 occlusions requested but the take has 41"));
}

TEST(Corruption, WritesC3dAndGroundTruth) {
  const auto dir = testing::CreateTestDir();
  LabeledSequence clean = Hdm05();
  clean.frames.Resize(300, clean.num_columns());
  const LabeledSequence out = CorruptSequence(clean, {5, false, 3, 20}, 100);
  WriteCorruptedSequence(out, dir / "take", "OC_05_G_03_BT_20", 100);

  const C3dData c3d = ReadC3d(dir / "take.c3d");
  ASSERT_EQ(c3d.num_points, out.num_columns());
  ASSERT_EQ(c3d.num_frames, 300);
  EXPECT_EQ(c3d.labels, out.column_names);
  EXPECT_EQ(c3d.frame_rate, 120.0);
  for (int t = 0; t < 300; t += 7) {
    for (int k = 0; k < out.num_columns(); ++k) {
      const float* xyz = out.frames.frame_points(t) + 3 * k;
      ASSERT_EQ(c3d.valid(t, k), !IsZero(xyz));
      if (!c3d.valid(t, k)) continue;
      const Eigen::Vector3f p = c3d.Point(t, k) * c3d.MetresPerUnit();
      EXPECT_NEAR(p.x(), xyz[0], 1e-6);
      EXPECT_NEAR(p.z(), xyz[2], 1e-6);
    }
  }

  DatasetReader truth(dir / "take.h5");
  EXPECT_EQ(truth.info().labels, BuiltinLayoutLabels("cmu41"));
  EXPECT_EQ(truth.info().attributes.at("setting"), "OC_05_G_03_BT_20");
  EXPECT_EQ(truth.info().attributes.at("source"), "HDM_mm_01-02_03_120");
  LabeledFrames frames;
  truth.Read(0, 300, &frames);
  EXPECT_EQ(frames.labels, out.frames.labels);
  EXPECT_EQ(frames.points, out.frames.points);
}

}  // namespace
}  // namespace soma
