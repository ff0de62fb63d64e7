#include "framework/motion/coverage.h"

#include "framework/core/file.h"
#include "framework/core/plot.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace soma {
namespace {

double Fraction(const std::vector<int>& histogram,
                int first_bin,
                int last_bin,
                int total) {
  int sum = 0;
  for (int b = first_bin; b <= last_bin; ++b) sum += histogram[b];
  return total > 0 ? static_cast<double>(sum) / total : 0.0;
}

std::string TypeOf(const std::string& clip_name) {
  const size_t underscore = clip_name.find_last_of('_');
  if (underscore == std::string::npos) return clip_name;
  const std::string suffix = clip_name.substr(underscore + 1);
  const bool numeric =
      !suffix.empty() && std::all_of(suffix.begin(), suffix.end(), ::isdigit);
  return numeric ? clip_name.substr(0, underscore) : clip_name;
}

}  // namespace

double CoverageReport::UprightFraction() const {
  return Fraction(tilt_histogram, 0, 1, num_frames);
}
double CoverageReport::HorizontalFraction() const {
  return Fraction(tilt_histogram, 4, 7, num_frames);
}
double CoverageReport::InvertedFraction() const {
  return Fraction(tilt_histogram, 10, 11, num_frames);
}

CoverageReport ComputeCoverage(const BodyModel& body,
                               const std::vector<PoseSequence>& clips) {
  CoverageReport report;
  const Eigen::Matrix3Xd rest = body.RestJoints(body.template_vertices);
  std::vector<std::vector<double>> angles(kNumCoreJoints);
  for (const PoseSequence& clip : clips) {
    ++report.num_clips;
    report.frames_per_type[TypeOf(clip.name)] += clip.num_frames();
    for (const BodyPose& pose : clip.frames) {
      const PosedSkeleton s = PoseSkeleton(body, rest, pose);
      const Eigen::Vector3d axis =
          s.global[kNeck].translation() - s.global[kPelvis].translation();
      const double tilt =
          std::acos(std::clamp(axis.normalized().z(), -1.0, 1.0)) * 180.0 /
          M_PI;
      ++report.tilt_histogram[std::min(11, static_cast<int>(tilt / 15.0))];
      const double height = s.global[kPelvis].translation().z();
      ++report.pelvis_height_histogram[std::clamp(
          static_cast<int>(height / 0.1), 0, 19)];
      for (int j = 0; j < kNumCoreJoints; ++j) {
        angles[j].push_back(pose.rotations.col(j).norm() * 180.0 / M_PI);
      }
      ++report.num_frames;
    }
  }
  report.joint_angle_percentiles.resize(kNumCoreJoints, {0, 0, 0, 0});
  for (int j = 0; j < kNumCoreJoints; ++j) {
    std::vector<double>& a = angles[j];
    if (a.empty()) continue;
    std::sort(a.begin(), a.end());
    auto at = [&](double q) {
      return a[static_cast<size_t>(q * (a.size() - 1))];
    };
    report.joint_angle_percentiles[j] = {at(0.05), at(0.5), at(0.95), a.back()};
  }
  return report;
}

void WriteCoverageReport(const CoverageReport& report,
                         const std::filesystem::path& dir) {
  CreateDirectories(dir);
  std::ostringstream md;
  md << "# Pose coverage\n\n"
     << fmt::format(
            "{} clips, {} frames.\n\n", report.num_clips, report.num_frames)
     << "| body tilt | fraction of frames |\n|---|---|\n"
     << fmt::format("| upright (< 30 deg) | {:.3f} |\n",
                    report.UprightFraction())
     << fmt::format("| horizontal (60-120 deg) | {:.3f} |\n",
                    report.HorizontalFraction())
     << fmt::format("| inverted (> 150 deg) | {:.3f} |\n\n",
                    report.InvertedFraction())
     << "| tilt bin (deg) | frames |\n|---|---|\n";
  for (int b = 0; b < 12; ++b) {
    md << fmt::format(
        "| {}-{} | {} |\n", 15 * b, 15 * (b + 1), report.tilt_histogram[b]);
  }
  md << "\n| pelvis height (m) | frames |\n|---|---|\n";
  for (int b = 0; b < 20; ++b) {
    md << fmt::format("| {:.1f}-{:.1f} | {} |\n",
                      0.1 * b,
                      0.1 * (b + 1),
                      report.pelvis_height_histogram[b]);
  }
  md << "\n| motion | frames |\n|---|---|\n";
  for (const auto& [type, frames] : report.frames_per_type) {
    md << fmt::format("| {} | {} |\n", type, frames);
  }
  std::ostringstream csv;
  csv << "joint,angle_p5_deg,angle_p50_deg,angle_p95_deg,angle_max_deg\n";
  md << "\n| joint | local rotation p5 / p50 / p95 / max (deg) |\n|---|---|\n";
  for (int j = 0; j < kNumCoreJoints &&
                  j < static_cast<int>(report.joint_angle_percentiles.size());
       ++j) {
    const auto& p = report.joint_angle_percentiles[j];
    csv << fmt::format("{},{:.2f},{:.2f},{:.2f},{:.2f}\n",
                       CoreJointNames()[j],
                       p[0],
                       p[1],
                       p[2],
                       p[3]);
    md << fmt::format("| {} | {:.1f} / {:.1f} / {:.1f} / {:.1f} |\n",
                      CoreJointNames()[j],
                      p[0],
                      p[1],
                      p[2],
                      p[3]);
  }
  WriteFileAtomic(dir / "coverage.md", md.str());
  WriteFileAtomic(dir / "coverage.csv", csv.str());

  const double n = std::max(1, report.num_frames);
  std::vector<std::string> tilt_labels;
  std::vector<double> tilt_values;
  for (int b = 0; b < 12; ++b) {
    tilt_labels.push_back(std::to_string(15 * b));
    tilt_values.push_back(report.tilt_histogram[b] / n);
  }
  BarChart(tilt_labels,
           tilt_values,
           {.title = "Body tilt (0 upright, 180 inverted)",
            .x_label = "tilt bin start (deg)",
            .y_label = "fraction of frames"})
      .WritePng(dir / "coverage_tilt.png");
  std::vector<std::string> height_labels;
  std::vector<double> height_values;
  for (int b = 0; b < 20; ++b) {
    height_labels.push_back(fmt::format("{:.1f}", 0.1 * b));
    height_values.push_back(report.pelvis_height_histogram[b] / n);
  }
  BarChart(height_labels,
           height_values,
           {.title = "Pelvis height",
            .x_label = "height bin start (m)",
            .y_label = "fraction of frames"})
      .WritePng(dir / "coverage_pelvis_height.png");
  std::vector<std::string> joint_labels;
  std::vector<double> p95;
  for (int j = 1; j < kNumCoreJoints; ++j) {
    joint_labels.push_back(std::to_string(j));
    p95.push_back(report.joint_angle_percentiles[j][2]);
  }
  BarChart(joint_labels,
           p95,
           {.title = "95th percentile local rotation per joint",
            .x_label = "core joint index",
            .y_label = "degrees"})
      .WritePng(dir / "coverage_joints.png");
}

}  // namespace soma
