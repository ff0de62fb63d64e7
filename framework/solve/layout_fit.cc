#include "framework/solve/layout_fit.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <cmath>
#include <limits>
#include <sstream>

namespace soma {

MarkerLayout NearestVertexLayout(const BodyModel& body,
                                 const MarkerLayout& initial,
                                 const Eigen::VectorXd& betas,
                                 const Eigen::Matrix3Xd& latent,
                                 std::vector<double>* normal_distances) {
  if (latent.cols() != initial.num_markers()) {
    throw ShapeError(
        fmt::format("NearestVertexLayout: {} latent markers for "
                    "{} layout markers",
                    latent.cols(),
                    initial.num_markers()));
  }
  const Eigen::Matrix3Xd shaped = body.ShapedVertices(betas);
  const Eigen::Matrix3Xd normals = VertexNormals(shaped, body.faces);
  MarkerLayout layout = initial;
  if (normal_distances != nullptr) normal_distances->clear();
  for (int m = 0; m < initial.num_markers(); ++m) {
    Eigen::Index best = 0;
    (shaped.colwise() - latent.col(m)).colwise().squaredNorm().minCoeff(&best);
    layout.markers[m].vertex_ids = {static_cast<int>(best)};
    if (normal_distances != nullptr) {
      normal_distances->push_back(
          normals.col(best).dot(latent.col(m) - shaped.col(best)));
    }
  }
  return layout;
}

LayoutFitResult FitLayoutToFrame(const BodyModel& body,
                                 const MarkerLayout& initial,
                                 const LabelledMarkers& markers,
                                 int frame,
                                 const PosePrior* prior,
                                 const StageIOptions& options,
                                 const StageIIOptions& repose) {
  if (frame < 0 || frame >= markers.num_frames()) {
    throw ShapeError(fmt::format(
        "FitLayoutToFrame: frame {} of {}", frame, markers.num_frames()));
  }
  if (static_cast<int>(markers.labels.size()) != initial.num_markers()) {
    throw ShapeError(
        "FitLayoutToFrame: markers were matched to another layout");
  }
  const auto [vids, distances] = MarkerVertices(initial);
  MarkerModel model(body, vids);
  LayoutFitResult result;
  result.fit = SolveStageI(
      body, &model, distances, {markers.frames[frame]}, prior, options);
  result.fit.frames = {frame};

  // Residuals in the fitted frame.
  const Eigen::Matrix3Xd& obs = markers.frames[frame];
  Eigen::Matrix3Xd sim;
  model.Evaluate(result.fit.frame_params[0].data(), {}, &sim, nullptr);
  double sq = 0.0;
  for (int m = 0; m < model.num_markers(); ++m) {
    if (obs.col(m).allFinite()) {
      const double r = (sim.col(m) - obs.col(m)).norm();
      result.residuals_m.push_back(r);
      sq += r * r;
      ++result.markers_used;
    } else {
      result.residuals_m.push_back(std::numeric_limits<double>::quiet_NaN());
    }
  }
  result.rms_m = std::sqrt(sq / std::max(1, result.markers_used));

  result.layout = NearestVertexLayout(body,
                                      initial,
                                      result.fit.betas,
                                      model.latent_markers(),
                                      &result.normal_distances);

  // The layout as written: vertex + normal * per-type distance, re-posed.
  const auto [layout_vids, layout_distances] = MarkerVertices(result.layout);
  MarkerModel layout_model(body, layout_vids);
  layout_model.SetShape(
      result.fit.betas,
      NormalOffsets(body, result.fit.betas, layout_vids, layout_distances));
  StageIISolver pose_only(&layout_model, prior, repose);
  Eigen::VectorXd params;
  const SolveSummary summary = pose_only.SolveFrame(frame, obs, &params);
  result.layout_rms_m = summary.usable()
                            ? summary.rms_m
                            : std::numeric_limits<double>::quiet_NaN();
  return result;
}

int MostCompleteFrame(const LabelledMarkers& markers) {
  int best = 0;
  int best_count = -1;
  for (int t = 0; t < markers.num_frames(); ++t) {
    const int count =
        static_cast<int>(ObservedMarkers(markers.frames[t]).size());
    if (count > best_count) {
      best = t;
      best_count = count;
    }
  }
  return best;
}

std::string LayoutFitToCsv(const LayoutFitResult& fit,
                           const MarkerLayout& initial) {
  std::ostringstream csv;
  csv << "label,vertex_id,initial_vertex_id,normal_distance_mm,residual_mm\n";
  for (int m = 0; m < fit.layout.num_markers(); ++m) {
    csv << fmt::format("{},{},{},{:.2f},{:.2f}\n",
                       fit.layout.markers[m].label,
                       fit.layout.markers[m].vertex_ids[0],
                       initial.markers[m].vertex_ids[0],
                       1e3 * fit.normal_distances[m],
                       1e3 * fit.residuals_m[m]);
  }
  return csv.str();
}

}  // namespace soma
