#include "framework/io/skeleton_motion.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <set>

namespace soma {
namespace {

Eigen::Quaterniond AxisRotation(int axis, double angle) {
  return Eigen::Quaterniond(
      Eigen::AngleAxisd(angle, Eigen::Vector3d::Unit(axis)));
}

// +90 degrees about X: (x, y, z) -> (x, -z, y).
Eigen::Quaterniond YUpToZUpRotation() {
  return Eigen::Quaterniond(
      Eigen::AngleAxisd(0.5 * M_PI, Eigen::Vector3d::UnitX()));
}

}  // namespace

std::string_view ToString(ChannelType type) {
  switch (type) {
    case ChannelType::kXPosition:
      return "Xposition";
    case ChannelType::kYPosition:
      return "Yposition";
    case ChannelType::kZPosition:
      return "Zposition";
    case ChannelType::kXRotation:
      return "Xrotation";
    case ChannelType::kYRotation:
      return "Yrotation";
    case ChannelType::kZRotation:
      return "Zrotation";
  }
  return "?";
}

bool IsRotation(ChannelType type) {
  return type == ChannelType::kXRotation || type == ChannelType::kYRotation ||
         type == ChannelType::kZRotation;
}

int ChannelAxis(ChannelType type) {
  switch (type) {
    case ChannelType::kXPosition:
    case ChannelType::kXRotation:
      return 0;
    case ChannelType::kYPosition:
    case ChannelType::kYRotation:
      return 1;
    case ChannelType::kZPosition:
    case ChannelType::kZRotation:
      return 2;
  }
  return 0;
}

std::string_view ToString(EulerConvention convention) {
  switch (convention) {
    case EulerConvention::kMovingAxes:
      return "moving_axes";
    case EulerConvention::kFixedAxes:
      return "fixed_axes";
  }
  return "?";
}

std::string_view ToString(UpAxis axis) {
  return axis == UpAxis::kY ? "Y" : "Z";
}

UpAxis UpAxisFromString(std::string_view text) {
  if (text == "Y" || text == "y") return UpAxis::kY;
  if (text == "Z" || text == "z") return UpAxis::kZ;
  throw ConfigError(
      fmt::format("Invalid up axis '{}'. Expected one of: Y, Z", text));
}

// ---------------------------------------------------------------------------
// Skeleton

int Skeleton::Find(std::string_view name) const {
  for (int j = 0; j < num_joints(); ++j) {
    if (names[j] == name) return j;
  }
  return -1;
}

std::vector<int> Skeleton::Children(int joint) const {
  std::vector<int> children;
  for (int j = joint + 1; j < num_joints(); ++j) {
    if (parents[j] == joint) children.push_back(j);
  }
  return children;
}

bool Skeleton::IsEndSite(int joint) const {
  return channels[joint].empty() && Children(joint).empty();
}

void Skeleton::Validate() const {
  const size_t n = parents.size();
  if (n == 0) throw ShapeError("Skeleton: no joints");
  if (names.size() != n || offsets.size() != n || channels.size() != n ||
      dof_frames.size() != n) {
    throw ShapeError(fmt::format(
        "Skeleton: per-joint arrays disagree: {} parents, {} names, {} "
        "offsets, {} channel lists, {} dof frames",
        n,
        names.size(),
        offsets.size(),
        channels.size(),
        dof_frames.size()));
  }
  if (parents[0] != -1) {
    throw ShapeError(
        fmt::format("Skeleton: root parent is {}, expected -1", parents[0]));
  }
  std::set<std::string_view> seen;
  for (size_t j = 0; j < n; ++j) {
    if (j > 0 && (parents[j] < 0 || parents[j] >= static_cast<int>(j))) {
      throw ShapeError(fmt::format(
          "Skeleton: joint {} '{}' has parent {}; expected 0 <= parent < {}",
          j,
          names[j],
          parents[j],
          j));
    }
    if (!seen.insert(names[j]).second) {
      throw ShapeError(
          fmt::format("Skeleton: duplicate joint name '{}'", names[j]));
    }
    if (j > 0) {
      for (const Channel& channel : channels[j]) {
        if (!IsRotation(channel.type)) {
          throw ShapeError(fmt::format(
              "Skeleton: joint '{}' has a {} channel; only the root may "
              "translate",
              names[j],
              ToString(channel.type)));
        }
      }
    }
  }
}

int Skeleton::NumRotationChannels(int joint) const {
  int count = 0;
  for (const Channel& channel : channels[joint]) {
    if (IsRotation(channel.type)) ++count;
  }
  return count;
}

Eigen::Quaterniond Skeleton::RotationFromChannels(
    int joint, std::span<const double> angles) const {
  const int count = NumRotationChannels(joint);
  if (static_cast<int>(angles.size()) != count) {
    throw ShapeError(fmt::format(
        "Skeleton::RotationFromChannels: joint '{}' has {} rotation "
        "channels, got {} angles",
        names[joint],
        count,
        angles.size()));
  }
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  size_t k = 0;
  for (const Channel& channel : channels[joint]) {
    if (!IsRotation(channel.type)) continue;
    const Eigen::Quaterniond r =
        AxisRotation(ChannelAxis(channel.type), angles[k++]);
    // Moving axes: R = R1 R2 R3 (append on the right); fixed axes: the first
    // listed is applied first, R = R3 R2 R1 (prepend on the left).
    rotation = euler_convention == EulerConvention::kMovingAxes ? rotation * r
                                                                : r * rotation;
  }
  const Eigen::Quaterniond& frame = dof_frames[joint];
  return (frame * rotation * frame.conjugate()).normalized();
}

std::vector<Eigen::Vector3d> Skeleton::RestPositions() const {
  std::vector<Eigen::Vector3d> positions(num_joints());
  for (int j = 0; j < num_joints(); ++j) {
    positions[j] = j == 0 ? Eigen::Vector3d::Zero().eval()
                          : (positions[parents[j]] + offsets[j]).eval();
  }
  return positions;
}

// ---------------------------------------------------------------------------
// MotionClip

double MotionClip::duration() const {
  if (num_frames() < 2 || frame_rate <= 0.0) return 0.0;
  return (num_frames() - 1) / frame_rate;
}

void MotionClip::Validate() const {
  skeleton.Validate();
  if (!(frame_rate > 0.0) || !std::isfinite(frame_rate)) {
    throw ShapeError(fmt::format(
        "MotionClip '{}': frame rate {} is not positive", name, frame_rate));
  }
  if (root_translation.size() != local_rotations.size()) {
    throw ShapeError(fmt::format(
        "MotionClip '{}': {} root translations for {} frames of rotations",
        name,
        root_translation.size(),
        local_rotations.size()));
  }
  for (size_t t = 0; t < local_rotations.size(); ++t) {
    if (static_cast<int>(local_rotations[t].size()) != num_joints()) {
      throw ShapeError(fmt::format(
          "MotionClip '{}': frame {} has {} rotations for {} joints",
          name,
          t,
          local_rotations[t].size(),
          num_joints()));
    }
  }
}

std::vector<Eigen::Isometry3d> MotionClip::GlobalPose(int frame) const {
  SOMA_CHECK(frame >= 0 && frame < num_frames())
      << "frame " << frame << " of " << num_frames();
  return ForwardKinematics(
      skeleton, root_translation[frame], local_rotations[frame]);
}

std::vector<Eigen::Vector3d> MotionClip::JointPositions(int frame) const {
  const std::vector<Eigen::Isometry3d> pose = GlobalPose(frame);
  std::vector<Eigen::Vector3d> positions(pose.size());
  for (size_t j = 0; j < pose.size(); ++j) positions[j] = pose[j].translation();
  return positions;
}

// ---------------------------------------------------------------------------
// Free functions

std::vector<Eigen::Isometry3d> ForwardKinematics(
    const Skeleton& skeleton,
    const Eigen::Vector3d& root_translation,
    const std::vector<Eigen::Quaterniond>& local_rotations) {
  const int n = skeleton.num_joints();
  if (static_cast<int>(local_rotations.size()) != n ||
      static_cast<int>(skeleton.offsets.size()) != n) {
    throw ShapeError(fmt::format(
        "ForwardKinematics: {} local rotations, {} offsets for {} joints",
        local_rotations.size(),
        skeleton.offsets.size(),
        n));
  }
  std::vector<Eigen::Isometry3d> global(n);
  for (int j = 0; j < n; ++j) {
    const int parent = skeleton.parents[j];
    Eigen::Isometry3d& frame = global[j];
    frame.setIdentity();
    if (parent < 0) {
      frame.linear() = local_rotations[j].toRotationMatrix();
      frame.translation() = root_translation;
    } else {
      const Eigen::Isometry3d& parent_frame = global[parent];
      frame.linear() =
          parent_frame.linear() * local_rotations[j].toRotationMatrix();
      frame.translation() = parent_frame * skeleton.offsets[j];
    }
  }
  return global;
}

MotionClip ResampleClip(const MotionClip& clip, double target_rate) {
  if (clip.num_frames() == 0) {
    throw ShapeError(
        fmt::format("ResampleClip: clip '{}' has no frames", clip.name));
  }
  if (!(target_rate > 0.0) || !(clip.frame_rate > 0.0)) {
    throw ShapeError(fmt::format(
        "ResampleClip: clip '{}' rate {} Hz, target {} Hz; both must be > 0",
        clip.name,
        clip.frame_rate,
        target_rate));
  }
  MotionClip out = clip;
  out.frame_rate = target_rate;
  out.root_translation.clear();
  out.local_rotations.clear();

  const int n = clip.num_frames();
  const double ratio = clip.frame_rate / target_rate;  // source frames/step
  // Snap to an exact source frame when within this many frames (absorbs the
  // rounding of k * ratio so that aligned frames are copied exactly).
  constexpr double kSnap = 1e-9;
  const int num_out = static_cast<int>(std::floor((n - 1) / ratio + kSnap)) + 1;
  out.root_translation.reserve(num_out);
  out.local_rotations.reserve(num_out);
  for (int k = 0; k < num_out; ++k) {
    double source = k * clip.frame_rate / target_rate;
    const double nearest = std::round(source);
    if (std::abs(source - nearest) < kSnap) source = nearest;
    int i0 = static_cast<int>(std::floor(source));
    i0 = std::clamp(i0, 0, n - 1);
    const double alpha = source - i0;
    if (alpha == 0.0 || i0 == n - 1) {
      out.root_translation.push_back(clip.root_translation[i0]);
      out.local_rotations.push_back(clip.local_rotations[i0]);
      continue;
    }
    const int i1 = i0 + 1;
    out.root_translation.push_back((1.0 - alpha) * clip.root_translation[i0] +
                                   alpha * clip.root_translation[i1]);
    std::vector<Eigen::Quaterniond> rotations(clip.num_joints());
    for (int j = 0; j < clip.num_joints(); ++j) {
      rotations[j] = clip.local_rotations[i0][j]
                         .slerp(alpha, clip.local_rotations[i1][j])
                         .normalized();
    }
    out.local_rotations.push_back(std::move(rotations));
  }
  return out;
}

MotionClip ConvertYUpToZUp(const MotionClip& clip) {
  SOMA_CHECK(clip.up_axis == UpAxis::kY)
      << "ConvertYUpToZUp: clip '" << clip.name << "' is already "
      << ToString(clip.up_axis) << "-up";
  const Eigen::Quaterniond r = YUpToZUpRotation();
  const Eigen::Matrix3d r_matrix = r.toRotationMatrix();
  MotionClip out = clip;
  out.up_axis = UpAxis::kZ;
  Skeleton& skeleton = out.skeleton;
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    skeleton.offsets[j] = r_matrix * skeleton.offsets[j];
    // L' = R L R^-1 = (R C) R(angles) (R C)^-1: the dof frame is rotated.
    skeleton.dof_frames[j] = (r * skeleton.dof_frames[j]).normalized();
  }
  for (Eigen::Vector3d& translation : out.root_translation) {
    translation = r_matrix * translation;
  }
  for (std::vector<Eigen::Quaterniond>& frame : out.local_rotations) {
    for (Eigen::Quaterniond& rotation : frame) {
      rotation = (r * rotation * r.conjugate()).normalized();
    }
  }
  return out;
}

}  // namespace soma
