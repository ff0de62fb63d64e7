// Per-frame labelling of raw mocap point clouds with a trained labeler
// (REFERENCE 5.3-5.4; paper Sec. 4.5 "Using SOMA", per-frame mode).
//
//   FrameLabeler labeler(model.ptr(), options);
//   FrameLabels labels = labeler.Label(points);  // points: T x P x 3
//
// Frames are processed in batches of `batch_size`; each frame's points get an
// independent random permutation (seeded) before the network and the outputs
// are permuted back. No confidence threshold is applied. If two or more
// points of a frame are assigned the same real label, all of them become null
// (decode argmax, SOMA's rule), or the frame's labels are the most probable
// one-to-one matching (decode matching, model/label_matching.h).
#pragma once

#include "framework/config/node.h"
#include "framework/model/label_matching.h"

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <memory>
#include <utility>

namespace soma {

class LabelerImpl;
class FastLabeler;
struct LabelSlots;

/// Options of FrameLabeler.
struct InferenceOptions {
  int batch_size = 512;  // frames per forward pass (released default)
  /// Apply a random permutation to each frame's points before the network and
  /// invert it on the outputs (REFERENCE 5.3). Frame t of a Label() call uses
  /// Rng(seed).Stream(t), so results do not depend on batch_size.
  bool permute = true;
  uint64_t seed = 0;
  /// Use the optimised FastLabeler (same results to ~1e-5) when the model is
  /// supported; else the libtorch forward.
  bool use_fast_path = true;
  /// How the rows become labels (FrameLabels::label_ids).
  LabelDecode decode = LabelDecode::kArgmax;
  /// Test-time rotation ensemble: each frame is labelled `views` times,
  /// view v rotated by 2*pi*v/views about the vertical (Z) axis with its own
  /// point permutation, and the label distributions are averaged before the
  /// decode. The network is trained on every rotation about Z (REFERENCE
  /// 3.2) and centres each frame on its median, so every view is an equally
  /// valid input; averaging removes part of what one view gets wrong.
  /// 1 = one view, SOMA's labelling.
  int views = 1;
  void Validate() const;  // ConfigError on violation
};

/// Decodes `batch_size`, `permute`, `seed`, `use_fast_path`, `decode`,
/// `views` (unknown keys are an error).
InferenceOptions DecodeInferenceOptions(const ConfigNode& node);

/// Per-point labels of T frames of P points, L labels (null id = L).
struct FrameLabels {
  /// `T x P` int64: final labels after the duplicate rule (decode argmax)
  /// or the matching (decode matching); zero (missing) points are always
  /// null.
  at::Tensor label_ids;
  /// `T x P` int64: the network's argmax over the L+1 columns, before the
  /// duplicate rule (zero points included); with several views, the argmax
  /// of their mean distribution.
  at::Tensor predicted_ids;
  /// `T x P x (L+1)` float: per-point label distribution (exp of A' point
  /// rows, the mean over the views), in the input point order.
  at::Tensor label_confidence;
};

/// REFERENCE 5.4: `label_ids` (`T x P` int64, null = `num_labels`) with every
/// point whose `valid` (`T x P` bool) flag is false set to null, and every
/// real label carried by two or more valid points of a frame demoted to null
/// on all of those points.
at::Tensor ResolveDuplicateLabels(const at::Tensor& label_ids,
                                  const at::Tensor& valid,
                                  int64_t num_labels);

/// MatchFrameLabels (label_matching.h) of every frame: `probabilities` `T x
/// P x (L+1)` float (null = column L), `valid` `T x P` bool; returns `T x P`
/// int64 labels, null = L.
at::Tensor MatchLabels(const at::Tensor& probabilities,
                       const at::Tensor& valid);

/// `points` (`... x 3`) rotated by `angle` radians about the Z axis through
/// the origin (zero points stay zero).
at::Tensor RotateAboutVertical(const at::Tensor& points, double angle);

/// Batched per-frame inference with a labeler (eval mode, no autograd).
class FrameLabeler {
 public:
  /// Puts `model` in eval mode; with `use_fast_path`, snapshots its weights
  /// into a FastLabeler (later weight changes are not seen: rebuild).
  explicit FrameLabeler(std::shared_ptr<LabelerImpl> model,
                        const InferenceOptions& options = {});
  ~FrameLabeler();
  FrameLabeler(FrameLabeler&&) noexcept;
  FrameLabeler& operator=(FrameLabeler&&) noexcept;

  /// `points`: `T x P x 3` float, (0,0,0) = missing/padding. Frame t is
  /// permuted with Rng(seed).Stream(first_frame + t) (view v > 0: its
  /// .Stream(v)): a stream labelling one
  /// frame per call passes the frame's index to get the permutation of an
  /// offline call over the whole take. `slots` (a conditioned labeler only):
  /// each frame's own label slots, `T x L x Q` (GatherLabelSlots), in place
  /// of the layout the model holds; label ids then index each frame's slots.
  FrameLabels Label(const at::Tensor& points,
                    int64_t first_frame = 0,
                    const LabelSlots* slots = nullptr) const;

  int64_t num_labels() const;
  bool uses_fast_path() const { return fast_ != nullptr; }
  const InferenceOptions& options() const { return options_; }

 private:
  /// One view of frames [first_frame, first_frame + B) (`batch`: `B x P x
  /// 3`, slots `B x L x Q` or null): rotated by 2*pi*view/views about Z,
  /// permuted, through the network; the label distributions (`B x P x
  /// (L+1)`, first) and their argmax (`B x P`, second) in input order.
  std::pair<at::Tensor, at::Tensor> LabelView(const at::Tensor& batch,
                                              int64_t first_frame,
                                              int view,
                                              const LabelSlots* slots) const;

  std::shared_ptr<LabelerImpl> model_;
  InferenceOptions options_;
  std::unique_ptr<FastLabeler> fast_;
};

}  // namespace soma
