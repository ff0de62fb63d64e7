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

}  // namespace soma
