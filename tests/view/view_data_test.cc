#include "framework/view/view_data.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

namespace soma {
namespace {

using ::soma::testing::ErrorMessage;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

/// Inverse of Base64Encode for the tests (standard alphabet, padding).
std::vector<uint8_t> Base64Decode(const std::string& text) {
  static const std::string kAlphabet =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::vector<uint8_t> out;
  uint32_t buffer = 0;
  int bits = 0;
  for (const char c : text) {
    if (c == '=') break;
    const size_t v = kAlphabet.find(c);
    EXPECT_NE(v, std::string::npos) << "not base64: " << c;
    buffer = (buffer << 6) | static_cast<uint32_t>(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<uint8_t>((buffer >> bits) & 0xff));
    }
  }
  return out;
}

/// The values of the array `name` of a packed page.
template <typename T>
std::vector<T> DecodeArray(const ConfigNode& json,
                           const std::string& name,
                           const std::string& dtype) {
  const ConfigNode& entry = json.at("arrays").at(name);
  EXPECT_EQ(entry.at("dtype").AsString(), dtype) << name;
  const std::vector<uint8_t> bytes =
      Base64Decode(entry.at("base64").AsString());
  EXPECT_EQ(bytes.size() % sizeof(T), 0u) << name;
  std::vector<T> values(bytes.size() / sizeof(T));
  std::memcpy(values.data(), bytes.data(), values.size() * sizeof(T));
  EXPECT_EQ(static_cast<int64_t>(values.size()), entry.at("length").AsInt())
      << name;
  return values;
}

/// `frames` frames; frame t has 2 + t % 3 points: label ids t % L for the
/// first, null for the rest; truth = the label except on frame 1 (the
/// first point wrong) and frame 2 (a ghost labelled as a marker, a missed
/// marker).
ViewFrames MakeFrames(int frames, bool truth, bool confidence) {
  ViewFrames v;
  v.title = "take";
  v.source = "take.c3d";
  v.frame_rate = 120.0;
  v.labels = {"LFHD", "RFHD", "C7"};
  v.sticks = {{0, 1}, {1, 2}};
  v.with_truth = truth;
  v.with_confidence = confidence;
  const int L = 3;
  for (int t = 0; t < frames; ++t) {
    const int n = 2 + t % 3;
    for (int p = 0; p < n; ++p) {
      const float x[3] = {0.001f * t, 0.1f * p, 1.0f};
      const int label = p == 0 ? t % L : L;
      int true_label = label;
      if (t == 1 && p == 0) true_label = (label + 1) % L;  // wrong
      if (t == 2 && p == 0) true_label = L;                // ghost as marker
      if (t == 2 && p == 1) true_label = 1;                // missed
      v.AddPoint(x, label, true_label, 0.5f + 0.01f * p, 10 + p);
    }
    v.EndFrame();
  }
  return v;
}

TEST(Base64, MatchesTheRfc4648TestVectors) {
  auto encode = [](const std::string& s) {
    return Base64Encode(s.data(), s.size());
  };
  EXPECT_EQ(encode(""), "");
  EXPECT_EQ(encode("f"), "Zg==");
  EXPECT_EQ(encode("fo"), "Zm8=");
  EXPECT_EQ(encode("foo"), "Zm9v");
  EXPECT_EQ(encode("foob"), "Zm9vYg==");
  EXPECT_EQ(encode("fooba"), "Zm9vYmE=");
  EXPECT_EQ(encode("foobar"), "Zm9vYmFy");
}

TEST(Base64, RoundTripsEveryByteValue) {
  std::vector<uint8_t> bytes(256 * 3 + 1);
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = (i * 7 + 3) & 0xff;
  const std::string text = Base64Encode(bytes.data(), bytes.size());
  EXPECT_EQ(text.size(), (bytes.size() + 2) / 3 * 4);
  EXPECT_EQ(Base64Decode(text), bytes);
  const uint8_t high[] = {0xff, 0xfe, 0xfd};
  EXPECT_EQ(Base64Encode(high, 3), "//79");
}

TEST(JsonString, EscapesQuotesControlsAndHtml) {
  EXPECT_EQ(JsonString("a\"b\\c\n"), R"("a\"b\\c\n")");
  const std::string s = JsonString("</script><b>&");
  EXPECT_EQ(s.find('<'), std::string::npos);
  EXPECT_EQ(s.find('>'), std::string::npos);
  EXPECT_EQ(s, R"("\u003c/script\u003e\u003cb\u003e\u0026")");
  EXPECT_EQ(JsonString(std::string("\x01", 1)), R"("\u0001")");
}

TEST(ClassifyPoint, NamesEveryCase) {
  const int L = 3;  // ids 0..2 markers, 3 null, 4 no ground truth
  EXPECT_EQ(ClassifyPoint(1, 1, L), PointStatus::kCorrect);
  EXPECT_EQ(ClassifyPoint(L, L, L), PointStatus::kCorrect);  // ghost rejected
  EXPECT_EQ(ClassifyPoint(1, 2, L), PointStatus::kWrong);
  EXPECT_EQ(ClassifyPoint(1, L, L), PointStatus::kGhostAsMarker);
  EXPECT_EQ(ClassifyPoint(L, 2, L), PointStatus::kMissed);
  EXPECT_EQ(ClassifyPoint(1, L + 1, L), PointStatus::kNoTruth);
  EXPECT_EQ(ClassifyPoint(L, L + 1, L), PointStatus::kNoTruth);
}

TEST(ViewFrames, ValidateRejectsInconsistentArrays) {
  ViewFrames v = MakeFrames(4, true, true);
  EXPECT_NO_THROW(v.Validate());
  ViewFrames bad = v;
  bad.label.pop_back();
  EXPECT_THAT(ErrorMessage<ShapeError>([&] { bad.Validate(); }),
              HasSubstr("label has"));
  bad = v;
  bad.label[0] = 4;  // > L
  EXPECT_THROW(bad.Validate(), ShapeError);
  bad = v;
  bad.sticks.push_back({0, 3});
  EXPECT_THAT(ErrorMessage<ShapeError>([&] { bad.Validate(); }),
              HasSubstr("stick 0-3"));
  bad = v;
  const float x[3] = {0, 0, 0};
  bad.AddPoint(x, 0, 0, 1.0f, 0);  // a point of an unclosed frame
  EXPECT_THROW(bad.Validate(), ShapeError);
}

TEST(PackViewData, CountsAndArraysRoundTrip) {
  const ViewFrames v = MakeFrames(5, true, true);
  ViewDataSummary summary;
  const std::string json = PackViewData(v, {}, &summary);
  EXPECT_EQ(summary.take_frames, 5);
  EXPECT_EQ(summary.shown_frames, 5);
  EXPECT_EQ(summary.frame_step, 1);
  EXPECT_EQ(summary.shown_points, v.num_points());
  EXPECT_EQ(summary.note, "");
  EXPECT_EQ(summary.data_bytes, static_cast<int64_t>(json.size()));

  const ConfigNode page = ParseYaml(json, "page.json");
  EXPECT_EQ(page.at("format").AsString(), "soma-view");
  EXPECT_EQ(page.at("format_version").AsInt(), 1);
  EXPECT_EQ(page.at("take_frames").AsInt(), 5);
  EXPECT_EQ(page.at("num_frames").AsInt(), 5);
  EXPECT_EQ(page.at("num_points").AsInt(), v.num_points());
  EXPECT_EQ(page.at("frame_step").AsInt(), 1);
  EXPECT_TRUE(page.at("has_truth").AsBool());
  EXPECT_TRUE(page.at("has_confidence").AsBool());
  EXPECT_EQ(page.at("labels").items().size(), 3u);
  EXPECT_EQ(page.at("labels").at(2).AsString(), "C7");
  EXPECT_EQ(page.at("sticks").items().size(), 2u);

  EXPECT_THAT(DecodeArray<uint32_t>(page, "frame", "uint32"),
              ElementsAre(0, 1, 2, 3, 4));
  // 2, 3, 4, 2, 3 points.
  EXPECT_THAT(DecodeArray<uint32_t>(page, "offset", "uint32"),
              ElementsAre(0, 2, 5, 9, 11, 14));
  EXPECT_EQ(DecodeArray<float>(page, "position", "float32"), v.positions);
  const auto labels = DecodeArray<uint8_t>(page, "label", "uint8");
  EXPECT_EQ(std::vector<int>(labels.begin(), labels.end()), v.label);
  const auto truth = DecodeArray<uint8_t>(page, "truth", "uint8");
  EXPECT_EQ(std::vector<int>(truth.begin(), truth.end()), v.truth);
  const auto track = DecodeArray<int16_t>(page, "track", "int16");
  EXPECT_EQ(std::vector<int>(track.begin(), track.end()), v.track);

  // Frame 1: first point wrong; frame 2: a ghost as marker and a miss.
  const auto status = DecodeArray<uint8_t>(page, "status", "uint8");
  EXPECT_EQ(status[2], uint8_t(PointStatus::kWrong));
  EXPECT_EQ(status[5], uint8_t(PointStatus::kGhostAsMarker));
  EXPECT_EQ(status[6], uint8_t(PointStatus::kMissed));
  EXPECT_EQ(summary.status_counts[int(PointStatus::kWrong)], 1);
  EXPECT_EQ(summary.status_counts[int(PointStatus::kGhostAsMarker)], 1);
  EXPECT_EQ(summary.status_counts[int(PointStatus::kMissed)], 1);
  EXPECT_EQ(summary.status_counts[int(PointStatus::kCorrect)], 14 - 3);
  EXPECT_THAT(DecodeArray<float>(page, "accuracy", "float32"),
              ElementsAre(1.0f, 2.0f / 3.0f, 2.0f / 4.0f, 1.0f, 1.0f));

  const auto confidence = DecodeArray<uint16_t>(page, "confidence", "uint16");
  EXPECT_EQ(confidence[0], std::lround(0.5f * 65534.0f));
  EXPECT_EQ(confidence[1], std::lround(0.51f * 65534.0f));
  const auto mean = DecodeArray<float>(page, "confidence_mean", "float32");
  EXPECT_NEAR(mean[0], 0.505, 1e-6);
}

TEST(PackViewData, WithoutTruthOrConfidenceOmitsTheirArrays) {
  const ViewFrames v = MakeFrames(3, false, false);
  const ConfigNode page = ParseYaml(PackViewData(v, {}), "page.json");
  EXPECT_FALSE(page.at("has_truth").AsBool());
  EXPECT_EQ(page.at("arrays").Find("truth"), nullptr);
  EXPECT_EQ(page.at("arrays").Find("status"), nullptr);
  EXPECT_EQ(page.at("arrays").Find("confidence"), nullptr);
  EXPECT_NE(page.at("arrays").Find("position"), nullptr);
}

TEST(PackViewData, UnknownConfidenceIsTheSentinel) {
  ViewFrames v;
  v.labels = {"A"};
  v.with_confidence = true;
  const float x[3] = {1, 2, 3};
  v.AddPoint(x, 0, -1, std::nanf(""), 0);
  v.AddPoint(x, 1, -1, 1.0f, 1);
  v.EndFrame();
  const ConfigNode page = ParseYaml(PackViewData(v, {}), "page.json");
  EXPECT_THAT(DecodeArray<uint16_t>(page, "confidence", "uint16"),
              ElementsAre(65535, 65534));
  EXPECT_THAT(DecodeArray<float>(page, "confidence_mean", "float32"),
              ElementsAre(1.0f));
}

TEST(PackViewData, ManyLabelsAndLargeTrackIdsWidenTheirTypes) {
  ViewFrames v;
  for (int i = 0; i < 300; ++i) v.labels.push_back(fmt::format("M{}", i));
  const float x[3] = {0, 0, 0};
  v.AddPoint(x, 299, -1, 0, 70000);
  v.EndFrame();
  const ConfigNode page = ParseYaml(PackViewData(v, {}), "page.json");
  EXPECT_THAT(DecodeArray<uint16_t>(page, "label", "uint16"), ElementsAre(299));
  EXPECT_THAT(DecodeArray<int32_t>(page, "track", "int32"), ElementsAre(70000));
}

TEST(ChooseFrameStep, IsOneWhenThePageFitsAndTheSmallestFittingStepElse) {
  const ViewFrames v = MakeFrames(600, true, true);
  ViewPageOptions options;
  options.template_bytes = 500'000;
  EXPECT_EQ(ChooseFrameStep(v, options), 1);

  const int64_t overhead =
      options.template_bytes + 64 * 1024 + 32 * int64_t(v.labels.size());
  // Each chosen step is the first that fits (the size need not fall
  // monotonically with the step: the frames have 2, 3, 4, 2, ... points).
  for (const int64_t room : {EstimateDataBytes(v, 1) / 3 - 1,
                             EstimateDataBytes(v, 7),
                             EstimateDataBytes(v, 7) - 1,
                             EstimateDataBytes(v, 50)}) {
    options.max_page_bytes = overhead + room;
    const int step = ChooseFrameStep(v, options);
    ASSERT_GT(step, 1) << "room " << room;
    EXPECT_LE(EstimateDataBytes(v, step), room) << "room " << room;
    for (int smaller = 1; smaller < step; ++smaller) {
      EXPECT_GT(EstimateDataBytes(v, smaller), room) << "room " << room;
    }
  }
  options.max_page_bytes = overhead + EstimateDataBytes(v, 7);
  EXPECT_LE(ChooseFrameStep(v, options), 7);
}

TEST(ChooseFrameStep, ThrowsWhenNotEvenOneFrameFits) {
  const ViewFrames v = MakeFrames(10, false, false);
  ViewPageOptions options;
  options.template_bytes = 1000;
  options.max_page_bytes = 1000 + 64 * 1024;  // no room for data
  EXPECT_THAT(ErrorMessage<ConfigError>([&] { ChooseFrameStep(v, options); }),
              HasSubstr("task.max_page_mb"));
}

TEST(PackViewData, SubsamplesEveryKthFrameAndSaysSo) {
  const ViewFrames v = MakeFrames(90, true, true);
  ViewPageOptions options;
  options.max_page_bytes = 64 * 1024 + 32 * 3 + EstimateDataBytes(v, 4);
  const int step = ChooseFrameStep(v, options);
  ASSERT_GT(step, 1);
  ViewDataSummary summary;
  const ConfigNode page =
      ParseYaml(PackViewData(v, options, &summary), "page.json");
  EXPECT_EQ(summary.frame_step, step);
  EXPECT_EQ(summary.shown_frames, (90 + step - 1) / step);
  EXPECT_EQ(page.at("frame_step").AsInt(), step);
  EXPECT_EQ(page.at("take_frames").AsInt(), 90);
  EXPECT_THAT(page.at("note").AsString(),
              HasSubstr(fmt::format("1 frame in {} is shown ({} of 90 frames)",
                                    step,
                                    summary.shown_frames)));
  const auto frames = DecodeArray<uint32_t>(page, "frame", "uint32");
  ASSERT_EQ(static_cast<int>(frames.size()), summary.shown_frames);
  for (size_t f = 0; f < frames.size(); ++f) EXPECT_EQ(frames[f], f * step);
  // The points of shown frame f are those of take frame f * step.
  const auto offsets = DecodeArray<uint32_t>(page, "offset", "uint32");
  const auto positions = DecodeArray<float>(page, "position", "float32");
  for (size_t f = 0; f < frames.size(); ++f) {
    const int t = frames[f];
    ASSERT_EQ(offsets[f + 1] - offsets[f], v.offsets[t + 1] - v.offsets[t]);
    EXPECT_EQ(positions[3 * offsets[f]], v.positions[3 * v.offsets[t]]);
  }
  EXPECT_EQ(page.at("num_points").AsInt(), int64_t(offsets.back()));
  EXPECT_LE(summary.data_bytes, options.max_page_bytes);
}

/// Two triangles over 4 vertices, a mesh on take frames 0 and 3.
void AddMeshes(ViewFrames* v, float offset = 0.0f) {
  v->mesh_faces = {0, 1, 2, 0, 2, 3};
  v->mesh_frames = {0, 3};
  v->mesh_step = 3;
  v->mesh_source = "fit.h5";
  for (int m = 0; m < 2; ++m) {
    std::vector<float> coords;
    for (int k = 0; k < 12; ++k) coords.push_back(offset + 0.0014f * k + m);
    v->mesh_vertices.push_back(coords);
  }
}

TEST(PackViewData, MeshesAsFacesFramesAndMillimetreVertices) {
  ViewFrames v = MakeFrames(5, false, false);
  AddMeshes(&v);
  ViewDataSummary summary;
  const ConfigNode page = ParseYaml(PackViewData(v, {}, &summary), "p.json");
  EXPECT_TRUE(page.at("has_mesh").AsBool());
  EXPECT_EQ(page.at("mesh_unit").AsString(), "mm");
  EXPECT_EQ(page.at("mesh_step").AsInt(), 3);
  EXPECT_EQ(page.at("mesh_source").AsString(), "fit.h5");
  EXPECT_THAT(DecodeArray<uint16_t>(page, "mesh_faces", "uint16"),
              ElementsAre(0, 1, 2, 0, 2, 3));
  EXPECT_THAT(DecodeArray<uint32_t>(page, "mesh_frame", "uint32"),
              ElementsAre(0, 3));
  const auto mm = DecodeArray<int16_t>(page, "mesh_vertices", "int16");
  ASSERT_EQ(mm.size(), 24u);
  for (size_t i = 0; i < mm.size(); ++i) {  // rounded to the millimetre
    EXPECT_EQ(mm[i], std::lround(1000.0f * v.mesh_vertices[i / 12][i % 12]));
  }
  EXPECT_EQ(mm[1], 1);  // 1.4 mm
  EXPECT_EQ(mm[12], 1000);
  // The meshes count against the page budget.
  ViewFrames plain = MakeFrames(5, false, false);
  EXPECT_EQ(EstimateDataBytes(v, 1) - EstimateDataBytes(plain, 1),
            EstimateMeshBytes(4, 2, 2));
}

TEST(PackViewData, FarMeshesFallBackToFloatMetres) {
  ViewFrames v = MakeFrames(5, false, false);
  AddMeshes(&v, 40.0f);  // beyond the +-32.7 m of int16 millimetres
  const ConfigNode page = ParseYaml(PackViewData(v, {}), "p.json");
  EXPECT_EQ(page.at("mesh_unit").AsString(), "m");
  const auto m = DecodeArray<float>(page, "mesh_vertices", "float32");
  EXPECT_EQ(m[5], v.mesh_vertices[0][5]);
}

TEST(ViewFrames, ValidateRejectsInconsistentMeshes) {
  ViewFrames v = MakeFrames(5, false, false);
  AddMeshes(&v);
  EXPECT_NO_THROW(v.Validate());
  ViewFrames bad = v;
  bad.mesh_faces.push_back(4);  // no vertex 4; and not a multiple of 3
  EXPECT_THROW(bad.Validate(), ShapeError);
  bad = v;
  bad.mesh_faces[0] = 4;
  EXPECT_THAT(ErrorMessage<ShapeError>([&] { bad.Validate(); }),
              HasSubstr("mesh face vertex 4"));
  bad = v;
  bad.mesh_frames = {3, 3};  // not ascending
  EXPECT_THROW(bad.Validate(), ShapeError);
  bad = v;
  bad.mesh_frames = {0, 5};  // the take has frames 0..4
  EXPECT_THROW(bad.Validate(), ShapeError);
  bad = v;
  bad.mesh_vertices[1].pop_back();
  EXPECT_THROW(bad.Validate(), ShapeError);
}

TEST(ChooseMeshStep, IsTheSmallestStepThatFits) {
  const int V = 7000, F = 13996, n = 120;
  EXPECT_EQ(ChooseMeshStep(V, F, n, EstimateMeshBytes(V, F, n)), 1);
  EXPECT_EQ(ChooseMeshStep(V, F, n, EstimateMeshBytes(V, F, n) - 1), 2);
  EXPECT_EQ(ChooseMeshStep(V, F, n, EstimateMeshBytes(V, F, 12)), 10);
  EXPECT_EQ(ChooseMeshStep(V, F, n, EstimateMeshBytes(V, F, 1)), n);
  EXPECT_EQ(ChooseMeshStep(V, F, n, EstimateMeshBytes(V, F, 1) - 1), 0);
  // 32-bit indices beyond 65535 vertices.
  EXPECT_GT(EstimateMeshBytes(70000, 10, 0), EstimateMeshBytes(60000, 10, 0));
}

TEST(FillViewTemplate, ReplacesThePlaceholderOnce) {
  EXPECT_EQ(FillViewTemplate("<p>__SOMA_VIEW_DATA__</p>", "{}", "t.html"),
            "<p>{}</p>");
  EXPECT_THAT(ErrorMessage<IoError>(
                  [] { FillViewTemplate("<p></p>", "{}", "t.html"); }),
              HasSubstr("t.html: a soma view template holds the placeholder "
                        "__SOMA_VIEW_DATA__ exactly once (not found)"));
  EXPECT_THAT(ErrorMessage<IoError>([] {
                FillViewTemplate(
                    "__SOMA_VIEW_DATA____SOMA_VIEW_DATA__", "{}", "t.html");
              }),
              HasSubstr("found twice"));
}

}  // namespace
}  // namespace soma
