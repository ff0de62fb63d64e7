// Minimal charts rendered to an Image (line plots, bar charts) for reports a
// person looks at: coverage histograms, learning curves. Publication figures
// are made by the notebooks in notebooks/ from results/ CSVs.
#pragma once

#include "framework/core/image.h"

#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace soma {

struct PlotOptions {
  std::string title;
  std::string x_label;
  std::string y_label;
  int width = 800;
  int height = 480;
  std::optional<std::pair<double, double>> y_range;  // default: data range
};

struct PlotSeries {
  std::string name;
  std::vector<double> x;
  std::vector<double> y;
};

/// Line plot of one or more series with axes, ticks, grid and a legend.
Image LinePlot(const std::vector<PlotSeries>& series,
               const PlotOptions& options);

/// Bar chart: one bar per category (labels drawn below, rotated text is not
/// supported, so keep them short).
Image BarChart(const std::vector<std::string>& categories,
               const std::vector<double>& values,
               const PlotOptions& options);

/// "Nice" tick positions covering [lo, hi] (1-2-5 steps), about `target` of
/// them.
std::vector<double> NiceTicks(double lo, double hi, int target = 6);

}  // namespace soma
