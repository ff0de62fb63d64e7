// A marker layout from one labelled frame: fit the body (stage I on that
// single frame: shape, latent marker placement and pose) to a labelled real
// frame, then give every label the canonical vertex nearest to its fitted
// latent marker (MoSh++'s markers_latent_vids, the "finetuned" layout) and
// report its distance along that vertex's normal.
#pragma once

#include "framework/body/marker_layout.h"
#include "framework/solve/labelled_markers.h"
#include "framework/solve/pose_prior.h"
#include "framework/solve/stage_i.h"
#include "framework/solve/stage_ii.h"

#include <string>
#include <vector>

namespace soma {

struct LayoutFitResult {
  /// `initial` with each label's vertex ids replaced by the nearest vertex
  /// of the fitted latent marker; types and per-type distances kept.
  MarkerLayout layout;
  StageIResult fit;
  /// Per marker (layout order): signed distance of the latent marker along
  /// the normal of its new vertex (metres), and |sim - obs| in the fitted
  /// frame (NaN where the frame lacks the marker).
  std::vector<double> normal_distances;
  std::vector<double> residuals_m;
  double rms_m = 0.0;  // RMS of residuals_m over observed markers
  int markers_used = 0;
  /// The written layout as it will be used: its vertices offset along their
  /// normals by the layout's per-type distances on the fitted shape, posed
  /// to the frame anew (stage II, shape fixed). RMS over observed markers:
  /// what the layout itself explains, without stage I's free offsets.
  double layout_rms_m = 0.0;
};

/// `initial` with each label's vertex ids replaced by the vertex of the
/// body shaped by `betas` nearest to its latent marker (columns of `latent`,
/// rest frame); `normal_distances` (optional) gets the signed distance of
/// each latent marker along its new vertex's normal.
MarkerLayout NearestVertexLayout(const BodyModel& body,
                                 const MarkerLayout& initial,
                                 const Eigen::VectorXd& betas,
                                 const Eigen::Matrix3Xd& latent,
                                 std::vector<double>* normal_distances);

/// Fits `body` to frame `frame` of `markers` (matched to `initial`, e.g. by
/// MatchToLayout). `prior` may be null; `repose` solves the pose of the
/// derived layout (layout_rms_m). Throws Error if the frame has fewer than
/// 3 markers.
LayoutFitResult FitLayoutToFrame(const BodyModel& body,
                                 const MarkerLayout& initial,
                                 const LabelledMarkers& markers,
                                 int frame,
                                 const PosePrior* prior,
                                 const StageIOptions& options,
                                 const StageIIOptions& repose = {});

/// The frame of `markers` with the most observed markers (the first of
/// equals): a default frame for FitLayoutToFrame.
int MostCompleteFrame(const LabelledMarkers& markers);

/// CSV of a fit: label,vertex_id,initial_vertex_id,normal_distance_mm,
/// residual_mm.
std::string LayoutFitToCsv(const LayoutFitResult& fit,
                           const MarkerLayout& initial);

// ---- A layout for a capture with a marker set we have never seen (issue
// #25 item 2): fit the body to the markers the alias table recognises, then
// place every other marker of the frame on the fitted body.

/// What became of one marker of the capture.
enum class MarkerPlacement {
  kFitted,     // recognised: fitted by stage I, nearest vertex of its latent
  kPlaced,     // not recognised: nearest surface point of the fitted body
  kMissing,    // not observed in the chosen frame: not placed
  kTooFar,     // farther than max_skin_distance_m from the body: not placed
  kInside,     // deeper than max_depth_m inside the body: not placed
  kDuplicate,  // repeats an earlier column's label: not placed
};
std::string_view ToString(MarkerPlacement placement);

struct CaptureLayoutOptions {
  /// Recognised markers (observed in the frame) needed to fit the body.
  /// Stage I fits the pose (3 + 3J), betas and free offsets from one frame;
  /// with fewer markers it fits them almost exactly and places nothing
  /// reliably (Res16bits: 6 recognised, fit RMS 1.9 mm, a meaningless body).
  int min_recognised = 12;
  /// A marker whose nearest surface point on the fitted, posed body is
  /// farther than this is not placed (metres). Markers sit 5-40 mm off the
  /// skin (9.5 mm body markers, 39 mm wrist bars); 60 mm leaves room for a
  /// body shape that is off by a couple of centimetres and rejects points
  /// that are not on the body (props, Plug-in Gait's virtual segment
  /// points).
  double max_skin_distance_m = 0.060;
  /// A point this far inside the fitted body's surface (metres) is no skin
  /// marker (Plug-in Gait's joint centres and segment origins, which the
  /// file does not tell from markers): not placed. Real markers on a fitted
  /// body lie outside or a few millimetres inside (a body a little too
  /// broad).
  double max_depth_m = 0.020;
  void Validate() const;  // ConfigError naming task.<key>
};

/// One marker (column) of the capture.
struct CaptureLayoutMarker {
  std::string label;     // the capture's name, subject prefix stripped
  std::string match_as;  // the name matched to the layout (name map applied)
  std::string recognised_as;  // the layout label it matched, "" if none
  MarkerPlacement placement = MarkerPlacement::kMissing;
  int vertex_id = -1;  // in the written layout; -1 if not placed
  /// Signed distance from the fitted posed body's surface (to the nearest
  /// surface point; negative inside), and along the chosen vertex's normal,
  /// metres (NaN if not observed).
  double skin_distance_m = 0.0;
  double normal_distance_m = 0.0;
  /// |sim - obs| of the written layout re-posed on the frame (NaN if not
  /// placed).
  double layout_residual_m = 0.0;
};

struct CaptureLayoutResult {
  /// Every placed marker under the capture's name: vertex + the per-type
  /// distance along the normal (BuiltinMarkerType / BuiltinDistanceFromSkin:
  /// body 9.5 mm, wrist bar 39 mm), sorted (MarkerLayout::Sort).
  MarkerLayout layout;
  int frame = 0;
  /// Stage I on the recognised markers (its layout: the recognition
  /// layout's labels).
  LayoutFitResult fit;
  std::vector<CaptureLayoutMarker> markers;  // capture column order
  int recognised = 0;  // distinct recognised labels of the capture
  int placed = 0;      // markers in `layout` (fitted + placed)
  int not_placed = 0;  // missing, too far or duplicate
  /// Layout labels the capture does not have.
  std::vector<std::string> absent_labels;
  /// The written layout re-posed on the frame (stage II, shape fixed): RMS
  /// over every marker of `layout`, and over the fitted ones only.
  double layout_rms_m = 0.0;
  double fitted_layout_rms_m = 0.0;
};

/// The marker columns of a capture: labelled points that are neither model
/// outputs (ModelOutputColumns of io/c3d.h: POINT:ANGLES ... and Plug-in
/// Gait's virtual points) nor unlabelled (`*k`); `labels` as in the file,
/// `frames` one 3 x columns matrix per frame in metres, NaN = missing.
void CaptureMarkerColumns(const C3dData& c3d,
                          std::vector<std::string>* labels,
                          std::vector<Eigen::Matrix3Xd>* frames);

/// Fits `recognition` (a layout whose labels the capture's are matched to
/// through CanonicalMarkerLabel) to frame `frame` (-1: the frame with the
/// most observed markers, then the most recognised ones) of a capture given
/// as column labels and frames (3 x columns, metres, NaN = missing), and
/// places the other markers. `match_as` (empty, or one per column): the
/// names to match, e.g. the labels through a name map. Throws Error naming
/// how many markers were recognised, the minimum and their names when fewer
/// than options.min_recognised recognised markers are observed in the frame.
CaptureLayoutResult FitCaptureLayout(
    const BodyModel& body,
    const MarkerLayout& recognition,
    const std::vector<std::string>& labels,
    const std::vector<std::string>& match_as,
    const std::vector<Eigen::Matrix3Xd>& frames,
    int frame,
    const PosePrior* prior,
    const CaptureLayoutOptions& options,
    const StageIOptions& stagei,
    const StageIIOptions& repose = {});

/// CSV of a capture layout, one row per capture column: label,placement,
/// recognised_as,vertex_id,skin_distance_mm,normal_distance_mm,
/// layout_residual_mm (empty cells where not applicable).
std::string CaptureLayoutToCsv(const CaptureLayoutResult& result);

/// The nearest point of the triangle mesh (vertices 3 x V, faces 3 x F) to
/// `point`: returns the face index and sets `closest` (brute force).
int NearestSurfacePoint(const Eigen::Vector3d& point,
                        const Eigen::Matrix3Xd& vertices,
                        const Eigen::Matrix3Xi& faces,
                        Eigen::Vector3d* closest);

}  // namespace soma
