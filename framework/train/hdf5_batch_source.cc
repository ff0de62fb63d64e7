// Hdf5BatchSource (kept apart from batch_source.cc so that code using only
// the in-memory source does not link HDF5).
#include "framework/core/error.h"
#include "framework/train/batch_source.h"

#include <fmt/format.h>

#include <mutex>

namespace soma {

struct Hdf5BatchSource::Impl {
  explicit Impl(const std::filesystem::path& path) : reader(path) {}
  DatasetReader reader;
  bool shuffle = false;
  uint64_t seed = 0;
  mutable std::mutex mutex;
  // The permutation of the last epoch read (recomputed per epoch).
  mutable int cached_epoch = -1;
  mutable std::vector<int64_t> order;
};

Hdf5BatchSource::Hdf5BatchSource(const std::filesystem::path& path,
                                 bool shuffle,
                                 uint64_t seed,
                                 int64_t max_frames)
    : impl_(std::make_unique<Impl>(path)) {
  impl_->shuffle = shuffle;
  impl_->seed = seed;
  frames_per_epoch_ = impl_->reader.num_frames();
  if (max_frames > 0 && max_frames < frames_per_epoch_) {
    frames_per_epoch_ = max_frames;
  }
  if (frames_per_epoch_ < 1) {
    throw IoError(fmt::format("{}: the dataset has no frames", path.string()));
  }
}

Hdf5BatchSource::~Hdf5BatchSource() = default;

const std::vector<std::string>& Hdf5BatchSource::labels() const {
  return impl_->reader.info().labels;
}

int Hdf5BatchSource::num_points() const {
  return impl_->reader.info().num_points;
}

const SlotTable* Hdf5BatchSource::slot_table() const {
  const DatasetInfo& info = impl_->reader.info();
  return info.num_slots > 0 ? &info.slot_table : nullptr;
}

void Hdf5BatchSource::Read(int epoch,
                           int64_t begin,
                           int64_t count,
                           LabeledFrames* out) const {
  if (begin < 0 || count < 0 || begin + count > frames_per_epoch_) {
    throw ShapeError(
        fmt::format("Hdf5BatchSource::Read: frames [{}, {}) outside [0, {})",
                    begin,
                    begin + count,
                    frames_per_epoch_));
  }
  std::lock_guard<std::mutex> lock(impl_->mutex);
  if (!impl_->shuffle) {
    impl_->reader.Read(begin, count, out);
    return;
  }
  if (impl_->cached_epoch != epoch) {
    impl_->order =
        EpochPermutation(impl_->seed, epoch, impl_->reader.num_frames());
    impl_->cached_epoch = epoch;
  }
  const std::vector<int64_t> indices(impl_->order.begin() + begin,
                                     impl_->order.begin() + begin + count);
  impl_->reader.ReadIndices(indices, out);
}

}  // namespace soma
