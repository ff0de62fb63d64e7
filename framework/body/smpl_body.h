// SMPL / SMPL+H / SMPL-X model files (.npz) as BodyModel.
//
// Keys read (other members, e.g. SMPL-X's pickled 'joint2num', are ignored):
//   v_template   V x 3          rest vertices of the mean shape, metres
//   f            F x 3          triangles (CCW seen from outside)
//   shapedirs    V x 3 x B      shape blend shapes (SMPL-X: 300 shape then
//                               100 expression columns; 10 + 10 in v1.0)
//   posedirs     V x 3 x P      pose correctives, P = 9 (J - 1)
//   J_regressor  J x V          dense joint regressor, rows summing to 1
//                               (a scipy.sparse matrix pickled into the npz
//                               is an object array: IoError, densify it)
//   weights      V x J          skinning weights
//   kintree_table 2 x J         row 0: parent of joint row1[k] (root's
//                               parent 4294967295 or -1), row 1: joint ids
// The family is told by J: 24 = SMPL, 52 = SMPL+H, 55 = SMPL-X.
//
// Frame. SMPL is Y up with the body facing +Z (left at +X). Our frame is Z
// up, facing -Y (body_model.h): p_ours = C p_smpl + t with
//   C = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]   ((x, y, z) -> (x, -z, y)),
// a proper rotation (det +1), and t = (0, 0, -min z) so that the template's
// lowest vertex lies on z = 0. Shape and pose blend-shape vectors are
// displacements: they get C but not t. The regressor and weights are
// unchanged (regressor rows sum to 1 in the published models, so regressed
// joints move with t).
//
// Pose correctives. SMPL drives posedirs with the row-major flattening of
// (R_j - I) of joints 1..J-1, R_j expressed in SMPL's frame. The same
// physical rotation in our frame is R'_j = C R_j C^T, so
// R_j - I = C^T (R'_j - I) C, i.e. vec(R_j - I) = K vec(R'_j - I) with
// K[3a+b, 3c+d] = C[c, a] C[d, b] (a signed permutation). Hence, per vertex v
// and joint block, posedirs_ours(v) = C posedirs_smpl(v) K — exact, no
// approximation; column blocks are then permuted with the joints (below).
// Poses convert likewise: an SMPL axis-angle w_j is C w_j in our frame.
//
// Joints. The first 24 joints of every BodyModel are the core joints in
// CoreJoint order (body_model.h). SMPL's 24 joints are exactly that. SMPL+H
// and SMPL-X lack SMPL's left/right_hand joints (22, 23); their hand roots
// are the finger bases. We use the middle-finger base joints: core 22
// ("left_hand") = left_middle1, core 23 ("right_hand") = right_middle1. All
// other joints follow in file order (SMPL-X: jaw, left_eye_smplhf,
// right_eye_smplhf, then the hand joints without the two middle1 joints),
// keeping their standard names; parents are remapped and satisfy
// parents[j] < j. Weights columns, regressor rows and posedirs blocks are
// permuted accordingly.
#pragma once

#include "framework/body/body_model.h"

#include <Eigen/Core>

#include <filesystem>
#include <string>
#include <vector>

namespace soma {

/// The SMPL family members this loader reads.
enum class SmplFamily { kSmpl, kSmplH, kSmplX };

/// "smpl", "smplh", "smplx".
const char* ToString(SmplFamily family);

/// Options of LoadSmplNpz.
struct SmplLoadOptions {
  /// Number of shape components kept (the first columns of shapedirs). At
  /// most B for SMPL / SMPL+H; for SMPL-X at most the shape part (300 when
  /// shapedirs has more than 300 columns, else 10) — expression columns are
  /// never used as betas.
  int num_betas = 10;
  /// Convert posedirs into BodyModel::pose_dirs (exact, see above). When
  /// false the body has no pose correctives and 'posedirs' is not read.
  bool load_pose_correctives = true;
  /// Regressor entries and skinning weights with |w| below this are dropped
  /// (weights rows are renormalised to sum to 1 afterwards).
  double sparsity_threshold = 1e-8;
  /// BodyModel::name; empty = the family name ("smpl", "smplh", "smplx").
  std::string name;

  /// Throws ConfigError on num_betas < 0 or a negative / non-finite
  /// threshold.
  void Validate() const;
};

/// Loads an SMPL / SMPL+H / SMPL-X model .npz into our frame and joint order
/// (see the file comment). Throws IoError naming the file and key on a
/// missing key, an array of the wrong shape (with the expected shape), an
/// unsupported joint count, a malformed kinematic tree or bad values; the
/// result passes BodyModel::Validate().
BodyModel LoadSmplNpz(const std::filesystem::path& npz,
                      const SmplLoadOptions& options = {});

/// C: SMPL frame (Y up, facing +Z) to ours (Z up, facing -Y).
Eigen::Matrix3d SmplToBodyFrame();

/// Standard joint names in file order: SMPL 24, SMPL+H 52, SMPL-X 55 (as in
/// the smplx package's joint_names.py).
const std::vector<std::string>& SmplFileJointNames(SmplFamily family);

/// For each of our joints, the file joint it comes from (size J).
std::vector<int> SmplJointOrder(SmplFamily family);

/// Our joint names for a family: file names permuted by SmplJointOrder, the
/// first 24 replaced by CoreJointNames().
std::vector<std::string> SmplBodyJointNames(SmplFamily family);

}  // namespace soma
