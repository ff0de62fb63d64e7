#include "framework/model/label_matching.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace soma {
namespace {

// The floor of a probability before its log (MatchFrameLabels).
constexpr double kMinProbability = 1e-30;

// Minimum-cost assignment of every one of `n` rows to a distinct one of `m`
// >= n columns (cost row-major n x m): the Hungarian method with potentials
// (Kuhn-Munkres as formulated by Jonker and Volgenant, shortest augmenting
// paths, O(n^2 m)). Returns the column of each row.
std::vector<int> MinCostAssignment(const std::vector<double>& cost,
                                   int n,
                                   int m) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  // 1-based: row 0 / column 0 are the virtual start of each augmenting path.
  std::vector<double> u(n + 1, 0.0), v(m + 1, 0.0);
  std::vector<int> row_of(m + 1, 0), way(m + 1, 0);
  std::vector<double> min_slack(m + 1);
  std::vector<char> used(m + 1);
  for (int i = 1; i <= n; ++i) {
    row_of[0] = i;
    int j0 = 0;
    std::fill(min_slack.begin(), min_slack.end(), kInf);
    std::fill(used.begin(), used.end(), 0);
    do {
      used[j0] = 1;
      const int i0 = row_of[j0];
      double delta = kInf;
      int j1 = 0;
      const double* row = cost.data() + static_cast<size_t>(i0 - 1) * m;
      for (int j = 1; j <= m; ++j) {
        if (used[j]) continue;
        const double slack = row[j - 1] - u[i0] - v[j];
        if (slack < min_slack[j]) {
          min_slack[j] = slack;
          way[j] = j0;
        }
        if (min_slack[j] < delta) {
          delta = min_slack[j];
          j1 = j;
        }
      }
      for (int j = 0; j <= m; ++j) {
        if (used[j]) {
          u[row_of[j]] += delta;
          v[j] -= delta;
        } else {
          min_slack[j] -= delta;
        }
      }
      j0 = j1;
    } while (row_of[j0] != 0);
    do {  // flip the augmenting path
      const int j1 = way[j0];
      row_of[j0] = row_of[j1];
      j0 = j1;
    } while (j0 != 0);
  }
  std::vector<int> column_of(n, -1);
  for (int j = 1; j <= m; ++j) {
    if (row_of[j] != 0) column_of[row_of[j] - 1] = j - 1;
  }
  return column_of;
}

}  // namespace

std::string_view ToString(LabelDecode decode) {
  switch (decode) {
    case LabelDecode::kArgmax:
      return "argmax";
    case LabelDecode::kMatching:
      return "matching";
  }
  return "?";
}

LabelDecode LabelDecodeFromString(std::string_view name) {
  if (name == "argmax") return LabelDecode::kArgmax;
  if (name == "matching") return LabelDecode::kMatching;
  throw ConfigError(fmt::format(
      "Invalid configuration. decode = {}. Violated constraint: one of "
      "argmax, matching",
      name));
}

void MatchFrameLabels(std::span<const float> probabilities,
                      std::span<const bool> valid,
                      int64_t num_labels,
                      std::span<int64_t> labels) {
  const int64_t num_points = static_cast<int64_t>(labels.size());
  const int64_t width = num_labels + 1;
  if (num_labels < 0 || static_cast<int64_t>(valid.size()) != num_points ||
      static_cast<int64_t>(probabilities.size()) != num_points * width) {
    throw InternalError(fmt::format(
        "MatchFrameLabels: {} probabilities, {} valid flags and {} labels do "
        "not make {} points x {} labels + null",
        probabilities.size(),
        valid.size(),
        labels.size(),
        num_points,
        num_labels));
  }
  std::fill(labels.begin(), labels.end(), num_labels);
  std::vector<int64_t> rows;  // the valid points
  for (int64_t i = 0; i < num_points; ++i) {
    if (valid[i]) rows.push_back(i);
  }
  if (rows.empty() || num_labels == 0) return;
  // Each row's own best label (first of ties; null at num_labels). When no
  // real label is anyone's best twice, that labelling is feasible and
  // maximises every term of the sum at once: the matching is the argmax,
  // and most frames of a trained labeler end here.
  {
    std::vector<char> taken(num_labels, 0);
    bool distinct = true;
    for (const int64_t i : rows) {
      const float* row = probabilities.data() + i * width;
      const int64_t best = std::max_element(row, row + width) - row;
      labels[i] = best;
      if (best < num_labels && taken[best]++) distinct = false;
    }
    if (distinct) return;
    for (const int64_t i : rows) labels[i] = num_labels;
  }
  const int n = static_cast<int>(rows.size());
  const int m = std::max(n, static_cast<int>(num_labels));
  // cost = -max(w_ij, 0) with w_ij = log p_ij - log p_i,null, and the columns
  // past num_labels (when points outnumber labels) cost 0. A maximum-weight
  // matching over the pairs with w > 0 is a minimum-cost perfect assignment
  // of this matrix with its zero-cost (w <= 0) pairs dropped.
  std::vector<double> cost(static_cast<size_t>(n) * m, 0.0);
  for (int r = 0; r < n; ++r) {
    const float* row = probabilities.data() + rows[r] * width;
    const double null_log =
        std::log(std::max<double>(row[num_labels], kMinProbability));
    for (int64_t j = 0; j < num_labels; ++j) {
      const double w =
          std::log(std::max<double>(row[j], kMinProbability)) - null_log;
      cost[static_cast<size_t>(r) * m + j] = -std::max(w, 0.0);
    }
  }
  const std::vector<int> column_of = MinCostAssignment(cost, n, m);
  for (int r = 0; r < n; ++r) {
    const int j = column_of[r];
    if (j >= 0 && j < num_labels && cost[static_cast<size_t>(r) * m + j] < 0) {
      labels[rows[r]] = j;
    }
  }
}

}  // namespace soma
