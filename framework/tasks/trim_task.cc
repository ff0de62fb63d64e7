// `soma trim`: cuts a frame range out of a C3D capture, points and labels
// kept bit for bit (analog data and vendor parameter groups are not
// written; framework/io/c3d.h WriteC3d).
//
//   soma trim take.c3d task.first=0 task.frames=600
//
// writes `<run dir>/<stem>_f<first>-<last>.c3d` (0-based, inclusive frame
// indices of the input); the C3D's first-frame number moves with the cut.
// The bundled clip data/cmu_01_01_f0-599.c3d was made this way
// (data/README.md).
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/io/c3d.h"
#include "framework/registry/registry.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

#include <filesystem>

namespace soma {
namespace {

struct TrimOptions {
  std::string input;
  int first = 0;    // first frame kept (0-based)
  int frames = -1;  // frames kept; -1 = to the end
};

class TrimTask : public Task {
 public:
  explicit TrimTask(TrimOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode&, RunContext& ctx) override {
    C3dData c3d = ReadC3d(options_.input);
    const int available = c3d.num_frames - options_.first;
    if (available <= 0) {
      throw ConfigError(fmt::format(
          "task.first={}: {} has only {} frames (0-based first frame "
          "expected below that)",
          options_.first,
          options_.input,
          c3d.num_frames));
    }
    const int n = options_.frames < 0 ? available : options_.frames;
    if (n > available) {
      throw ConfigError(
          fmt::format("task.frames={}: {} has {} frames from frame {}",
                      options_.frames,
                      options_.input,
                      available,
                      options_.first));
    }
    C3dData out = c3d;
    out.num_frames = n;
    out.first_frame = c3d.first_frame + options_.first;
    out.points = c3d.points.middleRows(options_.first, n);
    if (c3d.residuals.rows() == c3d.num_frames) {
      out.residuals = c3d.residuals.middleRows(options_.first, n);
    }
    if (c3d.valid.rows() == c3d.num_frames) {
      out.valid = c3d.valid.middleRows(options_.first, n);
    }
    out.analog = C3dAnalog();
    const std::string stem = std::filesystem::path(options_.input).stem();
    const std::filesystem::path path =
        ctx.output_dir /
        fmt::format(
            "{}_f{}-{}.c3d", stem, options_.first, options_.first + n - 1);
    out.source = path.string();
    WriteC3d(path, out);
    SOMA_LOG(INFO,
             "trim: frames {}-{} of {} ({} of {}) -> {}",
             options_.first,
             options_.first + n - 1,
             options_.input,
             n,
             c3d.num_frames,
             path.string());
    ctx.ReportMetric("frames", n);
  }

 private:
  TrimOptions options_;
};

}  // namespace

void RegisterTrimTask(Registry<Task>& registry) {
  registry.Register("trim", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    TrimOptions options;
    reader.Require("input", &options.input);
    reader.Read("first", &options.first);
    reader.Read("frames", &options.frames);
    reader.Check("first", options.first >= 0, "a frame index >= 0");
    reader.Check("frames",
                 options.frames == -1 || options.frames > 0,
                 "a positive frame count, or -1 for the rest of the take");
    reader.Finish();
    return std::make_unique<TrimTask>(std::move(options));
  });
}

}  // namespace soma
