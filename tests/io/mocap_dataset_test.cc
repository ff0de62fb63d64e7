#include "framework/io/mocap_dataset.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

// The test writes wrong-schema files with the HDF5 C API. soma_io links HDF5
// privately, so the include directory is not on this target's path; Debian
// installs the serial headers under /usr/include/hdf5/serial.
#if __has_include(<hdf5/serial/hdf5.h>)
#include <hdf5/serial/hdf5.h>
#else
#include <hdf5.h>
#endif

#include <fmt/format.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <set>
#include <string>
#include <sys/wait.h>
#include <utility>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

constexpr int kPoints = 5;

DatasetInfo MakeInfo() {
  DatasetInfo info;
  info.labels = {"C7", "LFHD", "RFHD"};
  info.num_points = kPoints;
  info.frame_rate = 120.0;
  info.seed = 1234567890123ULL;
  info.config_yaml = "task:\n  name: synth\n";
  info.code_version = "v0.1-test";
  info.attributes = {{"noise", "b_c_g"}, {"source", "unit test"}};
  return info;
}

/// Frames [first, first + count) of a deterministic pattern: point p of frame
/// f = (f + 0.001 p, -p, 0.5 c), label (f + p) % (L + 1); every 7th point
/// is missing (zero, null).
LabeledFrames MakeFrames(int64_t first, int64_t count, int num_labels = 3) {
  LabeledFrames frames;
  frames.Resize(count, kPoints);
  for (int64_t i = 0; i < count; ++i) {
    const int64_t f = first + i;
    for (int p = 0; p < kPoints; ++p) {
      float* xyz = frames.frame_points(i) + 3 * p;
      int16_t& label = frames.frame_labels(i)[p];
      if ((f * kPoints + p) % 7 == 0) {
        xyz[0] = xyz[1] = xyz[2] = 0.0f;
        label = static_cast<int16_t>(num_labels);
        continue;
      }
      xyz[0] = static_cast<float>(f) + 0.001f * static_cast<float>(p);
      xyz[1] = -static_cast<float>(p);
      xyz[2] = 0.5f * static_cast<float>(p % 3);
      label = static_cast<int16_t>((f + p) % (num_labels + 1));
    }
  }
  return frames;
}

void WriteDataset(const fs::path& path,
                  int64_t frames,
                  int64_t block = 1000,
                  const DatasetInfo& info = MakeInfo()) {
  DatasetWriter writer(path, info);
  for (int64_t f = 0; f < frames; f += block) {
    writer.Append(MakeFrames(f, std::min(block, frames - f)));
  }
  EXPECT_EQ(writer.num_frames(), frames);
  writer.Close();
}

void ExpectFramesEqual(const LabeledFrames& actual,
                       const LabeledFrames& expected) {
  ASSERT_EQ(actual.num_points, expected.num_points);
  ASSERT_EQ(actual.num_frames(), expected.num_frames());
  EXPECT_EQ(actual.points, expected.points);
  EXPECT_EQ(actual.labels, expected.labels);
}

TEST(LabeledFrames, ResizeAndAppend) {
  LabeledFrames a = MakeFrames(0, 3);
  EXPECT_EQ(a.num_frames(), 3);
  a.Append(MakeFrames(3, 2));
  ExpectFramesEqual(a, MakeFrames(0, 5));
  LabeledFrames empty;
  empty.Append(a);
  EXPECT_EQ(empty.num_frames(), 5);
  LabeledFrames other;
  other.Resize(2, kPoints + 1);
  EXPECT_THAT(testing::ErrorMessage<ShapeError>([&] { a.Append(other); }),
              HasSubstr("6 points appended to frames with 5 points"));
}

TEST(LabeledFrames, SlotsTravelWithTheFrames) {
  // Layout-sampled frames carry S slot rows per frame; Append keeps them in
  // frame order and refuses frames with another S.
  auto with_slots = [](int64_t first, int64_t count, int num_slots) {
    LabeledFrames frames = MakeFrames(first, count);
    frames.num_slots = num_slots;
    frames.Resize(count, kPoints);
    for (int64_t i = 0; i < count * num_slots; ++i) {
      frames.slots[static_cast<size_t>(i)] =
          static_cast<int16_t>(first * num_slots + i);
    }
    return frames;
  };
  LabeledFrames a = with_slots(0, 3, 4);
  a.Append(with_slots(3, 2, 4));
  ASSERT_EQ(a.slots.size(), 20u);
  for (int64_t f = 0; f < 5; ++f) {
    EXPECT_EQ(a.frame_slots(f)[0], f * 4);
    EXPECT_EQ(a.frame_slots(f)[3], f * 4 + 3);
  }
  LabeledFrames empty;
  empty.Append(a);
  EXPECT_EQ(empty.num_slots, 4);
  EXPECT_EQ(empty.slots, a.slots);
  EXPECT_THAT(
      testing::ErrorMessage<ShapeError>([&] { a.Append(with_slots(5, 1, 3)); }),
      HasSubstr("3 label slots appended to frames with 4 label slots"));
  EXPECT_THAT(
      testing::ErrorMessage<ShapeError>([&] { a.Append(MakeFrames(5, 1)); }),
      HasSubstr("0 label slots"));
  // A dataset without slots refuses slotted frames instead of dropping them.
  DatasetWriter writer(testing::CreateTestDir() / "slots.h5", MakeInfo());
  EXPECT_THAT(testing::ErrorMessage<ShapeError>([&] { writer.Append(a); }),
              HasSubstr("4 label slots per frame, the dataset 0"));
}

constexpr int kSlots = 4;

/// A dataset of slotted frames: L = S = 4 slot labels, a table of 6 rows of
/// width 3 over two layouts.
DatasetInfo SlottedInfo() {
  DatasetInfo info = MakeInfo();
  info.labels = {"slot0", "slot1", "slot2", "slot3"};
  info.num_slots = kSlots;
  SlotTable& table = info.slot_table;
  table.width = 3;
  for (int g = 0; g < 6; ++g) {
    for (int c = 0; c < 3; ++c) table.rows.push_back(0.25f * g - 0.1f * c);
    table.names.push_back(fmt::format("M{}", g));
    table.row_layout.push_back(g < 4 ? 0 : 1);
  }
  table.layouts = {"cmu41", "random"};
  return info;
}

/// MakeFrames with L = 4 and slot rows: frame f's slots are rows
/// (f + s) % 7 - 1 (-1 = padded).
LabeledFrames SlottedFrames(int64_t first, int64_t count) {
  LabeledFrames frames = MakeFrames(first, count, kSlots);
  frames.num_slots = kSlots;
  frames.Resize(count, kPoints);
  for (int64_t i = 0; i < count; ++i) {
    for (int s = 0; s < kSlots; ++s) {
      frames.frame_slots(i)[s] = static_cast<int16_t>((first + i + s) % 7 - 1);
    }
  }
  return frames;
}

TEST(DatasetWriter, SlottedFramesRoundTripWithTheirSlotTable) {
  const fs::path path = testing::CreateTestDir() / "slotted.h5";
  {
    DatasetWriter writer(path, SlottedInfo());
    // Uneven blocks: partial chunks, whole chunks, a partial tail.
    for (const auto& [first, count] : std::vector<std::pair<int, int>>{
             {0, 10}, {10, 130}, {140, 3}, {143, 57}}) {
      writer.Append(SlottedFrames(first, count));
    }
    writer.Close();
  }
  DatasetReader reader(path);
  const DatasetInfo& info = reader.info();
  const DatasetInfo expected = SlottedInfo();
  EXPECT_EQ(info.num_slots, kSlots);
  EXPECT_EQ(info.slot_table.width, 3);
  EXPECT_EQ(info.slot_table.rows, expected.slot_table.rows);
  EXPECT_EQ(info.slot_table.names, expected.slot_table.names);
  EXPECT_EQ(info.slot_table.row_layout, expected.slot_table.row_layout);
  EXPECT_EQ(info.slot_table.layouts, expected.slot_table.layouts);
  EXPECT_EQ(info.attributes.count("slot_names"), 0u);  // reserved, not free
  LabeledFrames range;
  reader.Read(60, 80, &range);
  const LabeledFrames want = SlottedFrames(60, 80);
  ExpectFramesEqual(range, want);
  EXPECT_EQ(range.num_slots, kSlots);
  EXPECT_EQ(range.slots, want.slots);
  const std::vector<int64_t> indices = {199, 3, 64, 63, 3};
  LabeledFrames picked;
  reader.ReadIndices(indices, &picked);
  ASSERT_EQ(picked.num_slots, kSlots);
  for (size_t k = 0; k < indices.size(); ++k) {
    const LabeledFrames one = SlottedFrames(indices[k], 1);
    for (int s = 0; s < kSlots; ++s) {
      EXPECT_EQ(picked.frame_slots(static_cast<int64_t>(k))[s],
                one.frame_slots(0)[s])
          << k << " " << s;
    }
  }
  // A dataset without slots reads as before.
  const fs::path plain = testing::CreateTestDir() / "plain.h5";
  WriteDataset(plain, 10);
  DatasetReader plain_reader(plain);
  EXPECT_EQ(plain_reader.info().num_slots, 0);
  plain_reader.Read(0, 10, &range);
  EXPECT_EQ(range.num_slots, 0);
  EXPECT_TRUE(range.slots.empty());
}

TEST(DatasetWriter, SlottedBadInputIsOneLine) {
  const fs::path dir = testing::CreateTestDir();
  auto create_error = [&](const DatasetInfo& info) {
    return testing::ErrorMessage<ShapeError>(
        [&] { DatasetWriter writer(dir / "bad.h5", info); });
  };
  DatasetInfo info = SlottedInfo();
  info.labels.pop_back();
  EXPECT_THAT(create_error(info), HasSubstr("3 labels for 4 slots"));
  info = SlottedInfo();
  info.slot_table.rows.pop_back();
  EXPECT_THAT(create_error(info), HasSubstr("17 values for width 3"));
  info = SlottedInfo();
  info.slot_table.names.pop_back();
  EXPECT_THAT(create_error(info), HasSubstr("6 rows, 5 names"));
  info = SlottedInfo();
  info.slot_table.row_layout[2] = 2;
  EXPECT_THAT(create_error(info), HasSubstr("row 2 has layout 2"));
  info = SlottedInfo();
  info.slot_table.names[1] = "a\nb";
  EXPECT_THAT(create_error(info), HasSubstr("row 1 has a name with a newline"));

  DatasetWriter writer(dir / "ok.h5", SlottedInfo());
  LabeledFrames bad = SlottedFrames(0, 3);
  bad.frame_slots(2)[1] = 6;  // the table has rows 0..5
  const std::string message =
      testing::ErrorMessage<ShapeError>([&] { writer.Append(bad); });
  EXPECT_THAT(message,
              HasSubstr("slot row 6 at frame 2 slot 1 is outside "
                        "[-1, 6)"));
  EXPECT_EQ(message.find('\n'), std::string::npos);
  EXPECT_THAT(testing::ErrorMessage<ShapeError>(
                  [&] { writer.Append(MakeFrames(0, 2, kSlots)); }),
              HasSubstr("0 label slots per frame, the dataset 4"));
}

TEST(DatasetWriter, RoundTripWithAttributes) {
  const fs::path path = testing::CreateTestDir() / "data.h5";
  WriteDataset(path, 300, 300);
  DatasetReader reader(path);
  const DatasetInfo& info = reader.info();
  EXPECT_EQ(reader.num_frames(), 300);
  EXPECT_EQ(info.num_frames, 300);
  EXPECT_EQ(info.labels, MakeInfo().labels);
  EXPECT_EQ(info.num_points, kPoints);
  EXPECT_EQ(info.frame_rate, 120.0);
  EXPECT_EQ(info.seed, 1234567890123ULL);
  EXPECT_EQ(info.config_yaml, "task:\n  name: synth\n");
  EXPECT_EQ(info.code_version, "v0.1-test");
  EXPECT_EQ(info.attributes.at("noise"), "b_c_g");
  EXPECT_EQ(info.attributes.at("source"), "unit test");
  EXPECT_EQ(info.attributes.at("created_by"), "somalab");
  LabeledFrames all;
  reader.Read(0, 300, &all);
  ExpectFramesEqual(all, MakeFrames(0, 300));
  // No temp file is left beside the dataset.
  int files = 0;
  for (const auto& entry : fs::directory_iterator(path.parent_path())) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);
}

TEST(DatasetWriter, ExtraPointArrays) {
  const fs::path path = testing::CreateTestDir() / "labels.h5";
  std::vector<float> confidence(130 * kPoints);
  for (size_t i = 0; i < confidence.size(); ++i) confidence[i] = 0.001f * i;
  {
    DatasetWriter writer(path, MakeInfo());
    writer.Append(MakeFrames(0, 130));
    EXPECT_THAT(testing::ErrorMessage<ShapeError>(
                    [&] { writer.WritePointArray("confidence", {1.0f}); }),
                HasSubstr("expected 130 frames x 5 points"));
    writer.WritePointArray("confidence", confidence);
    EXPECT_THAT(testing::ErrorMessage<IoError>(
                    [&] { writer.WritePointArray("labels", confidence); }),
                HasSubstr("'labels' already exists"));
    writer.Close();
  }
  DatasetReader reader(path);
  EXPECT_EQ(reader.ReadPointArray("confidence"), confidence);
  EXPECT_THAT(
      testing::ErrorMessage<IoError>([&] { reader.ReadPointArray("column"); }),
      HasSubstr("no point array 'column'"));
  EXPECT_THAT(
      testing::ErrorMessage<IoError>([&] { reader.ReadPointArray("labels"); }),
      HasSubstr("not a 130 x 5 float32 point array"));
}

TEST(DatasetWriter, AppendInUnevenBlocks) {
  const fs::path dir = testing::CreateTestDir();
  // Blocks smaller than, equal to and larger than a chunk (64 frames).
  DatasetWriter writer(dir / "blocks.h5", MakeInfo());
  int64_t f = 0;
  for (int64_t block : {1, 63, 64, 1, 200, 0, 7, 128}) {
    writer.Append(MakeFrames(f, block));
    f += block;
  }
  EXPECT_EQ(writer.num_frames(), f);
  writer.Close();
  EXPECT_THROW(writer.Append(MakeFrames(0, 1)), IoError);
  DatasetReader reader(dir / "blocks.h5");
  LabeledFrames all;
  reader.Read(0, f, &all);
  ExpectFramesEqual(all, MakeFrames(0, f));
}

TEST(DatasetWriter, EmptyDatasetAndUnclosedWriterLeavesNothing) {
  const fs::path dir = testing::CreateTestDir();
  WriteDataset(dir / "empty.h5", 0);
  EXPECT_EQ(DatasetReader(dir / "empty.h5").num_frames(), 0);
  {
    DatasetWriter writer(dir / "abandoned.h5", MakeInfo());
    writer.Append(MakeFrames(0, 100));
  }
  EXPECT_FALSE(fs::exists(dir / "abandoned.h5"));
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);
}

TEST(DatasetWriter, WideFramesUseSmallerChunks) {
  // 30000 points = 360 KB per frame: chunks shrink to stay <= 1 MiB.
  const fs::path path = testing::CreateTestDir() / "wide.h5";
  DatasetInfo info = MakeInfo();
  info.num_points = 30000;
  LabeledFrames frames;
  frames.Resize(7, info.num_points);
  for (size_t i = 0; i < frames.points.size(); ++i) {
    frames.points[i] = static_cast<float>(i % 1000) * 0.25f;
  }
  for (size_t i = 0; i < frames.labels.size(); ++i) {
    frames.labels[i] = static_cast<int16_t>(i % 4);
  }
  DatasetWriter writer(path, info);
  writer.Append(frames);
  writer.Close();
  DatasetReader reader(path);
  LabeledFrames back;
  reader.Read(0, 7, &back);
  EXPECT_EQ(back.points, frames.points);
  EXPECT_EQ(back.labels, frames.labels);
}

TEST(DatasetWriter, BadInput) {
  const fs::path dir = testing::CreateTestDir();
  DatasetInfo info = MakeInfo();
  info.num_points = 0;
  EXPECT_THAT(testing::ErrorMessage<ShapeError>(
                  [&] { DatasetWriter writer(dir / "a.h5", info); }),
              HasSubstr("num_points >= 1"));
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] {
                DatasetWriter writer(dir / "missing/dir/a.h5", MakeInfo());
              }),
              HasSubstr("missing/dir/a.h5: cannot create"));
  info = MakeInfo();
  info.attributes["seed"] = "x";
  EXPECT_THAT(testing::ErrorMessage<IoError>(
                  [&] { DatasetWriter writer(dir / "a.h5", info); }),
              HasSubstr("'seed' is reserved"));

  DatasetWriter writer(dir / "b.h5", MakeInfo());
  LabeledFrames wrong_n;
  wrong_n.Resize(2, kPoints + 1);
  EXPECT_THAT(
      testing::ErrorMessage<ShapeError>([&] { writer.Append(wrong_n); }),
      HasSubstr("6 points, the dataset has 5"));
  LabeledFrames bad_label = MakeFrames(0, 2);
  bad_label.frame_labels(1)[2] = 4;  // L = 3, null = 3
  EXPECT_THAT(
      testing::ErrorMessage<ShapeError>([&] { writer.Append(bad_label); }),
      HasSubstr("label 4 at frame 1 point 2 is outside [0, 3]"));
  bad_label.frame_labels(1)[2] = -1;
  EXPECT_THROW(writer.Append(bad_label), ShapeError);
}

TEST(DatasetReader, ReadRangeAndIndices) {
  const fs::path path = testing::CreateTestDir() / "data.h5";
  WriteDataset(path, 500, 77);
  DatasetReader reader(path);
  LabeledFrames range;
  reader.Read(130, 70, &range);
  ExpectFramesEqual(range, MakeFrames(130, 70));
  reader.Read(499, 1, &range);
  ExpectFramesEqual(range, MakeFrames(499, 1));
  reader.Read(10, 0, &range);
  EXPECT_EQ(range.num_frames(), 0);

  const std::vector<int64_t> indices = {499, 3, 4, 5, 3, 0, 250, 64, 63};
  LabeledFrames picked;
  reader.ReadIndices(indices, &picked);
  ASSERT_EQ(picked.num_frames(), static_cast<int64_t>(indices.size()));
  for (size_t k = 0; k < indices.size(); ++k) {
    LabeledFrames one;
    one.Resize(1, kPoints);
    std::copy_n(picked.frame_points(k), kPoints * 3, one.frame_points(0));
    std::copy_n(picked.frame_labels(k), kPoints, one.frame_labels(0));
    ExpectFramesEqual(one, MakeFrames(indices[k], 1));
  }

  EXPECT_THAT(
      testing::ErrorMessage<IoError>([&] { reader.Read(450, 51, &range); }),
      HasSubstr(
          "frames [450, 501) requested, the dataset has frames [0, 500)"));
  EXPECT_THROW(reader.Read(-1, 2, &range), IoError);
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] {
                reader.ReadIndices({1, 500}, &picked);
              }),
              HasSubstr("frame 500 requested"));

  // Move keeps the reader usable.
  DatasetReader moved = std::move(reader);
  moved.Read(0, 1, &range);
  ExpectFramesEqual(range, MakeFrames(0, 1));
}

TEST(DatasetWriter, ByteIdenticalForIdenticalInput) {
  const fs::path dir = testing::CreateTestDir();
  WriteDataset(dir / "a.h5", 1000, 100);
  WriteDataset(dir / "b.h5", 1000, 333);  // other block sizes, same bytes
  const std::string a = ReadFile(dir / "a.h5");
  const std::string b = ReadFile(dir / "b.h5");
  EXPECT_GT(a.size(), 1000u);
  EXPECT_TRUE(a == b) << "files differ (timestamps or uninitialised bytes?)";
}

// ---- Bad files.

TEST(DatasetReader, MissingAndTruncatedFiles) {
  const fs::path dir = testing::CreateTestDir();
  EXPECT_THAT(
      testing::ErrorMessage<IoError>([&] { DatasetReader r(dir / "no.h5"); }),
      HasSubstr("no.h5: no such file"));

  WriteDataset(dir / "full.h5", 2000, 500);
  const std::string bytes = ReadFile(dir / "full.h5");
  for (size_t keep :
       {bytes.size() / 2, bytes.size() - 100, size_t{1000}, size_t{10}}) {
    const fs::path cut = dir / fmt::format("cut_{}.h5", keep);
    WriteFileAtomic(cut, std::string_view(bytes).substr(0, keep));
    const std::string message =
        testing::ErrorMessage<IoError>([&] { DatasetReader r(cut); });
    EXPECT_THAT(message, HasSubstr(cut.string())) << keep;
    EXPECT_THAT(message, HasSubstr("truncated or corrupt")) << keep;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  }
  WriteFileAtomic(dir / "text.h5", "this is not HDF5\n");
  EXPECT_THAT(
      testing::ErrorMessage<IoError>([&] { DatasetReader r(dir / "text.h5"); }),
      HasSubstr("not a readable HDF5 file"));
}

/// Writes HDF5 files with a chosen (wrong) schema through the C API.
class RawFile {
 public:
  explicit RawFile(const fs::path& path) {
    file_ = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    EXPECT_GE(file_, 0);
  }
  ~RawFile() { H5Fclose(file_); }

  void StringAttr(const char* name, const std::string& value) {
    hid_t type = H5Tcopy(H5T_C_S1);
    H5Tset_size(type, H5T_VARIABLE);
    hid_t space = H5Screate(H5S_SCALAR);
    hid_t attr = H5Acreate2(file_, name, type, space, H5P_DEFAULT, H5P_DEFAULT);
    const char* data = value.c_str();
    H5Awrite(attr, type, &data);
    H5Aclose(attr);
    H5Sclose(space);
    H5Tclose(type);
  }
  void LabelsAttr(const std::vector<std::string>& labels) {
    hid_t type = H5Tcopy(H5T_C_S1);
    H5Tset_size(type, H5T_VARIABLE);
    const hsize_t dims[1] = {labels.size()};
    hid_t space = H5Screate_simple(1, dims, nullptr);
    hid_t attr =
        H5Acreate2(file_, "labels", type, space, H5P_DEFAULT, H5P_DEFAULT);
    std::vector<const char*> pointers;
    for (const auto& l : labels) pointers.push_back(l.c_str());
    H5Awrite(attr, type, pointers.data());
    H5Aclose(attr);
    H5Sclose(space);
    H5Tclose(type);
  }
  void IntAttr(const char* name, int64_t value) {
    hid_t space = H5Screate(H5S_SCALAR);
    hid_t attr =
        H5Acreate2(file_, name, H5T_STD_I64LE, space, H5P_DEFAULT, H5P_DEFAULT);
    H5Awrite(attr, H5T_NATIVE_INT64, &value);
    H5Aclose(attr);
    H5Sclose(space);
  }
  void DoubleAttr(const char* name, double value) {
    hid_t space = H5Screate(H5S_SCALAR);
    hid_t attr = H5Acreate2(
        file_, name, H5T_IEEE_F64LE, space, H5P_DEFAULT, H5P_DEFAULT);
    H5Awrite(attr, H5T_NATIVE_DOUBLE, &value);
    H5Aclose(attr);
    H5Sclose(space);
  }
  /// A dataset of `dims` filled with `value` converted from int16/float.
  void Dataset(const char* name,
               const std::vector<hsize_t>& dims,
               hid_t file_type,
               double value) {
    hsize_t count = 1;
    for (hsize_t d : dims) count *= d;
    std::vector<double> data(count, value);
    hid_t space =
        H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr);
    hid_t dataset = H5Dcreate2(
        file_, name, file_type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    H5Dwrite(
        dataset, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, data.data());
    H5Dclose(dataset);
    H5Sclose(space);
  }

  /// Everything a valid dataset of F frames, N = 2, L = 2 has, except what
  /// the test leaves out.
  void Standard(const std::set<std::string>& skip = {}) {
    if (!skip.count("format")) StringAttr("format", "soma-dataset");
    if (!skip.count("format_version")) IntAttr("format_version", 1);
    if (!skip.count("labels")) LabelsAttr({"A", "B"});
    if (!skip.count("num_labels")) IntAttr("num_labels", 2);
    if (!skip.count("num_points")) IntAttr("num_points", 2);
    if (!skip.count("frame_rate")) DoubleAttr("frame_rate", 30.0);
    if (!skip.count("seed")) IntAttr("seed", 0);
    if (!skip.count("config")) StringAttr("config", "");
    if (!skip.count("code_version")) StringAttr("code_version", "");
    if (!skip.count("points")) Dataset("points", {4, 2, 3}, H5T_IEEE_F32LE, 1);
    if (!skip.count("labels_ds")) Dataset("labels", {4, 2}, H5T_STD_I16LE, 1);
  }

 private:
  hid_t file_ = -1;
};

TEST(DatasetReader, WrongSchemaErrors) {
  const fs::path dir = testing::CreateTestDir();
  int index = 0;
  // Writes a file with `make`, opens it and returns the error message.
  auto open_error = [&](const std::function<void(RawFile&)>& make) {
    const fs::path path = dir / fmt::format("bad_{}.h5", index++);
    {
      RawFile file(path);
      make(file);
    }
    const std::string message =
        testing::ErrorMessage<IoError>([&] { DatasetReader r(path); });
    EXPECT_THAT(message, HasSubstr(path.string()));
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
    return message;
  };

  // The raw writer itself produces a valid file.
  {
    RawFile file(dir / "good.h5");
    file.Standard();
  }
  {
    DatasetReader good(dir / "good.h5");
    EXPECT_EQ(good.num_frames(), 4);
    LabeledFrames frames;
    good.Read(0, 4, &frames);
    EXPECT_EQ(frames.labels, std::vector<int16_t>(8, 1));
  }

  EXPECT_THAT(
      open_error([](RawFile& f) { f.Standard({"format"}); }),
      HasSubstr("missing attribute 'format' (expected 'soma-dataset')"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.StringAttr("format", "other-format");
                f.Standard({"format"});
              }),
              HasSubstr("'format' is 'other-format', expected 'soma-dataset'"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.IntAttr("format_version", 2);
                f.Standard({"format_version"});
              }),
              HasSubstr("format_version is 2, this build reads version 1"));
  EXPECT_THAT(open_error([](RawFile& f) { f.Standard({"labels"}); }),
              HasSubstr("missing attribute 'labels'"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.IntAttr("num_labels", 3);
                f.Standard({"num_labels"});
              }),
              HasSubstr("num_labels = 3 but 'labels' has 2 names"));
  EXPECT_THAT(open_error([](RawFile& f) { f.Standard({"points"}); }),
              HasSubstr("missing dataset '/points'"));
  EXPECT_THAT(open_error([](RawFile& f) { f.Standard({"labels_ds"}); }),
              HasSubstr("missing dataset '/labels'"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.Dataset("points", {4, 6}, H5T_IEEE_F32LE, 0);
                f.Standard({"points"});
              }),
              HasSubstr("'/points' has rank 2, expected 3 (F x 2 x 3)"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.Dataset("points", {4, 3, 3}, H5T_IEEE_F32LE, 0);
                f.Standard({"points"});
              }),
              HasSubstr("'/points' has shape 4 x 3 x 3, expected F x 2 x 3"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.Dataset("points", {4, 2, 3}, H5T_IEEE_F64LE, 0);
                f.Standard({"points"});
              }),
              HasSubstr("'/points' has the wrong element type, expected "
                        "float32"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.Dataset("labels", {4, 2}, H5T_STD_I32LE, 0);
                f.Standard({"labels_ds"});
              }),
              HasSubstr("'/labels' has the wrong element type, expected "
                        "int16"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.Dataset("labels", {4, 2}, H5T_STD_U16LE, 0);
                f.Standard({"labels_ds"});
              }),
              HasSubstr("expected int16"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.Dataset("labels", {5, 2}, H5T_STD_I16LE, 0);
                f.Standard({"labels_ds"});
              }),
              HasSubstr("'/points' has 4 frames but '/labels' has 5"));
  EXPECT_THAT(open_error([](RawFile& f) {
                f.IntAttr("num_frames", 7);
                f.Standard();
              }),
              HasSubstr("num_frames = 7 but the datasets hold 4 frames"));

  // Labels outside [0, L] are found when the frames are read.
  for (double bad : {3.0, -1.0}) {
    const fs::path path = dir / fmt::format("label_{}.h5", index++);
    {
      RawFile file(path);
      file.Dataset("labels", {4, 2}, H5T_STD_I16LE, bad);
      file.Standard({"labels_ds"});
    }
    DatasetReader reader(path);
    LabeledFrames frames;
    const std::string message =
        testing::ErrorMessage<IoError>([&] { reader.Read(0, 4, &frames); });
    EXPECT_THAT(message, HasSubstr(path.string()));
    EXPECT_THAT(message,
                HasSubstr(fmt::format("label {} at frame 0 point 0 is "
                                      "outside [0, 2]",
                                      static_cast<int>(bad))));
  }
}

// ---- Python h5py interoperability.

/// A Python interpreter that imports h5py and numpy: $SOMA_PYTHON, else
/// `python3` on PATH, else Debian's /usr/bin/python3 (python3-h5py); empty
/// if none does.
std::string PythonWithH5py() {
  std::vector<std::string> candidates;
  if (const char* env = std::getenv("SOMA_PYTHON")) candidates.push_back(env);
  candidates.push_back("python3");
  candidates.push_back("/usr/bin/python3");
  for (const std::string& python : candidates) {
    const std::string command =
        "'" + python + "' -c 'import h5py, numpy' >/dev/null 2>&1";
    if (std::system(command.c_str()) == 0) return python;
  }
  return "";
}

int RunPython(const std::string& python,
              const fs::path& dir,
              const std::string& script,
              const std::string& arg) {
  WriteFileAtomic(dir / "script.py", script);
  const std::string command =
      "'" + python + "' '" + (dir / "script.py").string() + "' '" + arg +
      "' > '" + (dir / "python.log").string() + "' 2>&1";
  const int status = std::system(command.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(DatasetPython, H5pyReadsWhatWeWrite) {
  const std::string python = PythonWithH5py();
  if (python.empty()) GTEST_SKIP() << "no python3 with h5py + numpy";
  const fs::path dir = testing::CreateTestDir();
  WriteDataset(dir / "data.h5", 200, 50);
  const std::string script = R"(
import sys, h5py, numpy as np
with h5py.File(sys.argv[1], "r") as f:
    a = f.attrs
    assert a["format"] == "soma-dataset", a["format"]
    assert int(a["format_version"]) == 1
    assert list(a["labels"]) == ["C7", "LFHD", "RFHD"], list(a["labels"])
    assert int(a["num_labels"]) == 3 and int(a["num_points"]) == 5
    assert int(a["num_frames"]) == 200
    assert float(a["frame_rate"]) == 120.0
    assert int(a["seed"]) == 1234567890123
    assert a["config"] == "task:\n  name: synth\n"
    assert a["code_version"] == "v0.1-test" and a["noise"] == "b_c_g"
    p, l = f["points"], f["labels"]
    assert p.shape == (200, 5, 3) and p.dtype == np.float32, (p.shape, p.dtype)
    assert l.shape == (200, 5) and l.dtype == np.int16, (l.shape, l.dtype)
    assert p.compression == "gzip" and p.shuffle and p.chunks[1:] == (5, 3)
    P, L = p[:], l[:]
    f_idx, p_idx = np.meshgrid(np.arange(200), np.arange(5), indexing="ij")
    missing = (f_idx * 5 + p_idx) % 7 == 0
    exp_l = np.where(missing, 3, (f_idx + p_idx) % 4).astype(np.int16)
    exp_p = np.stack([f_idx.astype(np.float32) + np.float32(0.001) * p_idx.astype(np.float32),
                      -p_idx.astype(np.float32),
                      np.float32(0.5) * (p_idx % 3).astype(np.float32)], -1)
    exp_p[missing] = 0
    assert np.array_equal(L, exp_l)
    assert np.array_equal(P, exp_p.astype(np.float32)), np.abs(P - exp_p).max()
print("ok")
)";
  EXPECT_EQ(RunPython(python, dir, script, (dir / "data.h5").string()), 0)
      << ReadFile(dir / "python.log");
}

TEST(DatasetPython, WeReadWhatH5pyWrites) {
  const std::string python = PythonWithH5py();
  if (python.empty()) GTEST_SKIP() << "no python3 with h5py + numpy";
  const fs::path dir = testing::CreateTestDir();
  const std::string script = R"(
import sys, h5py, numpy as np
F, N = 150, 5
f_idx, p_idx = np.meshgrid(np.arange(F), np.arange(N), indexing="ij")
points = np.stack([f_idx, -p_idx, 0.5 * (p_idx % 3)], -1).astype(np.float32)
labels = ((f_idx + p_idx) % 4).astype(np.int16)
with h5py.File(sys.argv[1], "w") as f:
    f.attrs["format"] = "soma-dataset"
    f.attrs["format_version"] = np.int32(1)
    f.attrs["labels"] = ["C7", "LFHD", "RFHD"]
    f.attrs["num_labels"] = np.int32(3)
    f.attrs["num_points"] = np.int32(N)
    f.attrs["num_frames"] = np.int64(F)
    f.attrs["frame_rate"] = 60.0
    f.attrs["seed"] = np.uint64(7)
    f.attrs["config"] = "seed: 7\n"
    f.attrs["code_version"] = "python"
    f.attrs["origin"] = "h5py"
    f.create_dataset("points", data=points, chunks=(64, N, 3), maxshape=(None, N, 3),
                     compression="gzip", shuffle=True)
    f.create_dataset("labels", data=labels, chunks=(64, N), maxshape=(None, N),
                     compression="gzip", shuffle=True)
)";
  ASSERT_EQ(RunPython(python, dir, script, (dir / "py.h5").string()), 0)
      << ReadFile(dir / "python.log");
  DatasetReader reader(dir / "py.h5");
  EXPECT_EQ(reader.num_frames(), 150);
  EXPECT_EQ(reader.info().labels,
            (std::vector<std::string>{"C7", "LFHD", "RFHD"}));
  EXPECT_EQ(reader.info().frame_rate, 60.0);
  EXPECT_EQ(reader.info().seed, 7u);
  EXPECT_EQ(reader.info().config_yaml, "seed: 7\n");
  EXPECT_EQ(reader.info().attributes.at("origin"), "h5py");
  LabeledFrames frames;
  reader.ReadIndices({149, 0, 77}, &frames);
  const int64_t expect_f[3] = {149, 0, 77};
  for (int k = 0; k < 3; ++k) {
    for (int p = 0; p < kPoints; ++p) {
      EXPECT_EQ(frames.frame_points(k)[3 * p], static_cast<float>(expect_f[k]));
      EXPECT_EQ(frames.frame_points(k)[3 * p + 1], -static_cast<float>(p));
      EXPECT_EQ(frames.frame_labels(k)[p], (expect_f[k] + p) % 4);
    }
  }
}

}  // namespace
}  // namespace soma
