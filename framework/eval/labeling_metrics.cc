#include "framework/eval/labeling_metrics.h"

#include "framework/core/csv.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/image.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <sstream>

namespace soma {
namespace {

bool IsMissing(const Eigen::Vector3d& p) {
  return !p.allFinite() || (p.array() == 0.0).all();
}

bool IsClose(const Eigen::Vector3d& gt,
             const Eigen::Vector3d& rec,
             const MatchTolerance& tol) {
  for (int k = 0; k < 3; ++k) {
    if (!(std::abs(gt[k] - rec[k]) <= tol.atol)) {
      return false;
    }
  }
  return true;
}

/// Sorted union of the labels of `pairs` and the index of each.
std::vector<std::string> ClassesOf(const std::vector<LabelPair>& pairs) {
  std::vector<std::string> labels;
  labels.reserve(2 * pairs.size());
  for (const LabelPair& p : pairs) {
    labels.push_back(p.gt);
    labels.push_back(p.rec);
  }
  std::sort(labels.begin(), labels.end());
  labels.erase(std::unique(labels.begin(), labels.end()), labels.end());
  return labels;
}

int IndexOf(const std::vector<std::string>& sorted, const std::string& s) {
  return static_cast<int>(std::lower_bound(sorted.begin(), sorted.end(), s) -
                          sorted.begin());
}

}  // namespace

std::vector<LabelPair> MatchFrameLabels(
    const Eigen::Matrix3Xd& gt_points,
    const std::vector<std::string>& gt_labels,
    const Eigen::Matrix3Xd& rec_points,
    const std::vector<std::string>& rec_labels,
    const MatchTolerance& tolerance) {
  if (static_cast<Eigen::Index>(gt_labels.size()) != gt_points.cols() ||
      static_cast<Eigen::Index>(rec_labels.size()) != rec_points.cols()) {
    throw ShapeError(fmt::format(
        "MatchFrameLabels: {} ground-truth labels for {} points, {} predicted "
        "labels for {} points",
        gt_labels.size(),
        gt_points.cols(),
        rec_labels.size(),
        rec_points.cols()));
  }
  std::vector<int> rec_present;
  rec_present.reserve(rec_points.cols());
  for (Eigen::Index j = 0; j < rec_points.cols(); ++j) {
    if (!IsMissing(rec_points.col(j)))
      rec_present.push_back(static_cast<int>(j));
  }
  std::vector<LabelPair> pairs;
  for (Eigen::Index i = 0; i < gt_points.cols(); ++i) {
    if (IsMissing(gt_points.col(i))) continue;
    int match = -1, matches = 0;
    for (int j : rec_present) {
      if (IsClose(gt_points.col(i), rec_points.col(j), tolerance)) {
        match = j;
        if (++matches > 1) break;
      }
    }
    if (matches == 1) pairs.push_back({gt_labels[i], rec_labels[match]});
  }
  return pairs;
}

std::set<std::string> UnknownGroundTruthLabels(
    const std::vector<LabelPair>& pairs, const std::set<std::string>& known) {
  std::set<std::string> unknown;
  for (const LabelPair& pair : pairs) {
    if (pair.gt != kNullLabel && known.count(pair.gt) == 0) {
      unknown.insert(pair.gt);
    }
  }
  return unknown;
}

int64_t ScoreLabelsAsNull(const std::set<std::string>& labels,
                          std::vector<LabelPair>* pairs) {
  int64_t changed = 0;
  for (LabelPair& pair : *pairs) {
    if (labels.count(pair.gt) > 0 && pair.gt != kNullLabel) {
      pair.gt = std::string(kNullLabel);
      ++changed;
    }
  }
  return changed;
}

LabelingMetrics ComputeLabelingMetrics(const std::vector<LabelPair>& pairs) {
  if (pairs.empty()) {
    throw ShapeError("labelling metrics of an empty set of point pairs");
  }
  const std::vector<std::string> labels = ClassesOf(pairs);
  const size_t c = labels.size();
  std::vector<int64_t> tp(c, 0), support(c, 0), predicted(c, 0);
  int64_t correct = 0;
  for (const LabelPair& p : pairs) {
    const int g = IndexOf(labels, p.gt), r = IndexOf(labels, p.rec);
    ++support[g];
    ++predicted[r];
    if (g == r) {
      ++tp[g];
      ++correct;
    }
  }
  LabelingMetrics m;
  m.num_pairs = static_cast<int64_t>(pairs.size());
  m.accuracy = static_cast<double>(correct) / static_cast<double>(m.num_pairs);
  for (size_t k = 0; k < c; ++k) {
    ClassReport r;
    r.label = labels[k];
    r.support = support[k];
    r.predicted = predicted[k];
    r.precision =
        predicted[k] > 0 ? static_cast<double>(tp[k]) / predicted[k] : 0.0;
    r.recall = support[k] > 0 ? static_cast<double>(tp[k]) / support[k] : 0.0;
    // sklearn: F1 = 2 tp / (2 tp + fp + fn), 0 when undefined.
    const int64_t denom = support[k] + predicted[k];
    r.f1 = denom > 0
               ? 2.0 * static_cast<double>(tp[k]) / static_cast<double>(denom)
               : 0.0;
    m.precision += r.precision;
    m.recall += r.recall;
    m.f1 += r.f1;
    m.classes.push_back(std::move(r));
  }
  m.precision /= static_cast<double>(c);
  m.recall /= static_cast<double>(c);
  m.f1 /= static_cast<double>(c);
  return m;
}

ConfusionMatrix ComputeConfusionMatrix(const std::vector<LabelPair>& pairs) {
  ConfusionMatrix m;
  m.labels = ClassesOf(pairs);
  m.counts.assign(m.labels.size(), std::vector<int64_t>(m.labels.size(), 0));
  for (const LabelPair& p : pairs) {
    ++m.counts[IndexOf(m.labels, p.gt)][IndexOf(m.labels, p.rec)];
  }
  return m;
}

Summary Summarize(const std::vector<double>& values) {
  std::vector<double> v;
  v.reserve(values.size());
  for (double x : values) {
    if (std::isfinite(x)) v.push_back(x);
  }
  Summary s;
  s.count = static_cast<int64_t>(v.size());
  if (v.empty()) {
    s.mean = s.median = s.std = std::numeric_limits<double>::quiet_NaN();
    return s;
  }
  double sum = 0.0;
  for (double x : v) sum += x;
  s.mean = sum / static_cast<double>(v.size());
  double ss = 0.0;
  for (double x : v) ss += (x - s.mean) * (x - s.mean);
  s.std = std::sqrt(ss / static_cast<double>(v.size()));
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  s.median = n % 2 == 1 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
  return s;
}

void LabelingEvaluator::AddFrame(const std::vector<LabelPair>& pairs) {
  if (pairs.empty()) return;
  const LabelingMetrics m = ComputeLabelingMetrics(pairs);
  accuracy_.push_back(m.accuracy);
  precision_.push_back(m.precision);
  recall_.push_back(m.recall);
  f1_.push_back(m.f1);
  pooled_.insert(pooled_.end(), pairs.begin(), pairs.end());
}

LabelingEvaluator::Result LabelingEvaluator::Finish() const {
  if (accuracy_.empty()) {
    throw ShapeError(
        "labelling evaluation: no frame had a ground-truth point matching an "
        "output point (are the files the same capture, in the same units?)");
  }
  Result r;
  r.accuracy = Summarize(accuracy_);
  r.precision = Summarize(precision_);
  r.recall = Summarize(recall_);
  r.f1 = Summarize(f1_);
  r.pooled = ComputeLabelingMetrics(pooled_);
  r.num_frames = num_frames();
  return r;
}

void WriteClassReportCsv(const LabelingMetrics& metrics,
                         const std::filesystem::path& path) {
  std::ostringstream out;
  out << "label,precision,recall,f1,support,predicted\n";
  for (const ClassReport& r : metrics.classes) {
    out << fmt::format("{},{:.6f},{:.6f},{:.6f},{},{}\n",
                       CsvField(r.label),
                       r.precision,
                       r.recall,
                       r.f1,
                       r.support,
                       r.predicted);
  }
  out << fmt::format("macro avg,{:.6f},{:.6f},{:.6f},{},\n",
                     metrics.precision,
                     metrics.recall,
                     metrics.f1,
                     metrics.num_pairs);
  out << fmt::format(
      "accuracy,,,{:.6f},{},\n", metrics.accuracy, metrics.num_pairs);
  WriteFileAtomic(path, out.str());
}

void WriteConfusionMatrixCsv(const ConfusionMatrix& matrix,
                             const std::filesystem::path& path) {
  std::ostringstream out;
  out << "gt\\rec";
  for (const std::string& l : matrix.labels) out << ',' << CsvField(l);
  out << '\n';
  for (size_t i = 0; i < matrix.labels.size(); ++i) {
    out << CsvField(matrix.labels[i]);
    for (int64_t c : matrix.counts[i]) out << ',' << c;
    out << '\n';
  }
  WriteFileAtomic(path, out.str());
}

void WriteConfusionMatrixPng(const ConfusionMatrix& matrix,
                             const std::filesystem::path& path) {
  const int n = static_cast<int>(matrix.labels.size());
  const int cell = std::clamp(720 / std::max(n, 1), 6, 24);
  int label_width = 0;
  for (const std::string& l : matrix.labels) {
    label_width = std::max(label_width, Image::TextWidth(l));
  }
  const int margin = label_width + 12;
  const int title = 24;
  // Column labels are drawn vertically, one glyph per row of 8 pixels.
  int longest = 0;
  for (const std::string& l : matrix.labels) {
    longest = std::max(longest, static_cast<int>(l.size()));
  }
  const int top = title + 8 * longest + 8;
  Image image(margin + n * cell + 10, top + n * cell + 30);
  image.DrawText(8,
                 6,
                 "confusion (rows: ground truth, cols: predicted; "
                 "row-normalised)",
                 kBlack);
  for (int i = 0; i < n; ++i) {
    int64_t row_total = 0;
    for (int64_t c : matrix.counts[i]) row_total += c;
    image.DrawText(margin - 6 - Image::TextWidth(matrix.labels[i]),
                   top + i * cell + (cell - 7) / 2,
                   matrix.labels[i],
                   kBlack);
    for (int j = 0; j < n; ++j) {
      const double f = row_total > 0
                           ? static_cast<double>(matrix.counts[i][j]) /
                                 static_cast<double>(row_total)
                           : 0;
      const uint8_t v = static_cast<uint8_t>(std::lround(255.0 * (1.0 - f)));
      const Rgb color = i == j ? Rgb{v, v, 255} : Rgb{255, v, v};
      image.FillRect(margin + j * cell,
                     top + i * cell,
                     margin + (j + 1) * cell - 1,
                     top + (i + 1) * cell - 1,
                     f > 0 ? color : kWhite);
    }
  }
  for (int j = 0; j < n; ++j) {
    const std::string& l = matrix.labels[j];
    for (size_t k = 0; k < l.size(); ++k) {
      image.DrawText(margin + j * cell + (cell - 5) / 2,
                     title + static_cast<int>(k) * 8,
                     std::string(1, l[k]),
                     kBlack);
    }
  }
  image.DrawRect(margin - 1, top - 1, margin + n * cell, top + n * cell, kGray);
  image.WritePng(path);
}

}  // namespace soma
