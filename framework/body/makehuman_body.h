// The MakeHuman / MPFB2 body (CC0 assets, ../shared/data/body/makehuman) as
// a BodyModel.
//
// Assets read from `dir`:
//   3dobjs/base.obj                       hm08 base mesh (19158 vertices: the
//                                         skin "body" group, vertices
//                                         0..13379, then helper geometry and
//                                         joint cubes); quads
//   mesh_metadata/basemesh_vertex_groups.json  vertex ranges of the joint
//                                         cubes ("joint-l-knee", ...)
//   rigs/standard/rig.cmu_mb.json         31-bone CMU-named rig: per bone a
//                                         parent, a roll and head/tail
//                                         definitions (CUBE: centre of a
//                                         joint cube; MEAN / VERTEX / XYZ:
//                                         mesh vertices)
//   rigs/standard/weights.cmu_mb.json     skinning weights, bone -> [[vertex,
//                                         weight], ...]
//   targets/macrodetails/*.target.gz      macro shape targets: gzipped lines
//                                         "vertex dx dy dz" (mesh units)
//   poses/cmu_mb_fk/t-pose.json           MPFB pose that turns the rig into a
//                                         T-pose (only for RestPose::kTPose)
//
// Units and frame (measured): the OBJ is in decimetres, Y up, the body
// facing +Z with its left side (MakeHuman "l", the character's left) at +X;
// the body group spans 16.66 units = 1.666 m. Points map to ours (metres,
// Z up, facing -Y, left at +X) by p = 0.1 * (x, -z, y); the result is
// shifted so that the template's lowest vertex lies on z = 0. This is also
// Blender's frame, in which MPFB's rig rolls and pose angles are defined.
//
// Mesh: only the "body" group (13380 vertices, 13378 quads -> 26756
// triangles, split a-b-c / a-c-d; OBJ order is counter-clockwise seen from
// outside, checked by the signed volume). Helpers, joint cubes, eyes, teeth,
// tongue, hair and clothes proxies are dropped (they still drive joints:
// see below).
//
// Mean shape (betas = 0; stature 1.672 m in the T-pose, 1.659 m in the
// asset pose, volume 0.057 m^3; 0.056 with the asset proportions): MakeHuman's
// default human, i.e. the base mesh plus the macro targets at gender 0.5, age
// 0.5 (25 years), muscle 0.5, weight 0.5 and 1/3 of each ethnicity (MakeHuman's
// macro-modifier weighting: universal-<gender>-<age>-<muscle>-<weight> targets
// weighted by the product of the four slider weights, <race>-<gender>-<age>
// targets by race x gender x age; sliders interpolate piecewise-linearly
// between the named targets, e.g. weight 0..0.5 min->average, 0.5..1
// average->max).
//
// Shape space (MakeHumanShapeComponentNames(); every component is a
// displacement field, displacement = f(slider extremes) evaluated by the
// same macro weighting; betas ~ N(0, 1) give adults):
//   0 stature  uniform scaling about the floor centre, 4 % per unit
//              (beta = 1: +6.7 cm)
//   1 gender   0.5 (male - female): beta = +1 fully male, -1 fully female
//   2 weight   0.25 (maxweight - minweight): beta = +-2 reaches the sliders'
//              extremes
//   3 muscle   0.25 (maxmuscle - minmuscle): likewise
//   4 age      0.5 (old - young): beta = +1 is age slider 0.75 (about 57
//              years), +2 is 90 years; negative betas extrapolate mildly
//              ("younger than 25" along the same direction)
//   5 african  0.5 (african - default mix): beta = 2 fully African, < 0
//              moves towards Asian + Caucasian
//   6 asian    0.5 (asian - default mix): likewise
// Extrapolation beyond the sliders (|beta| > 1 for gender, > 2 otherwise)
// stays linear. beta_stddev = 1.
//
// Proportions (measured, T-pose): shoulder-elbow joint distance 0.242 m at
// the mean shape, 0.145 x stature (0.137-0.154 over age beta +2..-2, 0.145
// along every other component); elbow-wrist 0.239 m, 0.143 x stature (0.132
// at gender beta -1, 0.153 at +1). The rig's elbow is where the asset mesh
// bends (the crossing of the upper-arm and forearm centre lines of the
// A-pose, 5.5 mm away; makehuman_body_test.cc), so the short upper arm
// (anthropometric tables: 0.186 x stature) is the mesh's own; it makes
// `soma realism`'s upper-arm distances 24.5% shorter than the captures'.
//
// Proportions::kAnthropometric (default) therefore corrects the upper arm at
// load time, after the rest pose and the skinning weights are built and
// before the joint regressor is fitted: on each side the shoulder -> elbow
// joint distance becomes upper_arm_ratio x stature (0.186, Drillis & Contini
// 1966 via Winter, "Biomechanics and Motor Control of Human Movement"; the
// stature of the rest template). The elbow and every joint below it (wrist,
// hand, thumb, fingers) move rigidly by the stretch vector s along the bone,
// so the forearm and hand keep their lengths exactly. Each body vertex moves
// by sum_j w_vj d_j (w: the final skinning weights) with d_j = t_v s for the
// shoulder joint (the upper-arm segment; t_v in [0, 1] the vertex's clamped
// normalised projection on shoulder -> elbow, so the upper arm stretches
// evenly instead of at the elbow crease), d_j = s for the elbow and its
// descendants and 0 for every other joint. The shape directions stay as
// they are, except that the stature direction (a uniform scaling) also
// scales the correction, so the ratio holds for every stature beta; the
// regressor is then fitted to the corrected template and joints. Measured
// (T-pose, mean shape, stature 1.672 m): shoulder-elbow 0.2421 -> 0.3109 m,
// elbow-wrist 0.2386 m unchanged; 4256 vertices move, no edge stretches more
// than 1.35x (the bone: 1.28x), volume 0.0562 -> 0.0571 m^3; `soma
// realism` upper arm -24.5% -> -4.6% (LSHO-LELB 0.272 -> 0.340 m, captures
// 0.343-0.353 m). Proportions::kAsset keeps the asset's proportions.
//
// Rest pose. RestPose::kTPose (default, as body_model.h prescribes): the
// asset's A-pose (arms ~45 degrees down, elbows slightly bent) is posed with
// the full 31-bone rig to MPFB's T-pose (poses/cmu_mb_fk/t-pose.json: Blender
// XYZ Euler angles per bone, in the bone frames given by head, tail and
// roll) by linear blend skinning, and the result is the template. The shape
// components are posed the same way: each is the finite difference
// TPose(mean + component) - TPose(mean), so the rig follows the shape.
// RestPose::kAsset keeps the asset's A-pose instead.
//
// Skeleton (MakeHumanJointMap()): 28 joints, the 24 core joints in CoreJoint
// order then left_thumb, left_fingers, right_thumb, right_fingers. A joint is
// its bone's head. LHipJoint / RHipJoint (their heads coincide with Hips'
// head; they only carry the hip offset) and Neck1 (mid-neck, which would sit
// between neck and head in the core order) are dropped: their skinning weights
// go to their parent (Hips, Neck) and their children re-parent to it. The asset
// has 11 stray weights across the midline (<= 0.5 %, e.g. right toe vertices on
// LeftToeBase, a right fingertip on LeftHandFinger1): weights of left_*
// (right_*) joints on vertices more than 1 cm on the other side are removed.
// Skinning weights are then normalised.
//
// Joint regressor: joints must follow the shape, but the rig defines them on
// joint cubes, which are not part of the kept mesh. For each joint we fit a
// sparse affine combination of nearby body vertices (the nearest 200, more
// if within regressor_support_factor x the distance to the nearest vertex,
// at most 400): the minimum-norm change from uniform weights such that the
// weights sum to 1 and reproduce the joint for the mean shape and its
// displacement for every shape component (rows normalised, ridge 1e-10).
// Since the shape space is linear, the regressed joints then equal the rig's
// joints for every beta. Measured on the hm08 assets: largest residual
// 2.4e-6 m, largest |weight| 1.05, 5900 non-zeros (MakeHumanLoadReport).
#pragma once

#include "framework/body/body_model.h"

#include <filesystem>
#include <string>
#include <vector>

namespace soma {

/// Options of LoadMakeHumanBody.
struct MakeHumanLoadOptions {
  enum class RestPose {
    kTPose,  // MPFB's T-pose (poses/cmu_mb_fk/t-pose.json), the default
    kAsset,  // the base mesh's own A-pose
  };
  RestPose rest_pose = RestPose::kTPose;
  /// Segment lengths (see the file comment).
  enum class Proportions {
    kAnthropometric,  // upper arm = upper_arm_ratio x stature, the default
    kAsset,           // the asset mesh's own (upper arm 0.145 x stature)
  };
  Proportions proportions = Proportions::kAnthropometric;
  /// Shoulder-elbow joint distance as a fraction of stature for
  /// Proportions::kAnthropometric (Drillis & Contini 1966 / Winter: 0.186);
  /// in (0, 0.5).
  double upper_arm_ratio = 0.186;
  /// Number of shape components kept, in MakeHumanShapeComponentNames()
  /// order (0..7).
  int num_betas = 7;
  /// Metres per mesh unit (the hm08 mesh is in decimetres).
  double metres_per_unit = 0.1;
  /// Regressor support radius as a multiple of the joint's distance to the
  /// nearest body vertex (see the file comment); >= 1.
  double regressor_support_factor = 2.0;

  /// Throws ConfigError on out-of-range values.
  void Validate() const;
};

/// What LoadMakeHumanBody measured, for logs and tests.
struct MakeHumanLoadReport {
  int num_obj_vertices = 0;    // all vertices of base.obj
  int num_body_vertices = 0;   // kept
  int num_body_quads = 0;      // faces of the body group (before triangulation)
  bool faces_flipped = false;  // OBJ order was clockwise and got reversed
  int cross_side_weights_removed = 0;  // stray weights across the midline
  double stature_m = 0.0;  // template height (max z - min z) at betas = 0
  std::vector<std::string> targets_loaded;  // target file names read
  /// Largest distance between a regressed joint and the rig's joint, over
  /// all joints, for the mean shape and each shape component at beta = 1
  /// (metres).
  double max_regressor_residual_m = 0.0;
  double max_abs_regressor_weight = 0.0;
  int regressor_nonzeros = 0;
  /// Left shoulder-elbow and elbow-wrist joint distances of the rest
  /// template (betas = 0) before and after the proportion correction
  /// (equal for Proportions::kAsset), metres.
  double asset_upper_arm_m = 0.0;
  double upper_arm_m = 0.0;
  double asset_forearm_m = 0.0;
  double forearm_m = 0.0;
};

/// Loads the MakeHuman body from `dir` (see the file comment). Throws IoError
/// naming the directory or file if something is missing, unreadable or
/// malformed (JSON errors carry file:line:col). The result passes
/// BodyModel::Validate().
BodyModel LoadMakeHumanBody(const std::filesystem::path& dir,
                            const MakeHumanLoadOptions& options = {},
                            MakeHumanLoadReport* report = nullptr);

/// Shape component names in order: stature, gender, weight, muscle, age,
/// african, asian.
const std::vector<std::string>& MakeHumanShapeComponentNames();

/// One row of the joint mapping: our joint name, the CMU rig bone whose head
/// is the joint.
struct MakeHumanJointSource {
  std::string joint;
  std::string bone;
};

/// The 28 joints in BodyModel order with their source bones.
const std::vector<MakeHumanJointSource>& MakeHumanJointMap();

/// A rig bone that is not a joint of the body, and the kept bone that
/// receives its skinning weights and children.
struct MakeHumanDroppedBone {
  std::string bone;
  std::string merged_into;
};

/// LHipJoint -> Hips, RHipJoint -> Hips, Neck1 -> Neck.
const std::vector<MakeHumanDroppedBone>& MakeHumanDroppedBones();

}  // namespace soma
