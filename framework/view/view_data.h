// The data of a `soma view` page (issue #27): a capture's points per frame,
// their labels, ground truth, confidences and trajectory ids, packed as
// base64 typed arrays into one JSON object that the page template
// (viewer/soma_view.html, built from viewer/src) reads at load time.
//
// The embedded JSON (format "soma-view", format_version 1) is documented in
// README.md, "File formats"; every array is {"dtype", "length", "base64"} of
// little-endian values:
//   per shown frame (F):  frame (uint32, 0-based take frame), offset (uint32,
//                         F + 1: the frame's points are [offset[f],
//                         offset[f+1])), accuracy (float32, NaN = no pairs;
//                         with ground truth), confidence_mean (float32, NaN =
//                         no point; with confidences)
//   per shown point (P):  position (float32, 3 P, metres), label (uint8 or
//                         uint16: id into `labels`, L = null), truth (same
//                         dtype: L = null, L + 1 = no ground-truth point;
//                         with ground truth), status (uint8 PointStatus; with
//                         ground truth), confidence (uint16: round(c * 65534),
//                         65535 = unknown; with confidences), track (int16 or
//                         int32: trajectory id, -1 = unknown)
//   body meshes (with a solve): mesh_faces (uint16 or uint32, 3 F vertex
//                         ids), mesh_frame (uint32: the take frame of each
//                         mesh), mesh_vertices (int16 millimetres, rounded,
//                         or float32 metres when a coordinate is beyond
//                         +-32.7 m: 3 V per mesh)
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// RFC 4648 base64 (standard alphabet, '=' padding) of `size` bytes.
std::string Base64Encode(const void* data, size_t size);

/// A string as a JSON string literal (quotes included). Besides the JSON
/// escapes, '<', '>' and '&' are written as \u003c, \u003e, \u0026, so the
/// literal can sit inside an HTML <script> element.
std::string JsonString(std::string_view text);

/// Correctness of a labelled point against ground truth (the colour mode
/// "correctness" of the page).
enum class PointStatus : uint8_t {
  kNoTruth = 0,        ///< no ground truth given, or no ground-truth point
                       ///< at these coordinates
  kCorrect = 1,        ///< label == true label (marker or null)
  kWrong = 2,          ///< a marker labelled as another marker
  kGhostAsMarker = 3,  ///< a ghost (true null) labelled as a marker
  kMissed = 4,         ///< a marker labelled null
};

/// The status of a point with label id `label` and true label id `truth`
/// (ids < num_labels are markers, num_labels = null, num_labels + 1 = no
/// ground-truth point).
PointStatus ClassifyPoint(int label, int truth, int num_labels);

/// A whole capture as the page shows it, before subsampling. Points are
/// stored frame after frame; frame t holds points [offsets[t],
/// offsets[t+1]).
struct ViewFrames {
  std::string title;                       ///< shown in the page header
  double frame_rate = 0.0;                 ///< Hz
  int64_t first_frame = 1;                 ///< C3D number of frame 0
  std::vector<std::string> labels;         ///< L class names; id L = null
  std::vector<std::array<int, 2>> sticks;  ///< label-id pairs drawn as lines
  /// Provenance shown in the page: input files and what the track ids are.
  std::string source, truth_source, confidence_source, track_source;

  /// Whether `truth` / `confidence` are filled (set before AddPoint).
  bool with_truth = false;
  bool with_confidence = false;

  std::vector<int64_t> offsets{0};  ///< T + 1
  std::vector<float> positions;     ///< 3 P, metres, z up
  std::vector<int> label;           ///< P label ids (L = null)
  std::vector<int> truth;           ///< P true ids (L null, L+1 none)
  std::vector<float> confidence;    ///< P in [0, 1] (NaN unknown)
  std::vector<int> track;           ///< P trajectory ids (-1 unknown)

  /// Optional body meshes (a `soma solve` fit), drawn semi-transparent:
  /// triangles (3 F vertex ids), and per mesh its take frame (ascending)
  /// and posed vertices (3 V, metres). `mesh_step`: take frames between two
  /// meshes (the page shows a mesh within that distance of the frame).
  std::vector<int> mesh_faces;
  std::vector<int> mesh_frames;
  std::vector<std::vector<float>> mesh_vertices;
  int mesh_step = 1;
  std::string mesh_source;
  bool has_mesh() const { return !mesh_frames.empty(); }

  int num_frames() const { return static_cast<int>(offsets.size()) - 1; }
  /// Points of the closed frames.
  int64_t num_points() const { return offsets.back(); }
  int null_id() const { return static_cast<int>(labels.size()); }
  bool has_truth() const { return with_truth; }
  bool has_confidence() const { return with_confidence; }

  /// Appends one point to the current frame; `truth_id` and
  /// `point_confidence` are kept only when with_truth / with_confidence.
  void AddPoint(const float position[3],
                int label_id,
                int truth_id,
                float point_confidence,
                int track_id);
  /// Closes the current frame (the next AddPoint starts a new one).
  void EndFrame() { offsets.push_back(static_cast<int64_t>(label.size())); }
  /// ShapeError unless every per-point array has P entries (3 P
  /// positions), ids are in range and offsets are non-decreasing.
  void Validate() const;
};

/// How to pack a page.
struct ViewPageOptions {
  /// Largest page in bytes (template included); frames are subsampled
  /// (every k-th frame, k as small as fits) above it. The README's ~30 MB.
  int64_t max_page_bytes = 30'000'000;
  /// Bytes of the template the data goes into (counted against the limit).
  int64_t template_bytes = 0;
  void Validate() const;
};

/// What PackViewData did.
struct ViewDataSummary {
  int take_frames = 0;   ///< T
  int shown_frames = 0;  ///< F = ceil(T / frame_step)
  int frame_step = 1;    ///< 1 = every frame
  int64_t shown_points = 0;
  int64_t data_bytes = 0;  ///< size of the JSON
  /// Over the shown points (with ground truth): points per PointStatus.
  std::array<int64_t, 5> status_counts{};
  std::string note;  ///< the subsampling note shown in the page ("" if none)
};

/// Base64 bytes of the arrays of the frames t = 0, step, 2 step, ... and of
/// the meshes (the estimate ChooseFrameStep compares with the budget).
int64_t EstimateDataBytes(const ViewFrames& frames, int step);

/// Base64 bytes of `num_meshes` meshes of `num_vertices` vertices and
/// `num_faces` triangles (int16 vertices).
int64_t EstimateMeshBytes(int num_vertices, int num_faces, int num_meshes);

/// The smallest k >= 1 such that every k-th of `num_candidates` meshes fits
/// `budget_bytes`; 0 when not even one mesh does.
int ChooseMeshStep(int num_vertices,
                   int num_faces,
                   int num_candidates,
                   int64_t budget_bytes);

/// The smallest step k >= 1 whose page (data + template + 64 KiB for the
/// JSON's other fields) fits `options.max_page_bytes`. ConfigError if not
/// even the first frame alone fits.
int ChooseFrameStep(const ViewFrames& frames, const ViewPageOptions& options);

/// The page's JSON object (format "soma-view" 1, see the file comment) of
/// every `ChooseFrameStep`-th frame; `summary` (optional) says what was
/// packed.
std::string PackViewData(const ViewFrames& frames,
                         const ViewPageOptions& options,
                         ViewDataSummary* summary = nullptr);

/// The placeholder of the template that PackViewData's JSON replaces.
inline constexpr std::string_view kViewDataPlaceholder = "__SOMA_VIEW_DATA__";

/// `html` with its one kViewDataPlaceholder replaced by `json`. IoError
/// naming `template_name` if the placeholder is missing or not unique.
std::string FillViewTemplate(std::string_view html,
                             std::string_view json,
                             std::string_view template_name);

}  // namespace soma
