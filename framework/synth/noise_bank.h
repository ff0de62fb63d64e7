// The real-noise residual bank of the `real_noise` module (REFERENCE.md 3.4,
// "AMASS marker noise model"): K rows of per-label residual vectors
// (observed - simulated marker, metres), each label's column shuffled
// independently so that one row mixes residuals of unrelated real frames.
//
// File format (HDF5, readable with h5py):
//   /residuals   K x L x 3 float32   (chunked, deflate)
//   attrs: format = "soma-noise-bank", format_version = 1,
//          labels = L strings (superset label order), num_labels
#pragma once

#include "framework/core/random.h"

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace soma {

struct NoiseBank {
  std::vector<std::string> labels;  // L superset labels, id order
  int64_t num_rows = 0;             // K
  std::vector<float> residuals;     // K x L x 3, row-major

  int num_labels() const { return static_cast<int>(labels.size()); }
  const float* row(int64_t k) const {
    return residuals.data() + k * num_labels() * 3;
  }
  /// ShapeError if the sizes disagree.
  void Validate() const;
};

/// Builds a bank from F frames of real (observed) markers and the markers
/// simulated for them (each F x L x 3, superset label order, (0,0,0) =
/// unobserved): the residual obs - sim of every label whose observed and
/// simulated markers are both present, per label; K = the largest count;
/// labels with fewer residuals are oversampled with replacement, labels with
/// none get K zero vectors; every label's column is shuffled independently.
/// ShapeError on size mismatches.
NoiseBank BuildNoiseBank(const std::vector<std::string>& labels,
                         const std::vector<float>& observed,
                         const std::vector<float>& simulated,
                         Rng& rng);

/// Writes `bank` atomically (`<path>.tmp` + rename). IoError on failure.
void WriteNoiseBank(const NoiseBank& bank, const std::filesystem::path& path);

/// Reads a bank; IoError naming the file for a missing or unreadable file,
/// a wrong format attribute or version, or a residuals dataset that is not
/// K x L x 3 float32 with L = the number of labels.
NoiseBank ReadNoiseBank(const std::filesystem::path& path);

}  // namespace soma
