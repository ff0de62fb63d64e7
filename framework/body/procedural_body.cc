#include "framework/body/procedural_body.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <unordered_map>
#include <utility>

namespace soma {
namespace {

using Eigen::Vector3d;

// ---------------------------------------------------------------------------
// Anthropometric constants.
//
// Stature: ANSUR II (Gordon et al. 2014, "2012 Anthropometric Survey of U.S.
// Army Personnel: Methods and Summary Statistics", NATICK/TR-15/007): men
// 1756 mm (SD 69), women 1629 mm (SD 64), 4082 men and 1986 women. The
// sample-weighted mean is 1714 mm; the pooled SD including the between-sex
// difference is sqrt(67^2 + 0.673 * 0.327 * 128^2) = 90 mm, so betas ~ N(0,1)
// give a 95% stature range of about 1.54-1.89 m.
//
// The ANSUR II figures in this file are rounded summary statistics (means,
// coefficients of variation) of the survey's report; breadths and girths
// marked "~" are approximate and should be checked against the report's
// tables before being quoted. The mean mesh, measured with a convex-hull
// "tape" on horizontal slices, has: chest girth 0.94 m, waist 0.83 m, hips
// 0.97 m, thigh 0.59 m, calf 0.37 m, neck 0.40 m, upper arm 0.30 m, forearm
// 0.27 m, hip breadth 0.36 m, chest depth 0.26 m, foot length 0.26 m, arm
// span 1.04 H; volume ~0.07 m^3 (~70 kg).
constexpr double kMeanStature = 1.714;
constexpr double kStatureSd = 0.090;

// Joint heights and segment lengths as fractions of stature H (Drillis &
// Contini 1966, tabulated in Winter 2009, Fig. 4.1): ankle (lateral
// malleolus) 0.039 H, knee 0.285 H, hip (greater trochanter) 0.530 H,
// shoulder (acromion) 0.818 H, chin 0.870 H; upper arm 0.186 H, forearm
// 0.146 H, hand 0.108 H, foot length 0.152 H. The upper arm and forearm are
// shortened slightly (0.172 H, 0.142 H) and the glenohumeral joints put at
// +-0.100 H so that the T-pose arm span is 1.04 H, as ANSUR II span/stature
// (~1.02-1.04) requires; Winter's fractions measure overlapping landmarks.
constexpr double kAnkleHeight = 0.039;
constexpr double kKneeHeight = 0.285;
constexpr double kHipHeight = 0.530;
constexpr double kNeckBaseHeight = 0.840;  // C7 / base of neck
constexpr double kHipHalfSpacing = 0.052;  // hip joint centres, +-x
constexpr double kKneeHalfSpacing = 0.049;
constexpr double kShoulderHalfWidth = 0.100;  // glenohumeral centres
constexpr double kCollarHalfWidth = 0.045;
constexpr double kUpperArm = 0.172;
constexpr double kForearm = 0.142;
constexpr double kPalm = 0.055;  // wrist to knuckles
constexpr double kHand = 0.108;  // wrist to fingertip (Winter)
constexpr double kFoot = 0.152;  // foot length (Winter)

// Head (ANSUR II, sample-weighted means): head breadth ~154 mm, head length
// ~196 mm, chin-to-vertex height ~225 mm (Winter: chin at 0.870 H).
constexpr double kHeadSemiBreadth = 0.077;
constexpr double kHeadSemiLength = 0.098;
constexpr double kHeadSemiHeight = 0.1125;

// ---------------------------------------------------------------------------
// Primitives: tapered capsules with elliptic cross-sections (and ellipsoids,
// length 0), in a frame (d, e1, e2): d along the axis a -> b, e1 from `hint1`,
// e2 = d x e1 oriented along `hint2`.

struct Section {
  double t;   // position along the axis, 0 at a, 1 at b
  double r1;  // semi-axis along e1, metres
  double r2;  // semi-axis along e2
  double c1;  // centre offset along e1
  double c2;  // centre offset along e2
};

struct Primitive {
  Vector3d a = Vector3d::Zero();
  Vector3d b = Vector3d::Zero();
  Vector3d hint1 = Vector3d::UnitX();
  Vector3d hint2 = Vector3d::UnitY();
  Vector3d axis_if_degenerate = Vector3d::UnitZ();
  std::vector<Section> sections;  // t ascending, first 0, last 1
  double cap0 = 0.0;              // axial semi-length of the cap at a
  double cap1 = 0.0;              // ... at b
  int owner = 0;                  // joint whose segment this part is
  // Optional partition of the part among joints along t: (t, joint) means
  // "from t upwards the owner is joint"; blended over +-owner_blend metres.
  std::vector<std::pair<double, int>> owner_breaks;
  double owner_blend = 0.0;

  // Derived by Finalize().
  Vector3d d = Vector3d::UnitZ();
  Vector3d e1 = Vector3d::UnitX();
  Vector3d e2 = Vector3d::UnitY();
  double length = 0.0;

  void Finalize() {
    const Vector3d ab = b - a;
    length = ab.norm();
    d = length > 1e-9 ? Vector3d(ab / length) : axis_if_degenerate.normalized();
    e1 = hint1 - hint1.dot(d) * d;
    SOMA_CHECK_GT(e1.norm(), 1e-6)
        << "primitive frame hint parallel to its axis";
    e1.normalize();
    e2 = d.cross(e1);
    if (e2.dot(hint2) < 0.0) e2 = -e2;
  }

  Section SectionAt(double t) const {
    if (t <= sections.front().t) return sections.front();
    for (size_t k = 1; k < sections.size(); ++k) {
      if (t <= sections[k].t) {
        const Section& s0 = sections[k - 1];
        const Section& s1 = sections[k];
        const double u = (t - s0.t) / std::max(s1.t - s0.t, 1e-12);
        return {t,
                s0.r1 + u * (s1.r1 - s0.r1),
                s0.r2 + u * (s1.r2 - s0.r2),
                s0.c1 + u * (s1.c1 - s0.c1),
                s0.c2 + u * (s1.c2 - s0.c2)};
      }
    }
    return sections.back();
  }

  void Bounds(Vector3d* lo, Vector3d* hi) const {
    double reach = std::max(cap0, cap1);
    for (const Section& s : sections) {
      reach = std::max(reach,
                       std::max(s.r1, s.r2) + std::abs(s.c1) + std::abs(s.c2));
    }
    *lo = a.cwiseMin(b) - Vector3d::Constant(reach);
    *hi = a.cwiseMax(b) + Vector3d::Constant(reach);
  }
};

/// Where a point sits relative to a primitive: axial position, normalised
/// radial coordinates and normalised overshoot past an end cap.
struct PrimitiveCoords {
  double t = 0.0;
  double n1 = 0.0;
  double n2 = 0.0;
  double nw = 0.0;
};

/// Approximate signed distance (Quilez' ellipsoid bound: exact on the
/// surface, first-order accurate nearby) and the point's coordinates.
double PrimitiveField(const Primitive& prim,
                      const Vector3d& p,
                      PrimitiveCoords* coords) {
  const Vector3d q = p - prim.a;
  const double s = q.dot(prim.d);
  double tc = 0.0;
  double w = s;
  if (prim.length > 1e-9) {
    tc = std::clamp(s / prim.length, 0.0, 1.0);
    w = s - tc * prim.length;
  }
  const Section sec = prim.SectionAt(tc);
  const double x1 = q.dot(prim.e1) - sec.c1;
  const double x2 = q.dot(prim.e2) - sec.c2;
  const double r3 = w < 0.0 ? prim.cap0 : prim.cap1;
  const double u1 = x1 / sec.r1;
  const double u2 = x2 / sec.r2;
  const double u3 = w / r3;
  if (coords != nullptr) *coords = {tc, u1, u2, u3};
  const double k0 = std::sqrt(u1 * u1 + u2 * u2 + u3 * u3);
  const double v1 = u1 / sec.r1;
  const double v2 = u2 / sec.r2;
  const double v3 = u3 / r3;
  const double k1 = std::sqrt(v1 * v1 + v2 * v2 + v3 * v3);
  if (k1 < 1e-12) return -std::min({sec.r1, sec.r2, r3});
  return k0 * (k0 - 1.0) / k1;
}

/// Inverse of the coordinates: the point with `coords` on (possibly another
/// anthropometry's version of) the same primitive.
Vector3d PrimitivePoint(const Primitive& prim, const PrimitiveCoords& coords) {
  const Section sec = prim.SectionAt(coords.t);
  const double r3 = coords.nw < 0.0 ? prim.cap0 : prim.cap1;
  return prim.a + (coords.t * prim.length + coords.nw * r3) * prim.d +
         (sec.c1 + coords.n1 * sec.r1) * prim.e1 +
         (sec.c2 + coords.n2 * sec.r2) * prim.e2;
}

/// Owner joints of a primitive at axial position t (weights sum to 1).
void PrimitiveOwners(const Primitive& prim,
                     double t,
                     std::vector<std::pair<int, double>>* out) {
  out->clear();
  if (prim.owner_breaks.empty()) {
    out->emplace_back(prim.owner, 1.0);
    return;
  }
  // Piecewise owners with smoothstep transitions at the breaks.
  const double blend_t =
      prim.length > 1e-9 ? prim.owner_blend / prim.length : 0.0;
  std::vector<int> owners = {prim.owner};
  std::vector<double> weights = {1.0};
  for (const auto& [t_break, joint] : prim.owner_breaks) {
    double u = blend_t > 0 ? (t - (t_break - blend_t)) / (2.0 * blend_t)
                           : (t >= t_break ? 1 : 0);
    u = std::clamp(u, 0.0, 1.0);
    const double s = u * u * (3.0 - 2.0 * u);
    for (double& w : weights) w *= (1.0 - s);
    owners.push_back(joint);
    weights.push_back(s);
  }
  for (size_t k = 0; k < owners.size(); ++k) {
    if (weights[k] > 1e-9) out->emplace_back(owners[k], weights[k]);
  }
}

// ---------------------------------------------------------------------------
// Anthropometry -> skeleton and primitives.

constexpr int kMirrorJoint[kNumCoreJoints] = {0,  2,  1,  3,  5,  4,  6,  8,
                                              7,  9,  11, 10, 12, 14, 13, 15,
                                              17, 16, 19, 18, 21, 20, 23, 22};
constexpr int kSmplParents[kNumCoreJoints] = {-1, 0,  0,  0,  1,  2,  3,  4,
                                              5,  6,  7,  8,  9,  9,  9,  12,
                                              13, 14, 16, 17, 18, 19, 20, 21};

Vector3d Mirror(const Vector3d& p) { return {-p.x(), p.y(), p.z()}; }

Primitive MirrorPrimitive(const Primitive& prim) {
  Primitive out = prim;
  out.a = Mirror(prim.a);
  out.b = Mirror(prim.b);
  out.hint1 = Mirror(prim.hint1);
  out.hint2 = Mirror(prim.hint2);
  out.axis_if_degenerate = Mirror(prim.axis_if_degenerate);
  out.owner = kMirrorJoint[prim.owner];
  for (auto& [t, joint] : out.owner_breaks) joint = kMirrorJoint[joint];
  out.Finalize();
  return out;
}

struct BodyGeometry {
  Eigen::Matrix3Xd joints;  // 3 x 24, SMPL order
  std::vector<Primitive>
      primitives;  // same count and order for every anthropometry
};

Primitive MakeSweep(const Vector3d& a,
                    const Vector3d& b,
                    std::vector<Section> sections,
                    double cap0_ratio,
                    double cap1_ratio,
                    int owner,
                    const Vector3d& hint1,
                    const Vector3d& hint2) {
  Primitive prim;
  prim.a = a;
  prim.b = b;
  prim.sections = std::move(sections);
  prim.hint1 = hint1;
  prim.hint2 = hint2;
  prim.owner = owner;
  const Section& s0 = prim.sections.front();
  const Section& s1 = prim.sections.back();
  prim.cap0 = cap0_ratio * std::min(s0.r1, s0.r2);
  prim.cap1 = cap1_ratio * std::min(s1.r1, s1.r2);
  prim.Finalize();
  return prim;
}

Primitive MakeEllipsoid(
    const Vector3d& centre, double rx, double ry, double rz, int owner) {
  Primitive prim;
  prim.a = centre;
  prim.b = centre;
  prim.axis_if_degenerate = Vector3d::UnitZ();
  prim.hint1 = Vector3d::UnitX();
  prim.hint2 = Vector3d::UnitY();
  prim.sections = {{0.0, rx, ry, 0.0, 0.0}, {1.0, rx, ry, 0.0, 0.0}};
  prim.cap0 = rz;
  prim.cap1 = rz;
  prim.owner = owner;
  prim.Finalize();
  return prim;
}

BodyGeometry BuildGeometry(const ProceduralAnthropometry& an) {
  const double h = an.stature;
  const double s = h / kMeanStature;    // length scale
  const double g_h = std::pow(s, 0.6);  // girth follows stature weakly
  const double girth = an.girth * g_h;  // overall girth factor
  const double sex = an.sex;
  const double ext = an.extremity_size;
  const double sf = s * ext;  // hand/foot scale
  // Sex effects per unit coordinate = half the ANSUR II men-women difference
  // of the stature-normalised measure: biacromial breadth/H +2.5%, hip
  // breadth/H -4.5%, neck circumference +4.5%, arm girths +4%, thigh girth
  // -2%, chest depth +2%, head size +1%.
  const double hip_w = an.hip_width * (1.0 - 0.045 * sex);
  const double sho_w = an.shoulder_width * (1.0 + 0.025 * sex);
  const double head_s = an.head_size * (1.0 + 0.01 * sex) * std::sqrt(s);
  const double arm_g =
      std::pow(girth, 0.8) * an.limb_girth * (1.0 + 0.04 * sex);
  const double leg_g =
      std::pow(girth, 0.9) * std::pow(an.limb_girth, 0.8) * (1.0 - 0.02 * sex);
  const double neck_g = std::pow(girth, 0.7) * (1.0 + 0.045 * sex);

  // ---- Skeleton (left side; right = mirror).
  const double ankle_z = kAnkleHeight * h * ext;
  const double hip_z =
      ankle_z + (kHipHeight - kAnkleHeight) * h * an.leg_length;
  const double knee_z =
      ankle_z + (kKneeHeight - kAnkleHeight) * h * an.leg_length;
  const double neck_z = kNeckBaseHeight * h;
  const double trunk = neck_z - hip_z;
  const double pelvis_z = hip_z + 0.10 * trunk;
  const double spine1_z = hip_z + 0.28 * trunk;
  const double spine2_z = hip_z + 0.47 * trunk;
  const double spine3_z = hip_z + 0.66 * trunk;
  const double shoulder_z = hip_z + 0.87 * trunk;
  const double collar_z = hip_z + 0.90 * trunk;
  const double head_c = kHeadSemiHeight * head_s;
  const double chin_z = h - 2.0 * head_c;
  const double head_joint_z = chin_z + 0.035 * s;
  const Vector3d head_centre(0.0, -0.010 * s, h - head_c);

  const double hip_x = kHipHalfSpacing * h * hip_w;
  const double knee_x = kKneeHalfSpacing * h * (0.6 + 0.4 * hip_w);
  const double shoulder_x = kShoulderHalfWidth * h * sho_w;
  const double collar_x = kCollarHalfWidth * h * std::sqrt(sho_w);
  const double elbow_x = shoulder_x + kUpperArm * h * an.arm_length;
  const double wrist_x = elbow_x + kForearm * h * an.arm_length;
  const double hand_x = wrist_x + kPalm * h * ext;
  const double fingertip_x = wrist_x + kHand * h * ext;
  const double foot_len = kFoot * h * ext;

  Eigen::Matrix3Xd joints(3, kNumCoreJoints);
  auto set_left = [&](int joint, const Vector3d& p) {
    joints.col(joint) = p;
    joints.col(kMirrorJoint[joint]) = Mirror(p);
  };
  joints.col(kPelvis) = Vector3d(0.0, 0.0, pelvis_z);
  joints.col(kSpine1) = Vector3d(0.0, 0.004 * s, spine1_z);
  joints.col(kSpine2) = Vector3d(0.0, 0.006 * s, spine2_z);
  joints.col(kSpine3) = Vector3d(0.0, 0.004 * s, spine3_z);
  joints.col(kNeck) = Vector3d(0.0, 0.010 * s, neck_z);
  joints.col(kHead) = Vector3d(0.0, 0.0, head_joint_z);
  set_left(kLeftHip, Vector3d(hip_x, 0.0, hip_z));
  set_left(kLeftKnee, Vector3d(knee_x, 0.0, knee_z));
  set_left(kLeftAnkle, Vector3d(knee_x, 0.0, ankle_z));
  set_left(kLeftFoot,
           Vector3d(knee_x + 0.006 * s, -0.47 * foot_len, 0.018 * sf));
  set_left(kLeftCollar, Vector3d(collar_x, 0.0, collar_z));
  set_left(kLeftShoulder, Vector3d(shoulder_x, 0.0, shoulder_z));
  set_left(kLeftElbow, Vector3d(elbow_x, 0.0, shoulder_z));
  set_left(kLeftWrist, Vector3d(wrist_x, 0.0, shoulder_z));
  set_left(kLeftHand, Vector3d(hand_x, 0.0, shoulder_z));

  BodyGeometry geometry;
  geometry.joints = joints;
  std::vector<Primitive>& prims = geometry.primitives;
  const Vector3d ux = Vector3d::UnitX();
  const Vector3d uy = Vector3d::UnitY();
  const Vector3d uz = Vector3d::UnitZ();

  // ---- Torso: one sweep along z with elliptic cross-sections (x = breadth,
  // y = depth, centre offset in y). Mean values for the 1.714 m body chosen
  // to match ANSUR II sample-weighted means: hip breadth ~350 mm (with the
  // thighs), waist circumference ~880 mm, chest circumference ~990 mm,
  // chest depth ~250 mm, buttock depth ~240 mm.
  {
    struct Key {
      double u;  // (z - hip_z) / trunk
      double rx, ry, cy;
      double hip_share, shoulder_share, belly_share, chest_share;
    };
    const Key keys[] = {
        {-0.14, 0.118, 0.095, 0.006, 1.0, 0.0, 0.0, 0.0},  // crotch
        {0.00, 0.155, 0.120, 0.014, 1.0, 0.0, 0.0, 0.0},   // hips, buttocks
        {0.10, 0.158, 0.118, 0.006, 1.0, 0.0, 0.5, 0.0},   // iliac crest
        {0.28, 0.150, 0.112, -0.002, 0.3, 0.0, 1.0, 0.0},  // waist
        {0.47, 0.158, 0.120, -0.008, 0.0, 0.2, 0.6, 0.3},  // lower chest
        {0.64, 0.170, 0.130, -0.012, 0.0, 0.5, 0.0, 1.0},  // chest
        {0.80, 0.168, 0.118, -0.006, 0.0, 1.0, 0.0, 0.7},  // upper chest
        {0.93, 0.125, 0.088, 0.002, 0.0, 1.0, 0.0, 0.0},   // shoulder top
        {1.02, 0.068, 0.060, 0.006, 0.0, 0.3, 0.0, 0.0},   // base of neck
    };
    const double z0 = hip_z + keys[0].u * trunk;
    const double z1 = hip_z + keys[8].u * trunk;
    std::vector<Section> sections;
    for (const Key& k : keys) {
      const double z = hip_z + k.u * trunk;
      double rx = k.rx * std::pow(girth, 0.8) * std::pow(hip_w, k.hip_share) *
                  std::pow(sho_w, k.shoulder_share) *
                  (1.0 + sex * (0.02 * k.shoulder_share - 0.03 * k.hip_share));
      const double ry0 = k.ry * girth;
      const double ry =
          ry0 * std::pow(an.belly, k.belly_share) *
          std::pow(an.chest_depth * (1.0 + 0.02 * sex), k.chest_share);
      // Extra depth goes mostly to the front (-y), keeping the back in place.
      const double cy = k.cy * girth - 0.7 * (ry - ry0);
      sections.push_back({(z - z0) / (z1 - z0), rx, ry, 0.0, cy});
    }
    Primitive torso = MakeSweep(Vector3d(0, 0, z0),
                                Vector3d(0, 0, z1),
                                sections,
                                0.55,
                                0.6,
                                kPelvis,
                                ux,
                                uy);
    const double length = z1 - z0;
    torso.owner_breaks = {{(spine1_z - z0) / length, kSpine1},
                          {(spine2_z - z0) / length, kSpine2},
                          {(spine3_z - z0) / length, kSpine3}};
    torso.owner_blend = 0.035 * s;
    prims.push_back(torso);
  }

  // ---- Neck (ANSUR II neck circumference ~377 mm) and head.
  prims.push_back(MakeSweep(Vector3d(0.0, 0.012 * s, neck_z - 0.03 * s),
                            Vector3d(0.0, 0.004 * s, head_joint_z + 0.02 * s),
                            {{0.0, 0.054 * neck_g, 0.052 * neck_g, 0.0, 0.0},
                             {1.0, 0.049 * neck_g, 0.049 * neck_g, 0.0, 0.0}},
                            1.0,
                            1.0,
                            kNeck,
                            ux,
                            uy));
  prims.push_back(MakeEllipsoid(head_centre,
                                kHeadSemiBreadth * head_s,
                                kHeadSemiLength * head_s,
                                head_c,
                                kHead));
  // Jaw and chin.
  prims.push_back(
      MakeEllipsoid(Vector3d(0.0, -0.032 * head_s, chin_z + 0.036 * head_s),
                    0.052 * head_s,
                    0.048 * head_s,
                    0.040 * head_s,
                    kHead));

  // ---- Left limbs (mirrored below).
  std::vector<Primitive> left;
  // Shoulder girdle (trapezius slope from the base of the neck to the
  // acromion): owned by the collar.
  left.push_back(
      MakeSweep(Vector3d(0.040 * s, 0.005 * s, collar_z + 0.030 * s),
                Vector3d(shoulder_x - 0.010 * s, 0.0, shoulder_z + 0.005 * s),
                {{0.0,
                  0.050 * std::pow(girth, 0.7),
                  0.040 * std::pow(girth, 0.7),
                  0.0,
                  0.0},
                 {1.0, 0.050 * arm_g, 0.042 * arm_g, 0.0, 0.0}},
                1.0,
                1.0,
                kLeftCollar,
                uy,
                uz));
  // Upper arm (ANSUR II relaxed upper-arm circumference ~310 mm), forearm
  // (forearm circumference ~290 mm, wrist ~167 mm): e1 = depth (y),
  // e2 = height (z).
  left.push_back(MakeSweep(Vector3d(shoulder_x - 0.015 * s, 0.0, shoulder_z),
                           joints.col(kLeftElbow),
                           {{0.0, 0.055 * arm_g, 0.054 * arm_g, 0.0, 0.0},
                            {0.4, 0.053 * arm_g, 0.049 * arm_g, 0.0, 0.0},
                            {1.0, 0.040 * arm_g, 0.037 * arm_g, 0.0, 0.0}},
                           1.0,
                           1.0,
                           kLeftShoulder,
                           uy,
                           uz));
  left.push_back(MakeSweep(
      joints.col(kLeftElbow),
      joints.col(kLeftWrist),
      {{0.0, 0.042 * arm_g, 0.037 * arm_g, 0.0, 0.0},
       {0.25, 0.047 * arm_g, 0.040 * arm_g, 0.0, 0.0},
       {1.0, 0.026 * std::sqrt(arm_g), 0.018 * std::sqrt(arm_g), 0.0, 0.0}},
      1.0,
      1.0,
      kLeftElbow,
      uy,
      uz));
  // Hand (ANSUR II hand breadth ~87 mm, hand length 0.108 H): flat palm and
  // a "mitten" of fingers, 2.5-3.5 cm thick, plus a thumb.
  const double hand_g = sf * std::pow(girth, 0.3);
  left.push_back(MakeSweep(joints.col(kLeftWrist) + Vector3d(0.005 * s, 0, 0),
                           joints.col(kLeftHand),
                           {{0.0, 0.024 * sf, 0.017 * hand_g, 0.0, 0.0},
                            {0.6, 0.044 * sf, 0.017 * hand_g, 0.0, 0.0},
                            {1.0, 0.043 * sf, 0.015 * hand_g, 0.0, 0.0}},
                           0.5,
                           0.5,
                           kLeftWrist,
                           uy,
                           uz));
  left.push_back(MakeSweep(
      joints.col(kLeftHand),
      Vector3d(fingertip_x - 0.012 * sf, 0.0, shoulder_z - 0.002 * sf),
      {{0.0, 0.041 * sf, 0.0135 * hand_g, 0.0, 0.0},
       {1.0, 0.033 * sf, 0.0125 * hand_g, 0.0, 0.0}},
      0.5,
      1.0,
      kLeftHand,
      uy,
      uz));
  left.push_back(
      MakeSweep(joints.col(kLeftWrist) + sf * Vector3d(0.030, -0.016, -0.006),
                joints.col(kLeftWrist) + sf * Vector3d(0.086, -0.058, -0.014),
                {{0.0, 0.0125 * hand_g, 0.0125 * hand_g, 0.0, 0.0},
                 {1.0, 0.0110 * hand_g, 0.0105 * hand_g, 0.0, 0.0}},
                1.0,
                1.0,
                kLeftWrist,
                uz,
                uy));
  // Thigh (ANSUR II thigh circumference ~620 mm below the buttock), shank
  // (calf ~385 mm, ankle ~230 mm): e1 = breadth (x), e2 = depth (y).
  left.push_back(MakeSweep(
      joints.col(kLeftHip),
      joints.col(kLeftKnee),
      {{0.0, 0.090 * leg_g, 0.104 * leg_g, 0.0, 0.008},
       {0.2, 0.082 * leg_g, 0.103 * leg_g, 0.0, 0.006},
       {0.55, 0.070 * leg_g, 0.080 * leg_g, 0.0, 0.003},
       {1.0, 0.050 * std::sqrt(leg_g), 0.053 * std::sqrt(leg_g), 0.0, 0.0}},
      1.0,
      1.0,
      kLeftHip,
      ux,
      uy));
  left.push_back(MakeSweep(
      joints.col(kLeftKnee),
      joints.col(kLeftAnkle),
      {{0.0, 0.050 * std::sqrt(leg_g), 0.053 * std::sqrt(leg_g), 0.0, 0.0},
       {0.3, 0.054 * leg_g, 0.066 * leg_g, 0.0, 0.012 * leg_g},
       {1.0, 0.030 * s, 0.031 * s, 0.0, 0.0}},
      1.0,
      1.0,
      kLeftKnee,
      ux,
      uy));
  // Foot (ANSUR II foot breadth ~99 mm; length 0.152 H): heel to toe,
  // e1 = breadth (x), e2 = height (z); partly below z = 0, flattened by the
  // floor plane. Owned by the ankle, the toes by the foot joint.
  {
    const Vector3d heel(knee_x, 0.15 * foot_len, 0.030 * sf);
    const Vector3d toe(knee_x + 0.012 * s, -0.69 * foot_len, 0.014 * sf);
    Primitive foot = MakeSweep(heel,
                               toe,
                               {{0.0, 0.030 * sf, 0.036 * sf, 0.0, 0.0},
                                {0.45, 0.044 * sf, 0.034 * sf, 0.0, 0.0},
                                {0.72, 0.048 * sf, 0.026 * sf, 0.0, 0.0},
                                {1.0, 0.034 * sf, 0.017 * sf, 0.0, 0.0}},
                               1.0,
                               1.0,
                               kLeftAnkle,
                               ux,
                               uz);
    const double t_ball = (0.15 + 0.47) / (0.15 + 0.69);
    foot.owner_breaks = {{t_ball - 0.04, kLeftFoot}};
    foot.owner_blend = 0.02 * sf;
    left.push_back(foot);
  }
  for (const Primitive& prim : left) prims.push_back(prim);
  for (const Primitive& prim : left) prims.push_back(MirrorPrimitive(prim));
  return geometry;
}

// ---------------------------------------------------------------------------
// The implicit surface on a grid over x >= 0 (the body is mirror symmetric).

class FieldGrid {
 public:
  FieldGrid(const std::vector<Primitive>& prims, double spacing, double blend)
      : h_(spacing), blend_(blend) {
    Vector3d lo = Vector3d::Constant(std::numeric_limits<double>::max());
    Vector3d hi = -lo;
    for (const Primitive& prim : prims) {
      Vector3d a, b;
      prim.Bounds(&a, &b);
      lo = lo.cwiseMin(a);
      hi = hi.cwiseMax(b);
    }
    const double margin = 3.0 * h_;
    y0_ = lo.y() - margin;
    z0_ = -margin;  // soles at z = 0
    nx_ = static_cast<int>(std::ceil((hi.x() + margin) / h_)) + 1;
    ny_ = static_cast<int>(std::ceil((hi.y() + margin - y0_) / h_)) + 1;
    nz_ = static_cast<int>(std::ceil((hi.z() + margin - z0_) / h_)) + 1;
    const size_t n = static_cast<size_t>(nx_) * ny_ * nz_;
    std::vector<double> acc(n, 0.0);
    for (const Primitive& prim : prims) {
      Vector3d a, b;
      prim.Bounds(&a, &b);
      a -= Vector3d::Constant(kBand);
      b += Vector3d::Constant(kBand);
      const int i0 = std::max(0, static_cast<int>(std::floor(a.x() / h_)));
      const int i1 = std::min(nx_ - 1, static_cast<int>(std::ceil(b.x() / h_)));
      const int j0 =
          std::max(0, static_cast<int>(std::floor((a.y() - y0_) / h_)));
      const int j1 =
          std::min(ny_ - 1, static_cast<int>(std::ceil((b.y() - y0_) / h_)));
      const int k0 =
          std::max(0, static_cast<int>(std::floor((a.z() - z0_) / h_)));
      const int k1 =
          std::min(nz_ - 1, static_cast<int>(std::ceil((b.z() - z0_) / h_)));
      for (int k = k0; k <= k1; ++k) {
        for (int j = j0; j <= j1; ++j) {
          for (int i = i0; i <= i1; ++i) {
            const double f = PrimitiveField(prim, Node(i, j, k), nullptr);
            if (f < kBand)
              acc[Index(i, j, k)] += std::exp(-std::max(f, -kDeep) / blend_);
          }
        }
      }
    }
    values_.resize(n);
    for (int k = 0; k < nz_; ++k) {
      const double z = z0_ + k * h_;
      for (int j = 0; j < ny_; ++j) {
        for (int i = 0; i < nx_; ++i) {
          const size_t idx = Index(i, j, k);
          const double body =
              acc[idx] > 0.0 ? -blend_ * std::log(acc[idx]) : kBand;
          values_[idx] = FloorClip(body, z);
        }
      }
    }
  }

  /// Smooth intersection with the half-space z >= 0 (flat soles).
  static double FloorClip(double body, double z) {
    const double a = body;
    const double b = -z;
    const double m = std::max(a, b);
    return m + kSoleBlend * std::log1p(std::exp(-std::abs(a - b) / kSoleBlend));
  }

  int nx() const { return nx_; }
  int ny() const { return ny_; }
  int nz() const { return nz_; }
  double spacing() const { return h_; }
  size_t Index(int i, int j, int k) const {
    return (static_cast<size_t>(k) * ny_ + j) * nx_ + i;
  }
  Vector3d Node(int i, int j, int k) const {
    return {i * h_, y0_ + j * h_, z0_ + k * h_};
  }
  double Value(int i, int j, int k) const { return values_[Index(i, j, k)]; }

  /// Trilinear value and gradient at p (x < 0 by mirror symmetry).
  double Sample(const Vector3d& p, Vector3d* gradient) const {
    const bool mirrored = p.x() < 0.0;
    const double gx = (mirrored ? -p.x() : p.x()) / h_;
    const double gy = (p.y() - y0_) / h_;
    const double gz = (p.z() - z0_) / h_;
    const int i = std::clamp(static_cast<int>(std::floor(gx)), 0, nx_ - 2);
    const int j = std::clamp(static_cast<int>(std::floor(gy)), 0, ny_ - 2);
    const int k = std::clamp(static_cast<int>(std::floor(gz)), 0, nz_ - 2);
    const double u = std::clamp(gx - i, 0.0, 1.0);
    const double v = std::clamp(gy - j, 0.0, 1.0);
    const double w = std::clamp(gz - k, 0.0, 1.0);
    double c[2][2][2];
    for (int dk = 0; dk < 2; ++dk) {
      for (int dj = 0; dj < 2; ++dj) {
        for (int di = 0; di < 2; ++di)
          c[dk][dj][di] = Value(i + di, j + dj, k + dk);
      }
    }
    const auto lerp = [](double a, double b, double t) {
      return a + t * (b - a);
    };
    const double c00 = lerp(c[0][0][0], c[0][0][1], u);
    const double c01 = lerp(c[0][1][0], c[0][1][1], u);
    const double c10 = lerp(c[1][0][0], c[1][0][1], u);
    const double c11 = lerp(c[1][1][0], c[1][1][1], u);
    const double c0 = lerp(c00, c01, v);
    const double c1 = lerp(c10, c11, v);
    if (gradient != nullptr) {
      const double dx0 =
          lerp(c[0][0][1] - c[0][0][0], c[0][1][1] - c[0][1][0], v);
      const double dx1 =
          lerp(c[1][0][1] - c[1][0][0], c[1][1][1] - c[1][1][0], v);
      const double dx = lerp(dx0, dx1, w) / h_;
      const double dy = lerp(c01 - c00, c11 - c10, w) / h_;
      const double dz = (c1 - c0) / h_;
      *gradient = Vector3d(mirrored ? -dx : dx, dy, dz);
    }
    return lerp(c0, c1, w);
  }

  /// Newton steps onto the zero level set; `on_seam` keeps x = 0.
  void Project(Vector3d* p, bool on_seam) const {
    for (int iter = 0; iter < 4; ++iter) {
      Vector3d g;
      const double f = Sample(*p, &g);
      if (on_seam) g.x() = 0.0;
      const double g2 = g.squaredNorm();
      if (g2 < 1e-12) return;
      Vector3d step = (f / g2) * g;
      const double len = step.norm();
      if (len > h_) step *= h_ / len;
      *p -= step;
      if (std::abs(f) < 1e-7) return;
    }
  }

 private:
  static constexpr double kBand = 0.06;  // primitives farther away are ignored
  static constexpr double kDeep = 0.3;   // clamp of deep-inside values
  static constexpr double kSoleBlend = 0.003;

  double h_;
  double blend_;
  double y0_ = 0.0;
  double z0_ = 0.0;
  int nx_ = 0;
  int ny_ = 0;
  int nz_ = 0;
  std::vector<double> values_;
};

// ---------------------------------------------------------------------------
// Marching tetrahedra (Kuhn decomposition of each cube into 6 tetrahedra
// around its main diagonal; consistent across cubes, so the result is a
// closed 2-manifold wherever the surface stays inside the grid).

struct HalfMesh {
  std::vector<Vector3d> vertices;
  std::vector<char> seam;  // on x = 0 (the boundary of the half mesh)
  std::vector<std::array<int, 3>> faces;
};

HalfMesh MarchingTetrahedra(const FieldGrid& grid) {
  HalfMesh mesh;
  std::unordered_map<uint64_t, int> edge_vertex;
  edge_vertex.reserve(1 << 17);
  const int nx = grid.nx();
  const int ny = grid.ny();
  const int nz = grid.nz();
  static constexpr int kTets[6][4] = {{0, 1, 3, 7},
                                      {0, 1, 5, 7},
                                      {0, 2, 3, 7},
                                      {0, 2, 6, 7},
                                      {0, 4, 5, 7},
                                      {0, 4, 6, 7}};
  auto corner_node = [](int i, int j, int k, int c, int* ci, int* cj, int* ck) {
    *ci = i + (c & 1);
    *cj = j + ((c >> 1) & 1);
    *ck = k + ((c >> 2) & 1);
  };
  auto edge_point = [&](int i, int j, int k, int ca, int cb) -> int {
    // ca is a bit-subset of cb (Kuhn chains are monotone).
    int ai, aj, ak, bi, bj, bk;
    corner_node(i, j, k, ca, &ai, &aj, &ak);
    corner_node(i, j, k, cb, &bi, &bj, &bk);
    const uint64_t key =
        static_cast<uint64_t>(grid.Index(ai, aj, ak)) * 8 + (ca ^ cb);
    const auto it = edge_vertex.find(key);
    if (it != edge_vertex.end()) return it->second;
    const double fa = grid.Value(ai, aj, ak);
    const double fb = grid.Value(bi, bj, bk);
    const double t = std::clamp(fa / (fa - fb), 0.02, 0.98);
    const Vector3d pa = grid.Node(ai, aj, ak);
    const Vector3d pb = grid.Node(bi, bj, bk);
    const int id = static_cast<int>(mesh.vertices.size());
    mesh.vertices.push_back(pa + t * (pb - pa));
    mesh.seam.push_back(ai == 0 && bi == 0 ? 1 : 0);
    edge_vertex.emplace(key, id);
    return id;
  };
  auto add_triangle = [&](int v0, int v1, int v2, const Vector3d& outward) {
    const Vector3d n = (mesh.vertices[v1] - mesh.vertices[v0])
                           .cross(mesh.vertices[v2] - mesh.vertices[v0]);
    if (n.dot(outward) >= 0.0) {
      mesh.faces.push_back({v0, v1, v2});
    } else {
      mesh.faces.push_back({v0, v2, v1});
    }
  };
  for (int k = 0; k + 1 < nz; ++k) {
    for (int j = 0; j + 1 < ny; ++j) {
      for (int i = 0; i + 1 < nx; ++i) {
        double f[8];
        int inside_count = 0;
        for (int c = 0; c < 8; ++c) {
          f[c] =
              grid.Value(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
          if (f[c] < 0.0) ++inside_count;
        }
        if (inside_count == 0 || inside_count == 8) continue;
        for (const auto& tet : kTets) {
          int in[4], out[4];
          int n_in = 0, n_out = 0;
          for (const int c : tet) {
            if (f[c] < 0.0) {
              in[n_in++] = c;
            } else {
              out[n_out++] = c;
            }
          }
          if (n_in == 0 || n_out == 0) continue;
          Vector3d in_centre = Vector3d::Zero();
          Vector3d out_centre = Vector3d::Zero();
          for (int q = 0; q < n_in; ++q) {
            in_centre += grid.Node(
                i + (in[q] & 1), j + ((in[q] >> 1) & 1), k + (in[q] >> 2));
          }
          for (int q = 0; q < n_out; ++q) {
            out_centre += grid.Node(
                i + (out[q] & 1), j + ((out[q] >> 1) & 1), k + (out[q] >> 2));
          }
          const Vector3d outward = out_centre / n_out - in_centre / n_in;
          auto ep = [&](int c0, int c1) {
            return c0 < c1 ? edge_point(i, j, k, c0, c1)
                           : edge_point(i, j, k, c1, c0);
          };
          if (n_in == 1 || n_out == 1) {
            const int apex = n_in == 1 ? in[0] : out[0];
            const int* others = n_in == 1 ? out : in;
            add_triangle(ep(apex, others[0]),
                         ep(apex, others[1]),
                         ep(apex, others[2]),
                         outward);
          } else {
            // Quad: in {a, b}, out {c, d}; cycle ac, ad, bd, bc.
            const int ac = ep(in[0], out[0]);
            const int ad = ep(in[0], out[1]);
            const int bd = ep(in[1], out[1]);
            const int bc = ep(in[1], out[0]);
            add_triangle(ac, ad, bd, outward);
            add_triangle(ac, bd, bc, outward);
          }
        }
      }
    }
  }
  return mesh;
}

// ---------------------------------------------------------------------------
// Shortest-edge-first collapse decimation of the half mesh. Seam vertices
// (x = 0) only collapse along the seam; an interior vertex collapses into a
// seam vertex; no interior edge may join two seam vertices (the mirrored mesh
// would be non-manifold there). The link condition keeps the mesh a
// manifold, the normal test prevents fold-overs.

double TriangleQuality(const Vector3d& a,
                       const Vector3d& b,
                       const Vector3d& c) {
  const double area2 = (b - a).cross(c - a).norm();  // 2 * area
  const double sum_sq =
      (b - a).squaredNorm() + (c - b).squaredNorm() + (a - c).squaredNorm();
  if (sum_sq <= 0.0) return 0.0;
  return 2.0 * std::sqrt(3.0) * area2 / sum_sq;  // 1 for equilateral
}

class Decimator {
 public:
  /// Largest allowed angle between a new face and the surface normal: 70 deg.
  static constexpr double kMinNormalCosine = 0.34;

  Decimator(HalfMesh* mesh, const FieldGrid* grid) : mesh_(mesh), grid_(grid) {
    const int nv = static_cast<int>(mesh_->vertices.size());
    vertex_alive_.assign(nv, 1);
    face_alive_.assign(mesh_->faces.size(), 1);
    stamp_.assign(nv, 0);
    vertex_faces_.resize(nv);
    for (size_t f = 0; f < mesh_->faces.size(); ++f) {
      for (const int v : mesh_->faces[f])
        vertex_faces_[v].push_back(static_cast<int>(f));
    }
    alive_ = nv;
    alive_seam_ = 0;
    for (const char s : mesh_->seam) alive_seam_ += s;
  }

  void Run(int target_full_vertices) {
    // Edges rejected once may become collapsible after their neighbourhood
    // changed: re-seed the queue with every live edge a few times.
    for (int round = 0; round < 6 && FullCount() > target_full_vertices;
         ++round) {
      // Each undirected edge once (seam edges have a single face).
      for (size_t f = 0; f < mesh_->faces.size(); ++f) {
        if (!face_alive_[f]) continue;
        const auto& tri = mesh_->faces[f];
        for (int e = 0; e < 3; ++e) {
          const int a = tri[e];
          const int b = tri[(e + 1) % 3];
          if (a < b || (mesh_->seam[a] && mesh_->seam[b])) {
            Push(std::min(a, b), std::max(a, b));
          }
        }
      }
      int collapses = 0;
      Entry entry;
      while (FullCount() > target_full_vertices && queue_.Pop(&entry)) {
        if (!vertex_alive_[entry.a] || !vertex_alive_[entry.b]) continue;
        if (stamp_[entry.a] != entry.stamp_a ||
            stamp_[entry.b] != entry.stamp_b) {
          continue;
        }
        collapses += TryCollapse(entry.a, entry.b) ? 1 : 0;
      }
      queue_.Clear();
      if (collapses == 0) break;
    }
  }

  /// Removes dead vertices and faces.
  void Compact() {
    std::vector<int> remap(mesh_->vertices.size(), -1);
    HalfMesh out;
    for (size_t v = 0; v < mesh_->vertices.size(); ++v) {
      if (!vertex_alive_[v]) continue;
      remap[v] = static_cast<int>(out.vertices.size());
      out.vertices.push_back(mesh_->vertices[v]);
      out.seam.push_back(mesh_->seam[v]);
    }
    for (size_t f = 0; f < mesh_->faces.size(); ++f) {
      if (!face_alive_[f]) continue;
      const auto& tri = mesh_->faces[f];
      out.faces.push_back({remap[tri[0]], remap[tri[1]], remap[tri[2]]});
    }
    *mesh_ = std::move(out);
  }

 private:
  struct Entry {
    int a = 0, b = 0;
    int stamp_a = 0, stamp_b = 0;
  };

  /// Shortest-edge-first order up to kBucketWidth: a bucket queue (O(1)
  /// push/pop, cache friendly) instead of a binary heap over ~10^5 edges.
  /// LIFO within a bucket, so the order is deterministic.
  class EdgeQueue {
   public:
    static constexpr double kBucketWidth = 2.5e-4;  // metres
    static constexpr int kNumBuckets = 800;         // edges up to 20 cm

    void Push(double length, const Entry& entry) {
      const int bucket =
          std::min(kNumBuckets - 1, static_cast<int>(length / kBucketWidth));
      buckets_[bucket].push_back(entry);
      first_ = std::min(first_, bucket);
    }
    bool Pop(Entry* entry) {
      while (first_ < kNumBuckets && buckets_[first_].empty()) ++first_;
      if (first_ == kNumBuckets) return false;
      *entry = buckets_[first_].back();
      buckets_[first_].pop_back();
      return true;
    }
    void Clear() {
      for (auto& bucket : buckets_) bucket.clear();
      first_ = kNumBuckets;
    }

   private:
    std::vector<std::vector<Entry>> buckets_ =
        std::vector<std::vector<Entry>>(kNumBuckets);
    int first_ = kNumBuckets;
  };

  int FullCount() const { return 2 * alive_ - alive_seam_; }

  void Push(int a, int b) {
    queue_.Push((mesh_->vertices[a] - mesh_->vertices[b]).norm(),
                {a, b, stamp_[a], stamp_[b]});
  }

  void Neighbours(int v, std::vector<int>* out) const {
    out->clear();
    for (const int f : vertex_faces_[v]) {
      for (const int u : mesh_->faces[f]) {
        if (u != v) out->push_back(u);
      }
    }
    std::sort(out->begin(), out->end());
    out->erase(std::unique(out->begin(), out->end()), out->end());
  }

  static bool Contains(const std::array<int, 3>& tri, int v) {
    return tri[0] == v || tri[1] == v || tri[2] == v;
  }

  bool TryCollapse(int a, int b) {
    auto& seam = mesh_->seam;
    if (!seam[a] && seam[b]) std::swap(a, b);  // keep the seam vertex
    const bool both_seam = seam[a] && seam[b];
    shared_.clear();
    for (const int f : vertex_faces_[a]) {
      if (Contains(mesh_->faces[f], b)) shared_.push_back(f);
    }
    if (both_seam ? shared_.size() != 1 : shared_.size() != 2) return false;
    opposite_.clear();
    for (const int f : shared_) {
      for (const int u : mesh_->faces[f]) {
        if (u != a && u != b) opposite_.push_back(u);
      }
    }
    std::sort(opposite_.begin(), opposite_.end());
    Neighbours(a, &na_);
    Neighbours(b, &nb_);
    common_.clear();
    std::set_intersection(na_.begin(),
                          na_.end(),
                          nb_.begin(),
                          nb_.end(),
                          std::back_inserter(common_));
    if (common_ != opposite_) return false;  // link condition
    if (seam[a] && !seam[b]) {
      for (const int c : nb_) {
        if (c != a && seam[c] &&
            !std::binary_search(common_.begin(), common_.end(), c)) {
          return false;  // would create an interior seam-to-seam edge
        }
      }
    }
    const size_t remaining =
        vertex_faces_[a].size() + vertex_faces_[b].size() - 2 * shared_.size();
    if (remaining < (seam[a] ? 2u : 3u)) return false;

    Vector3d p;
    if (both_seam) {
      p = 0.5 * (mesh_->vertices[a] + mesh_->vertices[b]);
      p.x() = 0.0;
      grid_->Project(&p, true);
      p.x() = 0.0;
    } else if (seam[a]) {
      p = mesh_->vertices[a];
    } else {
      p = 0.5 * (mesh_->vertices[a] + mesh_->vertices[b]);
      grid_->Project(&p, false);
    }
    // Geometric checks on every surviving face around a and b.
    for (const int v : {a, b}) {
      for (const int f : vertex_faces_[v]) {
        if (std::find(shared_.begin(), shared_.end(), f) != shared_.end())
          continue;
        const auto& tri = mesh_->faces[f];
        Vector3d before[3], after[3];
        for (int q = 0; q < 3; ++q) {
          before[q] = mesh_->vertices[tri[q]];
          after[q] = (tri[q] == a || tri[q] == b) ? p : before[q];
        }
        const Vector3d n0 =
            (before[1] - before[0]).cross(before[2] - before[0]);
        const Vector3d n1 = (after[1] - after[0]).cross(after[2] - after[0]);
        const double l0 = n0.norm();
        const double l1 = n1.norm();
        if (l1 < 1e-14) return false;
        if (l0 > 1e-14 && n0.dot(n1) < 0.0) return false;  // flipped
        // The new face must face the way the surface does (the MT faces
        // themselves are noisy, so compare with the field gradient).
        Vector3d gradient;
        grid_->Sample((after[0] + after[1] + after[2]) / 3.0, &gradient);
        if (n1.dot(gradient) < kMinNormalCosine * l1 * gradient.norm())
          return false;
        const double q1 = TriangleQuality(after[0], after[1], after[2]);
        if (q1 < 0.1 && q1 < TriangleQuality(before[0], before[1], before[2])) {
          return false;
        }
      }
    }
    // Apply: b disappears into a.
    for (const int f : shared_) {
      face_alive_[f] = 0;
      for (const int u : mesh_->faces[f]) {
        auto& list = vertex_faces_[u];
        list.erase(std::remove(list.begin(), list.end(), f), list.end());
      }
    }
    for (const int f : vertex_faces_[b]) {
      for (int& u : mesh_->faces[f]) {
        if (u == b) u = a;
      }
      vertex_faces_[a].push_back(f);
    }
    vertex_faces_[b].clear();
    vertex_alive_[b] = 0;
    --alive_;
    if (seam[b]) --alive_seam_;
    mesh_->vertices[a] = p;
    ++stamp_[a];
    Neighbours(a, &na_);
    for (const int u : na_) Push(std::min(a, u), std::max(a, u));
    return true;
  }

  HalfMesh* mesh_;
  const FieldGrid* grid_;
  std::vector<char> vertex_alive_;
  std::vector<char> face_alive_;
  std::vector<int> stamp_;
  std::vector<std::vector<int>> vertex_faces_;
  EdgeQueue queue_;
  int alive_ = 0;
  int alive_seam_ = 0;
  // Scratch.
  std::vector<int> shared_, opposite_, na_, nb_, common_;
};

/// Edge flips that raise the worse quality of the two triangles around an
/// interior edge (a local Delaunay-like improvement that removes the slivers
/// decimation could not collapse). Seam edges are never flipped and no
/// interior seam-to-seam edge is created.
void ImproveByFlips(const FieldGrid& grid, HalfMesh* mesh) {
  auto key = [](int a, int b) {
    return (static_cast<uint64_t>(std::min(a, b)) << 32) |
           static_cast<uint32_t>(std::max(a, b));
  };
  auto& faces = mesh->faces;
  const auto& pos = mesh->vertices;
  for (int pass = 0; pass < 8; ++pass) {
    std::unordered_map<uint64_t, std::array<int, 2>> edge_faces;
    edge_faces.reserve(faces.size() * 2);
    for (size_t f = 0; f < faces.size(); ++f) {
      for (int e = 0; e < 3; ++e) {
        auto [it, inserted] =
            edge_faces.try_emplace(key(faces[f][e], faces[f][(e + 1) % 3]),
                                   std::array<int, 2>{static_cast<int>(f), -1});
        if (!inserted) it->second[1] = static_cast<int>(f);
      }
    }
    // Deterministic order: by edge key.
    std::vector<uint64_t> keys;
    keys.reserve(edge_faces.size());
    for (const auto& [k, fs] : edge_faces) keys.push_back(k);
    std::sort(keys.begin(), keys.end());
    std::vector<char> touched(faces.size(), 0);
    int flips = 0;
    for (const uint64_t k : keys) {
      const auto& fs = edge_faces[k];
      if (fs[1] < 0 || touched[fs[0]] || touched[fs[1]]) continue;
      const int u = static_cast<int>(k >> 32);
      const int w = static_cast<int>(k & 0xffffffffu);
      // Orient: f1 has the directed edge a -> b.
      int f1 = fs[0], f2 = fs[1];
      int a = -1, b = -1, c = -1, d = -1;
      for (int e = 0; e < 3; ++e) {
        const int p = faces[f1][e], q = faces[f1][(e + 1) % 3];
        if ((p == u && q == w) || (p == w && q == u)) {
          a = p;
          b = q;
          c = faces[f1][(e + 2) % 3];
        }
      }
      for (const int v : faces[f2]) {
        if (v != a && v != b) d = v;
      }
      if (c == d || (mesh->seam[c] && mesh->seam[d])) continue;
      if (edge_faces.count(key(c, d)))
        continue;  // the flipped edge exists already
      const double before = std::min(TriangleQuality(pos[a], pos[b], pos[c]),
                                     TriangleQuality(pos[b], pos[a], pos[d]));
      const double after = std::min(TriangleQuality(pos[a], pos[d], pos[c]),
                                    TriangleQuality(pos[d], pos[b], pos[c]));
      if (after < before + 0.05) continue;
      bool facing = true;
      for (const auto& tri :
           {std::array<int, 3>{a, d, c}, std::array<int, 3>{d, b, c}}) {
        const Vector3d n =
            (pos[tri[1]] - pos[tri[0]]).cross(pos[tri[2]] - pos[tri[0]]);
        Vector3d g;
        grid.Sample((pos[tri[0]] + pos[tri[1]] + pos[tri[2]]) / 3.0, &g);
        if (n.dot(g) < 0.5 * n.norm() * g.norm()) facing = false;
      }
      if (!facing) continue;
      faces[f1] = {a, d, c};
      faces[f2] = {d, b, c};
      touched[f1] = touched[f2] = 1;
      ++flips;
    }
    if (flips == 0) break;
  }
}

// ---------------------------------------------------------------------------
// Full mesh: mirror the half mesh, relax tangentially, keep exact symmetry.

struct FullMesh {
  Eigen::Matrix3Xd vertices;
  Eigen::Matrix3Xi faces;
  std::vector<int> mirror;  // mirror[v] = vertex at (-x, y, z)
  std::vector<char> seam;
};

FullMesh MirrorHalfMesh(const HalfMesh& half) {
  const int nh = static_cast<int>(half.vertices.size());
  std::vector<int> mirror_index(nh);
  int next = nh;
  for (int v = 0; v < nh; ++v) mirror_index[v] = half.seam[v] ? v : next++;
  FullMesh full;
  full.vertices.resize(3, next);
  full.mirror.resize(next);
  full.seam.assign(next, 0);
  for (int v = 0; v < nh; ++v) {
    full.vertices.col(v) = half.vertices[v];
    full.vertices.col(mirror_index[v]) = Mirror(half.vertices[v]);
    full.mirror[v] = mirror_index[v];
    full.mirror[mirror_index[v]] = v;
    full.seam[v] = half.seam[v];
    if (half.seam[v]) full.vertices(0, v) = 0.0;
  }
  const int nf = static_cast<int>(half.faces.size());
  full.faces.resize(3, 2 * nf);
  for (int f = 0; f < nf; ++f) {
    const auto& tri = half.faces[f];
    full.faces.col(f) << tri[0], tri[1], tri[2];
    full.faces.col(nf + f) << mirror_index[tri[0]], mirror_index[tri[2]],
        mirror_index[tri[1]];
  }
  return full;
}

void RelaxMesh(const FieldGrid& grid, int iterations, FullMesh* mesh) {
  const int nv = static_cast<int>(mesh->vertices.cols());
  const auto neighbours = VertexNeighbours(nv, mesh->faces);
  const double min_x = 0.02 * grid.spacing();
  for (int iter = 0; iter < iterations; ++iter) {
    const Eigen::Matrix3Xd normals = VertexNormals(mesh->vertices, mesh->faces);
    Eigen::Matrix3Xd next = mesh->vertices;
    for (int v = 0; v < nv; ++v) {
      // Primary copies (the half mesh: seam vertices and their x > 0
      // partners have mirror[v] >= v); the others are their mirror images.
      if (mesh->mirror[v] < v) continue;
      const bool seam = mesh->seam[v] != 0;
      Vector3d centre = Vector3d::Zero();
      for (const int u : neighbours[v]) centre += mesh->vertices.col(u);
      centre /= static_cast<double>(neighbours[v].size());
      Vector3d delta = centre - mesh->vertices.col(v);
      const Vector3d n = normals.col(v);
      delta -= delta.dot(n) * n;
      Vector3d p = mesh->vertices.col(v) + 0.5 * delta;
      if (seam) p.x() = 0.0;
      grid.Project(&p, seam);
      p.x() =
          seam ? 0.0 : std::max(p.x(), min_x);  // never cross the mirror plane
      next.col(v) = p;
      next.col(mesh->mirror[v]) = Mirror(p);
      if (seam) next(0, v) = 0.0;
    }
    mesh->vertices = next;
  }
}

// ---------------------------------------------------------------------------
// Attachment of each vertex to nearby primitives (for shape and skinning).

struct Attachment {
  int primitive;
  double weight;
  PrimitiveCoords coords;
};

std::vector<std::vector<Attachment>> AttachVertices(
    const Eigen::Matrix3Xd& vertices,
    const std::vector<Primitive>& prims,
    double radius) {
  std::vector<std::vector<Attachment>> result(vertices.cols());
  std::vector<double> f(prims.size());
  std::vector<PrimitiveCoords> coords(prims.size());
  for (Eigen::Index v = 0; v < vertices.cols(); ++v) {
    double fmin = std::numeric_limits<double>::max();
    for (size_t i = 0; i < prims.size(); ++i) {
      f[i] = PrimitiveField(prims[i], vertices.col(v), &coords[i]);
      fmin = std::min(fmin, f[i]);
    }
    double total = 0.0;
    for (size_t i = 0; i < prims.size(); ++i) {
      const double x = (f[i] - fmin) / radius;
      if (x > 6.0) continue;
      const double w = std::exp(-x);
      result[v].push_back({static_cast<int>(i), w, coords[i]});
      total += w;
    }
    for (Attachment& att : result[v]) att.weight /= total;
  }
  return result;
}

Eigen::Matrix3Xd DeformVertices(
    const std::vector<std::vector<Attachment>>& attachments,
    const std::vector<Primitive>& prims) {
  Eigen::Matrix3Xd out(3, attachments.size());
  for (size_t v = 0; v < attachments.size(); ++v) {
    Vector3d p = Vector3d::Zero();
    for (const Attachment& att : attachments[v]) {
      p += att.weight * PrimitivePoint(prims[att.primitive], att.coords);
    }
    out.col(static_cast<Eigen::Index>(v)) = p;
  }
  return out;
}

// ---------------------------------------------------------------------------
// Skinning weights.

std::array<std::array<int, kNumCoreJoints>, kNumCoreJoints> TreeDistances() {
  std::array<std::array<int, kNumCoreJoints>, kNumCoreJoints> dist;
  std::vector<std::vector<int>> adjacency(kNumCoreJoints);
  for (int j = 1; j < kNumCoreJoints; ++j) {
    adjacency[j].push_back(kSmplParents[j]);
    adjacency[kSmplParents[j]].push_back(j);
  }
  for (int s = 0; s < kNumCoreJoints; ++s) {
    dist[s].fill(-1);
    dist[s][s] = 0;
    std::vector<int> queue = {s};
    for (size_t q = 0; q < queue.size(); ++q) {
      for (const int u : adjacency[queue[q]]) {
        if (dist[s][u] < 0) {
          dist[s][u] = dist[s][queue[q]] + 1;
          queue.push_back(u);
        }
      }
    }
  }
  return dist;
}

/// +1 for joints of the left limbs, -1 for the right, 0 on the midline.
int JointSide(int joint) {
  switch (joint) {
    case kLeftHip:
    case kLeftKnee:
    case kLeftAnkle:
    case kLeftFoot:
    case kLeftCollar:
    case kLeftShoulder:
    case kLeftElbow:
    case kLeftWrist:
    case kLeftHand:
      return 1;
    case kRightHip:
    case kRightKnee:
    case kRightAnkle:
    case kRightFoot:
    case kRightCollar:
    case kRightShoulder:
    case kRightElbow:
    case kRightWrist:
    case kRightHand:
      return -1;
    default:
      return 0;
  }
}

Eigen::SparseMatrix<double, Eigen::RowMajor> ComputeSkinningWeights(
    const Eigen::Matrix3Xd& vertices,
    const Eigen::Matrix3Xi& faces,
    const std::vector<Primitive>& prims) {
  const int nv = static_cast<int>(vertices.cols());
  static const auto kDist = TreeDistances();
  // Joints a vertex owned by `dominant` may follow: within two steps of the
  // kinematic tree and never a limb of the other side (the thighs touch near
  // the crotch, the knees nearly do).
  const auto compatible = [](int dominant, int joint) {
    return kDist[dominant][joint] <= 2 &&
           JointSide(dominant) * JointSide(joint) >= 0;
  };
  const auto attachments = AttachVertices(vertices, prims, 0.015);
  Eigen::MatrixXd w = Eigen::MatrixXd::Zero(nv, kNumCoreJoints);
  std::vector<std::pair<int, double>> owners;
  for (int v = 0; v < nv; ++v) {
    // The dominant joint: main owner of the closest primitive.
    const Attachment* closest = &attachments[v].front();
    for (const Attachment& att : attachments[v]) {
      if (att.weight > closest->weight) closest = &att;
    }
    PrimitiveOwners(prims[closest->primitive], closest->coords.t, &owners);
    const int dominant = std::max_element(owners.begin(),
                                          owners.end(),
                                          [](const auto& x, const auto& y) {
                                            return x.second < y.second;
                                          })
                             ->first;
    for (const Attachment& att : attachments[v]) {
      PrimitiveOwners(prims[att.primitive], att.coords.t, &owners);
      for (const auto& [joint, share] : owners) {
        if (compatible(dominant, joint)) w(v, joint) += att.weight * share;
      }
    }
  }
  // Diffuse along the mesh (never across empty space): smooth transitions
  // over a few centimetres around each joint.
  const auto neighbours = VertexNeighbours(nv, faces);
  for (int iter = 0; iter < 6; ++iter) {
    Eigen::MatrixXd next(nv, kNumCoreJoints);
    for (int v = 0; v < nv; ++v) {
      Eigen::RowVectorXd mean = Eigen::RowVectorXd::Zero(kNumCoreJoints);
      for (const int u : neighbours[v]) mean += w.row(u);
      mean /= static_cast<double>(std::max<size_t>(1, neighbours[v].size()));
      next.row(v) = 0.5 * w.row(v) + 0.5 * mean;
    }
    w = next;
  }
  std::vector<Eigen::Triplet<double>> triplets;
  for (int v = 0; v < nv; ++v) {
    int best = 0;
    for (int j = 1; j < kNumCoreJoints; ++j) {
      if (w(v, j) > w(v, best)) best = j;
    }
    std::vector<std::pair<double, int>> ranked;
    for (int j = 0; j < kNumCoreJoints; ++j) {
      if (w(v, j) > 0.01 && compatible(best, j))
        ranked.emplace_back(w(v, j), j);
    }
    std::sort(ranked.begin(), ranked.end(), [](const auto& x, const auto& y) {
      return x.first != y.first ? x.first > y.first : x.second < y.second;
    });
    if (ranked.size() > 4) ranked.resize(4);
    double total = 0.0;
    for (const auto& r : ranked) total += r.first;
    for (const auto& r : ranked)
      triplets.emplace_back(v, r.second, r.first / total);
  }
  Eigen::SparseMatrix<double, Eigen::RowMajor> weights(nv, kNumCoreJoints);
  weights.setFromTriplets(triplets.begin(), triplets.end());
  weights.makeCompressed();
  return weights;
}

// ---------------------------------------------------------------------------
// Joint regressor: for each joint, non-negative weights (summing to 1) on a
// ring of vertices around the joint that reproduce the joint exactly.

/// Min ||w - uniform||^2 s.t. sum w = 1, sum w v = target, w >= 0 (active set
/// on the equality-constrained closed form). Returns false if no
/// non-negative exact solution was found.
bool SolveRingWeights(const Eigen::Matrix3Xd& points,
                      const Vector3d& target,
                      std::vector<double>* weights) {
  const int n = static_cast<int>(points.cols());
  std::vector<int> active(n);
  std::iota(active.begin(), active.end(), 0);
  for (int iter = 0; iter < 100 && active.size() >= 4; ++iter) {
    const int m = static_cast<int>(active.size());
    Eigen::MatrixXd a(4, m);
    for (int q = 0; q < m; ++q) {
      a.block<3, 1>(0, q) = points.col(active[q]);
      a(3, q) = 1.0;
    }
    Eigen::Vector4d b;
    b << target, 1.0;
    const Eigen::VectorXd w0 = Eigen::VectorXd::Constant(m, 1.0 / m);
    const Eigen::Matrix4d gram = a * a.transpose();
    const Eigen::Vector4d lambda = gram.ldlt().solve(b - a * w0);
    const Eigen::VectorXd w = w0 + a.transpose() * lambda;
    if ((a * w - b).norm() > 1e-9) return false;
    if (w.minCoeff() >= 0.0) {
      weights->assign(n, 0.0);
      for (int q = 0; q < m; ++q) (*weights)[active[q]] = w(q);
      return true;
    }
    std::vector<int> keep;
    for (int q = 0; q < m; ++q) {
      if (w(q) > 0.0) keep.push_back(active[q]);
    }
    active = std::move(keep);
  }
  return false;
}

Eigen::SparseMatrix<double, Eigen::RowMajor> ComputeJointRegressor(
    const Eigen::Matrix3Xd& vertices,
    const Eigen::Matrix3Xd& joints,
    double length_scale) {
  struct RingSpec {
    Vector3d axis;
    double radius;
  };
  const Vector3d ux = Vector3d::UnitX();
  const Vector3d uy = Vector3d::UnitY();
  const Vector3d uz = Vector3d::UnitZ();
  std::array<RingSpec, kNumCoreJoints> specs;
  auto leg_axis = [&](int hip, int ankle) {
    return Vector3d(joints.col(hip) - joints.col(ankle)).normalized();
  };
  specs[kPelvis] = {uz, 0.25};
  specs[kSpine1] = {uz, 0.25};
  specs[kSpine2] = {uz, 0.25};
  specs[kSpine3] = {uz, 0.25};
  specs[kNeck] = {uz, 0.09};
  specs[kHead] = {uz, 0.12};
  for (const int side : {0, 1}) {
    const int hip = side == 0 ? kLeftHip : kRightHip;
    const int knee = side == 0 ? kLeftKnee : kRightKnee;
    const int ankle = side == 0 ? kLeftAnkle : kRightAnkle;
    const int foot = side == 0 ? kLeftFoot : kRightFoot;
    const int collar = side == 0 ? kLeftCollar : kRightCollar;
    const int shoulder = side == 0 ? kLeftShoulder : kRightShoulder;
    const int elbow = side == 0 ? kLeftElbow : kRightElbow;
    const int wrist = side == 0 ? kLeftWrist : kRightWrist;
    const int hand = side == 0 ? kLeftHand : kRightHand;
    specs[hip] = {uz, 0.13};
    specs[knee] = {leg_axis(hip, ankle), 0.09};
    specs[ankle] = {uz, 0.07};
    specs[foot] = {uy, 0.07};
    specs[collar] = {ux, 0.11};
    specs[shoulder] = {ux, 0.09};
    specs[elbow] = {ux, 0.07};
    specs[wrist] = {ux, 0.06};
    specs[hand] = {ux, 0.06};
  }
  std::vector<Eigen::Triplet<double>> triplets;
  for (int j = 0; j < kNumCoreJoints; ++j) {
    const Vector3d centre = joints.col(j);
    const RingSpec& spec = specs[j];
    const double radius = spec.radius * length_scale;
    bool solved = false;
    for (double slab = 0.006 * length_scale; slab < 0.1 && !solved;
         slab *= 1.4) {
      std::vector<int> ids;
      for (Eigen::Index v = 0; v < vertices.cols(); ++v) {
        const Vector3d r = vertices.col(v) - centre;
        if (std::abs(r.dot(spec.axis)) < slab && r.norm() < radius) {
          ids.push_back(static_cast<int>(v));
        }
      }
      if (ids.size() < 12) continue;
      Eigen::Matrix3Xd points(3, ids.size());
      for (size_t q = 0; q < ids.size(); ++q)
        points.col(q) = vertices.col(ids[q]);
      std::vector<double> w;
      if (!SolveRingWeights(points, centre, &w)) continue;
      for (size_t q = 0; q < ids.size(); ++q) {
        if (w[q] > 0.0) triplets.emplace_back(j, ids[q], w[q]);
      }
      solved = true;
    }
    if (!solved) {
      throw InternalError(fmt::format(
          "procedural body: no vertex ring reproduces joint {} ({})",
          j,
          CoreJointNames()[j]));
    }
  }
  Eigen::SparseMatrix<double, Eigen::RowMajor> regressor(kNumCoreJoints,
                                                         vertices.cols());
  regressor.setFromTriplets(triplets.begin(), triplets.end());
  regressor.makeCompressed();
  return regressor;
}

/// Every undirected edge in exactly two faces with opposite orientation.
void CheckClosedManifold(const Eigen::Matrix3Xi& faces) {
  std::unordered_map<uint64_t, int> directed;
  directed.reserve(faces.cols() * 3);
  for (Eigen::Index f = 0; f < faces.cols(); ++f) {
    for (int e = 0; e < 3; ++e) {
      const uint64_t a = static_cast<uint32_t>(faces(e, f));
      const uint64_t b = static_cast<uint32_t>(faces((e + 1) % 3, f));
      SOMA_CHECK(a != b) << "degenerate face " << f;
      const int count = ++directed[(a << 32) | b];
      SOMA_CHECK_EQ(count, 1)
          << "directed edge used twice (non-manifold or flipped face)";
    }
  }
  for (const auto& [key, count] : directed) {
    const uint64_t reverse = (key << 32) | (key >> 32);
    SOMA_CHECK(directed.count(reverse) == 1)
        << "open edge (hole) in the procedural mesh";
  }
}

}  // namespace

void ProceduralBodyOptions::Validate() const {
  auto fail = [](const std::string& key,
                 const std::string& value,
                 const std::string& rule) {
    throw ConfigError(
        fmt::format("Invalid configuration. procedural_body.{} = {}. Violated "
                    "constraint: {}",
                    key,
                    value,
                    rule));
  };
  if (!(grid_spacing >= 0.005 && grid_spacing <= 0.014)) {
    fail("grid_spacing",
         fmt::format("{}", grid_spacing),
         "0.005 <= grid_spacing <= 0.014");
  }
  if (target_vertices < 3000 || target_vertices > 10000) {
    fail("target_vertices",
         fmt::format("{}", target_vertices),
         "3000 <= target_vertices <= 10000");
  }
  if (num_betas < 10 || num_betas > kNumProceduralShapeComponents) {
    fail("num_betas",
         fmt::format("{}", num_betas),
         fmt::format("10 <= num_betas <= {}", kNumProceduralShapeComponents));
  }
  if (relax_iterations < 0 || relax_iterations > 50) {
    fail("relax_iterations",
         fmt::format("{}", relax_iterations),
         "0 <= relax_iterations <= 50");
  }
  if (!(blend_radius >= 0.004 && blend_radius <= 0.03)) {
    fail("blend_radius",
         fmt::format("{}", blend_radius),
         "0.004 <= blend_radius <= 0.03");
  }
}

const std::vector<ProceduralShapeComponent>& ProceduralShapeComponents() {
  static const std::vector<ProceduralShapeComponent>* const kComponents =
      new std::vector<ProceduralShapeComponent>{
          {"stature",
           "stature [m]",
           kStatureSd,
           "ANSUR II (Gordon et al. 2014): men 1756 +- 69 mm, women 1629 +- 64 "
           "mm; pooled SD "
           "with the sex difference 90 mm"},
          {"girth",
           "overall girth multiplier",
           0.10,
           "ANSUR II waist circumference CV ~11-12%, chest ~8%"},
          {"leg_length",
           "hip height / stature multiplier",
           0.023,
           "ANSUR II crotch height / stature: SD ~0.011 on a mean of ~0.47"},
          {"arm_length",
           "upper arm + forearm multiplier",
           0.025,
           "ANSUR II acromion-radiale and radiale-stylion lengths, "
           "stature-adjusted CV ~2.5%"},
          {"shoulder_width",
           "biacromial breadth multiplier",
           0.040,
           "ANSUR II biacromial breadth CV ~4.6%"},
          {"hip_width",
           "hip breadth multiplier",
           0.050,
           "ANSUR II hip breadth CV ~6%"},
          {"belly",
           "abdominal depth multiplier",
           0.12,
           "ANSUR II waist depth CV ~14%"},
          {"head_size",
           "head size multiplier",
           0.030,
           "ANSUR II head circumference CV ~2.8%"},
          {"sex",
           "dimorphism coordinate (-1 female, +1 male)",
           1.0,
           "half the ANSUR II men-women differences of stature-normalised "
           "breadths and girths"},
          {"limb_girth",
           "arm and leg girth multiplier",
           0.08,
           "ANSUR II biceps, forearm, thigh and calf circumference CV ~8-10%"},
          {"extremity_size",
           "hand and foot size multiplier",
           0.040,
           "ANSUR II foot length CV ~4.7%, hand length ~4.5%"},
          {"chest_depth",
           "chest depth multiplier",
           0.08,
           "ANSUR II chest depth CV ~9%"},
      };
  return *kComponents;
}

ProceduralAnthropometry ProceduralAnthropometryFromBetas(
    const Eigen::VectorXd& betas) {
  if (betas.size() > kNumProceduralShapeComponents) {
    throw ShapeError(fmt::format("procedural body: {} betas given, at most {}",
                                 betas.size(),
                                 kNumProceduralShapeComponents));
  }
  const auto& comps = ProceduralShapeComponents();
  auto beta = [&](int k) { return k < betas.size() ? betas(k) : 0.0; };
  ProceduralAnthropometry an;
  an.stature = kMeanStature + comps[0].stddev * beta(0);
  an.girth = 1.0 + comps[1].stddev * beta(1);
  an.leg_length = 1.0 + comps[2].stddev * beta(2);
  an.arm_length = 1.0 + comps[3].stddev * beta(3);
  an.shoulder_width = 1.0 + comps[4].stddev * beta(4);
  an.hip_width = 1.0 + comps[5].stddev * beta(5);
  an.belly = 1.0 + comps[6].stddev * beta(6);
  an.head_size = 1.0 + comps[7].stddev * beta(7);
  an.sex = comps[8].stddev * beta(8);
  an.limb_girth = 1.0 + comps[9].stddev * beta(9);
  an.extremity_size = 1.0 + comps[10].stddev * beta(10);
  an.chest_depth = 1.0 + comps[11].stddev * beta(11);
  return an;
}

Eigen::Matrix3Xd ProceduralSkeletonJoints(
    const ProceduralAnthropometry& anthropometry) {
  return BuildGeometry(anthropometry).joints;
}

BodyModel MakeProceduralBody(const ProceduralBodyOptions& options) {
  options.Validate();
  const ProceduralAnthropometry mean;
  const BodyGeometry geometry = BuildGeometry(mean);

  // Surface.
  const FieldGrid grid(
      geometry.primitives, options.grid_spacing, options.blend_radius);
  HalfMesh half = MarchingTetrahedra(grid);
  {
    Decimator decimator(&half, &grid);
    decimator.Run(options.target_vertices);
    decimator.Compact();
  }
  ImproveByFlips(grid, &half);
  FullMesh mesh = MirrorHalfMesh(half);
  RelaxMesh(grid, options.relax_iterations, &mesh);
  CheckClosedManifold(mesh.faces);

  BodyModel body;
  body.name = "procedural";
  body.template_vertices = mesh.vertices;
  body.faces = mesh.faces;
  body.joint_names = CoreJointNames();
  body.parents.assign(std::begin(kSmplParents), std::end(kSmplParents));

  // Shape space: linearised displacement fields of the attached vertices.
  const auto attachments =
      AttachVertices(mesh.vertices, geometry.primitives, 0.010);
  const int nv = static_cast<int>(mesh.vertices.cols());
  body.shape_dirs.resize(3 * static_cast<Eigen::Index>(nv), options.num_betas);
  for (int k = 0; k < options.num_betas; ++k) {
    Eigen::VectorXd unit = Eigen::VectorXd::Zero(kNumProceduralShapeComponents);
    unit(k) = 1.0;
    const Eigen::Matrix3Xd plus = DeformVertices(
        attachments,
        BuildGeometry(ProceduralAnthropometryFromBetas(unit)).primitives);
    const Eigen::Matrix3Xd minus = DeformVertices(
        attachments,
        BuildGeometry(ProceduralAnthropometryFromBetas(-unit)).primitives);
    const Eigen::Matrix3Xd dir = 0.5 * (plus - minus);
    body.shape_dirs.col(k) =
        Eigen::Map<const Eigen::VectorXd>(dir.data(), dir.size());
  }
  body.beta_stddev = Eigen::VectorXd::Ones(options.num_betas);

  body.skinning_weights =
      ComputeSkinningWeights(mesh.vertices, mesh.faces, geometry.primitives);
  body.joint_regressor =
      ComputeJointRegressor(mesh.vertices, geometry.joints, 1.0);
  body.Validate();
  return body;
}

}  // namespace soma
