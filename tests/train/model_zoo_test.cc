// Bundled models (models/<name>/: model.pt + card.yaml) and choosing one for
// a capture by its labels.
#include "framework/train/model_zoo.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <Eigen/Geometry>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <string>
#include <vector>

namespace soma {
namespace {

using ::testing::HasSubstr;

std::vector<std::string> Cmu41Labels() {
  return {"ARIEL",  "C7",   "CLAV", "LANK", "LBHD",   "LBSH", "LBWT",
          "LELB",   "LFHD", "LFRM", "LFSH", "LFWT",   "LHEL", "LIEL",
          "LIHAND", "LIWR", "LKNE", "LKNI", "LMT1",   "LMT5", "LOHAND",
          "LOWR",   "LSHN", "LTHI", "LTOE", "LUPA",   "MBWT", "MFWT",
          "RANK",   "RBHD", "RBSH", "RBWT", "RELB",   "RFHD", "RFRM",
          "RFSH",   "RFWT", "RHEL", "RIEL", "RIHAND", "RIWR"};
}

BundledModel Model(const std::string& name,
                   std::vector<std::string> labels,
                   int priority = 100) {
  BundledModel m;
  m.name = name;
  m.layout = name;
  m.description = name + " model";
  m.priority = priority;
  m.labels = std::move(labels);
  m.checkpoint = "models/" + name + "/model.pt";
  return m;
}

TEST(ModelZoo, MatchLabelsCanonicalisesCaptureLabels) {
  // Subject prefixes, `*k` unlabelled columns and duplicates do not count.
  const LabelMatch m =
      MatchLabels({"meinard:C7", "meinard:CLAV", "*0", "*12", "C7", "XYZ"},
                  {"C7", "CLAV", "STRN"});
  EXPECT_EQ(m.capture_labels, 3);  // C7, CLAV, XYZ
  EXPECT_EQ(m.shared, 2);
  EXPECT_EQ(m.model_labels, 3);
  EXPECT_NEAR(m.capture_coverage(), 2.0 / 3.0, 1e-12);
  EXPECT_NEAR(m.jaccard(), 2.0 / 4.0, 1e-12);
  EXPECT_FALSE(m.matches());
  EXPECT_TRUE(MatchLabels({"C7", "CLAV"}, {"C7", "CLAV", "STRN"}).matches());
  EXPECT_FALSE(MatchLabels({"*0", "*1"}, {"C7"}).matches());
}

TEST(ModelZoo, AutoPicksTheBestMatchTiesGoToPriority) {
  std::vector<std::string> small = Cmu41Labels();
  small.resize(20);
  const std::vector<BundledModel> models = {Model("full", Cmu41Labels(), 1),
                                            Model("twin", Cmu41Labels(), 2),
                                            Model("small", small, 3)};
  const ModelChoice full =
      ChooseBundledModel(models, Cmu41Labels(), "auto", "t");
  ASSERT_NE(full.model, nullptr);
  EXPECT_EQ(full.model->name, "full");
  EXPECT_THAT(full.reason, HasSubstr("41 of the capture's 41"));
  EXPECT_THAT(full.reason,
              HasSubstr("'twin' matches as well (task.model=twin)"));
  // A capture with only the first 20 labels fits `small` best (Jaccard 1).
  EXPECT_EQ(ChooseBundledModel(models, small, "", "t").model->name, "small");
  // By name.
  EXPECT_EQ(ChooseBundledModel(models, {}, "twin", "t").model->name, "twin");
}

TEST(ModelZoo, NoMatchIsOneLineListingTheModelsAndHowToTrain) {
  const std::vector<BundledModel> models = {Model("cmu41", Cmu41Labels())};
  try {
    ChooseBundledModel(models, {"*0", "*1", "*2"}, "auto", "raw.c3d");
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    EXPECT_THAT(what, HasSubstr("raw.c3d: no bundled model matches"));
    EXPECT_THAT(what, HasSubstr("an unlabelled capture"));
    EXPECT_THAT(what, HasSubstr("cmu41 (layout cmu41, 41 labels)"));
    EXPECT_THAT(what, HasSubstr("soma train"));
  }
  EXPECT_THROW(ChooseBundledModel(models, Cmu41Labels(), "nope", "t"),
               ConfigError);
  EXPECT_THROW(ChooseBundledModel({}, Cmu41Labels(), "auto", "t"), ConfigError);
}

/// A capture of `model`'s markers scaled by `scale`, moved rigidly from
/// frame to frame; the last marker wanders (not rigid with the others).
CaptureSummary RigidCapture(const BundledModel& model, double scale) {
  CaptureSummary c;
  c.name = "synthetic";
  c.labels = model.marker_labels;
  c.canonical = model.marker_labels;
  for (int t = 0; t < 40; ++t) {
    const Eigen::Matrix3d r =
        Eigen::AngleAxisd(0.1 * t, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    Eigen::Matrix3Xd f = (r * (scale * model.marker_positions)).colwise() +
                         Eigen::Vector3d(0.05 * t, 0.0, 0.01 * t);
    f.col(f.cols() - 1) += Eigen::Vector3d(0.0, 0.2 * std::sin(t), 0.0);
    if (t % 7 == 0) f.col(0).setConstant(std::nan(""));  // a gap
    c.frames.push_back(f);
  }
  return c;
}

TEST(ModelZoo, PlacementMismatchTellsLayoutsWithTheSameLabelsApart) {
  BundledModel a = Model("a", {}, /*priority=*/2);
  const int n = 8;
  a.marker_positions.resize(3, n);
  for (int m = 0; m < n; ++m) {
    a.marker_labels.push_back("M" + std::to_string(m));
    a.marker_positions.col(m) =
        Eigen::Vector3d(0.1 * m, 0.05 * (m % 3), 1.0 + 0.07 * (m % 4));
  }
  a.labels = a.marker_labels;
  BundledModel b = a;
  b.name = "b";
  b.priority = 1;  // b would win a plain tie
  b.marker_positions.col(2) += Eigen::Vector3d(0.0, 0.0, -0.13);  // moved 13 cm
  const CaptureSummary capture = RigidCapture(a, 1.1);
  int pairs = 0;
  // The subject's size is a scale factor: a fits exactly.
  EXPECT_NEAR(PlacementMismatch(capture, a, &pairs), 0.0, 1e-9);
  EXPECT_EQ(pairs, (n - 1) * (n - 2) / 2);  // the wandering marker is out
  EXPECT_GT(PlacementMismatch(capture, b), 0.01);
  const std::vector<BundledModel> models{b, a};  // choice.model points in
  const ModelChoice choice = ChooseBundledModel(models, capture, "auto");
  EXPECT_EQ(choice.model->name, "a");
  EXPECT_THAT(choice.reason, HasSubstr("marker placement fits best"));
  // Without positions the tie goes to the priority.
  CaptureSummary labels_only = capture;
  labels_only.frames.clear();
  EXPECT_EQ(ChooseBundledModel({b, a}, labels_only, "auto").model->name, "b");
  // Too few rigid pairs: not measurable.
  BundledModel tiny = a;
  tiny.marker_labels.resize(3);
  tiny.marker_positions.conservativeResize(3, 3);
  EXPECT_TRUE(std::isnan(PlacementMismatch(capture, tiny)));
}

TEST(ModelZoo, ListingAMissingDirectoryIsEmpty) {
  EXPECT_TRUE(ListBundledModels(testing::CreateTestDir() / "none").empty());
}

TEST(ModelZoo, ACardWithoutItsCheckpointIsAClearError) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(dir, "m/card.yaml", "description: x\nlayout: cmu41\n");
  EXPECT_THROW(ListBundledModels(dir), IoError);
  testing::WriteTextFile(dir, "m/card.yaml", "layout: cmu41\n");
  EXPECT_THROW(ListBundledModels(dir), Error);  // description is mandatory
}

TEST(ModelZoo, EveryBundledModelHasACompleteCard) {
  // The repository's own models/: each card names how the model was made
  // and what it scores; the checkpoint's labels are those of its layout.
  const std::vector<BundledModel> models =
      ListBundledModels(testing::SourceDir() / "models");
  ASSERT_GE(models.size(), 2u) << "expected the cmu41 and hdm05 models";
  std::set<std::string> layouts;
  for (const BundledModel& m : models) {
    SCOPED_TRACE(m.name);
    layouts.insert(m.layout);
    EXPECT_EQ(m.labels.size(), 41u);
    for (const char* key : {"command",
                            "commit",
                            "machine",
                            "training_time_s",
                            "parameters",
                            "val_acc",
                            "bundled_take",
                            "real_takes"}) {
      EXPECT_TRUE(m.card.Has(key)) << "card.yaml lacks " << key;
    }
    EXPECT_TRUE(std::filesystem::exists(m.dir / "README.md"));
  }
  EXPECT_TRUE(layouts.count("cmu41"));
  EXPECT_TRUE(layouts.count("hdm05"));
}

}  // namespace
}  // namespace soma
