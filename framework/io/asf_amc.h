// Acclaim ASF (skeleton) / AMC (motion) reader, as used by the CMU and HDM05
// motion-capture databases.
//
// Format: M. Schafer, "Acclaim Skeleton File Definition V1.10" (1995), and
// the VICON BodyBuilder notes "Acclaim Format - ASF line Details"
// (graphics.cs.cmu.edu/nsp/course/cs229/info/ACCLAIMdef.html). An ASF has
// `:units` (length multiplier, angle deg|rad), `:root` (order, axis,
// position, orientation), `:bonedata` (per bone: name, unit direction in
// the global rest frame, length, `axis ax ay az ORDER`, dof, limits) and
// `:hierarchy` (parent child child ...). An AMC has header lines
// (`:FULLY-SPECIFIED`, `:DEGREES`), then per frame a frame-number line and
// one `bone v1 v2 ...` line per bone with dofs, values in dof order.
//
// Forward kinematics (the CMU amc_player / Acclaim convention): with C_b the
// rotation built from bone b's `axis` and R_b the rotation from its AMC
// values, the global rotation of bone b is
//     M_b = M_parent * C_b * R_b * C_b^-1     (M_root = C_r * R_r * C_r^-1)
// and bone b's tip lies at  p_tip(b) = p_start(b) + M_b * direction_b *
// length_b, where p_start(b) is the tip of the parent bone (the root position
// for the root's children). Both `axis ... ORDER` and the dof list are
// rotations about fixed axes applied in the listed order: "XYZ" and "rx ry rz"
// give Rz * Ry * Rx (EulerConvention::kFixedAxes).
//
// Mapping onto MotionClip (skeleton_motion.h, world-aligned rest frames):
//  - joint 0 is "root"; every bone b becomes a joint named as the bone,
//    placed at the bone's START (where its rotation acts): the hip joint is
//    "lfemur", the knee "ltibia". Its local rotation is L_b = C_b R_b C_b^-1
//    and its children sit at offset direction_b * length_b. A bone without
//    children gets an extra joint "<bone>_end" at its tip (toes, fingers,
//    thumbs, head top). Joints are in hierarchy pre-order.
//  - dof_frames[b] = C_b, channels = the dofs with their limits (radians).
//  - root translation = (`:root position` + AMC TX TY TZ) * length_to_metres.
//  - up_axis is Y.
#pragma once

#include "framework/io/skeleton_motion.h"

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>

namespace soma {

/// Options of the ASF/AMC readers.
struct AsfAmcReadOptions {
  /// Metres per ASF length unit. Unset: 0.0254 / L for the ASF's
  /// `:units length L`. The Acclaim definition reads "length 1.0 ... (eg.
  /// 2.54 - data in cm, local units in inches)", i.e. file value / L =
  /// inches; CMU and HDM05 files use L = 0.45 (1 unit = 5.644 cm; HDM05
  /// actor bd: femur 7.34 units = 0.41 m). L defaults to 1 (inches) when the
  /// ASF has no `:units length`.
  std::optional<double> length_to_metres;
  /// AMC frame rate, Hz (AMC files do not store it). Unset: the `_<rate>`
  /// suffix of an HDM05 file name (`HDM_bd_squat1Reps_003_120.amc` -> 120),
  /// otherwise 120 Hz, the capture rate of both CMU and HDM05.
  std::optional<double> frame_rate;

  /// Throws ConfigError on a non-positive or non-finite value.
  void Validate() const;
};

/// A parsed ASF file.
struct AsfSkeleton {
  std::string name;         // `:name`
  std::string source_path;  // the ASF file
  /// Joints as described in asf_amc.h; offsets in metres.
  Skeleton skeleton;
  /// `:root position`, metres (added to every AMC root translation).
  Eigen::Vector3d root_position = Eigen::Vector3d::Zero();
  /// The factor applied to every ASF/AMC length.
  double length_to_metres = 0.0254;
  /// `:units angle` is deg (the default) rather than rad.
  bool angles_in_degrees = true;
};

/// Reads an ASF skeleton. Throws IoError naming `path:line` on malformed
/// input (unknown keywords, a `:bonedata` entry with missing or non-numeric
/// fields, limits that do not match the dofs, a `:hierarchy` naming an
/// undefined bone, a bone with two parents or not reachable from the root,
/// translational dofs on a bone, which are not supported).
AsfSkeleton ReadAsf(const std::filesystem::path& path,
                    const AsfAmcReadOptions& options = {});
/// Parses ASF text; `source_name` is used in error messages.
AsfSkeleton ParseAsf(std::string_view text,
                     const std::filesystem::path& source_name,
                     const AsfAmcReadOptions& options = {});

/// Reads an AMC motion for `asf`. Throws IoError naming `path:line` on an
/// unknown bone, a wrong number of values, a bad number, values before the
/// first frame number, non-consecutive frame numbers, a repeated bone in a
/// frame, or (in a `:FULLY-SPECIFIED` file) a frame that lacks a bone with
/// dofs. Bones absent from a frame of a file that is not fully specified get
/// zero dof values.
MotionClip ReadAmc(const std::filesystem::path& path,
                   const AsfSkeleton& asf,
                   const AsfAmcReadOptions& options = {});
/// Parses AMC text; `source_name` is used in messages, as the clip's
/// source_path and (stem) name, and for the HDM05 frame-rate suffix.
MotionClip ParseAmc(std::string_view text,
                    const std::filesystem::path& source_name,
                    const AsfSkeleton& asf,
                    const AsfAmcReadOptions& options = {});

/// ReadAsf + ReadAmc.
MotionClip ReadAsfAmc(const std::filesystem::path& asf_path,
                      const std::filesystem::path& amc_path,
                      const AsfAmcReadOptions& options = {});

}  // namespace soma
