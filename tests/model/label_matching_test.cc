// The one-to-one label decode (model/label_matching.h): against SOMA's
// argmax rule on frames where the answer is known, and against every
// labelling of small random frames enumerated by brute force.
#include "framework/model/label_matching.h"

#include "framework/core/error.h"
#include "framework/core/random.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <span>
#include <vector>

namespace soma {
namespace {

std::vector<int64_t> Match(const std::vector<float>& probabilities,
                           const std::vector<bool>& valid_in,
                           int64_t num_labels) {
  // std::vector<bool> has no contiguous storage for a span.
  const std::unique_ptr<bool[]> valid(new bool[valid_in.size()]);
  for (size_t i = 0; i < valid_in.size(); ++i) valid[i] = valid_in[i];
  std::vector<int64_t> labels(valid_in.size(), -7);
  MatchFrameLabels(probabilities,
                   std::span<const bool>(valid.get(), valid_in.size()),
                   num_labels,
                   labels);
  return labels;
}

// log-likelihood of a labelling (null = num_labels); -inf when a real label
// is used twice.
double LogLikelihood(const std::vector<float>& probabilities,
                     const std::vector<int64_t>& labels,
                     const std::vector<bool>& valid,
                     int64_t num_labels) {
  std::vector<int> used(num_labels, 0);
  double sum = 0;
  for (size_t i = 0; i < labels.size(); ++i) {
    if (!valid[i]) continue;
    const int64_t j = labels[i];
    if (j < num_labels && used[j]++ > 0) {
      return -std::numeric_limits<double>::infinity();
    }
    sum += std::log(probabilities[i * (num_labels + 1) + j]);
  }
  return sum;
}

TEST(LabelMatching, TheSurerPointKeepsAContestedLabelAndTheOtherTakesItsNext) {
  // Two points both put most mass on label 0; SOMA's rule nulls both. The
  // matching gives label 0 to point 0 (0.9 against 0.6) and point 1 its
  // second choice, label 1 (0.3 beats its null 0.1).
  const std::vector<float> p = {
      0.90f,
      0.05f,
      0.05f,  // point 0
      0.60f,
      0.30f,
      0.10f,  // point 1
  };
  EXPECT_EQ(Match(p, {true, true}, 2), (std::vector<int64_t>{0, 1}));
}

TEST(LabelMatching, NullWhenNoFreeLabelBeatsIt) {
  // Point 1's only label better than null is taken by the surer point 0.
  const std::vector<float> p = {
      0.90f,
      0.05f,
      0.05f,  // point 0
      0.50f,
      0.05f,
      0.45f,  // point 1: label 1 (0.05) is worse than null
  };
  EXPECT_EQ(Match(p, {true, true}, 2), (std::vector<int64_t>{0, 2}));
}

TEST(LabelMatching, AgreesWithTheArgmaxWhenItsLabelsAreDistinct) {
  const std::vector<float> p = {
      0.10f,
      0.70f,
      0.10f,
      0.10f,  // argmax 1
      0.05f,
      0.05f,
      0.05f,
      0.85f,  // argmax null
      0.80f,
      0.10f,
      0.05f,
      0.05f,  // argmax 0
  };
  EXPECT_EQ(Match(p, {true, true, true}, 3), (std::vector<int64_t>{1, 3, 0}));
}

TEST(LabelMatching, MissingPointsAndZeroProbabilitiesStayNull) {
  // Point 0 is missing (its row would win label 0); label 1 is a padded slot
  // (probability exactly 0 everywhere).
  const std::vector<float> p = {
      1.0f,
      0.0f,
      0.0f,  // missing
      0.4f,
      0.0f,
      0.6f,  // null is likelier than label 0
      0.7f,
      0.0f,
      0.3f,
  };
  EXPECT_EQ(Match(p, {false, true, true}, 2), (std::vector<int64_t>{2, 2, 0}));
}

TEST(LabelMatching, MorePointsThanLabelsAndNoLabels) {
  const std::vector<float> p = {
      0.6f,
      0.4f,  //
      0.9f,
      0.1f,  //
      0.7f,
      0.3f,
  };
  EXPECT_EQ(Match(p, {true, true, true}, 1), (std::vector<int64_t>{1, 0, 1}));
  EXPECT_EQ(Match({1.0f, 1.0f}, {true, true}, 0), (std::vector<int64_t>{0, 0}));
}

TEST(LabelMatching, FindsTheMostLikelyLabellingOfRandomFrames) {
  // Every labelling of up to 5 points with up to 4 labels, enumerated.
  Rng rng(5);
  for (int trial = 0; trial < 300; ++trial) {
    const int points = 1 + trial % 5;
    const int64_t labels = trial % 4 + (trial % 7 == 0 ? 0 : 1);
    std::vector<float> p(static_cast<size_t>(points) * (labels + 1));
    std::vector<bool> valid(points);
    for (int i = 0; i < points; ++i) {
      valid[i] = rng.Uniform() < 0.85;
      double sum = 0;
      for (int64_t j = 0; j <= labels; ++j) {
        // Peaked rows, as a trained network gives.
        const double x = std::exp(6.0 * rng.Uniform());
        p[i * (labels + 1) + j] = static_cast<float>(x);
        sum += x;
      }
      for (int64_t j = 0; j <= labels; ++j) {
        p[i * (labels + 1) + j] /= static_cast<float>(sum);
      }
    }
    double best = -std::numeric_limits<double>::infinity();
    std::vector<int64_t> labelling(points, labels);
    std::function<void(int)> enumerate = [&](int i) {
      if (i == points) {
        best = std::max(best, LogLikelihood(p, labelling, valid, labels));
        return;
      }
      for (int64_t j = 0; j <= labels; ++j) {
        labelling[i] = j;
        enumerate(i + 1);
      }
    };
    enumerate(0);
    const std::vector<int64_t> matched = Match(p, valid, labels);
    for (int i = 0; i < points; ++i) {
      if (!valid[i]) EXPECT_EQ(matched[i], labels) << "trial " << trial;
    }
    EXPECT_NEAR(LogLikelihood(p, matched, valid, labels), best, 1e-9)
        << "trial " << trial << ": " << points << " points, " << labels
        << " labels";
  }
}

TEST(LabelMatching, ShapeMismatchIsAnError) {
  std::vector<int64_t> labels(2);
  const bool valid[2] = {true, true};
  const std::vector<float> p(5, 0.5f);  // not 2 x 3
  EXPECT_THROW(MatchFrameLabels(p, valid, 2, labels), InternalError);
}

TEST(LabelDecode, NamesRoundTripAndAnUnknownOneIsAConfigError) {
  for (LabelDecode d : {LabelDecode::kArgmax, LabelDecode::kMatching}) {
    EXPECT_EQ(LabelDecodeFromString(ToString(d)), d);
  }
  EXPECT_THROW(LabelDecodeFromString("hungarian"), ConfigError);
}

}  // namespace
}  // namespace soma
