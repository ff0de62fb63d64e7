// The evaluation corruption protocol on real labelled mocap (REFERENCE.md
// 3.6, SOMA's `inject_synthetic_noise_into_real_mocap`): clean, manually
// labelled real sequences get synthetic occlusions, ghost points, one column
// permutation and broken trajectories, and keep their per-frame ground truth
// so that a labeller's output can be scored against it.
//
// For each setting (OC, G, BT) and sequence of T frames x K columns:
//  1. occlusion: per frame k = OC if exact, else k ~ U{0..OC-1} (exclusive
//     upper bound, unlike training); k distinct columns are zeroed;
//  2. ghosts: G columns of spherical Gaussian points around the per-frame
//     median with the per-frame (unbiased) std, both over ALL K columns
//     including zeros; up-to rejection: each of G draws r ~ U{0..3G-1}
//     zeroes ghost r when r < G; ghosts are labelled null (the sampling of
//     the ghosts noise module, ghosts.h, with exactly G ghosts);
//  3. every zero point is labelled null; one random permutation of the
//     columns (the same for all frames, so columns stay tracklets);
//  4. broken trajectories: min(BT, T) distinct cut times from [2, T-2],
//     ascending; at each, a random cuttable column (re-drawn while its label
//     at t is null; drawn columns leave the pool) is zeroed from t on and a
//     new column with its data from t on is appended (null before t); the
//     new column joins the pool. Sequences with T < 3 BT are skipped.
//  5. columns are anonymised `*000`, `*001`, ...
#pragma once

#include "framework/io/mocap_dataset.h"

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace soma {

/// One corruption setting of the protocol.
struct CorruptionSetting {
  int occlusions = 0;  // OC: up to OC-1 per frame (exactly OC if exact)
  bool exact_occlusions = false;  // k = OC in every frame
  int ghosts = 0;               // G: ghost columns (up-to rejection per frame)
  int broken_trajectories = 0;  // BT: max number of trajectory cuts

  bool operator==(const CorruptionSetting&) const = default;
};

/// "OC_05_G_03_BT_00" (`OCE_` for exact occlusions); numbers are zero-padded
/// to two digits (wider numbers are printed in full).
std::string CorruptionSettingName(const CorruptionSetting& setting);

/// Inverse of CorruptionSettingName; ConfigError for anything else.
CorruptionSetting ParseCorruptionSettingName(const std::string& name);

/// A labelled sequence: T frames of K columns (tracklets).
///  - input (clean real data): column k is one labelled marker; its label id
///    in every frame where it is present, null where missing;
///  - output (corrupted): anonymised columns, per-frame ground-truth ids.
struct LabeledSequence {
  std::string name;                       // source take, for names/messages
  double frame_rate = 0.0;                // Hz
  std::vector<std::string> label_names;   // L: id -> name (layout order)
  std::vector<std::string> column_names;  // K: one per column
  /// T x K points in metres ((0,0,0) = missing) and per-frame label ids
  /// (null = L).
  LabeledFrames frames;

  int64_t num_frames() const { return frames.num_frames(); }
  int num_columns() const { return frames.num_points; }
  int null_label() const { return static_cast<int>(label_names.size()); }
};

/// Reads a labelled C3D restricted to `layout_labels` (canonical names, id
/// order): labels go through CanonicalMarkerLabel (subject prefix stripped,
/// aliases mapped); points whose label is not in the layout (e.g. HDM05's
/// `*0..*2` copies, other subjects' extra markers) are dropped; a label seen
/// twice keeps its first point. Columns are in layout order (only labels
/// present in the file); coordinates converted to metres; invalid points
/// are (0,0,0) with the null label. IoError if no layout label is present
/// or the file looks like several subjects (matched points / distinct
/// labels > 1.5, SOMA's rule).
LabeledSequence ReadLabeledC3d(const std::filesystem::path& path,
                               const std::vector<std::string>& layout_labels);

/// Why `setting` cannot be applied to `sequence` ("" if it can): T < 3 BT,
/// or more occlusions than columns.
std::string CorruptionSkipReason(const LabeledSequence& sequence,
                                 const CorruptionSetting& setting);

/// Statistics of one corrupted sequence (for logs and metrics).
struct CorruptionSummary {
  double missing_before = 0.0;    // fraction of zero points in the clean input
  double missing_after = 0.0;     // fraction of zero real points after step 1
  double ghosts_per_frame = 0.0;  // mean non-zero ghosts per frame
  int cuts = 0;                   // trajectories broken (= new columns)
};

/// Applies `setting` with the random streams of `seed` (each setting and
/// sequence name gets its own sub-stream, so adding one never changes
/// another). ShapeError if CorruptionSkipReason is not empty.
LabeledSequence CorruptSequence(const LabeledSequence& clean,
                                const CorruptionSetting& setting,
                                uint64_t seed,
                                CorruptionSummary* summary = nullptr);

/// Writes `<stem>.c3d` (the corrupted points in mm, anonymised labels,
/// missing points invalid) and its ground truth `<stem>.h5` (a soma dataset,
/// docs/dataset_format.md: points in metres, labels = per-frame ground-truth
/// ids, attribute labels = label_names, plus `source`, `setting` and
/// `columns`). Both written atomically.
void WriteCorruptedSequence(const LabeledSequence& sequence,
                            const std::filesystem::path& stem,
                            const std::string& setting_name,
                            uint64_t seed);

}  // namespace soma
