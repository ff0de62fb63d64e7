#include "framework/model/fast_parallel.h"

#include <ATen/Parallel.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <exception>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

namespace soma::internal {
namespace {

/// Spin iterations a worker waits for the next job before it sleeps (~0.2
/// ms: the gaps between the regions of a step are shorter).
constexpr int kWorkerSpins = 20000;
/// Spin iterations the caller waits for running chunks before yielding.
constexpr int kCallerSpins = 4000;
/// Chunks per job at most (the job word holds 16-bit counts).
constexpr int64_t kMaxChunks = 0xFFFF;

inline void CpuRelax() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#endif
}

thread_local int tls_thread_index = 0;
thread_local bool tls_in_job = false;

/// The job word: epoch (32 bits) | front (16) | back (16): the chunks not yet
/// claimed are [front, back). The calling thread claims from the front and
/// the workers from the back, so when no thread is held up each runs the
/// same contiguous part of every loop (its rows stay in its own caches from
/// one loop to the next) and the parts meet wherever the threads' speeds put
/// them. Claiming a chunk is one compare-and-swap on the word, so a worker
/// that wakes up late can never claim a chunk of a newer job than the one it
/// read.
class Pool {
 public:
  static Pool& Get() {
    static Pool* pool = new Pool();  // never destroyed: workers may sleep
    return *pool;
  }

  void Run(int64_t begin,
           int64_t end,
           int64_t grain,
           detail::ChunkFn fn,
           const void* context) {
    grain = std::max<int64_t>(1, grain);
    int64_t chunks = (end - begin + grain - 1) / grain;
    if (chunks > kMaxChunks) {
      grain = (end - begin + kMaxChunks - 1) / kMaxChunks;
      chunks = (end - begin + grain - 1) / grain;
    }
    const int threads = FastParallelThreads();
    bool expected = false;
    if (chunks <= 1 || threads <= 1 || tls_in_job ||
        !busy_.compare_exchange_strong(expected, true)) {
      fn(context, begin, end);
      return;
    }
    EnsureWorkers(threads - 1);
    begin_ = begin;
    end_ = end;
    grain_ = grain;
    fn_ = fn;
    context_ = context;
    active_workers_.store(threads - 1, std::memory_order_relaxed);
    done_.store(0, std::memory_order_relaxed);
    const uint64_t epoch = (job_.load(std::memory_order_relaxed) >> 32) + 1;
    job_.store((epoch << 32) | static_cast<uint64_t>(chunks),
               std::memory_order_seq_cst);
    if (sleepers_.load(std::memory_order_seq_cst) > 0) {
      std::lock_guard<std::mutex> lock(mutex_);
      wake_.notify_all();
    }
    tls_in_job = true;
    tls_thread_index = 0;
    const int64_t mine = Work(epoch, /*from_front=*/true);
    tls_in_job = false;
    // Wait for the chunks other threads hold.
    int spins = 0;
    while (done_.load(std::memory_order_acquire) + mine < chunks) {
      if (++spins < kCallerSpins) {
        CpuRelax();
      } else {
        std::this_thread::yield();
      }
    }
    std::exception_ptr error;
    {
      std::lock_guard<std::mutex> lock(error_mutex_);
      std::swap(error, error_);
    }
    busy_.store(false, std::memory_order_release);
    if (error != nullptr) std::rethrow_exception(error);
  }

 private:
  Pool() = default;

  /// Claims and runs chunks of job `epoch` (from the front or the back)
  /// until none is left; returns how many this thread ran (the caller's are
  /// not added to done_).
  int64_t Work(uint64_t epoch, bool from_front) {
    int64_t ran = 0;
    uint64_t word = job_.load(std::memory_order_acquire);
    for (;;) {
      if ((word >> 32) != epoch) break;
      const uint64_t front = (word >> 16) & 0xFFFF;
      const uint64_t back = word & 0xFFFF;
      if (front >= back) break;
      const uint64_t claimed =
          from_front ? word + (uint64_t{1} << 16) : word - 1;
      if (!job_.compare_exchange_weak(
              word, claimed, std::memory_order_acq_rel)) {
        continue;  // `word` reloaded
      }
      const uint64_t next = from_front ? front : back - 1;
      // The job cannot end (nor its fields change) before this chunk is done.
      const int64_t b = begin_ + static_cast<int64_t>(next) * grain_;
      const int64_t e = std::min(end_, b + grain_);
      try {
        fn_(context_, b, e);
      } catch (...) {
        std::lock_guard<std::mutex> lock(error_mutex_);
        if (error_ == nullptr) error_ = std::current_exception();
      }
      ++ran;
      word = job_.load(std::memory_order_acquire);
    }
    return ran;
  }

  void EnsureWorkers(int count) {
    while (static_cast<int>(workers_.size()) < count) {
      const int index = static_cast<int>(workers_.size()) + 1;
      workers_.emplace_back([this, index] { WorkerLoop(index); });
      workers_.back().detach();
    }
  }

  void WorkerLoop(int index) {
    tls_thread_index = index;
    uint64_t seen = job_.load(std::memory_order_acquire) >> 32;
    for (;;) {
      // Wait for a new job: spin, then sleep.
      uint64_t word = job_.load(std::memory_order_acquire);
      for (int spin = 0; (word >> 32) == seen && spin < kWorkerSpins; ++spin) {
        CpuRelax();
        word = job_.load(std::memory_order_acquire);
      }
      if ((word >> 32) == seen) {
        std::unique_lock<std::mutex> lock(mutex_);
        sleepers_.fetch_add(1, std::memory_order_seq_cst);
        wake_.wait(lock, [&] {
          return (job_.load(std::memory_order_seq_cst) >> 32) != seen;
        });
        sleepers_.fetch_sub(1, std::memory_order_seq_cst);
        word = job_.load(std::memory_order_acquire);
      }
      seen = word >> 32;
      // Workers beyond the job's thread count sit it out.
      if (index > active_workers_.load(std::memory_order_relaxed)) continue;
      tls_in_job = true;
      const int64_t ran = Work(seen, /*from_front=*/false);
      tls_in_job = false;
      if (ran > 0) done_.fetch_add(ran, std::memory_order_acq_rel);
    }
  }

  std::atomic<uint64_t> job_{0};
  std::atomic<int64_t> done_{0};
  std::atomic<int> active_workers_{0};
  std::atomic<int> sleepers_{0};
  std::atomic<bool> busy_{false};
  int64_t begin_ = 0;
  int64_t end_ = 0;
  int64_t grain_ = 1;
  detail::ChunkFn fn_ = nullptr;
  const void* context_ = nullptr;
  std::mutex mutex_;
  std::condition_variable wake_;
  std::mutex error_mutex_;
  std::exception_ptr error_;  // the first exception a chunk threw
  std::vector<std::thread> workers_;
};

}  // namespace

int FastParallelThreads() { return std::max(1, at::get_num_threads()); }

int FastParallelThreadIndex() { return tls_thread_index; }

namespace detail {

void FastParallelRun(int64_t begin,
                     int64_t end,
                     int64_t grain,
                     ChunkFn fn,
                     const void* context) {
  Pool::Get().Run(begin, end, grain, fn, context);
}

}  // namespace detail
}  // namespace soma::internal
