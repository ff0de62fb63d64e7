// Wall-clock timing helpers.
#pragma once

#include <chrono>
#include <string>

namespace soma {

/// A monotonic stopwatch started at construction.
class Timer {
 public:
  Timer() : start_(std::chrono::steady_clock::now()) {}
  void Restart() { start_ = std::chrono::steady_clock::now(); }
  double ElapsedSeconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() -
                                         start_)
        .count();
  }

 private:
  std::chrono::steady_clock::time_point start_;
};

/// "1h02m03s", "4m05s", "6.7s" — for progress bars and logs.
std::string FormatDuration(double seconds);

}  // namespace soma
