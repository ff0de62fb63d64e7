// The weight average: its decay schedule, the update formula, a bit-exact
// swap, and an archive of the average that Module::load reads back without
// aliasing the live weights.
#include "framework/train/weight_average.h"

#include "framework/core/error.h"

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <limits>
#include <sstream>
#include <vector>

namespace soma {
namespace {

TEST(WeightAverage, DecayWarmsUpToItsValue) {
  EXPECT_DOUBLE_EQ(WeightAverage::DecayAt(0.999, 1), 2.0 / 11.0);
  EXPECT_DOUBLE_EQ(WeightAverage::DecayAt(0.999, 90), 91.0 / 100.0);
  EXPECT_DOUBLE_EQ(WeightAverage::DecayAt(0.999, 100000), 0.999);
  EXPECT_DOUBLE_EQ(WeightAverage::DecayAt(0.5, 1), 2.0 / 11.0);
  EXPECT_DOUBLE_EQ(WeightAverage::DecayAt(0.5, 100), 0.5);
}

TEST(WeightAverage, RejectsADecayOutsideTheOpenUnitInterval) {
  for (const double decay :
       {0.0, 1.0, -0.1, 1.5, std::numeric_limits<double>::quiet_NaN()}) {
    EXPECT_THROW(WeightAverage({torch::zeros({2})}, decay), ConfigError)
        << decay;
  }
}

TEST(WeightAverage, FollowsTheFormulaAndCopiesIntegerTensors) {
  torch::manual_seed(3);
  torch::Tensor w = torch::randn({4, 3}).requires_grad_();
  torch::Tensor count = torch::zeros({}, torch::kLong);
  WeightAverage average({w, count}, 0.5);
  average.Reset();
  torch::Tensor expected = w.detach().to(torch::kDouble);
  for (int64_t step = 1; step <= 40; ++step) {
    {
      torch::NoGradGuard no_grad;
      w.add_(torch::randn({4, 3}));
      count.add_(1);
    }
    average.Update(step);
    const double d = WeightAverage::DecayAt(0.5, step);
    expected = d * expected + (1 - d) * w.detach().to(torch::kDouble);
  }
  const torch::Tensor live = w.detach().clone();
  average.Swap();
  EXPECT_TRUE(torch::allclose(
      w.detach().to(torch::kDouble), expected, /*rtol=*/1e-5, /*atol=*/1e-6));
  EXPECT_FALSE(torch::allclose(w.detach(), live));
  EXPECT_EQ(count.item<int64_t>(), 40);  // the copy of the live count
  average.Swap();
  EXPECT_TRUE(torch::equal(w.detach(), live));
}

TEST(WeightAverage, SwappedScopeRestoresBitForBit) {
  torch::manual_seed(4);
  torch::Tensor w = torch::randn({5});
  WeightAverage average({w}, 0.9);
  average.Reset();
  const torch::Tensor first = w.clone();
  w.mul_(3).add_(0.1);
  average.Update(1);
  const torch::Tensor live = w.clone();
  {
    const WeightAverage::Swapped swapped(&average);
    EXPECT_FALSE(torch::equal(w, live));
    const double d = WeightAverage::DecayAt(0.9, 1);
    EXPECT_TRUE(torch::allclose(w, d * first + (1 - d) * live));
  }
  EXPECT_TRUE(torch::equal(w, live));
  const WeightAverage::Swapped none(nullptr);  // no average: nothing to do
  EXPECT_TRUE(torch::equal(w, live));
}

struct TinyNet : torch::nn::Module {
  TinyNet()
      : linear(register_module("linear", torch::nn::Linear(3, 4))),
        norm(register_module("norm", torch::nn::BatchNorm1d(4))) {
    register_parameter("scale", torch::ones({1}));
  }
  torch::nn::Linear linear;
  torch::nn::BatchNorm1d norm;
};

TEST(WeightAverage, SavedAverageLoadsIntoAModuleAndDoesNotAliasTheWeights) {
  torch::manual_seed(5);
  TinyNet net;
  WeightAverage average(WeightAverage::WeightsOf(net), 0.9);
  average.Reset();
  for (int64_t step = 1; step <= 3; ++step) {
    {
      torch::NoGradGuard no_grad;
      for (torch::Tensor& p : net.parameters()) p.add_(torch::randn_like(p));
    }
    net.train();
    net.norm(net.linear(torch::randn({8, 3})));  // running stats move
    average.Update(step);
  }
  torch::serialize::OutputArchive archive;
  average.SaveAverage(net, &archive);
  // The weights change after the archive is written and before it is
  // serialised: the archive holds copies.
  std::vector<torch::Tensor> averaged;
  average.Swap();
  for (const torch::Tensor& w : WeightAverage::WeightsOf(net)) {
    averaged.push_back(w.clone());
  }
  average.Swap();
  {
    torch::NoGradGuard no_grad;
    for (torch::Tensor& p : net.parameters()) p.add_(1);
  }
  std::stringstream bytes;
  archive.save_to(bytes);

  TinyNet loaded;
  torch::serialize::InputArchive in;
  in.load_from(bytes);
  loaded.load(in);
  const std::vector<torch::Tensor> got = WeightAverage::WeightsOf(loaded);
  ASSERT_EQ(got.size(), averaged.size());
  for (size_t i = 0; i < got.size(); ++i) {
    EXPECT_TRUE(torch::equal(got[i], averaged[i])) << "weight " << i;
  }
}

}  // namespace
}  // namespace soma
