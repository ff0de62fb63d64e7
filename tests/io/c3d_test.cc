#include "framework/io/c3d.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <set>
#include <string>
#include <vector>

namespace soma {
namespace {

using ::testing::HasSubstr;

std::filesystem::path C3dDir() { return testing::SharedDataDir() / "c3d"; }

std::vector<uint8_t> FileBytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

// ---------------------------------------------------------------------------
// Independent decoders (deliberately written differently from c3d.cc) used to
// verify sample coordinates straight from the file bytes.

float RawIntelFloat(const std::vector<uint8_t>& b, size_t offset) {
  float value;
  std::memcpy(&value, b.data() + offset, 4);
  return value;
}

float RawMipsFloat(const std::vector<uint8_t>& b, size_t offset) {
  const uint8_t swapped[4] = {
      b[offset + 3], b[offset + 2], b[offset + 1], b[offset]};
  float value;
  std::memcpy(&value, swapped, 4);
  return value;
}

// VAX F-float: value = (0.5 + fraction / 2^24) * 2^(exponent - 128).
float RawDecFloat(const std::vector<uint8_t>& b, size_t offset) {
  const unsigned word0 = b[offset] | (b[offset + 1] << 8);
  const unsigned word1 = b[offset + 2] | (b[offset + 3] << 8);
  const int sign = (word0 & 0x8000) ? -1 : 1;
  const int exponent = static_cast<int>((word0 >> 7) & 0xff);
  if (exponent == 0) return 0.0f;
  const double fraction = ((word0 & 0x7f) << 16 | word1) / 16777216.0;
  return static_cast<float>(sign * std::ldexp(0.5 + fraction, exponent - 128));
}

int16_t RawLeInt16(const std::vector<uint8_t>& b, size_t offset) {
  return static_cast<int16_t>(b[offset] | (b[offset + 1] << 8));
}

// ---------------------------------------------------------------------------
// Every shared file, with the facts verified for it.

struct FileFacts {
  std::string name;
  C3dProcessor processor;
  bool float_data;
  int num_frames;
  int64_t first_frame;
  int num_points;
  double frame_rate;
  int num_file_labels;
  int analog_channels;
  int analog_samples_per_frame;
  std::vector<std::pair<int, std::string>> some_labels;
};

const std::vector<FileFacts>& AllFileFacts() {
  static const std::vector<FileFacts> facts = {
      {"Eb015pi.c3d",
       C3dProcessor::kIntel,
       false,
       450,
       1,
       26,
       50.0,
       26,
       16,
       4,
       {{0, "RFT1"}, {22, "PV1"}, {25, "pv4"}}},
      {"Eb015sr.c3d",
       C3dProcessor::kMips,
       true,
       450,
       1,
       26,
       50.0,
       26,
       16,
       4,
       {{0, "RFT1"}, {25, "pv4"}}},
      {"Eb015vr.c3d",
       C3dProcessor::kDec,
       true,
       450,
       1,
       26,
       50.0,
       26,
       16,
       4,
       {{0, "RFT1"}, {25, "pv4"}}},
      {"Gait.c3d",
       C3dProcessor::kDec,
       false,
       487,
       1,
       33,
       100.0,
       33,
       28,
       10,
       {{0, "RSHO"}, {7, "RASI"}, {30, "C7"}, {32, "PX"}}},
      {"HDM_mm_01-02_03_120.c3d",
       C3dProcessor::kIntel,
       true,
       3990,
       1,
       44,
       120.0,
       44,
       0,
       0,
       {{0, "*0"}, {3, "meinard:LFHD"}, {43, "meinard:RMT5"}}},
      {"Movement_trial.c3d",
       C3dProcessor::kIntel,
       true,
       323,
       695,
       239,
       120.0,
       239,
       69,
       9,
       {{0, "LBHD"},
        {115, "*115"},
        {157, "LHipAngles"},
        {238, "CentreOfMassFloor"}}},
      // Declares 1149 frames; 29 are present (read with allow_truncated).
      {"Optotrak_truncated.c3d",
       C3dProcessor::kIntel,
       true,
       29,
       1,
       54,
       30.0,
       54,
       0,
       0,
       {{0, "Marker_1"}, {53, "Marker_54"}}},
      {"PiG_Calibration-FlatFoot-Full.c3d",
       C3dProcessor::kIntel,
       true,
       94,
       30,
       137,
       100.0,
       137,
       38,
       10,
       {{0, "LFHD"}, {136, "RFootProgressAngles"}}},
      {"PiG_Motion-FlatFoot-Hole.c3d",
       C3dProcessor::kIntel,
       true,
       320,
       143,
       193,
       100.0,
       193,
       38,
       10,
       {{0, "LFHD"}, {35, "CentreOfMass"}, {192, "RWristMoment"}}},
      {"Res16bits.c3d",
       C3dProcessor::kIntel,
       true,
       100,
       1,
       44,
       100.0,
       44,
       81,
       10,
       {{0, "RTET"}, {1, "LTET"}, {43, "LHAL"}}},
      {"cmu_01_01.c3d",
       C3dProcessor::kIntel,
       true,
       2751,
       40,
       42,
       120.0,
       42,
       0,
       0,
       {{0, "LBWT"}, {22, "LFHD"}, {41, "RBAC-1"}}},
      {"mocap36.c3d",
       C3dProcessor::kIntel,
       true,
       1380,
       1,
       36,
       100.0,
       36,
       0,
       0,
       {{0, "Skeleton_Hip2"}, {35, "Skeleton_RFoot2"}}},
      // Empty parameter section: labels synthesized as *0..*39.
      {"phasespace_sample.c3d",
       C3dProcessor::kIntel,
       true,
       701,
       1,
       40,
       30.0,
       0,
       0,
       0,
       {{0, "*0"}, {39, "*39"}}},
      {"shd01.c3d",
       C3dProcessor::kIntel,
       true,
       237,
       91,
       27,
       250.0,
       27,
       6,
       4,
       {{0, "AbcdeFghijk:RASI"}, {26, "AbcdeFghijk:LFIN"}}},
      {"vicon_nexus_markers_analogs.c3d",
       C3dProcessor::kIntel,
       true,
       580,
       1,
       51,
       100.0,
       51,
       38,
       20,
       {{0, "boite:gauche_ext"}, {8, "Daphnee:ASISr"}, {50, "Daphnee:LATH"}}},
  };
  return facts;
}

TEST(C3dReader, EverySharedFileIsCoveredByTheTable) {
  std::set<std::string> on_disk;
  for (const auto& entry : std::filesystem::directory_iterator(C3dDir())) {
    if (entry.path().extension() == ".c3d") {
      on_disk.insert(entry.path().filename().string());
    }
  }
  std::set<std::string> in_table;
  for (const FileFacts& f : AllFileFacts()) in_table.insert(f.name);
  EXPECT_EQ(on_disk, in_table);
}

TEST(C3dReader, ReadsEverySharedFileWithVerifiedFacts) {
  for (const FileFacts& facts : AllFileFacts()) {
    SCOPED_TRACE(facts.name);
    C3dReadOptions options;
    options.allow_truncated = true;
    const C3dData d = ReadC3d(C3dDir() / facts.name, options);
    EXPECT_EQ(d.processor, facts.processor);
    EXPECT_EQ(d.point_scale < 0.0f, facts.float_data);
    EXPECT_EQ(d.num_frames, facts.num_frames);
    EXPECT_EQ(d.first_frame, facts.first_frame);
    EXPECT_EQ(d.num_points, facts.num_points);
    EXPECT_DOUBLE_EQ(d.frame_rate, facts.frame_rate);
    EXPECT_EQ(d.num_file_labels, facts.num_file_labels);
    EXPECT_EQ(d.analog.num_channels, facts.analog_channels);
    EXPECT_EQ(d.analog.samples_per_frame, facts.analog_samples_per_frame);
    ASSERT_EQ(d.labels.size(), static_cast<size_t>(facts.num_points));
    ASSERT_EQ(d.descriptions.size(), static_cast<size_t>(facts.num_points));
    for (const auto& [index, label] : facts.some_labels) {
      EXPECT_EQ(d.labels[index], label) << "point " << index;
    }
    // Units: every file with a parameter section says mm.
    EXPECT_EQ(d.units, facts.num_file_labels > 0 ? "mm" : "");
    EXPECT_DOUBLE_EQ(d.MetresPerUnit(), 0.001);
    // Shapes and the validity contract.
    ASSERT_EQ(d.points.rows(), facts.num_frames);
    ASSERT_EQ(d.points.cols(), 3 * facts.num_points);
    ASSERT_EQ(d.residuals.rows(), facts.num_frames);
    ASSERT_EQ(d.residuals.cols(), facts.num_points);
    ASSERT_EQ(d.valid.rows(), facts.num_frames);
    ASSERT_EQ(d.valid.cols(), facts.num_points);
    for (int f = 0; f < d.num_frames; ++f) {
      for (int p = 0; p < d.num_points; ++p) {
        const Eigen::Vector3f x = d.Point(f, p);
        if (d.valid(f, p)) {
          ASSERT_TRUE(x.allFinite());
          ASSERT_GE(d.residuals(f, p), 0.0f);
        } else {
          ASSERT_TRUE(x.array().isNaN().all());
          ASSERT_EQ(d.residuals(f, p), -1.0f);
        }
      }
    }
  }
}

TEST(C3dReader, ValidityCountsPerFile) {
  // Counts of valid (frame, point) pairs: these files have gaps.
  const std::map<std::string, int> expected = {
      {"Eb015pi.c3d", 11474},
      {"Gait.c3d", 6389},
      {"HDM_mm_01-02_03_120.c3d", 3990 * 44},
      {"PiG_Motion-FlatFoot-Hole.c3d", 55271},
      {"cmu_01_01.c3d", 112769},
      {"mocap36.c3d", 41436},
      {"phasespace_sample.c3d", 26759},
  };
  for (const auto& [name, count] : expected) {
    SCOPED_TRACE(name);
    const C3dData d = ReadC3d(C3dDir() / name);
    EXPECT_EQ(d.valid.count(), count);
  }
}

TEST(C3dReader, SampleCoordinatesMatchRawBytes) {
  // Intel float (HDM05): data block 10, 44 points x 16 bytes per frame.
  {
    const auto bytes = FileBytes(C3dDir() / "HDM_mm_01-02_03_120.c3d");
    const C3dData d = ReadC3d(C3dDir() / "HDM_mm_01-02_03_120.c3d");
    ASSERT_EQ(d.header.data_start_block, 10);
    for (const auto& [f, p] :
         {std::pair{0, 0}, {1, 3}, {1000, 20}, {3989, 43}}) {
      const size_t at = size_t{9} * 512 + static_cast<size_t>(f) * 44 * 16 +
                        static_cast<size_t>(p) * 16;
      for (Eigen::Index c = 0; c < 3; ++c) {
        EXPECT_EQ(d.points(f, 3 * Eigen::Index{p} + c),
                  RawIntelFloat(bytes, at + 4 * c))
            << f << "," << p << "," << c;
      }
    }
    EXPECT_FLOAT_EQ(d.points(0, 0), 142.77927f);
  }
  // Intel int16 (Eb015pi): coordinates = int16 * POINT:SCALE; frames hold
  // 26 points x 4 words + 64 analog words.
  {
    const auto bytes = FileBytes(C3dDir() / "Eb015pi.c3d");
    const C3dData d = ReadC3d(C3dDir() / "Eb015pi.c3d");
    const float scale = RawIntelFloat(bytes, 12);
    EXPECT_FLOAT_EQ(scale, 1.0f / 12.0f);
    for (const auto& [f, p] : {std::pair{0, 0}, {100, 10}, {449, 25}}) {
      const size_t at = size_t{10} * 512 + static_cast<size_t>(f) * 168 * 2 +
                        static_cast<size_t>(p) * 8;
      if (RawLeInt16(bytes, at + 6) < 0) continue;
      for (Eigen::Index c = 0; c < 3; ++c) {
        EXPECT_FLOAT_EQ(d.points(f, 3 * Eigen::Index{p} + c),
                        RawLeInt16(bytes, at + 2 * c) * scale);
      }
    }
  }
  // MIPS float (Eb015sr) and DEC float (Eb015vr): 168 words of 4 bytes.
  {
    const auto sr = FileBytes(C3dDir() / "Eb015sr.c3d");
    const auto vr = FileBytes(C3dDir() / "Eb015vr.c3d");
    const C3dData dsr = ReadC3d(C3dDir() / "Eb015sr.c3d");
    const C3dData dvr = ReadC3d(C3dDir() / "Eb015vr.c3d");
    EXPECT_FLOAT_EQ(RawMipsFloat(sr, 20), 50.0f);  // header frame rate
    EXPECT_FLOAT_EQ(RawDecFloat(vr, 20), 50.0f);
    for (const auto& [f, p] : {std::pair{0, 0}, {200, 13}, {449, 24}}) {
      const size_t at = size_t{10} * 512 + static_cast<size_t>(f) * 168 * 4 +
                        static_cast<size_t>(p) * 16;
      for (Eigen::Index c = 0; c < 3; ++c) {
        EXPECT_EQ(dsr.points(f, 3 * Eigen::Index{p} + c),
                  RawMipsFloat(sr, at + 4 * c));
        EXPECT_FLOAT_EQ(dvr.points(f, 3 * Eigen::Index{p} + c),
                        RawDecFloat(vr, at + 4 * c));
      }
    }
  }
  // DEC int16 (Gait): 33 points x 4 words + 280 analog words per frame.
  {
    const auto bytes = FileBytes(C3dDir() / "Gait.c3d");
    const C3dData d = ReadC3d(C3dDir() / "Gait.c3d");
    const float scale = RawDecFloat(bytes, 12);
    EXPECT_FLOAT_EQ(d.point_scale, scale);
    int checked = 0;
    for (int f = 0; f < d.num_frames; f += 37) {
      for (int p = 0; p < d.num_points; p += 5) {
        const size_t at = size_t{10} * 512 + static_cast<size_t>(f) * 412 * 2 +
                          static_cast<size_t>(p) * 8;
        const bool valid = RawLeInt16(bytes, at + 6) >= 0;
        ASSERT_EQ(d.valid(f, p), valid);
        if (!valid) continue;
        ++checked;
        for (Eigen::Index c = 0; c < 3; ++c) {
          EXPECT_FLOAT_EQ(d.points(f, 3 * Eigen::Index{p} + c),
                          RawLeInt16(bytes, at + 2 * c) * scale);
        }
      }
    }
    EXPECT_GT(checked, 10);
  }
}

TEST(C3dReader, ThreeEncodingsOfEb015Agree) {
  const C3dData pi = ReadC3d(C3dDir() / "Eb015pi.c3d");  // Intel int16
  const C3dData sr = ReadC3d(C3dDir() / "Eb015sr.c3d");  // MIPS float
  const C3dData vr = ReadC3d(C3dDir() / "Eb015vr.c3d");  // DEC float
  ASSERT_EQ(pi.num_frames, 450);
  for (const C3dData* other : {&sr, &vr}) {
    ASSERT_EQ(other->num_frames, pi.num_frames);
    ASSERT_EQ(other->num_points, pi.num_points);
    EXPECT_EQ(other->labels, pi.labels);
    EXPECT_TRUE((other->valid == pi.valid).all());
    for (int f = 0; f < pi.num_frames; ++f) {
      for (int p = 0; p < pi.num_points; ++p) {
        if (!pi.valid(f, p)) continue;
        for (Eigen::Index c = 0; c < 3; ++c) {
          ASSERT_NEAR(other->points(f, 3 * Eigen::Index{p} + c),
                      pi.points(f, 3 * Eigen::Index{p} + c),
                      1e-3)
              << ToString(other->processor) << " frame " << f << " point " << p;
        }
        ASSERT_NEAR(other->residuals(f, p), pi.residuals(f, p), 1e-4);
      }
    }
    // Header events and parameters decode identically too.
    ASSERT_EQ(other->header.events.size(), 3u);
    EXPECT_EQ(other->header.events[1].label, "RHS");
    EXPECT_FLOAT_EQ(other->header.events[1].time, 5.4f);
    EXPECT_EQ(other->FindParameter("FORCE_PLATFORM", "CORNERS")->AsFloats(),
              pi.FindParameter("FORCE_PLATFORM", "CORNERS")->AsFloats());
  }
}

TEST(C3dReader, AnalogsOfEb015AgreeAcrossEncodings) {
  C3dReadOptions options;
  options.read_analogs = true;
  const C3dData pi = ReadC3d(C3dDir() / "Eb015pi.c3d", options);
  const C3dData vr = ReadC3d(C3dDir() / "Eb015vr.c3d", options);
  ASSERT_EQ(pi.analog.samples.rows(), 450 * 4);
  ASSERT_EQ(pi.analog.samples.cols(), 16);
  EXPECT_EQ(pi.analog.labels[0], "FX1");
  EXPECT_DOUBLE_EQ(pi.analog.rate, 200.0);
  EXPECT_TRUE(pi.analog.samples.isApprox(vr.analog.samples, 1e-5f));
  // Reading analogs does not change the points.
  const C3dData plain = ReadC3d(C3dDir() / "Eb015pi.c3d");
  EXPECT_EQ(plain.analog.samples.size(), 0);
  EXPECT_TRUE(((plain.points.array() == pi.points.array()) ||
               (plain.points.array().isNaN() && pi.points.array().isNaN()))
                  .all());
}

TEST(C3dReader, ViconNexusAnalogsAreSkippedCorrectly) {
  // 51 points interleaved with 38 channels x 20 samples per frame: a wrong
  // stride would put analog voltages into the marker coordinates.
  C3dReadOptions options;
  options.read_analogs = true;
  const C3dData d =
      ReadC3d(C3dDir() / "vicon_nexus_markers_analogs.c3d", options);
  EXPECT_EQ(d.analog.samples.rows(), 580 * 20);
  EXPECT_EQ(d.analog.samples.cols(), 38);
  EXPECT_DOUBLE_EQ(d.analog.rate, 2000.0);
  EXPECT_EQ(d.analog.units[0], "V");
  // Box markers stay rigid: the distance between two of them is constant.
  const int a = 0;  // boite:gauche_ext
  const int b = 3;  // boite:droite_ext
  float first = -1.0f;
  for (int f = 0; f < d.num_frames; ++f) {
    if (!d.valid(f, a) || !d.valid(f, b)) continue;
    const float dist = (d.Point(f, a) - d.Point(f, b)).norm();
    if (first < 0.0f) first = dist;
    ASSERT_NEAR(dist, first, 2.0f) << "frame " << f;
  }
  EXPECT_GT(first, 50.0f);
}

TEST(C3dReader, Hdm05MarkersAreHumanSizedInMillimetres) {
  const C3dData d = ReadC3d(C3dDir() / "HDM_mm_01-02_03_120.c3d");
  ASSERT_EQ(d.units, "mm");
  int lfhd = -1, rfhd = -1, lank = -1;
  for (int p = 0; p < d.num_points; ++p) {
    const std::string_view name = StripSubjectPrefix(d.labels[p]);
    if (name == "LFHD") lfhd = p;
    if (name == "RFHD") rfhd = p;
    if (name == "LANK") lank = p;
  }
  ASSERT_GE(lfhd, 0);
  ASSERT_GE(rfhd, 0);
  ASSERT_GE(lank, 0);
  for (int f = 0; f < d.num_frames; f += 10) {
    // Front head markers are a head width apart: 5..25 cm.
    const float head = (d.Point(f, lfhd) - d.Point(f, rfhd)).norm();
    ASSERT_GT(head, 50.0f) << f;
    ASSERT_LT(head, 250.0f) << f;
    // Head to ankle: roughly standing height, 0.5..2.2 m.
    const float height = (d.Point(f, lfhd) - d.Point(f, lank)).norm();
    ASSERT_GT(height, 500.0f) << f;
    ASSERT_LT(height, 2200.0f) << f;
  }
  EXPECT_LT(d.points.cwiseAbs().maxCoeff(), 5000.0f);
}

TEST(C3dReader, TruncatedFileIsAnErrorNamingTheByteRange) {
  const auto path = C3dDir() / "Optotrak_truncated.c3d";
  try {
    ReadC3d(path);
    FAIL() << "expected IoError";
  } catch (const IoError& e) {
    // Data start block 8 → byte 3584; 54 points x 16 bytes per frame.
    EXPECT_EQ(std::string(e.what()),
              "Truncated C3D file '" + path.string() +
                  "': frame 29 of 1149 needs bytes [28640, 29504) but the "
                  "file has 28640 bytes");
  }
  C3dReadOptions options;
  options.allow_truncated = true;
  const C3dData d = ReadC3d(path, options);
  EXPECT_EQ(d.num_frames, 29);
  EXPECT_EQ(d.FindParameter("POINT", "FRAMES")->AsInts()[0], 1149);
}

TEST(C3dReader, EmptyParameterSection) {
  const C3dData d = ReadC3d(C3dDir() / "phasespace_sample.c3d");
  EXPECT_TRUE(d.groups.empty());
  EXPECT_EQ(d.num_points, 40);
  EXPECT_EQ(d.num_frames, 701);
  EXPECT_DOUBLE_EQ(d.frame_rate, 30.0);
  EXPECT_EQ(d.num_file_labels, 0);
  EXPECT_EQ(d.labels[7], "*7");
  EXPECT_EQ(d.units, "");
  EXPECT_DOUBLE_EQ(d.MetresPerUnit(), 0.001);
}

TEST(C3dReader, ParameterSectionIsComplete) {
  const C3dData d = ReadC3d(C3dDir() / "Eb015pi.c3d");
  const std::vector<std::string> group_names = {
      "POINT", "ANALOG", "FORCE_PLATFORM", "FPLOC", "SUBJECT"};
  ASSERT_EQ(d.groups.size(), group_names.size());
  for (size_t i = 0; i < group_names.size(); ++i) {
    EXPECT_EQ(d.groups[i].name, group_names[i]);
  }
  EXPECT_EQ(d.groups[0].description, "3-D point parameters");
  EXPECT_NE(d.FindGroup("point"), nullptr);  // case-insensitive

  const C3dParameter* used = d.FindParameter("POINT", "USED");
  ASSERT_NE(used, nullptr);
  EXPECT_EQ(used->type, C3dParameterType::kInt16);
  EXPECT_TRUE(used->locked);
  EXPECT_TRUE(used->dims.empty());
  EXPECT_EQ(used->AsInts(), std::vector<int>{26});

  const C3dParameter* rate = d.FindParameter("POINT", "RATE");
  EXPECT_EQ(rate->type, C3dParameterType::kFloat);
  EXPECT_EQ(rate->AsFloats(), std::vector<float>{50.0f});
  EXPECT_EQ(rate->AsInts(), std::vector<int>{50});

  const C3dParameter* labels = d.FindParameter("POINT", "LABELS");
  EXPECT_EQ(labels->type, C3dParameterType::kChar);
  ASSERT_EQ(labels->dims.size(), 2u);
  EXPECT_EQ(labels->dims[1], 48);  // room for 48, 26 used
  EXPECT_FALSE(labels->locked);
  EXPECT_EQ(labels->AsStrings().size(), 48u);
  EXPECT_EQ(d.descriptions[0], "DIST/LAT FOOT");
  EXPECT_THROW(labels->AsFloats(), IoError);
  EXPECT_THROW(used->AsStrings(), IoError);

  // A 3-D float array: FORCE_PLATFORM:CORNERS is 3 x 4 x 2.
  const C3dParameter* corners = d.FindParameter("FORCE_PLATFORM", "CORNERS");
  EXPECT_EQ(corners->dims, (std::vector<int>{3, 4, 2}));
  EXPECT_EQ(corners->NumElements(), 24);
  EXPECT_EQ(corners->AsFloats().size(), 24u);

  // Byte parameters (type 1) exist in the Vicon files.
  const C3dData hdm = ReadC3d(C3dDir() / "HDM_mm_01-02_03_120.c3d");
  const C3dParameter* drop = hdm.FindParameter("TIMECODE", "DROP_FRAMES");
  ASSERT_NE(drop, nullptr);
  EXPECT_EQ(drop->type, C3dParameterType::kByte);
  EXPECT_EQ(drop->AsInts().size(), static_cast<size_t>(drop->NumElements()));
  EXPECT_EQ(hdm.FindParameter("TRIAL", "ACTUAL_END_FIELD")->AsInts(),
            (std::vector<int>{3990, 0}));
}

TEST(C3dReader, SubjectPrefixes) {
  const C3dData d = ReadC3d(C3dDir() / "shd01.c3d");
  EXPECT_EQ(d.labels[0], "AbcdeFghijk:RASI");
  EXPECT_EQ(StripSubjectPrefix(d.labels[0]), "RASI");
  EXPECT_EQ(StripSubjectPrefix("LFHD"), "LFHD");
  EXPECT_EQ(StripSubjectPrefix("a:b:C7"), "C7");
  EXPECT_EQ(StripSubjectPrefix(""), "");
}

TEST(C3dUnits, ScaleToMetres) {
  EXPECT_DOUBLE_EQ(UnitScaleToMetres("mm"), 0.001);
  EXPECT_DOUBLE_EQ(UnitScaleToMetres(" MM "), 0.001);
  EXPECT_DOUBLE_EQ(UnitScaleToMetres("cm"), 0.01);
  EXPECT_DOUBLE_EQ(UnitScaleToMetres("m"), 1.0);
  EXPECT_DOUBLE_EQ(UnitScaleToMetres("meters"), 1.0);
  EXPECT_DOUBLE_EQ(UnitScaleToMetres("Millimetres"), 0.001);
  EXPECT_THROW(UnitScaleToMetres("inch"), IoError);
  EXPECT_THROW(UnitScaleToMetres(""), IoError);
}

// ---------------------------------------------------------------------------
// Writer.

C3dData MakeSynthetic(int frames, int points) {
  C3dData d;
  d.source = "synthetic";
  d.frame_rate = 100.0;
  d.num_frames = frames;
  d.num_points = points;
  d.units = "mm";
  d.first_frame = 1;
  d.point_scale = -0.1f;
  d.points.resize(frames, 3 * Eigen::Index{points});
  d.residuals.setZero(frames, points);
  d.valid.setConstant(frames, points, true);
  for (int f = 0; f < frames; ++f) {
    for (int p = 0; p < points; ++p) {
      for (Eigen::Index c = 0; c < 3; ++c) {
        d.points(f, 3 * Eigen::Index{p} + c) =
            0.25f * f - 3.5f * p + 1000.0f * c + 0.125f;
      }
      d.residuals(f, p) = 0.1f * ((f + p) % 20);
    }
  }
  for (int p = 0; p < points; ++p) d.labels.push_back(fmt::format("M{}", p));
  return d;
}

TEST(MarkerLabels, PlugInGaitVirtualPointsNeedTheirSegmentGroup) {
  const std::vector<std::string> labels = {
      "LFHD", "PELO", "PELA",      "PELL",         "PELP",
      "LTOP", "LTOE", "subj:LFEO", "subj:LFEA ",   "subj:LFEL",
      "RTIO", "RTIB", "LTIB",      "CentreOfMass", "HEDO",
      "HEDA", "pelo", "XPELO",     "LXXO",         "CentreOfMassFloor"};
  const std::vector<bool> flags = PlugInGaitVirtualPoints(labels);
  ASSERT_EQ(flags.size(), labels.size());
  std::vector<std::string> flagged;
  for (size_t i = 0; i < labels.size(); ++i) {
    if (flags[i]) flagged.emplace_back(StripSubjectPrefix(labels[i]));
  }
  // A segment with its origin and at least two more axes is the model's;
  // LTOP alone, RTIO alone and HEDO + HEDA (one more axis) are kept.
  EXPECT_EQ(flagged,
            (std::vector<std::string>{"PELO",
                                      "PELA",
                                      "PELL",
                                      "PELP",
                                      "LFEO",
                                      "LFEA",
                                      "LFEL",
                                      "CentreOfMass",
                                      "CentreOfMassFloor"}));
  EXPECT_TRUE(PlugInGaitVirtualPoints({}).empty());
}

TEST(C3dReader, PlugInGaitOutputsAreNotMarkers) {
  // Vicon Nexus files: the Plug-in Gait model's angles, forces ... are listed
  // in POINT:ANGLES etc.; its virtual points (19 segments x 4 axes, and the
  // centre of mass and its floor projection where the model computed them)
  // are listed nowhere.
  struct Take {
    const char* file;
    int markers;   // what the capture's cameras saw
    int virtuals;  // Plug-in Gait's virtual points
  };
  for (const Take& take : {Take{"PiG_Motion-FlatFoot-Hole.c3d", 35, 78},
                           Take{"PiG_Calibration-FlatFoot-Full.c3d", 35, 76},
                           Take{"Movement_trial.c3d", 39, 78}}) {
    SCOPED_TRACE(take.file);
    const C3dData d = ReadC3d(C3dDir() / take.file);
    const std::vector<bool> non_position = NonPositionColumns(d);
    const std::vector<bool> outputs = ModelOutputColumns(d);
    const std::vector<bool> virtual_points = PlugInGaitVirtualPoints(d.labels);
    ASSERT_EQ(outputs.size(), static_cast<size_t>(d.num_points));
    int markers = 0;
    int virtuals = 0;
    std::set<std::string> kept;
    for (int p = 0; p < d.num_points; ++p) {
      EXPECT_EQ(outputs[p], non_position[p] || virtual_points[p]) << p;
      EXPECT_FALSE(non_position[p] && virtual_points[p]) << d.labels[p];
      virtuals += virtual_points[p] ? 1 : 0;
      const std::string_view name = StripSubjectPrefix(d.labels[p]);
      if (outputs[p] || name.empty() || name[0] == '*') continue;
      ++markers;
      kept.emplace(name);
    }
    EXPECT_EQ(virtuals, take.virtuals);
    EXPECT_EQ(markers, take.markers);
    for (const char* marker : {"LASI",
                               "RPSI",
                               "LTHI",
                               "LKNE",
                               "LTIB",
                               "RANK",
                               "RHEE",
                               "LTOE",
                               "C7",
                               "CLAV",
                               "LFIN",
                               "RWRB"}) {
      EXPECT_EQ(kept.count(marker), 1u) << marker;
    }
  }
  for (const char* file : {"HDM_mm_01-02_03_120.c3d", "cmu_01_01.c3d"}) {
    const C3dData d = ReadC3d(C3dDir() / file);
    const std::vector<bool> outputs = ModelOutputColumns(d);
    EXPECT_EQ(std::count(outputs.begin(), outputs.end(), true), 0) << file;
  }
}

size_t DataOffset(const std::vector<uint8_t>& bytes) {
  return static_cast<size_t>(RawLeInt16(bytes, 16) - 1) * 512;
}

TEST(C3dWriter, RoundTripOfRealFilePreservesEverything) {
  for (const char* name : {"HDM_mm_01-02_03_120.c3d",
                           "Gait.c3d",
                           "Movement_trial.c3d",
                           "phasespace_sample.c3d"}) {
    SCOPED_TRACE(name);
    const C3dData in = ReadC3d(C3dDir() / name);
    const auto path = testing::CreateTestDir() / "out.c3d";
    WriteC3d(path, in);
    const C3dData out = ReadC3d(path);
    EXPECT_EQ(out.processor, C3dProcessor::kIntel);
    EXPECT_LT(out.point_scale, 0.0f);
    EXPECT_EQ(out.num_frames, in.num_frames);
    EXPECT_EQ(out.num_points, in.num_points);
    EXPECT_EQ(out.first_frame, in.first_frame);
    EXPECT_DOUBLE_EQ(out.frame_rate, in.frame_rate);
    EXPECT_EQ(out.labels, in.labels);
    EXPECT_EQ(out.units, in.units.empty() ? "mm" : in.units);
    EXPECT_TRUE((out.valid == in.valid).all());
    for (int f = 0; f < in.num_frames; ++f) {
      for (int p = 0; p < in.num_points; ++p) {
        if (!in.valid(f, p)) continue;
        ASSERT_EQ(out.Point(f, p), in.Point(f, p)) << f << "," << p;
        ASSERT_NEAR(out.residuals(f, p),
                    in.residuals(f, p),
                    std::fabs(in.point_scale) / 2 + 1e-6);
      }
    }
  }
}

TEST(C3dWriter, MoreThan255PointsUseLabels2) {
  C3dData d = MakeSynthetic(3, 600);
  d.labels[255] = "second_chunk_first";
  d.labels[599] = "last";
  const std::vector<uint8_t> bytes = EncodeC3d(d);
  const C3dData r = ParseC3d(bytes, "mem");
  EXPECT_EQ(r.num_points, 600);
  EXPECT_EQ(r.num_file_labels, 600);
  EXPECT_EQ(r.labels, d.labels);
  ASSERT_NE(r.FindParameter("POINT", "LABELS2"), nullptr);
  ASSERT_NE(r.FindParameter("POINT", "LABELS3"), nullptr);
  EXPECT_EQ(r.FindParameter("POINT", "LABELS3")->AsStrings().size(), 90u);
  EXPECT_TRUE(r.points.isApprox(d.points));
}

TEST(C3dWriter, MoreThan65535FramesUseTrialFields) {
  C3dData d = MakeSynthetic(70000, 1);
  d.first_frame = 65000;
  const std::vector<uint8_t> bytes = EncodeC3d(d);
  const C3dData r = ParseC3d(bytes, "mem");
  EXPECT_EQ(r.header.last_frame, 65535);  // saturated
  EXPECT_EQ(r.num_frames, 70000);
  EXPECT_EQ(r.first_frame, 65000);
  EXPECT_EQ(r.FindParameter("POINT", "FRAMES")->type, C3dParameterType::kFloat);
  EXPECT_EQ(r.Point(69999, 0), d.Point(69999, 0));

  // Without the TRIAL group, the float POINT:FRAMES gives the count.
  std::vector<uint8_t> no_trial = bytes;
  const std::string_view trial = "TRIAL";
  const auto it =
      std::search(no_trial.begin(), no_trial.end(), trial.begin(), trial.end());
  ASSERT_NE(it, no_trial.end());
  *(it + 3) = 'X';  // the group is now "TRIXL"
  const C3dData f = ParseC3d(no_trial, "mem");
  EXPECT_EQ(f.FindParameter("TRIAL", "ACTUAL_END_FIELD"), nullptr);
  EXPECT_EQ(f.num_frames, 70000);
  EXPECT_EQ(f.first_frame, 65000);
}

TEST(C3dWriter, PointUsedAbove32767IsUnsigned) {
  C3dData d = MakeSynthetic(1, 40000);
  const std::vector<uint8_t> bytes = EncodeC3d(d);
  const C3dData r = ParseC3d(bytes, "mem");
  EXPECT_EQ(r.num_points, 40000);
  EXPECT_EQ(r.FindParameter("POINT", "USED")->AsInts()[0], 40000 - 65536);
  EXPECT_EQ(r.labels[39999], "M39999");
}

TEST(C3dWriter, InvalidPointsRoundTrip) {
  C3dData d = MakeSynthetic(4, 3);
  d.residuals(0, 0) = -1.0f;
  d.valid(1, 1) = false;
  d.points(2, 7) = std::numeric_limits<float>::quiet_NaN();
  d.points(3, 0) = std::numeric_limits<float>::infinity();
  const C3dData r = ParseC3d(EncodeC3d(d), "mem");
  EXPECT_FALSE(r.valid(0, 0));
  EXPECT_FALSE(r.valid(1, 1));
  EXPECT_FALSE(r.valid(2, 2));
  EXPECT_FALSE(r.valid(3, 0));
  EXPECT_EQ(r.valid.count(), 12 - 4);
  EXPECT_TRUE(std::isnan(r.points(1, 3)));
  EXPECT_EQ(r.residuals(1, 1), -1.0f);
  EXPECT_EQ(r.Point(1, 0), d.Point(1, 0));
}

TEST(C3dWriter, RejectsInconsistentData) {
  C3dData d = MakeSynthetic(2, 2);
  d.labels.pop_back();
  EXPECT_THROW(EncodeC3d(d), ShapeError);
  d = MakeSynthetic(2, 2);
  d.num_points = 3;
  EXPECT_THROW(EncodeC3d(d), ShapeError);
  d = MakeSynthetic(2, 2);
  d.frame_rate = 0.0;
  EXPECT_THROW(EncodeC3d(d), IoError);
  d = MakeSynthetic(2, 2);
  d.labels[0] = std::string(300, 'x');
  EXPECT_THROW(EncodeC3d(d), IoError);
}

TEST(C3dWriter, WriteIsAtomic) {
  const auto dir = testing::CreateTestDir();
  const auto path = dir / "x.c3d";
  WriteC3d(path, MakeSynthetic(2, 2));
  const auto before = FileBytes(path);
  C3dData bad = MakeSynthetic(2, 2);
  bad.frame_rate = -1.0;
  EXPECT_THROW(WriteC3d(path, bad), IoError);
  EXPECT_EQ(FileBytes(path), before);
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);
}

// ---------------------------------------------------------------------------
// Bad input: every case is a one-line IoError, never a crash.

std::string ParseError(const std::vector<uint8_t>& bytes) {
  try {
    ParseC3d(bytes, "bad.c3d");
  } catch (const IoError& e) {
    return e.what();
  }
  return "no error";
}

TEST(C3dBadInput, WrongMagicByte) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeSynthetic(2, 2));
  bytes[1] = 0x51;
  EXPECT_THAT(ParseError(bytes), HasSubstr("'bad.c3d' at byte 1"));
  EXPECT_THAT(ParseError(bytes), HasSubstr("expected 0x50"));
}

TEST(C3dBadInput, TooShortForAHeader) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeSynthetic(2, 2));
  bytes.resize(100);
  EXPECT_THAT(ParseError(bytes), HasSubstr("less than the 512-byte header"));
  EXPECT_THAT(ParseError({}), HasSubstr("has 0 bytes"));
}

TEST(C3dBadInput, ParameterBlockPastTheEnd) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeSynthetic(2, 2));
  bytes[0] = 200;
  EXPECT_THAT(ParseError(bytes), HasSubstr("parameter section preamble"));
  bytes[0] = 0;
  EXPECT_THAT(ParseError(bytes), HasSubstr("parameter block 0"));
}

TEST(C3dBadInput, UnknownProcessorType) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeSynthetic(2, 2));
  bytes[512 + 3] = 99;
  EXPECT_THAT(ParseError(bytes), HasSubstr("at byte 515: unknown processor"));
}

TEST(C3dBadInput, LastFrameBeforeFirstFrame) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeSynthetic(2, 2));
  bytes[6] = 10;  // first frame 10, last frame 2
  EXPECT_THAT(ParseError(bytes), HasSubstr("before the first frame"));
  // first = last + 1 is zero frames: valid.
  bytes[6] = 3;
  EXPECT_EQ(ParseC3d(bytes, "ok").num_frames, 0);
}

TEST(C3dBadInput, ZeroFramesIsValid) {
  const C3dData r = ParseC3d(EncodeC3d(MakeSynthetic(0, 5)), "empty");
  EXPECT_EQ(r.num_frames, 0);
  EXPECT_EQ(r.num_points, 5);
  EXPECT_EQ(r.points.rows(), 0);
  EXPECT_EQ(r.points.cols(), 15);
  EXPECT_EQ(r.labels[4], "M4");
}

TEST(C3dBadInput, ZeroPointsIsValid) {
  const C3dData r = ParseC3d(EncodeC3d(MakeSynthetic(7, 0)), "nopoints");
  EXPECT_EQ(r.num_frames, 7);
  EXPECT_EQ(r.num_points, 0);
}

TEST(C3dBadInput, HugePointCountIsBoundedByFileSize) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeSynthetic(2, 2));
  bytes[2] = 0xff;  // 65535 points, 65535 frames
  bytes[3] = 0xff;
  bytes[8] = 0xfe;
  bytes[9] = 0xff;
  EXPECT_THAT(ParseError(bytes),
              HasSubstr("Truncated C3D file 'bad.c3d': frame 0 of 65534"));
}

TEST(C3dBadInput, ZeroScale) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeSynthetic(2, 2));
  std::memset(bytes.data() + 12, 0, 4);
  // The header scale is 0 → POINT:SCALE (-0.1) is used.
  EXPECT_EQ(ParseC3d(bytes, "ok").point_scale, -0.1f);
}

TEST(C3dBadInput, ScaleThatOverflowsMakesPointsInvalid) {
  C3dData d = MakeSynthetic(2, 2);
  d.point_scale = 0.1f;  // int16 data
  std::vector<uint8_t> bytes = EncodeC3d(d);
  const float huge = 3e38f;  // int16 * huge = inf (found by the fuzzer)
  std::memcpy(bytes.data() + 12, &huge, 4);
  const C3dData r = ParseC3d(bytes, "huge_scale");
  EXPECT_EQ(r.point_scale, huge);
  EXPECT_FALSE(r.valid.any());
  EXPECT_TRUE(r.points.array().isNaN().all());
  EXPECT_TRUE((r.residuals.array() == -1.0f).all());
}

TEST(C3dBadInput, OddLabelBytesAreKept) {
  C3dData d = MakeSynthetic(1, 3);
  d.labels[0] = "\xff\xfe\x80X";
  d.labels[1] =
      "A\x01"
      "B";
  d.labels[2] = "\xe9l\xe8ve:LFHD";  // latin-1 subject prefix
  const C3dData r = ParseC3d(EncodeC3d(d), "latin1");
  EXPECT_EQ(r.labels, d.labels);
  EXPECT_EQ(StripSubjectPrefix(r.labels[2]), "LFHD");
}

TEST(C3dBadInput, NanCoordinatesAreInvalid) {
  const C3dData d = MakeSynthetic(2, 2);
  std::vector<uint8_t> bytes = EncodeC3d(d);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // Frame 1, point 0, Y: the residual word stays >= 0.
  std::memcpy(bytes.data() + DataOffset(bytes) + 32 + 4, &nan, 4);
  const C3dData r = ParseC3d(bytes, "nan");
  EXPECT_FALSE(r.valid(1, 0));
  EXPECT_EQ(r.residuals(1, 0), -1.0f);
  EXPECT_TRUE(r.Point(1, 0).array().isNaN().all());
  EXPECT_EQ(r.valid.count(), 3);
}

TEST(C3dBadInput, TruncatedData) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeSynthetic(10, 2));
  const size_t data = DataOffset(bytes);
  bytes.resize(data + 101);  // 3 frames of 32 bytes + 5
  EXPECT_EQ(ParseError(bytes),
            fmt::format("Truncated C3D file 'bad.c3d': frame 3 of 10 needs "
                        "bytes [{}, {}) but the file has {} bytes",
                        data + 96,
                        data + 128,
                        bytes.size()));
  C3dReadOptions options;
  options.allow_truncated = true;
  EXPECT_EQ(ParseC3d(bytes, "t", options).num_frames, 3);
}

TEST(C3dBadInput, BadParameterRecords) {
  const std::vector<uint8_t> good = EncodeC3d(MakeSynthetic(2, 2));
  // The first record is the POINT group; the second is POINT:USED: name
  // length 4, id 1, "USED", offset(2), type at +8.
  const size_t group = 512 + 4;
  const size_t group_next = group + 2 + 5;
  const size_t used = group_next + RawLeInt16(good, group_next);
  ASSERT_EQ(std::string(good.begin() + used + 2, good.begin() + used + 6),
            "USED");
  {
    std::vector<uint8_t> bytes = good;
    bytes[used + 8] = 3;  // type 3 does not exist
    EXPECT_THAT(ParseError(bytes), HasSubstr("has type 3"));
  }
  {
    std::vector<uint8_t> bytes = good;
    bytes[used + 9] = 3;  // 3 dims of 255 x 255 x (next byte)
    bytes[used + 10] = 255;
    bytes[used + 11] = 255;
    bytes[used + 12] = 255;
    EXPECT_THAT(ParseError(bytes), HasSubstr("declares 16581375 elements"));
  }
  {
    // A next-record offset past the section end ends the chain: the file
    // still reads from its header, without parameters.
    std::vector<uint8_t> bytes = good;
    bytes[group_next] = 0xff;
    bytes[group_next + 1] = 0xff;
    const C3dData r = ParseC3d(bytes, "chain");
    ASSERT_EQ(r.groups.size(), 1u);
    EXPECT_TRUE(r.groups[0].parameters.empty());
    EXPECT_EQ(r.num_file_labels, 0);
    EXPECT_EQ(r.labels[1], "*1");
    EXPECT_EQ(r.num_frames, 2);
  }
}

TEST(C3dBadInput, DataStartZeroUsesPointDataStart) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeSynthetic(2, 2));
  bytes[16] = 0;
  bytes[17] = 0;
  const C3dData r = ParseC3d(bytes, "ok");
  EXPECT_EQ(r.num_frames, 2);
  EXPECT_EQ(r.Point(1, 1), MakeSynthetic(2, 2).Point(1, 1));
}

TEST(C3dBadInput, MissingFile) {
  EXPECT_THROW(ReadC3d("/nonexistent/x.c3d"), IoError);
  EXPECT_THROW(ReadC3d(testing::CreateTestDir()), IoError);  // a directory
}

}  // namespace
}  // namespace soma
