#include "framework/solve/layout_fit.h"

#include "framework/core/error.h"
#include "framework/io/marker_labels.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <map>
#include <set>
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

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// The point of triangle (a, b, c) nearest to p (Ericson, Real-Time
/// Collision Detection, 5.1.5).
Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p,
                                       const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b,
                                       const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + d1 / (d1 - d3) * ab;
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + d2 / (d2 - d6) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  }
  const double denom = 1.0 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

/// Subject prefix stripped, upper-cased: duplicate columns compare equal.
std::string UpperLabel(std::string_view label) {
  std::string name(StripSubjectPrefix(label));
  for (char& c : name)
    c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return name;
}

}  // namespace

std::string_view ToString(MarkerPlacement placement) {
  switch (placement) {
    case MarkerPlacement::kFitted:
      return "fitted";
    case MarkerPlacement::kPlaced:
      return "placed";
    case MarkerPlacement::kMissing:
      return "missing";
    case MarkerPlacement::kTooFar:
      return "too_far";
    case MarkerPlacement::kInside:
      return "inside";
    case MarkerPlacement::kDuplicate:
      return "duplicate";
  }
  return "?";
}

void CaptureLayoutOptions::Validate() const {
  if (min_recognised < 3) {
    throw ConfigError(
        fmt::format("Invalid configuration. task.min_recognised = {}. Violated "
                    "constraint: min_recognised >= 3 (stage I needs 3 markers)",
                    min_recognised));
  }
  if (!(max_skin_distance_m > 0.0) || !std::isfinite(max_skin_distance_m)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. task.max_skin_distance_mm = {}. Violated "
        "constraint: max_skin_distance_mm > 0",
        1e3 * max_skin_distance_m));
  }
  if (!(max_depth_m >= 0.0) || !std::isfinite(max_depth_m)) {
    throw ConfigError(
        fmt::format("Invalid configuration. task.max_depth_mm = {}. Violated "
                    "constraint: max_depth_mm >= 0",
                    1e3 * max_depth_m));
  }
}

int NearestSurfacePoint(const Eigen::Vector3d& point,
                        const Eigen::Matrix3Xd& vertices,
                        const Eigen::Matrix3Xi& faces,
                        Eigen::Vector3d* closest) {
  int best = -1;
  double best_sq = std::numeric_limits<double>::infinity();
  for (Eigen::Index f = 0; f < faces.cols(); ++f) {
    const Eigen::Vector3d q = ClosestPointOnTriangle(point,
                                                     vertices.col(faces(0, f)),
                                                     vertices.col(faces(1, f)),
                                                     vertices.col(faces(2, f)));
    const double sq = (q - point).squaredNorm();
    if (sq < best_sq) {
      best_sq = sq;
      best = static_cast<int>(f);
      if (closest != nullptr) *closest = q;
    }
  }
  return best;
}

// The marker columns of a capture: labelled points that are not model
// outputs (ModelOutputColumns: Plug-in Gait's angles, forces ... and virtual
// points) nor unlabelled (`*k`); frames in metres, NaN = missing.
void CaptureMarkerColumns(const C3dData& c3d,
                          std::vector<std::string>* labels,
                          std::vector<Eigen::Matrix3Xd>* frames) {
  const std::vector<bool> is_output = ModelOutputColumns(c3d);
  std::vector<int> columns;
  for (int p = 0; p < c3d.num_points; ++p) {
    const std::string& label = c3d.labels[p];
    const std::string_view name = StripSubjectPrefix(label);
    if (name.empty() || name[0] == '*' || is_output[p]) continue;
    columns.push_back(p);
    labels->push_back(label);
  }
  const double scale = c3d.MetresPerUnit();
  frames->assign(
      c3d.num_frames,
      Eigen::Matrix3Xd::Constant(3,
                                 static_cast<Eigen::Index>(columns.size()),
                                 std::numeric_limits<double>::quiet_NaN()));
  for (int t = 0; t < c3d.num_frames; ++t) {
    for (size_t k = 0; k < columns.size(); ++k) {
      if (!c3d.valid(t, columns[k])) continue;
      const Eigen::Vector3d x = c3d.Point(t, columns[k]).cast<double>() * scale;
      if (x.allFinite()) (*frames)[t].col(static_cast<Eigen::Index>(k)) = x;
    }
  }
}

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
    const StageIIOptions& repose) {
  options.Validate();
  const int C = static_cast<int>(labels.size());
  if (!match_as.empty() && static_cast<int>(match_as.size()) != C) {
    throw ShapeError(
        fmt::format("FitCaptureLayout: {} names to match for {} labels",
                    match_as.size(),
                    C));
  }
  if (frames.empty())
    throw IoError("FitCaptureLayout: the capture has no frames");
  for (const Eigen::Matrix3Xd& f : frames) {
    if (f.cols() != C) {
      throw ShapeError(
          fmt::format("FitCaptureLayout: a frame of {} columns for {} labels",
                      f.cols(),
                      C));
    }
  }
  CaptureLayoutResult result;
  result.markers.resize(C);
  std::map<std::string, int> layout_index;
  for (int m = 0; m < recognition.num_markers(); ++m) {
    layout_index.emplace(CanonicalMarkerLabel(recognition.markers[m].label), m);
  }
  std::vector<int> column_of(recognition.num_markers(), -1);
  std::set<std::string> seen;
  std::vector<bool> usable(C, false);
  for (int c = 0; c < C; ++c) {
    CaptureLayoutMarker& m = result.markers[c];
    m.label = std::string(StripSubjectPrefix(labels[c]));
    m.match_as = match_as.empty() ? m.label : match_as[c];
    m.skin_distance_m = m.normal_distance_m = m.layout_residual_m = kNaN;
    if (!seen.insert(UpperLabel(m.label)).second) {
      m.placement = MarkerPlacement::kDuplicate;
      continue;
    }
    usable[c] = true;
    const auto it = layout_index.find(CanonicalMarkerLabel(m.match_as));
    if (it != layout_index.end() && column_of[it->second] < 0) {
      column_of[it->second] = c;
      m.recognised_as = recognition.markers[it->second].label;
      ++result.recognised;
    }
  }
  for (int m = 0; m < recognition.num_markers(); ++m) {
    if (column_of[m] < 0) {
      result.absent_labels.push_back(recognition.markers[m].label);
    }
  }

  // The frame: the most observed markers, then the most recognised ones.
  const int T = static_cast<int>(frames.size());
  if (frame >= T) {
    throw ShapeError(fmt::format("FitCaptureLayout: frame {} of {}", frame, T));
  }
  if (frame < 0) {
    std::pair<int, int> best{-1, -1};
    for (int t = 0; t < T; ++t) {
      std::pair<int, int> count{0, 0};
      for (int c = 0; c < C; ++c) {
        if (!usable[c] || !frames[t].col(c).allFinite()) continue;
        ++count.first;
        if (!result.markers[c].recognised_as.empty()) ++count.second;
      }
      if (count > best) {
        best = count;
        frame = t;
      }
    }
  }
  result.frame = frame;
  const Eigen::Matrix3Xd& obs = frames[frame];

  // Stage I on the recognised markers observed in the frame.
  MarkerLayout sub;
  sub.surface_model_type = recognition.surface_model_type;
  std::vector<int> sub_column;
  std::vector<std::string> names;
  for (int m = 0; m < recognition.num_markers(); ++m) {
    const int c = column_of[m];
    if (c < 0 || !obs.col(c).allFinite()) continue;
    sub.markers.push_back(recognition.markers[m]);
    sub_column.push_back(c);
    names.push_back(result.markers[c].label == recognition.markers[m].label
                        ? result.markers[c].label
                        : fmt::format("{}={}",
                                      result.markers[c].label,
                                      recognition.markers[m].label));
  }
  if (sub.num_markers() < options.min_recognised) {
    throw Error(fmt::format(
        "fit_layout: {} of the capture's markers are recognised by the alias "
        "table and observed in frame {} ({} recognised in all), at least {} "
        "(task.min_recognised) are needed to fit the body; recognised: [{}]; "
        "map more of its names onto ours with task.name_map",
        sub.num_markers(),
        frame,
        result.recognised,
        options.min_recognised,
        fmt::join(names, " ")));
  }
  LabelledMarkers sub_markers;
  sub_markers.labels = sub.Labels();
  sub_markers.frames.emplace_back(3, sub.num_markers());
  for (int i = 0; i < sub.num_markers(); ++i) {
    sub_markers.frames[0].col(i) = obs.col(sub_column[i]);
  }
  result.fit =
      FitLayoutToFrame(body, sub, sub_markers, 0, prior, stagei, repose);
  result.fit.fit.frames = {frame};
  result.fitted_layout_rms_m = result.fit.layout_rms_m;

  // The fitted body in the frame's pose.
  const BodyPose pose = UnpackFrameParams(result.fit.fit.frame_params[0].data(),
                                          body.num_joints());
  const Eigen::Matrix3Xd posed = PoseVertices(body, result.fit.fit.betas, pose);
  const Eigen::Matrix3Xd normals = VertexNormals(posed, body.faces);

  std::vector<int> sub_of(C, -1);
  for (int i = 0; i < sub.num_markers(); ++i) sub_of[sub_column[i]] = i;
  std::map<std::string, int> column_of_label;
  for (int c = 0; c < C; ++c) {
    CaptureLayoutMarker& m = result.markers[c];
    if (!usable[c]) continue;
    const Eigen::Vector3d x = obs.col(c);
    if (!x.allFinite()) {
      m.placement = MarkerPlacement::kMissing;
      continue;
    }
    Eigen::Vector3d closest;
    const int face = NearestSurfacePoint(x, posed, body.faces, &closest);
    const Eigen::Vector3d face_normal =
        (posed.col(body.faces(1, face)) - posed.col(body.faces(0, face)))
            .cross(posed.col(body.faces(2, face)) -
                   posed.col(body.faces(0, face)));
    m.skin_distance_m = (x - closest).norm();
    if (face_normal.dot(x - closest) < 0.0) m.skin_distance_m *= -1.0;
    MarkerLayout::Marker marker;
    marker.label = m.label;
    if (sub_of[c] >= 0) {
      const int i = sub_of[c];
      m.placement = MarkerPlacement::kFitted;
      m.vertex_id = result.fit.layout.markers[i].vertex_ids[0];
      m.normal_distance_m = result.fit.normal_distances[i];
      marker.type = sub.markers[i].type;
      marker.distance_from_skin = sub.markers[i].distance_from_skin;
    } else {
      if (std::abs(m.skin_distance_m) > options.max_skin_distance_m) {
        m.placement = MarkerPlacement::kTooFar;
        continue;
      }
      if (m.skin_distance_m < -options.max_depth_m) {
        m.placement = MarkerPlacement::kInside;
        continue;
      }
      int best = body.faces(0, face);
      for (int k = 1; k < 3; ++k) {
        const int v = body.faces(k, face);
        if ((posed.col(v) - closest).squaredNorm() <
            (posed.col(best) - closest).squaredNorm()) {
          best = v;
        }
      }
      m.placement = MarkerPlacement::kPlaced;
      m.vertex_id = best;
      m.normal_distance_m = normals.col(best).dot(x - posed.col(best));
      marker.type = BuiltinMarkerType(m.label);
      marker.distance_from_skin = BuiltinDistanceFromSkin(marker.type);
    }
    marker.vertex_ids = {m.vertex_id};
    column_of_label.emplace(marker.label, c);
    result.layout.markers.push_back(std::move(marker));
  }
  result.layout.surface_model_type = body.name;
  result.layout.Sort();
  result.placed = result.layout.num_markers();
  result.not_placed = C - result.placed;

  // The written layout re-posed on the frame.
  const auto [vids, distances] = MarkerVertices(result.layout);
  MarkerModel model(body, vids);
  model.SetShape(result.fit.fit.betas,
                 NormalOffsets(body, result.fit.fit.betas, vids, distances));
  Eigen::Matrix3Xd layout_obs(3, result.layout.num_markers());
  std::vector<int> layout_column;
  for (int i = 0; i < result.layout.num_markers(); ++i) {
    layout_column.push_back(column_of_label.at(result.layout.markers[i].label));
    layout_obs.col(i) = obs.col(layout_column.back());
  }
  StageIISolver pose_only(&model, prior, repose);
  Eigen::VectorXd params;
  const SolveSummary summary = pose_only.SolveFrame(frame, layout_obs, &params);
  if (!summary.usable()) {
    result.layout_rms_m = kNaN;
    return result;
  }
  Eigen::Matrix3Xd sim;
  model.Evaluate(params.data(), {}, &sim, nullptr);
  double sq = 0.0;
  for (int i = 0; i < result.layout.num_markers(); ++i) {
    const double r = (sim.col(i) - layout_obs.col(i)).norm();
    result.markers[layout_column[i]].layout_residual_m = r;
    sq += r * r;
  }
  result.layout_rms_m =
      std::sqrt(sq / std::max(1, result.layout.num_markers()));
  return result;
}

std::string CaptureLayoutToCsv(const CaptureLayoutResult& result) {
  const auto mm = [](double metres) {
    return std::isfinite(metres) ? fmt::format("{:.2f}", 1e3 * metres)
                                 : std::string();
  };
  std::ostringstream csv;
  csv << "label,placement,recognised_as,vertex_id,skin_distance_mm,"
         "normal_distance_mm,layout_residual_mm\n";
  for (const CaptureLayoutMarker& m : result.markers) {
    csv << fmt::format("{},{},{},{},{},{},{}\n",
                       m.label,
                       ToString(m.placement),
                       m.recognised_as,
                       m.vertex_id >= 0 ? std::to_string(m.vertex_id) : "",
                       mm(m.skin_distance_m),
                       mm(m.normal_distance_m),
                       mm(m.layout_residual_m));
  }
  return csv.str();
}

}  // namespace soma
