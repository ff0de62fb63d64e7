// `soma coverage`: the pose-coverage report of a motion source on a body
// (tilt, pelvis height and joint-angle distributions, as numbers and plots).
#include "framework/config/decode.h"
#include "framework/core/logging.h"
#include "framework/core/timer.h"
#include "framework/motion/coverage.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

namespace soma {
namespace {

struct CoverageOptions {
  std::string split = "train";
  double frame_rate = 30.0;
};

class CoverageTask : public Task {
 public:
  explicit CoverageTask(CoverageOptions options)
      : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const BodyModel body = BuildBody(cfg, build);
    Timer timer;
    Rng rng = Rng(ctx.seed).Stream("motion");
    const std::vector<PoseSequence> clips =
        BuildMotionSource(cfg, build)
            ->Load(body,
                   SplitFromString(options_.split),
                   options_.frame_rate,
                   rng);
    SOMA_LOG(INFO,
             "coverage: {} clips loaded in {:.1f}s",
             clips.size(),
             timer.ElapsedSeconds());
    const CoverageReport report = ComputeCoverage(body, clips);
    WriteCoverageReport(report, ctx.output_dir);
    SOMA_LOG(INFO,
             "coverage: {} frames; upright {:.3f}, horizontal {:.3f}, inverted "
             "{:.3f}; report "
             "{}/coverage.md",
             report.num_frames,
             report.UprightFraction(),
             report.HorizontalFraction(),
             report.InvertedFraction(),
             ctx.output_dir.string());
    ctx.ReportMetric("frames", report.num_frames);
    ctx.ReportMetric("upright_fraction", report.UprightFraction());
    ctx.ReportMetric("horizontal_fraction", report.HorizontalFraction());
    ctx.ReportMetric("inverted_fraction", report.InvertedFraction());
  }

 private:
  CoverageOptions options_;
};

}  // namespace

void RegisterCoverageTask(Registry<Task>& registry) {
  registry.Register("coverage", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    CoverageOptions options;
    reader.Read("split", &options.split);
    reader.Read("frame_rate", &options.frame_rate);
    reader.Check("split",
                 options.split == "train" || options.split == "val" ||
                     options.split == "test",
                 "split is train, val or test");
    reader.Check("frame_rate", options.frame_rate > 0, "frame_rate > 0");
    reader.Finish();
    return std::make_unique<CoverageTask>(options);
  });
}

}  // namespace soma
