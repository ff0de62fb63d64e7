#include "framework/motion/anatomy.h"

#include "framework/core/error.h"

#include <Eigen/Geometry>

#include <cmath>

namespace soma {
namespace {

constexpr double kDeg = M_PI / 180.0;

/// Axes of (flexion, abduction, twist) for the left side and the midline, in
/// the joint's world-aligned rest frame (derivations in the comments).
struct JointAxes {
  Eigen::Vector3d flexion, abduction, twist;
};

JointAxes LeftOrCentralAxes(int joint) {
  const Eigen::Vector3d x = Eigen::Vector3d::UnitX(),
                        y = Eigen::Vector3d::UnitY(),
                        z = Eigen::Vector3d::UnitZ();
  switch (joint) {
    case kPelvis:
    case kSpine1:
    case kSpine2:
    case kSpine3:
    case kNeck:
    case kHead:
      // Rx(+t) moves +Z towards -Y (forward); Ry(+t) moves +Z towards +X
      // (the body's left); Rz(+t) turns -Y towards +X (turn left).
      return {x, y, z};
    case kLeftHip:
      // Rx(-t) swings the leg (0,0,-1) towards -Y (forward); Ry(-t) moves the
      // foot towards +X (outward); Rz(-t) turns the toes (-Y) towards -X
      // (inward = internal rotation).
      return {-x, -y, -z};
    case kLeftKnee:
      // Rx(+t) swings the shank backwards (+Y).
      return {x, -y, -z};
    case kLeftAnkle:
    case kLeftFoot:
      // Rx(+t) turns the toes (-Y) downwards (plantarflexion); Ry(+t) turns
      // the sole (-Z) towards -X (medial: inversion). The foot as the ankle.
      return {x, y, -z};
    case kLeftCollar:
    case kLeftShoulder:
    case kLeftElbow:
      // Arm along +X. Rz(-t) swings it towards -Y (forward); Ry(-t) raises
      // it (+Z); twist about the arm axis. Forearm along +X, palm down:
      // elbow flexion brings the hand forwards (-Y).
      return {-z, -y, -x};
    case kLeftWrist:
    case kLeftHand:
      // Ry(+t) bends the hand (+X) downwards (palmar flexion, palm down).
      return {y, -z, -x};
    default:
      throw InternalError("AnatomicalRotation: not a core left/central joint");
  }
}

int MirrorOf(int joint) {
  switch (joint) {
    case kRightHip:
      return kLeftHip;
    case kRightKnee:
      return kLeftKnee;
    case kRightAnkle:
      return kLeftAnkle;
    case kRightFoot:
      return kLeftFoot;
    case kRightCollar:
      return kLeftCollar;
    case kRightShoulder:
      return kLeftShoulder;
    case kRightElbow:
      return kLeftElbow;
    case kRightWrist:
      return kLeftWrist;
    case kRightHand:
      return kLeftHand;
    default:
      return -1;
  }
}

/// Mirror of a rotation axis through the YZ plane (x -> -x): axial vectors
/// map to (x, -y, -z).
Eigen::Vector3d MirrorAxis(const Eigen::Vector3d& axis) {
  return {axis.x(), -axis.y(), -axis.z()};
}

JointLimits Limits(
    double f0, double f1, double a0, double a1, double t0, double t1) {
  return {
      {f0 * kDeg, f1 * kDeg}, {a0 * kDeg, a1 * kDeg}, {t0 * kDeg, t1 * kDeg}};
}

}  // namespace

Eigen::Vector3d AnatomicalRotation(int joint, const JointAngles& angles) {
  SOMA_CHECK(joint >= 0 && joint < kNumCoreJoints) << "joint " << joint;
  const int mirror = MirrorOf(joint);
  JointAxes axes = LeftOrCentralAxes(mirror >= 0 ? mirror : joint);
  if (mirror >= 0) {
    axes = {MirrorAxis(axes.flexion),
            MirrorAxis(axes.abduction),
            MirrorAxis(axes.twist)};
  }
  const Eigen::Matrix3d rotation =
      (Eigen::AngleAxisd(angles.flexion, axes.flexion) *
       Eigen::AngleAxisd(angles.abduction, axes.abduction) *
       Eigen::AngleAxisd(angles.twist, axes.twist))
          .toRotationMatrix();
  const Eigen::AngleAxisd aa(rotation);
  return aa.axis() * aa.angle();
}

const JointLimits& CoreJointLimits(int joint) {
  // Degrees: {flexion}, {abduction}, {twist}; see the header for sources.
  static const std::array<JointLimits, kNumCoreJoints> kLimits = [] {
    std::array<JointLimits, kNumCoreJoints> l;
    l[kPelvis] = Limits(-180, 180, -180, 180, -180, 180);
    // Thoracolumbar: flexion 80, extension 25, lateral 35, rotation 45 (AAOS),
    // shared by the three spine joints.
    for (int j : {kSpine1, kSpine2, kSpine3})
      l[j] = Limits(-8, 27, -12, 12, -15, 15);
    // Cervical: flexion 45, extension 45, lateral 45, rotation 60, shared by
    // neck and head.
    for (int j : {kNeck, kHead}) l[j] = Limits(-23, 23, -23, 23, -30, 30);
    // Hip: flexion 120, extension 30, abduction 45, adduction 30, rotation 45.
    for (int j : {kLeftHip, kRightHip})
      l[j] = Limits(-30, 120, -30, 45, -45, 45);
    // Knee: flexion 135 (Soucie 2011: ~ 140).
    for (int j : {kLeftKnee, kRightKnee}) l[j] = Limits(0, 135, 0, 0, -5, 5);
    // Ankle: dorsiflexion 20, plantarflexion 50, inversion 35, eversion 15.
    for (int j : {kLeftAnkle, kRightAnkle})
      l[j] = Limits(-20, 50, -15, 35, -10, 10);
    // Toes (MTP): extension 70 (used: 30), flexion 40 (used: 30).
    for (int j : {kLeftFoot, kRightFoot}) l[j] = Limits(-30, 30, 0, 0, 0, 0);
    // Collar (shoulder girdle): protraction/retraction 15, elevation 30.
    for (int j : {kLeftCollar, kRightCollar})
      l[j] = Limits(-15, 15, -10, 30, -10, 10);
    // Shoulder, relative to the T-pose: horizontal flexion 135, extension 45,
    // raise 90 (180 total abduction), lowered to hanging (-90) and 10 across.
    for (int j : {kLeftShoulder, kRightShoulder})
      l[j] = Limits(-45, 135, -100, 90, -90, 90);
    // Elbow: flexion 150, pronation/supination 80.
    for (int j : {kLeftElbow, kRightElbow})
      l[j] = Limits(0, 150, 0, 0, -80, 80);
    // Wrist: extension 70, flexion 80, radial 20, ulnar 30.
    for (int j : {kLeftWrist, kRightWrist})
      l[j] = Limits(-70, 80, -20, 30, 0, 0);
    // Hand (finger curl as a whole).
    for (int j : {kLeftHand, kRightHand}) l[j] = Limits(-10, 90, 0, 0, 0, 0);
    return l;
  }();
  SOMA_CHECK(joint >= 0 && joint < kNumCoreJoints) << "joint " << joint;
  return kLimits[joint];
}

BodyPose ToBodyPose(const AnatomicalPose& angles,
                    const Eigen::Vector3d& root_orientation,
                    const Eigen::Vector3d& translation,
                    int num_joints) {
  SOMA_CHECK_GE(num_joints, static_cast<int>(kNumCoreJoints));
  BodyPose pose = BodyPose::Rest(num_joints);
  pose.translation = translation;
  for (int j = 0; j < kNumCoreJoints; ++j) {
    pose.rotations.col(j) = AnatomicalRotation(j, angles[j]);
  }
  // Root: world orientation applied after the pelvis' anatomical rotation.
  const double root_angle = root_orientation.norm();
  Eigen::Matrix3d root = Eigen::Matrix3d::Identity();
  if (root_angle > 0) {
    root = Eigen::AngleAxisd(root_angle, root_orientation / root_angle)
               .toRotationMatrix();
  }
  const Eigen::Vector3d pelvis = pose.rotations.col(kPelvis);
  const double pelvis_angle = pelvis.norm();
  if (pelvis_angle > 0) {
    root = root * Eigen::AngleAxisd(pelvis_angle, pelvis / pelvis_angle)
                      .toRotationMatrix();
  }
  const Eigen::AngleAxisd aa(root);
  pose.rotations.col(kPelvis) = aa.axis() * aa.angle();
  return pose;
}

AnatomicalPose StandingPose() {
  AnatomicalPose pose{};
  pose[kLeftShoulder].abduction = -80 * kDeg;
  pose[kRightShoulder].abduction = -80 * kDeg;
  pose[kLeftElbow].flexion = 10 * kDeg;
  pose[kRightElbow].flexion = 10 * kDeg;
  return pose;
}

}  // namespace soma
