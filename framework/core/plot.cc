#include "framework/core/plot.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace soma {
namespace {

constexpr int kLeft = 70, kRight = 20, kTop = 40, kBottom = 50;

std::string TickLabel(double v) {
  if (std::abs(v) < 1e-12) return "0";
  if (std::abs(v) >= 1e4 || std::abs(v) < 1e-3) return fmt::format("{:.1e}", v);
  return fmt::format("{:g}", v);
}

struct Frame {
  double x0, x1, y0, y1;
  int px0, px1, py0, py1;
  double X(double x) const { return px0 + (x - x0) / (x1 - x0) * (px1 - px0); }
  double Y(double y) const { return py1 - (y - y0) / (y1 - y0) * (py1 - py0); }
};

void DrawAxes(Image& image,
              const Frame& f,
              const PlotOptions& options,
              bool x_ticks) {
  for (double t : NiceTicks(f.y0, f.y1)) {
    const int y = static_cast<int>(std::lround(f.Y(t)));
    image.DrawLine(f.px0, y, f.px1, y, kLightGray);
    const std::string label = TickLabel(t);
    image.DrawText(f.px0 - 6 - Image::TextWidth(label), y - 3, label, kBlack);
  }
  if (x_ticks) {
    for (double t : NiceTicks(f.x0, f.x1)) {
      const int x = static_cast<int>(std::lround(f.X(t)));
      image.DrawLine(x, f.py0, x, f.py1, kLightGray);
      const std::string label = TickLabel(t);
      image.DrawText(x - Image::TextWidth(label) / 2, f.py1 + 6, label, kBlack);
    }
  }
  image.DrawRect(f.px0, f.py0, f.px1, f.py1, kBlack);
  image.DrawText((image.width() - Image::TextWidth(options.title, 2)) / 2,
                 10,
                 options.title,
                 kBlack,
                 2);
  image.DrawText((f.px0 + f.px1 - Image::TextWidth(options.x_label)) / 2,
                 image.height() - 16,
                 options.x_label,
                 kBlack);
  image.DrawText(4, f.py0 - 14, options.y_label, kBlack);
}

std::pair<double, double> Padded(double lo, double hi) {
  if (!std::isfinite(lo) || !std::isfinite(hi)) return {0, 1};
  if (hi - lo < 1e-12) return {lo - 0.5, hi + 0.5};
  const double pad = 0.05 * (hi - lo);
  return {lo - pad, hi + pad};
}

}  // namespace

std::vector<double> NiceTicks(double lo, double hi, int target) {
  std::vector<double> ticks;
  if (!(hi > lo) || !std::isfinite(lo) || !std::isfinite(hi)) return ticks;
  const double raw = (hi - lo) / std::max(1, target);
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  double step = magnitude;
  for (double m : {1.0, 2.0, 5.0, 10.0}) {
    step = m * magnitude;
    if (step >= raw) break;
  }
  for (double t = std::ceil(lo / step) * step; t <= hi + 1e-9 * step;
       t += step) {
    ticks.push_back(std::abs(t) < 1e-12 * step ? 0.0 : t);
  }
  return ticks;
}

Image LinePlot(const std::vector<PlotSeries>& series,
               const PlotOptions& options) {
  Image image(options.width, options.height);
  double xmin = std::numeric_limits<double>::infinity(), xmax = -xmin;
  double ymin = xmin, ymax = -xmin;
  for (const PlotSeries& s : series) {
    for (size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.y[i])) continue;
      xmin = std::min(xmin, s.x[i]);
      xmax = std::max(xmax, s.x[i]);
      ymin = std::min(ymin, s.y[i]);
      ymax = std::max(ymax, s.y[i]);
    }
  }
  auto [y0, y1] = options.y_range ? *options.y_range : Padded(ymin, ymax);
  auto [x0, x1] = std::isfinite(xmin) && xmax > xmin ? std::pair{xmin, xmax}
                                                     : Padded(xmin, xmax);
  const Frame f{x0,
                x1,
                y0,
                y1,
                kLeft,
                options.width - kRight,
                kTop,
                options.height - kBottom};
  DrawAxes(image, f, options, true);
  for (size_t k = 0; k < series.size(); ++k) {
    const PlotSeries& s = series[k];
    const Rgb color = CategoricalColor(static_cast<int>(k));
    for (size_t i = 1; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.y[i - 1]) || !std::isfinite(s.y[i])) continue;
      image.DrawLine(
          f.X(s.x[i - 1]), f.Y(s.y[i - 1]), f.X(s.x[i]), f.Y(s.y[i]), color, 2);
    }
    if (s.x.size() == 1) image.FillCircle(f.X(s.x[0]), f.Y(s.y[0]), 3, color);
    // Legend.
    const int ly = kTop + 8 + 14 * static_cast<int>(k);
    image.FillRect(f.px1 - 150, ly, f.px1 - 140, ly + 7, color);
    image.DrawText(f.px1 - 135, ly, s.name, kBlack);
  }
  return image;
}

Image BarChart(const std::vector<std::string>& categories,
               const std::vector<double>& values,
               const PlotOptions& options) {
  Image image(options.width, options.height);
  double ymax = 0, ymin = 0;
  for (double v : values) {
    if (!std::isfinite(v)) continue;
    ymax = std::max(ymax, v);
    ymin = std::min(ymin, v);
  }
  auto [y0, y1] = options.y_range
                      ? *options.y_range
                      : std::pair{ymin, ymax > ymin ? ymax * 1.05 : 1.0};
  const int n = static_cast<int>(std::max<size_t>(1, values.size()));
  const Frame f{0,
                static_cast<double>(n),
                y0,
                y1,
                kLeft,
                options.width - kRight,
                kTop,
                options.height - kBottom};
  DrawAxes(image, f, options, false);
  const double slot = static_cast<double>(f.px1 - f.px0) / n;
  for (int i = 0; i < static_cast<int>(values.size()); ++i) {
    if (!std::isfinite(values[i])) continue;
    const int bx0 = static_cast<int>(f.px0 + i * slot + slot * 0.15);
    const int bx1 = static_cast<int>(f.px0 + (i + 1) * slot - slot * 0.15);
    image.FillRect(bx0,
                   static_cast<int>(f.Y(values[i])),
                   bx1,
                   static_cast<int>(f.Y(std::max(0.0, y0))),
                   CategoricalColor(0));
    if (i < static_cast<int>(categories.size())) {
      const std::string& label = categories[i];
      const int max_chars = std::max(1, static_cast<int>(slot / 6));
      const std::string shown = label.substr(0, max_chars);
      image.DrawText(static_cast<int>(f.px0 + (i + 0.5) * slot) -
                         Image::TextWidth(shown) / 2,
                     f.py1 + 6,
                     shown,
                     kBlack);
    }
  }
  return image;
}

}  // namespace soma
