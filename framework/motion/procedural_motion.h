// The built-in procedural motion library: the embedded default motion source.
//
// Pose coverage decides real-data accuracy (DESIGN.md: a labeler trained on
// upright motion fails on floor and inverted frames), so besides locomotion
// the library covers the floor (sit, kneel, crawl, lie down), the inverted
// (handstand, cartwheel, flips) and the extreme (martial-arts kicks, random
// poses anywhere inside the joint limits with any root orientation).
//
// Each motion type is a parameterised generator; every parameter (speed,
// amplitudes, timing, heading, per-clip joint offsets) is drawn from the
// clip's own RNG stream, so the same seed gives the same clips. Feet (or
// whatever touches the floor) are put on z = 0 by a ground-contact pass over
// the posed skeleton.
#pragma once

#include "framework/body/body_model.h"
#include "framework/core/random.h"
#include "framework/motion/pose_sequence.h"

#include <string>
#include <vector>

namespace soma {

/// Names of the motion types, in a fixed order: walk, run, crouch_walk,
/// bear_walk, jump, squat, kick, throw, reach, turn, sit, lie_down, crawl,
/// kneel, cartwheel, handstand, flip, martial_arts, random_pose.
const std::vector<std::string>& ProceduralMotionTypes();

struct ProceduralMotionOptions {
  double frame_rate = 30.0;       // Hz
  double duration_s = 4.0;        // clip length (seconds)
  double joint_jitter_deg = 5.0;  // per-clip random offset of every angle
  /// Scale of random_pose angles within the joint limits (1 = full range).
  double random_pose_range = 0.9;
  /// Looking around: every clip but random_pose turns the head (neck and
  /// head joints, half each) by a smooth random yaw of amplitude up to this
  /// many degrees, with pitch up to half of it and roll up to a quarter, at
  /// 0.1-0.6 Hz; the joint limits still clamp. 0 = the types' own head
  /// angles only.
  double head_turn_deg = 0.0;
};

/// Generates one clip of `type` for `body` (its mean-shape rest joints are
/// used for ground contact). Throws ConfigError for an unknown type (listing
/// the known ones).
PoseSequence GenerateProceduralMotion(const std::string& type,
                                      const BodyModel& body,
                                      const ProceduralMotionOptions& options,
                                      Rng& rng);

/// Puts the lowest point of the posed body on z = `lift` by changing the
/// root translation's z. The lowest point is estimated from the posed
/// joints minus per-joint surface radii (pelvis 0.10 m ... hands 0.03 m).
void ApplyGroundContact(const BodyModel& body,
                        const Eigen::Matrix3Xd& rest_joints,
                        BodyPose& pose,
                        double lift = 0.0);

}  // namespace soma
