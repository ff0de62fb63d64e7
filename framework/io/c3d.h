// C3D motion-capture files: a reader for every processor type (Intel, DEC,
// SGI/MIPS) and both storage formats (int16, float), and a writer (Intel,
// float). The whole parameter section is kept; points are returned in file
// units with a validity mask.
//
// File layout (https://www.c3d.org/HTML/default.htm), all in 512-byte blocks:
//   block 1           header: byte 0 = first parameter block (1-based),
//                     byte 1 = 0x50, then 16-bit words (point count, analog
//                     words per frame, first/last frame, scale, data start
//                     block, analog samples per frame, frame rate, events).
//   parameter blocks  4-byte preamble (byte 3 = processor type 84/85/86), then
//                     a chain of group and parameter records.
//   data blocks       per frame: num_points x (X, Y, Z, residual word), then
//                     the analog samples of that frame; int16 words when
//                     POINT:SCALE > 0 (coordinates multiplied by the scale),
//                     floats when POINT:SCALE < 0.
//
// Invalid points (residual word < 0, or non-finite coordinates in float files)
// have `valid == false`, `residual == -1` and NaN coordinates.
//
// Hand-written because Debian 12 packages no C3D library (ezc3d and BTK are
// not in it); the parser is fuzzed (tests/fuzz/c3d_fuzzer.cc).
#pragma once

#include "framework/io/marker_labels.h"

#include <Eigen/Core>

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// The processor type byte of the parameter section (byte 3): the byte order
/// of 16-bit words and the float format of the whole file.
enum class C3dProcessor : uint8_t {
  kIntel = 84,  ///< little-endian, IEEE floats
  kDec = 85,    ///< little-endian, VAX F-floats
  kMips = 86,   ///< big-endian (SGI/MIPS), IEEE floats
};

/// "intel", "dec" or "mips".
std::string_view ToString(C3dProcessor processor);

/// Type codes of a C3D parameter (the signed byte after the name).
enum class C3dParameterType : int8_t {
  kChar = -1,
  kByte = 1,
  kInt16 = 2,
  kFloat = 4,
};

/// One parameter of the parameter section.
struct C3dParameter {
  std::string name;         ///< as in the file (usually upper case)
  std::string description;  ///< may be empty
  C3dParameterType type = C3dParameterType::kInt16;
  /// Array dimensions, first index fastest (Fortran order); empty for a
  /// scalar. For char parameters dims[0] is the string length.
  std::vector<int> dims;
  bool locked = false;  ///< negative name length in the file
  /// The element bytes converted to Intel order: little-endian int16 and
  /// IEEE float, whatever the processor type of the file was.
  std::vector<uint8_t> raw;

  /// Number of elements: product of dims (1 for a scalar).
  int64_t NumElements() const;

  /// Char parameters as strings of dims[0] characters each (one string per
  /// combination of the remaining dims), trailing/leading blanks and NULs
  /// removed. Bytes are kept as they are (no encoding check). Throws IoError
  /// for non-char parameters.
  std::vector<std::string> AsStrings() const;
  /// Numeric parameters as floats (int16 signed, bytes unsigned). Throws
  /// IoError for char parameters.
  std::vector<float> AsFloats() const;
  /// Numeric parameters as ints: int16 signed, bytes unsigned, floats rounded
  /// to nearest (IoError if not representable). Throws for char parameters.
  std::vector<int> AsInts() const;

  /// A char parameter holding `values` padded with blanks to a common length
  /// (dims = {max length, values.size()}). IoError if a string > 255 chars.
  static C3dParameter FromStrings(std::string name,
                                  const std::vector<std::string>& values,
                                  std::string description = "");
  /// A char parameter holding one string (dims = {length}).
  static C3dParameter FromString(std::string name,
                                 std::string_view value,
                                 std::string description = "");
  /// An int16 parameter. Values in [32768, 65535] are stored as their
  /// unsigned bit pattern (POINT:USED, DATA_START). `dims` empty: a scalar
  /// for one value, else a 1-D array.
  static C3dParameter FromInt16s(std::string name,
                                 const std::vector<int>& values,
                                 std::vector<int> dims = {},
                                 std::string description = "");
  /// A float parameter; `dims` as for FromInt16s.
  static C3dParameter FromFloats(std::string name,
                                 const std::vector<float>& values,
                                 std::vector<int> dims = {},
                                 std::string description = "");
};

/// One group of the parameter section with its parameters, in file order.
struct C3dGroup {
  int id = 0;  ///< positive group number (stored negated in the file)
  std::string name;
  std::string description;
  bool locked = false;
  std::vector<C3dParameter> parameters;

  /// The parameter `name` (ASCII case-insensitive), or nullptr.
  const C3dParameter* Find(std::string_view name) const;
};

/// A header event (up to 18 in the C3D header).
struct C3dEvent {
  float time = 0.0f;  ///< seconds
  bool display = false;
  std::string label;  ///< up to 4 characters, trimmed
};

/// The 512-byte header, decoded but not interpreted (unsigned words).
struct C3dHeader {
  int parameter_block = 0;        ///< byte 0: first parameter block, 1-based
  int num_points = 0;             ///< word 2
  int analog_per_frame = 0;       ///< word 3: analog words per 3D frame
  int first_frame = 0;            ///< word 4 (1-based)
  int last_frame = 0;             ///< word 5
  int max_interpolation_gap = 0;  ///< word 6
  float scale = 0.0f;             ///< words 7-8: POINT:SCALE (< 0: float data)
  int data_start_block = 0;       ///< word 9 (1-based)
  int analog_samples_per_frame = 0;  ///< word 10
  float frame_rate = 0.0f;           ///< words 11-12, Hz
  bool long_event_labels = false;    ///< word 150 == 12345
  std::vector<C3dEvent> events;      ///< word 151 events
};

/// Row-major float matrices used for C3D data.
using C3dMatrix =
    Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using C3dMask =
    Eigen::Array<bool, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// Analog channel metadata and (if requested) samples.
struct C3dAnalog {
  int num_channels = 0;       ///< analog words per frame / samples per frame
  int samples_per_frame = 0;  ///< analog samples per 3D frame
  double rate = 0.0;          ///< Hz (ANALOG:RATE, else frame rate x samples)
  std::vector<std::string> labels;  ///< ANALOG:LABELS (+LABELS2...), trimmed
  std::vector<std::string> units;   ///< ANALOG:UNITS, trimmed
  /// (num_frames * samples_per_frame) x num_channels, scaled as
  /// (raw - ANALOG:OFFSET) * ANALOG:SCALE * ANALOG:GEN_SCALE. Empty unless
  /// C3dReadOptions::read_analogs.
  C3dMatrix samples;
};

/// Everything read from a C3D file.
struct C3dData {
  std::string source;  ///< file name (for messages)
  C3dProcessor processor = C3dProcessor::kIntel;
  C3dHeader header;

  double frame_rate = 0.0;  ///< Hz (header, else POINT:RATE)
  /// Number of the first frame (header word 4, or TRIAL:ACTUAL_START_FIELD
  /// for files with more than 65535 frames); 1-based by convention.
  int64_t first_frame = 1;
  /// Frames read: last - first + 1 from header words 4-5; when word 5 is
  /// saturated (65535), TRIAL:ACTUAL_START/END_FIELD (two unsigned words
  /// each), else POINT:FRAMES (int16 read as unsigned, or float). Smaller
  /// than declared only with C3dReadOptions::allow_truncated.
  int num_frames = 0;
  /// Points per frame: header word 2, which defines the data layout
  /// (POINT:USED, read as unsigned, is only compared; a mismatch is logged).
  int num_points = 0;
  /// POINT:SCALE from the header (the parameter if the header's is 0): > 0
  /// int16 data multiplied by it; < 0 float data. Residuals are the residual
  /// byte times |scale|.
  float point_scale = -1.0f;

  /// One label per point: POINT:LABELS, LABELS2, ... concatenated, trimmed,
  /// raw (subject prefixes such as `meinard:LFHD` are kept; see
  /// StripSubjectPrefix). Points without a label in the file (e.g. files
  /// with an empty parameter section) get the synthesized label `*<index>`
  /// (0-based), the convention SOMA uses for unlabelled points.
  std::vector<std::string> labels;
  /// How many of `labels` came from the file (the rest are synthesized).
  int num_file_labels = 0;
  /// POINT:DESCRIPTIONS (+DESCRIPTIONS2...), one per point ("" if absent).
  std::vector<std::string> descriptions;
  /// POINT:UNITS trimmed, e.g. "mm"; empty if the file has none (C3D's
  /// customary default is mm, see MetresPerUnit()).
  std::string units;

  /// num_frames x (3 * num_points): X, Y, Z of every point, in file units.
  /// Invalid points are NaN.
  C3dMatrix points;
  /// num_frames x num_points: residuals in file units; -1 for invalid points,
  /// 0 for points the capture software interpolated or did not report.
  C3dMatrix residuals;
  /// num_frames x num_points: residual >= 0 and finite coordinates.
  C3dMask valid;

  C3dAnalog analog;
  /// The parameter section, groups in order of appearance.
  std::vector<C3dGroup> groups;

  /// The group `name` (case-insensitive), or nullptr.
  const C3dGroup* FindGroup(std::string_view name) const;
  /// The parameter `group:name` (case-insensitive), or nullptr.
  const C3dParameter* FindParameter(std::string_view group,
                                    std::string_view name) const;
  /// Metres per file unit: UnitScaleToMetres(units), "mm" if units is empty.
  double MetresPerUnit() const;
  /// The position of `point` at `frame` (file units; NaN if invalid).
  Eigen::Vector3f Point(int frame, int point) const {
    return points.row(frame).segment<3>(3 * Eigen::Index{point}).transpose();
  }
};

/// Which point columns of `c3d` are model outputs that are no positions: the
/// labels listed in POINT:ANGLES, FORCES, MOMENTS, POWERS, SCALARS and
/// REACTIONS (Vicon Nexus stores Plug-in Gait's angles, forces ... as
/// points). One flag per point (`num_points`).
std::vector<bool> NonPositionColumns(const C3dData& c3d);

/// Which point columns of `c3d` are model outputs rather than markers:
/// NonPositionColumns, and Plug-in Gait's virtual points (segment axes,
/// centre of mass: PlugInGaitVirtualPoints of marker_labels.h), positions
/// the model computed that no camera saw. One flag per point.
std::vector<bool> ModelOutputColumns(const C3dData& c3d);

/// How to read a C3D file.
struct C3dReadOptions {
  /// A file whose data section ends before the declared last frame: false →
  /// IoError naming the byte range; true → return the complete frames and
  /// log a warning.
  bool allow_truncated = false;
  /// Decode analog samples into C3dData::analog.samples (they are always
  /// skipped correctly when false).
  bool read_analogs = false;
};

/// Reads a C3D file. Throws IoError (one line, naming the file and the byte
/// offset) for anything malformed.
C3dData ReadC3d(const std::filesystem::path& path,
                const C3dReadOptions& options = {});

/// Parses a C3D file held in memory; `source_name` is used in messages.
/// Never reads outside `bytes`, never allocates more than a small multiple of
/// bytes.size(), terminates on any input (the fuzzer's entry point).
C3dData ParseC3d(std::span<const uint8_t> bytes,
                 std::string_view source_name,
                 const C3dReadOptions& options = {});

/// Encodes `data` as an Intel float C3D file: header (with events), groups
/// POINT (USED, SCALE, RATE, DATA_START, FRAMES, UNITS, LABELS,
/// DESCRIPTIONS, LABELS2.. for more than 255 points), ANALOG (USED = 0,
/// RATE) and TRIAL (ACTUAL_START_FIELD, ACTUAL_END_FIELD), then the points.
/// Other parameter groups and analog data are not written. The shape is
/// taken from `data.points` (frames x 3*points); `labels` must be empty or
/// one per point (empty: `*<index>`); `residuals` may be empty (all valid).
/// A point is written as invalid (residual word -1, coordinates 0) when its
/// residual is < 0 or NaN, `valid` (if sized) is false, or a coordinate is not
/// finite. Throws ShapeError/IoError on inconsistent data.
std::vector<uint8_t> EncodeC3d(const C3dData& data);

/// EncodeC3d + an atomic write (temp file, fsync, rename).
void WriteC3d(const std::filesystem::path& path, const C3dData& data);

/// Metres per unit for a C3D/TRC unit string: "mm" → 0.001, "cm" → 0.01,
/// "dm" → 0.1, "m" → 1 (also "millimeters", "meters", ...; case- and
/// blank-insensitive). Throws IoError for anything else (including "").
double UnitScaleToMetres(std::string_view units);

}  // namespace soma
