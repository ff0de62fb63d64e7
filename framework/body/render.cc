#include "framework/body/render.h"

#include "framework/core/error.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace soma {
namespace {

/// A view: screen axes (right, up) and the direction towards the camera.
struct View {
  Eigen::Vector3d right, up, to_camera;
};

struct Projection {
  double scale, cx, cy, wx, wz;  // pixel = (c + scale * (world - w))
  int offset_x, offset_y, size;
  Eigen::Vector2d Pixel(const View& view, const Eigen::Vector3d& p) const {
    const double u = p.dot(view.right) - wx;
    const double v = p.dot(view.up) - wz;
    return {offset_x + cx + scale * u, offset_y + cy - scale * v};
  }
};

void RenderView(Image& image,
                const View& view,
                const Projection& proj,
                const Eigen::Matrix3Xd& vertices,
                const Eigen::Matrix3Xi& faces,
                const Eigen::Matrix3Xd& markers,
                const std::vector<std::string>& labels,
                const RenderOptions& options) {
  const int size = proj.size;
  std::vector<double> depth(static_cast<size_t>(size) * size,
                            -std::numeric_limits<double>::infinity());
  std::vector<Eigen::Vector2d> pixels(vertices.cols());
  std::vector<double> vertex_depth(vertices.cols());
  for (int i = 0; i < vertices.cols(); ++i) {
    pixels[i] = proj.Pixel(view, vertices.col(i));
    vertex_depth[i] = vertices.col(i).dot(view.to_camera);
  }
  for (int f = 0; f < faces.cols(); ++f) {
    const int a = faces(0, f), b = faces(1, f), c = faces(2, f);
    const Eigen::Vector3d normal =
        (vertices.col(b) - vertices.col(a))
            .cross(vertices.col(c) - vertices.col(a));
    const double norm = normal.norm();
    if (norm <= 0) continue;
    const double facing = normal.dot(view.to_camera) / norm;
    if (facing <= 0) continue;  // back face
    const double shade = 0.25 + 0.75 * facing;
    const Rgb color{static_cast<uint8_t>(205 * shade),
                    static_cast<uint8_t>(180 * shade),
                    static_cast<uint8_t>(160 * shade)};
    const Eigen::Vector2d p0 = pixels[a], p1 = pixels[b], p2 = pixels[c];
    const int x0 = std::max(
        0, static_cast<int>(std::floor(std::min({p0.x(), p1.x(), p2.x()}))));
    const int x1 = std::min(
        size - 1 + proj.offset_x,
        static_cast<int>(std::ceil(std::max({p0.x(), p1.x(), p2.x()}))));
    const int y0 = std::max(
        0, static_cast<int>(std::floor(std::min({p0.y(), p1.y(), p2.y()}))));
    const int y1 = std::min(
        size - 1 + proj.offset_y,
        static_cast<int>(std::ceil(std::max({p0.y(), p1.y(), p2.y()}))));
    const double area = (p1.x() - p0.x()) * (p2.y() - p0.y()) -
                        (p2.x() - p0.x()) * (p1.y() - p0.y());
    if (std::abs(area) < 1e-12) continue;
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        const double px = x + 0.5, py = y + 0.5;
        const double w0 =
            ((p1.x() - px) * (p2.y() - py) - (p2.x() - px) * (p1.y() - py)) /
            area;
        const double w1 =
            ((p2.x() - px) * (p0.y() - py) - (p0.x() - px) * (p2.y() - py)) /
            area;
        const double w2 = 1.0 - w0 - w1;
        if (w0 < 0 || w1 < 0 || w2 < 0) continue;
        const int lx = x - proj.offset_x, ly = y - proj.offset_y;
        if (lx < 0 || ly < 0 || lx >= size || ly >= size) continue;
        const double z =
            w0 * vertex_depth[a] + w1 * vertex_depth[b] + w2 * vertex_depth[c];
        double& stored = depth[static_cast<size_t>(ly) * size + lx];
        if (z <= stored) continue;
        stored = z;
        image.Set(x, y, color);
      }
    }
  }
  for (int m = 0; m < markers.cols(); ++m) {
    const Eigen::Vector2d p = proj.Pixel(view, markers.col(m));
    const int lx = static_cast<int>(p.x()) - proj.offset_x;
    const int ly = static_cast<int>(p.y()) - proj.offset_y;
    bool hidden = false;
    if (lx >= 0 && ly >= 0 && lx < size && ly < size) {
      hidden = depth[static_cast<size_t>(ly) * size + lx] >
               markers.col(m).dot(view.to_camera) + 0.005;
    }
    const Rgb color = CategoricalColor(3);
    if (hidden) {
      const double r = options.marker_radius_px;
      for (int k = 0; k < 24; ++k) {
        const double t0 = 2 * M_PI * k / 24, t1 = 2 * M_PI * (k + 1) / 24;
        image.DrawLine(p.x() + r * std::cos(t0),
                       p.y() + r * std::sin(t0),
                       p.x() + r * std::cos(t1),
                       p.y() + r * std::sin(t1),
                       color);
      }
    } else {
      image.FillCircle(p.x(), p.y(), options.marker_radius_px, color);
    }
    if (options.labels && m < static_cast<int>(labels.size()) && !hidden) {
      image.DrawText(static_cast<int>(p.x() + options.marker_radius_px + 2),
                     static_cast<int>(p.y() - 3),
                     labels[m],
                     kBlack);
    }
  }
}

}  // namespace

Image RenderBodyViews(const Eigen::Matrix3Xd& vertices,
                      const Eigen::Matrix3Xi& faces,
                      const Eigen::Matrix3Xd& markers,
                      const std::vector<std::string>& labels,
                      const RenderOptions& options) {
  SOMA_CHECK_GT(vertices.cols(), 0);
  SOMA_CHECK(options.view_size >= 64 && options.view_size <= 4096)
      << options.view_size;
  const View front{Eigen::Vector3d::UnitX(),
                   Eigen::Vector3d::UnitZ(),
                   -Eigen::Vector3d::UnitY()};
  const View side{-Eigen::Vector3d::UnitY(),
                  Eigen::Vector3d::UnitZ(),
                  Eigen::Vector3d::UnitX()};
  const int title_height = options.title.empty() ? 0 : 30;
  Image image(2 * options.view_size, options.view_size + title_height);
  if (!options.title.empty()) image.DrawText(10, 8, options.title, kBlack, 2);

  // One scale for both views: fit the larger extent, centre each view.
  Eigen::Vector3d lo = vertices.rowwise().minCoeff(),
                  hi = vertices.rowwise().maxCoeff();
  if (markers.cols() > 0) {
    lo = lo.cwiseMin(markers.rowwise().minCoeff());
    hi = hi.cwiseMax(markers.rowwise().maxCoeff());
  }
  const Eigen::Vector3d center = 0.5 * (lo + hi);
  const double extent = (hi - lo).maxCoeff();
  const double scale = 0.9 * options.view_size / std::max(extent, 1e-6);
  for (int v = 0; v < 2; ++v) {
    const View& view = v == 0 ? front : side;
    Projection proj{scale,
                    options.view_size / 2.0,
                    options.view_size / 2.0,
                    center.dot(view.right),
                    center.dot(view.up),
                    v * options.view_size,
                    title_height,
                    options.view_size};
    RenderView(image, view, proj, vertices, faces, markers, labels, options);
    image.DrawText(v * options.view_size + 8,
                   title_height + 8,
                   v == 0 ? "front" : "left side",
                   kGray);
  }
  image.DrawLine(options.view_size,
                 title_height,
                 options.view_size,
                 options.view_size + title_height,
                 kLightGray);
  return image;
}

}  // namespace soma
