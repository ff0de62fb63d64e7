// A sequence of body poses: the output of every motion source.
#pragma once

#include "framework/body/body_model.h"

#include <string>
#include <vector>

namespace soma {

struct PoseSequence {
  std::string name;          // e.g. "walk_003" or a file stem
  std::string source;        // "procedural", "bvh:<path>", "amc:<path>", ...
  double frame_rate = 30.0;  // Hz
  std::vector<BodyPose> frames;

  int num_frames() const { return static_cast<int>(frames.size()); }
};

}  // namespace soma
