#include "framework/core/progress.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <unistd.h>

namespace soma {

std::string FormatDuration(double seconds) {
  if (!(seconds >= 0) || seconds > 1e8) return "?";
  if (seconds < 60) return fmt::format("{:.1f}s", seconds);
  const int64_t total = std::llround(seconds);
  const int64_t h = total / 3600, m = (total % 3600) / 60, s = total % 60;
  if (h > 0) return fmt::format("{}h{:02d}m{:02d}s", h, m, s);
  return fmt::format("{}m{:02d}s", m, s);
}

ProgressBar::ProgressBar(int64_t total, Options options)
    : total_(std::max<int64_t>(total, 0)),
      options_(std::move(options)),
      is_tty_(::isatty(STDERR_FILENO) != 0) {}

ProgressBar::~ProgressBar() {
  if (!finished_) Finish();
}

double ProgressBar::Rate() const {
  const double elapsed = timer_.ElapsedSeconds();
  return elapsed > 0 ? static_cast<double>(done_ - start_done_) / elapsed : 0.0;
}

std::string ProgressBar::StatusLine() const {
  const double fraction =
      total_ > 0 ? std::min(1.0, static_cast<double>(done_) / total_) : 0.0;
  constexpr int kWidth = 28;
  const int filled = static_cast<int>(fraction * kWidth);
  std::string bar(filled, '#');
  bar.resize(kWidth, '.');
  const double rate = Rate();
  const double eta = rate > 0 ? static_cast<double>(total_ - done_) / rate : -1;
  std::string line =
      fmt::format("{}{}[{}] {:3.0f}% {}/{} | {:.1f} {}/s | {} elapsed, ETA {}",
                  options_.label,
                  options_.label.empty() ? "" : " ",
                  bar,
                  100 * fraction,
                  done_,
                  total_,
                  rate,
                  options_.unit,
                  FormatDuration(timer_.ElapsedSeconds()),
                  done_ >= total_ ? "0.0s" : FormatDuration(eta));
  if (!postfix_.empty()) line += " | " + postfix_;
  return line;
}

void ProgressBar::Draw(bool force) {
  if (!options_.enabled) return;
  const double now = timer_.ElapsedSeconds();
  const double interval = is_tty_ ? 0.1 : options_.plain_interval_s;
  if (!force && now - last_draw_s_ < interval) return;
  last_draw_s_ = now;
  const std::string line = StatusLine();
  if (is_tty_) {
    std::fprintf(stderr, "\r\033[K%s", line.c_str());
  } else {
    std::fprintf(stderr, "%s\n", line.c_str());
  }
  std::fflush(stderr);
}

void ProgressBar::Update(int64_t n, const std::string& postfix) {
  done_ += n;
  if (!postfix.empty()) postfix_ = postfix;
  Draw(false);
}

void ProgressBar::SetPosition(int64_t done) {
  done_ = done;
  start_done_ = done;
  timer_.Restart();
}

void ProgressBar::Finish() {
  if (finished_) return;
  finished_ = true;
  Draw(true);
  if (is_tty_ && options_.enabled) {
    std::fputc('\n', stderr);
    std::fflush(stderr);
  }
}

}  // namespace soma
