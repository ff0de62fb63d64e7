#include "framework/body/marker_layout.h"

#include "framework/body/makehuman_body.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include "tests/body/body_test_util.h"
#include <algorithm>
#include <filesystem>
#include <functional>
#include <map>
#include <set>
#include <string>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

std::string MessageOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "<no error>";
}

MarkerLayout SmallLayout() {
  MarkerLayout layout;
  layout.surface_model_type = "procedural";
  layout.markers.push_back({"LFHD", "body", {12, 40}, 0.0095});
  layout.markers.push_back({"C7", "body", {3832}, 0.0095});
  layout.markers.push_back({"LTHM1", "finger_left", {7}, 0.0002});
  layout.markers.push_back({"ARIEL", "body", {5}, 0.0095});
  layout.Sort();
  return layout;
}

TEST(MarkerLayout, SortsByTypeThenLabel) {
  const MarkerLayout layout = SmallLayout();
  EXPECT_EQ(layout.Labels(),
            (std::vector<std::string>{"ARIEL", "C7", "LFHD", "LTHM1"}));
  EXPECT_EQ(layout.FindLabel("C7"), 1);
  EXPECT_EQ(layout.FindLabel("XX"), -1);
}

TEST(MarkerLayout, JsonRoundTrip) {
  const MarkerLayout layout = SmallLayout();
  const auto dir = soma::testing::CreateTestDir();
  WriteMarkerLayout(layout, dir / "layout.json");
  const MarkerLayout back = ReadMarkerLayout(dir / "layout.json");
  EXPECT_EQ(back, layout);
  const std::string text = ReadFile(dir / "layout.json");
  // MoSh++ layout: sorted keys, indent 2, a single id as an integer and a
  // superset entry as a list.
  EXPECT_NE(text.find("\"C7\": 3832"), std::string::npos) << text;
  EXPECT_NE(text.find("\"LFHD\": [\n"), std::string::npos) << text;
  EXPECT_LT(text.find("\"markersets\""), text.find("\"surface_model_type\""));
  EXPECT_LT(text.find("\"distance_from_skin\""), text.find("\"indices\""));
  EXPECT_NE(text.find("\n  \"markersets\": ["), std::string::npos) << text;
  // Rewriting the parsed layout gives the same bytes.
  EXPECT_EQ(MarkerLayoutToJson(back), text);
}

TEST(MarkerLayout, ParsesMoshStyleJsonWithDefaults) {
  const MarkerLayout layout = ParseMarkerLayout(
      R"({"markersets": [{"indices": {"RBAC": 10, "LFHD": [3, 3, 4]}}]})",
      "mosh.json");
  EXPECT_EQ(layout.surface_model_type, "smplx");  // MoSh++ default
  ASSERT_EQ(layout.num_markers(), 2);
  EXPECT_EQ(layout.markers[0].label, "LFHD");
  EXPECT_EQ(layout.markers[0].vertex_ids,
            (std::vector<int>{3, 4}));  // distinct ids
  EXPECT_EQ(layout.markers[0].type, "body");
  EXPECT_DOUBLE_EQ(layout.markers[1].distance_from_skin,
                   kDefaultDistanceFromSkin);
}

TEST(MarkerLayout, MalformedFilesGiveClearErrors) {
  const auto dir = soma::testing::CreateTestDir();
  const auto write = [&](const std::string& name, const std::string& text) {
    WriteFileAtomic(dir / name, text);
    return dir / name;
  };
  const auto p1 =
      write("broken.json",
            "{\n  \"markersets\": [\n    {\"type\": \"body\" \"x\": 1}\n");
  const std::string m1 = MessageOf([&] { ReadMarkerLayout(p1); });
  // nlohmann-json locates the error at the last character it read: the end
  // of the unexpected "x".
  EXPECT_NE(m1.find("broken.json:3:23: "), std::string::npos) << m1;
  EXPECT_NE(m1.find("unexpected string literal"), std::string::npos) << m1;

  const auto p2 =
      write("negative.json", R"({"markersets": [{"indices": {"C7": -4}}]})");
  const std::string m2 = MessageOf([&] { ReadMarkerLayout(p2); });
  EXPECT_NE(m2.find("negative.json"), std::string::npos) << m2;
  EXPECT_NE(m2.find("markersets[0].indices.C7"), std::string::npos) << m2;

  const auto p3 =
      write("float.json", R"({"markersets": [{"indices": {"C7": [1, 2.5]}}]})");
  EXPECT_NE(MessageOf([&] { ReadMarkerLayout(p3); }).find("indices.C7[1]"),
            std::string::npos);

  const auto p4 =
      write("typo.json",
            R"({"markersets": [{"distance_form_skin": 0.01, "indices": {}}]})");
  EXPECT_NE(MessageOf([&] { ReadMarkerLayout(p4); }).find("distance_form_skin"),
            std::string::npos);

  const auto p5 =
      write("dup.json",
            R"({"markersets": [{"type": "body", "indices": {"C7": 1}},
                                           {"type": "wrist", "indices": {"C7": 2}}]})");
  EXPECT_NE(MessageOf([&] { ReadMarkerLayout(p5); }).find("several markersets"),
            std::string::npos);

  const auto p6 = write("nosets.json", R"({"surface_model_type": "smplx"})");
  EXPECT_NE(MessageOf([&] { ReadMarkerLayout(p6); }).find("markersets"),
            std::string::npos);

  EXPECT_THROW(ReadMarkerLayout(dir / "missing.json"), IoError);
}

TEST(MarkerLayout, ValidationAgainstABodyNamesFileAndLabel) {
  const BodyModel& body = ProceduralBody();
  MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  EXPECT_NO_THROW(ValidateLayoutForBody(layout, body, "cmu41.json"));

  MarkerLayout out_of_range = layout;
  out_of_range.markers[3].vertex_ids.push_back(body.num_vertices());
  const std::string m1 = MessageOf(
      [&] { ValidateLayoutForBody(out_of_range, body, "my_layout.json"); });
  EXPECT_NE(m1.find("my_layout.json"), std::string::npos) << m1;
  EXPECT_NE(m1.find(layout.markers[3].label), std::string::npos) << m1;
  EXPECT_NE(m1.find("outside"), std::string::npos) << m1;

  MarkerLayout unknown = layout;
  unknown.markers[0].label = "XYZW";
  const std::string m2 =
      MessageOf([&] { ValidateLayoutForBody(unknown, body, "u.json"); });
  EXPECT_NE(m2.find("u.json"), std::string::npos) << m2;
  EXPECT_NE(m2.find("XYZW"), std::string::npos) << m2;
  LayoutCheckOptions lenient;
  lenient.allow_unknown_labels = true;
  EXPECT_NO_THROW(ValidateLayoutForBody(unknown, body, "u.json", lenient));

  MarkerLayout other_model = layout;
  other_model.surface_model_type = "smplx";
  EXPECT_THROW(ValidateLayoutForBody(other_model, body, "s.json"), IoError);

  // Through a file.
  const auto dir = soma::testing::CreateTestDir();
  WriteMarkerLayout(out_of_range, dir / "bad_vid.json");
  const std::string m3 =
      MessageOf([&] { LoadMarkerLayoutForBody(dir / "bad_vid.json", body); });
  EXPECT_NE(m3.find("bad_vid.json"), std::string::npos) << m3;
}

TEST(MarkerLayout, SubjectPrefixAndAliases) {
  EXPECT_EQ(StripSubjectPrefix("meinard:LFHD"), "LFHD");
  EXPECT_EQ(StripSubjectPrefix("LFHD  "), "LFHD");
  EXPECT_EQ(StripSubjectPrefix("a:b:RTOE"), "RTOE");
  EXPECT_EQ(CanonicalMarkerLabel("meinard:LFHD"), "LFHD");
  EXPECT_EQ(CanonicalMarkerLabel("JustinFriday:LASI"), "LFWT");
  EXPECT_EQ(CanonicalMarkerLabel("RASI"), "RFWT");
  EXPECT_EQ(CanonicalMarkerLabel("LPSI"), "LBWT");
  EXPECT_EQ(CanonicalMarkerLabel("rpsi"), "RBWT");
  EXPECT_EQ(CanonicalMarkerLabel("RBAK"), "RBAC");
  EXPECT_EQ(CanonicalMarkerLabel("LIWR"), "LWRA");  // MoSh++ name -> CMU name
  EXPECT_EQ(CanonicalMarkerLabel("ROWR"), "RWRB");
  EXPECT_EQ(CanonicalMarkerLabel("LWRA"), "LWRA");  // CMU names are canonical
  EXPECT_EQ(CanonicalMarkerLabel("HEAD_TOP"), "ARIEL");
  EXPECT_EQ(CanonicalMarkerLabel("L_INKNEE"), "LKNI");
  EXPECT_EQ(CanonicalMarkerLabel("RBAC-1"),
            "RBAC-1");  // CMU duplicate stays distinct
  EXPECT_EQ(CanonicalMarkerLabel("CUSTOM1"), "CUSTOM1");
  EXPECT_TRUE(IsKnownMarkerLabel("LASI"));
  EXPECT_TRUE(IsKnownMarkerLabel("LFWT"));
  EXPECT_FALSE(IsKnownMarkerLabel("CUSTOM1"));
}

TEST(MarkerLayout, AliasTableIsConsistent) {
  const auto& rules = AnatomicalMarkerLabels();
  ASSERT_EQ(rules.size(), 89u);
  std::set<std::string> aliases;
  for (const auto& a : MarkerLabelAliases()) {
    EXPECT_TRUE(std::binary_search(rules.begin(), rules.end(), a.canonical))
        << a.alias << " -> " << a.canonical;
    EXPECT_FALSE(std::binary_search(rules.begin(), rules.end(), a.alias))
        << "alias " << a.alias << " shadows a canonical label";
    EXPECT_TRUE(aliases.insert(a.alias).second) << a.alias;
  }
  EXPECT_GT(aliases.size(), 100u);
}

TEST(MarkerLayout, CanonicalizeMergesAliasesOfTheSameMarker) {
  MarkerLayout layout;
  layout.markers = {{"LASI", "body", {1}, 0.0095},
                    {"subj:LFWT", "body", {2}, 0.0095},
                    {"C7", "body", {3}, 0.0095}};
  const MarkerLayout canonical = CanonicalizeLayout(layout);
  ASSERT_EQ(canonical.num_markers(), 2);
  EXPECT_EQ(canonical.markers[1].label, "LFWT");
  EXPECT_EQ(canonical.markers[1].vertex_ids, (std::vector<int>{1, 2}));
}

TEST(MarkerLayout, ExcludeRemovesMarkersByCanonicalName) {
  const MarkerLayout cmu = MakeBuiltinLayout(ProceduralBody(), "cmu41");
  // RBAK is the Plug-in Gait name of RBAC; names are case-insensitive.
  const MarkerLayout subset =
      ExcludeMarkers(cmu, {"RBAK", "lshn"}, "layout.exclude");
  EXPECT_EQ(subset.num_markers(), 39);
  EXPECT_EQ(subset.FindLabel("RBAC"), -1);
  EXPECT_EQ(subset.FindLabel("LSHN"), -1);
  EXPECT_EQ(subset.markers[subset.FindLabel("RSHN")],
            cmu.markers[cmu.FindLabel("RSHN")]);
  EXPECT_EQ(subset.surface_model_type, cmu.surface_model_type);
  EXPECT_EQ(ExcludeMarkers(cmu, {}, "layout.exclude"), cmu);

  const std::vector<std::string> labels = {"C7", "LFHD", "RBAC"};
  EXPECT_EQ(KeptLabelPositions(labels, {"LFHD"}, "k"),
            (std::vector<int>{0, 2}));
  EXPECT_EQ(MessageOf([&] { KeptLabelPositions(labels, {"T10"}, "k.ex"); }),
            "Invalid configuration. k.ex: 'T10' is not a label of the layout "
            "(C7 LFHD RBAC)");
  EXPECT_EQ(MessageOf([&] {
              KeptLabelPositions(labels, {"C7", "LFHD", "RBAK"}, "k.ex");
            }),
            "Invalid configuration. k.ex removes every label of the layout");
}

TEST(MarkerLayout, MergeBuildsTheSuperset) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout cmu = MakeBuiltinLayout(body, "cmu41");
  const MarkerLayout pig = MakeBuiltinLayout(body, "pig39");
  MarkerLayout shifted = cmu;  // same labels on other vertices
  for (auto& m : shifted.markers) m.vertex_ids = {m.vertex_ids[0] + 1};
  const MarkerLayout superset = MergeLayouts({cmu, pig, shifted});
  EXPECT_EQ(superset.num_markers(), 43);  // CMU 41 + LTIB, RTIB
  const MarkerLayout::Marker& lfwt =
      superset.markers[superset.FindLabel("LFWT")];
  EXPECT_EQ(lfwt.vertex_ids.size(), 2u);  // CMU/PiG share the vertex, + shifted
  EXPECT_EQ(superset.FindLabel("LASI"), -1);
  EXPECT_GE(superset.FindLabel("RTIB"), 0);
  EXPECT_EQ(superset.markers[superset.FindLabel("RTIB")].vertex_ids.size(), 1u);
  // Without canonicalisation PiG names stay separate labels.
  MergeLayoutsOptions raw;
  raw.canonicalize_labels = false;
  EXPECT_EQ(MergeLayouts({cmu, pig}, raw).num_markers(), 41 + 7);
  // Inconsistent inputs.
  MarkerLayout other_distance = pig;
  for (auto& m : other_distance.markers) m.distance_from_skin = 0.012;
  const std::string m1 = MessageOf([&] {
    MergeLayouts({cmu, other_distance});
  });
  EXPECT_NE(m1.find("distance_from_skin"), std::string::npos) << m1;
  MarkerLayout other_model = pig;
  other_model.surface_model_type = "smplx";
  EXPECT_THROW(MergeLayouts({cmu, other_model}), ConfigError);
  EXPECT_THROW(MergeLayouts({}), ConfigError);
}

// Real CMU/HDM05 and Plug-in Gait wrist markers sit on a wrist bar off the
// skin: the built-in layouts put them in their own type with a larger
// distance (SOMA's wrist_markers_on_stick, 0.039 m).
TEST(BuiltinLayouts, WristBarMarkersHaveTheirOwnTypeAndDistance) {
  const std::vector<std::string> wrist = {"LWRA", "LWRB", "RWRA", "RWRB"};
  for (const auto& label : wrist) {
    EXPECT_EQ(BuiltinMarkerType(label), kWristMarkerType) << label;
  }
  EXPECT_EQ(BuiltinMarkerType("LIWR"), kWristMarkerType);  // MoSh++ aliases
  EXPECT_EQ(BuiltinMarkerType("subj:rowr"), kWristMarkerType);
  EXPECT_EQ(BuiltinMarkerType("LFIN"), "body");
  EXPECT_EQ(BuiltinMarkerType("C7"), "body");
  EXPECT_GT(kWristBarDistanceFromSkin, 2 * kDefaultDistanceFromSkin);
  EXPECT_DOUBLE_EQ(BuiltinDistanceFromSkin(kWristMarkerType),
                   kWristBarDistanceFromSkin);
  EXPECT_DOUBLE_EQ(BuiltinDistanceFromSkin("body"), kDefaultDistanceFromSkin);

  const BodyModel& body = ProceduralBody();
  std::vector<MarkerLayout> all;
  for (const auto& name : BuiltinLayoutNames()) {
    const MarkerLayout layout = MakeBuiltinLayout(body, name);
    for (const auto& m : layout.markers) {
      const bool is_wrist =
          std::find(wrist.begin(), wrist.end(), m.label) != wrist.end();
      EXPECT_EQ(m.type, is_wrist ? "wrist" : "body") << name << " " << m.label;
      EXPECT_DOUBLE_EQ(
          m.distance_from_skin,
          is_wrist ? kWristBarDistanceFromSkin : kDefaultDistanceFromSkin)
          << name << " " << m.label;
    }
    // Label ids are ordered by (type, label): the wrist labels come last.
    const std::vector<std::string> labels = layout.Labels();
    ASSERT_GE(labels.size(), 4u);
    EXPECT_EQ(std::vector<std::string>(labels.end() - 4, labels.end()), wrist)
        << name;
    // Two markersets in the JSON, and it reads back unchanged.
    const std::string json = MarkerLayoutToJson(layout);
    EXPECT_NE(json.find("\"wrist\""), std::string::npos) << name;
    EXPECT_EQ(ParseMarkerLayout(json, name), layout) << name;
    all.push_back(layout);
  }

  // Virtual markers of the wrist bar are further apart than their skin
  // vertices (by about twice the distance: the normals are nearly opposite).
  const MarkerLayout& cmu = all[0];
  const Eigen::Matrix3Xd normals =
      VertexNormals(body.template_vertices, body.faces);
  const Eigen::Matrix3Xd p =
      MarkerPositions(cmu, body.template_vertices, normals);
  for (const char* side : {"L", "R"}) {
    const int a = cmu.FindLabel(std::string(side) + "WRA");
    const int b = cmu.FindLabel(std::string(side) + "WRB");
    ASSERT_GE(a, 0);
    ASSERT_GE(b, 0);
    const double skin =
        (body.template_vertices.col(cmu.markers[a].vertex_ids[0]) -
         body.template_vertices.col(cmu.markers[b].vertex_ids[0]))
            .norm();
    const double markers = (p.col(a) - p.col(b)).norm();
    EXPECT_GT(markers, skin + 1.5 * kWristBarDistanceFromSkin) << side;
    EXPECT_LT(markers, skin + 2.0 * kWristBarDistanceFromSkin + 1e-9) << side;
  }

  // The built-in layouts merge (one distance per type), also with MoSh++
  // wrist names, and the superset keeps the wrist type.
  const MarkerLayout superset = MergeLayouts(all);
  EXPECT_EQ(superset.num_markers(), 89);
  EXPECT_EQ(superset.Labels(), BuiltinLayoutLabels("superset89"));
  MarkerLayout mosh = cmu;
  for (auto& m : mosh.markers) {
    if (m.label == "LWRA") m.label = "LIWR";
    if (m.label == "RWRB") m.label = "ROWR";
  }
  const MarkerLayout merged = MergeLayouts({cmu, mosh});
  EXPECT_EQ(merged, cmu);
  // A layout that gives a wrist label the body type cannot be merged.
  MarkerLayout body_wrist = cmu;
  for (auto& m : body_wrist.markers) {
    m.type = "body";
    m.distance_from_skin = kDefaultDistanceFromSkin;
  }
  EXPECT_THROW(MergeLayouts({cmu, body_wrist}), ConfigError);
}

TEST(BuiltinLayouts, HaveTheDocumentedLabels) {
  EXPECT_EQ(
      BuiltinLayoutNames(),
      (std::vector<std::string>{"cmu41", "pig39", "soma53", "superset89"}));
  const std::map<std::string, size_t> sizes = {
      {"cmu41", 41}, {"pig39", 39}, {"soma53", 53}, {"superset89", 89}};
  for (const auto& [name, size] : sizes) {
    const auto& labels = BuiltinLayoutLabels(name);
    EXPECT_EQ(labels.size(), size) << name;
    EXPECT_EQ(std::set<std::string>(labels.begin(), labels.end()).size(), size)
        << name;
  }
  const auto contains = [](const std::vector<std::string>& labels,
                           const std::string& label) {
    return std::find(labels.begin(), labels.end(), label) != labels.end();
  };
  const auto& cmu = BuiltinLayoutLabels("cmu41");
  for (const char* label :
       {"RBAC", "LWRA", "LWRB", "LFWT", "LBWT", "LSHN", "LMT5", "C7"}) {
    EXPECT_TRUE(contains(cmu, label)) << label;
  }
  const auto& pig = BuiltinLayoutLabels("pig39");
  for (const char* label : {"RBAK", "LASI", "RPSI", "LTIB"}) {
    EXPECT_TRUE(contains(pig, label)) << label;
  }
  // The superset is canonical: every cmu/soma label is in it.
  const auto& superset = BuiltinLayoutLabels("superset89");
  for (const auto& label : BuiltinLayoutLabels("soma53")) {
    EXPECT_TRUE(contains(superset, label)) << label;
  }
  EXPECT_EQ(std::set<std::string>(superset.begin(), superset.end()),
            std::set<std::string>(AnatomicalMarkerLabels().begin(),
                                  AnatomicalMarkerLabels().end()));
  EXPECT_THROW(BuiltinLayoutLabels("vicon99"), ConfigError);
}

TEST(BuiltinLayouts, ResolveToDistinctWellSeparatedVertices) {
  const BodyModel& body = ProceduralBody();
  const Eigen::Matrix3Xd normals =
      VertexNormals(body.template_vertices, body.faces);
  for (const auto& name : BuiltinLayoutNames()) {
    const MarkerLayout layout = MakeBuiltinLayout(body, name);
    EXPECT_EQ(layout.surface_model_type, "procedural");
    ASSERT_EQ(layout.num_markers(),
              static_cast<int>(BuiltinLayoutLabels(name).size()));
    EXPECT_NO_THROW(ValidateLayoutForBody(layout, body, name));
    std::set<int> vids;
    for (const auto& m : layout.markers) {
      ASSERT_EQ(m.vertex_ids.size(), 1u);
      vids.insert(m.vertex_ids[0]);
      EXPECT_EQ(m.type, BuiltinMarkerType(m.label)) << m.label;
      EXPECT_DOUBLE_EQ(m.distance_from_skin, BuiltinDistanceFromSkin(m.type))
          << m.label;
    }
    // BuiltinLayoutLabels lists the labels in label-id order.
    EXPECT_EQ(layout.Labels(), BuiltinLayoutLabels(name)) << name;
    EXPECT_EQ(vids.size(), static_cast<size_t>(layout.num_markers())) << name;
    const Eigen::Matrix3Xd p =
        MarkerPositions(layout, body.template_vertices, normals);
    double closest = 1e9;
    std::string pair;
    for (int a = 0; a < p.cols(); ++a) {
      for (int b = a + 1; b < p.cols(); ++b) {
        const double d = (p.col(a) - p.col(b)).norm();
        if (d < closest) {
          closest = d;
          pair = layout.markers[a].label + "-" + layout.markers[b].label;
        }
      }
    }
    EXPECT_GT(closest, 0.025) << name << ": " << pair;
  }
}

TEST(BuiltinLayouts, LeftAndRightMarkersMirrorEachOther) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "superset89");
  const Eigen::Matrix3Xd p =
      MarkerPositions(layout,
                      body.template_vertices,
                      VertexNormals(body.template_vertices, body.faces));
  int pairs = 0;
  for (int i = 0; i < layout.num_markers(); ++i) {
    const std::string& label = layout.markers[i].label;
    if (label[0] != 'L') continue;
    const int j = layout.FindLabel("R" + label.substr(1));
    if (j < 0) continue;
    ++pairs;
    const Eigen::Vector3d mirrored(-p(0, j), p(1, j), p(2, j));
    EXPECT_LT((p.col(i) - mirrored).norm(), 0.02) << label;
  }
  EXPECT_EQ(pairs, 39);
  // Midline markers sit on the midline.
  for (const char* label : {"C7", "T10", "CLAV", "STRN", "ARIEL", "SACR"}) {
    EXPECT_LT(std::abs(p(0, layout.FindLabel(label))), 0.02) << label;
  }
}

TEST(BuiltinLayouts, Cmu41IsAnatomicallyPlausible) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const Eigen::Matrix3Xd p =
      MarkerPositions(layout,
                      body.template_vertices,
                      VertexNormals(body.template_vertices, body.faces));
  const auto at = [&](const char* label) {
    return Eigen::Vector3d(p.col(layout.FindLabel(label)));
  };
  const auto dist = [&](const char* a, const char* b) {
    return (at(a) - at(b)).norm();
  };
  EXPECT_GT(dist("LFHD", "RFHD"), 0.12);
  EXPECT_LT(dist("LFHD", "RFHD"), 0.20);
  EXPECT_GT(dist("LKNE", "LANK"), 0.35);
  EXPECT_LT(dist("LKNE", "LANK"), 0.50);
  EXPECT_GT(dist("LSHO", "RSHO"), 0.28);
  EXPECT_LT(dist("LSHO", "RSHO"), 0.45);
  EXPECT_GT(dist("LFWT", "RFWT"), 0.18);
  EXPECT_LT(dist("LFWT", "RFWT"), 0.32);
  // Wrist bar (real captures: ~0.14 m).
  EXPECT_GT(dist("LWRA", "LWRB"), 0.10);
  EXPECT_LT(dist("LWRA", "LWRB"), 0.18);
  EXPECT_GT(dist("C7", "CLAV"), 0.12);
  EXPECT_LT(dist("C7", "CLAV"), 0.25);
  EXPECT_GT(dist("LHEE", "LTOE"), 0.12);
  EXPECT_LT(dist("LHEE", "LTOE"), 0.25);
  // Orientation: front markers in front (-Y), back markers behind, head on top.
  EXPECT_LT(at("CLAV").y(), at("C7").y());
  EXPECT_LT(at("STRN").y(), at("T10").y());
  EXPECT_LT(at("LFWT").y(), at("LBWT").y());
  EXPECT_LT(at("LFHD").y(), at("LBHD").y());
  EXPECT_GT(at("LFHD").x(), 0.0);  // left is +X
  EXPECT_LT(at("LTOE").y(), at("LHEE").y());
  EXPECT_GT(at("LFHD").z(), at("C7").z());
  EXPECT_LT(at("LANK").z(), 0.12);
  EXPECT_NEAR(at("LWRA").z(), at("LELB").z(), 0.08);  // T-pose arms horizontal
}

TEST(BuiltinLayouts, PigAndCmuShareAnatomicalRules) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout cmu = MakeBuiltinLayout(body, "cmu41");
  const MarkerLayout pig = MakeBuiltinLayout(body, "pig39");
  const auto vid = [](const MarkerLayout& l, const char* label) {
    return l.markers[l.FindLabel(label)].vertex_ids[0];
  };
  EXPECT_EQ(vid(pig, "LASI"), vid(cmu, "LFWT"));
  EXPECT_EQ(vid(pig, "RPSI"), vid(cmu, "RBWT"));
  EXPECT_EQ(vid(pig, "RBAK"), vid(cmu, "RBAC"));
  EXPECT_EQ(vid(pig, "LKNE"), vid(cmu, "LKNE"));
}

TEST(MarkerLayout, MarkerPositionsOffsetAlongTheNormal) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const Eigen::Matrix3Xd n = VertexNormals(body.template_vertices, body.faces);
  const Eigen::Matrix3Xd p = MarkerPositions(layout, body.template_vertices, n);
  for (int i = 0; i < layout.num_markers(); ++i) {
    const int vid = layout.markers[i].vertex_ids[0];
    EXPECT_NEAR((p.col(i) - body.template_vertices.col(vid)).norm(),
                layout.markers[i].distance_from_skin,
                1e-12);
    EXPECT_GT((p.col(i) - body.template_vertices.col(vid)).dot(n.col(vid)),
              0.0);
  }
}

// A closed cube [-1, 1]^3 (counter-clockwise = outward, 12 triangles on
// vertices 0..7) and one extra triangle (vertices 8..10) in the plane x = 0.5
// whose normal is +x if `inner_faces_out`, else -x (facing the centre).
struct CubeWithInnerFace {
  Eigen::Matrix3Xd vertices;
  Eigen::Matrix3Xi faces;
};

CubeWithInnerFace MakeCubeWithInnerFace(bool inner_faces_out) {
  CubeWithInnerFace mesh;
  mesh.vertices.resize(3, 11);
  for (int i = 0; i < 8; ++i) {
    mesh.vertices.col(i) = Eigen::Vector3d(
        (i & 1) ? 1.0 : -1.0, (i & 2) ? 1.0 : -1.0, (i & 4) ? 1.0 : -1.0);
  }
  mesh.vertices.col(8) = Eigen::Vector3d(0.5, -0.5, -0.5);
  mesh.vertices.col(9) = Eigen::Vector3d(0.5, 0.8, -0.5);
  mesh.vertices.col(10) = Eigen::Vector3d(0.5, -0.5, 0.8);
  std::vector<Eigen::Vector3i> faces;
  const auto add = [&](int a, int b, int c, const Eigen::Vector3d& out) {
    const Eigen::Vector3d n =
        (mesh.vertices.col(b) - mesh.vertices.col(a))
            .cross(mesh.vertices.col(c) - mesh.vertices.col(a));
    faces.push_back(n.dot(out) > 0 ? Eigen::Vector3i(a, b, c)
                                   : Eigen::Vector3i(a, c, b));
  };
  // Each side: the 4 cube vertices with coordinate `axis` = `bit`.
  for (int axis = 0; axis < 3; ++axis) {
    for (int bit = 0; bit < 2; ++bit) {
      std::vector<int> quad;
      for (int i = 0; i < 8; ++i) {
        if (((i >> axis) & 1) == bit) quad.push_back(i);
      }
      // quad[0], quad[1], quad[3], quad[2] go round the square.
      Eigen::Vector3d out = Eigen::Vector3d::Zero();
      out(axis) = bit ? 1.0 : -1.0;
      add(quad[0], quad[1], quad[3], out);
      add(quad[0], quad[3], quad[2], out);
    }
  }
  add(8, 9, 10, Eigen::Vector3d(inner_faces_out ? 1.0 : -1.0, 0, 0));
  mesh.faces.resize(3, static_cast<Eigen::Index>(faces.size()));
  for (size_t f = 0; f < faces.size(); ++f) mesh.faces.col(f) = faces[f];
  return mesh;
}

TEST(SkinVertexAlongRay, LeavesThroughTheExitFacePastInnerFaces) {
  const Eigen::Vector3d dir = Eigen::Vector3d(1.0, 0.1, 0.05).normalized();
  // An inner surface facing the origin (a double layer, the far wall of a
  // cavity seen from outside it) is passed through: the marker lands on the
  // outer skin, x = 1. Nearest-hit placement took the inner triangle.
  const CubeWithInnerFace inward = MakeCubeWithInnerFace(false);
  const int v = SkinVertexAlongRay(
      Eigen::Vector3d::Zero(), dir, inward.vertices, inward.faces);
  ASSERT_GE(v, 0);
  EXPECT_LT(v, 8);
  EXPECT_EQ(inward.vertices(0, v), 1.0);
  // The hit triangle's vertex nearest the exit point (1, 0.1, 0.05).
  EXPECT_EQ(inward.vertices.col(v), Eigen::Vector3d(1.0, 1.0, 1.0))
      << inward.vertices.col(v).transpose();
  // An inner surface the ray leaves through is an exit: it is taken.
  const CubeWithInnerFace outward = MakeCubeWithInnerFace(true);
  const int w = SkinVertexAlongRay(
      Eigen::Vector3d::Zero(), dir, outward.vertices, outward.faces);
  EXPECT_GE(w, 8);
  // From outside, the ray enters through x = -1 and leaves through x = 1.
  const int from_outside = SkinVertexAlongRay(
      Eigen::Vector3d(-3.0, 0.0, 0.0), dir, inward.vertices, inward.faces);
  ASSERT_GE(from_outside, 0);
  EXPECT_EQ(inward.vertices(0, from_outside), 1.0);
  // Only entry faces ahead: the nearest hit. Nothing ahead: -1.
  Eigen::Matrix3Xi entry_only(3, 1);
  entry_only.col(0) = inward.faces.col(inward.faces.cols() - 1);
  EXPECT_GE(SkinVertexAlongRay(
                Eigen::Vector3d::Zero(), dir, inward.vertices, entry_only),
            8);
  EXPECT_EQ(
      SkinVertexAlongRay(
          Eigen::Vector3d(3.0, 0.0, 0.0), dir, inward.vertices, inward.faces),
      -1);
}

// Median inter-marker distances of the CMU/HDM05 head markers in the real
// captures (`soma realism`: HDM_mm_01-02_03_120 and cmu_01_01, mean of the two
// per-take medians), metres.
struct HeadPair {
  const char* a;
  const char* b;
  double real_m;
};
constexpr HeadPair kRealHeadPairs[] = {{"LFHD", "RFHD", 0.159},
                                       {"LBHD", "RBHD", 0.118},
                                       {"LFHD", "LBHD", 0.140},
                                       {"RFHD", "RBHD", 0.150}};

void ExpectRealisticHead(const BodyModel& body) {
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const Eigen::Matrix3Xd p =
      MarkerPositions(layout,
                      body.template_vertices,
                      VertexNormals(body.template_vertices, body.faces));
  const auto at = [&](const char* label) {
    return Eigen::Vector3d(p.col(layout.FindLabel(label)));
  };
  double body_sum = 0.0, real_sum = 0.0;
  for (const HeadPair& pair : kRealHeadPairs) {
    const double d = (at(pair.a) - at(pair.b)).norm();
    // Each pair within 20% (real head markers sit on a headband over hair,
    // further off the skin than the layout's 9.5 mm).
    EXPECT_NEAR(d / pair.real_m, 1.0, 0.2)
        << body.name << " " << pair.a << "-" << pair.b << " " << d;
    body_sum += d;
    real_sum += pair.real_m;
  }
  EXPECT_NEAR(body_sum / real_sum, 1.0, 0.1) << body.name;
  // On the cranium: above the head joint, front markers in front of the back
  // ones, left on +X.
  const Eigen::Matrix3Xd joints = body.RestJoints(body.template_vertices);
  for (const char* label : {"LFHD", "RFHD", "LBHD", "RBHD"}) {
    EXPECT_GT(at(label).z(), joints(2, kHead)) << body.name << " " << label;
  }
  EXPECT_LT(at("LFHD").y() + 0.08, at("LBHD").y()) << body.name;
  EXPECT_GT(at("LFHD").x(), 0.04) << body.name;
  EXPECT_LT(at("RBHD").x(), -0.04) << body.name;
}

TEST(BuiltinLayouts, HeadMarkersMatchRealCapturesOnTheProceduralBody) {
  ExpectRealisticHead(ProceduralBody());
}

// The MakeHuman neck leans forward: head rules cast from a point extrapolated
// from the neck through the head joint started in the face and put LFHD-RFHD
// 0.095 m apart on the brows (captures 0.159 m), LBHD on the cheeks.
TEST(BuiltinLayouts, HeadMarkersMatchRealCapturesOnTheMakeHumanBody) {
  const std::filesystem::path dir =
      soma::testing::SharedDataDir() / "body/makehuman";
  if (!std::filesystem::is_directory(dir)) {
    GTEST_SKIP() << "MakeHuman assets not found at " << dir;
  }
  const BodyModel body = LoadMakeHumanBody(dir);
  ExpectRealisticHead(body);
  const MarkerLayout layout = MakeBuiltinLayout(body, "superset89");
  EXPECT_NO_THROW(ValidateLayoutForBody(layout, body, "superset89"));
  std::set<int> vids;
  for (const auto& m : layout.markers) vids.insert(m.vertex_ids[0]);
  EXPECT_EQ(vids.size(), static_cast<size_t>(layout.num_markers()));
}

// Forefoot markers. Real captures (HDM_mm_01-02_03_120 and cmu_01_01, median
// over frames per side): LTOE-LMT5 0.073 / 0.066 m and 0.085 / 0.084 m.
void ExpectRealisticForefoot(const BodyModel& body) {
  const MarkerLayout layout = MakeBuiltinLayout(body, "soma53");
  const Eigen::Matrix3Xd p =
      MarkerPositions(layout,
                      body.template_vertices,
                      VertexNormals(body.template_vertices, body.faces));
  const auto at = [&](const char* label) {
    return Eigen::Vector3d(p.col(layout.FindLabel(label)));
  };
  for (const char* side : {"L", "R"}) {
    const std::string s(side);
    const Eigen::Vector3d toe = at((s + "TOE").c_str());
    const Eigen::Vector3d mt5 = at((s + "MT5").c_str());
    const Eigen::Vector3d mt1 = at((s + "MT1").c_str());
    const double sign = s == "L" ? 1.0 : -1.0;  // lateral is +X on the left
    EXPECT_GT((toe - mt5).norm(), 0.05) << body.name << " " << s << "TOE-MT5";
    EXPECT_LT((toe - mt5).norm(), 0.10) << body.name << " " << s << "TOE-MT5";
    // MT5 on the lateral border, MT1 on the medial one, LTOE between them.
    EXPECT_GT(sign * (mt5.x() - toe.x()), 0.03) << body.name << " " << s;
    EXPECT_GT(sign * (toe.x() - mt1.x()), 0.0) << body.name << " " << s;
    EXPECT_GT((mt1 - mt5).norm(), 0.07) << body.name << " " << s;
    // Off the floor and on the forefoot, in front of the ankle.
    EXPECT_GT(mt5.z(), 0.0) << body.name << " " << s;
    EXPECT_LT(mt5.y(), at((s + "ANK").c_str()).y() - 0.06)
        << body.name << " " << s;
  }
}

TEST(BuiltinLayouts, ForefootMarkersMatchRealCapturesOnTheProceduralBody) {
  ExpectRealisticForefoot(ProceduralBody());
}

// The MakeHuman foot joint is the third MTP joint between separate toes: a
// ray cast laterally from it left through the web of the third toe and put
// LMT5 7 mm from LTOE.
TEST(BuiltinLayouts, ForefootMarkersMatchRealCapturesOnTheMakeHumanBody) {
  const std::filesystem::path dir =
      soma::testing::SharedDataDir() / "body/makehuman";
  if (!std::filesystem::is_directory(dir)) {
    GTEST_SKIP() << "MakeHuman assets not found at " << dir;
  }
  ExpectRealisticForefoot(LoadMakeHumanBody(dir));
}

}  // namespace
}  // namespace soma

namespace soma {
namespace {

TEST(MarkerNameMap, ParsesAndAppliesBeforeTheAliasTable) {
  const MarkerNameMap map = ParseMarkerNameMap(
      "LeftKnee: LKNE\nREAS: RASI\n'meinard:Hips_L': LFWT\n", "names.yaml");
  ASSERT_EQ(map.entries.size(), 3u);
  EXPECT_EQ(map.Apply("LeftKnee"), "LKNE");
  EXPECT_EQ(map.Apply("subject:leftknee"), "LKNE");  // prefix, case ignored
  EXPECT_EQ(map.Apply("REAS"), "RASI");
  EXPECT_EQ(CanonicalMarkerLabel(map.Apply("REAS")), "RFWT");  // then aliases
  EXPECT_EQ(map.Apply("HIPS_L"), "LFWT");
  EXPECT_EQ(map.Apply("C7"), "C7");  // not in the map: unchanged
  EXPECT_EQ(map.Apply(std::vector<std::string>{"LeftKnee", "X"}),
            (std::vector<std::string>{"LKNE", "X"}));
  EXPECT_TRUE(ParseMarkerNameMap("", "empty.yaml").empty());
  // Checked against the labels it maps onto.
  const std::vector<std::string> labels = {"LKNE", "RFWT", "LFWT", "C7"};
  EXPECT_NO_THROW(CheckMarkerNameMap(map, labels, "the layout"));
}

TEST(MarkerNameMap, BadInputIsAOneLineErrorNamingFileAndKey) {
  const auto message = [](const std::string& text) -> std::string {
    try {
      ParseMarkerNameMap(text, "names.yaml");
    } catch (const IoError& e) {
      return e.what();
    }
    return "";
  };
  const auto expect_error = [&](const std::string& text,
                                const std::string& part) {
    const std::string what = message(text);
    EXPECT_NE(what.find("names.yaml"), std::string::npos) << text;
    EXPECT_NE(what.find(part), std::string::npos) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
  };
  expect_error("LeftKnee: 12\n", "LeftKnee: expected our marker name");
  expect_error("LeftKnee: [LKNE]\n", "a list");
  expect_error("LeftKnee:\n", "null");
  expect_error("LeftKnee: yes\n", "a bool");
  expect_error("- LKNE\n", "expected one mapping");
  expect_error("a: [\n", "names.yaml");
  expect_error("LeftKnee: LKNE\nleftknee: RKNE\n", "the same capture name");
  EXPECT_THROW(ReadMarkerNameMap(soma::testing::CreateTestDir() / "none.yaml"),
               IoError);
  // A target that is not a label, two names onto one label.
  const std::vector<std::string> labels = {"LKNE", "RFWT"};
  const auto check_message = [&](const std::string& text) -> std::string {
    try {
      CheckMarkerNameMap(
          ParseMarkerNameMap(text, "names.yaml"), labels, "the layout");
    } catch (const IoError& e) {
      return e.what();
    }
    return "";
  };
  std::string what = check_message("LeftKnee: KNEE_L\n");
  EXPECT_NE(what.find("names.yaml: LeftKnee: KNEE_L is not a label of the "
                      "layout (2 labels: LKNE RFWT)"),
            std::string::npos)
      << what;
  what = check_message("REAS: RASI\nHipR: RFWT\n");  // RASI is RFWT
  EXPECT_NE(what.find("names.yaml: HipR: maps onto RFWT, as REAS does"),
            std::string::npos)
      << what;
}

}  // namespace
}  // namespace soma
