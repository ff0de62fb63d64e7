// Labelled point-cloud frames and the HDF5 dataset format that stores them
// (README.md, "File formats"). One frame is N points (fixed per dataset,
// zero-padded; (0,0,0) = missing) and one label id per point (0..L-1, null =
// L). The same struct carries training batches in memory.
//
//   /points   F x N x 3 float32   chunked (frames), shuffle + deflate
//   /labels   F x N     int16     null = L
//   attrs: format ("soma-dataset"), format_version, labels (L strings),
//          num_labels, num_points, frame_rate, seed, config (YAML),
//          code_version, created_by, + free-form string attributes.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace soma {

/// F frames of N points each, frame-major.
struct LabeledFrames {
  int num_points = 0;           // N
  std::vector<float> points;    // F * N * 3, (0,0,0) = missing / padding
  std::vector<int16_t> labels;  // F * N, label id or null (= L)
  /// Label slots of a layout-conditioned stream (docs/any_layout_design.md,
  /// "The data"): S slots per frame (0 = none, the labels index the
  /// dataset's label list). Frame f's slot s is row `slots[f * S + s]` of
  /// the stream's SlotTable (-1 = a padded slot), and its labels are slot
  /// indices (null = L = S). In memory only (DatasetWriter refuses frames
  /// with slots).
  int num_slots = 0;           // S
  std::vector<int16_t> slots;  // F * S

  const int16_t* frame_slots(int64_t f) const {
    return slots.data() + f * num_slots;
  }
  int16_t* frame_slots(int64_t f) { return slots.data() + f * num_slots; }

  int64_t num_frames() const {
    return num_points == 0 ? 0
                           : static_cast<int64_t>(labels.size()) / num_points;
  }
  /// Sets N and resizes to `frames` frames (contents unspecified); the
  /// slots keep S and are resized to match.
  void Resize(int64_t frames, int points_per_frame);
  float* frame_points(int64_t f) { return points.data() + f * num_points * 3; }
  const float* frame_points(int64_t f) const {
    return points.data() + f * num_points * 3;
  }
  int16_t* frame_labels(int64_t f) { return labels.data() + f * num_points; }
  const int16_t* frame_labels(int64_t f) const {
    return labels.data() + f * num_points;
  }
  /// Appends all frames of `other` (same N and S; ShapeError otherwise).
  void Append(const LabeledFrames& other);
};

/// The descriptors of every label slot a layout-conditioned stream can use:
/// row g (Q floats, body/vertex_descriptors.h) describes marker g of the
/// stream's layouts, concatenated in order. LabeledFrames::slots index it.
struct SlotTable {
  int width = 0;                   // Q
  std::vector<float> rows;         // G * Q, row-major
  std::vector<std::string> names;  // G marker labels (for messages and logs)
  /// Per row, the layout it belongs to (index into `layouts`).
  std::vector<int> row_layout;
  std::vector<std::string> layouts;  // the layouts' names

  int64_t num_rows() const {
    return width == 0 ? 0 : static_cast<int64_t>(rows.size()) / width;
  }
};

/// Dataset-level metadata (HDF5 attributes of the root group).
struct DatasetInfo {
  std::vector<std::string> labels;  // L label names, id order
  int num_points = 0;               // N
  int64_t num_frames = 0;           // F (filled by the reader)
  double frame_rate = 30.0;         // Hz of the source motion
  uint64_t seed = 0;
  std::string config_yaml;   // composed config that produced the data
  std::string code_version;  // BuildInfo (git describe)
  std::map<std::string, std::string> attributes;  // free-form provenance
  /// Frames with label slots (a layout-sampled stream): S per frame, and the
  /// table their rows index. 0 = none (labels index `labels`).
  int num_slots = 0;
  SlotTable slot_table;

  int num_labels() const { return static_cast<int>(labels.size()); }
};

/// Streams frames into a new dataset: written to `<path>.tmp` and renamed to
/// `path` by Close(), so a crash never leaves a truncated file under the
/// final name. Memory use is bounded by one chunk.
class DatasetWriter {
 public:
  /// IoError if the directory cannot be written; ShapeError for N < 1, and
  /// for num_slots > 0 with a slot table that is empty or inconsistent, or
  /// with L != S (the labels of slotted frames are slot indices).
  DatasetWriter(const std::filesystem::path& path, const DatasetInfo& info);
  ~DatasetWriter();  // abandons (removes the temp file) if not Closed
  DatasetWriter(const DatasetWriter&) = delete;
  DatasetWriter& operator=(const DatasetWriter&) = delete;

  /// ShapeError if frames.num_points != info.num_points, a label id is
  /// outside [0, L], or the frames' slots disagree with info.num_slots or
  /// index no row of info.slot_table.
  void Append(const LabeledFrames& frames);
  int64_t num_frames() const;
  /// An extra per-point float32 dataset `/<name>` (F x N) beside points and
  /// labels, e.g. a labeller's confidences. Call after the last Append;
  /// ShapeError unless `values` has F * N entries, IoError if `name` is
  /// taken.
  void WritePointArray(const std::string& name,
                       const std::vector<float>& values);
  /// Flushes, writes num_frames, renames into place.
  void Close();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Random access to a dataset. Open validates the schema: a missing file,
/// a truncated file, a wrong format attribute or version, missing
/// datasets, wrong ranks/dtypes, or points/labels frame counts that disagree
/// are IoError naming the file and what was expected.
class DatasetReader {
 public:
  explicit DatasetReader(const std::filesystem::path& path);
  ~DatasetReader();
  DatasetReader(DatasetReader&&) noexcept;
  DatasetReader& operator=(DatasetReader&&) noexcept;

  const DatasetInfo& info() const;
  int64_t num_frames() const;
  /// Frames [begin, begin + count) into `out` (resized). IoError if out of
  /// range.
  void Read(int64_t begin, int64_t count, LabeledFrames* out) const;
  /// The frames with the given indices (any order, repeats allowed).
  void ReadIndices(const std::vector<int64_t>& indices,
                   LabeledFrames* out) const;
  /// An extra per-point dataset (DatasetWriter::WritePointArray), F * N
  /// values; IoError if absent or not F x N float32.
  std::vector<float> ReadPointArray(const std::string& name) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace soma
