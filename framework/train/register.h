// Registration of the train module's components (optimizers, LR schedules,
// batch sources and their config groups).
#pragma once

namespace soma {

void RegisterTrainComponents();

}  // namespace soma
