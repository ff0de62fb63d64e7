#include "framework/body/procedural_body.h"

#include "framework/body/mesh_builder.h"
#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <utility>

namespace soma {
namespace {

using Eigen::Vector3d;
using internal::MakeEllipsoid;
using internal::MakeSweep;
using internal::Mirror;
using internal::Primitive;
using internal::PrimitiveCoords;
using internal::PrimitiveField;
using internal::PrimitivePoint;
using internal::Section;

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
// Ownership of the body-part primitives (their `owner` joints).

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
  const internal::SymmetricMesh mesh =
      internal::MeshPrimitives(geometry.primitives,
                               {.grid_spacing = options.grid_spacing,
                                .blend_radius = options.blend_radius,
                                .target_vertices = options.target_vertices,
                                .relax_iterations = options.relax_iterations});

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
