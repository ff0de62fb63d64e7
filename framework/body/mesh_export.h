// Mesh export for inspection: ASCII PLY (with colours and marker points) and
// Wavefront OBJ. Both writes are atomic (temp file + rename).
#pragma once

#include "framework/core/image.h"

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <filesystem>
#include <vector>

namespace soma {

/// An RGB colour, 0-255 per channel.

/// Extra points written after the mesh vertices (e.g. markers), each with a
/// colour. `colors` is empty (all red) or one per point.
struct ColoredPoints {
  Eigen::Matrix3Xd positions;  // 3 x N, metres
  std::vector<Rgb> colors;
};

/// Writes an ASCII PLY: the mesh vertices (light grey, or `vertex_colors`
/// when it has one colour per vertex), the faces, and `points` appended as
/// extra coloured vertices referenced by no face. Throws ShapeError on
/// inconsistent sizes and IoError if the file cannot be written.
void WritePly(const std::filesystem::path& path,
              const Eigen::Matrix3Xd& vertices,
              const Eigen::Matrix3Xi& faces,
              const ColoredPoints& points = {},
              const std::vector<Rgb>& vertex_colors = {});

/// Writes a Wavefront OBJ (1-based face indices). `normals` (3 x V) are
/// written as `vn` lines when given. `points` are appended as extra `v`
/// lines with the common "v x y z r g b" colour extension (r, g, b in
/// [0, 1]) and referenced by one `p` element, so viewers show them as points.
void WriteObj(const std::filesystem::path& path,
              const Eigen::Matrix3Xd& vertices,
              const Eigen::Matrix3Xi& faces,
              const Eigen::Matrix3Xd& normals = {},
              const ColoredPoints& points = {});

}  // namespace soma
