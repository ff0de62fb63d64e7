#include "framework/model/loss.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/model/register.h"
#include "framework/model/torch_utils.h"
#include "framework/registry/registry.h"

#include <fmt/format.h>
#include <torch/torch.h>

#include <memory>

namespace soma {

AugmentedTargets BuildAugmentedTargets(const at::Tensor& label_ids,
                                       int64_t num_labels,
                                       const at::Tensor& label_available) {
  if (label_ids.dim() != 2) {
    throw ShapeError(
        fmt::format("BuildAugmentedTargets: label_ids must be B x N, got {}",
                    ShapeString(label_ids)));
  }
  SOMA_CHECK(num_labels > 0) << "num_labels = " << num_labels;
  const int64_t batch = label_ids.size(0);
  const int64_t n = label_ids.size(1);
  const int64_t l = num_labels;
  const torch::Tensor ids = label_ids.to(torch::kLong);
  if (n > 0) {
    SOMA_CHECK(ids.min().item<int64_t>() >= 0 && ids.max().item<int64_t>() <= l)
        << "label ids must lie in [0, " << l << "]";
  }
  const auto float_options = torch::TensorOptions().dtype(torch::kFloat);
  const torch::Tensor one_hot =
      torch::one_hot(ids, l + 1).to(torch::kFloat);            // B N L+1
  const torch::Tensor count = one_hot.narrow(2, 0, l).sum(1);  // B L
  SOMA_CHECK(count.numel() == 0 || count.max().item<float>() <= 1.0f)
      << "a real label is carried by two points of one frame";
  const torch::Tensor present = count.gt(0);
  if (label_available.defined()) {
    if (label_available.dim() != 2 || label_available.size(0) != batch ||
        label_available.size(1) != l) {
      throw ShapeError(fmt::format(
          "BuildAugmentedTargets: label_available must be {} x {}, got {}",
          batch,
          l,
          ShapeString(label_available)));
    }
    SOMA_CHECK(label_available.to(torch::kBool).eq(present).all().item<bool>())
        << "label_available disagrees with the label ids (a label is available "
           "iff "
           "exactly one point carries it)";
  }
  const torch::Tensor not_available =
      present.logical_not().to(torch::kFloat);  // B L
  const torch::Tensor corner = static_cast<double>(l + 1) -
                               not_available.sum(1, /*keepdim=*/true);  // B 1
  const torch::Tensor dustbin_row =
      torch::cat({not_available, corner}, 1).unsqueeze(1);
  AugmentedTargets targets;
  targets.assignment = torch::cat({one_hot, dustbin_row}, 1);  // B N+1 L+1
  // Null rows (ghosts and zero points) share a total weight of one.
  const torch::Tensor is_null = ids.eq(l);                              // B N
  const torch::Tensor n_null = is_null.sum(1, true).to(torch::kFloat);  // B 1
  const torch::Tensor null_weight = torch::where(
      n_null.gt(0), 1.0 / n_null.clamp_min(1), torch::ones_like(n_null));
  const torch::Tensor point_weight =
      torch::where(is_null,
                   null_weight.expand({batch, n}),
                   torch::ones({batch, n}, float_options));
  const torch::Tensor row_weight =
      torch::cat({point_weight, null_weight}, 1);  // B N+1
  targets.weights =
      row_weight.unsqueeze(2).expand({batch, n + 1, l + 1}).contiguous();
  return targets;
}

at::Tensor ComputeLabelingLoss(const at::Tensor& log_assignment,
                               const AugmentedTargets& targets,
                               const LabelingLossOptions& options) {
  const torch::Tensor& g = targets.assignment;
  const torch::Tensor& w = targets.weights;
  if (log_assignment.dim() != 3 || g.dim() != 3 ||
      !g.sizes().equals(w.sizes()) || log_assignment.size(0) != g.size(0) ||
      log_assignment.size(2) != g.size(2)) {
    throw ShapeError(
        fmt::format("ComputeLabelingLoss: A' {} does not match G' {} / W {}",
                    ShapeString(log_assignment),
                    ShapeString(g),
                    ShapeString(w)));
  }
  const int64_t rows = log_assignment.size(1);
  const torch::Tensor gt = g.to(log_assignment.options());
  const torch::Tensor wt = w.to(log_assignment.options());
  if (rows == g.size(1)) {
    // Optimal transport: the full augmented matrix incl. dustbin row/corner.
    const torch::Tensor per_sample =
        -(gt * wt * log_assignment).sum({1, 2}) / gt.sum({1, 2});
    return per_sample.sum();
  }
  if (rows + 1 != g.size(1)) {
    throw ShapeError(
        fmt::format("ComputeLabelingLoss: A' has {} rows; expected N+1 = {} "
                    "(optimal transport) or "
                    "N = {} (log-softmax)",
                    rows,
                    g.size(1),
                    g.size(1) - 1));
  }
  // Log-softmax: point rows only.
  const torch::Tensor gp = gt.narrow(1, 0, rows);
  const torch::Tensor wp = wt.narrow(1, 0, rows);
  const torch::Tensor values =
      options.quirk_probability_loss ? log_assignment.exp() : log_assignment;
  const torch::Tensor per_sample =
      -(gp * wp * values).sum({1, 2}) / gp.sum({1, 2});
  return per_sample.sum();
}

at::Tensor SomaLabelingLoss::Compute(const at::Tensor& log_assignment,
                                     const AugmentedTargets& targets) const {
  return ComputeLabelingLoss(log_assignment, targets, options_);
}

void RegisterLosses() {
  GetRegistry<LabelingLoss>().Register(
      "soma", [](const ConfigNode& node, BuildContext&) {
        ConfigReader reader(node);
        LabelingLossOptions options;
        reader.Read("quirk_probability_loss", &options.quirk_probability_loss);
        reader.Finish();
        return std::make_unique<SomaLabelingLoss>(options);
      });
  RegisterConfigGroup<LabelingLoss>("loss");
}

}  // namespace soma
