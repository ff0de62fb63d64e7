// Pose-coverage report of a motion set: how much of the space of human poses
// the synthetic training data covers (DESIGN.md: coverage, more than model
// size, decides real-data accuracy).
#pragma once

#include "framework/body/body_model.h"
#include "framework/motion/pose_sequence.h"

#include <array>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace soma {

struct CoverageReport {
  int num_frames = 0;
  int num_clips = 0;
  /// Body tilt = angle between the body axis (pelvis -> neck) and +Z:
  /// 0 upright, 90 horizontal, 180 upside down. Counts per 15-degree bin.
  std::vector<int> tilt_histogram = std::vector<int>(12, 0);
  /// Pelvis height above the floor, counts per 0.1 m bin from 0 to 2 m
  /// (last bin: >= 1.9 m).
  std::vector<int> pelvis_height_histogram = std::vector<int>(20, 0);
  /// Per core joint: percentiles (5, 50, 95) and maximum of the local
  /// rotation angle (degrees) over all frames.
  std::vector<std::array<double, 4>> joint_angle_percentiles;
  /// Frames per clip name prefix (motion type / file stem).
  std::map<std::string, int> frames_per_type;

  double UprightFraction() const;     // tilt < 30 deg
  double HorizontalFraction() const;  // 60..120 deg
  double InvertedFraction() const;    // > 150 deg
};

CoverageReport ComputeCoverage(const BodyModel& body,
                               const std::vector<PoseSequence>& clips);

/// Writes `coverage.md` (numbers), `coverage.csv` (per-joint table) and the
/// plots `coverage_tilt.png`, `coverage_pelvis_height.png`,
/// `coverage_joints.png` into `dir`.
void WriteCoverageReport(const CoverageReport& report,
                         const std::filesystem::path& dir);

}  // namespace soma
