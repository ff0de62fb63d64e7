#include "framework/motion/amass.h"

#include "framework/body/smpl_body.h"
#include "framework/core/error.h"
#include "framework/io/npz.h"
#include "framework/motion/procedural_motion.h"

#include <Eigen/Geometry>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>

namespace soma {
namespace {

/// Number of SMPL body joints whose rotations are used (pelvis .. wrists).
constexpr int kAmassBodyJoints = 22;

const NpyArray& Member(const std::map<std::string, NpyArray>& npz,
                       const std::filesystem::path& path,
                       const std::string& key) {
  auto it = npz.find(key);
  if (it == npz.end()) it = npz.find(key + ".npy");
  if (it == npz.end()) {
    throw IoError(fmt::format(
        "{}: missing key '{}' (not an AMASS pose file?)", path.string(), key));
  }
  return it->second;
}

Eigen::Quaterniond FromAxisAngle(const Eigen::Vector3d& v) {
  const double angle = v.norm();
  if (angle < 1e-12) return Eigen::Quaterniond::Identity();
  return Eigen::Quaterniond(Eigen::AngleAxisd(angle, v / angle));
}

Eigen::Vector3d ToAxisAngle(const Eigen::Quaterniond& q) {
  const Eigen::AngleAxisd aa(q);
  return aa.axis() * aa.angle();
}

}  // namespace

PoseSequence LoadAmassNpz(const std::filesystem::path& path,
                          const BodyModel& body) {
  const std::map<std::string, NpyArray> npz = ReadNpz(path);
  const NpyArray& poses_array = Member(npz, path, "poses");
  const NpyArray& trans_array = Member(npz, path, "trans");
  double frame_rate = 0;
  if (npz.count("mocap_framerate") || npz.count("mocap_framerate.npy")) {
    frame_rate = Member(npz, path, "mocap_framerate").AsDoubles().at(0);
  } else {
    frame_rate = Member(npz, path, "mocap_frame_rate").AsDoubles().at(0);
  }
  if (poses_array.shape.size() != 2 ||
      poses_array.shape[1] < 3 * kAmassBodyJoints ||
      poses_array.shape[1] % 3 != 0) {
    throw IoError(
        fmt::format("{}: 'poses' must be T x 3J with J >= {}; got shape [{}]",
                    path.string(),
                    kAmassBodyJoints,
                    fmt::join(poses_array.shape, ", ")));
  }
  const int64_t frames = poses_array.shape[0];
  if (trans_array.shape.size() != 2 || trans_array.shape[0] != frames ||
      trans_array.shape[1] != 3) {
    throw IoError(fmt::format("{}: 'trans' must be {} x 3; got shape [{}]",
                              path.string(),
                              frames,
                              fmt::join(trans_array.shape, ", ")));
  }
  if (!(frame_rate > 0) || !std::isfinite(frame_rate)) {
    throw IoError(fmt::format(
        "{}: frame rate must be positive, got {}", path.string(), frame_rate));
  }
  const Eigen::MatrixXd poses = poses_array.AsMatrix();
  const Eigen::MatrixXd trans = trans_array.AsMatrix();
  if (!poses.allFinite() || !trans.allFinite()) {
    throw IoError(fmt::format("{}: 'poses' or 'trans' has NaN/inf values",
                              path.string()));
  }
  // An axis-angle vector is an axial vector: under the proper rotation C of
  // the frame change it maps to C v.
  const Eigen::Matrix3d c = SmplToBodyFrame();
  PoseSequence sequence;
  sequence.name = path.stem().string();
  sequence.source = "amass:" + path.string();
  sequence.frame_rate = frame_rate;
  const Eigen::Matrix3Xd rest = body.RestJoints(body.template_vertices);
  std::vector<double> lowest;
  for (int64_t t = 0; t < frames; ++t) {
    BodyPose pose = BodyPose::Rest(body.num_joints());
    for (int j = 0; j < kAmassBodyJoints; ++j) {
      pose.rotations.col(j) = c * poses.block<1, 3>(t, 3 * j).transpose();
    }
    const Eigen::Vector3d world = c * trans.row(t).transpose();
    pose.translation = Eigen::Vector3d(world.x(), world.y(), 0.0);
    BodyPose grounded = pose;
    ApplyGroundContact(body, rest, grounded, 0.0);
    pose.translation.z() = world.z();
    lowest.push_back(world.z() - grounded.translation.z());
    sequence.frames.push_back(pose);
  }
  // One vertical offset per clip (the trans of AMASS refers to the SMPL
  // body's root, not ours): its lowest 5% of frames touch the floor.
  if (!lowest.empty()) {
    std::vector<double> sorted = lowest;
    std::sort(sorted.begin(), sorted.end());
    const double floor = sorted[sorted.size() / 20];
    for (BodyPose& pose : sequence.frames) pose.translation.z() -= floor;
  }
  return sequence;
}

PoseSequence ResamplePoseSequence(const PoseSequence& sequence,
                                  double frame_rate) {
  SOMA_CHECK_GT(frame_rate, 0.0);
  if (sequence.frames.empty() ||
      std::abs(frame_rate - sequence.frame_rate) < 1e-9) {
    PoseSequence copy = sequence;
    copy.frame_rate = frame_rate;
    return copy;
  }
  PoseSequence out = sequence;
  out.frame_rate = frame_rate;
  out.frames.clear();
  const double duration = (sequence.num_frames() - 1) / sequence.frame_rate;
  const int count =
      static_cast<int>(std::floor(duration * frame_rate + 1e-9)) + 1;
  for (int i = 0; i < count; ++i) {
    const double s = i / frame_rate * sequence.frame_rate;
    const int a =
        std::min(static_cast<int>(std::floor(s)), sequence.num_frames() - 1);
    const int b = std::min(a + 1, sequence.num_frames() - 1);
    const double w = s - a;
    const BodyPose& pa = sequence.frames[a];
    const BodyPose& pb = sequence.frames[b];
    BodyPose pose = pa;
    pose.translation = (1 - w) * pa.translation + w * pb.translation;
    for (int j = 0; j < pa.rotations.cols(); ++j) {
      pose.rotations.col(j) =
          ToAxisAngle(FromAxisAngle(pa.rotations.col(j))
                          .slerp(w, FromAxisAngle(pb.rotations.col(j))));
    }
    out.frames.push_back(pose);
  }
  return out;
}

}  // namespace soma
