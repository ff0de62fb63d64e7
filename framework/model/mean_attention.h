// The attention a labeler pays on a set of frames, as SOMA's Appendix A
// measures it for the self-attention span (eval/attention_span.h): per
// self-attention layer, the attention weights maxed over heads and averaged
// over frames.
#pragma once

#include "framework/model/labeler.h"

#include <Eigen/Core>
#include <torch/torch.h>

#include <vector>

namespace soma {

/// Per self-attention layer of `model` (k layers): the L x L attention
/// weights (rows = the attending point) maxed over heads and averaged over
/// the frames of `points` (`F x L x 3` float, metres), run in eval mode
/// without gradients in batches of `batch_size` frames. ConfigError if the
/// model has no self-attention layers (e.g. model=conv1d).
std::vector<Eigen::MatrixXd> MeanAttention(LabelerImpl& model,
                                           const torch::Tensor& points,
                                           int batch_size);

}  // namespace soma
