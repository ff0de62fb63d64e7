#include "framework/synth/register.h"

#include "framework/config/node.h"
#include "framework/registry/registry.h"
#include "framework/synth/noise.h"
#include "framework/synth/synthesizer.h"

namespace soma {

void RegisterSynthComponents() {
  RegisterNoiseModules();
  // configs/noise/: a whole pipeline ({modules: [...]}) per option.
  RegisterConfigGroup("noise",
                      std::string(NoiseModule::kRegistryName),
                      [](const ConfigNode& node, BuildContext& ctx) {
                        BuildNoisePipeline(node, ctx);
                      });
  // configs/synth/: the synthesis options (decoded and validated).
  RegisterConfigGroup(
      "synth", "synthesis_options", [](const ConfigNode& node, BuildContext&) {
        DecodeSynthesisOptions(node);
      });
}

}  // namespace soma
