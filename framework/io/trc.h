// TRC marker files (Motion Analysis "Track Row Column", also written by
// OpenSim, MOTEK and Vicon exporters): tab-separated text.
//
//   line 1  PathFileType  4  (X/Y/Z)  <file name>
//   line 2  DataRate CameraRate NumFrames NumMarkers Units OrigDataRate
//           OrigDataStartFrame OrigNumFrames          (keys)
//   line 3  the values of line 2
//   line 4  Frame#  Time  <marker 1>  <tab> <tab>  <marker 2> ...
//   line 5  <tab> <tab> X1 Y1 Z1 X2 Y2 Z2 ...
//   then    one row per frame: frame number, time (s), X Y Z per marker;
//           blank cells (or NaN) mark a missing marker. Blank lines are
//           ignored anywhere.
#pragma once

#include "framework/io/c3d.h"

#include <filesystem>
#include <map>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// Everything read from a TRC file; same conventions as C3dData (row-major
/// frames x 3*markers, NaN for missing, a validity mask).
struct TrcData {
  std::string source;             ///< file name (for messages)
  double frame_rate = 0.0;        ///< DataRate, Hz
  double camera_rate = 0.0;       ///< CameraRate, Hz (0 if absent)
  double orig_data_rate = 0.0;    ///< OrigDataRate, Hz (0 if absent)
  int orig_data_start_frame = 0;  ///< OrigDataStartFrame (0 if absent)
  int orig_num_frames = 0;        ///< OrigNumFrames (0 if absent)
  int num_frames = 0;             ///< data rows read
  int num_markers = 0;            ///< NumMarkers
  std::string units;              ///< Units, e.g. "mm"
  /// Every key/value pair of header lines 2-3, as text.
  std::map<std::string, std::string> header;

  std::vector<std::string> labels;  ///< one per marker, trimmed
  std::vector<int> frame_numbers;   ///< the Frame# column
  std::vector<double> times;        ///< the Time column, seconds
  /// num_frames x (3 * num_markers), file units; NaN where missing.
  C3dMatrix points;
  /// num_frames x num_markers: all three coordinates present and finite.
  C3dMask valid;

  /// Metres per file unit (UnitScaleToMetres(units)).
  double MetresPerUnit() const { return UnitScaleToMetres(units); }
  /// Position of `marker` at `frame` (file units; NaN if missing).
  Eigen::Vector3f Point(int frame, int marker) const {
    return points.row(frame).segment<3>(3 * Eigen::Index{marker}).transpose();
  }
};

/// How to read a TRC file.
struct TrcReadOptions {
  /// Fewer data rows than NumFrames: false → IoError; true → keep the rows
  /// present and log a warning.
  bool allow_truncated = false;
};

/// Reads a TRC file. Throws IoError naming the file and line (1-based) for
/// malformed headers, truncated rows, non-numeric cells or too few rows.
TrcData ReadTrc(const std::filesystem::path& path,
                const TrcReadOptions& options = {});

/// Parses TRC text held in memory; `source_name` is used in messages.
TrcData ParseTrc(std::string_view text,
                 std::string_view source_name,
                 const TrcReadOptions& options = {});

}  // namespace soma
