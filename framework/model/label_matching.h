// How a frame's per-point label distributions become labels
// (`task.inference.decode`).
//
//   argmax    REFERENCE 5.4, SOMA's rule: every point takes the argmax of its
//             row over the L labels and the null column, and a real label
//             claimed by two or more points of the frame is taken from all
//             of them (null). Two points that both want label j lose it
//             both, even when one of them is far more sure.
//   matching  The most probable labelling in which no real label is used
//             twice: points are matched to labels one-to-one (null any
//             number of times), maximising sum_i log p(i, label_i), the
//             log-likelihood of the frame's labelling under the rows'
//             distributions. With w_ij = log p_ij - log p_i,null (what
//             labelling point i with j gains over leaving it null) this is
//             a maximum-weight bipartite matching over the pairs with
//             w_ij > 0, solved exactly by the Hungarian method (O(n^3), n =
//             max(points, labels); ~10^5 operations for a 41-marker frame).
//             Where no real label is two points' argmax, the two decodes
//             agree and the Hungarian step is skipped (most frames of a
//             trained labeler).
//
// Neither rule changes the network or its training; the trainer's validation
// accuracy keeps SOMA's rule.
#pragma once

#include <cstdint>
#include <span>
#include <string_view>

namespace soma {

enum class LabelDecode {
  kArgmax,    ///< per-point argmax, duplicates -> null (REFERENCE 5.4)
  kMatching,  ///< one-to-one maximum-likelihood matching
};
std::string_view ToString(LabelDecode decode);
/// "argmax" | "matching"; ConfigError naming `decode` otherwise.
LabelDecode LabelDecodeFromString(std::string_view name);

/// One frame of `num_points` points and `num_labels` real labels:
/// `probabilities` holds num_points rows of num_labels + 1 values (column
/// num_labels = null), row-major; `valid[i]` false marks a missing point
/// (always null). Writes each point's label (null = num_labels) to
/// `labels`. Probabilities below 1e-30 count as 1e-30 (a padded label slot
/// holds exactly 0), so that every weight is finite.
void MatchFrameLabels(std::span<const float> probabilities,
                      std::span<const bool> valid,
                      int64_t num_labels,
                      std::span<int64_t> labels);

}  // namespace soma
