// Biovision Hierarchy (BVH) reader: skeleton + per-frame joint channels.
//
// Format (Meredith & Maddock, "Motion Capture File Formats Explained",
// Univ. of Sheffield CS-01-11, 2001): a HIERARCHY of ROOT / JOINT blocks,
// each with an OFFSET (rest position relative to the parent, parent axes)
// and CHANNELS (any of Xposition Yposition Zposition Xrotation Yrotation
// Zrotation, in any order), `End Site` blocks that carry only an OFFSET, then
// MOTION with `Frames: N`, `Frame Time: dt` and N lines of channel values
// (joints in hierarchy order, angles in degrees).
//
// Mapping onto MotionClip (skeleton_motion.h):
//  - Joints keep the file's names and pre-order. Every `End Site` becomes a
//    joint named `<parent>_end` (a second one under the same parent
//    `<parent>_end2`, ...) with no channels, so chain tips (head top, toe and
//    finger tips) are available to FK.
//  - Rotation channels compose in the listed order about the moving axes:
//    "Zrotation Xrotation Yrotation" gives L = Rz * Rx * Ry
//    (EulerConvention::kMovingAxes). BVH joint frames are world-aligned at
//    rest, so dof_frames are identity.
//  - The root's world position is (root OFFSET + its position channels)
//    * length_to_metres; skeleton.offsets[0] is zero. Only the root may have
//    position channels (an IoError otherwise).
//  - The frame rate is 1 / Frame Time, rounded to the nearest integer when
//    within 0.005 Hz of it (".0083333" -> 120 Hz).
//  - up_axis is Y (the BVH convention); see ConvertYUpToZUp().
#pragma once

#include "framework/io/skeleton_motion.h"

#include <filesystem>
#include <string_view>

namespace soma {

/// Metres per length unit of the CMU motion-capture skeletons. Their ASF
/// files declare `:units length 0.45`, which in the Acclaim ASF definition
/// (M. Schafer, "Acclaim Skeleton File Definition V1.10", 1995: "length
/// 1.0 ... eg. 2.54 - data in cm, local units in inches") means that a file
/// value divided by 0.45 is in inches: 1 unit = 0.0254 / 0.45 m = 5.644 cm.
/// The cgspeed BVH conversion of the CMU database keeps these units (its
/// offsets are the ASF bone vectors: subject 131's femur is 7.29 units =
/// 0.41 m, its standing root height 16.9 units = 0.95 m).
inline constexpr double kCmuLengthUnitToMetres = 0.0254 / 0.45;

/// Options of ReadBvh.
struct BvhReadOptions {
  /// Metres per BVH length unit. BVH files do not state their unit. The
  /// default fits the CMU cgspeed BVH files in ../shared/data/motion;
  /// centimetre files (e.g. Mixamo, LAFAN1) need 0.01, metre files 1.0.
  double length_to_metres = kCmuLengthUnitToMetres;

  /// Throws ConfigError unless length_to_metres is positive and finite.
  void Validate() const;
};

/// Reads a BVH file. Throws IoError naming `path:line` on unreadable or
/// malformed input (unknown keywords, bad numbers, unbalanced braces, a
/// frame line with the wrong number of values, fewer or more frame lines
/// than `Frames:` announces).
MotionClip ReadBvh(const std::filesystem::path& path,
                   const BvhReadOptions& options = {});

/// Parses BVH text; `source_name` is used in error messages and as
/// MotionClip::source_path, its stem as MotionClip::name.
MotionClip ParseBvh(std::string_view text,
                    const std::filesystem::path& source_name,
                    const BvhReadOptions& options = {});

}  // namespace soma
