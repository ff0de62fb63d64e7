// The labelers shipped with somalab (`models/<name>/` under the resource
// root, framework/core/resources.h), and choosing one for a capture.
//
// A bundled model is a directory holding
//   model.pt    a `soma train` checkpoint (weights, model config, labels);
//   card.yaml   its model card: how it was made and what it scores
//               (models/README.md documents the keys);
//   README.md   the same card for people;
//   markers.csv optional (the card's `markers`): its training layout's
//               markers on the mean body, standing (`soma inspect`'s
//               markers.csv: label,vertex_id,x,y,z in metres).
//   calibration.yaml optional: the temperature of its confidences
//               (`soma calibrate <name>`, framework/eval/calibration.h).
// `soma label take.c3d` without `task.checkpoint` picks the bundled model
// whose labels match the capture's (ChooseBundledModel).
#pragma once

#include "framework/config/node.h"

#include <Eigen/Core>

#include <filesystem>
#include <string>
#include <vector>

namespace soma {

struct C3dData;

/// One bundled labeler.
struct BundledModel {
  std::string name;                  // its directory name
  std::filesystem::path dir;         // models/<name>
  std::filesystem::path checkpoint;  // models/<name>/model.pt
  std::string layout;                // the card's `layout`: trained on what
  std::string description;           // the card's one-line `description`
  /// Among models whose labels match a capture equally well, the lowest
  /// priority wins (the card's `priority`, default 100).
  int priority = 100;
  std::vector<std::string> labels;  // the checkpoint's labels (model order)
  ConfigNode card;                  // card.yaml as parsed
  /// The training layout's markers (from markers.csv; empty without one).
  std::vector<std::string> marker_labels;  // canonical
  Eigen::Matrix3Xd marker_positions;       // metres, one column per label
};

/// What the chooser knows of a capture: its column labels and, to tell
/// apart models with the same labels but another marker placement, the
/// labelled points of up to 200 evenly spaced frames.
struct CaptureSummary {
  std::string name;
  std::vector<std::string> labels;  // raw C3D column labels
  /// Canonical label per column ("" for unlabelled columns) and the sampled
  /// frames, 3 x columns in metres, NaN where the point is missing.
  std::vector<std::string> canonical;
  std::vector<Eigen::Matrix3Xd> frames;
};

/// The summary of a C3D capture read from `c3d_path` (IoError naming the
/// file), or of one already read.
CaptureSummary SummarizeCapture(const std::filesystem::path& c3d_path);
CaptureSummary SummarizeCapture(const C3dData& c3d);

/// Every `<models_dir>/<name>/card.yaml` with its `model.pt`, ordered by
/// (priority, name). An empty list when `models_dir` does not exist; IoError
/// or ConfigError naming the file for a card or checkpoint that cannot be
/// read.
std::vector<BundledModel> ListBundledModels(
    const std::filesystem::path& models_dir);

/// How well a capture's labels fit a model's.
struct LabelMatch {
  int capture_labels = 0;  // distinct canonical labels in the capture
  int shared = 0;          // of those, labels the model has
  int model_labels = 0;
  /// shared / capture_labels: the share of the capture the model can name.
  double capture_coverage() const {
    return capture_labels > 0 ? static_cast<double>(shared) / capture_labels
                              : 0.0;
  }
  /// shared / |capture ∪ model| (Jaccard).
  double jaccard() const {
    const int unite = capture_labels + model_labels - shared;
    return unite > 0 ? static_cast<double>(shared) / unite : 0.0;
  }
  /// A capture matches a model when the model can name at least 90% of the
  /// capture's labels.
  bool matches() const {
    return capture_labels > 0 && capture_coverage() >= 0.9;
  }
};

/// Compares the capture's column labels (raw C3D labels: subject prefixes,
/// vendor aliases and `*k` unlabelled columns are handled through
/// CanonicalMarkerLabel) with a model's labels.
LabelMatch MatchLabels(const std::vector<std::string>& capture_labels,
                       const std::vector<std::string>& model_labels);

/// The model chosen for a capture, and one line saying why.
struct ModelChoice {
  const BundledModel* model = nullptr;
  std::string reason;
};

/// How far a capture's marker placement is from a model's training layout,
/// from the label pairs that are rigid in the capture (the distance varies
/// by less than 1 cm, standard deviation over the sampled frames, i.e. two
/// markers on one body segment): after one scale factor (the median ratio of
/// capture to layout distances) for the subject's size, the mean absolute
/// difference of those distances, in metres. NaN when fewer than 10 rigid
/// pairs are shared or the model has no markers.
double PlacementMismatch(const CaptureSummary& capture,
                         const BundledModel& model,
                         int* pairs_used = nullptr);

/// `requested` = a bundled model's name picks it; "auto" (or "") picks the
/// matching model (MatchLabels) with the highest Jaccard index. Among models
/// that match equally well (same labels, another placement, such as cmu41
/// and the fitted HDM05 layout) the one with the smallest PlacementMismatch
/// wins when every one of them can be measured, else the lowest
/// (priority, name). Throws ConfigError with one line that lists the
/// bundled models and how to train one when nothing matches (an unlabelled
/// capture matches nothing) or `requested` names no model.
ModelChoice ChooseBundledModel(const std::vector<BundledModel>& models,
                               const CaptureSummary& capture,
                               const std::string& requested);

/// The same from labels alone (no placement tie-break).
ModelChoice ChooseBundledModel(const std::vector<BundledModel>& models,
                               const std::vector<std::string>& capture_labels,
                               const std::string& requested,
                               const std::string& capture_name);

/// The bundled model chosen for a capture, copied out of the listing.
struct BundledChoice {
  BundledModel model;
  std::string reason;  // one line, for the log
};

/// ChooseBundledModel among the models of the resource root's `models/`
/// (framework/core/resources.h): what `soma label` and `soma label_eval`
/// use when no checkpoint is given.
BundledChoice ChooseInstalledModel(const CaptureSummary& capture,
                                   const std::string& requested);

/// "cmu41 (layout cmu41, 41 labels), hdm05 (...)" or "none".
std::string DescribeBundledModels(const std::vector<BundledModel>& models);

}  // namespace soma
