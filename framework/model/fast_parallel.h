// The thread pool of the fast training engine (fast_train.h): a parallel loop
// whose chunks are claimed dynamically, so that a thread the OS has
// descheduled (another process, the data-synthesis thread of `soma train`)
// delays a step by at most the chunk it holds, instead of every parallel
// region waiting for it at a barrier as OpenMP's static split does. The
// calling thread always takes part; the region ends when every chunk is
// done, without waiting for a worker that never started.
//
// Chunk boundaries depend only on the loop size and the grain, never on which
// thread runs a chunk, so results are deterministic.
#pragma once

#include <cstdint>

namespace soma::internal {

/// Threads a FastParallelFor uses: torch's intra-op thread count
/// (at::get_num_threads(), i.e. `threads` / SetTorchThreads).
int FastParallelThreads();

/// Index of the calling thread within the running FastParallelFor, in [0,
/// FastParallelThreads()) (0 outside one): for per-thread scratch.
int FastParallelThreadIndex();

namespace detail {
using ChunkFn = void (*)(const void* context, int64_t begin, int64_t end);
void FastParallelRun(
    int64_t begin, int64_t end, int64_t grain, ChunkFn fn, const void* context);
}  // namespace detail

/// Calls `f(chunk_begin, chunk_end)` for the chunks `[begin + i * grain,
/// min(end, begin + (i + 1) * grain))` of `[begin, end)` on the pool's
/// threads; returns when all are done. Called from inside another
/// FastParallelFor (or while another thread runs one) it runs serially.
template <typename F>
void FastParallelFor(int64_t begin, int64_t end, int64_t grain, const F& f) {
  if (begin >= end) return;
  detail::FastParallelRun(
      begin,
      end,
      grain,
      [](const void* context, int64_t b, int64_t e) {
        (*static_cast<const F*>(context))(b, e);
      },
      &f);
}

}  // namespace soma::internal
