// A progress bar with rate and ETA.
//
// On a terminal it redraws one line on stderr (at most 10 times a second); when
// stderr is not a terminal (CI, a log file) it prints a plain line at most
// every `plain_interval_s` seconds and one at the end, so logs stay readable.
#pragma once

#include "framework/core/timer.h"

#include <cstdint>
#include <string>

namespace soma {

class ProgressBar {
 public:
  struct Options {
    std::string label;             // shown before the bar, e.g. "synth"
    std::string unit = "it";       // rate unit, e.g. "frames"
    double plain_interval_s = 10;  // non-terminal: seconds between lines
    bool enabled = true;           // false: print nothing at all
  };

  ProgressBar(int64_t total, Options options);
  ProgressBar(const ProgressBar&) = delete;
  ProgressBar& operator=(const ProgressBar&) = delete;
  /// Finishes the line if Finish() was not called.
  ~ProgressBar();

  /// Advances by `n` items; `postfix` (e.g. "loss=0.12") is shown after.
  void Update(int64_t n = 1, const std::string& postfix = "");
  /// Sets the absolute position (for resumed work).
  void SetPosition(int64_t done);
  void Finish();

  int64_t done() const { return done_; }
  /// Items per second since construction (or since SetPosition).
  double Rate() const;
  /// The text of the current status line (without terminal control codes).
  std::string StatusLine() const;

 private:
  void Draw(bool force);

  int64_t total_;
  int64_t done_ = 0;
  int64_t start_done_ = 0;
  Options options_;
  bool is_tty_;
  bool finished_ = false;
  std::string postfix_;
  Timer timer_;
  double last_draw_s_ = -1e9;
};

}  // namespace soma
