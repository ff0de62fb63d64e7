// soma_bench_train_*: the registrations InitFramework() makes for the modules
// these executables link (body, motion, synth, model, train), in its order.
#include "tests/bench/registrations.h"

#include "framework/body/body_source.h"
#include "framework/model/register.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"
#include "framework/synth/register.h"
#include "framework/train/register.h"

#include <mutex>

namespace soma::bench {

void RegisterComponents() {
  static std::once_flag once;
  std::call_once(once, [] {
    RegisterBodySources();
    RegisterMotionSources();
    RegisterSynthComponents();
    RegisterModelComponents();
    RegisterTrainComponents();
    FreezeRegistries();
  });
}

}  // namespace soma::bench
