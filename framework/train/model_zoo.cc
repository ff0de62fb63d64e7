#include "framework/train/model_zoo.h"

#include "framework/body/marker_layout.h"
#include "framework/config/decode.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/resources.h"
#include "framework/io/c3d.h"
#include "framework/train/trainer.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <system_error>
#include <tuple>

namespace soma {
namespace fs = std::filesystem;

namespace {

std::set<std::string> CanonicalLabelSet(const std::vector<std::string>& raw) {
  std::set<std::string> out;
  for (const std::string& label : raw) {
    const std::string canonical = CanonicalMarkerLabel(label);
    if (canonical.empty() || canonical.front() == '*') continue;
    out.insert(canonical);
  }
  return out;
}

/// `soma inspect`'s markers.csv: a header, then label,vertex_id,x,y,z.
void ReadMarkersCsv(const fs::path& path, BundledModel* model) {
  std::istringstream in(ReadFile(path));
  std::string line;
  std::getline(in, line);  // header
  std::vector<Eigen::Vector3d> positions;
  int line_number = 1;
  while (std::getline(in, line)) {
    ++line_number;
    if (line.empty()) continue;
    std::vector<std::string> fields;
    std::stringstream row(line);
    for (std::string field; std::getline(row, field, ',');) {
      fields.push_back(field);
    }
    Eigen::Vector3d p;
    try {
      if (fields.size() != 5) throw std::invalid_argument("fields");
      for (int i = 0; i < 3; ++i) p[i] = std::stod(fields[2 + i]);
    } catch (const std::exception&) {
      throw IoError(fmt::format(
          "{}:{}: expected label,vertex_id,x,y,z", path.string(), line_number));
    }
    model->marker_labels.push_back(CanonicalMarkerLabel(fields[0]));
    positions.push_back(p);
  }
  model->marker_positions.resize(3,
                                 static_cast<Eigen::Index>(positions.size()));
  for (size_t i = 0; i < positions.size(); ++i) {
    model->marker_positions.col(static_cast<Eigen::Index>(i)) = positions[i];
  }
}

BundledModel ReadBundledModel(const fs::path& dir) {
  BundledModel model;
  model.name = dir.filename().string();
  model.dir = dir;
  const fs::path card_path = dir / "card.yaml";
  model.card = ParseYaml(ReadFile(card_path), card_path.string());
  ConfigReader reader(model.card);
  std::string checkpoint = "model.pt";
  reader.Read("checkpoint", &checkpoint);
  reader.Require("layout", &model.layout);
  reader.Require("description", &model.description);
  reader.Read("priority", &model.priority);
  std::string markers;
  reader.Read("markers", &markers);
  // The rest of the card (command, commit, machine, metrics) is for people
  // and for the test that checks the weights against it.
  for (const std::string& key : model.card.Keys()) reader.Ignore(key);
  reader.Finish();
  model.checkpoint = dir / checkpoint;
  if (!fs::exists(model.checkpoint)) {
    throw IoError(
        fmt::format("{}: the card names the checkpoint {}, which "
                    "does not exist",
                    card_path.string(),
                    model.checkpoint.string()));
  }
  model.labels = ReadCheckpointInfo(model.checkpoint).labels;
  if (!markers.empty()) ReadMarkersCsv(dir / markers, &model);
  return model;
}

}  // namespace

std::vector<BundledModel> ListBundledModels(const fs::path& models_dir) {
  std::vector<BundledModel> models;
  std::error_code ec;
  if (!fs::is_directory(models_dir, ec)) return models;
  for (const fs::directory_entry& entry : fs::directory_iterator(models_dir)) {
    if (entry.is_directory() && fs::exists(entry.path() / "card.yaml")) {
      models.push_back(ReadBundledModel(entry.path()));
    }
  }
  std::sort(models.begin(),
            models.end(),
            [](const BundledModel& a, const BundledModel& b) {
              return std::tie(a.priority, a.name) <
                     std::tie(b.priority, b.name);
            });
  return models;
}

LabelMatch MatchLabels(const std::vector<std::string>& capture_labels,
                       const std::vector<std::string>& model_labels) {
  const std::set<std::string> capture = CanonicalLabelSet(capture_labels);
  const std::set<std::string> model = CanonicalLabelSet(model_labels);
  LabelMatch match;
  match.capture_labels = static_cast<int>(capture.size());
  match.model_labels = static_cast<int>(model.size());
  for (const std::string& label : capture) match.shared += model.count(label);
  return match;
}

std::string DescribeBundledModels(const std::vector<BundledModel>& models) {
  if (models.empty()) return "none";
  std::string out;
  for (const BundledModel& m : models) {
    out += fmt::format("{}{} (layout {}, {} labels)",
                       out.empty() ? "" : ", ",
                       m.name,
                       m.layout,
                       m.labels.size());
  }
  return out;
}

CaptureSummary SummarizeCapture(const fs::path& c3d_path) {
  CaptureSummary summary = SummarizeCapture(ReadC3d(c3d_path));
  summary.name = c3d_path.string();
  return summary;
}

CaptureSummary SummarizeCapture(const C3dData& c3d) {
  CaptureSummary summary;
  summary.name = c3d.source;
  summary.labels = c3d.labels;
  for (const std::string& label : c3d.labels) {
    const std::string canonical = CanonicalMarkerLabel(label);
    summary.canonical.push_back(
        canonical.empty() || canonical.front() == '*' ? "" : canonical);
  }
  constexpr int kMaxFrames = 200;
  const int n = std::min(kMaxFrames, c3d.num_frames);
  const double to_metres = c3d.MetresPerUnit();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (int i = 0; i < n; ++i) {
    const int t = static_cast<int>(int64_t{i} * c3d.num_frames / n);
    Eigen::Matrix3Xd frame = Eigen::Matrix3Xd::Constant(3, c3d.num_points, nan);
    for (int k = 0; k < c3d.num_points; ++k) {
      if (!c3d.valid(t, k)) continue;
      const Eigen::Vector3d p = c3d.Point(t, k).cast<double>() * to_metres;
      if (p.allFinite() && !p.isZero()) frame.col(k) = p;
    }
    summary.frames.push_back(std::move(frame));
  }
  return summary;
}

double PlacementMismatch(const CaptureSummary& capture,
                         const BundledModel& model,
                         int* pairs_used) {
  constexpr double kRigidStd = 0.01;  // metres
  constexpr int kMinPairs = 10;
  if (pairs_used) *pairs_used = 0;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (model.marker_labels.empty() || capture.frames.empty()) return nan;
  std::map<std::string, int> marker_of;
  for (size_t m = 0; m < model.marker_labels.size(); ++m) {
    marker_of.emplace(model.marker_labels[m], static_cast<int>(m));
  }
  // The first capture column of each label the model has.
  std::vector<std::pair<int, int>> columns;  // (capture column, marker)
  std::map<std::string, bool> seen;
  for (size_t k = 0; k < capture.canonical.size(); ++k) {
    const auto it = marker_of.find(capture.canonical[k]);
    if (it == marker_of.end() || seen[it->first]) continue;
    seen[it->first] = true;
    columns.emplace_back(static_cast<int>(k), it->second);
  }
  const int num_frames = static_cast<int>(capture.frames.size());
  std::vector<std::pair<double, double>> rigid;  // (capture, layout) distance
  for (size_t a = 0; a < columns.size(); ++a) {
    for (size_t b = a + 1; b < columns.size(); ++b) {
      double sum = 0, sum_sq = 0;
      int count = 0;
      for (const Eigen::Matrix3Xd& f : capture.frames) {
        const Eigen::Vector3d pa = f.col(columns[a].first);
        const Eigen::Vector3d pb = f.col(columns[b].first);
        if (!pa.allFinite() || !pb.allFinite()) continue;
        const double d = (pa - pb).norm();
        sum += d;
        sum_sq += d * d;
        ++count;
      }
      if (count < std::max(3, num_frames / 2)) continue;
      const double mean = sum / count;
      const double var = std::max(0.0, sum_sq / count - mean * mean);
      const double layout = (model.marker_positions.col(columns[a].second) -
                             model.marker_positions.col(columns[b].second))
                                .norm();
      if (std::sqrt(var) < kRigidStd && layout > 1e-6) {
        rigid.emplace_back(mean, layout);
      }
    }
  }
  if (static_cast<int>(rigid.size()) < kMinPairs) return nan;
  std::vector<double> ratios;
  for (const auto& [cap, lay] : rigid) ratios.push_back(cap / lay);
  std::nth_element(
      ratios.begin(), ratios.begin() + ratios.size() / 2, ratios.end());
  const double scale = ratios[ratios.size() / 2];
  double total = 0;
  for (const auto& [cap, lay] : rigid) total += std::abs(cap - scale * lay);
  if (pairs_used) *pairs_used = static_cast<int>(rigid.size());
  return total / static_cast<double>(rigid.size());
}

namespace {

constexpr const char* kHowToTrain =
    "train one with `soma train scale=cpu layout=file "
    "layout.path=<layout.json>` (a layout from one labelled frame: `soma "
    "fit_layout take.c3d`) and pass task.checkpoint=<run>/checkpoints/"
    "best.pt";

/// The models that match `capture_labels` best (equal Jaccard), in
/// (priority, name) order; ConfigError when none matches.
std::vector<const BundledModel*> BestLabelMatches(
    const std::vector<BundledModel>& models,
    const std::vector<std::string>& capture_labels,
    const std::string& capture_name,
    LabelMatch* best_match) {
  std::vector<const BundledModel*> best;
  for (const BundledModel& m : models) {
    const LabelMatch match = MatchLabels(capture_labels, m.labels);
    if (!match.matches()) continue;
    if (best.empty() || match.jaccard() > best_match->jaccard() + 1e-12) {
      best = {&m};
      *best_match = match;
    } else if (std::abs(match.jaccard() - best_match->jaccard()) <= 1e-12) {
      best.push_back(&m);
    }
  }
  if (best.empty()) {
    const LabelMatch any = MatchLabels(capture_labels, {});
    throw ConfigError(fmt::format(
        "{}: no bundled model matches the capture's labels ({} named "
        "labels{}); bundled: {}. Pass task.model=<name> to use one anyway, "
        "or {}",
        capture_name,
        any.capture_labels,
        any.capture_labels == 0 ? ": an unlabelled capture" : "",
        DescribeBundledModels(models),
        kHowToTrain));
  }
  return best;
}

const BundledModel* FindByName(const std::vector<BundledModel>& models,
                               const std::string& requested) {
  for (const BundledModel& m : models) {
    if (m.name == requested) return &m;
  }
  throw ConfigError(
      fmt::format("task.model={}: no such bundled model; bundled: {}. Or {}",
                  requested,
                  DescribeBundledModels(models),
                  kHowToTrain));
}

std::string LabelReason(const BundledModel& m, const LabelMatch& match) {
  return fmt::format(
      "bundled model '{}' ({}): it names {} of the capture's {} labels",
      m.name,
      m.description,
      match.shared,
      match.capture_labels);
}

}  // namespace

ModelChoice ChooseBundledModel(const std::vector<BundledModel>& models,
                               const std::vector<std::string>& capture_labels,
                               const std::string& requested,
                               const std::string& capture_name) {
  CaptureSummary capture;
  capture.name = capture_name;
  capture.labels = capture_labels;
  return ChooseBundledModel(models, capture, requested);
}

ModelChoice ChooseBundledModel(const std::vector<BundledModel>& models,
                               const CaptureSummary& capture,
                               const std::string& requested) {
  if (!requested.empty() && requested != "auto") {
    const BundledModel* m = FindByName(models, requested);
    return {
        m,
        fmt::format("bundled model '{}' (task.model={})", m->name, requested)};
  }
  LabelMatch match;
  const std::vector<const BundledModel*> best =
      BestLabelMatches(models, capture.labels, capture.name, &match);
  if (best.size() == 1)
    return {best.front(), LabelReason(*best.front(), match)};

  // Same labels, other placements: the layout that fits the capture's rigid
  // marker pairs best, when every candidate can be measured.
  std::vector<double> mismatch;
  std::vector<int> pairs;
  for (const BundledModel* m : best) {
    int n = 0;
    mismatch.push_back(PlacementMismatch(capture, *m, &n));
    pairs.push_back(n);
  }
  const bool measurable =
      std::all_of(mismatch.begin(), mismatch.end(), [](double x) {
        return std::isfinite(x);
      });
  if (measurable) {
    const size_t pick = static_cast<size_t>(
        std::min_element(mismatch.begin(), mismatch.end()) - mismatch.begin());
    std::string reason = LabelReason(*best[pick], match) +
                         fmt::format(
                             ", and its marker placement fits best "
                             "({:.1f} mm mean difference over {} rigid "
                             "marker pairs",
                             1000 * mismatch[pick],
                             pairs[pick]);
    for (size_t i = 0; i < best.size(); ++i) {
      if (i == pick) continue;
      reason += fmt::format("; '{}' {:.1f} mm, task.model={}",
                            best[i]->name,
                            1000 * mismatch[i],
                            best[i]->name);
    }
    return {best[pick], reason + ")"};
  }
  std::string reason = LabelReason(*best.front(), match);
  for (size_t i = 1; i < best.size(); ++i) {
    reason += fmt::format(
        "; '{}' matches as well (task.model={})", best[i]->name, best[i]->name);
  }
  return {best.front(), reason};
}

BundledChoice ChooseInstalledModel(const CaptureSummary& capture,
                                   const std::string& requested) {
  const std::vector<BundledModel> models =
      ListBundledModels(ResourcePath("models"));
  const ModelChoice choice = ChooseBundledModel(models, capture, requested);
  return {*choice.model, choice.reason};
}

}  // namespace soma
