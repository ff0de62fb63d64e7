#include "framework/body/marker_layout.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include "tests/body/body_test_util.h"
#include <algorithm>
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
  EXPECT_NE(m1.find("broken.json:3:21:"), std::string::npos) << m1;

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
  const auto& cmu = BuiltinLayoutLabels("cmu41");
  for (const char* label :
       {"RBAC", "LWRA", "LWRB", "LFWT", "LBWT", "LSHN", "LMT5", "C7"}) {
    EXPECT_TRUE(std::binary_search(cmu.begin(), cmu.end(), std::string(label)))
        << label;
  }
  const auto& pig = BuiltinLayoutLabels("pig39");
  for (const char* label : {"RBAK", "LASI", "RPSI", "LTIB"}) {
    EXPECT_TRUE(std::binary_search(pig.begin(), pig.end(), std::string(label)))
        << label;
  }
  // The superset is canonical: every cmu/soma label is in it.
  const auto& superset = BuiltinLayoutLabels("superset89");
  for (const auto& label : BuiltinLayoutLabels("soma53")) {
    EXPECT_TRUE(std::binary_search(superset.begin(), superset.end(), label))
        << label;
  }
  EXPECT_EQ(superset, AnatomicalMarkerLabels());
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
      EXPECT_DOUBLE_EQ(m.distance_from_skin, kDefaultDistanceFromSkin);
    }
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
  EXPECT_GT(dist("LWRA", "LWRB"), 0.04);
  EXPECT_LT(dist("LWRA", "LWRB"), 0.09);
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
    EXPECT_NEAR(
        (p.col(i) - body.template_vertices.col(vid)).norm(), 0.0095, 1e-12);
    EXPECT_GT((p.col(i) - body.template_vertices.col(vid)).dot(n.col(vid)),
              0.0);
  }
}

}  // namespace
}  // namespace soma
