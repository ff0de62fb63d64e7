#include "framework/motion/procedural_motion.h"

#include "framework/core/error.h"
#include "framework/motion/anatomy.h"

#include <Eigen/Geometry>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>

namespace soma {
namespace {

constexpr double kDeg = M_PI / 180.0;
constexpr double kTwoPi = 2.0 * M_PI;

/// One frame as a generator writes it: anatomical angles, the root's world
/// orientation, the horizontal root position and the height of the lowest
/// body point above the floor (0 = on the floor; > 0 in flight).
struct Frame {
  AnatomicalPose angles = StandingPose();
  Eigen::Quaterniond root = Eigen::Quaterniond::Identity();
  Eigen::Vector2d xy = Eigen::Vector2d::Zero();
  double lift = 0.0;
};

/// Everything a generator needs: timing and the clip's random stream.
struct Clip {
  int num_frames;
  double frame_rate;
  Rng* rng;
  const ProceduralMotionOptions* options;

  double Time(int frame) const { return frame / frame_rate; }
  double Duration() const { return num_frames / frame_rate; }
  double U(double lo, double hi) const { return rng->Uniform(lo, hi); }
  bool Coin(double p = 0.5) const { return rng->Bernoulli(p); }
};

double Smoothstep(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * (3.0 - 2.0 * x);
}

/// The joints of one side of the body (0 = left, 1 = right), for generators
/// that loop over the two sides.
struct SideJoints {
  int hip, knee, ankle, shoulder, elbow, wrist;
};

SideJoints Side(int side) {
  return side == 0 ? SideJoints{kLeftHip,
                                kLeftKnee,
                                kLeftAnkle,
                                kLeftShoulder,
                                kLeftElbow,
                                kLeftWrist}
                   : SideJoints{kRightHip,
                                kRightKnee,
                                kRightAnkle,
                                kRightShoulder,
                                kRightElbow,
                                kRightWrist};
}

Eigen::Quaterniond Yaw(double angle) {
  return Eigen::Quaterniond(Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()));
}

Eigen::Quaterniond AxisRotation(double angle, const Eigen::Vector3d& axis) {
  return Eigen::Quaterniond(Eigen::AngleAxisd(angle, axis.normalized()));
}

/// Uniformly random rotation (Shoemake's method).
Eigen::Quaterniond RandomRotation(Rng& rng) {
  const double u1 = rng.Uniform(), u2 = rng.Uniform(), u3 = rng.Uniform();
  const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
  return Eigen::Quaterniond(a * std::sin(kTwoPi * u2),
                            a * std::cos(kTwoPi * u2),
                            b * std::sin(kTwoPi * u3),
                            b * std::cos(kTwoPi * u3))
      .normalized();
}

JointAngles Mix(const JointAngles& a, const JointAngles& b, double w) {
  return {a.flexion + w * (b.flexion - a.flexion),
          a.abduction + w * (b.abduction - a.abduction),
          a.twist + w * (b.twist - a.twist)};
}

Frame Blend(const Frame& a, const Frame& b, double w) {
  Frame f;
  for (int j = 0; j < kNumCoreJoints; ++j)
    f.angles[j] = Mix(a.angles[j], b.angles[j], w);
  f.root = a.root.slerp(w, b.root);
  f.xy = a.xy + w * (b.xy - a.xy);
  f.lift = a.lift + w * (b.lift - a.lift);
  return f;
}

/// Smooth (smoothstep) interpolation through keyframes at normalised times
/// in [0, 1].
class Keyframes {
 public:
  void Add(double t, const Frame& frame) { keys_.push_back({t, frame}); }
  Frame At(double t) const {
    SOMA_CHECK(!keys_.empty());
    if (t <= keys_.front().first) return keys_.front().second;
    for (size_t i = 1; i < keys_.size(); ++i) {
      if (t <= keys_[i].first) {
        const double span = keys_[i].first - keys_[i - 1].first;
        const double w = span > 0 ? (t - keys_[i - 1].first) / span : 1.0;
        return Blend(keys_[i - 1].second, keys_[i].second, Smoothstep(w));
      }
    }
    return keys_.back().second;
  }

 private:
  std::vector<std::pair<double, Frame>> keys_;
};

std::vector<Frame> Sample(const Keyframes& keys, const Clip& clip) {
  std::vector<Frame> frames(clip.num_frames);
  for (int i = 0; i < clip.num_frames; ++i) {
    frames[i] = keys.At(clip.num_frames > 1
                            ? i / static_cast<double>(clip.num_frames - 1)
                            : 0.0);
  }
  return frames;
}

void SetBoth(AnatomicalPose& p,
             int left,
             int right,
             const JointAngles& angles) {
  p[left] = angles;
  p[right] = angles;
}

void SetSpine(AnatomicalPose& p,
              double flexion,
              double lateral = 0,
              double twist = 0) {
  for (int j : {kSpine1, kSpine2, kSpine3}) {
    p[j] = {flexion / 3, lateral / 3, twist / 3};
  }
}

/// Arms hanging with a given extra shoulder flexion (swing) per side.
void ArmSwing(AnatomicalPose& p,
              double left_swing,
              double right_swing,
              double elbow) {
  p[kLeftShoulder] = {left_swing, -80 * kDeg, 0};
  p[kRightShoulder] = {right_swing, -80 * kDeg, 0};
  p[kLeftElbow].flexion = elbow;
  p[kRightElbow].flexion = elbow;
}

// ---------------------------------------------------------------------------
// Locomotion.

/// Walk (or run) cycle. Phase 0 = left heel strike.
std::vector<Frame> Gait(const Clip& clip, bool run) {
  const double speed = run ? clip.U(2.0, 4.5) : clip.U(0.6, 1.7);    // m/s
  const double cadence = run ? clip.U(2.6, 3.2) : clip.U(1.6, 2.1);  // steps/s
  const double stride_freq = cadence / 2;                            // cycles/s
  const double hip_amp = (run ? clip.U(35, 50) : clip.U(20, 30)) * kDeg;
  const double knee_peak = (run ? clip.U(90, 120) : clip.U(55, 70)) * kDeg;
  const double arm_amp = (run ? clip.U(35, 60) : clip.U(10, 30)) * kDeg;
  const double elbow = (run ? clip.U(80, 100) : clip.U(5, 25)) * kDeg;
  const double lean = (run ? clip.U(5, 15) : clip.U(0, 5)) * kDeg;
  const double heading = clip.U(-M_PI, M_PI);
  const double phase0 = clip.U(0, kTwoPi);
  std::vector<Frame> frames(clip.num_frames);
  for (int i = 0; i < clip.num_frames; ++i) {
    const double t = clip.Time(i);
    const double phase = phase0 + kTwoPi * stride_freq * t;
    Frame& f = frames[i];
    AnatomicalPose& p = f.angles;
    for (int side = 0; side < 2; ++side) {
      const double ph = phase + side * M_PI;
      const SideJoints joints = Side(side);
      const int hip = joints.hip, knee = joints.knee, ankle = joints.ankle;
      p[hip].flexion = hip_amp * std::cos(ph) + (run ? 10 * kDeg : 0);
      // Knee flexes in swing (second half of the cycle), a little at loading.
      const double swing = std::max(0.0, std::sin(ph - M_PI * 0.95));
      const double loading = std::max(0.0, std::sin(ph * 2)) * 0.2;
      p[knee].flexion = knee_peak * swing * swing + knee_peak * loading;
      p[ankle].flexion = 15 * kDeg * std::sin(ph - 0.5);
    }
    ArmSwing(p,
             -arm_amp * std::cos(phase),
             -arm_amp * std::cos(phase + M_PI),
             elbow);
    SetSpine(p, lean, 0, 6 * kDeg * std::cos(phase));
    p[kPelvis].twist = -5 * kDeg * std::cos(phase);
    f.root = Yaw(heading);
    // Body faces -Y at rest; forward is the rotated -Y.
    const Eigen::Vector3d forward = f.root * Eigen::Vector3d(0, -1, 0);
    f.xy = forward.head<2>() * speed * t;
    f.lift = run ? std::max(0.0, 0.08 * std::sin(2 * phase)) : 0.0;
  }
  return frames;
}

/// Crouched locomotion: sneaking and duck walking with the hips low (knees
/// at 70-130 degrees throughout), the trunk pitched forward and the arms
/// forward or down for balance. Real captures hold whole segments of it
/// (HDM05's sneaking takes, CMU's crouched walks) that upright gait, squats
/// in place and hands-and-knees crawling do not cover.
std::vector<Frame> CrouchWalk(const Clip& clip) {
  const double speed = clip.U(0.15, 0.9);            // m/s
  const double stride_freq = clip.U(0.5, 0.9);       // cycles/s
  const double pitch = clip.U(0, 35) * kDeg;         // pelvis forward
  const double hip_base = clip.U(60, 105) * kDeg;    // mean hip flexion
  const double knee_base = clip.U(80, 125) * kDeg;   // mean knee flexion
  const double ankle_base = clip.U(-20, 20) * kDeg;  // < 0: dorsiflexion
  const double hip_amp = clip.U(10, 25) * kDeg;
  const double knee_swing = clip.U(10, 30) * kDeg;  // extra in swing
  const double lean = clip.U(20, 60) * kDeg;        // trunk, total
  const double abduction = clip.U(0, 25) * kDeg;    // knees apart
  const double shoulder = clip.U(0, 80) * kDeg;     // arms forward
  const double arm_amp = clip.U(0, 20) * kDeg;
  const double elbow = clip.U(10, 80) * kDeg;
  const double heading = clip.U(-M_PI, M_PI);
  const double phase0 = clip.U(0, kTwoPi);
  std::vector<Frame> frames(clip.num_frames);
  for (int i = 0; i < clip.num_frames; ++i) {
    const double t = clip.Time(i);
    const double phase = phase0 + kTwoPi * stride_freq * t;
    Frame& f = frames[i];
    AnatomicalPose& p = f.angles;
    for (int side = 0; side < 2; ++side) {
      const double ph = phase + side * M_PI;
      const SideJoints joints = Side(side);
      const int hip = joints.hip, knee = joints.knee, ankle = joints.ankle;
      const double swing = std::max(0.0, std::sin(ph - M_PI * 0.95));
      p[hip] = {hip_base + hip_amp * std::cos(ph), abduction, 0};
      p[knee].flexion = knee_base + knee_swing * swing;
      p[ankle].flexion = ankle_base + 10 * kDeg * std::sin(ph - 0.5);
    }
    // Arms from hanging (flexion 0, abduction -80) to forward (80, -10).
    const double hang = -80 * kDeg + shoulder * 70.0 / 80.0;
    p[kLeftShoulder] = {shoulder - arm_amp * std::cos(phase), hang, 0};
    p[kRightShoulder] = {shoulder - arm_amp * std::cos(phase + M_PI), hang, 0};
    SetBoth(p, kLeftElbow, kRightElbow, {elbow, 0, 0});
    SetSpine(p, std::max(0.0, lean - pitch), 0, 5 * kDeg * std::cos(phase));
    p[kHead].flexion = -0.6 * lean;  // looking ahead
    f.root = Yaw(heading) * AxisRotation(pitch, Eigen::Vector3d::UnitX());
    const Eigen::Vector3d forward = f.root * Eigen::Vector3d(0, -1, 0);
    f.xy = forward.head<2>() * speed * t;
  }
  return frames;
}

/// Walking low on hands and feet (HDM05's four-legged walks, animal
/// imitations, low martial-arts and playground movement): each leg swings
/// between a front pose (thigh raised to about the pelvis' height, knee near
/// 90 degrees, the foot planted ahead) and a rear pose (thigh down, knee
/// deeply flexed and dropped towards the floor, the foot behind), so hip and
/// knee flexion move in opposite directions, unlike upright or crouched
/// gait. The trunk is pitched 45-75 degrees and the arms reach down towards
/// the floor, each stepping with the opposite leg; the pelvis joint stays
/// ~0.55-0.65 m above the floor on average (the real take's waist markers:
/// 0.37-0.56 m). crouch_walk keeps the hands off the floor and its knees
/// bend with the hips; crawl kneels on the floor.
std::vector<Frame> BearWalk(const Clip& clip) {
  const double speed = clip.U(0.1, 0.7);      // m/s
  const double step_freq = clip.U(0.4, 0.9);  // cycles/s
  const double pitch = clip.U(0, 10) * kDeg;  // pelvis forward
  const double lean = clip.U(45, 75) * kDeg;  // trunk, total
  // Thigh angles in the world (from straight down, forward > 0) and knee
  // flexion of the front and rear poses: the rear thigh still points
  // forward-down, so a 120-135 degree knee puts the foot behind on its toes
  // and the knee near the floor. Pitching the pelvis forward turns the legs
  // back, so the hip flexes by the thigh angle plus the pitch (<= 120).
  const double thigh_front = clip.U(95, 110) * kDeg;
  const double thigh_rear = clip.U(45, 65) * kDeg;
  const double knee_front = clip.U(75, 95) * kDeg;
  const double knee_rear = clip.U(120, 135) * kDeg;
  const double hip_mid = 0.5 * (thigh_front + thigh_rear) + pitch;
  const double hip_amp = 0.5 * (thigh_front - thigh_rear);
  const double knee_mid = 0.5 * (knee_front + knee_rear);
  const double knee_amp = 0.5 * (knee_rear - knee_front);
  const double ankle_base = clip.U(-20, 10) * kDeg;  // < 0: dorsiflexion
  const double abduction = clip.U(5, 30) * kDeg;     // knees apart
  // The arm swings forward from hanging by about the trunk's pitch to point
  // at the floor; beyond it the hands land ahead of the shoulders.
  const double reach = lean + clip.U(-10, 15) * kDeg;
  const double arm_amp = clip.U(10, 30) * kDeg;
  const double elbow = clip.U(0, 35) * kDeg;
  const double wrist = -clip.U(20, 60) * kDeg;  // hand flat on the floor
  const double heading = clip.U(-M_PI, M_PI);
  const double phase0 = clip.U(0, kTwoPi);
  std::vector<Frame> frames(clip.num_frames);
  for (int i = 0; i < clip.num_frames; ++i) {
    const double t = clip.Time(i);
    const double phase = phase0 + kTwoPi * step_freq * t;
    Frame& f = frames[i];
    AnatomicalPose& p = f.angles;
    for (int side = 0; side < 2; ++side) {
      const double ph = phase + side * M_PI;
      const auto [hip, knee, ankle, shoulder, elbow_joint, wrist_joint] =
          Side(side);
      p[hip] = {hip_mid + hip_amp * std::cos(ph), abduction, 0};
      p[knee].flexion = knee_mid - knee_amp * std::cos(ph);
      p[ankle].flexion = ankle_base + 15 * kDeg * std::cos(ph);
      // The arm steps with the opposite leg (phase + pi).
      // Forward swing s from hanging (0, -80) towards forward (80, -10), as
      // in crouch_walk.
      const double swing = reach + arm_amp * std::cos(ph + M_PI);
      p[shoulder] = {swing, -80 * kDeg + swing * 70.0 / 80.0, 0};
      p[elbow_joint].flexion = elbow;
      p[wrist_joint].flexion = wrist;
    }
    SetSpine(p, std::max(0.0, lean - pitch), 0, 5 * kDeg * std::cos(phase));
    p[kHead].flexion = -0.6 * lean;  // looking ahead
    f.root = Yaw(heading) * AxisRotation(pitch, Eigen::Vector3d::UnitX());
    const Eigen::Vector3d forward = f.root * Eigen::Vector3d(0, -1, 0);
    f.xy = forward.head<2>() * speed * t;
  }
  return frames;
}

std::vector<Frame> Walk(const Clip& clip) { return Gait(clip, false); }
std::vector<Frame> Run(const Clip& clip) { return Gait(clip, true); }

/// Walking on the spot while the heading turns by up to a full circle.
std::vector<Frame> Turn(const Clip& clip) {
  std::vector<Frame> frames = Gait(clip, false);
  const double total = clip.U(0.5, 2.0) * M_PI * (clip.Coin() ? 1 : -1);
  const double heading0 = clip.U(-M_PI, M_PI);
  for (int i = 0; i < clip.num_frames; ++i) {
    const double w = i / static_cast<double>(std::max(1, clip.num_frames - 1));
    frames[i].root = Yaw(heading0 + total * Smoothstep(w));
    frames[i].xy *= 0.15;  // mostly in place
  }
  return frames;
}

// ---------------------------------------------------------------------------
// Keyframed whole-body actions.

Frame Standing(const Clip& clip, double heading) {
  Frame f;
  f.root = Yaw(heading);
  return f;
}

std::vector<Frame> Squat(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  const double depth = clip.U(0.5, 1.0);  // fraction of a full squat
  const int reps = clip.Coin(0.6) ? 2 : 1;
  Keyframes keys;
  Frame stand = Standing(clip, heading);
  Frame down = stand;
  const double hip = (60 + 60 * depth) * kDeg, knee = (60 + 70 * depth) * kDeg;
  SetBoth(down.angles,
          kLeftHip,
          kRightHip,
          {hip, clip.U(5, 20) * kDeg, -10 * kDeg});
  SetBoth(down.angles, kLeftKnee, kRightKnee, {knee, 0, 0});
  SetBoth(down.angles, kLeftAnkle, kRightAnkle, {-clip.U(15, 25) * kDeg, 0, 0});
  SetSpine(down.angles, clip.U(15, 45) * kDeg);
  if (clip.Coin()) {  // arms forward for balance
    down.angles[kLeftShoulder] = {80 * kDeg, -10 * kDeg, 0};
    down.angles[kRightShoulder] = {80 * kDeg, -10 * kDeg, 0};
  }
  keys.Add(0.0, stand);
  for (int r = 0; r < reps; ++r) {
    const double t0 = r / static_cast<double>(reps);
    keys.Add(t0 + 0.15 / reps, stand);
    keys.Add(t0 + 0.5 / reps, down);
    keys.Add(t0 + 0.6 / reps, down);
    keys.Add(t0 + 0.95 / reps, stand);
  }
  return Sample(keys, clip);
}

/// A jump in place or forward, in one of two styles: a tuck (hips and knees
/// flexed in the air, arms swung up) or a straight "pencil" jump (legs nearly
/// straight, toes pointed, arms at the sides or swung up). Real captures hold
/// the straight kind, e.g. CMU 01_01's forward jumps: the whole body upright
/// and 0.1-0.3 m off the floor for a quarter of a second.
std::vector<Frame> Jump(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  const double height = clip.U(0.1, 0.5);
  const double distance = clip.Coin() ? clip.U(0.0, 1.2) : 0.0;
  const bool tuck = clip.Coin();
  const bool arms_up = clip.Coin();
  Frame stand = Standing(clip, heading);
  Frame crouch = stand;
  SetBoth(crouch.angles, kLeftHip, kRightHip, {clip.U(50, 80) * kDeg, 0, 0});
  SetBoth(crouch.angles, kLeftKnee, kRightKnee, {clip.U(70, 100) * kDeg, 0, 0});
  SetBoth(crouch.angles, kLeftAnkle, kRightAnkle, {-20 * kDeg, 0, 0});
  SetSpine(crouch.angles, 30 * kDeg);
  crouch.angles[kLeftShoulder] = {-40 * kDeg, -80 * kDeg, 0};
  crouch.angles[kRightShoulder] = {-40 * kDeg, -80 * kDeg, 0};
  Frame takeoff = stand;
  SetBoth(takeoff.angles, kLeftAnkle, kRightAnkle, {40 * kDeg, 0, 0});
  if (arms_up) {
    takeoff.angles[kLeftShoulder] = {clip.U(60, 130) * kDeg, -20 * kDeg, 0};
    takeoff.angles[kRightShoulder] = takeoff.angles[kLeftShoulder];
  } else {  // arms at the sides, a little forward or back
    const double swing = clip.U(-30, 30) * kDeg;
    ArmSwing(takeoff.angles, swing, swing, clip.U(0, 40) * kDeg);
  }
  Frame air = takeoff;
  if (tuck) {
    SetBoth(air.angles,
            kLeftHip,
            kRightHip,
            {clip.U(10, 70) * kDeg, clip.U(0, 25) * kDeg, 0});
    SetBoth(air.angles, kLeftKnee, kRightKnee, {clip.U(20, 100) * kDeg, 0, 0});
  } else {
    SetBoth(air.angles,
            kLeftHip,
            kRightHip,
            {clip.U(-5, 15) * kDeg, clip.U(0, 10) * kDeg, 0});
    SetBoth(air.angles, kLeftKnee, kRightKnee, {clip.U(0, 25) * kDeg, 0, 0});
    SetBoth(air.angles, kLeftAnkle, kRightAnkle, {clip.U(20, 60) * kDeg, 0, 0});
  }
  // One to three jumps in a row, each over an equal share of the clip, in
  // the same style (forward hops when `distance` > 0).
  const int reps = 1 + static_cast<int>(clip.U(0, 3));
  const Eigen::Vector2d forward =
      (stand.root * Eigen::Vector3d(0, -1, 0)).head<2>();
  Keyframes keys;
  keys.Add(0.0, stand);
  for (int r = 0; r < reps; ++r) {
    const double t0 = r / static_cast<double>(reps), span = 1.0 / reps;
    const Eigen::Vector2d start = forward * distance * r;
    Frame from = stand, crouch_r = crouch, takeoff_r = takeoff, air_r = air;
    from.xy = crouch_r.xy = start;
    takeoff_r.xy = start + forward * distance * 0.1;
    air_r.xy = start + forward * distance * 0.5;
    Frame land = crouch;
    land.xy = start + forward * distance;
    Frame end = stand;
    end.xy = land.xy;
    keys.Add(t0 + 0.05 * span, from);
    keys.Add(t0 + 0.25 * span, crouch_r);
    keys.Add(t0 + 0.38 * span, takeoff_r);
    keys.Add(t0 + 0.5 * span, air_r);
    keys.Add(t0 + 0.65 * span, land);
    keys.Add(t0 + 0.85 * span, end);
  }
  std::vector<Frame> frames = Sample(keys, clip);
  // Ballistic flight between each take-off (0.38) and landing (0.62).
  for (int i = 0; i < clip.num_frames; ++i) {
    const double t = i / static_cast<double>(std::max(1, clip.num_frames - 1));
    const double local = std::fmod(t * reps, 1.0);
    const double s = (local - 0.38) / 0.24;
    frames[i].lift = (s > 0 && s < 1) ? 4 * height * s * (1 - s) : 0.0;
  }
  return frames;
}

std::vector<Frame> Kick(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  const bool left = clip.Coin();
  const int hip = left ? kLeftHip : kRightHip,
            knee = left ? kLeftKnee : kRightKnee;
  const int arm = left ? kRightShoulder : kLeftShoulder;
  Frame stand = Standing(clip, heading);
  Frame chamber = stand;
  chamber.angles[hip] = {clip.U(60, 100) * kDeg, clip.U(0, 30) * kDeg, 0};
  chamber.angles[knee].flexion = clip.U(80, 120) * kDeg;
  chamber.angles[arm].flexion = 40 * kDeg;
  SetSpine(chamber.angles, -5 * kDeg);
  Frame extend = chamber;
  extend.angles[hip].flexion = clip.U(70, 115) * kDeg;
  extend.angles[knee].flexion = clip.U(0, 15) * kDeg;
  extend.angles[left ? kLeftAnkle : kRightAnkle].flexion = 30 * kDeg;
  SetSpine(extend.angles, -clip.U(5, 20) * kDeg);
  Keyframes keys;
  keys.Add(0.0, stand);
  keys.Add(0.3, chamber);
  keys.Add(0.45, extend);
  keys.Add(0.6, chamber);
  keys.Add(0.85, stand);
  return Sample(keys, clip);
}

std::vector<Frame> Throw(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  const bool right = clip.Coin(0.8);
  const int shoulder = right ? kRightShoulder : kLeftShoulder;
  const int elbow = right ? kRightElbow : kLeftElbow;
  const double side = right ? 1.0 : -1.0;
  Frame stand = Standing(clip, heading);
  Frame windup = stand;
  windup.angles[shoulder] = {
      -30 * kDeg, clip.U(0, 30) * kDeg, -clip.U(60, 90) * kDeg};
  windup.angles[elbow].flexion = clip.U(70, 110) * kDeg;
  SetSpine(windup.angles, -10 * kDeg, 0, side * clip.U(20, 40) * kDeg);
  SetBoth(windup.angles, kLeftKnee, kRightKnee, {20 * kDeg, 0, 0});
  Frame release = stand;
  release.angles[shoulder] = {
      clip.U(90, 140) * kDeg, clip.U(-10, 30) * kDeg, 20 * kDeg};
  release.angles[elbow].flexion = clip.U(0, 20) * kDeg;
  SetSpine(
      release.angles, clip.U(20, 40) * kDeg, 0, -side * clip.U(20, 40) * kDeg);
  release.angles[right ? kLeftHip : kRightHip].flexion = 30 * kDeg;
  release.angles[right ? kLeftKnee : kRightKnee].flexion = 30 * kDeg;
  Keyframes keys;
  keys.Add(0.0, stand);
  keys.Add(0.35, windup);
  keys.Add(0.55, release);
  keys.Add(0.9, stand);
  return Sample(keys, clip);
}

std::vector<Frame> Reach(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  Keyframes keys;
  Frame stand = Standing(clip, heading);
  keys.Add(0.0, stand);
  const int reaches = 1 + static_cast<int>(clip.U(0, 3));
  for (int r = 0; r < reaches; ++r) {
    Frame f = stand;
    const bool both = clip.Coin(0.3);
    for (int s = 0; s < 2; ++s) {
      if (!both && s == 1) break;
      const bool left = both ? s == 0 : clip.Coin();
      f.angles[left ? kLeftShoulder : kRightShoulder] = {
          clip.U(-30, 130) * kDeg,
          clip.U(-90, 90) * kDeg,
          clip.U(-40, 40) * kDeg};
      f.angles[left ? kLeftElbow : kRightElbow].flexion = clip.U(0, 60) * kDeg;
    }
    const double low = clip.U(0, 1);
    if (low > 0.6) {  // reach down: bend and squat
      SetSpine(f.angles,
               clip.U(30, 80) * kDeg,
               clip.U(-20, 20) * kDeg,
               clip.U(-30, 30) * kDeg);
      SetBoth(f.angles, kLeftHip, kRightHip, {clip.U(20, 80) * kDeg, 0, 0});
      SetBoth(f.angles, kLeftKnee, kRightKnee, {clip.U(0, 90) * kDeg, 0, 0});
    } else {
      SetSpine(f.angles,
               clip.U(-15, 20) * kDeg,
               clip.U(-25, 25) * kDeg,
               clip.U(-30, 30) * kDeg);
      if (low < 0.2) {  // on tiptoes
        SetBoth(
            f.angles, kLeftAnkle, kRightAnkle, {clip.U(20, 45) * kDeg, 0, 0});
      }
    }
    const double t0 = (r + 0.5) / (reaches + 0.5);
    keys.Add(t0, f);
    keys.Add(t0 + 0.1 / reaches, f);
  }
  keys.Add(1.0, stand);
  return Sample(keys, clip);
}

std::vector<Frame> Sit(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  Frame stand = Standing(clip, heading);
  Frame seated = stand;
  SetBoth(seated.angles,
          kLeftHip,
          kRightHip,
          {clip.U(80, 100) * kDeg, clip.U(0, 20) * kDeg, 0});
  SetBoth(seated.angles, kLeftKnee, kRightKnee, {clip.U(70, 110) * kDeg, 0, 0});
  SetSpine(seated.angles, clip.U(-10, 20) * kDeg);
  seated.angles[kLeftShoulder] = {clip.U(20, 60) * kDeg, -70 * kDeg, 0};
  seated.angles[kRightShoulder] = {clip.U(20, 60) * kDeg, -70 * kDeg, 0};
  SetBoth(
      seated.angles, kLeftElbow, kRightElbow, {clip.U(30, 90) * kDeg, 0, 0});
  Frame leaning = seated;
  SetSpine(leaning.angles,
           clip.U(-20, 40) * kDeg,
           clip.U(-15, 15) * kDeg,
           clip.U(-30, 30) * kDeg);
  if (clip.Coin()) {  // cross the legs
    leaning.angles[kLeftHip] = {100 * kDeg, -20 * kDeg, 20 * kDeg};
    leaning.angles[kLeftKnee].flexion = 60 * kDeg;
  }
  Keyframes keys;
  keys.Add(0.0, stand);
  keys.Add(0.25, seated);
  keys.Add(0.5, leaning);
  keys.Add(0.7, seated);
  keys.Add(0.95, clip.Coin() ? stand : seated);
  return Sample(keys, clip);
}

std::vector<Frame> Kneel(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  const bool both = clip.Coin();
  Frame stand = Standing(clip, heading);
  Frame kneel = stand;
  // Down knee: thigh vertical, shank on the floor behind.
  kneel.angles[kLeftHip].flexion = clip.U(-10, 20) * kDeg;
  kneel.angles[kLeftKnee].flexion = clip.U(85, 130) * kDeg;
  kneel.angles[kLeftAnkle].flexion = 40 * kDeg;
  if (both) {
    kneel.angles[kRightHip] = kneel.angles[kLeftHip];
    kneel.angles[kRightKnee] = kneel.angles[kLeftKnee];
    kneel.angles[kRightAnkle] = kneel.angles[kLeftAnkle];
  } else {  // other foot planted in front
    kneel.angles[kRightHip].flexion = 90 * kDeg;
    kneel.angles[kRightKnee].flexion = 90 * kDeg;
  }
  SetSpine(kneel.angles, clip.U(0, 40) * kDeg, 0, clip.U(-20, 20) * kDeg);
  Frame work = kneel;
  work.angles[kLeftShoulder] = {clip.U(30, 90) * kDeg, -30 * kDeg, 0};
  work.angles[kRightShoulder] = {clip.U(30, 90) * kDeg, -30 * kDeg, 0};
  SetSpine(work.angles, clip.U(20, 70) * kDeg);
  Keyframes keys;
  keys.Add(0.0, stand);
  keys.Add(0.3, kneel);
  keys.Add(0.55, work);
  keys.Add(0.75, kneel);
  keys.Add(1.0, clip.Coin() ? stand : kneel);
  return Sample(keys, clip);
}

std::vector<Frame> LieDown(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  Frame stand = Standing(clip, heading);
  Frame kneel = stand;
  SetBoth(kneel.angles, kLeftKnee, kRightKnee, {120 * kDeg, 0, 0});
  SetBoth(kneel.angles, kLeftHip, kRightHip, {20 * kDeg, 0, 0});
  SetSpine(kneel.angles, 30 * kDeg);
  Frame floor_sit = stand;
  SetBoth(floor_sit.angles, kLeftHip, kRightHip, {90 * kDeg, 10 * kDeg, 0});
  SetBoth(
      floor_sit.angles, kLeftKnee, kRightKnee, {clip.U(0, 60) * kDeg, 0, 0});
  // Lying: supine, prone or on a side, the body axis horizontal.
  const int style = static_cast<int>(clip.U(0, 3));
  Frame lying = stand;
  const Eigen::Quaterniond yaw = Yaw(heading);
  if (style == 0) {  // supine: pitch backwards
    lying.root = yaw * AxisRotation(-M_PI / 2, Eigen::Vector3d::UnitX());
  } else if (style == 1) {  // prone
    lying.root = yaw * AxisRotation(M_PI / 2, Eigen::Vector3d::UnitX());
  } else {  // on a side
    lying.root = yaw * AxisRotation(M_PI / 2, Eigen::Vector3d::UnitY()) *
                 AxisRotation(clip.Coin() ? M_PI / 2 : -M_PI / 2,
                              Eigen::Vector3d::UnitZ());
    SetBoth(lying.angles, kLeftHip, kRightHip, {clip.U(0, 60) * kDeg, 0, 0});
    SetBoth(lying.angles, kLeftKnee, kRightKnee, {clip.U(0, 90) * kDeg, 0, 0});
  }
  lying.angles[kLeftShoulder] = {
      clip.U(-20, 120) * kDeg, clip.U(-90, 60) * kDeg, 0};
  lying.angles[kRightShoulder] = {
      clip.U(-20, 120) * kDeg, clip.U(-90, 60) * kDeg, 0};
  Frame lying2 = lying;
  lying2.angles[kLeftHip].flexion = clip.U(0, 90) * kDeg;
  lying2.angles[kLeftKnee].flexion = clip.U(0, 120) * kDeg;
  lying2.angles[kHead].flexion = clip.U(-20, 30) * kDeg;
  Keyframes keys;
  keys.Add(0.0, stand);
  keys.Add(0.2, kneel);
  keys.Add(0.4, floor_sit);
  keys.Add(0.6, lying);
  keys.Add(0.85, lying2);
  keys.Add(1.0, lying);
  return Sample(keys, clip);
}

std::vector<Frame> Crawl(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  const double freq = clip.U(0.5, 1.2);
  const double speed = clip.U(0.2, 0.6);
  const double amp = clip.U(10, 25) * kDeg;
  const Eigen::Quaterniond root =
      Yaw(heading) *
      AxisRotation(M_PI / 2 + clip.U(-10, 10) * kDeg, Eigen::Vector3d::UnitX());
  std::vector<Frame> frames(clip.num_frames);
  for (int i = 0; i < clip.num_frames; ++i) {
    const double phase = kTwoPi * freq * clip.Time(i);
    Frame& f = frames[i];
    f.root = root;
    AnatomicalPose& p = f.angles;
    p = AnatomicalPose{};
    // Thighs down to the floor, shanks along it; arms down to the floor.
    p[kLeftHip].flexion = 90 * kDeg + amp * std::cos(phase);
    p[kRightHip].flexion = 90 * kDeg + amp * std::cos(phase + M_PI);
    SetBoth(p, kLeftKnee, kRightKnee, {90 * kDeg, 0, 0});
    p[kLeftShoulder] = {90 * kDeg + amp * std::cos(phase + M_PI), -5 * kDeg, 0};
    p[kRightShoulder] = {90 * kDeg + amp * std::cos(phase), -5 * kDeg, 0};
    SetBoth(p, kLeftWrist, kRightWrist, {-70 * kDeg, 0, 0});
    p[kHead].flexion = -30 * kDeg;
    const Eigen::Vector3d forward = Yaw(heading) * Eigen::Vector3d(0, -1, 0);
    f.xy = forward.head<2>() * speed * clip.Time(i);
  }
  return frames;
}

// ---------------------------------------------------------------------------
// Inverted and acrobatic.

std::vector<Frame> Handstand(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  Frame stand = Standing(clip, heading);
  Frame arms_up = stand;
  SetBoth(arms_up.angles, kLeftShoulder, kRightShoulder, {0, 85 * kDeg, 0});
  Frame inverted = arms_up;
  inverted.root = Yaw(heading) * AxisRotation(M_PI + clip.U(-15, 15) * kDeg,
                                              Eigen::Vector3d::UnitX());
  const double split = clip.U(0, 1);
  if (split < 0.4) {
    SetBoth(inverted.angles, kLeftHip, kRightHip, {0, clip.U(0, 40) * kDeg, 0});
  } else if (split < 0.7) {
    inverted.angles[kLeftHip].flexion = clip.U(30, 90) * kDeg;
    inverted.angles[kRightHip].flexion = -clip.U(10, 30) * kDeg;
  } else {
    SetBoth(
        inverted.angles, kLeftKnee, kRightKnee, {clip.U(30, 120) * kDeg, 0, 0});
  }
  SetSpine(inverted.angles, -clip.U(0, 25) * kDeg);
  Frame hold = inverted;
  SetSpine(hold.angles, -clip.U(0, 25) * kDeg, clip.U(-10, 10) * kDeg);
  Keyframes keys;
  keys.Add(0.0, stand);
  keys.Add(0.15, arms_up);
  keys.Add(0.35, inverted);
  keys.Add(0.7, hold);
  keys.Add(0.85, inverted);
  keys.Add(1.0, clip.Coin(0.3) ? arms_up : inverted);
  return Sample(keys, clip);
}

std::vector<Frame> Cartwheel(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  const double direction = clip.Coin() ? 1.0 : -1.0;
  const double distance = clip.U(1.0, 2.0);
  std::vector<Frame> frames(clip.num_frames);
  for (int i = 0; i < clip.num_frames; ++i) {
    const double w = Smoothstep(
        i / static_cast<double>(std::max(1, clip.num_frames - 1)) * 1.2 - 0.1);
    Frame& f = frames[i];
    // Rotation in the frontal plane: about the body's forward axis (Y).
    f.root = Yaw(heading) *
             AxisRotation(direction * kTwoPi * w, Eigen::Vector3d::UnitY());
    SetBoth(
        f.angles, kLeftShoulder, kRightShoulder, {0, clip.U(70, 90) * kDeg, 0});
    SetBoth(f.angles, kLeftElbow, kRightElbow, {0, 0, 0});
    SetBoth(
        f.angles, kLeftHip, kRightHip, {0, 40 * kDeg * std::sin(M_PI * w), 0});
    const Eigen::Vector3d side =
        Yaw(heading) * Eigen::Vector3d(-direction, 0, 0);
    f.xy = side.head<2>() * distance * w;
  }
  return frames;
}

std::vector<Frame> Flip(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  const bool back = clip.Coin();
  const bool tuck = clip.Coin(0.7);
  const double height = clip.U(0.5, 0.9);
  std::vector<Frame> frames(clip.num_frames);
  for (int i = 0; i < clip.num_frames; ++i) {
    const double t = i / static_cast<double>(std::max(1, clip.num_frames - 1));
    const double s = std::clamp((t - 0.3) / 0.4, 0.0, 1.0);  // flight phase
    Frame& f = frames[i];
    f.root =
        Yaw(heading) * AxisRotation((back ? -1 : 1) * kTwoPi * Smoothstep(s),
                                    Eigen::Vector3d::UnitX());
    const double tuck_amount =
        tuck ? std::sin(M_PI * s) : 0.3 * std::sin(M_PI * s);
    SetBoth(f.angles, kLeftHip, kRightHip, {120 * kDeg * tuck_amount, 0, 0});
    SetBoth(f.angles, kLeftKnee, kRightKnee, {130 * kDeg * tuck_amount, 0, 0});
    SetBoth(f.angles,
            kLeftShoulder,
            kRightShoulder,
            {60 * kDeg * tuck_amount,
             (-80 + 150 * std::sin(M_PI * std::min(1.0, t / 0.3))) * kDeg *
                     (1 - s) +
                 -20 * kDeg * s,
             0});
    SetSpine(f.angles, 40 * kDeg * tuck_amount);
    f.lift = (s > 0 && s < 1) ? 4 * height * s * (1 - s) : 0.0;
  }
  return frames;
}

std::vector<Frame> MartialArts(const Clip& clip) {
  const double heading = clip.U(-M_PI, M_PI);
  Frame stance = Standing(clip, heading);
  SetBoth(stance.angles,
          kLeftHip,
          kRightHip,
          {clip.U(10, 30) * kDeg, clip.U(10, 25) * kDeg, 0});
  SetBoth(stance.angles, kLeftKnee, kRightKnee, {clip.U(20, 50) * kDeg, 0, 0});
  stance.angles[kLeftShoulder] = {70 * kDeg, -40 * kDeg, 0};
  stance.angles[kRightShoulder] = {70 * kDeg, -40 * kDeg, 0};
  SetBoth(stance.angles, kLeftElbow, kRightElbow, {110 * kDeg, 0, 0});
  Keyframes keys;
  keys.Add(0.0, stance);
  const int moves = 2 + static_cast<int>(clip.U(0, 3));
  for (int m = 0; m < moves; ++m) {
    Frame f = stance;
    const double kind = clip.U(0, 1);
    const bool left = clip.Coin();
    if (kind < 0.4) {  // punch
      f.angles[left ? kLeftShoulder : kRightShoulder] = {
          clip.U(80, 100) * kDeg, clip.U(-20, 10) * kDeg, 0};
      f.angles[left ? kLeftElbow : kRightElbow].flexion = clip.U(0, 15) * kDeg;
      SetSpine(f.angles, 5 * kDeg, 0, (left ? -1 : 1) * clip.U(15, 35) * kDeg);
    } else if (kind < 0.7) {  // front or side kick, high
      f.angles[left ? kLeftHip : kRightHip] = {
          clip.U(70, 120) * kDeg, clip.U(0, 60) * kDeg, 0};
      f.angles[left ? kLeftKnee : kRightKnee].flexion = clip.U(0, 30) * kDeg;
      SetSpine(f.angles,
               -clip.U(10, 30) * kDeg,
               (left ? -1 : 1) * clip.U(0, 30) * kDeg);
    } else {  // roundhouse: leg abducted and turned
      f.angles[left ? kLeftHip : kRightHip] = {
          clip.U(40, 80) * kDeg, clip.U(50, 80) * kDeg, clip.U(-40, 0) * kDeg};
      f.angles[left ? kLeftKnee : kRightKnee].flexion = clip.U(10, 60) * kDeg;
      SetSpine(f.angles,
               -10 * kDeg,
               (left ? -1 : 1) * clip.U(20, 35) * kDeg,
               (left ? 1 : -1) * clip.U(20, 40) * kDeg);
    }
    const double t0 = (m + 0.6) / (moves + 0.5);
    keys.Add(t0 - 0.12 / moves, stance);
    keys.Add(t0, f);
    keys.Add(t0 + 0.12 / moves, stance);
  }
  keys.Add(1.0, stance);
  return Sample(keys, clip);
}

/// Random poses anywhere inside the joint limits, with any root
/// orientation, smoothly interpolated.
std::vector<Frame> RandomPose(const Clip& clip) {
  const double range = clip.options->random_pose_range;
  Keyframes keys;
  const int num_keys = 3 + static_cast<int>(clip.U(0, 3));
  for (int k = 0; k < num_keys; ++k) {
    Frame f;
    for (int j = 1; j < kNumCoreJoints; ++j) {
      const JointLimits& lim = CoreJointLimits(j);
      auto draw = [&](const std::array<double, 2>& r) {
        const double mid = 0.5 * (r[0] + r[1]),
                     half = 0.5 * (r[1] - r[0]) * range;
        return clip.U(mid - half, mid + half);
      };
      f.angles[j] = {draw(lim.flexion), draw(lim.abduction), draw(lim.twist)};
    }
    f.angles[kPelvis] = {};
    f.root = RandomRotation(*clip.rng);
    keys.Add(k / static_cast<double>(num_keys - 1), f);
  }
  return Sample(keys, clip);
}

/// Adds a smooth random head turn to every frame (ProceduralMotionOptions::
/// head_turn_deg): yaw, pitch and roll as sums of two sinusoids each, split
/// evenly over the neck and head joints.
void LookAround(const Clip& clip, std::vector<Frame>& frames) {
  const double max_yaw = clip.options->head_turn_deg * kDeg;
  struct Wave {
    double amplitude[2], freq[2], phase[2];
    double At(double t) const {
      return amplitude[0] * std::sin(kTwoPi * freq[0] * t + phase[0]) +
             amplitude[1] * std::sin(kTwoPi * freq[1] * t + phase[1]);
    }
  };
  auto draw = [&](double max_amplitude) {
    Wave w;
    const double total = clip.U(0, max_amplitude);
    const double split = clip.U(0.2, 0.8);
    w.amplitude[0] = total * split;
    w.amplitude[1] = total * (1 - split);
    for (int k = 0; k < 2; ++k) {
      w.freq[k] = clip.U(0.1, 0.6);
      w.phase[k] = clip.U(0, kTwoPi);
    }
    return w;
  };
  const Wave yaw = draw(max_yaw);
  const Wave pitch = draw(0.5 * max_yaw);
  const Wave roll = draw(0.25 * max_yaw);
  for (size_t i = 0; i < frames.size(); ++i) {
    const double t = clip.Time(static_cast<int>(i));
    for (int j : {kNeck, kHead}) {
      JointAngles& a = frames[i].angles[j];
      a.twist += 0.5 * yaw.At(t);
      a.flexion += 0.5 * pitch.At(t);
      a.abduction += 0.5 * roll.At(t);
    }
  }
}

using Generator = std::function<std::vector<Frame>(const Clip&)>;

const std::vector<std::pair<std::string, Generator>>& Generators() {
  static const std::vector<std::pair<std::string, Generator>> kGenerators = {
      {"walk", Walk},
      {"run", Run},
      {"crouch_walk", CrouchWalk},
      {"bear_walk", BearWalk},
      {"jump", Jump},
      {"squat", Squat},
      {"kick", Kick},
      {"throw", Throw},
      {"reach", Reach},
      {"turn", Turn},
      {"sit", Sit},
      {"lie_down", LieDown},
      {"crawl", Crawl},
      {"kneel", Kneel},
      {"cartwheel", Cartwheel},
      {"handstand", Handstand},
      {"flip", Flip},
      {"martial_arts", MartialArts},
      {"random_pose", RandomPose},
  };
  return kGenerators;
}

double JointRadius(int joint) {
  switch (joint) {
    case kPelvis:
    case kSpine1:
    case kSpine2:
    case kSpine3:
      return 0.10;
    case kLeftHip:
    case kRightHip:
    case kHead:
      return 0.09;
    case kNeck:
    case kLeftCollar:
    case kRightCollar:
    case kLeftShoulder:
    case kRightShoulder:
      return 0.06;
    case kLeftKnee:
    case kRightKnee:
    case kLeftAnkle:
    case kRightAnkle:
      return 0.055;
    case kLeftElbow:
    case kRightElbow:
      return 0.04;
    default:  // wrists, hands, feet (toe base)
      return 0.03;
  }
}

}  // namespace

const std::vector<std::string>& ProceduralMotionTypes() {
  static const std::vector<std::string> kTypes = [] {
    std::vector<std::string> types;
    for (const auto& [name, generator] : Generators()) types.push_back(name);
    return types;
  }();
  return kTypes;
}

void ApplyGroundContact(const BodyModel& body,
                        const Eigen::Matrix3Xd& rest_joints,
                        BodyPose& pose,
                        double lift) {
  pose.translation.z() = 0.0;
  const PosedSkeleton skeleton = PoseSkeleton(body, rest_joints, pose);
  double lowest = std::numeric_limits<double>::infinity();
  const int joints = std::min<int>(body.num_joints(), kNumCoreJoints);
  for (int j = 0; j < joints; ++j) {
    lowest =
        std::min(lowest, skeleton.global[j].translation().z() - JointRadius(j));
  }
  pose.translation.z() = lift - lowest;
}

PoseSequence GenerateProceduralMotion(const std::string& type,
                                      const BodyModel& body,
                                      const ProceduralMotionOptions& options,
                                      Rng& rng) {
  const auto& generators = Generators();
  auto it = std::find_if(generators.begin(),
                         generators.end(),
                         [&](const auto& g) { return g.first == type; });
  if (it == generators.end()) {
    throw ConfigError(
        fmt::format("Unknown procedural motion '{}'. Known motions: {}",
                    type,
                    fmt::join(ProceduralMotionTypes(), ", ")));
  }
  SOMA_CHECK_GT(options.frame_rate, 0.0);
  SOMA_CHECK_GT(options.duration_s, 0.0);
  Clip clip{std::max(1,
                     static_cast<int>(
                         std::lround(options.duration_s * options.frame_rate))),
            options.frame_rate,
            &rng,
            &options};
  std::vector<Frame> frames = it->second(clip);
  if (options.head_turn_deg > 0 && type != "random_pose")
    LookAround(clip, frames);

  // Per-clip random offsets of every angle (individual style), then clamp to
  // the joint limits.
  AnatomicalPose jitter{};
  const double jitter_rad = options.joint_jitter_deg * kDeg;
  for (int j = 1; j < kNumCoreJoints; ++j) {
    jitter[j] = {rng.Normal(0, jitter_rad),
                 rng.Normal(0, jitter_rad),
                 rng.Normal(0, jitter_rad)};
  }
  const Eigen::Matrix3Xd rest_joints = body.RestJoints(body.template_vertices);
  PoseSequence sequence;
  sequence.name = type;
  sequence.source = "procedural";
  sequence.frame_rate = options.frame_rate;
  sequence.frames.reserve(frames.size());
  for (Frame& f : frames) {
    for (int j = 1; j < kNumCoreJoints; ++j) {
      const JointLimits& lim = CoreJointLimits(j);
      JointAngles& a = f.angles[j];
      a.flexion = std::clamp(
          a.flexion + jitter[j].flexion, lim.flexion[0], lim.flexion[1]);
      a.abduction = std::clamp(a.abduction + jitter[j].abduction,
                               lim.abduction[0],
                               lim.abduction[1]);
      a.twist =
          std::clamp(a.twist + jitter[j].twist, lim.twist[0], lim.twist[1]);
    }
    const Eigen::AngleAxisd root(f.root);
    BodyPose pose = ToBodyPose(f.angles,
                               root.axis() * root.angle(),
                               Eigen::Vector3d(f.xy.x(), f.xy.y(), 0.0),
                               body.num_joints());
    ApplyGroundContact(body, rest_joints, pose, f.lift);
    sequence.frames.push_back(std::move(pose));
  }
  return sequence;
}

}  // namespace soma
