// The embedded procedural human body: a BodyModel generated entirely by code
// (no downloads, no licence), the default body of the framework.
//
// Construction (see procedural_body.cc for the numbers and their sources,
// mesh_builder.h for the primitives and the mesher of steps 2-3):
//  1. Anthropometry -> skeleton. Joint heights and segment lengths are
//     fractions of stature (Drillis & Contini 1966, as tabulated in Winter,
//     "Biomechanics and Motor Control of Human Movement", 4th ed. 2009,
//     Fig. 4.1); breadths, girths and head/hand/foot sizes are rounded
//     means of the ANSUR II survey of US Army personnel (Gordon et al. 2014,
//     NATICK/TR-15/007), averaged over men and women with the survey's
//     sample weights (4082 men, 1986 women).
//  2. Skeleton + girths -> ~22 body-part primitives (tapered capsules with
//     elliptic cross-sections and ellipsoids), blended into one implicit
//     surface by an exponential soft-min, with flat soles (z = 0).
//  3. Marching tetrahedra on a regular grid over the half-space x >= 0
//     (watertight and manifold by construction), shortest-edge-first
//     collapse decimation (link condition, no fold-overs, vertices
//     re-projected onto the implicit surface), mirroring to x < 0 (the mesh
//     is exactly left/right symmetric) and tangential relaxation.
//  4. Skinning weights from the body part each vertex belongs to (soft
//     attachment to the primitives, each owned by a joint), diffused along
//     the mesh and pruned to 4 influences within 2 steps of the kinematic
//     tree; joint regressor = non-negative weights on a ring of vertices
//     around each joint that reproduce the joint exactly at the mean shape.
//  5. Shape space: component k changes one anthropometric parameter by one
//     survey standard deviation; each vertex follows the primitives it is
//     attached to (normalised coordinates), the displacement field is
//     linearised by central differences: dir_k = (V(+e_k) - V(-e_k)) / 2.
//
// Conventions of body_model.h: metres, Z up, T-pose, feet on z = 0, faces -Y,
// left side at +X, SMPL joint order.
#pragma once

#include "framework/body/body_model.h"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace soma {

/// Number of shape components of the procedural body (see
/// ProceduralShapeComponents()).
inline constexpr int kNumProceduralShapeComponents = 12;

/// Options of MakeProceduralBody. Defaults give ~7000 vertices in ~0.2 s.
struct ProceduralBodyOptions {
  /// Marching-tetrahedra grid step, metres. Must resolve the hands (2.6 cm
  /// thick): in [0.005, 0.014].
  double grid_spacing = 0.010;
  /// Vertex count of the final (full, mirrored) mesh, in [3000, 10000].
  int target_vertices = 7000;
  /// Number of shape components (betas), in [10,
  /// kNumProceduralShapeComponents].
  int num_betas = kNumProceduralShapeComponents;
  /// Tangential relaxation passes after decimation (0 disables).
  int relax_iterations = 4;
  /// Soft-min blend radius of the body-part primitives, metres (fillets at
  /// armpits, crotch, neck): in [0.004, 0.03].
  double blend_radius = 0.012;

  /// Throws ConfigError naming the violated constraint.
  void Validate() const;
};

/// The anthropometric parameters the procedural body is built from. Lengths
/// in metres; everything else is a dimensionless multiplier (1 = survey mean)
/// or a coordinate (sex: -1 = female mean, +1 = male mean, 0 = pooled).
struct ProceduralAnthropometry {
  double stature = 1.714;       // vertex (head top) to floor, metres
  double girth = 1.0;           // overall girth (body mass at fixed stature)
  double leg_length = 1.0;      // hip height / stature, at constant stature
  double arm_length = 1.0;      // upper arm + forearm length
  double shoulder_width = 1.0;  // biacromial breadth
  double hip_width = 1.0;       // hip breadth and hip-joint spacing
  double belly = 1.0;           // abdominal (waist) depth
  double head_size = 1.0;       // head breadth, length and height
  double sex = 0.0;             // dimorphism coordinate
  double limb_girth = 1.0;      // arm and leg girths (muscularity)
  double extremity_size = 1.0;  // hand and foot size
  double chest_depth = 1.0;     // chest depth
};

/// Documentation of one shape component: beta_k = +1 moves `parameter` by
/// `stddev` (in the parameter's unit) from the mean.
struct ProceduralShapeComponent {
  std::string name;
  std::string parameter;
  double stddev = 0.0;
  std::string source;
};

/// The components in beta order (0 = stature, 1 = girth, 2 = leg length,
/// 3 = arm length, 4 = shoulder width, 5 = hip width, 6 = belly, 7 = head
/// size, 8 = sex dimorphism, 9 = limb girth, 10 = hand/foot size,
/// 11 = chest depth).
const std::vector<ProceduralShapeComponent>& ProceduralShapeComponents();

/// The anthropometric parameters of `betas` (missing entries = 0). This is
/// the non-linear map the shape space linearises.
ProceduralAnthropometry ProceduralAnthropometryFromBetas(
    const Eigen::VectorXd& betas);

/// Rest joints (3 x 24, SMPL order) of the skeleton the body is built on.
Eigen::Matrix3Xd ProceduralSkeletonJoints(
    const ProceduralAnthropometry& anthropometry);

/// Builds the procedural body (deterministic: the same options give the same
/// bytes). name = "procedural", 24 core joints, no pose correctives,
/// beta_stddev = 1 (betas ~ N(0, 1)).
BodyModel MakeProceduralBody(const ProceduralBodyOptions& options = {});

}  // namespace soma
