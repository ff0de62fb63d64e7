#include "framework/eval/calibration.h"

#include "framework/config/decode.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/plot.h"
#include "framework/core/random.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <tuple>

namespace soma {

namespace fs = std::filesystem;

namespace {

void CheckTemperature(double temperature) {
  if (!(temperature > 0) || !std::isfinite(temperature)) {
    throw ConfigError(
        fmt::format("Invalid configuration. temperature = {}. Violated "
                    "constraint: 0 < temperature < inf",
                    temperature));
  }
}

void CheckSamples(const std::vector<float>& log_probs,
                  const std::vector<int>& targets,
                  int cols) {
  if (cols < 1 ||
      log_probs.size() != targets.size() * static_cast<size_t>(cols)) {
    throw ShapeError(
        fmt::format("temperature fit: {} log-probabilities for {} samples of "
                    "{} columns",
                    log_probs.size(),
                    targets.size(),
                    cols));
  }
  for (size_t i = 0; i < targets.size(); ++i) {
    if (targets[i] < 0 || targets[i] >= cols) {
      throw ShapeError(
          fmt::format("temperature fit: sample {} has target {}, not in "
                      "[0, {})",
                      i,
                      targets[i],
                      cols));
    }
  }
}

}  // namespace

void ApplyTemperature(float* probs,
                      int64_t rows,
                      int64_t cols,
                      double temperature) {
  CheckTemperature(temperature);
  const double inv = 1.0 / temperature;
  std::vector<double> z(static_cast<size_t>(cols));
  for (int64_t r = 0; r < rows; ++r) {
    float* row = probs + r * cols;
    double max_z = -std::numeric_limits<double>::infinity();
    for (int64_t c = 0; c < cols; ++c) {
      z[c] = std::log(std::max<double>(row[c], kMinProbability)) * inv;
      max_z = std::max(max_z, z[c]);
    }
    double sum = 0;
    for (int64_t c = 0; c < cols; ++c) {
      z[c] = std::exp(z[c] - max_z);
      sum += z[c];
    }
    for (int64_t c = 0; c < cols; ++c) {
      row[c] = static_cast<float>(z[c] / sum);
    }
  }
}

void TemperatureFitOptions::Validate() const {
  if (!(min_temperature > 0 && max_temperature > min_temperature &&
        tolerance > 0)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. temperature search [{}, {}], tolerance {}. "
        "Violated constraint: 0 < min_temperature < max_temperature, "
        "tolerance > 0",
        min_temperature,
        max_temperature,
        tolerance));
  }
}

double MeanNll(const std::vector<float>& log_probs,
               const std::vector<int>& targets,
               int cols,
               double temperature) {
  CheckTemperature(temperature);
  CheckSamples(log_probs, targets, cols);
  const double inv = 1.0 / temperature;
  double total = 0;
  for (size_t i = 0; i < targets.size(); ++i) {
    const float* row = log_probs.data() + i * cols;
    double max_z = -std::numeric_limits<double>::infinity();
    for (int c = 0; c < cols; ++c) max_z = std::max(max_z, row[c] * inv);
    double sum = 0;
    for (int c = 0; c < cols; ++c) sum += std::exp(row[c] * inv - max_z);
    total += max_z + std::log(sum) - row[targets[i]] * inv;
  }
  return targets.empty() ? 0.0 : total / static_cast<double>(targets.size());
}

TemperatureFit FitTemperature(const std::vector<float>& log_probs,
                              const std::vector<int>& targets,
                              int cols,
                              const TemperatureFitOptions& options) {
  options.Validate();
  CheckSamples(log_probs, targets, cols);
  if (targets.empty()) {
    throw ShapeError("temperature fit: no samples");
  }
  // The NLL is convex in beta = 1/T: golden-section search over beta.
  auto nll = [&](double beta) {
    return MeanNll(log_probs, targets, cols, 1.0 / beta);
  };
  const double lo_beta = 1.0 / options.max_temperature;
  const double hi_beta = 1.0 / options.min_temperature;
  const double phi = (std::sqrt(5.0) - 1) / 2;
  double a = lo_beta, b = hi_beta;
  double c = b - phi * (b - a), d = a + phi * (b - a);
  double fc = nll(c), fd = nll(d);
  while (b - a > options.tolerance * std::max(1.0, std::abs(c))) {
    if (fc < fd) {
      b = d;
      d = c;
      fd = fc;
      c = b - phi * (b - a);
      fc = nll(c);
    } else {
      a = c;
      c = d;
      fc = fd;
      d = a + phi * (b - a);
      fd = nll(d);
    }
  }
  const double beta = (a + b) / 2;
  TemperatureFit fit;
  fit.temperature = 1.0 / beta;
  fit.samples = static_cast<int64_t>(targets.size());
  fit.nll_before = MeanNll(log_probs, targets, cols, 1.0);
  fit.nll_after = nll(beta);
  const double edge = 10 * options.tolerance * std::max(1.0, beta);
  fit.at_bound = beta - lo_beta < edge || hi_beta - beta < edge;
  return fit;
}

TemperatureFit FitTemperatureByEce(const std::vector<float>& log_probs,
                                   const std::vector<int>& targets,
                                   const std::vector<int>& chosen,
                                   int cols,
                                   int num_bins,
                                   const TemperatureFitOptions& options) {
  options.Validate();
  CheckSamples(log_probs, chosen, cols);
  CheckSamples(log_probs, targets, cols);
  if (targets.empty()) {
    throw ShapeError("temperature fit: no samples");
  }
  const size_t n = targets.size();
  // Per sample: the row less its maximum (the chosen column's confidence at
  // T is exp(d_chosen / T) / sum_c exp(d_c / T), d <= 0).
  std::vector<float> shifted(log_probs.size());
  std::vector<bool> correct(n);
  for (size_t i = 0; i < n; ++i) {
    const float* row = log_probs.data() + i * cols;
    const float top = *std::max_element(row, row + cols);
    for (int c = 0; c < cols; ++c) shifted[i * cols + c] = row[c] - top;
    correct[i] = chosen[i] == targets[i];
  }
  std::vector<double> confidence(n);
  auto ece = [&](double temperature) {
    const float inv = static_cast<float>(1.0 / temperature);
    for (size_t i = 0; i < n; ++i) {
      const float* d = shifted.data() + i * cols;
      float sum = 0;
      for (int c = 0; c < cols; ++c) sum += std::exp(d[c] * inv);
      confidence[i] = std::exp(d[chosen[i]] * inv) / sum;
    }
    return ComputeReliability(confidence, correct, num_bins).ece;
  };
  // Coarse, then fine, log grids; the first least value wins ties.
  const double lo = std::log(options.min_temperature);
  const double hi = std::log(options.max_temperature);
  double best = 0, best_ece = ece(1.0);
  auto scan = [&](double from, double to, double step) {
    for (double x = from; x <= to + 1e-12; x += step) {
      const double e = ece(std::exp(x));
      if (e < best_ece) {
        best_ece = e;
        best = x;
      }
    }
  };
  const double coarse = std::log(1.05);
  scan(lo, hi, coarse);
  scan(std::max(lo, best - coarse), std::min(hi, best + coarse), coarse / 20);
  TemperatureFit fit;
  fit.temperature = std::exp(best);
  fit.samples = static_cast<int64_t>(n);
  fit.nll_before = MeanNll(log_probs, targets, cols, 1.0);
  fit.nll_after = MeanNll(log_probs, targets, cols, fit.temperature);
  fit.at_bound = best - lo < coarse || hi - best < coarse;
  return fit;
}

Reliability ComputeReliability(const std::vector<double>& confidence,
                               const std::vector<bool>& correct,
                               int num_bins) {
  if (confidence.size() != correct.size() || num_bins < 1) {
    throw ShapeError(
        fmt::format("reliability: {} confidences, {} outcomes, {} bins",
                    confidence.size(),
                    correct.size(),
                    num_bins));
  }
  Reliability r;
  r.bins.resize(num_bins);
  std::vector<double> sum_conf(num_bins, 0.0), sum_correct(num_bins, 0.0);
  for (size_t i = 0; i < confidence.size(); ++i) {
    const double p = std::clamp(confidence[i], 0.0, 1.0);
    const int b = std::min(num_bins - 1, static_cast<int>(p * num_bins));
    ++r.bins[b].count;
    sum_conf[b] += p;
    sum_correct[b] += correct[i] ? 1.0 : 0.0;
    r.mean_confidence += p;
    r.accuracy += correct[i] ? 1.0 : 0.0;
  }
  r.count = static_cast<int64_t>(confidence.size());
  const double n = static_cast<double>(std::max<int64_t>(r.count, 1));
  r.mean_confidence /= n;
  r.accuracy /= n;
  for (int b = 0; b < num_bins; ++b) {
    ReliabilityBin& bin = r.bins[b];
    bin.lower = static_cast<double>(b) / num_bins;
    bin.upper = static_cast<double>(b + 1) / num_bins;
    if (bin.count == 0) {
      bin.mean_confidence = bin.accuracy = std::nan("");
      continue;
    }
    bin.mean_confidence = sum_conf[b] / bin.count;
    bin.accuracy = sum_correct[b] / bin.count;
    const double gap = std::abs(bin.accuracy - bin.mean_confidence);
    r.ece += bin.count / n * gap;
    r.mce = std::max(r.mce, gap);
  }
  return r;
}

std::vector<CoveragePoint> PrecisionCoverageCurve(
    const std::vector<ThresholdedPrediction>& predictions,
    const std::vector<double>& thresholds) {
  std::vector<CoveragePoint> curve;
  curve.reserve(thresholds.size());
  const double total = static_cast<double>(predictions.size());
  for (double threshold : thresholds) {
    CoveragePoint point;
    point.threshold = threshold;
    for (const ThresholdedPrediction& p : predictions) {
      if (p.confidence < threshold) continue;
      ++point.kept;
      point.correct += p.correct ? 1 : 0;
    }
    point.precision =
        point.kept > 0 ? static_cast<double>(point.correct) / point.kept : 1.0;
    point.coverage = total > 0 ? point.kept / total : 0.0;
    curve.push_back(point);
  }
  return curve;
}

std::vector<double> DefaultThresholds() {
  std::vector<double> t;
  for (int i = 0; i <= 18; ++i) t.push_back(0.05 * i);  // 0 .. 0.90
  for (int i = 91; i <= 99; ++i) t.push_back(0.01 * i);
  for (int i = 991; i <= 999; ++i) t.push_back(0.001 * i);
  t.push_back(0.9995);
  t.push_back(0.9999);
  return t;
}

CoveragePoint CoverageAtPrecision(
    const std::vector<ThresholdedPrediction>& predictions,
    double min_precision) {
  std::vector<ThresholdedPrediction> sorted = predictions;
  std::sort(sorted.begin(),
            sorted.end(),
            [](const ThresholdedPrediction& a, const ThresholdedPrediction& b) {
              return a.confidence > b.confidence;
            });
  CoveragePoint best;
  best.threshold = std::numeric_limits<double>::infinity();
  best.precision = 1.0;
  int64_t kept = 0, correct = 0;
  const double total = static_cast<double>(sorted.size());
  for (size_t i = 0; i < sorted.size();) {
    // Keep every prediction tied at this confidence together.
    size_t j = i;
    while (j < sorted.size() && sorted[j].confidence == sorted[i].confidence) {
      correct += sorted[j].correct ? 1 : 0;
      ++kept;
      ++j;
    }
    const double precision = static_cast<double>(correct) / kept;
    if (precision >= min_precision) {
      best.threshold = sorted[i].confidence;
      best.kept = kept;
      best.correct = correct;
      best.precision = precision;
      best.coverage = kept / total;
    }
    i = j;
  }
  return best;
}

std::string ReliabilityCsv(const std::vector<NamedReliability>& diagrams) {
  std::string csv =
      "series,bin_lower,bin_upper,count,mean_confidence,accuracy\n";
  for (const NamedReliability& d : diagrams) {
    for (const ReliabilityBin& b : d.reliability.bins) {
      csv += fmt::format(
          "{},{:.4f},{:.4f},{},", d.name, b.lower, b.upper, b.count);
      if (b.count > 0) {
        csv += fmt::format("{:.6f},{:.6f}", b.mean_confidence, b.accuracy);
      } else {
        csv += ",";
      }
      csv += "\n";
    }
  }
  return csv;
}

void WriteReliabilityPng(const std::vector<NamedReliability>& diagrams,
                         const std::string& title,
                         const fs::path& path) {
  std::vector<PlotSeries> series;
  for (const NamedReliability& d : diagrams) {
    PlotSeries s;
    s.name = fmt::format("{} ECE {:.4f}", d.name, d.reliability.ece);
    for (const ReliabilityBin& b : d.reliability.bins) {
      if (b.count == 0) continue;
      s.x.push_back(b.mean_confidence);
      s.y.push_back(b.accuracy);
    }
    series.push_back(std::move(s));
  }
  series.push_back(PlotSeries{"perfect calibration", {0.0, 1.0}, {0.0, 1.0}});
  PlotOptions options;
  options.title = title;
  options.x_label = "confidence (mean per bin)";
  options.y_label = "accuracy";
  options.y_range = std::make_pair(0.0, 1.0);
  LinePlot(series, options).WritePng(path);
}

std::string PrecisionCoverageCsv(const std::vector<CoveragePoint>& curve) {
  std::string csv = "threshold,kept,correct,precision,coverage\n";
  for (const CoveragePoint& p : curve) {
    csv += fmt::format("{:.4f},{},{},{:.6f},{:.6f}\n",
                       p.threshold,
                       p.kept,
                       p.correct,
                       p.precision,
                       p.coverage);
  }
  return csv;
}

void WritePrecisionCoveragePng(const std::vector<CoveragePoint>& curve,
                               double target,
                               const std::string& title,
                               const fs::path& path) {
  PlotSeries precision{"precision", {}, {}};
  for (const CoveragePoint& p : curve) {
    if (p.kept == 0) continue;
    precision.x.push_back(p.coverage);
    precision.y.push_back(p.precision);
  }
  const PlotSeries line{fmt::format("precision {:g}%", 100 * target),
                        {0.0, 1.0},
                        {target, target}};
  PlotOptions options;
  options.title = title;
  options.x_label = "coverage (share of assigned labels kept)";
  options.y_label = "precision";
  LinePlot({precision, line}, options).WritePng(path);
}

std::vector<ReviewRange> LowConfidenceRanges(
    const std::vector<int>& labels,
    const std::vector<float>& confidence,
    int frames,
    int points,
    int num_labels,
    double threshold,
    int max_gap) {
  const size_t n = static_cast<size_t>(frames) * std::max(points, 0);
  if (frames < 0 || points < 0 || max_gap < 0 || labels.size() != n ||
      confidence.size() != n) {
    throw ShapeError(fmt::format(
        "review list: {} labels and {} confidences for {} frames x {} points "
        "(max gap {})",
        labels.size(),
        confidence.size(),
        frames,
        points,
        max_gap));
  }
  std::vector<ReviewRange> out;
  // Per label, the open range (low_frames == 0: none).
  std::vector<ReviewRange> open(num_labels);
  std::vector<double> low(num_labels);
  for (int t = 0; t < frames; ++t) {
    std::fill(low.begin(), low.end(), 2.0);  // > 1: not low in frame t
    for (int p = 0; p < points; ++p) {
      const size_t i = static_cast<size_t>(t) * points + p;
      const int id = labels[i];
      if (id < 0 || id >= num_labels || !(confidence[i] < threshold)) continue;
      low[id] = std::min<double>(low[id], confidence[i]);
    }
    for (int id = 0; id < num_labels; ++id) {
      if (low[id] > 1.0) continue;
      ReviewRange& r = open[id];
      if (r.low_frames > 0 && t - r.last_frame - 1 > max_gap) {
        out.push_back(r);
        r = ReviewRange{};
      }
      if (r.low_frames == 0) r = ReviewRange{id, t, t, 0, low[id]};
      r.last_frame = t;
      ++r.low_frames;
      r.min_confidence = std::min(r.min_confidence, low[id]);
    }
  }
  for (const ReviewRange& r : open) {
    if (r.low_frames > 0) out.push_back(r);
  }
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) {
    return std::tie(a.first_frame, a.label) < std::tie(b.first_frame, b.label);
  });
  return out;
}

std::string FileFingerprint(const fs::path& path) {
  return fmt::format("{:016x}", Fnv1a64(ReadFile(path)));
}

void WriteCalibration(const fs::path& path,
                      const TemperatureCalibration& calibration) {
  ConfigNode node = ConfigNode::EmptyMap();
  node.Set("temperature", calibration.temperature);
  node.Set("checkpoint", ConfigNode::LiteralString(calibration.checkpoint));
  node.Set("checkpoint_fnv1a64",
           ConfigNode::LiteralString(calibration.checkpoint_fnv1a64));
  node.Set("fitted_on", ConfigNode::LiteralString(calibration.fitted_on));
  node.Set("frames", calibration.frames);
  node.Set("points", calibration.points);
  node.Set("nll_before", calibration.nll_before);
  node.Set("nll_after", calibration.nll_after);
  node.Set("ece_raw", calibration.ece_raw);
  node.Set("ece_before", calibration.ece_before);
  node.Set("ece_after", calibration.ece_after);
  node.Set("command", ConfigNode::LiteralString(calibration.command));
  node.Set("code_version", ConfigNode::LiteralString(calibration.code_version));
  const std::string header =
      "# Temperature scaling of a labeler's assignment probabilities, written\n"
      "# by `soma calibrate` (README \"Confidence you can trust\"; "
      "framework/eval/"
      "calibration.h).\n"
      "# soma label / label_eval apply it (task.calibration=auto) when it "
      "sits\n"
      "# beside the checkpoint and checkpoint_fnv1a64 matches its bytes:\n"
      "# each point's distribution over the labels and null becomes\n"
      "# softmax(log p / temperature); labels are unchanged. nll_* and ece_*\n"
      "# are on the synthetic validation frames of the fit: ece_raw of the\n"
      "# raw Sinkhorn rows, ece_before of the rows renormalised (T = 1),\n"
      "# ece_after at the temperature.\n";
  WriteFileAtomic(path, header + DumpYaml(node));
}

TemperatureCalibration ReadCalibration(const fs::path& path) {
  const ConfigNode node = ParseYaml(ReadFile(path), path.string());
  ConfigReader reader(node);
  TemperatureCalibration c;
  reader.Require("temperature", &c.temperature);
  reader.Require("checkpoint", &c.checkpoint);
  reader.Require("checkpoint_fnv1a64", &c.checkpoint_fnv1a64);
  reader.Read("fitted_on", &c.fitted_on);
  reader.Read("frames", &c.frames);
  reader.Read("points", &c.points);
  reader.Read("nll_before", &c.nll_before);
  reader.Read("nll_after", &c.nll_after);
  reader.Read("ece_raw", &c.ece_raw);
  reader.Read("ece_before", &c.ece_before);
  reader.Read("ece_after", &c.ece_after);
  reader.Read("command", &c.command);
  reader.Read("code_version", &c.code_version);
  reader.Check("temperature",
               c.temperature > 0 && std::isfinite(c.temperature),
               "0 < temperature < inf");
  reader.Finish();
  return c;
}

CalibrationChoice ResolveCalibration(const std::string& option,
                                     const fs::path& checkpoint) {
  CalibrationChoice choice;
  if (option == "none") {
    choice.reason = "no temperature scaling (task.calibration=none)";
    return choice;
  }
  const bool automatic = option == "auto" || option.empty();
  const fs::path file = automatic
                            ? checkpoint.parent_path() / kCalibrationFileName
                            : fs::path(option);
  if (!fs::exists(file)) {
    if (!automatic) {
      throw ConfigError(
          fmt::format("task.calibration={}: no such file (a `soma calibrate` "
                      "calibration.yaml, auto or none)",
                      option));
    }
    choice.reason = fmt::format(
        "no temperature scaling (no {} beside {}; `soma calibrate` fits one)",
        kCalibrationFileName,
        checkpoint.string());
    return choice;
  }
  const TemperatureCalibration c = ReadCalibration(file);
  const std::string fingerprint = FileFingerprint(checkpoint);
  if (c.checkpoint_fnv1a64 != fingerprint) {
    const std::string why = fmt::format(
        "{} was fitted for another checkpoint ({} with FNV-1a {}, this one "
        "is {} with {})",
        file.string(),
        c.checkpoint,
        c.checkpoint_fnv1a64,
        checkpoint.filename().string(),
        fingerprint);
    if (!automatic) {
      throw ConfigError(fmt::format(
          "task.calibration={}: {}; run `soma calibrate` for it", option, why));
    }
    choice.reason = "no temperature scaling: " + why +
                    "; run `soma calibrate` to fit this one";
    return choice;
  }
  choice.temperature = c.temperature;
  choice.file = file;
  choice.reason = fmt::format(
      "temperature {:.4f} from {} (fitted on {})",
      c.temperature,
      file.string(),
      c.fitted_on.empty() ? std::string("unknown data") : c.fitted_on);
  return choice;
}

}  // namespace soma
