// One frame of a live (or replayed) marker stream: the raw, unlabelled points
// of a capture frame as an optical system reports them.
#pragma once

#include <cstdint>
#include <vector>

namespace soma {

/// A raw capture frame. Points are in the source's units (the TCP protocol:
/// millimetres; a replayed C3D: the file's units).
struct StreamFrame {
  /// The capture's frame number (strictly increasing within a stream).
  int64_t number = 0;
  /// Capture timestamp, seconds (the source's clock).
  double timestamp = 0.0;
  /// Per point: the capture system's trajectory id (a point of trajectory
  /// `id` in one frame and a point of the same id in a later frame are the
  /// same marker as far as the system knows), or -1 for none.
  std::vector<int32_t> track_ids;
  /// Per point x, y, z (3 floats per point).
  std::vector<float> xyz;
  /// Per point residual; < 0 marks an invalid point (ignored).
  std::vector<float> residuals;
  /// Steady-clock seconds (SteadySeconds()) when the frame was complete at
  /// the source: the start of its latency.
  double arrival = 0.0;

  int num_points() const { return static_cast<int>(track_ids.size()); }
  /// True if point `i` is a real point: residual >= 0, finite, not (0,0,0).
  bool IsPresent(int i) const;
  /// Appends a point.
  void Add(int32_t track_id, float x, float y, float z, float residual = 0.f);
};

/// Seconds of std::chrono::steady_clock (the clock of StreamFrame::arrival).
double SteadySeconds();

}  // namespace soma
