// The demo task: a small, honest stand-in for a training run that exercises
// the run/multirun machinery (directories, logs, metrics, ledger, resume)
// before the real experiments land. It minimises f(w) = (w - target)^2 with
// noisy gradient descent, w0 = 0, gradient noise N(0, noise^2) drawn from the
// run's seed, and reports the final loss. With `checkpoint: true` it saves
// (step, w) after every step and resumes from it, like the trainer's
// `last.pt` (the SLURM launcher's requeue test uses it).
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/progress.h"
#include "framework/core/random.h"
#include "framework/registry/registry.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <iterator>
#include <sstream>
#include <thread>

namespace soma {
namespace {

struct DemoOptions {
  int steps = 20;           // gradient steps
  double lr = 0.1;          // step size
  double target = 1.0;      // minimiser of the objective
  double noise = 0.05;      // std of the gradient noise
  int step_ms = 0;          // sleep per step (to make a job take time)
  int fail_at_step = -1;    // >= 0: throw at that step (failure handling demo)
  bool checkpoint = false;  // save/resume <output_dir>/demo_checkpoint.txt
};

constexpr char kCheckpointFile[] = "demo_checkpoint.txt";

DemoOptions DecodeDemoOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  DemoOptions options;
  reader.Read("steps", &options.steps);
  reader.Read("lr", &options.lr);
  reader.Read("target", &options.target);
  reader.Read("noise", &options.noise);
  reader.Read("step_ms", &options.step_ms);
  reader.Read("fail_at_step", &options.fail_at_step);
  reader.Read("checkpoint", &options.checkpoint);
  reader.Check("steps", options.steps > 0, "steps > 0");
  reader.Check("lr", options.lr > 0 && options.lr < 1, "0 < lr < 1");
  reader.Check("noise", options.noise >= 0, "noise >= 0");
  reader.Check("step_ms", options.step_ms >= 0, "step_ms >= 0");
  reader.Finish();
  return options;
}

class DemoTask : public Task {
 public:
  explicit DemoTask(DemoOptions options) : options_(options) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    Rng rng = Rng(ctx.seed).Stream("task/demo");
    double w = 0.0;
    std::ostringstream csv;
    csv << "step,w,loss\n";
    int first_step = 0;
    const std::filesystem::path checkpoint = ctx.output_dir / kCheckpointFile;
    if (options_.checkpoint && std::filesystem::exists(checkpoint)) {
      // "<completed steps> <w>" then the metrics.csv rows so far.
      std::istringstream saved(ReadFile(checkpoint));
      saved >> first_step >> w;
      if (!saved || first_step < 0 || first_step > options_.steps) {
        throw IoError(
            fmt::format("Malformed demo checkpoint '{}'", checkpoint.string()));
      }
      saved.ignore(1);
      const std::string rows(std::istreambuf_iterator<char>(saved), {});
      csv << rows;
      // The noise stream is sequential: skip the draws already used.
      for (int i = 0; i < first_step; ++i) rng.Normal();
      SOMA_LOG(INFO,
               "demo: resumed from step {} ({})",
               first_step,
               checkpoint.string());
    }
    ProgressBar bar(options_.steps, {.label = "demo", .unit = "steps"});
    if (first_step > 0) bar.Update(first_step);
    for (int step = first_step; step < options_.steps; ++step) {
      if (step == options_.fail_at_step) {
        throw Error(
            fmt::format("demo task: failing at step {} as configured "
                        "(task.fail_at_step)",
                        step));
      }
      const double gradient =
          2.0 * (w - options_.target) + options_.noise * rng.Normal();
      w -= options_.lr * gradient;
      const double loss = (w - options_.target) * (w - options_.target);
      csv << fmt::format("{},{:.9g},{:.9g}\n", step, w, loss);
      if (options_.checkpoint) {
        const std::string text = csv.str();
        WriteFileAtomic(checkpoint,
                        fmt::format("{} {:.17g}\n{}",
                                    step + 1,
                                    w,
                                    text.substr(text.find('\n') + 1)));
      }
      if (options_.step_ms > 0) {
        std::this_thread::sleep_for(
            std::chrono::milliseconds(options_.step_ms));
      }
      bar.Update(1, fmt::format("loss={:.3g}", loss));
    }
    bar.Finish();
    const double final_loss = (w - options_.target) * (w - options_.target);
    WriteFileAtomic(ctx.output_dir / "metrics.csv", csv.str());
    SOMA_LOG(INFO,
             "demo: w={:.6f} loss={:.3e} after {} steps (seed {})",
             w,
             final_loss,
             options_.steps,
             ctx.seed);
    ctx.ReportMetric("loss", final_loss);
    ctx.ReportMetric("w", w);
  }

 private:
  DemoOptions options_;
};

}  // namespace

void RegisterDemoTask(Registry<Task>& registry) {
  registry.Register("demo", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<DemoTask>(DecodeDemoOptions(node));
  });
}

}  // namespace soma
