// SynthBatchSource (kept apart from batch_source.cc so that code using only
// the in-memory source does not link the synthesizer).
#include "framework/core/error.h"
#include "framework/synth/synthesizer.h"
#include "framework/train/batch_source.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstring>

namespace soma {

SynthBatchSource::SynthBatchSource(const Synthesizer& synthesizer,
                                   Mode mode,
                                   uint64_t seed,
                                   int64_t frames_per_epoch,
                                   int threads)
    : synthesizer_(&synthesizer),
      mode_(mode),
      seed_(seed),
      frames_per_epoch_(frames_per_epoch),
      threads_(threads < 1 ? 1 : threads) {
  if (frames_per_epoch_ < 1) {
    throw ConfigError(
        fmt::format("SynthBatchSource: frames per epoch must be >= 1, got {}",
                    frames_per_epoch_));
  }
}

SynthBatchSource::~SynthBatchSource() = default;

const std::vector<std::string>& SynthBatchSource::labels() const {
  return synthesizer_->labels();
}

int SynthBatchSource::num_points() const { return synthesizer_->num_points(); }

const SlotTable* SynthBatchSource::slot_table() const {
  return synthesizer_->slot_table();
}

namespace {

int NumSlots(const Synthesizer& synthesizer) {
  return synthesizer.layout_sampler() == nullptr
             ? 0
             : synthesizer.layout_sampler()->options().max_labels;
}

void CopySlots(const LabeledFrames& from,
               int64_t src,
               int64_t count,
               LabeledFrames* to,
               int64_t dst) {
  if (from.num_slots == 0 || count == 0) return;
  std::memcpy(to->frame_slots(dst),
              from.frame_slots(src),
              sizeof(int16_t) * static_cast<size_t>(count * from.num_slots));
}

}  // namespace

void SynthBatchSource::Fill(int64_t begin, int64_t end) const {
  const int n = synthesizer_->num_points();
  if (generated_.empty()) {
    cache_.num_points = n;
    cache_.points.assign(static_cast<size_t>(frames_per_epoch_) * n * 3, 0.f);
    cache_.labels.assign(static_cast<size_t>(frames_per_epoch_) * n, 0);
    cache_.num_slots = NumSlots(*synthesizer_);
    cache_.slots.assign(
        static_cast<size_t>(frames_per_epoch_) * cache_.num_slots, -1);
    generated_.assign(static_cast<size_t>(frames_per_epoch_), false);
  }
  LabeledFrames run;
  int64_t f = begin;
  while (f < end) {
    if (generated_[static_cast<size_t>(f)]) {
      ++f;
      continue;
    }
    int64_t stop = f;
    while (stop < end && !generated_[static_cast<size_t>(stop)]) ++stop;
    synthesizer_->Generate(seed_, f, stop - f, &run, threads_);
    std::memcpy(cache_.frame_points(f),
                run.points.data(),
                sizeof(float) * run.points.size());
    std::memcpy(cache_.frame_labels(f),
                run.labels.data(),
                sizeof(int16_t) * run.labels.size());
    CopySlots(run, 0, stop - f, &cache_, f);
    std::fill(generated_.begin() + f, generated_.begin() + stop, true);
    f = stop;
  }
}

void SynthBatchSource::Read(int epoch,
                            int64_t begin,
                            int64_t count,
                            LabeledFrames* out) const {
  if (begin < 0 || count < 0 || begin + count > frames_per_epoch_) {
    throw ShapeError(
        fmt::format("SynthBatchSource::Read: frames [{}, {}) outside [0, {})",
                    begin,
                    begin + count,
                    frames_per_epoch_));
  }
  if (mode_ == Mode::kStream) {
    synthesizer_->Generate(
        seed_,
        static_cast<int64_t>(epoch) * frames_per_epoch_ + begin,
        count,
        out,
        threads_);
    return;
  }
  std::lock_guard<std::mutex> lock(cache_mutex_);
  const int n = synthesizer_->num_points();
  out->num_points = n;
  out->points.resize(static_cast<size_t>(count) * n * 3);
  out->labels.resize(static_cast<size_t>(count) * n);
  out->num_slots = NumSlots(*synthesizer_);
  out->slots.resize(static_cast<size_t>(count) * out->num_slots);
  if (mode_ == Mode::kFixed || epoch == 0) {
    // In order: generate this range and a little ahead, in chunks large
    // enough for `threads_` workers (epoch 0 of a pool overlaps the
    // synthesis with training).
    const int64_t chunk = std::max<int64_t>(count, 128 * threads_);
    Fill(begin, std::min(frames_per_epoch_, begin + chunk));
    std::memcpy(out->points.data(),
                cache_.frame_points(begin),
                sizeof(float) * out->points.size());
    std::memcpy(out->labels.data(),
                cache_.frame_labels(begin),
                sizeof(int16_t) * out->labels.size());
    CopySlots(cache_, begin, count, out, 0);
    return;
  }
  Fill(0, frames_per_epoch_);  // a resumed run regenerates the pool once
  if (order_epoch_ != epoch) {
    order_ = EpochPermutation(seed_, epoch, frames_per_epoch_);
    order_epoch_ = epoch;
  }
  const std::vector<int64_t>& order = order_;
  for (int64_t i = 0; i < count; ++i) {
    const int64_t f = order[static_cast<size_t>(begin + i)];
    std::memcpy(out->frame_points(i),
                cache_.frame_points(f),
                sizeof(float) * 3 * static_cast<size_t>(n));
    std::memcpy(out->frame_labels(i),
                cache_.frame_labels(f),
                sizeof(int16_t) * static_cast<size_t>(n));
    CopySlots(cache_, f, 1, out, i);
  }
}

}  // namespace soma
