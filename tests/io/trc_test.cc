#include "framework/io/trc.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace soma {
namespace {

using ::testing::HasSubstr;

std::filesystem::path TrcDir() { return testing::SharedDataDir() / "trc"; }

struct TrcFacts {
  std::string name;
  int num_frames;
  double frame_rate;
  std::string first_label;
  std::string last_label;
  Eigen::Vector3f first_row_marker0;
  int last_frame_number;
  double last_time;
  Eigen::Vector3f last_row_marker40;
};

const std::vector<TrcFacts>& AllTrcFacts() {
  static const std::vector<TrcFacts> facts = {
      {"T.trc",
       89,
       30.0,
       "RFHD",
       "LFHD",
       {-336.42437f, 1639.63722f, -22.068f},
       89,
       2.933,
       {-266.26716f, 1614.56678f, 82.11697f}},
      {"ballet_reduced.trc",
       100,
       30.0,
       "RFHD",
       "LFHD",
       {93.08053f, 1542.35255f, -121.98482f},
       100,
       3.3,
       {-2.99656f, 1576.06381f, 16.54349f}},
      {"subject01_walk1.trc",
       151,
       60.0,
       "R.ASIS",
       "Top.Head",
       {617.24762f, 1055.27502f, 170.78198f},
       151,
       2.5,
       {614.13971f, 1776.27051f, 23.29867f}},
  };
  return facts;
}

// An independent reading of the data rows (istringstream + stod), to compare
// every coordinate with the reader's.
std::vector<std::vector<std::string>> RawRows(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::string line;
  std::vector<std::vector<std::string>> rows;
  for (int n = 1; std::getline(in, line); ++n) {
    if (n <= 5) continue;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, '\t')) cells.push_back(cell);
    rows.push_back(cells);
  }
  return rows;
}

TEST(TrcReader, ReadsEverySharedFile) {
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(TrcDir())) {
    if (entry.path().extension() == ".trc") ++files;
  }
  EXPECT_EQ(files, static_cast<int>(AllTrcFacts().size()));
  for (const TrcFacts& facts : AllTrcFacts()) {
    SCOPED_TRACE(facts.name);
    const TrcData d = ReadTrc(TrcDir() / facts.name);
    EXPECT_EQ(d.num_frames, facts.num_frames);
    EXPECT_EQ(d.num_markers, 41);
    EXPECT_DOUBLE_EQ(d.frame_rate, facts.frame_rate);
    EXPECT_DOUBLE_EQ(d.camera_rate, facts.frame_rate);
    EXPECT_DOUBLE_EQ(d.orig_data_rate, facts.frame_rate);
    EXPECT_EQ(d.orig_data_start_frame, 1);
    EXPECT_EQ(d.orig_num_frames, facts.num_frames);
    EXPECT_EQ(d.units, "mm");
    EXPECT_DOUBLE_EQ(d.MetresPerUnit(), 0.001);
    ASSERT_EQ(d.labels.size(), 41u);
    EXPECT_EQ(d.labels.front(), facts.first_label);
    EXPECT_EQ(d.labels.back(), facts.last_label);
    ASSERT_EQ(d.points.rows(), facts.num_frames);
    ASSERT_EQ(d.points.cols(), 3 * 41);
    EXPECT_EQ(d.frame_numbers.front(), 1);
    EXPECT_EQ(d.frame_numbers.back(), facts.last_frame_number);
    EXPECT_DOUBLE_EQ(d.times.front(), 0.0);
    EXPECT_DOUBLE_EQ(d.times.back(), facts.last_time);
    EXPECT_TRUE(d.Point(0, 0).isApprox(facts.first_row_marker0, 1e-6f));
    EXPECT_TRUE(d.Point(facts.num_frames - 1, 40)
                    .isApprox(facts.last_row_marker40, 1e-6f));
    EXPECT_TRUE(d.valid.all());  // these files have no gaps
    // Every coordinate against an independent parse.
    const auto rows = RawRows(TrcDir() / facts.name);
    ASSERT_EQ(rows.size(), static_cast<size_t>(facts.num_frames));
    for (int f = 0; f < facts.num_frames; ++f) {
      for (int c = 0; c < 3 * 41; ++c) {
        ASSERT_FLOAT_EQ(d.points(f, c), std::stof(rows[f][2 + c]))
            << "frame " << f << " column " << c;
      }
    }
  }
}

// A small TRC in the OpenSim layout, built by the tests.
std::string MakeTrc(const std::vector<std::string>& rows,
                    int num_frames = 2,
                    const std::string& names = "A\t\t\tB\t\t") {
  std::string text =
      "PathFileType\t4\t(X/Y/Z)\tx.trc\n"
      "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\n"
      "100\t100\t" +
      std::to_string(num_frames) +
      "\t2\tm\n"
      "Frame#\tTime\t" +
      names +
      "\n"
      "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
      "\n";
  for (const std::string& row : rows) text += row + "\n";
  return text;
}

std::string ParseError(const std::string& text,
                       const TrcReadOptions& options = {}) {
  try {
    ParseTrc(text, "bad.trc", options);
  } catch (const IoError& e) {
    return e.what();
  }
  return "no error";
}

TEST(TrcReader, BlankCellsAreMissingMarkers) {
  const TrcData d = ParseTrc(
      MakeTrc({"1\t0.00\t1\t2\t3\t\t\t", "2\t0.01\tNaN\tnan\tNaN\t4\t5\t6"}),
      "gaps.trc");
  EXPECT_EQ(d.num_frames, 2);
  EXPECT_DOUBLE_EQ(d.MetresPerUnit(), 1.0);
  EXPECT_TRUE(d.valid(0, 0));
  EXPECT_FALSE(d.valid(0, 1));
  EXPECT_FALSE(d.valid(1, 0));
  EXPECT_TRUE(d.valid(1, 1));
  EXPECT_TRUE(d.Point(0, 1).array().isNaN().all());
  EXPECT_EQ(d.Point(1, 1), Eigen::Vector3f(4, 5, 6));
  EXPECT_EQ(d.Point(0, 0), Eigen::Vector3f(1, 2, 3));
}

TEST(TrcReader, PartiallyBlankMarkerIsMissing) {
  const TrcData d =
      ParseTrc(MakeTrc({"1\t0\t1\t\t3\t4\t5\t6", "2\t0.01\t1\t2\t3\t4\t5\t6"}),
               "partial.trc");
  EXPECT_FALSE(d.valid(0, 0));
  EXPECT_TRUE(d.Point(0, 0).array().isNaN().all());
}

TEST(TrcReader, TrailingTabsAndCrLfAreAccepted) {
  std::string text =
      MakeTrc({"1\t0\t1\t2\t3\t4\t5\t6\t\t", "2\t0.01\t1\t2\t3\t4\t5\t6\t"});
  std::string crlf;
  for (char c : text) {
    if (c == '\n') crlf += '\r';
    crlf += c;
  }
  const TrcData d = ParseTrc(crlf, "crlf.trc");
  EXPECT_EQ(d.num_frames, 2);
  EXPECT_EQ(d.labels, (std::vector<std::string>{"A", "B"}));
  EXPECT_TRUE(d.valid.all());
}

TEST(TrcReader, TruncatedRowNamesTheLine) {
  // Header lines 1-5, blank line 6, rows on lines 7 and 8.
  EXPECT_THAT(
      ParseError(MakeTrc({"1\t0\t1\t2\t3\t4\t5\t6", "2\t0.01\t1\t2"})),
      HasSubstr("'bad.trc' line 8: truncated row: 4 cells, expected 8"));
}

TEST(TrcReader, NonNumericCellNamesLineAndColumn) {
  EXPECT_EQ(ParseError(MakeTrc(
                {"1\t0\t1\t2\t3\t4\tfive\t6", "2\t0.01\t1\t2\t3\t4\t5\t6"})),
            "Invalid TRC file 'bad.trc' line 7: column 7: 'five' is not a "
            "number");
  EXPECT_THAT(ParseError(MakeTrc(
                  {"1\t0\t1\t2\t3\t4\t5\t6", "x\t0.01\t1\t2\t3\t4\t5\t6"})),
              HasSubstr("line 8: column 1: 'x' is not a number"));
  // Control bytes are escaped: the message stays on one line.
  EXPECT_THAT(ParseError(MakeTrc(
                  {"1\t0\t1\t2\t3\t4\t5\t6", "2\t0.01\t1\t2\r3\t4\t5\t6\t7"})),
              HasSubstr("line 8: column 4: '2\\x0d3' is not a number"));
  EXPECT_THAT(ParseError(MakeTrc(
                  {"1\t0\t1\t2\t3\t4\t5\t6", "2\t0.01\t1\t2\t3\t4\t5\t6\t7"})),
              HasSubstr("line 8: column 9: unexpected value '7'"));
}

TEST(TrcReader, FewerRowsThanNumFrames) {
  const std::string text = MakeTrc({"1\t0\t1\t2\t3\t4\t5\t6"}, 5);
  EXPECT_THAT(ParseError(text),
              HasSubstr("line 7: NumFrames is 5 but the file ends after 1 "
                        "data rows"));
  TrcReadOptions options;
  options.allow_truncated = true;
  EXPECT_EQ(ParseTrc(text, "t.trc", options).num_frames, 1);
}

TEST(TrcReader, BadHeaders) {
  EXPECT_THAT(ParseError(""), HasSubstr("line 1: the file is empty"));
  EXPECT_THAT(ParseError("Hello\tworld\n"),
              HasSubstr("line 1: starts with 'Hello'"));
  EXPECT_THAT(
      ParseError(MakeTrc({"1\t0\t1\t2\t3\t4\t5\t6"}, 1, "A\t\t\tB\t\t\tC")),
      HasSubstr("line 4: NumMarkers is 2 but the line names 3 markers"));
  std::string no_rate = MakeTrc({});
  no_rate.replace(no_rate.find("100\t100"), 3, "abc");
  EXPECT_THAT(ParseError(no_rate),
              HasSubstr("line 3: DataRate is 'abc', expected a number"));
  EXPECT_THAT(ParseError("PathFileType\t4\nDataRate\n"),
              HasSubstr("the header ends before the key/value lines"));
}

TEST(TrcReader, ZeroFrames) {
  const TrcData d = ParseTrc(MakeTrc({}, 0), "empty.trc");
  EXPECT_EQ(d.num_frames, 0);
  EXPECT_EQ(d.points.rows(), 0);
  EXPECT_EQ(d.points.cols(), 6);
}

TEST(TrcReader, MissingFile) {
  EXPECT_THROW(ReadTrc("/nonexistent/x.trc"), IoError);
  EXPECT_THROW(ReadTrc(testing::CreateTestDir()), IoError);  // a directory
}

}  // namespace
}  // namespace soma
