// Retargeting of skeletal motion (BVH, ASF/AMC; io/skeleton_motion.h) onto a
// body's core joints.
//
// Both sides use world-aligned rest frames, so a source joint's global
// rotation at frame t, Delta_s(t), is its rotation relative to its own rest
// pose. The rest poses differ (bone directions, proportions), so each core
// joint j gets a constant correction C_j, the minimal rotation taking the
// body's rest bone direction (j -> its core child) to the source's rest bone
// direction (s -> its mapped child); the body's global rotation is
// Q_j(t) = Delta_s(t) * C_j, which makes every mapped bone point where the
// source bone points. The root uses a full frame correction (hip axis and
// spine). Local rotations follow as Q_parent^T Q_j. The root trajectory is
// scaled by the ratio of hip heights, and each clip is shifted vertically so
// that its lowest 5% of frames touch the floor.
#pragma once

#include "framework/body/body_model.h"
#include "framework/io/skeleton_motion.h"
#include "framework/motion/pose_sequence.h"

#include <string>
#include <vector>

namespace soma {

/// Correspondence between source joints and the core joints.
struct RetargetMap {
  struct Entry {
    int core_joint;            // CoreJoint
    std::string source_joint;  // joint whose rotation drives the core joint
    std::string source_child;  // defines the source bone direction ("" = none)
  };
  std::string name;
  std::vector<Entry> entries;
};

/// CMU BVH naming of ../shared/data/motion/cmu_bvh (Hips, LeftHip, LeftKnee,
/// ..., lowerback, Chest, Chest2, lowerneck, Neck, Head, LeftCollar, ...).
const RetargetMap& CmuBvhRetargetMap();
/// The cgspeed CMU BVH naming (Hips, LeftUpLeg, LeftLeg, ..., LeftFingerBase).
const RetargetMap& CmuCgspeedBvhRetargetMap();
/// Acclaim ASF naming used by CMU and HDM05 (root, lfemur, ..., lhand).
const RetargetMap& AsfRetargetMap();
/// Picks the map whose joints the skeleton has; IoError if none fits.
const RetargetMap& DetectRetargetMap(const Skeleton& skeleton,
                                     const std::string& source);

/// Retargets a Z-up clip (ConvertYUpToZUp first) onto `body` at its mean
/// shape. Throws IoError if a mapped joint is missing from the skeleton.
PoseSequence Retarget(const MotionClip& clip,
                      const BodyModel& body,
                      const RetargetMap& map);

}  // namespace soma
