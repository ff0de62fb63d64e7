// Anatomical joint angles for the core skeleton (body_model.h conventions:
// Z up, T-pose rest, faces -Y, left side at +X, world-aligned joint frames).
//
// A motion is easier to write, read and bound in anatomical terms — "left hip
// flexion 40 degrees" — than as axis-angle vectors. AnatomicalRotation() maps
// (flexion, abduction, twist) of a joint to its local axis-angle rotation, and
// JointLimits() gives the normal active range of motion of each angle.
#pragma once

#include "framework/body/body_model.h"

#include <Eigen/Core>

#include <array>

namespace soma {

/// Anatomical angles of one joint, radians. Sign conventions (the body's
/// point of view):
///  - spine/neck/head/pelvis: flexion = bend forward, abduction = bend to the
///    body's left, twist = turn to the left;
///  - hip/shoulder/collar: flexion = limb forward, abduction = limb away
///    from the midline, twist = internal rotation about the limb axis. The
///    shoulder's angles are relative to the T-pose rest, so a hanging arm is
///    abduction ~ -pi/2 and a raised arm +pi/2;
///  - knee: flexion = heel towards buttock; elbow: flexion = hand towards
///    the shoulder (forwards in the T-pose); ankle/wrist: flexion =
///    plantarflexion / palmar flexion;
///  - foot, hand: flexion only (toes/fingers curl).
struct JointAngles {
  double flexion = 0.0;
  double abduction = 0.0;
  double twist = 0.0;
};

/// Local axis-angle rotation of `joint` for anatomical angles. Left/right
/// joints mirror each other, so equal angles give mirror-symmetric poses.
Eigen::Vector3d AnatomicalRotation(int joint, const JointAngles& angles);

/// Normal active range of motion, radians: {min, max} per angle.
struct JointLimits {
  std::array<double, 2> flexion;
  std::array<double, 2> abduction;
  std::array<double, 2> twist;
};

/// Limits of a core joint. Sources: American Academy of Orthopaedic
/// Surgeons, "Joint Motion: Method of Measuring and Recording" (1965) and
/// Soucie et al., "Range of motion measurements: reference values and a
/// database for comparison studies", Haemophilia 17:500-507 (2011); spine
/// segments share the total thoracolumbar range.
const JointLimits& CoreJointLimits(int joint);

/// A full set of anatomical angles for the 24 core joints.
using AnatomicalPose = std::array<JointAngles, kNumCoreJoints>;

/// Converts anatomical angles (+ root orientation as axis-angle and
/// translation) to a BodyPose with `num_joints` joints (extra joints zero).
BodyPose ToBodyPose(const AnatomicalPose& angles,
                    const Eigen::Vector3d& root_orientation,
                    const Eigen::Vector3d& translation,
                    int num_joints);

/// The natural standing pose: arms hanging (shoulder abduction -80 deg),
/// slight elbow flexion; everything else zero.
AnatomicalPose StandingPose();

}  // namespace soma
