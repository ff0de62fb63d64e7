// A program outside somalab that uses its installed libraries: it registers
// a noise module of its own ("drift": moves every marker by dx metres),
// composes the somalab config with its own config directory on the search
// path (`noise=drift` comes from conf/noise/drift.yaml), builds the noise
// pipeline through the registry and applies it to one frame.
//
//   consumer noise=drift hydra.run.dir=out
#include "framework/config/app.h"
#include "framework/config/decode.h"
#include "framework/framework.h"
#include "framework/registry/registry.h"
#include "framework/synth/noise.h"

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

namespace {

class DriftNoise : public soma::NoiseModule {
 public:
  explicit DriftNoise(double dx) : dx_(static_cast<float>(dx)) {}
  void Apply(soma::MarkerFrame* frame, int, soma::Rng&) const override {
    for (int i = 0; i < frame->num_points(); ++i) {
      if (frame->IsPresent(i)) frame->point(i)[0] += dx_;
    }
  }

 private:
  float dx_;
};

void RunDrift(const soma::ConfigNode& cfg, soma::RunContext& ctx) {
  soma::BuildContext build(ctx.seed, ctx.output_dir.string());
  const soma::NoisePipeline pipeline =
      soma::BuildNoisePipeline(cfg.at("noise"), build);
  soma::MarkerFrame frame;
  frame.Reset(2, pipeline.num_ghost_slots());
  frame.Set(0, 1.0f, 2.0f, 3.0f, 0);
  frame.Set(1, -1.0f, 0.5f, 1.0f, 1);
  pipeline.Apply(&frame, soma::Rng(ctx.seed));
  float x_sum = 0.0f;
  for (int i = 0; i < frame.num_points(); ++i) x_sum += frame.point(i)[0];
  std::printf("pipeline: %s\nx_sum: %.3f\n",
              pipeline.Describe().c_str(),
              static_cast<double>(x_sum));
}

}  // namespace

int main(int argc, char** argv) {
  // Built-ins first, then our own component, then freeze.
  soma::RegisterBuiltins();
  soma::GetRegistry<soma::NoiseModule>().Register(
      "drift", [](const soma::ConfigNode& node, soma::BuildContext&) {
        soma::ConfigReader reader(node);
        double dx = 0.0;
        reader.Require("dx", &dx);
        reader.Finish();
        return std::make_unique<DriftNoise>(dx);
      });
  soma::FreezeRegistries();
  // `${soma.home:}` in somalab's configs resolves to the installed resources.
  setenv("SOMA_HOME", SOMALAB_DATA_DIR, /*overwrite=*/0);
  std::vector<std::string> args(argv + 1, argv + argc);
  args.insert(args.begin(), {"-cd", CONSUMER_CONF_DIR});
  return soma::RunHydraApp(
      args, SOMALAB_DATA_DIR "/configs", "config", RunDrift);
}
