#include "framework/solve/layout_fit.h"

#include "framework/core/error.h"
#include "framework/io/c3d.h"
#include "framework/io/marker_labels.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

// Measured 2026-12-01 (procedural body, cmu41, frame 0 of cmu_01_01): see
// the printed value; the bound leaves a margin.
constexpr double kCmuFrameRmsBound = 0.020;  // metres (issue #8 target)

TEST(LayoutFit, FitsARealCmuFrameAndWritesTheLayout) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout initial = MakeBuiltinLayout(body, "cmu41");
  const C3dData c3d =
      ReadC3d(soma::testing::SharedDataDir() / "c3d" / "cmu_01_01.c3d");
  const LabelledMarkers markers = MatchToLayout(c3d, initial);
  ASSERT_GT(markers.num_frames(), 0);
  // The first frame with every layout marker.
  int frame = 0;
  while (frame < markers.num_frames() && !markers.frames[frame].allFinite()) {
    ++frame;
  }
  ASSERT_LT(frame, markers.num_frames());
  const GaussianPosePrior prior =
      ProceduralPosePrior(body, ProceduralPosePriorOptions{});
  const LayoutFitResult fit =
      FitLayoutToFrame(body, initial, markers, frame, &prior, StageIOptions{});
  ASSERT_TRUE(fit.fit.summary.usable()) << fit.fit.summary.BriefReport();
  double max_residual = 0;
  for (double r : fit.residuals_m) max_residual = std::max(max_residual, r);
  std::printf(
      "cmu_01_01 frame %d on the procedural body: %d markers, fit RMS %.2f mm "
      "(max %.2f mm), stage I %d iterations %.2f s; unmatched labels %zu, "
      "absent %zu\n",
      frame,
      fit.markers_used,
      1e3 * fit.rms_m,
      1e3 * max_residual,
      fit.fit.summary.iterations,
      fit.fit.summary.time_s,
      markers.unmatched_labels.size(),
      markers.absent_labels.size());
  EXPECT_EQ(fit.markers_used, 41);
  EXPECT_LT(fit.rms_m, kCmuFrameRmsBound);
  // The written layout (vertex + per-type distance), re-posed on the frame.
  std::printf("  written layout re-posed: RMS %.2f mm\n",
              1e3 * fit.layout_rms_m);
  EXPECT_LT(fit.layout_rms_m, kCmuFrameRmsBound);
  EXPECT_GT(fit.layout_rms_m, fit.rms_m);  // no free offsets any more
  EXPECT_EQ(MostCompleteFrame(markers), frame);
  // For comparison: the built-in layout as it is (mean shape, markers at
  // vertex + normal * distance), only the pose fitted (stage II).
  const auto [vids, dist] = MarkerVertices(initial);
  MarkerModel fixed(body, vids);
  fixed.SetShape(
      Eigen::VectorXd::Zero(body.num_betas()),
      NormalOffsets(body, Eigen::VectorXd::Zero(body.num_betas()), vids, dist));
  StageIISolver pose_only(&fixed, &prior, StageIIOptions{});
  Eigen::VectorXd params;
  const SolveSummary pose_fit =
      pose_only.SolveFrame(frame, markers.frames[frame], &params);
  ASSERT_TRUE(pose_fit.usable()) << pose_fit.BriefReport();
  std::printf("  pose only, built-in layout at mean shape: RMS %.2f mm\n",
              1e3 * pose_fit.rms_m);
  EXPECT_LT(pose_fit.rms_m, 0.05);
  for (double d : fit.normal_distances) {
    EXPECT_GT(d, -0.02);
    EXPECT_LT(d, 0.06);
  }
  // The layout round-trips through MoSh's JSON.
  const auto path = soma::testing::CreateTestDir() / "cmu41_fitted.json";
  WriteMarkerLayout(fit.layout, path);
  const MarkerLayout back = LoadMarkerLayoutForBody(path, body);
  EXPECT_EQ(back, fit.layout);
  EXPECT_FALSE(LayoutFitToCsv(fit, initial).empty());
}

TEST(LayoutFit, LabelsOutsideTheLayoutAreReportedAndSkipped) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  Eigen::Matrix3Xd points = Eigen::Matrix3Xd::Zero(3, 4);
  points(0, 2) = std::nan("");
  const LabelledMarkers m =
      MatchToLayout({"meinard:LASI", "EAR", "C7", "C7"}, points, layout);
  ASSERT_EQ(m.num_frames(), 1);
  EXPECT_EQ(m.unmatched_labels, (std::vector<std::string>{"EAR", "C7"}));
  EXPECT_TRUE(m.frames[0].col(layout.FindLabel("LFWT")).allFinite());
  EXPECT_FALSE(m.frames[0].col(layout.FindLabel("C7")).allFinite());  // NaN
  EXPECT_EQ(m.absent_labels.size(), 39u);  // LFWT and C7 matched
  EXPECT_THROW(MatchToLayout({"A"}, Eigen::Matrix3Xd::Zero(3, 2), layout),
               ShapeError);
  // Too few markers in the frame for a fit.
  EXPECT_THROW(FitLayoutToFrame(body, layout, m, 0, nullptr, StageIOptions{}),
               Error);
  // A layout whose vertex ids do not fit the body.
  MarkerLayout wrong = layout;
  wrong.markers[0].vertex_ids = {body.num_vertices() + 5};
  LabelledMarkers all;
  all.labels = wrong.Labels();
  all.frames = {Eigen::Matrix3Xd::Zero(3, wrong.num_markers())};
  EXPECT_THROW(FitLayoutToFrame(body, wrong, all, 0, nullptr, StageIOptions{}),
               ShapeError);
}

// ---- Unseen marker sets (issue #25 item 2).

struct Capture {
  std::vector<std::string> labels;
  std::vector<Eigen::Matrix3Xd> frames;
};

Capture ReadCapture(const std::string& name) {
  Capture capture;
  CaptureMarkerColumns(ReadC3d(soma::testing::SharedDataDir() / "c3d" / name),
                       &capture.labels,
                       &capture.frames);
  return capture;
}

CaptureLayoutResult FitCapture(const Capture& capture,
                               const std::vector<std::string>& match_as = {}) {
  const BodyModel& body = ProceduralBody();
  const GaussianPosePrior prior =
      ProceduralPosePrior(body, ProceduralPosePriorOptions{});
  return FitCaptureLayout(body,
                          MakeBuiltinLayout(body, "superset89"),
                          capture.labels,
                          match_as,
                          capture.frames,
                          -1,
                          &prior,
                          CaptureLayoutOptions{},
                          StageIOptions{},
                          StageIIOptions{});
}

/// Every capture marker is in the layout (under its own name) or reported
/// with a reason; the layout holds nothing else.
void ExpectEveryMarkerPlacedOrReported(const CaptureLayoutResult& r) {
  int placed = 0;
  for (const CaptureLayoutMarker& m : r.markers) {
    const bool in_layout = r.layout.FindLabel(m.label) >= 0;
    switch (m.placement) {
      case MarkerPlacement::kFitted:
        EXPECT_FALSE(m.recognised_as.empty()) << m.label;
        [[fallthrough]];
      case MarkerPlacement::kPlaced:
        ++placed;
        EXPECT_TRUE(in_layout) << m.label;
        EXPECT_GE(m.vertex_id, 0) << m.label;
        EXPECT_TRUE(std::isfinite(m.layout_residual_m)) << m.label;
        break;
      case MarkerPlacement::kTooFar:
        EXPECT_GT(std::abs(m.skin_distance_m), 0.060) << m.label;
        break;
      case MarkerPlacement::kInside:
        EXPECT_LT(m.skin_distance_m, -0.020) << m.label;
        break;
      case MarkerPlacement::kMissing:
      case MarkerPlacement::kDuplicate:
        break;
    }
  }
  EXPECT_EQ(placed, r.layout.num_markers());
  EXPECT_EQ(r.placed, placed);
  EXPECT_EQ(r.placed + r.not_placed, static_cast<int>(r.markers.size()));
}

// Bounds, from the measured values (procedural body, superset89, the most
// complete frame; 2026-12-04): Plug-in Gait Movement_trial 39 markers, fit
// RMS 0.96 mm, written layout re-posed RMS 17.9 mm over the 39 markers (21.6
// mm over 67 points while its virtual points were still placed; 17.5 mm
// since they are left out, 2026-12-05); Res16bits through its name map 12.3
// mm; Gait.c3d 11.1 mm. The layout's markers sit at the fixed per-type
// distance from the skin (MoSh's format), the procedural body is coarse and
// one frame fixes the shape: 35 mm bounds the re-posed RMS with a margin,
// and more than that would mean a marker on the wrong limb.
constexpr double kLayoutRmsBound = 0.035;  // metres

TEST(CaptureLayout, PlugInGaitTakeGetsEveryMarkerUnderItsOwnName) {
  const Capture capture = ReadCapture("Movement_trial.c3d");
  const CaptureLayoutResult r = FitCapture(capture);
  std::printf(
      "Movement_trial: %zu columns, %d recognised, %d placed, %d not placed, "
      "fit RMS %.2f mm, layout RMS %.2f mm (fitted %.2f mm)\n",
      r.markers.size(),
      r.recognised,
      r.placed,
      r.not_placed,
      1e3 * r.fit.rms_m,
      1e3 * r.layout_rms_m,
      1e3 * r.fitted_layout_rms_m);
  ExpectEveryMarkerPlacedOrReported(r);
  // The 39 Plug-in Gait markers are recognised (LASI through the alias
  // table) and kept under the capture's names.
  EXPECT_EQ(r.recognised, 39);
  for (const char* label : {"LASI", "RPSI", "RBAK", "LFHD", "RTOE"}) {
    EXPECT_GE(r.layout.FindLabel(label), 0) << label;
  }
  EXPECT_LT(r.layout.FindLabel("LFWT"), 0);
  // Plug-in Gait's 78 virtual points (segment axes such as RFEO, the right
  // knee's joint centre, and the centre of mass) are model outputs, not
  // skin markers: CaptureMarkerColumns leaves them out, so every column is a
  // marker and every marker is placed.
  EXPECT_EQ(capture.labels.size(), 39u);
  EXPECT_EQ(std::count(capture.labels.begin(), capture.labels.end(), "RFEO"),
            0);
  EXPECT_EQ(r.not_placed, 0);
  EXPECT_LT(r.layout_rms_m, kLayoutRmsBound);
  EXPECT_FALSE(CaptureLayoutToCsv(r).empty());
  // The written layout loads back on the body (labels the alias table does
  // not know are allowed).
  const auto path = soma::testing::CreateTestDir() / "pig_layout.json";
  WriteMarkerLayout(r.layout, path);
  LayoutCheckOptions check;
  check.allow_unknown_labels = true;
  EXPECT_EQ(LoadMarkerLayoutForBody(path, ProceduralBody(), check), r.layout);
}

TEST(CaptureLayout, GaitSetPlacesItsUnknownMarkersAndReportsRepeats) {
  const Capture capture = ReadCapture("Gait.c3d");
  const CaptureLayoutResult r = FitCapture(capture);
  std::printf(
      "Gait: %zu columns, %d recognised, %d placed, layout RMS %.2f "
      "mm\n",
      r.markers.size(),
      r.recognised,
      r.placed,
      1e3 * r.layout_rms_m);
  ExpectEveryMarkerPlacedOrReported(r);
  int placed = 0, repeated = 0;
  for (const CaptureLayoutMarker& m : r.markers) {
    placed += m.placement == MarkerPlacement::kPlaced;
    repeated += m.placement == MarkerPlacement::kDuplicate;
  }
  EXPECT_GT(placed, 0);    // e.g. VSAC, IJ, PX: not in the alias table
  EXPECT_GT(repeated, 0);  // the file repeats RKNE, RANK, ...
  EXPECT_LT(r.layout_rms_m, kLayoutRmsBound);
}

TEST(CaptureLayout, TooFewRecognisedMarkersIsAClearError) {
  // Res16bits: French anatomical names, 6 recognised (C7, T8, MT1, MT5).
  const Capture capture = ReadCapture("Res16bits.c3d");
  const std::string what =
      soma::testing::ErrorMessage<Error>([&] { FitCapture(capture); });
  EXPECT_NE(what.find("6 of the capture's markers are recognised"),
            std::string::npos)
      << what;
  EXPECT_NE(what.find("at least 12"), std::string::npos) << what;
  EXPECT_NE(what.find("C7 LMT1 LMT5 RMT1 RMT5 T8"), std::string::npos) << what;
}

TEST(CaptureLayout, NameMapMakesACaptureUnderOtherNamesFittable) {
  // A real capture whose names are ours under other names: Res16bits with
  // results/capture_layouts/res16bits_name_map.yaml.
  const Capture capture = ReadCapture("Res16bits.c3d");
  const BodyModel& body = ProceduralBody();
  const MarkerLayout recognition = MakeBuiltinLayout(body, "superset89");
  const MarkerNameMap map =
      ReadMarkerNameMap(soma::testing::SourceDir() /
                        "results/capture_layouts/res16bits_name_map.yaml");
  CheckMarkerNameMap(map, recognition.Labels(), "the layout");
  const CaptureLayoutResult r = FitCapture(capture, map.Apply(capture.labels));
  std::printf(
      "Res16bits + name map: %d recognised, %d placed, layout RMS "
      "%.2f mm\n",
      r.recognised,
      r.placed,
      1e3 * r.layout_rms_m);
  ExpectEveryMarkerPlacedOrReported(r);
  EXPECT_EQ(r.recognised, 6 + 19);
  const CaptureLayoutMarker& reas =
      r.markers[std::find(
                    capture.labels.begin(), capture.labels.end(), "REAS") -
                capture.labels.begin()];
  EXPECT_EQ(reas.recognised_as, "RFWT");     // REAS -> RASI -> RFWT
  EXPECT_GE(r.layout.FindLabel("REAS"), 0);  // written as the capture's
  EXPECT_LT(r.layout_rms_m, kLayoutRmsBound);

  // The same for a synthetic renaming of a CMU take: the fitted vertices do
  // not depend on the names.
  Capture cmu = ReadCapture("cmu_01_01.c3d");
  const CaptureLayoutResult direct = FitCapture(cmu);
  std::string yaml;
  for (std::string& label : cmu.labels) {
    const std::string ours(StripSubjectPrefix(label));
    if (ours.empty() || ours == "RBAC-1") continue;
    label = "marker_" + ours;
    yaml += fmt::format("{}: {}\n", label, ours);
  }
  EXPECT_THROW(FitCapture(cmu), Error);  // nothing recognised
  const MarkerNameMap cmu_map = ParseMarkerNameMap(yaml, "cmu_names.yaml");
  const CaptureLayoutResult renamed =
      FitCapture(cmu, cmu_map.Apply(cmu.labels));
  EXPECT_EQ(renamed.recognised, direct.recognised);
  ASSERT_EQ(renamed.markers.size(), direct.markers.size());
  for (size_t c = 0; c < direct.markers.size(); ++c) {
    EXPECT_EQ(renamed.markers[c].vertex_id, direct.markers[c].vertex_id)
        << direct.markers[c].label;
    const std::string& label = direct.markers[c].label;
    EXPECT_EQ(renamed.markers[c].label,
              label == "RBAC-1" ? label : "marker_" + label);
  }
  EXPECT_NEAR(renamed.layout_rms_m, direct.layout_rms_m, 1e-9);
}

TEST(CaptureLayout, MissingFarAndInnerPointsAreReportedNotPlaced) {
  Capture capture = ReadCapture("cmu_01_01.c3d");
  const CaptureLayoutResult direct = FitCapture(capture);
  const int frame = direct.frame;
  const auto column = [&](const std::string& label) {
    for (size_t c = 0; c < capture.labels.size(); ++c) {
      if (StripSubjectPrefix(capture.labels[c]) == label)
        return static_cast<int>(c);
    }
    ADD_FAILURE() << label;
    return 0;
  };
  Eigen::Matrix3Xd& f = capture.frames[frame];
  const Eigen::Vector3d lfhd = f.col(column("LFHD"));
  const Eigen::Vector3d pelvis =
      0.25 * (f.col(column("LFWT")) + f.col(column("RFWT")) +
              f.col(column("LBWT")) + f.col(column("RBWT")));
  const Eigen::Vector3d strn = f.col(column("STRN"));
  f.col(column("T10")).setConstant(std::nan(""));  // missing in the frame
  // Three extra columns: a prop 1 m off, the pelvis centre, a new marker 5 mm
  // from the sternum marker.
  for (Eigen::Matrix3Xd& frame_points : capture.frames) {
    frame_points.conservativeResize(Eigen::NoChange, frame_points.cols() + 3);
    frame_points.col(frame_points.cols() - 3) = lfhd + Eigen::Vector3d(0, 0, 1);
    frame_points.col(frame_points.cols() - 2) = pelvis;
    frame_points.col(frame_points.cols() - 1) =
        strn + Eigen::Vector3d(0, 0, -0.005);
  }
  capture.labels.insert(capture.labels.end(), {"PROP", "PELVIS", "NEWMK"});
  const BodyModel& body = ProceduralBody();
  const GaussianPosePrior prior =
      ProceduralPosePrior(body, ProceduralPosePriorOptions{});
  const CaptureLayoutResult r =
      FitCaptureLayout(body,
                       MakeBuiltinLayout(body, "superset89"),
                       capture.labels,
                       {},
                       capture.frames,
                       frame,
                       &prior,
                       CaptureLayoutOptions{},
                       StageIOptions{},
                       StageIIOptions{});
  ExpectEveryMarkerPlacedOrReported(r);
  const int n = static_cast<int>(r.markers.size());
  EXPECT_EQ(r.markers[column("T10")].placement, MarkerPlacement::kMissing);
  EXPECT_LT(r.layout.FindLabel("T10"), 0);
  EXPECT_EQ(r.markers[n - 3].placement, MarkerPlacement::kTooFar);
  const MarkerPlacement inner = r.markers[n - 2].placement;
  EXPECT_TRUE(inner == MarkerPlacement::kInside ||
              inner == MarkerPlacement::kTooFar)
      << ToString(inner) << " " << r.markers[n - 2].skin_distance_m;
  EXPECT_EQ(r.markers[n - 1].placement, MarkerPlacement::kPlaced);
  EXPECT_GE(r.layout.FindLabel("NEWMK"), 0);
  EXPECT_EQ(r.placed, direct.placed - 1 + 1);  // - T10 + NEWMK
  // Options are checked.
  CaptureLayoutOptions bad;
  bad.min_recognised = 2;
  EXPECT_THROW(bad.Validate(), ConfigError);
  bad = CaptureLayoutOptions{};
  bad.max_skin_distance_m = 0.0;
  EXPECT_THROW(bad.Validate(), ConfigError);
}

TEST(CaptureLayout, AKnownMarkerSetGivesTodaysLayout) {
  // HDM05 frame 0 (every marker known): the same vertices and re-posed RMS
  // as FitLayoutToFrame on the markers matched by MatchToLayout.
  const BodyModel& body = ProceduralBody();
  const MarkerLayout cmu41 = MakeBuiltinLayout(body, "cmu41");
  const GaussianPosePrior prior =
      ProceduralPosePrior(body, ProceduralPosePriorOptions{});
  const C3dData c3d = ReadC3d(soma::testing::SharedDataDir() / "c3d" /
                              "HDM_mm_01-02_03_120.c3d");
  const LayoutFitResult today = FitLayoutToFrame(
      body, cmu41, MatchToLayout(c3d, cmu41), 0, &prior, StageIOptions{});
  Capture capture;
  CaptureMarkerColumns(c3d, &capture.labels, &capture.frames);
  const CaptureLayoutResult r = FitCaptureLayout(body,
                                                 cmu41,
                                                 capture.labels,
                                                 {},
                                                 capture.frames,
                                                 0,
                                                 &prior,
                                                 CaptureLayoutOptions{},
                                                 StageIOptions{},
                                                 StageIIOptions{});
  ASSERT_EQ(r.placed, 41);
  for (const MarkerLayout::Marker& m : today.layout.markers) {
    const int i = r.layout.FindLabel(m.label);
    ASSERT_GE(i, 0) << m.label;
    EXPECT_EQ(r.layout.markers[i].vertex_ids, m.vertex_ids) << m.label;
    EXPECT_EQ(r.layout.markers[i].type, m.type) << m.label;
  }
  EXPECT_NEAR(r.layout_rms_m, today.layout_rms_m, 1e-9);
  EXPECT_NEAR(r.fit.rms_m, today.rms_m, 1e-9);
}

TEST(CaptureLayout, NearestSurfacePointIsOnTheClosestFace) {
  Eigen::Matrix3Xd v(3, 4);
  v << 0, 1, 0, 0,  //
      0, 0, 1, 0,   //
      0, 0, 0, 1;
  Eigen::Matrix3Xi f(3, 2);
  f << 0, 0,  //
      2, 1,   //
      1, 3;
  Eigen::Vector3d closest;
  // Above the z = 0 face (0, 2, 1), inside it.
  EXPECT_EQ(NearestSurfacePoint({0.2, 0.3, -0.5}, v, f, &closest), 0);
  EXPECT_TRUE(closest.isApprox(Eigen::Vector3d(0.2, 0.3, 0.0)));
  // Beyond the edge of the y = 0 face (0, 1, 3): clamped to the edge.
  EXPECT_EQ(NearestSurfacePoint({0.5, -0.5, 0.8}, v, f, &closest), 1);
  EXPECT_TRUE(closest.isApprox(Eigen::Vector3d(0.35, 0.0, 0.65)));
}

}  // namespace
}  // namespace soma
