// Registration of the synth module's components (noise modules and the
// `noise` config group).
#pragma once

namespace soma {

void RegisterSynthComponents();

}  // namespace soma
