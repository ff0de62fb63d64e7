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
//
// The pool is one per process, created on first use and never destroyed: a
// deliberate exception to the no-global-state rule (STYLE.md), for the same
// reason the OpenMP runtime keeps one: worker threads are a process resource,
// and a pool per engine would put two sets of spinning threads on the same
// cores. It holds no results or configuration, only threads.
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
