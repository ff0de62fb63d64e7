// soma_bench_stream_*: the registrations InitFramework() makes for the
// modules these executables link (body, motion, solve, synth, model, train,
// stream), in its order.
#include "tests/bench/registrations.h"

#include "framework/body/body_source.h"
#include "framework/model/register.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"
#include "framework/solve/pose_prior.h"
#include "framework/stream/frame_source.h"
#include "framework/synth/register.h"
#include "framework/train/register.h"

#include <mutex>

namespace soma::bench {

void RegisterComponents() {
  static std::once_flag once;
  std::call_once(once, [] {
    RegisterBodySources();
    RegisterMotionSources();
    RegisterPosePriors();
    RegisterSynthComponents();
    RegisterModelComponents();
    RegisterTrainComponents();
    RegisterFrameSources();
    FreezeRegistries();
  });
}

}  // namespace soma::bench
