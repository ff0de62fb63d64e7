// Helpers shared by the files of the fast training engine (fast_train.h):
// fast_layers.cc (the per-point layers: LinearOp, BatchNormOp, ResBlockOp),
// fast_backbones.cc (SelfAttentionOp, Conv1dBackboneOp) and fast_train.cc
// (normalization + loss, FastTrainer, the fused Adam step). Not part of the
// engine's interface.
#pragma once

#include "framework/model/fast_train.h"

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <vector>

namespace soma::fast {

/// Rows per chunk of the elementwise passes.
inline constexpr int64_t kRowGrain = 64;
/// Frames per chunk of the per-frame loops (attention, loss).
inline constexpr int64_t kFrameGrain = 4;

/// `parameter.grad()` as float data; allocated as zeros when undefined.
float* Grad(at::Tensor& parameter);

/// Head-major position `head * dh + d` -> interleaved channel `d * h + head`.
std::vector<int64_t> HeadMajorOrder(int64_t d_model, int64_t heads);

/// `y = max(x, 0)` elementwise (`rows x cols`).
void Relu(const Mat& x, Mat& y);

/// `dy *= (mask > 0)` elementwise.
void ReluBackwardInPlace(const Mat& mask, Mat& dy);

/// `y += x` elementwise over the first `cols` columns.
void AddInPlace(const float* x,
                int64_t ldx,
                int64_t rows,
                int64_t cols,
                float* y,
                int64_t ldy);

/// `y = a + b` elementwise over the first `cols` columns.
void AddColumns(const float* a,
                int64_t lda,
                const float* b,
                int64_t ldb,
                int64_t rows,
                int64_t cols,
                float* y,
                int64_t ldy);

/// `y = x` over the first `cols` columns.
void CopyColumns(const float* x,
                 int64_t ldx,
                 int64_t rows,
                 int64_t cols,
                 float* y,
                 int64_t ldy);

}  // namespace soma::fast
