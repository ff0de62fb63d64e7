#include "framework/body/mesh_export.h"

#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>

#include <string>

namespace soma {
namespace {

constexpr Rgb kMeshGrey = {200, 200, 200};
constexpr Rgb kPointRed = {255, 0, 0};

void CheckInputs(const char* what,
                 const Eigen::Matrix3Xd& vertices,
                 const Eigen::Matrix3Xi& faces,
                 const ColoredPoints& points) {
  if (faces.size() > 0 &&
      (faces.minCoeff() < 0 || faces.maxCoeff() >= vertices.cols())) {
    throw ShapeError(
        fmt::format("{}: face indices must lie in [0, {}), found [{}, {}]",
                    what,
                    vertices.cols(),
                    faces.minCoeff(),
                    faces.maxCoeff()));
  }
  if (!points.colors.empty() &&
      static_cast<Eigen::Index>(points.colors.size()) !=
          points.positions.cols()) {
    throw ShapeError(fmt::format("{}: {} point colours for {} points",
                                 what,
                                 points.colors.size(),
                                 points.positions.cols()));
  }
}

Rgb PointColor(const ColoredPoints& points, Eigen::Index i) {
  return points.colors.empty() ? kPointRed
                               : points.colors[static_cast<size_t>(i)];
}

}  // namespace

void WritePly(const std::filesystem::path& path,
              const Eigen::Matrix3Xd& vertices,
              const Eigen::Matrix3Xi& faces,
              const ColoredPoints& points,
              const std::vector<Rgb>& vertex_colors) {
  CheckInputs("WritePly", vertices, faces, points);
  if (!vertex_colors.empty() &&
      static_cast<Eigen::Index>(vertex_colors.size()) != vertices.cols()) {
    throw ShapeError(fmt::format("WritePly: {} vertex colours for {} vertices",
                                 vertex_colors.size(),
                                 vertices.cols()));
  }
  const Eigen::Index num_points = points.positions.cols();
  std::string out;
  out.reserve(static_cast<size_t>(vertices.cols() + num_points) * 48 +
              static_cast<size_t>(faces.cols()) * 24 + 256);
  out += "ply\nformat ascii 1.0\ncomment written by somalab\n";
  out += fmt::format("element vertex {}\n", vertices.cols() + num_points);
  out +=
      "property float x\nproperty float y\nproperty float z\n"
      "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  out += fmt::format("element face {}\n", faces.cols());
  out += "property list uchar int vertex_indices\nend_header\n";
  for (Eigen::Index v = 0; v < vertices.cols(); ++v) {
    const Rgb c = vertex_colors.empty() ? kMeshGrey
                                        : vertex_colors[static_cast<size_t>(v)];
    out += fmt::format("{:.6f} {:.6f} {:.6f} {} {} {}\n",
                       vertices(0, v),
                       vertices(1, v),
                       vertices(2, v),
                       c.r,
                       c.g,
                       c.b);
  }
  for (Eigen::Index p = 0; p < num_points; ++p) {
    const Rgb c = PointColor(points, p);
    out += fmt::format("{:.6f} {:.6f} {:.6f} {} {} {}\n",
                       points.positions(0, p),
                       points.positions(1, p),
                       points.positions(2, p),
                       c.r,
                       c.g,
                       c.b);
  }
  for (Eigen::Index f = 0; f < faces.cols(); ++f) {
    out += fmt::format("3 {} {} {}\n", faces(0, f), faces(1, f), faces(2, f));
  }
  WriteFileAtomic(path, out);
}

void WriteObj(const std::filesystem::path& path,
              const Eigen::Matrix3Xd& vertices,
              const Eigen::Matrix3Xi& faces,
              const Eigen::Matrix3Xd& normals,
              const ColoredPoints& points) {
  CheckInputs("WriteObj", vertices, faces, points);
  const bool with_normals = normals.cols() > 0;
  if (with_normals && normals.cols() != vertices.cols()) {
    throw ShapeError(fmt::format("WriteObj: {} normals for {} vertices",
                                 normals.cols(),
                                 vertices.cols()));
  }
  std::string out;
  out.reserve(static_cast<size_t>(vertices.cols()) * (with_normals ? 80 : 40) +
              static_cast<size_t>(faces.cols()) * 40 + 64);
  out += "# written by somalab\n";
  for (Eigen::Index v = 0; v < vertices.cols(); ++v) {
    out += fmt::format("v {:.6f} {:.6f} {:.6f}\n",
                       vertices(0, v),
                       vertices(1, v),
                       vertices(2, v));
  }
  if (with_normals) {
    for (Eigen::Index v = 0; v < normals.cols(); ++v) {
      out += fmt::format("vn {:.6f} {:.6f} {:.6f}\n",
                         normals(0, v),
                         normals(1, v),
                         normals(2, v));
    }
  }
  for (Eigen::Index f = 0; f < faces.cols(); ++f) {
    const int a = faces(0, f) + 1;
    const int b = faces(1, f) + 1;
    const int c = faces(2, f) + 1;
    if (with_normals) {
      out += fmt::format("f {}//{} {}//{} {}//{}\n", a, a, b, b, c, c);
    } else {
      out += fmt::format("f {} {} {}\n", a, b, c);
    }
  }
  const Eigen::Index num_points = points.positions.cols();
  if (num_points > 0) {
    for (Eigen::Index p = 0; p < num_points; ++p) {
      const Rgb c = PointColor(points, p);
      out += fmt::format("v {:.6f} {:.6f} {:.6f} {:.4f} {:.4f} {:.4f}\n",
                         points.positions(0, p),
                         points.positions(1, p),
                         points.positions(2, p),
                         c.r / 255.0,
                         c.g / 255.0,
                         c.b / 255.0);
    }
    out += "p";
    for (Eigen::Index p = 0; p < num_points; ++p) {
      out += fmt::format(" {}", vertices.cols() + p + 1);
    }
    out += "\n";
  }
  WriteFileAtomic(path, out);
}

}  // namespace soma
