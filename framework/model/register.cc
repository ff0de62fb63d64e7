#include "framework/model/register.h"

namespace soma {

void RegisterModelComponents() {
  RegisterBackbones();
  RegisterNormalizations();
  RegisterModelSpecs();
  RegisterLosses();
}

}  // namespace soma
