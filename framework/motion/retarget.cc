#include "framework/motion/retarget.h"

#include "framework/core/error.h"
#include "framework/motion/procedural_motion.h"

#include <Eigen/Geometry>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace soma {
namespace {

/// The core child that defines each core joint's bone direction (-1: a leaf,
/// which keeps its parent's correction).
int CoreChild(int joint) {
  switch (joint) {
    case kLeftHip:
      return kLeftKnee;
    case kRightHip:
      return kRightKnee;
    case kLeftKnee:
      return kLeftAnkle;
    case kRightKnee:
      return kRightAnkle;
    case kLeftAnkle:
      return kLeftFoot;
    case kRightAnkle:
      return kRightFoot;
    case kSpine1:
      return kSpine2;
    case kSpine2:
      return kSpine3;
    case kSpine3:
      return kNeck;
    case kNeck:
      return kHead;
    case kLeftCollar:
      return kLeftShoulder;
    case kRightCollar:
      return kRightShoulder;
    case kLeftShoulder:
      return kLeftElbow;
    case kRightShoulder:
      return kRightElbow;
    case kLeftElbow:
      return kLeftWrist;
    case kRightElbow:
      return kRightWrist;
    case kLeftWrist:
      return kLeftHand;
    case kRightWrist:
      return kRightHand;
    default:
      return -1;
  }
}

/// Orthonormal frame from a left-pointing hip axis and an up vector.
Eigen::Matrix3d HipFrame(const Eigen::Vector3d& left,
                         const Eigen::Vector3d& up) {
  const Eigen::Vector3d x = left.normalized();
  const Eigen::Vector3d z = (up - up.dot(x) * x).normalized();
  Eigen::Matrix3d frame;
  frame << x, z.cross(x), z;
  return frame;
}

}  // namespace

const RetargetMap& CmuBvhRetargetMap() {
  // Naming of the CMU BVH files in ../shared/data/motion/cmu_bvh (bvh11).
  static const RetargetMap kMap = {
      "cmu_bvh",
      {{kPelvis, "Hips", ""},
       {kLeftHip, "LeftHip", "LeftKnee"},
       {kRightHip, "RightHip", "RightKnee"},
       {kLeftKnee, "LeftKnee", "LeftAnkle"},
       {kRightKnee, "RightKnee", "RightAnkle"},
       {kLeftAnkle, "LeftAnkle", "LeftToe"},
       {kRightAnkle, "RightAnkle", "RightToe"},
       {kLeftFoot, "LeftToe", ""},
       {kRightFoot, "RightToe", ""},
       {kSpine1, "lowerback", "Chest"},
       {kSpine2, "Chest", "Chest2"},
       {kSpine3, "Chest2", "lowerneck"},
       {kNeck, "Neck", "Head"},
       {kHead, "Head", ""},
       {kLeftCollar, "LeftCollar", "LeftShoulder"},
       {kRightCollar, "RightCollar", "RightShoulder"},
       {kLeftShoulder, "LeftShoulder", "LeftElbow"},
       {kRightShoulder, "RightShoulder", "RightElbow"},
       {kLeftElbow, "LeftElbow", "LeftWrist"},
       {kRightElbow, "RightElbow", "RightWrist"},
       {kLeftWrist, "LeftWrist", "lhand"},
       {kRightWrist, "RightWrist", "rhand"},
       {kLeftHand, "lhand", ""},
       {kRightHand, "rhand", ""}}};
  return kMap;
}

const RetargetMap& CmuCgspeedBvhRetargetMap() {
  // Naming of the cgspeed conversion of the CMU database.
  static const RetargetMap kMap = {
      "cmu_cgspeed_bvh",
      {{kPelvis, "Hips", ""},
       {kLeftHip, "LeftUpLeg", "LeftLeg"},
       {kRightHip, "RightUpLeg", "RightLeg"},
       {kLeftKnee, "LeftLeg", "LeftFoot"},
       {kRightKnee, "RightLeg", "RightFoot"},
       {kLeftAnkle, "LeftFoot", "LeftToeBase"},
       {kRightAnkle, "RightFoot", "RightToeBase"},
       {kLeftFoot, "LeftToeBase", ""},
       {kRightFoot, "RightToeBase", ""},
       {kSpine1, "LowerBack", "Spine"},
       {kSpine2, "Spine", "Spine1"},
       {kSpine3, "Spine1", "Neck"},
       {kNeck, "Neck1", "Head"},
       {kHead, "Head", ""},
       {kLeftCollar, "LeftShoulder", "LeftArm"},
       {kRightCollar, "RightShoulder", "RightArm"},
       {kLeftShoulder, "LeftArm", "LeftForeArm"},
       {kRightShoulder, "RightArm", "RightForeArm"},
       {kLeftElbow, "LeftForeArm", "LeftHand"},
       {kRightElbow, "RightForeArm", "RightHand"},
       {kLeftWrist, "LeftHand", "LeftFingerBase"},
       {kRightWrist, "RightHand", "RightFingerBase"},
       {kLeftHand, "LeftFingerBase", ""},
       {kRightHand, "RightFingerBase", ""}}};
  return kMap;
}

const RetargetMap& AsfRetargetMap() {
  static const RetargetMap kMap = {"asf",
                                   {{kPelvis, "root", ""},
                                    {kLeftHip, "lfemur", "ltibia"},
                                    {kRightHip, "rfemur", "rtibia"},
                                    {kLeftKnee, "ltibia", "lfoot"},
                                    {kRightKnee, "rtibia", "rfoot"},
                                    {kLeftAnkle, "lfoot", "ltoes"},
                                    {kRightAnkle, "rfoot", "rtoes"},
                                    {kLeftFoot, "ltoes", ""},
                                    {kRightFoot, "rtoes", ""},
                                    {kSpine1, "lowerback", "upperback"},
                                    {kSpine2, "upperback", "thorax"},
                                    {kSpine3, "thorax", "lowerneck"},
                                    {kNeck, "lowerneck", "upperneck"},
                                    {kHead, "head", ""},
                                    {kLeftCollar, "lclavicle", "lhumerus"},
                                    {kRightCollar, "rclavicle", "rhumerus"},
                                    {kLeftShoulder, "lhumerus", "lradius"},
                                    {kRightShoulder, "rhumerus", "rradius"},
                                    {kLeftElbow, "lradius", "lwrist"},
                                    {kRightElbow, "rradius", "rwrist"},
                                    {kLeftWrist, "lwrist", "lhand"},
                                    {kRightWrist, "rwrist", "rhand"},
                                    {kLeftHand, "lhand", ""},
                                    {kRightHand, "rhand", ""}}};
  return kMap;
}

const RetargetMap& DetectRetargetMap(const Skeleton& skeleton,
                                     const std::string& source) {
  for (const RetargetMap* map :
       {&CmuBvhRetargetMap(), &CmuCgspeedBvhRetargetMap(), &AsfRetargetMap()}) {
    const bool fits = std::all_of(map->entries.begin(),
                                  map->entries.end(),
                                  [&](const RetargetMap::Entry& e) {
                                    return skeleton.Find(e.source_joint) >= 0;
                                  });
    if (fits) return *map;
  }
  throw IoError(
      fmt::format("{}: the skeleton matches no retargeting map (CMU BVH names "
                  "Hips/LeftHip/..., "
                  "Hips/LeftUpLeg/... or ASF names root/lfemur/...)",
                  source));
}

PoseSequence Retarget(const MotionClip& clip,
                      const BodyModel& body,
                      const RetargetMap& map) {
  SOMA_CHECK_GE(body.num_joints(), static_cast<int>(kNumCoreJoints));
  const Skeleton& skeleton = clip.skeleton;
  const std::string source =
      clip.source_path.empty() ? clip.name : clip.source_path;
  if (clip.up_axis != UpAxis::kZ) {
    throw IoError(fmt::format(
        "{}: retargeting needs a Z-up clip (ConvertYUpToZUp)", source));
  }
  std::vector<int> source_of(kNumCoreJoints, -1),
      source_child_of(kNumCoreJoints, -1);
  for (const RetargetMap::Entry& e : map.entries) {
    const int s = skeleton.Find(e.source_joint);
    if (s < 0) {
      throw IoError(
          fmt::format("{}: joint '{}' of retargeting map '{}' is missing",
                      source,
                      e.source_joint,
                      map.name));
    }
    source_of[e.core_joint] = s;
    if (!e.source_child.empty()) {
      source_child_of[e.core_joint] = skeleton.Find(e.source_child);
      if (source_child_of[e.core_joint] < 0) {
        throw IoError(
            fmt::format("{}: joint '{}' of retargeting map '{}' is missing",
                        source,
                        e.source_child,
                        map.name));
      }
    }
  }
  const std::vector<Eigen::Vector3d> source_rest = skeleton.RestPositions();
  const Eigen::Matrix3Xd body_rest = body.RestJoints(body.template_vertices);

  // Rest corrections C_j (body rest bone -> source rest bone).
  std::vector<Eigen::Matrix3d> correction(kNumCoreJoints,
                                          Eigen::Matrix3d::Identity());
  {
    const Eigen::Vector3d src_left =
        source_rest[source_of[kLeftHip]] - source_rest[source_of[kRightHip]];
    const Eigen::Vector3d src_up =
        source_rest[source_of[kNeck]] - source_rest[source_of[kPelvis]];
    const Eigen::Vector3d body_left =
        body_rest.col(kLeftHip) - body_rest.col(kRightHip);
    const Eigen::Vector3d body_up =
        body_rest.col(kNeck) - body_rest.col(kPelvis);
    correction[kPelvis] =
        HipFrame(src_left, src_up) * HipFrame(body_left, body_up).transpose();
  }
  for (int j = 1; j < kNumCoreJoints; ++j) {
    const int child = CoreChild(j);
    if (child < 0 || source_child_of[j] < 0) {
      correction[j] = correction[body.parents[j]];
      continue;
    }
    const Eigen::Vector3d body_dir = body_rest.col(child) - body_rest.col(j);
    const Eigen::Vector3d src_dir =
        source_rest[source_child_of[j]] - source_rest[source_of[j]];
    if (body_dir.norm() < 1e-9 || src_dir.norm() < 1e-9) {
      correction[j] = correction[body.parents[j]];
      continue;
    }
    correction[j] = Eigen::Quaterniond::FromTwoVectors(body_dir, src_dir)
                        .toRotationMatrix();
  }

  // Root trajectory scale: hip height ratio.
  const double src_hip_height =
      0.5 * (source_rest[source_of[kLeftHip]].z() +
             source_rest[source_of[kRightHip]].z()) -
      std::min(source_rest[source_of[kLeftFoot]].z(),
               source_rest[source_of[kRightFoot]].z());
  const double body_hip_height =
      0.5 * (body_rest(2, kLeftHip) + body_rest(2, kRightHip)) -
      std::min(body_rest(2, kLeftFoot), body_rest(2, kRightFoot));
  const double scale =
      src_hip_height > 1e-6 ? body_hip_height / src_hip_height : 1.0;

  PoseSequence sequence;
  sequence.name = clip.name;
  sequence.source = source;
  sequence.frame_rate = clip.frame_rate;
  sequence.frames.reserve(clip.num_frames());
  std::vector<double> lowest;
  for (int t = 0; t < clip.num_frames(); ++t) {
    const std::vector<Eigen::Isometry3d> global = clip.GlobalPose(t);
    std::vector<Eigen::Matrix3d> q(kNumCoreJoints);
    for (int j = 0; j < kNumCoreJoints; ++j) {
      const int s = source_of[j];
      q[j] = global[s].linear() * correction[j];
    }
    BodyPose pose = BodyPose::Rest(body.num_joints());
    for (int j = 0; j < kNumCoreJoints; ++j) {
      const Eigen::Matrix3d local =
          j == 0 ? q[0] : q[body.parents[j]].transpose() * q[j];
      const Eigen::AngleAxisd aa(local);
      pose.rotations.col(j) = aa.axis() * aa.angle();
    }
    const Eigen::Vector3d pelvis = global[source_of[kPelvis]].translation();
    pose.translation = scale * pelvis - body_rest.col(kPelvis);
    sequence.frames.push_back(pose);
    BodyPose grounded = pose;
    ApplyGroundContact(body, body_rest, grounded, 0.0);
    lowest.push_back(pose.translation.z() - grounded.translation.z());
  }
  if (!lowest.empty()) {
    std::vector<double> sorted = lowest;
    std::sort(sorted.begin(), sorted.end());
    const double floor = sorted[sorted.size() / 20];
    for (BodyPose& pose : sequence.frames) pose.translation.z() -= floor;
  }
  return sequence;
}

}  // namespace soma
