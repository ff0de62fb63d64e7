// What the SOMA labeler returns for a batch of frames (REFERENCE 1.4, 1.5).
//
// Kept in a light header (ATen tensors only, no torch::nn) so that the
// optimised inference path and the inference API can use it without pulling
// in the module headers.
#pragma once

#include <ATen/core/Tensor.h>

namespace soma {

/// Outputs of one labeler forward pass for a batch of `B` frames of `N` points
/// and a layout of `L` labels (label id `L` is the null/ghost label).
struct LabelerOutput {
  /// Raw per-point scores of the score head, `B x N x C` with `C = L` for the
  /// optimal-transport normalization and `C = L + 1` for log-softmax (the
  /// score matrix S of the paper, Fig. 3).
  at::Tensor scores;
  /// The augmented log assignment A' (`aug_asmat`, Sec. 4.2, Eq. 6): for
  /// optimal transport `B x (N+1) x (L+1)` (dustbin row and column, rows are
  /// log-distributions), for log-softmax `B x N x (L+1)`.
  at::Tensor log_assignment;
  /// exp(A') restricted to the N point rows, `B x N x (L+1)`.
  at::Tensor label_confidence;
  /// argmax of `label_confidence` over the L+1 columns, `B x N` (int64);
  /// the value L means null (ghost point or missing marker).
  at::Tensor label_ids;
  /// Self-attention weights `B x k x h x N x N` (k layers, h heads) when they
  /// were requested and the backbone has attention; undefined otherwise.
  at::Tensor attention;
  /// A conditioned labeller's point keys `B x D x N`
  /// (ConditionedScoreHead::PointKeys; what LabelerImpl::PositionLoss
  /// takes); undefined for a fixed-layout one.
  at::Tensor point_keys;
};

}  // namespace soma
