#include "framework/model/mean_attention.h"

#include "framework/core/error.h"

#include <algorithm>

namespace soma {

std::vector<Eigen::MatrixXd> MeanAttention(LabelerImpl& model,
                                           const torch::Tensor& points,
                                           int batch_size) {
  torch::NoGradGuard no_grad;
  model.eval();
  torch::Tensor sum;
  const int64_t frames = points.size(0);
  for (int64_t t0 = 0; t0 < frames; t0 += batch_size) {
    const int64_t n = std::min<int64_t>(batch_size, frames - t0);
    const LabelerOutput out =
        model.forward(points.narrow(0, t0, n), /*return_attention=*/true);
    if (!out.attention.defined()) {
      throw ConfigError(
          "attention_span: the model has no self-attention layers (e.g. "
          "model=conv1d)");
    }
    // B x k x h x N x N -> max over heads -> sum over frames: k x N x N.
    const torch::Tensor layer_sum =
        std::get<0>(out.attention.max(/*dim=*/2)).sum(/*dim=*/0);
    sum = sum.defined() ? sum + layer_sum : layer_sum;
  }
  const torch::Tensor mean =
      (sum / static_cast<double>(frames)).to(torch::kDouble).contiguous();
  const int64_t k = mean.size(0), n = mean.size(1);
  std::vector<Eigen::MatrixXd> layers;
  for (int64_t l = 0; l < k; ++l) {
    // Row-major N x N (rows = attending marker) into a column-major matrix.
    layers.push_back(Eigen::Map<const Eigen::Matrix<double,
                                                    Eigen::Dynamic,
                                                    Eigen::Dynamic,
                                                    Eigen::RowMajor>>(
        mean[l].data_ptr<double>(), n, n));
  }
  return layers;
}

}  // namespace soma
