// AMASS motion (.npz with SMPL / SMPL+H / SMPL-X pose parameters) as a
// motion source: the body joints' axis-angle rotations are carried over to
// the core joints (same joint order as SMPL), converted from SMPL's Y-up
// frame to ours; the root trajectory's horizontal part is kept and each clip
// is put on the floor by the same ground-contact rule as retargeted clips.
#pragma once

#include "framework/body/body_model.h"
#include "framework/motion/pose_sequence.h"

#include <filesystem>

namespace soma {

/// Reads an AMASS npz (`poses` T x 3J with J >= 22 (SMPL+H 52, SMPL-X 55),
/// `trans` T x 3, `mocap_framerate` or `mocap_frame_rate`). IoError naming
/// the file and key on missing keys or wrong shapes. Hands, jaw and eyes are
/// ignored; core joints 22/23 (hands) stay at rest.
PoseSequence LoadAmassNpz(const std::filesystem::path& path,
                          const BodyModel& body);

/// Resamples a pose sequence to `frame_rate` (slerp per joint, linear
/// translation). Frame 0 is kept; the duration is preserved.
PoseSequence ResamplePoseSequence(const PoseSequence& sequence,
                                  double frame_rate);

}  // namespace soma
