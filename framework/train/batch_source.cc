#include "framework/train/batch_source.h"

#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/core/timer.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstring>
#include <utility>

namespace soma {
namespace {

void ResizeFrames(int64_t frames,
                  int num_points,
                  int num_slots,
                  LabeledFrames* out) {
  out->num_points = num_points;
  out->num_slots = num_slots;
  out->slots.resize(static_cast<size_t>(frames * num_slots));
  out->points.resize(static_cast<size_t>(frames * num_points * 3));
  out->labels.resize(static_cast<size_t>(frames * num_points));
}

void CopyFrame(const LabeledFrames& from,
               int64_t src,
               LabeledFrames* to,
               int64_t dst) {
  const int n = from.num_points;
  std::memcpy(to->frame_points(dst),
              from.frame_points(src),
              sizeof(float) * 3 * static_cast<size_t>(n));
  std::memcpy(to->frame_labels(dst),
              from.frame_labels(src),
              sizeof(int16_t) * static_cast<size_t>(n));
  if (from.num_slots > 0) {
    std::memcpy(to->frame_slots(dst),
                from.frame_slots(src),
                sizeof(int16_t) * static_cast<size_t>(from.num_slots));
  }
}

}  // namespace

std::vector<int64_t> EpochPermutation(uint64_t seed,
                                      int epoch,
                                      int64_t num_frames) {
  Rng rng = Rng(seed).Stream("epoch").Stream(static_cast<uint64_t>(epoch));
  const std::vector<int> perm = rng.Permutation(static_cast<int>(num_frames));
  return std::vector<int64_t>(perm.begin(), perm.end());
}

InMemoryBatchSource::InMemoryBatchSource(LabeledFrames frames,
                                         std::vector<std::string> labels,
                                         bool shuffle,
                                         uint64_t seed)
    : frames_(std::move(frames)),
      labels_(std::move(labels)),
      shuffle_(shuffle),
      seed_(seed) {
  if (frames_.num_points <= 0 ||
      frames_.points.size() != frames_.labels.size() * 3) {
    throw ShapeError(
        fmt::format("InMemoryBatchSource: inconsistent frames (N = {}, {} "
                    "point floats, {} labels)",
                    frames_.num_points,
                    frames_.points.size(),
                    frames_.labels.size()));
  }
}

void InMemoryBatchSource::Read(int epoch,
                               int64_t begin,
                               int64_t count,
                               LabeledFrames* out) const {
  const int64_t total = frames_.num_frames();
  if (begin < 0 || count < 0 || begin + count > total) {
    throw ShapeError(fmt::format(
        "InMemoryBatchSource::Read: frames [{}, {}) outside [0, {})",
        begin,
        begin + count,
        total));
  }
  ResizeFrames(count, frames_.num_points, frames_.num_slots, out);
  if (!shuffle_) {
    for (int64_t i = 0; i < count; ++i) CopyFrame(frames_, begin + i, out, i);
    return;
  }
  const std::vector<int64_t> order = EpochPermutation(seed_, epoch, total);
  for (int64_t i = 0; i < count; ++i) {
    CopyFrame(frames_, order[static_cast<size_t>(begin + i)], out, i);
  }
}

Prefetcher::Prefetcher(const BatchSource& source,
                       std::vector<BatchRequest> requests,
                       int depth)
    : source_(source), requests_(std::move(requests)), depth_(depth) {
  if (depth_ > 0 && !requests_.empty()) {
    thread_ = std::thread([this] { Run(); });
  }
}

Prefetcher::~Prefetcher() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void Prefetcher::Run() {
  for (const BatchRequest& request : requests_) {
    LabeledFrames buffer;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      cv_.wait(lock, [this] {
        return stop_ || static_cast<int>(ready_.size()) < depth_;
      });
      if (stop_) return;
      if (!free_.empty()) {
        buffer = std::move(free_.back());
        free_.pop_back();
      }
    }
    try {
      source_.Read(request.epoch, request.begin, request.count, &buffer);
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex_);
      error_ = std::current_exception();
      done_ = true;
      cv_.notify_all();
      return;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ready_.push_back(std::move(buffer));
    }
    cv_.notify_all();
  }
  std::lock_guard<std::mutex> lock(mutex_);
  done_ = true;
  cv_.notify_all();
}

bool Prefetcher::Next(LabeledFrames* out) {
  if (next_ >= requests_.size()) return false;
  if (depth_ <= 0) {
    const BatchRequest& r = requests_[next_++];
    source_.Read(r.epoch, r.begin, r.count, out);
    return true;
  }
  Timer timer;
  std::unique_lock<std::mutex> lock(mutex_);
  cv_.wait(lock, [this] { return !ready_.empty() || done_; });
  wait_seconds_ += timer.ElapsedSeconds();
  if (ready_.empty()) {
    if (error_) std::rethrow_exception(error_);
    throw InternalError("Prefetcher: the reader stopped early");
  }
  // The caller's previous buffer is recycled for a later read.
  std::swap(*out, ready_.front());
  free_.push_back(std::move(ready_.front()));
  ready_.pop_front();
  ++next_;
  lock.unlock();
  cv_.notify_all();
  return true;
}

}  // namespace soma
