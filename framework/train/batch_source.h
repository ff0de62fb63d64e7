// Where training and validation frames come from, and the prefetcher that
// reads the next batch on a background thread while the current one trains.
//
// A BatchSource is a pure function of (epoch, frame range): `Read(e, b, c)`
// returns the same frames whenever it is called, from any thread, in any
// order. That is what makes training deterministic and resumable: batch `k`
// of epoch `e` is frames [k*B, (k+1)*B) of epoch `e`'s order, whatever
// happened before.
//
//   InMemoryBatchSource  frames held in memory; optionally a per-epoch
//                        permutation seeded by (seed, epoch) (tests, small
//                        sets).
//   SynthBatchSource     frames synthesised on the fly. Train: a pool of F
//                        frames generated once (during epoch 0) and
//                        reshuffled per epoch, or a stream (epoch e = frames
//                        [e*F, (e+1)*F), fresh data every epoch). Validation:
//                        a fixed set of F frames, generated once and cached.
//   Hdf5BatchSource      a dataset file (DatasetReader); shuffled per epoch
//                        by (seed, epoch), or in file order.
#pragma once

#include "framework/io/mocap_dataset.h"

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace soma {

class Synthesizer;

/// A deterministic source of labelled frames, indexed by epoch.
class BatchSource {
 public:
  virtual ~BatchSource() = default;
  /// The L label names (id order; null id = L).
  virtual const std::vector<std::string>& labels() const = 0;
  int num_labels() const { return static_cast<int>(labels().size()); }
  /// N, points per frame.
  virtual int num_points() const = 0;
  /// The slot table its frames' LabeledFrames::slots index (a
  /// layout-sampled source for a layout-conditioned labeller), or null
  /// when the frames carry no slots.
  virtual const SlotTable* slot_table() const { return nullptr; }
  /// Frames available in one epoch.
  virtual int64_t frames_per_epoch() const = 0;
  /// Frames [begin, begin + count) of epoch `epoch`'s order into `out`
  /// (resized). Deterministic; thread-safe. ShapeError if the range exceeds
  /// frames_per_epoch().
  virtual void Read(int epoch,
                    int64_t begin,
                    int64_t count,
                    LabeledFrames* out) const = 0;
};

/// Frames held in memory.
class InMemoryBatchSource : public BatchSource {
 public:
  /// `shuffle`: epoch e reads the frames in the order
  /// Rng(seed).Stream("epoch").Stream(e).Permutation(F); else in order.
  InMemoryBatchSource(LabeledFrames frames,
                      std::vector<std::string> labels,
                      bool shuffle,
                      uint64_t seed);
  const std::vector<std::string>& labels() const override { return labels_; }
  int num_points() const override { return frames_.num_points; }
  int64_t frames_per_epoch() const override { return frames_.num_frames(); }
  void Read(int epoch,
            int64_t begin,
            int64_t count,
            LabeledFrames* out) const override;
  const LabeledFrames& frames() const { return frames_; }
  /// The table the frames' slots index (frames with LabeledFrames::slots).
  void SetSlotTable(SlotTable table) { slot_table_ = std::move(table); }
  const SlotTable* slot_table() const override {
    return frames_.num_slots > 0 ? &slot_table_ : nullptr;
  }

 private:
  LabeledFrames frames_;
  SlotTable slot_table_;
  std::vector<std::string> labels_;
  bool shuffle_;
  uint64_t seed_;
};

/// The frame order of epoch `epoch` for a shuffled source of `num_frames`
/// frames: a permutation drawn from Rng(seed).Stream("epoch").Stream(epoch).
std::vector<int64_t> EpochPermutation(uint64_t seed,
                                      int epoch,
                                      int64_t num_frames);

/// Frames synthesised on the fly by a Synthesizer (not owned; must outlive
/// the source; Generate() is const and is called from the prefetch thread).
class SynthBatchSource : public BatchSource {
 public:
  enum class Mode {
    /// Epoch e = frames [e*F, (e+1)*F) of stream `seed`: fresh frames every
    /// epoch (synthesis cost every epoch).
    kStream,
    /// A pool of frames [0, F) of stream `seed`, generated once on demand
    /// (in order during epoch 0, so synthesis overlaps training) and
    /// reshuffled every later epoch with EpochPermutation(seed, e, F).
    kPool,
    /// Frames [0, F) of stream `seed` in order every epoch (validation).
    kFixed,
  };
  /// `threads`: generation threads per Read (results do not depend on it).
  SynthBatchSource(const Synthesizer& synthesizer,
                   Mode mode,
                   uint64_t seed,
                   int64_t frames_per_epoch,
                   int threads = 1);
  ~SynthBatchSource() override;
  const std::vector<std::string>& labels() const override;
  int num_points() const override;
  const SlotTable* slot_table() const override;
  int64_t frames_per_epoch() const override { return frames_per_epoch_; }
  void Read(int epoch,
            int64_t begin,
            int64_t count,
            LabeledFrames* out) const override;

 private:
  /// Generates the frames of [begin, end) not generated yet into cache_.
  void Fill(int64_t begin, int64_t end) const;

  const Synthesizer* synthesizer_;
  Mode mode_;
  uint64_t seed_;
  int64_t frames_per_epoch_;
  int threads_;
  // kPool / kFixed: the frames, generated on first use.
  mutable std::mutex cache_mutex_;
  mutable LabeledFrames cache_;
  mutable std::vector<bool> generated_;
  mutable int order_epoch_ = -1;  // kPool: the cached permutation's epoch
  mutable std::vector<int64_t> order_;
};

/// Frames of an HDF5 dataset (DatasetReader). Reads go through one reader
/// under a mutex (HDF5 is not thread-safe).
class Hdf5BatchSource : public BatchSource {
 public:
  /// `shuffle`: per-epoch permutation EpochPermutation(seed, epoch, F); else
  /// file order. `max_frames` > 0 limits the epoch to the first frames of
  /// the file (of the permutation when shuffling).
  Hdf5BatchSource(const std::filesystem::path& path,
                  bool shuffle,
                  uint64_t seed,
                  int64_t max_frames = 0);
  ~Hdf5BatchSource() override;
  const std::vector<std::string>& labels() const override;
  int num_points() const override;
  int64_t frames_per_epoch() const override { return frames_per_epoch_; }
  /// The dataset's slot table when its frames carry label slots.
  const SlotTable* slot_table() const override;
  void Read(int epoch,
            int64_t begin,
            int64_t count,
            LabeledFrames* out) const override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int64_t frames_per_epoch_ = 0;
};

/// One batch to read: frames [begin, begin + count) of `epoch`.
struct BatchRequest {
  int epoch = 0;
  int64_t begin = 0;
  int64_t count = 0;
};

/// Reads a planned sequence of batches ahead on a background thread, at most
/// `depth` batches in flight, so the trainer never waits on I/O or synthesis
/// while it computes. `depth` 0 reads synchronously in Next(). An exception
/// thrown by the source is rethrown by Next(). The destructor stops and joins
/// the thread.
class Prefetcher {
 public:
  Prefetcher(const BatchSource& source,
             std::vector<BatchRequest> requests,
             int depth = 2);
  ~Prefetcher();
  Prefetcher(const Prefetcher&) = delete;
  Prefetcher& operator=(const Prefetcher&) = delete;

  /// The next batch in request order (swapped into `out`); false when all
  /// requests were delivered.
  bool Next(LabeledFrames* out);
  /// Seconds Next() spent waiting for the background thread.
  double wait_seconds() const { return wait_seconds_; }

 private:
  void Run();

  const BatchSource& source_;
  std::vector<BatchRequest> requests_;
  int depth_;
  size_t next_ = 0;  // next request to deliver
  double wait_seconds_ = 0;

  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<LabeledFrames> ready_;
  std::vector<LabeledFrames> free_;  // recycled buffers
  std::exception_ptr error_;
  bool stop_ = false;
  bool done_ = false;
  std::thread thread_;
};

}  // namespace soma
