#include "framework/body/marker_layout.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/json.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <map>
#include <set>

namespace soma {
namespace {

// ---------------------------------------------------------------------------
// Anatomical placement rules (rest T-pose frame: +X left, -Y forward, +Z up).
// The skin point is where the ray from lerp(joint_a, joint_b, t) along `dir`
// leaves the body (SkinVertexAlongRay: the nearest exit face); the marker
// vertex is the hit triangle's nearest vertex (Placement::kExtreme rules take
// the cross-section's vertex furthest along `dir` instead). `mirror` rules
// also define the other side's label (first letter L <-> R, joints mirrored,
// x negated).

/// Pseudo joint after the core joints: the centre of the cranium, measured on
/// the skin (HeadCentre()). Head rules cast their rays from it.
constexpr int kHeadCentre = kNumCoreJoints;
constexpr int kNumRuleJoints = kNumCoreJoints + 1;

/// How a rule finds its skin point. kRay: where the ray from
/// lerp(joint_a, joint_b, t) along `dir` leaves the body. kExtreme: the skin
/// vertex furthest along `dir` within the cross-section of the segment at
/// lerp(joint_a, joint_b, t) (ExtremeSkinVertex), for landmarks defined as
/// the most prominent point of a cross-section (the metatarsal heads).
enum class Placement { kRay, kExtreme };

struct Rule {
  const char* label;
  int joint_a;
  int joint_b;
  double t;
  double dx, dy, dz;
  bool mirror;
  const char* anatomy;
  Placement placement = Placement::kRay;
};

constexpr bool M = true;
constexpr bool C = false;

// Head rules start at the head centre measured on the skin (kHeadCentre,
// HeadCentre()), not at a point extrapolated from the neck through the head
// joint: that extrapolation (t = 1.9, fine on SMPL-like bodies) lands in the
// face of the MakeHuman body, whose neck leans forward (head joint 4 cm in
// front of the neck joint), and put LFHD/RFHD on the brows 0.095 m apart
// (captures: 0.159 m).
// LFHD/LBHD directions follow the real headband (`soma realism`, HDM05 + CMU
// medians): the front pair is wide (LFHD-RFHD 0.159 m: near the temples, 39
// degrees forward of lateral, low on the forehead), the back pair narrower
// (LBHD-RBHD 0.118 m: 58 degrees back of lateral) and the sides long
// (LFHD-LBHD 0.140-0.150 m). Was (1, -0.9, 0.45) / (1, 0.9, 0.35): a back pair
// as wide as the front pair and 0.13 m sides. Real head markers sit on a
// headband over hair, further off the skin than kDefaultDistanceFromSkin, so
// bare-skin bodies stay a few percent short (procedural -6%, MakeHuman -8%).
// clang-format off
const Rule kRules[] = {
    // Head and neck.
    {"LFHD", kHeadCentre, kHeadCentre, 0.0, 1.0, -0.8, 0.1, M, "left temple, front of the headband"},
    {"LBHD", kHeadCentre, kHeadCentre, 0.0, 1.0, 1.6, 0.15, M, "left back of the head, headband"},
    {"ARIEL", kHeadCentre, kHeadCentre, 0.0, 0.0, 0.0, 1.0, C, "vertex (top of the head)"},
    {"FHEAD", kHeadCentre, kHeadCentre, 0.0, 0.0, -1.0, 0.55, C, "mid forehead"},
    {"BHEAD", kHeadCentre, kHeadCentre, 0.0, 0.0, 1.0, 0.3, C, "back of the head, midline"},
    {"CHIN", kNeck, kHead, 1.2, 0.0, -1.0, -0.5, C, "chin"},
    {"LNECK", kNeck, kHead, 0.45, 1.0, 0.0, 0.0, M, "left side of the neck"},
    // Trunk.
    {"C7", kSpine3, kNeck, 1.0, 0.0, 1.0, 0.25, C, "spinous process of C7"},
    {"T8", kSpine2, kSpine3, 0.9, 0.0, 1.0, 0.0, C, "spinous process of T8"},
    {"T10", kSpine2, kSpine3, 0.35, 0.0, 1.0, 0.0, C, "spinous process of T10"},
    {"CLAV", kSpine3, kNeck, 0.78, 0.0, -1.0, 0.1, C, "jugular notch"},
    {"STRN", kSpine2, kSpine3, 0.75, 0.0, -1.0, 0.0, C, "xiphoid process"},
    {"RBAC", kSpine3, kRightShoulder, 0.45, -0.15, 1.0, 0.0, M, "middle of the right scapula"},
    {"LSCAP", kSpine2, kSpine3, 0.6, 0.8, 1.0, 0.0, M, "inferior angle of the left scapula"},
    {"LSHO", kLeftCollar, kLeftShoulder, 0.8, 0.0, 0.0, 1.0, M, "left acromion"},
    {"LBSH", kLeftCollar, kLeftShoulder, 0.7, 0.0, 1.0, 0.5, M, "back of the left shoulder"},
    {"LFSH", kLeftCollar, kLeftShoulder, 0.7, 0.0, -1.0, 0.5, M, "front of the left shoulder"},
    {"LCHST", kSpine3, kNeck, 0.0, 0.5, -1.0, 0.15, M, "left chest"},
    {"LBLLY", kSpine1, kSpine2, 0.5, 0.6, -1.0, 0.0, M, "left belly"},
    {"MFWT", kPelvis, kSpine1, 0.0, 0.0, -1.0, -0.15, C, "front waist, midline"},
    {"SACR", kPelvis, kSpine1, 0.0, 0.0, 1.0, 0.05, C, "sacrum"},
    {"LFWT", kPelvis, kSpine1, 0.0, 1.4, -1.0, 0.0, M, "left anterior superior iliac spine"},
    {"LBWT", kPelvis, kSpine1, 0.0, 0.45, 1.0, 0.15, M, "left posterior superior iliac spine"},
    {"LBUM", kLeftHip, kLeftKnee, 0.12, 0.15, 1.0, 0.0, M, "left buttock"},
    // Legs.
    // LTHI: Plug-in Gait puts it on the lower lateral 1/3 of the thigh, but
    // the CMU/HDM05 captures place it higher: the median LTHI-LKNE distance
    // is 0.17-0.34 m (mean 0.27 m, about 2/3 of the thigh above the knee), so the
    // rule uses the upper-middle lateral thigh, 35% of the way hip -> knee
    // (was 55%, which gave 0.19 m, -31% against the captures; `soma realism`).
    // The low lateral thigh is LTHILO.
    {"LTHI", kLeftHip, kLeftKnee, 0.35, 1.0, -0.35, 0.0, M, "lateral left thigh, upper-middle (CMU/HDM05 placement)"},
    {"LFTHI", kLeftHip, kLeftKnee, 0.45, 0.0, -1.0, 0.0, M, "front of the left thigh"},
    {"LBTHI", kLeftHip, kLeftKnee, 0.5, 0.0, 1.0, 0.0, M, "back of the left thigh"},
    {"LTHILO", kLeftHip, kLeftKnee, 0.8, 1.0, 0.0, 0.0, M, "lateral left thigh, low"},
    {"LKNE", kLeftKnee, kLeftAnkle, 0.0, 1.0, 0.0, 0.0, M, "left lateral femoral epicondyle"},
    {"LKNI", kLeftKnee, kLeftAnkle, 0.0, -1.0, 0.0, 0.0, M, "left medial femoral epicondyle"},
    {"LSHN", kLeftKnee, kLeftAnkle, 0.4, 0.3, -1.0, 0.0, M, "left shin (tibia, front)"},
    {"LTIB", kLeftKnee, kLeftAnkle, 0.55, 1.0, -0.3, 0.0, M, "lateral left shank"},
    {"LTIBIN", kLeftKnee, kLeftAnkle, 0.55, -1.0, -0.3, 0.0, M, "medial left shank"},
    {"LCLF", kLeftKnee, kLeftAnkle, 0.3, 0.2, 1.0, 0.0, M, "left calf"},
    {"LANK", kLeftAnkle, kLeftFoot, 0.0, 1.0, 0.0, 0.0, M, "left lateral malleolus"},
    {"LHEE", kLeftAnkle, kLeftFoot, 0.0, 0.0, 1.0, -0.45, M, "left calcaneus (heel)"},
    // Forefoot. The foot joint sits at the ball of the foot over the third
    // metatarsal (on MakeHuman it is the rig's toe-3-1 joint, the third MTP
    // joint), so LTOE tilts medially from it onto the dorsum over the second
    // metatarsal head. LMT5 is the lateral-most skin point of the forefoot
    // 10% of the ankle -> foot joint distance (~1.3 cm) behind the foot joint:
    // the metatarsal heads lie on an oblique line, the fifth behind the
    // third. A ray from the foot joint (the old rule, t = 1.0) left the
    // MakeHuman foot, whose toes are separate, through the side of the third
    // toe and put LMT5 7 mm from LTOE; the captures have 0.066-0.085 m
    // (HDM05/CMU per-side medians, mean 0.077 m).
    {"LTOE", kLeftAnkle, kLeftFoot, 1.05, -0.6, -0.2, 1.0, M, "left second metatarsal head"},
    {"LMT5", kLeftAnkle, kLeftFoot, 0.9, 1.0, 0.0, 0.0, M, "left fifth metatarsal head", Placement::kExtreme},
    {"LMT1", kLeftAnkle, kLeftFoot, 1.0, -1.0, 0.0, 0.2, M, "left first metatarsal head"},
    {"LFOOT", kLeftAnkle, kLeftFoot, 0.55, 0.0, 0.0, 1.0, M, "dorsum of the left mid-foot"},
    // Arms (T-pose, palms down: lateral = +Z, thumb = -Y).
    // LUPA: Vicon/CMU guides put the upper-arm marker on the lateral upper
    // arm between the shoulder and elbow markers; mid-way (was 55% towards
    // the elbow; real LUPA-LELB medians 0.11-0.23 m, mean 0.166 m).
    {"LUPA", kLeftShoulder, kLeftElbow, 0.5, 0.0, 0.35, 1.0, M, "lateral left upper arm, mid-way"},
    {"LBCEP", kLeftShoulder, kLeftElbow, 0.5, 0.0, -1.0, 0.1, M, "left biceps"},
    {"LELB", kLeftElbow, kLeftWrist, 0.0, 0.0, 0.6, 1.0, M, "left lateral humeral epicondyle"},
    {"LELBIN", kLeftElbow, kLeftWrist, 0.0, 0.0, 0.3, -1.0, M, "left medial humeral epicondyle"},
    // LFRM: the CMU/Vicon forearm marker sits on the proximal, fleshy part
    // of the lateral forearm, ~1/3 of the way elbow -> wrist (was 1/2,
    // which put it 0.14 m from LWRB; the left-side captures have 0.17-0.18 m).
    {"LFRM", kLeftElbow, kLeftWrist, 0.35, 0.0, 0.3, 1.0, M, "lateral left forearm, proximal third"},
    {"LFRMIN", kLeftElbow, kLeftWrist, 0.5, 0.0, -0.3, -1.0, M, "medial left forearm"},
    // LWRA/LWRB: thumb- and pinkie-side ends of the CMU/Vicon wrist bar, over
    // the radial and ulnar styloids. The bar holds the markers off the skin:
    // built-in layouts give the four wrist labels their own marker type
    // (kWristMarkerType, BuiltinMarkerType) with kWristBarDistanceFromSkin
    // (marker_layout.h), which turns the skin points' ~0.07 m into the
    // captures' ~0.14 m LWRA-LWRB.
    {"LWRA", kLeftWrist, kLeftHand, 0.0, 0.0, -1.0, 0.0, M, "left radial styloid (thumb side)"},
    {"LWRB", kLeftWrist, kLeftHand, 0.0, 0.0, 1.0, 0.0, M, "left ulnar styloid (pinkie side)"},
    {"LFIN", kLeftWrist, kLeftHand, 1.0, 0.0, 0.0, 1.0, M, "left second/third metacarpal head"},
    {"LTHMB", kLeftWrist, kLeftHand, 0.6, 0.25, -1.0, -0.2, M, "left thumb"},
};
// clang-format on

// clang-format off
constexpr int kMirrorJoint[kNumRuleJoints] = {0,  2,  1,  3,  5,  4,  6,  8,
                                              7,  9,  11, 10, 12, 14, 13, 15,
                                              17, 16, 19, 18, 21, 20, 23, 22,
                                              kHeadCentre};
// clang-format on

struct ResolvedRule {
  std::string label;
  int joint_a, joint_b;
  double t;
  Eigen::Vector3d dir;
  Placement placement;
};

const std::map<std::string, ResolvedRule, std::less<>>& AllRules() {
  static const auto* const kAll = [] {
    auto* rules = new std::map<std::string, ResolvedRule, std::less<>>();
    for (const Rule& r : kRules) {
      const Eigen::Vector3d dir =
          Eigen::Vector3d(r.dx, r.dy, r.dz).normalized();
      (*rules)[r.label] = {
          r.label, r.joint_a, r.joint_b, r.t, dir, r.placement};
      if (r.mirror) {
        std::string other = r.label;
        other[0] = other[0] == 'L' ? 'R' : 'L';
        (*rules)[other] = {other,
                           kMirrorJoint[r.joint_a],
                           kMirrorJoint[r.joint_b],
                           r.t,
                           Eigen::Vector3d(-dir.x(), dir.y(), dir.z()),
                           r.placement};
      }
    }
    return rules;
  }();
  return *kAll;
}

// ---------------------------------------------------------------------------
// Built-in label lists.

const std::vector<std::string>& Cmu41() {
  static const auto* const k = new std::vector<std::string>{
      "LFHD", "RFHD", "LBHD", "RBHD", "C7",   "T10",  "CLAV", "STRN", "RBAC",
      "LSHO", "LUPA", "LELB", "LFRM", "LWRA", "LWRB", "LFIN", "RSHO", "RUPA",
      "RELB", "RFRM", "RWRA", "RWRB", "RFIN", "LFWT", "RFWT", "LBWT", "RBWT",
      "LTHI", "LKNE", "LSHN", "LANK", "LHEE", "LTOE", "LMT5", "RTHI", "RKNE",
      "RSHN", "RANK", "RHEE", "RTOE", "RMT5"};
  return *k;
}

const std::vector<std::string>& Pig39() {
  static const auto* const k = new std::vector<std::string>{
      "LFHD", "RFHD", "LBHD", "RBHD", "C7",   "T10",  "CLAV", "STRN",
      "RBAK", "LSHO", "LUPA", "LELB", "LFRM", "LWRA", "LWRB", "LFIN",
      "RSHO", "RUPA", "RELB", "RFRM", "RWRA", "RWRB", "RFIN", "LASI",
      "RASI", "LPSI", "RPSI", "LTHI", "LKNE", "LTIB", "LANK", "LHEE",
      "LTOE", "RTHI", "RKNE", "RTIB", "RANK", "RHEE", "RTOE"};
  return *k;
}

const std::vector<std::string>& Soma53Extra() {
  static const auto* const k = new std::vector<std::string>{"ARIEL",
                                                            "LELBIN",
                                                            "RELBIN",
                                                            "LKNI",
                                                            "RKNI",
                                                            "LMT1",
                                                            "RMT1",
                                                            "LBSH",
                                                            "RBSH",
                                                            "LFSH",
                                                            "RFSH",
                                                            "SACR"};
  return *k;
}

const std::vector<std::string>& Superset89Extra() {
  static const auto* const k = new std::vector<std::string>{
      "LBCEP",  "RBCEP",  "LFRMIN", "RFRMIN", "LTHMB",  "RTHMB", "LFTHI",
      "RFTHI",  "LBTHI",  "RBTHI",  "LTHILO", "RTHILO", "LCLF",  "RCLF",
      "LTIBIN", "RTIBIN", "LCHST",  "RCHST",  "LBLLY",  "RBLLY", "LNECK",
      "RNECK",  "LSCAP",  "RSCAP",  "LFOOT",  "RFOOT",  "LBUM",  "RBUM",
      "LBAC",   "T8",     "CHIN",   "MFWT",   "BHEAD",  "FHEAD"};
  return *k;
}

std::vector<std::string> Sorted(std::vector<std::string> labels) {
  std::sort(labels.begin(), labels.end());
  labels.erase(std::unique(labels.begin(), labels.end()), labels.end());
  return labels;
}

// ---------------------------------------------------------------------------
// Alias table. "{S}" expands to L and R.

struct AliasTemplate {
  const char* alias;
  const char* canonical;
};

const AliasTemplate kAliasTemplates[] = {
    // Vicon Plug-in Gait -> CMU/HDM05.
    {"{S}ASI", "{S}FWT"},
    {"{S}PSI", "{S}BWT"},
    {"{S}BAK", "{S}BAC"},
    // MoSh++ wrist names -> CMU/HDM05.
    {"{S}IWR", "{S}WRA"},
    {"{S}OWR", "{S}WRB"},
    // Long forms and other vendors (after MoSh++ general_labels_map).
    {"{S}_ANKLE", "{S}ANK"},
    {"{S}_ANK", "{S}ANK"},
    {"{S}_HEEL", "{S}HEE"},
    {"{S}HEL", "{S}HEE"},
    {"{S}_KNEE", "{S}KNE"},
    {"{S}_OUTKNEE", "{S}KNE"},
    {"{S}_INKNEE", "{S}KNI"},
    {"{S}KNEEIN", "{S}KNI"},
    {"{S}_SHIN", "{S}SHN"},
    {"{S}SHIN", "{S}SHN"},
    {"{S}_ELBOW", "{S}ELB"},
    {"{S}_INELBOW", "{S}ELBIN"},
    {"{S}IEL", "{S}ELBIN"},
    {"{S}ILB", "{S}ELBIN"},
    {"{S}_FOREARM", "{S}FRM"},
    {"{S}FRA", "{S}FRM"},
    {"{S}ARM", "{S}FRM"},
    {"{S}_INWRIST", "{S}WRA"},
    {"{S}_OUTWRIST", "{S}WRB"},
    {"{S}_WRIST", "{S}WRB"},
    {"{S}_FIN", "{S}FIN"},
    {"{S}_PINKY", "{S}FIN"},
    {"{S}OHAND", "{S}FIN"},
    {"{S}_THUMB", "{S}THMB"},
    {"{S}IHAND", "{S}THMB"},
    {"{S}_TOETIP", "{S}TOE"},
    {"{S}TOE1", "{S}TOE"},
    {"{S}_PINKYTOE", "{S}MT5"},
    {"{S}_BIGTOE", "{S}MT1"},
    {"{S}HIP", "{S}THI"},
    {"{S}_HIP", "{S}THI"},
    {"{S}_HAM", "{S}THI"},
    {"{S}_F_WAIST", "{S}FWT"},
    {"{S}_FWT", "{S}FWT"},
    {"{S}_B_WAIST", "{S}BWT"},
    {"{S}_BWT", "{S}BWT"},
    {"{S}_F_SHOULDER", "{S}FSH"},
    {"{S}_B_SHOULDER", "{S}BSH"},
    {"{S}BSHO", "{S}BSH"},
    {"{S}_BICEP", "{S}BCEP"},
    {"{S}_TRICEP", "{S}UPA"},
    {"{S}_CALF", "{S}CLF"},
    {"{S}_THIGH", "{S}THILO"},
    {"{S}THIGH", "{S}THILO"},
    {"{S}_UPBACK", "{S}BAC"},
    {"{S}_MIDBACK", "{S}SCAP"},
    // Midline.
    {"HEAD_TOP", "ARIEL"},
    {"TOPBACK", "C7"},
    {"NECK_BASE", "C7"},
    {"CHEST", "CLAV"},
    {"UPTHRX", "CLAV"},
    {"STERNUM", "STRN"},
    {"LOTHRX", "STRN"},
    {"LOBACK", "T10"},
    {"MIDBACK", "T8"},
    {"MID_BACK", "T8"},
};

std::string ExpandSide(std::string_view pattern, char side) {
  std::string out;
  for (size_t i = 0; i < pattern.size(); ++i) {
    if (pattern.substr(i, 3) == "{S}") {
      out.push_back(side);
      i += 2;
    } else {
      out.push_back(pattern[i]);
    }
  }
  return out;
}

const std::map<std::string, std::string, std::less<>>& AliasMap() {
  static const auto* const kMap = [] {
    auto* map = new std::map<std::string, std::string, std::less<>>();
    for (const AliasTemplate& t : kAliasTemplates) {
      const std::string_view alias(t.alias);
      if (alias.find("{S}") == std::string_view::npos) {
        (*map)[t.alias] = t.canonical;
      } else {
        for (const char side : {'L', 'R'}) {
          (*map)[ExpandSide(t.alias, side)] = ExpandSide(t.canonical, side);
        }
      }
    }
    return map;
  }();
  return *kMap;
}

// ---------------------------------------------------------------------------
// JSON helpers.

[[noreturn]] void LayoutError(std::string_view source,
                              std::string_view path,
                              const std::string& message) {
  throw IoError(fmt::format("{}: {}: {}", source, path, message));
}

void RejectUnknownKeys(const Json& object,
                       std::initializer_list<std::string_view> known,
                       std::string_view source,
                       std::string_view path) {
  for (const auto& [key, value] : JsonObject(object)) {
    if (std::find(known.begin(), known.end(), key) == known.end()) {
      std::string expected;
      for (const auto k : known)
        expected += fmt::format("{}{}", expected.empty() ? "" : ", ", k);
      LayoutError(
          source,
          path,
          fmt::format("unknown key \"{}\" (expected {})", key, expected));
    }
  }
}

int ParseVertexId(const Json& value,
                  std::string_view source,
                  const std::string& path) {
  if (!JsonIsInteger(value) || JsonNumber(value) < 0 ||
      JsonNumber(value) >
          static_cast<double>(std::numeric_limits<int>::max())) {
    std::string shown = value.is_number() ? fmt::format("{}", JsonNumber(value))
                                          : std::string(JsonTypeName(value));
    LayoutError(
        source,
        path,
        fmt::format("vertex id must be a non-negative integer, got {}", shown));
  }
  return static_cast<int>(JsonInt(value));
}

// ---------------------------------------------------------------------------
// Ray casting (Moller-Trumbore), for marker placement.

bool RayTriangle(const Eigen::Vector3d& origin,
                 const Eigen::Vector3d& dir,
                 const Eigen::Vector3d& a,
                 const Eigen::Vector3d& b,
                 const Eigen::Vector3d& c,
                 double* t_hit) {
  const Eigen::Vector3d e1 = b - a;
  const Eigen::Vector3d e2 = c - a;
  const Eigen::Vector3d p = dir.cross(e2);
  const double det = e1.dot(p);
  if (std::abs(det) < 1e-14) return false;
  const double inv = 1.0 / det;
  const Eigen::Vector3d s = origin - a;
  const double u = s.dot(p) * inv;
  if (u < 0.0 || u > 1.0) return false;
  const Eigen::Vector3d q = s.cross(e1);
  const double v = dir.dot(q) * inv;
  if (v < 0.0 || u + v > 1.0) return false;
  const double t = e2.dot(q) * inv;
  if (t <= 1e-9) return false;
  *t_hit = t;
  return true;
}

/// The centre of the cranium from the skin: x and y are the centre of the
/// bounding box of the vertices above the head joint (within 0.25 m of it
/// horizontally, so raised hands cannot count), z lies kHeadCentreHeight of
/// the way from the head joint up to the top of the head. Body-independent:
/// the head joint sits at the skull base on SMPL-like bodies and in the upper
/// neck, forward of the neck joint, on MakeHuman.
constexpr double kHeadCentreHeight = 0.4;
constexpr double kHeadCentreRadius = 0.25;

Eigen::Vector3d HeadCentre(const Eigen::Matrix3Xd& vertices,
                           const Eigen::Matrix3Xd& joints,
                           const std::string& body_name) {
  const Eigen::Vector3d head = joints.col(kHead);
  Eigen::Vector3d lo =
      Eigen::Vector3d::Constant(std::numeric_limits<double>::max());
  Eigen::Vector3d hi = -lo;
  int count = 0;
  for (Eigen::Index v = 0; v < vertices.cols(); ++v) {
    const Eigen::Vector3d p = vertices.col(v);
    if (p.z() <= head.z() || (p - head).head<2>().norm() > kHeadCentreRadius) {
      continue;
    }
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
    ++count;
  }
  if (count < 4) {
    throw InternalError(fmt::format(
        "body '{}': no head above the head joint ({:.3f}, {:.3f}, {:.3f}) to "
        "place head markers on",
        body_name,
        head.x(),
        head.y(),
        head.z()));
  }
  return Eigen::Vector3d(0.5 * (lo.x() + hi.x()),
                         0.5 * (lo.y() + hi.y()),
                         head.z() + kHeadCentreHeight * (hi.z() - head.z()));
}

/// Cross-section of a segment for Placement::kExtreme: skin vertices within
/// kExtremeHalfWidth of the plane through the origin perpendicular to the
/// segment's horizontal direction, within kExtremeRadius of the origin (so
/// the other limb never counts) and not above the origin's upper joint.
constexpr double kExtremeHalfWidth = 0.01;
constexpr double kExtremeRadius = 0.08;

/// The vertex of the cross-section at `origin` furthest along `dir`; -1 if
/// the cross-section is empty.
int ExtremeSkinVertex(const Eigen::Vector3d& origin,
                      const Eigen::Vector3d& segment,
                      double max_z,
                      const Eigen::Vector3d& dir,
                      const Eigen::Matrix3Xd& vertices) {
  Eigen::Vector3d normal(segment.x(), segment.y(), 0.0);
  if (normal.norm() < 1e-9) return -1;
  normal.normalize();
  int best = -1;
  double best_along = -std::numeric_limits<double>::max();
  for (Eigen::Index v = 0; v < vertices.cols(); ++v) {
    const Eigen::Vector3d d = vertices.col(v) - origin;
    if (std::abs(d.dot(normal)) > kExtremeHalfWidth ||
        d.norm() > kExtremeRadius || vertices(2, v) > max_z) {
      continue;
    }
    const double along = d.dot(dir);
    if (along > best_along) {
      best_along = along;
      best = static_cast<int>(v);
    }
  }
  return best;
}

int PlaceByRule(const ResolvedRule& rule,
                const Eigen::Matrix3Xd& vertices,
                const Eigen::Matrix3Xi& faces,
                const Eigen::Matrix3Xd& joints,
                const std::string& body_name) {
  const Eigen::Vector3d a = joints.col(rule.joint_a);
  const Eigen::Vector3d b = joints.col(rule.joint_b);
  const Eigen::Vector3d origin = a + rule.t * (b - a);
  const int vertex =
      rule.placement == Placement::kExtreme
          ? ExtremeSkinVertex(
                origin, b - a, std::max(a.z(), b.z()), rule.dir, vertices)
          : SkinVertexAlongRay(origin, rule.dir, vertices, faces);
  if (vertex < 0) {
    throw InternalError(fmt::format(
        "marker {}: the placement {} at ({:.3f}, {:.3f}, "
        "{:.3f}) finds no skin of body '{}'",
        rule.label,
        rule.placement == Placement::kExtreme ? "cross-section" : "ray",
        origin.x(),
        origin.y(),
        origin.z(),
        body_name));
  }
  return vertex;
}

}  // namespace

// ---------------------------------------------------------------------------
// Ray casting.

int SkinVertexAlongRay(const Eigen::Vector3d& origin,
                       const Eigen::Vector3d& dir,
                       const Eigen::Matrix3Xd& vertices,
                       const Eigen::Matrix3Xi& faces) {
  double best_exit_t = std::numeric_limits<double>::max();
  double best_any_t = std::numeric_limits<double>::max();
  Eigen::Index best_exit = -1;
  Eigen::Index best_any = -1;
  for (Eigen::Index f = 0; f < faces.cols(); ++f) {
    const Eigen::Vector3d a = vertices.col(faces(0, f));
    const Eigen::Vector3d b = vertices.col(faces(1, f));
    const Eigen::Vector3d c = vertices.col(faces(2, f));
    double t = 0.0;
    if (!RayTriangle(origin, dir, a, b, c, &t)) continue;
    if (t < best_any_t) {
      best_any_t = t;
      best_any = f;
    }
    // An exit face: its outward normal points along the ray.
    if ((b - a).cross(c - a).dot(dir) > 0.0 && t < best_exit_t) {
      best_exit_t = t;
      best_exit = f;
    }
  }
  const Eigen::Index face = best_exit >= 0 ? best_exit : best_any;
  if (face < 0) return -1;
  const Eigen::Vector3d hit =
      origin + (best_exit >= 0 ? best_exit_t : best_any_t) * dir;
  int best_vertex = faces(0, face);
  for (int k = 1; k < 3; ++k) {
    const int v = faces(k, face);
    if ((vertices.col(v) - hit).squaredNorm() <
        (vertices.col(best_vertex) - hit).squaredNorm()) {
      best_vertex = v;
    }
  }
  return best_vertex;
}

// ---------------------------------------------------------------------------
// MarkerLayout.

void MarkerLayout::Sort() {
  std::stable_sort(
      markers.begin(), markers.end(), [](const Marker& a, const Marker& b) {
        return a.type != b.type ? a.type < b.type : a.label < b.label;
      });
}

std::vector<std::string> MarkerLayout::Labels() const {
  std::vector<std::string> labels;
  labels.reserve(markers.size());
  for (const Marker& m : markers) labels.push_back(m.label);
  return labels;
}

int MarkerLayout::FindLabel(std::string_view label) const {
  for (size_t i = 0; i < markers.size(); ++i) {
    if (markers[i].label == label) return static_cast<int>(i);
  }
  return -1;
}

MarkerLayout ParseMarkerLayout(std::string_view json_text,
                               std::string_view source_name) {
  const Json root = ParseJson(json_text, source_name);
  if (!root.is_object()) {
    LayoutError(source_name,
                "<root>",
                fmt::format("expected an object, got {}", JsonTypeName(root)));
  }
  RejectUnknownKeys(
      root, {"markersets", "surface_model_type"}, source_name, "<root>");
  MarkerLayout layout;
  if (const Json* type = JsonFind(root, "surface_model_type")) {
    if (!type->is_string()) {
      LayoutError(
          source_name,
          "surface_model_type",
          fmt::format("expected a string, got {}", JsonTypeName(*type)));
    }
    layout.surface_model_type = JsonString(*type);
  }
  const Json* sets = JsonFind(root, "markersets");
  if (sets == nullptr)
    LayoutError(source_name, "<root>", "missing key \"markersets\"");
  if (!sets->is_array()) {
    LayoutError(source_name,
                "markersets",
                fmt::format("expected an array, got {}", JsonTypeName(*sets)));
  }
  std::set<std::string> types;
  std::set<std::string> labels;
  for (size_t s = 0; s < JsonArray(*sets).size(); ++s) {
    const Json& set = JsonArray(*sets)[s];
    const std::string path = fmt::format("markersets[{}]", s);
    if (!set.is_object()) {
      LayoutError(source_name,
                  path,
                  fmt::format("expected an object, got {}", JsonTypeName(set)));
    }
    RejectUnknownKeys(
        set, {"distance_from_skin", "indices", "type"}, source_name, path);
    std::string type = "body";
    if (const Json* t = JsonFind(set, "type")) {
      if (!t->is_string() || JsonString(*t).empty()) {
        LayoutError(source_name, path + ".type", "expected a non-empty string");
      }
      type = JsonString(*t);
    }
    if (!types.insert(type).second) {
      LayoutError(
          source_name,
          path + ".type",
          fmt::format("marker type \"{}\" appears in several markersets",
                      type));
    }
    double distance = kDefaultDistanceFromSkin;
    if (const Json* d = JsonFind(set, "distance_from_skin")) {
      if (!d->is_number() || !std::isfinite(JsonNumber(*d)) ||
          JsonNumber(*d) < 0.0) {
        LayoutError(source_name,
                    path + ".distance_from_skin",
                    "expected a finite non-negative number (metres)");
      }
      distance = JsonNumber(*d);
    }
    const Json* indices = JsonFind(set, "indices");
    if (indices == nullptr)
      LayoutError(source_name, path, "missing key \"indices\"");
    if (!indices->is_object()) {
      LayoutError(
          source_name,
          path + ".indices",
          fmt::format("expected an object, got {}", JsonTypeName(*indices)));
    }
    for (const auto& [label, value] : JsonObject(*indices)) {
      const std::string label_path = fmt::format("{}.indices.{}", path, label);
      if (label.empty())
        LayoutError(source_name, label_path, "empty marker label");
      if (!labels.insert(label).second) {
        LayoutError(
            source_name,
            label_path,
            fmt::format("label \"{}\" appears in several markersets", label));
      }
      MarkerLayout::Marker marker;
      marker.label = label;
      marker.type = type;
      marker.distance_from_skin = distance;
      if (value.is_array()) {
        if (JsonArray(value).empty())
          LayoutError(source_name, label_path, "empty vertex id list");
        for (size_t k = 0; k < JsonArray(value).size(); ++k) {
          const int vid = ParseVertexId(JsonArray(value)[k],
                                        source_name,
                                        fmt::format("{}[{}]", label_path, k));
          if (std::find(marker.vertex_ids.begin(),
                        marker.vertex_ids.end(),
                        vid) == marker.vertex_ids.end()) {
            marker.vertex_ids.push_back(vid);
          }
        }
      } else {
        marker.vertex_ids.push_back(
            ParseVertexId(value, source_name, label_path));
      }
      layout.markers.push_back(std::move(marker));
    }
  }
  layout.Sort();
  return layout;
}

MarkerLayout ReadMarkerLayout(const std::filesystem::path& path) {
  return ParseMarkerLayout(ReadFile(path), path.string());
}

std::string MarkerLayoutToJson(const MarkerLayout& layout) {
  std::map<std::string, std::pair<double, Json>>
      sets;  // type -> (distance, indices)
  for (const MarkerLayout::Marker& m : layout.markers) {
    if (m.vertex_ids.empty()) {
      throw IoError(fmt::format(
          "MarkerLayoutToJson: marker {} has no vertex id", m.label));
    }
    auto it = sets.find(m.type);
    if (it == sets.end()) {
      it = sets.emplace(m.type,
                        std::make_pair(m.distance_from_skin, Json::object()))
               .first;
    } else if (it->second.first != m.distance_from_skin) {
      throw IoError(
          fmt::format("MarkerLayoutToJson: markers of type {} have different "
                      "distance_from_skin ({} and {})",
                      m.type,
                      it->second.first,
                      m.distance_from_skin));
    }
    if (m.vertex_ids.size() == 1) {
      it->second.second[m.label] = m.vertex_ids[0];
    } else {
      Json ids = Json::array();
      for (const int vid : m.vertex_ids) ids.push_back(vid);
      it->second.second[m.label] = std::move(ids);
    }
  }
  Json root = Json::object();
  root["surface_model_type"] = layout.surface_model_type;
  Json array = Json::array();
  for (auto& [type, entry] : sets) {
    Json set = Json::object();
    set["distance_from_skin"] = entry.first;
    set["indices"] = std::move(entry.second);
    set["type"] = type;
    array.push_back(std::move(set));
  }
  root["markersets"] = std::move(array);
  return WriteJson(root, 2) + "\n";
}

void WriteMarkerLayout(const MarkerLayout& layout,
                       const std::filesystem::path& path) {
  WriteFileAtomic(path, MarkerLayoutToJson(layout));
}

// ---------------------------------------------------------------------------
// Labels.

const std::vector<MarkerLabelAlias>& MarkerLabelAliases() {
  static const auto* const kList = [] {
    auto* list = new std::vector<MarkerLabelAlias>();
    for (const auto& [alias, canonical] : AliasMap())
      list->push_back({alias, canonical});
    return list;
  }();
  return *kList;
}

namespace {

/// The subject prefix stripped, upper-cased: how name-map keys and capture
/// labels are compared.
std::string NameMapKey(std::string_view label) {
  std::string name(StripSubjectPrefix(label));
  for (char& c : name)
    c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return name;
}

std::string_view NodeTypeName(const ConfigNode& node) {
  if (node.IsNull()) return "null";
  if (node.IsBool()) return "a bool";
  if (node.IsInt()) return "an int";
  if (node.IsDouble()) return "a float";
  if (node.IsList()) return "a list";
  if (node.IsMap()) return "a mapping";
  if (node.IsMissing()) return "???";
  return "an interpolation";
}

}  // namespace

std::string MarkerNameMap::Apply(std::string_view label) const {
  const std::string key = NameMapKey(label);
  for (const auto& [theirs, ours] : entries) {
    if (NameMapKey(theirs) == key) return ours;
  }
  return std::string(label);
}

std::vector<std::string> MarkerNameMap::Apply(
    const std::vector<std::string>& labels) const {
  std::vector<std::string> out;
  out.reserve(labels.size());
  for (const std::string& label : labels) out.push_back(Apply(label));
  return out;
}

MarkerNameMap ParseMarkerNameMap(std::string_view yaml_text,
                                 std::string_view source) {
  ConfigNode root;
  try {
    root = ParseYaml(yaml_text, source);
  } catch (const Error& e) {
    throw IoError(fmt::format(
        "{} (a name map: one YAML mapping their_name: our_name)", e.what()));
  }
  MarkerNameMap map;
  map.source = std::string(source);
  if (root.IsNull()) return map;
  if (!root.IsMap()) {
    throw IoError(
        fmt::format("{}: expected one mapping `their_name: our_name`, got {}",
                    source,
                    NodeTypeName(root)));
  }
  std::map<std::string, std::string> seen;  // key -> first key as written
  for (const auto& [key, value] : root.entries()) {
    if (!value.IsString()) {
      throw IoError(fmt::format(
          "{}: {}: expected our marker name (a string), got {} ({}); quote "
          "names YAML reads otherwise",
          source,
          key,
          NodeTypeName(value),
          value.text()));
    }
    const std::string& ours = value.AsString();
    if (NameMapKey(key).empty() || NameMapKey(ours).empty()) {
      throw IoError(fmt::format("{}: {}: empty marker name", source, key));
    }
    const auto [it, inserted] = seen.emplace(NameMapKey(key), key);
    if (!inserted) {
      throw IoError(fmt::format(
          "{}: {}: the same capture name as {} (case and subject prefix are "
          "ignored)",
          source,
          key,
          it->second));
    }
    map.entries.emplace_back(key, ours);
  }
  return map;
}

MarkerNameMap ReadMarkerNameMap(const std::filesystem::path& path) {
  return ParseMarkerNameMap(ReadFile(path), path.string());
}

void CheckMarkerNameMap(const MarkerNameMap& map,
                        const std::vector<std::string>& labels,
                        std::string_view what) {
  std::set<std::string> known;
  for (const std::string& label : labels) {
    known.insert(CanonicalMarkerLabel(label));
  }
  std::map<std::string, std::string> target_of;  // canonical target -> key
  for (const auto& [theirs, ours] : map.entries) {
    const std::string target = CanonicalMarkerLabel(ours);
    if (known.count(target) == 0) {
      throw IoError(
          fmt::format("{}: {}: {} is not a label of {} ({} labels: {})",
                      map.source,
                      theirs,
                      ours,
                      what,
                      labels.size(),
                      fmt::join(labels, " ")));
    }
    const auto [it, inserted] = target_of.emplace(target, theirs);
    if (!inserted) {
      throw IoError(fmt::format("{}: {}: maps onto {}, as {} does already",
                                map.source,
                                theirs,
                                ours,
                                it->second));
    }
  }
}

std::string CanonicalMarkerLabel(std::string_view label) {
  std::string name(StripSubjectPrefix(label));
  for (char& c : name)
    c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  const auto& aliases = AliasMap();
  const auto it = aliases.find(name);
  return it == aliases.end() ? name : it->second;
}

const std::vector<std::string>& AnatomicalMarkerLabels() {
  static const auto* const kLabels = [] {
    auto* labels = new std::vector<std::string>();
    for (const auto& [label, rule] : AllRules()) labels->push_back(label);
    return labels;
  }();
  return *kLabels;
}

const std::vector<std::string>& KnownMarkerLabels() {
  static const auto* const kLabels = [] {
    std::vector<std::string> labels = AnatomicalMarkerLabels();
    for (const auto& name : BuiltinLayoutNames()) {
      for (const auto& l : BuiltinLayoutLabels(name)) labels.push_back(l);
    }
    for (const auto& [alias, canonical] : AliasMap()) labels.push_back(alias);
    return new std::vector<std::string>(Sorted(std::move(labels)));
  }();
  return *kLabels;
}

bool IsKnownMarkerLabel(std::string_view label) {
  const auto& known = KnownMarkerLabels();
  return std::binary_search(known.begin(), known.end(), label);
}

MarkerLayout CanonicalizeLayout(const MarkerLayout& layout) {
  MarkerLayout out;
  out.surface_model_type = layout.surface_model_type;
  for (const MarkerLayout::Marker& m : layout.markers) {
    const std::string label = CanonicalMarkerLabel(m.label);
    const int existing = out.FindLabel(label);
    if (existing < 0) {
      MarkerLayout::Marker copy = m;
      copy.label = label;
      out.markers.push_back(std::move(copy));
      continue;
    }
    MarkerLayout::Marker& target = out.markers[existing];
    if (target.type != m.type) {
      throw ConfigError(fmt::format(
          "CanonicalizeLayout: label {} (from {}) has types {} and {}",
          label,
          m.label,
          target.type,
          m.type));
    }
    for (const int vid : m.vertex_ids) {
      if (std::find(target.vertex_ids.begin(), target.vertex_ids.end(), vid) ==
          target.vertex_ids.end()) {
        target.vertex_ids.push_back(vid);
      }
    }
  }
  out.Sort();
  return out;
}

MarkerLayout MergeLayouts(const std::vector<MarkerLayout>& layouts,
                          const MergeLayoutsOptions& options) {
  if (layouts.empty()) throw ConfigError("MergeLayouts: no layouts to merge");
  MarkerLayout out;
  out.surface_model_type = layouts.front().surface_model_type;
  std::map<std::string, double> distances;  // per type
  for (size_t i = 0; i < layouts.size(); ++i) {
    const MarkerLayout layout = options.canonicalize_labels
                                    ? CanonicalizeLayout(layouts[i])
                                    : layouts[i];
    if (layout.surface_model_type != out.surface_model_type) {
      throw ConfigError(
          fmt::format("MergeLayouts: layouts of different surface models "
                      "cannot be merged: {} (layout 0) "
                      "and {} (layout {})",
                      out.surface_model_type,
                      layout.surface_model_type,
                      i));
    }
    for (const MarkerLayout::Marker& m : layout.markers) {
      const auto [it, inserted] =
          distances.emplace(m.type, m.distance_from_skin);
      if (!inserted && it->second != m.distance_from_skin) {
        throw ConfigError(
            fmt::format("MergeLayouts: marker type {} has distance_from_skin "
                        "{} in one layout and {} in "
                        "layout {} (label {})",
                        m.type,
                        it->second,
                        m.distance_from_skin,
                        i,
                        m.label));
      }
      const int existing = out.FindLabel(m.label);
      if (existing < 0) {
        out.markers.push_back(m);
        continue;
      }
      MarkerLayout::Marker& target = out.markers[existing];
      if (target.type != m.type) {
        throw ConfigError(fmt::format(
            "MergeLayouts: label {} has types {} and {} (layout {})",
            m.label,
            target.type,
            m.type,
            i));
      }
      for (const int vid : m.vertex_ids) {
        if (std::find(target.vertex_ids.begin(),
                      target.vertex_ids.end(),
                      vid) == target.vertex_ids.end()) {
          target.vertex_ids.push_back(vid);
        }
      }
    }
  }
  out.Sort();
  return out;
}

void ValidateLayoutForBody(const MarkerLayout& layout,
                           const BodyModel& body,
                           std::string_view source,
                           const LayoutCheckOptions& options) {
  if (options.require_surface_model_match &&
      layout.surface_model_type != body.name) {
    throw IoError(fmt::format(
        "{}: marker layout is for surface model '{}' but the body is '{}'",
        source,
        layout.surface_model_type,
        body.name));
  }
  for (const MarkerLayout::Marker& m : layout.markers) {
    if (m.label.empty())
      throw IoError(fmt::format("{}: a marker has an empty label", source));
    if (!options.allow_unknown_labels && !IsKnownMarkerLabel(m.label) &&
        !IsKnownMarkerLabel(CanonicalMarkerLabel(m.label))) {
      throw IoError(fmt::format(
          "{}: unknown marker label '{}' (not a built-in label or alias; set "
          "allow_unknown_labels to accept custom labels)",
          source,
          m.label));
    }
    if (m.vertex_ids.empty()) {
      throw IoError(
          fmt::format("{}: marker {} has no vertex id", source, m.label));
    }
    for (const int vid : m.vertex_ids) {
      if (vid < 0 || vid >= body.num_vertices()) {
        throw IoError(fmt::format(
            "{}: marker {} has vertex id {} outside [0, {}) of body '{}'",
            source,
            m.label,
            vid,
            body.num_vertices(),
            body.name));
      }
    }
    if (!std::isfinite(m.distance_from_skin) || m.distance_from_skin < 0.0) {
      throw IoError(
          fmt::format("{}: marker {} has distance_from_skin {} (expected >= 0)",
                      source,
                      m.label,
                      m.distance_from_skin));
    }
  }
}

MarkerLayout LoadMarkerLayoutForBody(const std::filesystem::path& path,
                                     const BodyModel& body,
                                     const LayoutCheckOptions& options) {
  MarkerLayout layout = ReadMarkerLayout(path);
  ValidateLayoutForBody(layout, body, path.string(), options);
  return layout;
}

// ---------------------------------------------------------------------------
// Built-in layouts.

const std::vector<std::string>& BuiltinLayoutNames() {
  static const auto* const kNames =
      new std::vector<std::string>{"cmu41", "pig39", "soma53", "superset89"};
  return *kNames;
}

const std::vector<std::string>& BuiltinLayoutLabels(std::string_view name) {
  static const auto* const kLists = [] {
    auto* lists =
        new std::map<std::string, std::vector<std::string>, std::less<>>();
    (*lists)["cmu41"] = Sorted(Cmu41());
    (*lists)["pig39"] = Sorted(Pig39());
    std::vector<std::string> soma53 = Cmu41();
    soma53.insert(soma53.end(), Soma53Extra().begin(), Soma53Extra().end());
    (*lists)["soma53"] = Sorted(soma53);
    std::vector<std::string> superset;
    for (const auto* list :
         {&Cmu41(), &Pig39(), &Soma53Extra(), &Superset89Extra()}) {
      for (const auto& l : *list) superset.push_back(CanonicalMarkerLabel(l));
    }
    (*lists)["superset89"] = Sorted(superset);
    // Label-id order: by (type, label), as MarkerLayout::Sort() orders the
    // resolved layout.
    for (auto& [list_name, labels] : *lists) {
      std::sort(labels.begin(),
                labels.end(),
                [](const std::string& a, const std::string& b) {
                  const std::string ta = BuiltinMarkerType(a);
                  const std::string tb = BuiltinMarkerType(b);
                  return ta != tb ? ta < tb : a < b;
                });
    }
    return lists;
  }();
  const auto it = kLists->find(name);
  if (it == kLists->end()) {
    throw ConfigError(
        fmt::format("Unknown built-in marker layout '{}'. Available: {}",
                    name,
                    fmt::join(BuiltinLayoutNames(), ", ")));
  }
  return it->second;
}

std::string BuiltinMarkerType(std::string_view label) {
  const std::string canonical = CanonicalMarkerLabel(label);
  for (const char* wrist : {"LWRA", "LWRB", "RWRA", "RWRB"}) {
    if (canonical == wrist) return std::string(kWristMarkerType);
  }
  return "body";
}

double BuiltinDistanceFromSkin(std::string_view type) {
  return type == kWristMarkerType ? kWristBarDistanceFromSkin
                                  : kDefaultDistanceFromSkin;
}

std::vector<int> KeptLabelPositions(const std::vector<std::string>& labels,
                                    const std::vector<std::string>& exclude,
                                    std::string_view key) {
  std::vector<std::string> canonical;
  canonical.reserve(labels.size());
  for (const std::string& l : labels) {
    canonical.push_back(CanonicalMarkerLabel(l));
  }
  std::vector<bool> excluded(labels.size(), false);
  for (const std::string& name : exclude) {
    const auto it = std::find(
        canonical.begin(), canonical.end(), CanonicalMarkerLabel(name));
    if (it == canonical.end()) {
      throw ConfigError(fmt::format(
          "Invalid configuration. {}: '{}' is not a label of the layout ({})",
          key,
          name,
          fmt::join(labels, " ")));
    }
    excluded[it - canonical.begin()] = true;
  }
  std::vector<int> kept;
  for (size_t i = 0; i < labels.size(); ++i) {
    if (!excluded[i]) kept.push_back(static_cast<int>(i));
  }
  if (kept.empty()) {
    throw ConfigError(fmt::format(
        "Invalid configuration. {} removes every label of the layout", key));
  }
  return kept;
}

MarkerLayout ExcludeMarkers(const MarkerLayout& layout,
                            const std::vector<std::string>& exclude,
                            std::string_view key) {
  MarkerLayout out = layout;
  out.markers.clear();
  for (int i : KeptLabelPositions(layout.Labels(), exclude, key)) {
    out.markers.push_back(layout.markers[i]);
  }
  return out;
}

MarkerLayout MakeBuiltinLayout(const BodyModel& body, std::string_view name) {
  const std::vector<std::string>& labels = BuiltinLayoutLabels(name);
  if (body.num_joints() < kNumCoreJoints) {
    throw ShapeError(fmt::format(
        "MakeBuiltinLayout: body '{}' has {} joints, needs the {} core "
        "joints",
        body.name,
        body.num_joints(),
        static_cast<int>(kNumCoreJoints)));
  }
  const Eigen::Matrix3Xd core_joints =
      body.RestJoints(body.template_vertices).leftCols(kNumCoreJoints);
  Eigen::Matrix3Xd joints(3, kNumRuleJoints);
  joints.leftCols(kNumCoreJoints) = core_joints;
  joints.col(kHeadCentre) =
      HeadCentre(body.template_vertices, core_joints, body.name);
  const auto& rules = AllRules();
  MarkerLayout layout;
  layout.surface_model_type = body.name;
  for (const std::string& label : labels) {
    const auto it = rules.find(CanonicalMarkerLabel(label));
    if (it == rules.end()) {
      throw InternalError(
          fmt::format("built-in label {} has no placement rule", label));
    }
    MarkerLayout::Marker marker;
    marker.label = label;
    marker.type = BuiltinMarkerType(label);
    marker.distance_from_skin = BuiltinDistanceFromSkin(marker.type);
    marker.vertex_ids = {PlaceByRule(
        it->second, body.template_vertices, body.faces, joints, body.name)};
    layout.markers.push_back(std::move(marker));
  }
  layout.Sort();
  return layout;
}

Eigen::Matrix3Xd MarkerPositions(const MarkerLayout& layout,
                                 const Eigen::Matrix3Xd& vertices,
                                 const Eigen::Matrix3Xd& normals) {
  if (normals.cols() != vertices.cols()) {
    throw ShapeError(fmt::format("MarkerPositions: {} normals for {} vertices",
                                 normals.cols(),
                                 vertices.cols()));
  }
  Eigen::Matrix3Xd out(3, layout.num_markers());
  for (int i = 0; i < layout.num_markers(); ++i) {
    const MarkerLayout::Marker& m = layout.markers[i];
    if (m.vertex_ids.empty() || m.vertex_ids[0] < 0 ||
        m.vertex_ids[0] >= vertices.cols()) {
      throw ShapeError(fmt::format(
          "MarkerPositions: marker {} has no valid vertex id", m.label));
    }
    const int vid = m.vertex_ids[0];
    out.col(i) = vertices.col(vid) + m.distance_from_skin * normals.col(vid);
  }
  return out;
}

}  // namespace soma
