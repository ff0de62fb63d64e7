#include "framework/train/register.h"

#include "framework/train/optimizer.h"
#include "framework/train/schedule.h"
#include "framework/train/trainer.h"

namespace soma {

void RegisterTrainComponents() {
  RegisterOptimizers();
  RegisterSchedulers();
  RegisterTrainerConfigGroup();
}

}  // namespace soma
