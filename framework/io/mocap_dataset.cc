// The HDF5 dataset format (docs/dataset_format.md), written and read with the
// HDF5 C API. HDF5's automatic error printing is switched off; every failure
// becomes one IoError naming the file and what was expected.
#include "framework/io/mocap_dataset.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/io/hdf5_util.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstring>
#include <mutex>
#include <numeric>
#include <set>
#include <system_error>
#include <utility>
#include <zlib.h>

namespace soma {

void LabeledFrames::Resize(int64_t frames, int points_per_frame) {
  if (frames < 0 || points_per_frame < 0) {
    throw ShapeError(fmt::format(
        "LabeledFrames::Resize: frames = {} and points_per_frame = {} must "
        "be >= 0",
        frames,
        points_per_frame));
  }
  num_points = points_per_frame;
  points.resize(static_cast<size_t>(frames * points_per_frame * 3));
  labels.resize(static_cast<size_t>(frames * points_per_frame));
  slots.resize(static_cast<size_t>(frames * num_slots));
}

void LabeledFrames::Append(const LabeledFrames& other) {
  if (other.num_frames() == 0 && other.labels.empty()) return;
  if (num_frames() == 0 && labels.empty()) {
    num_points = other.num_points;
    num_slots = other.num_slots;
  } else if (other.num_slots != num_slots) {
    throw ShapeError(fmt::format(
        "LabeledFrames::Append: frames with {} label slots appended to frames "
        "with {} label slots",
        other.num_slots,
        num_slots));
  } else if (other.num_points != num_points) {
    throw ShapeError(fmt::format(
        "LabeledFrames::Append: frames with {} points appended to frames "
        "with {} points",
        other.num_points,
        num_points));
  }
  points.insert(points.end(), other.points.begin(), other.points.end());
  labels.insert(labels.end(), other.labels.begin(), other.labels.end());
  slots.insert(slots.end(), other.slots.begin(), other.slots.end());
}

namespace {

constexpr const char* kFormatName = "soma-dataset";
constexpr int kFormatVersion = 1;
constexpr int kDeflateLevel = 4;
constexpr int kChunkFrames = 64;
constexpr size_t kMaxChunkBytes = size_t{1} << 20;

/// The attribute names the format defines; free-form attributes may not use
/// them (created_by is written from DatasetInfo::attributes).
const std::set<std::string>& ReservedAttributes() {
  static const std::set<std::string> names = {"format",
                                              "format_version",
                                              "labels",
                                              "num_labels",
                                              "num_points",
                                              "num_frames",
                                              "frame_rate",
                                              "seed",
                                              "config",
                                              "code_version",
                                              "chunk_frames",
                                              "num_slots",
                                              "slot_names",
                                              "slot_layouts"};
  return names;
}

using hdf5::Check;
using hdf5::CheckStatus;
using hdf5::Hdf5Mutex;
using hdf5::Hid;
using hdf5::ReadNumberAttribute;
using hdf5::ReadStringArrayAttribute;
using hdf5::ReadStringAttribute;
using hdf5::ReadStrings;
using hdf5::WriteNumberAttribute;
using hdf5::WriteStringArrayAttribute;
using hdf5::WriteStringAttribute;

/// Schema errors: "<file>: not a valid soma dataset: <what>".
std::string Bad(const std::string& file, const std::string& what) {
  return hdf5::InvalidFilePrefix(file, "soma dataset") + what;
}

Hid OpenDataset(hid_t file_id,
                const char* name,
                const std::string& file,
                int rank,
                const std::vector<hsize_t>& fixed_dims,  // dims 1..rank-1
                H5T_class_t type_class,
                size_t type_size,
                const char* expected_type,
                hsize_t* frames) {
  if (H5Lexists(file_id, name, H5P_DEFAULT) <= 0) {
    throw IoError(Bad(file, fmt::format("missing dataset '/{}'", name)));
  }
  Hid dapl = Check(H5Pcreate(H5P_DATASET_ACCESS), H5Pclose, file);
  H5Pset_chunk_cache(dapl.get(), 521, size_t{8} << 20, 1.0);
  Hid dataset =
      Check(H5Dopen2(file_id, name, dapl.get()),
            H5Dclose,
            Bad(file, fmt::format("'/{}' is not a readable dataset", name)));
  Hid space = Check(H5Dget_space(dataset.get()), H5Sclose, file);
  const int actual_rank = H5Sget_simple_extent_ndims(space.get());
  std::string expected_shape = "F";
  for (hsize_t d : fixed_dims) expected_shape += fmt::format(" x {}", d);
  if (actual_rank != rank) {
    throw IoError(Bad(file,
                      fmt::format("dataset '/{}' has rank {}, expected {} "
                                  "({})",
                                  name,
                                  actual_rank,
                                  rank,
                                  expected_shape)));
  }
  std::vector<hsize_t> dims(rank);
  H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
  for (int d = 1; d < rank; ++d) {
    if (dims[d] != fixed_dims[d - 1]) {
      std::string actual = fmt::format("{}", dims[0]);
      for (int e = 1; e < rank; ++e) actual += fmt::format(" x {}", dims[e]);
      throw IoError(Bad(file,
                        fmt::format("dataset '/{}' has shape {}, expected {}",
                                    name,
                                    actual,
                                    expected_shape)));
    }
  }
  Hid type = Check(H5Dget_type(dataset.get()), H5Tclose, file);
  if (H5Tget_class(type.get()) != type_class ||
      H5Tget_size(type.get()) != type_size ||
      (type_class == H5T_INTEGER && H5Tget_sign(type.get()) != H5T_SGN_2)) {
    throw IoError(Bad(file,
                      fmt::format("dataset '/{}' has the wrong element type, "
                                  "expected {}",
                                  name,
                                  expected_type)));
  }
  *frames = dims[0];
  return dataset;
}

/// ShapeError unless `info`'s slot table fits frames of info.num_slots slots:
/// rows of the declared width, a name and a layout per row, layouts in
/// range, names without newlines (stored joined by them), L == S.
void CheckSlotTable(const DatasetInfo& info, const std::string& file) {
  const SlotTable& table = info.slot_table;
  auto fail = [&](const std::string& what) {
    throw ShapeError(fmt::format("{}: slot table: {}", file, what));
  };
  if (info.num_slots < 0) {
    fail(fmt::format("num_slots = {}, expected >= 0", info.num_slots));
  }
  if (info.num_labels() != info.num_slots) {
    fail(
        fmt::format("{} labels for {} slots (the labels of slotted frames "
                    "are slot indices)",
                    info.num_labels(),
                    info.num_slots));
  }
  const int64_t rows = table.num_rows();
  if (table.width < 1 || rows < 1 ||
      static_cast<int64_t>(table.rows.size()) != rows * table.width) {
    fail(fmt::format("{} values for width {}, expected rows x width >= 1",
                     table.rows.size(),
                     table.width));
  }
  if (rows > 32767) {
    fail(fmt::format("{} rows do not fit int16 slot rows", rows));
  }
  if (static_cast<int64_t>(table.names.size()) != rows ||
      static_cast<int64_t>(table.row_layout.size()) != rows) {
    fail(fmt::format("{} rows, {} names, {} row layouts",
                     rows,
                     table.names.size(),
                     table.row_layout.size()));
  }
  for (int64_t g = 0; g < rows; ++g) {
    const int k = table.row_layout[g];
    if (k < 0 || k >= static_cast<int>(table.layouts.size())) {
      fail(fmt::format(
          "row {} has layout {}, outside [0, {})", g, k, table.layouts.size()));
    }
    if (table.names[g].find('\n') != std::string::npos) {
      fail(fmt::format("row {} has a name with a newline", g));
    }
  }
}

}  // namespace

// ---- DatasetWriter.

struct DatasetWriter::Impl {
  std::filesystem::path path;
  std::filesystem::path temp;
  DatasetInfo info;
  std::string name;  // for messages
  Hid file;
  Hid points;
  Hid labels;
  Hid slots;  // only with num_slots > 0
  int chunk_frames = kChunkFrames;
  LabeledFrames buffer;  // < chunk_frames frames not yet written
  int64_t written = 0;   // frames in the file
  bool closed = false;

  // Chunks are filtered here (byte shuffle + zlib, exactly what HDF5's
  // shuffle and deflate filters produce, so any HDF5 reader decodes them) and
  // written with H5Dwrite_chunk: one persistent z_stream and buffers instead
  // of HDF5's per-chunk filter allocations, which cost 2-3x the compression.
  z_stream zlib{};
  bool zlib_ready = false;
  std::vector<uint8_t> staging;     // one chunk, zero-padded
  std::vector<uint8_t> shuffled;    // one chunk, byte-shuffled
  std::vector<uint8_t> compressed;  // deflateBound of one chunk

  /// Shuffles and compresses `bytes` bytes of `element_size`-byte elements
  /// from `staging` into `compressed`; returns the compressed size.
  size_t Filter(size_t bytes, size_t element_size) {
    const size_t elements = bytes / element_size;
    shuffled.resize(bytes);
    for (size_t j = 0; j < element_size; ++j) {
      uint8_t* out = shuffled.data() + j * elements;
      const uint8_t* in = staging.data() + j;
      for (size_t i = 0; i < elements; ++i) out[i] = in[i * element_size];
    }
    if (!zlib_ready) {
      if (deflateInit(&zlib, kDeflateLevel) != Z_OK) {
        throw IoError(fmt::format("{}: zlib initialisation failed", name));
      }
      zlib_ready = true;
    } else if (deflateReset(&zlib) != Z_OK) {
      throw IoError(fmt::format("{}: zlib reset failed", name));
    }
    compressed.resize(deflateBound(&zlib, bytes));
    zlib.next_in = shuffled.data();
    zlib.avail_in = static_cast<uInt>(bytes);
    zlib.next_out = compressed.data();
    zlib.avail_out = static_cast<uInt>(compressed.size());
    if (deflate(&zlib, Z_FINISH) != Z_STREAM_END) {
      throw IoError(fmt::format("{}: zlib compression failed", name));
    }
    return compressed.size() - zlib.avail_out;
  }

  /// Writes one chunk of `dataset` (frames x `width` elements of
  /// `element_size` bytes per frame, rank 2 or 3) at frame `begin`: `bytes`
  /// bytes of `data`, zero-padded to a full chunk, and extends the dataset
  /// to `total` frames.
  void WriteDatasetChunk(hid_t dataset,
                         const std::vector<hsize_t>& frame_dims,
                         size_t element_size,
                         hsize_t begin,
                         hsize_t total,
                         const void* data,
                         size_t bytes,
                         const std::string& what) {
    size_t frame_elements = 1;
    for (const hsize_t d : frame_dims) frame_elements *= d;
    std::vector<hsize_t> dims = {total};
    dims.insert(dims.end(), frame_dims.begin(), frame_dims.end());
    CheckStatus(H5Dset_extent(dataset, dims.data()), what);
    staging.assign(
        static_cast<size_t>(chunk_frames) * frame_elements * element_size, 0);
    std::memcpy(staging.data(), data, bytes);
    const size_t size = Filter(staging.size(), element_size);
    std::vector<hsize_t> offset(dims.size(), 0);
    offset[0] = begin;
    CheckStatus(
        H5Dwrite_chunk(
            dataset, H5P_DEFAULT, 0, offset.data(), size, compressed.data()),
        what);
  }

  /// Writes one chunk: `count` <= chunk_frames frames at frame `written`
  /// (a multiple of chunk_frames), zero-padded to a full chunk.
  void WriteChunk(const float* p,
                  const int16_t* l,
                  const int16_t* sl,
                  int64_t count) {
    const hsize_t n = static_cast<hsize_t>(info.num_points);
    const hsize_t begin = static_cast<hsize_t>(written);
    const hsize_t total = begin + static_cast<hsize_t>(count);
    const std::string what = fmt::format("{}: write failed", name);
    const size_t frames = static_cast<size_t>(count);
    WriteDatasetChunk(
        points.get(), {n, 3}, 4, begin, total, p, frames * n * 3 * 4, what);
    WriteDatasetChunk(
        labels.get(), {n}, 2, begin, total, l, frames * n * 2, what);
    if (info.num_slots > 0) {
      const hsize_t s = static_cast<hsize_t>(info.num_slots);
      WriteDatasetChunk(
          slots.get(), {s}, 2, begin, total, sl, frames * s * 2, what);
    }
    written = static_cast<int64_t>(total);
  }

  void WriteFrames(const float* p,
                   const int16_t* l,
                   const int16_t* sl,
                   int64_t count) {
    const int64_t n = info.num_points;
    const int64_t s = info.num_slots;
    for (int64_t f = 0; f < count; f += chunk_frames) {
      WriteChunk(p + f * n * 3,
                 l + f * n,
                 s > 0 ? sl + f * s : nullptr,
                 std::min<int64_t>(chunk_frames, count - f));
    }
  }

  void FlushBuffer() {
    WriteFrames(buffer.points.data(),
                buffer.labels.data(),
                buffer.slots.data(),
                buffer.num_frames());
    buffer.points.clear();
    buffer.labels.clear();
    buffer.slots.clear();
  }

  ~Impl() {
    if (zlib_ready) deflateEnd(&zlib);
  }

  void Abandon() {
    buffer.points.clear();
    buffer.labels.clear();
    buffer.slots.clear();
    points.Reset();
    labels.Reset();
    slots.Reset();
    file.Reset();
    std::error_code ec;
    std::filesystem::remove(temp, ec);
  }
};

DatasetWriter::DatasetWriter(const std::filesystem::path& path,
                             const DatasetInfo& info)
    : impl_(std::make_unique<Impl>()) {
  std::lock_guard lock(Hdf5Mutex());
  Impl& s = *impl_;
  s.path = path;
  s.temp = TempPathFor(path);
  s.info = info;
  s.name = path.string();
  if (info.num_points < 1) {
    throw ShapeError(fmt::format("{}: a dataset needs num_points >= 1 (got {})",
                                 s.name,
                                 info.num_points));
  }
  if (info.num_labels() > 32767) {
    throw ShapeError(fmt::format(
        "{}: {} labels do not fit int16 label ids", s.name, info.num_labels()));
  }
  if (info.num_slots != 0) CheckSlotTable(info, s.name);
  for (const auto& [key, value] : info.attributes) {
    if (ReservedAttributes().count(key) > 0 || key.empty()) {
      throw IoError(fmt::format(
          "{}: attribute name '{}' is reserved by the dataset format",
          s.name,
          key));
    }
  }
  const size_t frame_bytes = static_cast<size_t>(info.num_points) * 12;
  s.chunk_frames = static_cast<int>(std::clamp<size_t>(
      kMaxChunkBytes / frame_bytes, 1, static_cast<size_t>(kChunkFrames)));
  s.buffer.num_points = info.num_points;
  s.buffer.num_slots = info.num_slots;
  s.buffer.points.reserve(static_cast<size_t>(s.chunk_frames) * frame_bytes /
                          sizeof(float));
  s.buffer.labels.reserve(static_cast<size_t>(s.chunk_frames) *
                          static_cast<size_t>(info.num_points));

  // No timestamps anywhere: the same input gives the same bytes.
  Hid fcpl = Check(H5Pcreate(H5P_FILE_CREATE), H5Pclose, s.name);
  H5Pset_obj_track_times(fcpl.get(), false);
  s.file =
      Check(H5Fcreate(s.temp.c_str(), H5F_ACC_TRUNC, fcpl.get(), H5P_DEFAULT),
            H5Fclose,
            fmt::format("{}: cannot create the dataset file (is the directory "
                        "missing or not writable?)",
                        s.name));
  try {
    const hid_t root = s.file.get();
    const hsize_t n = static_cast<hsize_t>(info.num_points);
    const hsize_t chunk = static_cast<hsize_t>(s.chunk_frames);
    const std::string what = fmt::format("{}: cannot create datasets", s.name);
    if (H5Zfilter_avail(H5Z_FILTER_DEFLATE) <= 0 ||
        H5Zfilter_avail(H5Z_FILTER_SHUFFLE) <= 0) {
      throw IoError(fmt::format(
          "{}: this HDF5 library lacks the deflate/shuffle filters", s.name));
    }
    auto make_dataset = [&](const char* name,
                            int rank,
                            const hsize_t* dims,
                            const hsize_t* max_dims,
                            const hsize_t* chunk_dims,
                            hid_t type) {
      Hid dcpl = Check(H5Pcreate(H5P_DATASET_CREATE), H5Pclose, what);
      CheckStatus(H5Pset_chunk(dcpl.get(), rank, chunk_dims), what);
      CheckStatus(H5Pset_shuffle(dcpl.get()), what);
      CheckStatus(H5Pset_deflate(dcpl.get(), kDeflateLevel), what);
      CheckStatus(H5Pset_obj_track_times(dcpl.get(), false), what);
      CheckStatus(H5Pset_fill_time(dcpl.get(), H5D_FILL_TIME_NEVER), what);
      Hid space = Check(H5Screate_simple(rank, dims, max_dims), H5Sclose, what);
      return Check(H5Dcreate2(root,
                              name,
                              type,
                              space.get(),
                              H5P_DEFAULT,
                              dcpl.get(),
                              H5P_DEFAULT),
                   H5Dclose,
                   what);
    };
    {
      const hsize_t dims[3] = {0, n, 3};
      const hsize_t max_dims[3] = {H5S_UNLIMITED, n, 3};
      const hsize_t chunk_dims[3] = {chunk, n, 3};
      s.points =
          make_dataset("points", 3, dims, max_dims, chunk_dims, H5T_IEEE_F32LE);
    }
    {
      const hsize_t dims[2] = {0, n};
      const hsize_t max_dims[2] = {H5S_UNLIMITED, n};
      const hsize_t chunk_dims[2] = {chunk, n};
      s.labels =
          make_dataset("labels", 2, dims, max_dims, chunk_dims, H5T_STD_I16LE);
    }
    if (info.num_slots > 0) {
      const hsize_t slots = static_cast<hsize_t>(info.num_slots);
      {
        const hsize_t dims[2] = {0, slots};
        const hsize_t max_dims[2] = {H5S_UNLIMITED, slots};
        const hsize_t chunk_dims[2] = {chunk, slots};
        s.slots =
            make_dataset("slots", 2, dims, max_dims, chunk_dims, H5T_STD_I16LE);
      }
      // The slot table: small, written once through HDF5's own filters.
      const SlotTable& table = info.slot_table;
      const hsize_t rows = static_cast<hsize_t>(table.num_rows());
      const hsize_t width = static_cast<hsize_t>(table.width);
      {
        const hsize_t dims[2] = {rows, width};
        Hid descriptors = make_dataset(
            "slot_descriptors", 2, dims, dims, dims, H5T_IEEE_F32LE);
        CheckStatus(H5Dwrite(descriptors.get(),
                             H5T_NATIVE_FLOAT,
                             H5S_ALL,
                             H5S_ALL,
                             H5P_DEFAULT,
                             table.rows.data()),
                    what);
      }
      {
        const hsize_t dims[1] = {rows};
        Hid layout =
            make_dataset("slot_layout", 1, dims, dims, dims, H5T_STD_I32LE);
        const std::vector<int32_t> values(table.row_layout.begin(),
                                          table.row_layout.end());
        CheckStatus(H5Dwrite(layout.get(),
                             H5T_NATIVE_INT32,
                             H5S_ALL,
                             H5S_ALL,
                             H5P_DEFAULT,
                             values.data()),
                    what);
      }
      WriteNumberAttribute<int32_t>(root, "num_slots", info.num_slots, s.name);
      // One string (names joined by newlines): an attribute of thousands of
      // strings would exceed HDF5's 64 KiB compact attribute limit.
      WriteStringAttribute(root,
                           "slot_names",
                           fmt::format("{}", fmt::join(table.names, "\n")),
                           s.name);
      WriteStringArrayAttribute(root, "slot_layouts", table.layouts, s.name);
    }

    WriteStringAttribute(root, "format", kFormatName, s.name);
    WriteNumberAttribute<int32_t>(
        root, "format_version", kFormatVersion, s.name);
    WriteStringArrayAttribute(root, "labels", info.labels, s.name);
    WriteNumberAttribute<int32_t>(
        root, "num_labels", info.num_labels(), s.name);
    WriteNumberAttribute<int32_t>(root, "num_points", info.num_points, s.name);
    WriteNumberAttribute<int64_t>(root, "num_frames", int64_t{0}, s.name);
    WriteNumberAttribute<double>(root, "frame_rate", info.frame_rate, s.name);
    WriteNumberAttribute<uint64_t>(root, "seed", info.seed, s.name);
    WriteNumberAttribute<int32_t>(root, "chunk_frames", s.chunk_frames, s.name);
    WriteStringAttribute(root, "config", info.config_yaml, s.name);
    WriteStringAttribute(root, "code_version", info.code_version, s.name);
    std::map<std::string, std::string> extra = info.attributes;
    extra.emplace("created_by", "somalab");
    for (const auto& [key, value] : extra) {
      WriteStringAttribute(root, key, value, s.name);
    }
  } catch (...) {
    s.Abandon();
    throw;
  }
}

DatasetWriter::~DatasetWriter() {
  if (impl_ && !impl_->closed) {
    std::lock_guard lock(Hdf5Mutex());
    impl_->Abandon();
  }
}

void DatasetWriter::Append(const LabeledFrames& frames) {
  Impl& s = *impl_;
  if (s.closed) {
    throw IoError(fmt::format("{}: Append after Close", s.name));
  }
  const int64_t count = frames.num_frames();
  if (count == 0) return;
  if (frames.num_slots != s.info.num_slots) {
    throw ShapeError(fmt::format(
        "{}: appended frames have {} label slots per frame, the dataset {} "
        "(DatasetInfo::num_slots; slots come from synth.layout_sampler)",
        s.name,
        frames.num_slots,
        s.info.num_slots));
  }
  if (frames.num_points != s.info.num_points) {
    throw ShapeError(
        fmt::format("{}: appended frames have {} points, the dataset has {}",
                    s.name,
                    frames.num_points,
                    s.info.num_points));
  }
  const int64_t n = frames.num_points;
  if (static_cast<int64_t>(frames.points.size()) != count * n * 3) {
    throw ShapeError(
        fmt::format("{}: appended frames have {} coordinates, expected "
                    "{} frames x {} points x 3",
                    s.name,
                    frames.points.size(),
                    count,
                    n));
  }
  const int null_label = s.info.num_labels();
  for (size_t i = 0; i < frames.labels.size(); ++i) {
    const int16_t label = frames.labels[i];
    if (label < 0 || label > null_label) {
      throw ShapeError(
          fmt::format("{}: label {} at frame {} point {} is outside [0, {}] "
                      "(L = {} is null)",
                      s.name,
                      label,
                      static_cast<int64_t>(i) / n,
                      static_cast<int64_t>(i) % n,
                      null_label,
                      null_label));
    }
  }
  const int64_t num_slots = s.info.num_slots;
  if (num_slots > 0) {
    if (static_cast<int64_t>(frames.slots.size()) != count * num_slots) {
      throw ShapeError(
          fmt::format("{}: appended frames have {} slot rows, "
                      "expected {} frames x {} slots",
                      s.name,
                      frames.slots.size(),
                      count,
                      num_slots));
    }
    const int64_t rows = s.info.slot_table.num_rows();
    for (size_t i = 0; i < frames.slots.size(); ++i) {
      const int16_t row = frames.slots[i];
      if (row < -1 || row >= rows) {
        throw ShapeError(fmt::format(
            "{}: slot row {} at frame {} slot {} is outside [-1, {}) (the "
            "slot table's rows; -1 = padded)",
            s.name,
            row,
            static_cast<int64_t>(i) / num_slots,
            static_cast<int64_t>(i) % num_slots,
            rows));
      }
    }
  }
  std::lock_guard lock(Hdf5Mutex());
  int64_t f = 0;
  const int64_t chunk = s.chunk_frames;
  // Top up a partial chunk first, then write whole chunks straight from the
  // input, then buffer the rest: every chunk is compressed exactly once.
  while (f < count) {
    const int64_t buffered = s.buffer.num_frames();
    if (buffered == 0 && count - f >= chunk) {
      const int64_t whole = (count - f) / chunk * chunk;
      s.WriteFrames(frames.frame_points(f),
                    frames.frame_labels(f),
                    num_slots > 0 ? frames.frame_slots(f) : nullptr,
                    whole);
      f += whole;
      continue;
    }
    const int64_t take = std::min(chunk - buffered, count - f);
    s.buffer.points.insert(s.buffer.points.end(),
                           frames.frame_points(f),
                           frames.frame_points(f) + take * n * 3);
    s.buffer.labels.insert(s.buffer.labels.end(),
                           frames.frame_labels(f),
                           frames.frame_labels(f) + take * n);
    if (num_slots > 0) {
      s.buffer.slots.insert(s.buffer.slots.end(),
                            frames.frame_slots(f),
                            frames.frame_slots(f) + take * num_slots);
    }
    f += take;
    if (s.buffer.num_frames() == chunk) s.FlushBuffer();
  }
}

int64_t DatasetWriter::num_frames() const {
  return impl_->written + impl_->buffer.num_frames();
}

void DatasetWriter::WritePointArray(const std::string& name,
                                    const std::vector<float>& values) {
  Impl& s = *impl_;
  std::lock_guard lock(Hdf5Mutex());
  s.FlushBuffer();
  const hsize_t f = static_cast<hsize_t>(s.written);
  const hsize_t n = static_cast<hsize_t>(s.info.num_points);
  if (values.size() != f * n) {
    throw ShapeError(fmt::format(
        "{}: point array '{}' has {} values, expected {} frames x {} points",
        s.name,
        name,
        values.size(),
        f,
        n));
  }
  if (name == "points" || name == "labels" ||
      H5Lexists(s.file.get(), name.c_str(), H5P_DEFAULT) > 0) {
    throw IoError(
        fmt::format("{}: a dataset named '{}' already exists", s.name, name));
  }
  const std::string what =
      fmt::format("{}: cannot write point array '{}'", s.name, name);
  Hid dcpl = Check(H5Pcreate(H5P_DATASET_CREATE), H5Pclose, what);
  CheckStatus(H5Pset_obj_track_times(dcpl.get(), false), what);
  const hsize_t dims[2] = {f, n};
  if (f > 0) {
    const hsize_t chunk[2] = {
        std::min<hsize_t>(f, static_cast<hsize_t>(s.chunk_frames)), n};
    CheckStatus(H5Pset_chunk(dcpl.get(), 2, chunk), what);
    CheckStatus(H5Pset_shuffle(dcpl.get()), what);
    CheckStatus(H5Pset_deflate(dcpl.get(), kDeflateLevel), what);
  }
  Hid space = Check(H5Screate_simple(2, dims, nullptr), H5Sclose, what);
  Hid dataset = Check(H5Dcreate2(s.file.get(),
                                 name.c_str(),
                                 H5T_IEEE_F32LE,
                                 space.get(),
                                 H5P_DEFAULT,
                                 dcpl.get(),
                                 H5P_DEFAULT),
                      H5Dclose,
                      what);
  if (f > 0) {
    CheckStatus(H5Dwrite(dataset.get(),
                         H5T_NATIVE_FLOAT,
                         H5S_ALL,
                         H5S_ALL,
                         H5P_DEFAULT,
                         values.data()),
                what);
  }
}

void DatasetWriter::Close() {
  Impl& s = *impl_;
  if (s.closed) return;
  std::lock_guard lock(Hdf5Mutex());
  try {
    s.FlushBuffer();
    WriteNumberAttribute<int64_t>(
        s.file.get(), "num_frames", s.written, s.name);
    const bool ok =
        s.points.Reset() & s.labels.Reset() & s.slots.Reset() & s.file.Reset();
    if (!ok) throw IoError(fmt::format("{}: closing the file failed", s.name));
    CommitTempFile(s.temp, s.path);
  } catch (...) {
    s.Abandon();
    s.closed = true;
    throw;
  }
  s.closed = true;
}

// ---- DatasetReader.

struct DatasetReader::Impl {
  std::string name;
  DatasetInfo info;
  Hid file;
  Hid points;
  Hid labels;
  Hid slots;  // only with info.num_slots > 0

  /// Reads frames [begin, begin + count) into out->frame_*(offset).
  void ReadRun(int64_t begin,
               int64_t count,
               LabeledFrames* out,
               int64_t offset) const {
    const hsize_t n = static_cast<hsize_t>(info.num_points);
    const std::string what =
        fmt::format("{}: reading frames [{}, {}) failed (corrupt file?)",
                    name,
                    begin,
                    begin + count);
    // Frames [begin, begin + count) of a dataset whose frames are `rows` x
    // `width` values (width 0: rank 2).
    auto read_frames = [&](hid_t dataset,
                           hsize_t rows,
                           hsize_t width,
                           hid_t type,
                           void* dst) {
      Hid space = Check(H5Dget_space(dataset), H5Sclose, what);
      const int rank = width > 0 ? 3 : 2;
      const hsize_t start[3] = {static_cast<hsize_t>(begin), 0, 0};
      const hsize_t size[3] = {static_cast<hsize_t>(count), rows, width};
      CheckStatus(
          H5Sselect_hyperslab(
              space.get(), H5S_SELECT_SET, start, nullptr, size, nullptr),
          what);
      Hid memory = Check(H5Screate_simple(rank, size, nullptr), H5Sclose, what);
      CheckStatus(
          H5Dread(dataset, type, memory.get(), space.get(), H5P_DEFAULT, dst),
          what);
    };
    read_frames(
        points.get(), n, 3, H5T_NATIVE_FLOAT, out->frame_points(offset));
    read_frames(
        labels.get(), n, 0, H5T_NATIVE_INT16, out->frame_labels(offset));
    if (info.num_slots > 0) {
      const int64_t num_slots = info.num_slots;
      read_frames(slots.get(),
                  static_cast<hsize_t>(num_slots),
                  0,
                  H5T_NATIVE_INT16,
                  out->frame_slots(offset));
      const int16_t* sl = out->frame_slots(offset);
      const int64_t rows = info.slot_table.num_rows();
      for (int64_t i = 0; i < count * num_slots; ++i) {
        if (sl[i] < -1 || sl[i] >= rows) {
          throw IoError(Bad(name,
                            fmt::format("slot row {} at frame {} slot {} is "
                                        "outside [-1, {})",
                                        sl[i],
                                        begin + i / num_slots,
                                        i % num_slots,
                                        rows)));
        }
      }
    }
    const int16_t null_label = static_cast<int16_t>(info.num_labels());
    const int16_t* l = out->frame_labels(offset);
    const int64_t size = count * info.num_points;
    for (int64_t i = 0; i < size; ++i) {
      if (l[i] < 0 || l[i] > null_label) {
        throw IoError(Bad(name,
                          fmt::format("label {} at frame {} point {} is "
                                      "outside [0, {}] (L = {} is null)",
                                      l[i],
                                      begin + i / info.num_points,
                                      i % info.num_points,
                                      null_label,
                                      null_label)));
      }
    }
  }
};

DatasetReader::DatasetReader(const std::filesystem::path& path)
    : impl_(std::make_unique<Impl>()) {
  std::lock_guard lock(Hdf5Mutex());
  Impl& s = *impl_;
  s.name = path.string();
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw IoError(fmt::format(
        "{}: no such file (expected a soma dataset, HDF5)", s.name));
  }
  s.file = Check(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT),
                 H5Fclose,
                 fmt::format("{}: not a readable HDF5 file (truncated or "
                             "corrupt?); expected a soma dataset",
                             s.name));
  const hid_t root = s.file.get();
  const std::string bad = Bad(s.name, "");
  if (H5Aexists(root, "format") <= 0) {
    throw IoError(Bad(s.name,
                      fmt::format("missing attribute 'format' (expected '{}')",
                                  kFormatName)));
  }
  const std::string format = ReadStringAttribute(root, "format", bad);
  if (format != kFormatName) {
    throw IoError(Bad(
        s.name,
        fmt::format(
            "attribute 'format' is '{}', expected '{}'", format, kFormatName)));
  }
  const int version = ReadNumberAttribute<int32_t>(root, "format_version", bad);
  if (version != kFormatVersion) {
    throw IoError(Bad(s.name,
                      fmt::format("format_version is {}, this build reads "
                                  "version {}",
                                  version,
                                  kFormatVersion)));
  }
  DatasetInfo& info = s.info;
  info.labels = ReadStringArrayAttribute(root, "labels", bad);
  const int num_labels = ReadNumberAttribute<int32_t>(root, "num_labels", bad);
  if (num_labels != info.num_labels()) {
    throw IoError(Bad(s.name,
                      fmt::format("num_labels = {} but 'labels' has {} names",
                                  num_labels,
                                  info.num_labels())));
  }
  info.num_points = ReadNumberAttribute<int32_t>(root, "num_points", bad);
  if (info.num_points < 1) {
    throw IoError(
        Bad(s.name,
            fmt::format("num_points = {}, expected >= 1", info.num_points)));
  }
  info.frame_rate = ReadNumberAttribute<double>(root, "frame_rate", bad);
  info.seed = ReadNumberAttribute<uint64_t>(root, "seed", bad);
  info.config_yaml = ReadStringAttribute(root, "config", bad);
  info.code_version = ReadStringAttribute(root, "code_version", bad);

  const hsize_t n = static_cast<hsize_t>(info.num_points);
  hsize_t point_frames = 0;
  hsize_t label_frames = 0;
  s.points = OpenDataset(root,
                         "points",
                         s.name,
                         3,
                         {n, 3},
                         H5T_FLOAT,
                         4,
                         "float32",
                         &point_frames);
  s.labels = OpenDataset(
      root, "labels", s.name, 2, {n}, H5T_INTEGER, 2, "int16", &label_frames);
  if (point_frames != label_frames) {
    throw IoError(
        Bad(s.name,
            fmt::format("'/points' has {} frames but '/labels' has {}",
                        point_frames,
                        label_frames)));
  }
  info.num_frames = static_cast<int64_t>(point_frames);
  if (H5Lexists(root, "slots", H5P_DEFAULT) > 0) {
    // Label slots (docs/dataset_format.md, "Label slots").
    info.num_slots = ReadNumberAttribute<int32_t>(root, "num_slots", bad);
    if (info.num_slots < 1 || info.num_slots != info.num_labels()) {
      throw IoError(Bad(s.name,
                        fmt::format("num_slots = {}, expected the number of "
                                    "labels ({})",
                                    info.num_slots,
                                    info.num_labels())));
    }
    hsize_t slot_frames = 0;
    s.slots = OpenDataset(root,
                          "slots",
                          s.name,
                          2,
                          {static_cast<hsize_t>(info.num_slots)},
                          H5T_INTEGER,
                          2,
                          "int16",
                          &slot_frames);
    if (slot_frames != point_frames) {
      throw IoError(
          Bad(s.name,
              fmt::format("'/slots' has {} frames but '/points' has {}",
                          slot_frames,
                          point_frames)));
    }
    SlotTable& table = info.slot_table;
    std::vector<hsize_t> dims;
    table.rows =
        hdf5::ReadDataset<float>(root, "slot_descriptors", {0, 0}, bad, &dims);
    table.width = static_cast<int>(dims[1]);
    const std::vector<int32_t> layouts =
        hdf5::ReadDataset<int32_t>(root, "slot_layout", {dims[0]}, bad);
    table.row_layout.assign(layouts.begin(), layouts.end());
    const std::string names = ReadStringAttribute(root, "slot_names", bad);
    size_t start = 0;
    while (dims[0] > 0) {
      const size_t end = names.find('\n', start);
      table.names.push_back(names.substr(start, end - start));
      if (end == std::string::npos) break;
      start = end + 1;
    }
    table.layouts = ReadStringArrayAttribute(root, "slot_layouts", bad);
    try {
      CheckSlotTable(info, s.name);
    } catch (const ShapeError& e) {
      throw IoError(Bad(s.name, e.what()));
    }
  }
  if (H5Aexists(root, "num_frames") > 0) {
    const int64_t declared =
        ReadNumberAttribute<int64_t>(root, "num_frames", bad);
    if (declared != info.num_frames) {
      throw IoError(Bad(s.name,
                        fmt::format("num_frames = {} but the datasets hold {} "
                                    "frames (unfinished write?)",
                                    declared,
                                    info.num_frames)));
    }
  }

  // Free-form string attributes.
  struct Collector {
    Impl* impl;
    std::vector<std::string> names;
  } collector{&s, {}};
  H5Aiterate2(
      root,
      H5_INDEX_NAME,
      H5_ITER_INC,
      nullptr,
      [](hid_t, const char* name, const H5A_info_t*, void* data) -> herr_t {
        static_cast<Collector*>(data)->names.emplace_back(name);
        return 0;
      },
      &collector);
  for (const std::string& name : collector.names) {
    if (ReservedAttributes().count(name) > 0) continue;
    Hid attr = Check(H5Aopen(root, name.c_str(), H5P_DEFAULT), H5Aclose, "");
    Hid type = Check(H5Aget_type(attr.get()), H5Tclose, s.name);
    if (H5Tget_class(type.get()) != H5T_STRING) continue;
    std::vector<std::string> values = ReadStrings(attr.get(), name, bad);
    if (values.size() == 1) info.attributes[name] = values[0];
  }
}

DatasetReader::~DatasetReader() {
  if (impl_) {
    std::lock_guard lock(Hdf5Mutex());
    impl_.reset();
  }
}
DatasetReader::DatasetReader(DatasetReader&&) noexcept = default;
DatasetReader& DatasetReader::operator=(DatasetReader&& other) noexcept {
  if (this != &other) {
    std::lock_guard lock(Hdf5Mutex());
    impl_ = std::move(other.impl_);
  }
  return *this;
}

const DatasetInfo& DatasetReader::info() const { return impl_->info; }

int64_t DatasetReader::num_frames() const { return impl_->info.num_frames; }

void DatasetReader::Read(int64_t begin,
                         int64_t count,
                         LabeledFrames* out) const {
  const Impl& s = *impl_;
  if (begin < 0 || count < 0 || begin + count > s.info.num_frames) {
    throw IoError(
        fmt::format("{}: frames [{}, {}) requested, the dataset has "
                    "frames [0, {})",
                    s.name,
                    begin,
                    begin + count,
                    s.info.num_frames));
  }
  out->num_slots = s.info.num_slots;
  out->Resize(count, s.info.num_points);
  if (count == 0) return;
  std::lock_guard lock(Hdf5Mutex());
  s.ReadRun(begin, count, out, 0);
}

std::vector<float> DatasetReader::ReadPointArray(
    const std::string& name) const {
  const Impl& s = *impl_;
  std::lock_guard lock(Hdf5Mutex());
  if (H5Lexists(s.file.get(), name.c_str(), H5P_DEFAULT) <= 0) {
    throw IoError(fmt::format("{}: no point array '{}'", s.name, name));
  }
  Hid dataset = Check(H5Dopen2(s.file.get(), name.c_str(), H5P_DEFAULT),
                      H5Dclose,
                      fmt::format("{}: cannot open '{}'", s.name, name));
  Hid space = Check(H5Dget_space(dataset.get()), H5Sclose, s.name);
  Hid type = Check(H5Dget_type(dataset.get()), H5Tclose, s.name);
  hsize_t dims[2] = {0, 0};
  const hsize_t f = static_cast<hsize_t>(s.info.num_frames);
  const hsize_t n = static_cast<hsize_t>(s.info.num_points);
  if (H5Sget_simple_extent_ndims(space.get()) != 2 ||
      H5Sget_simple_extent_dims(space.get(), dims, nullptr) != 2 ||
      dims[0] != f || dims[1] != n || H5Tget_class(type.get()) != H5T_FLOAT ||
      H5Tget_size(type.get()) != 4) {
    throw IoError(fmt::format(
        "{}: '{}' is not a {} x {} float32 point array", s.name, name, f, n));
  }
  std::vector<float> values(f * n);
  if (!values.empty()) {
    CheckStatus(H5Dread(dataset.get(),
                        H5T_NATIVE_FLOAT,
                        H5S_ALL,
                        H5S_ALL,
                        H5P_DEFAULT,
                        values.data()),
                fmt::format("{}: cannot read '{}'", s.name, name));
  }
  return values;
}

void DatasetReader::ReadIndices(const std::vector<int64_t>& indices,
                                LabeledFrames* out) const {
  const Impl& s = *impl_;
  for (int64_t index : indices) {
    if (index < 0 || index >= s.info.num_frames) {
      throw IoError(
          fmt::format("{}: frame {} requested, the dataset has frames [0, {})",
                      s.name,
                      index,
                      s.info.num_frames));
    }
  }
  // Read the distinct frames in file order, one read per run of consecutive
  // indices, then scatter into the requested order.
  std::vector<int64_t> sorted = indices;
  std::sort(sorted.begin(), sorted.end());
  sorted.erase(std::unique(sorted.begin(), sorted.end()), sorted.end());
  LabeledFrames unique;
  unique.num_slots = s.info.num_slots;
  unique.Resize(static_cast<int64_t>(sorted.size()), s.info.num_points);
  {
    std::lock_guard lock(Hdf5Mutex());
    size_t i = 0;
    while (i < sorted.size()) {
      size_t j = i + 1;
      while (j < sorted.size() && sorted[j] == sorted[j - 1] + 1) ++j;
      s.ReadRun(sorted[i],
                static_cast<int64_t>(j - i),
                &unique,
                static_cast<int64_t>(i));
      i = j;
    }
  }
  const int64_t n = s.info.num_points;
  out->num_slots = s.info.num_slots;
  out->Resize(static_cast<int64_t>(indices.size()), s.info.num_points);
  for (size_t k = 0; k < indices.size(); ++k) {
    const int64_t u =
        std::lower_bound(sorted.begin(), sorted.end(), indices[k]) -
        sorted.begin();
    std::copy_n(unique.frame_points(u),
                n * 3,
                out->frame_points(static_cast<int64_t>(k)));
    std::copy_n(
        unique.frame_labels(u), n, out->frame_labels(static_cast<int64_t>(k)));
    std::copy_n(unique.frame_slots(u),
                s.info.num_slots,
                out->frame_slots(static_cast<int64_t>(k)));
  }
}

}  // namespace soma
