// Skeletal motion as read from motion-capture files (BVH, ASF/AMC): a joint
// tree with rest offsets, per-frame local joint rotations and a root
// trajectory, plus forward kinematics, resampling and up-axis conversion.
//
// Conventions (the same as body_model.h, so that retargeting is a matter of
// joint correspondence, not of frame bookkeeping):
//  - Lengths in metres. Each reader converts file units with an explicit
//    `length_to_metres` factor (see bvh.h, asf_amc.h).
//  - Every joint frame is aligned with the world axes in the rest pose (all
//    local rotations = identity). `offsets[j]` is the rest position of joint
//    j relative to its parent, in the parent's (rest-aligned) frame.
//  - `local_rotations[t][j]` is the rotation of joint j relative to its
//    parent, relative to the rest pose, expressed in the rest-aligned frame:
//      G_0 = L_0,            p_0 = root_translation,
//      G_j = G_parent * L_j,  p_j = p_parent + G_parent * offsets[j].
//    This is SMPL's convention. File-specific rotation frames (the ASF bone
//    `axis`, BVH channel orders) are folded into L_j by the readers and kept
//    in Skeleton::channels / dof_frames as metadata.
//  - Source files are Y-up (BVH, ASF/AMC); ConvertYUpToZUp() maps them to
//    the framework's Z-up world, (x, y, z) -> (x, -z, y).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <limits>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// A degree of freedom of a joint as stored in a motion file.
enum class ChannelType {
  kXPosition,
  kYPosition,
  kZPosition,
  kXRotation,
  kYRotation,
  kZRotation,
};

/// "Xposition", ..., "Zrotation" (BVH spelling).
std::string_view ToString(ChannelType type);
bool IsRotation(ChannelType type);
/// 0, 1, 2 for the X, Y, Z channels.
int ChannelAxis(ChannelType type);

/// One channel of a joint with its optional limits (ASF `limits`): radians
/// for rotations, metres for translations; infinite when the file has none.
struct Channel {
  ChannelType type = ChannelType::kXRotation;
  double lower = -std::numeric_limits<double>::infinity();
  double upper = std::numeric_limits<double>::infinity();
};

/// How the rotation channels of one joint, listed c1, c2, c3 in the file,
/// compose into a rotation matrix.
enum class EulerConvention {
  /// BVH: R = R(c1) * R(c2) * R(c3) (rotations about the moving axes in the
  /// listed order; "Zrotation Xrotation Yrotation" gives Rz * Rx * Ry).
  kMovingAxes,
  /// Acclaim ASF/AMC: c1 is applied first about the fixed axes, so
  /// R = R(c3) * R(c2) * R(c1) ("rx ry rz" gives Rz * Ry * Rx).
  kFixedAxes,
};

std::string_view ToString(EulerConvention convention);

/// The vertical axis of a clip's world frame.
enum class UpAxis { kY, kZ };

/// "Y" or "Z".
std::string_view ToString(UpAxis axis);
/// Inverse of ToString(UpAxis); throws ConfigError on anything else.
UpAxis UpAxisFromString(std::string_view text);

/// A joint tree with rest offsets. Joint 0 is the root; parents[0] = -1 and
/// parents[j] < j for every other joint (a pre-order of the tree).
struct Skeleton {
  std::vector<std::string> names;
  std::vector<int> parents;
  /// Rest position of joint j in its parent's rest-aligned frame, metres.
  /// offsets[0] is zero: the root's world position is the clip's
  /// root_translation.
  std::vector<Eigen::Vector3d> offsets;
  /// Channels of each joint in file order (what the file stores per frame).
  /// Empty for end sites. Only the root may have position channels.
  std::vector<std::vector<Channel>> channels;
  /// Orientation, in the rest-aligned frame, of the frame in which joint
  /// j's channel angles are measured (the ASF bone `axis` C_j; identity for
  /// BVH). The local rotation is L_j = C_j * R(channels) * C_j^-1.
  std::vector<Eigen::Quaterniond> dof_frames;
  /// How rotation channels compose (one convention per file format).
  EulerConvention euler_convention = EulerConvention::kMovingAxes;

  int num_joints() const { return static_cast<int>(parents.size()); }
  /// Index of the joint called `name`, -1 if absent (exact match).
  int Find(std::string_view name) const;
  /// Children of joint j in index order.
  std::vector<int> Children(int joint) const;
  /// True for joints with neither channels nor children (BVH `End Site`,
  /// ASF bone tips): they only mark where a chain ends.
  bool IsEndSite(int joint) const;
  /// Throws ShapeError if the per-joint arrays disagree in size, the tree is
  /// not a pre-order rooted at 0, names repeat, or a non-root joint has
  /// position channels.
  void Validate() const;

  /// Local rotation of `joint` from its rotation-channel values (radians, in
  /// the order of the joint's rotation channels; position channels are not
  /// counted): L = C * R(angles) * C^-1 with R composed per euler_convention.
  /// Throws ShapeError if `angles` has the wrong size.
  Eigen::Quaterniond RotationFromChannels(int joint,
                                          std::span<const double> angles) const;
  /// Number of rotation channels of `joint`.
  int NumRotationChannels(int joint) const;

  /// World joint positions in the rest pose with the root at the origin.
  std::vector<Eigen::Vector3d> RestPositions() const;
};

/// Per-frame local joint rotations and root trajectory of one take.
struct MotionClip {
  std::string name;         // file stem, e.g. "131_01"
  std::string source_path;  // the file it was read from (empty if built)
  double frame_rate = 0.0;  // Hz
  Skeleton skeleton;
  /// World position of the root joint per frame, metres.
  std::vector<Eigen::Vector3d> root_translation;
  /// frames x joints local rotations (see the file comment).
  std::vector<std::vector<Eigen::Quaterniond>> local_rotations;
  UpAxis up_axis = UpAxis::kY;

  int num_frames() const { return static_cast<int>(local_rotations.size()); }
  int num_joints() const { return skeleton.num_joints(); }
  /// Time from the first to the last frame, seconds.
  double duration() const;
  /// Throws ShapeError on inconsistent sizes or a non-positive frame rate
  /// (and everything Skeleton::Validate checks).
  void Validate() const;

  /// World frames of all joints at frame t (ForwardKinematics).
  std::vector<Eigen::Isometry3d> GlobalPose(int frame) const;
  /// World joint positions at frame t, metres.
  std::vector<Eigen::Vector3d> JointPositions(int frame) const;
};

/// Forward kinematics: the world frame of every joint (rotation = global
/// joint orientation relative to the rest pose, translation = joint
/// position, metres) for one frame. Throws ShapeError if `local_rotations`
/// does not have one entry per joint.
std::vector<Eigen::Isometry3d> ForwardKinematics(
    const Skeleton& skeleton,
    const Eigen::Vector3d& root_translation,
    const std::vector<Eigen::Quaterniond>& local_rotations);

/// Resamples a clip to `target_rate` Hz: frame k of the result is source
/// time k / target_rate, local rotations are slerped (shortest arc) and the
/// root translation is linearly interpolated between the two neighbouring
/// source frames. Frames that fall exactly on a source frame are copied
/// bit for bit (120 -> 30 Hz keeps every 4th frame). The result covers
/// [0, duration]; it has floor(duration * target_rate) + 1 frames.
/// Throws ShapeError on an empty clip or a non-positive rate.
MotionClip ResampleClip(const MotionClip& clip, double target_rate = 30.0);

/// Rotates the world so that +Z is up: (x, y, z) -> (x, -z, y), a rotation
/// of +90 degrees about X (as for SMPL in body_model.h). Offsets, root
/// translation and the dof frames are rotated and every local rotation is
/// conjugated, so the rest pose stays world-aligned and all distances are
/// kept. Throws InternalError (a caller bug) unless clip.up_axis is Y.
MotionClip ConvertYUpToZUp(const MotionClip& clip);

}  // namespace soma
