// `soma corrupt`: the evaluation corruption protocol on real labelled takes
// (REFERENCE.md 3.6). For every input C3D and setting it writes
// `<setting>/<take>.c3d` (corrupted points, anonymised labels) and
// `<setting>/<take>.h5` (the per-frame ground truth, a soma dataset; see
// docs/dataset_format.md) under the run directory, plus `corrupt.csv` with
// one line of statistics per written set.
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/registry/registry.h"
#include "framework/synth/corruption.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

#include <sstream>

namespace soma {
namespace {

struct CorruptOptions {
  std::vector<std::string> files;     // labelled real C3D takes
  std::vector<std::string> settings;  // OC_xx_G_xx_BT_xx names
};

CorruptOptions DecodeCorruptOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  CorruptOptions options;
  reader.Require("files", &options.files);
  reader.Require("settings", &options.settings);
  reader.Check("files", !options.files.empty(), "at least one file");
  reader.Check("settings", !options.settings.empty(), "at least one setting");
  for (const std::string& name : options.settings) {
    ParseCorruptionSettingName(name);  // throws ConfigError naming it
  }
  reader.Finish();
  return options;
}

class CorruptTask : public Task {
 public:
  explicit CorruptTask(CorruptOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    // Only the labels are needed, not a body: a take is restricted to them
    // (`layout.exclude` removes markers, e.g. for SOMA's Table 4).
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const std::vector<std::string> labels = BuildLayoutLabels(cfg, build);
    std::ostringstream csv;
    csv << "setting,take,frames,columns,missing_before,missing_after,"
           "ghosts_per_frame,cuts\n";
    int written = 0;
    int skipped = 0;
    for (const std::string& file : options_.files) {
      const LabeledSequence clean = ReadLabeledC3d(file, labels);
      SOMA_LOG(INFO,
               "corrupt: {} — {} frames, {} of {} layout labels",
               clean.name,
               clean.num_frames(),
               clean.num_columns(),
               labels.size());
      for (const std::string& name : options_.settings) {
        const CorruptionSetting setting = ParseCorruptionSettingName(name);
        const std::string reason = CorruptionSkipReason(clean, setting);
        if (!reason.empty()) {
          SOMA_LOG(WARNING, "corrupt: {}", reason);
          ++skipped;
          continue;
        }
        CorruptionSummary summary;
        const LabeledSequence out =
            CorruptSequence(clean, setting, ctx.seed, &summary);
        const std::filesystem::path dir = ctx.output_dir / name;
        CreateDirectories(dir);
        WriteCorruptedSequence(out, dir / clean.name, name, ctx.seed);
        csv << fmt::format("{},{},{},{},{:.4f},{:.4f},{:.3f},{}\n",
                           name,
                           clean.name,
                           out.num_frames(),
                           out.num_columns(),
                           summary.missing_before,
                           summary.missing_after,
                           summary.ghosts_per_frame,
                           summary.cuts);
        SOMA_LOG(INFO,
                 "corrupt: {}/{} — {} columns, missing {:.1f}% -> {:.1f}%, "
                 "{:.2f} ghosts/frame, {} cuts",
                 name,
                 clean.name,
                 out.num_columns(),
                 100 * summary.missing_before,
                 100 * summary.missing_after,
                 summary.ghosts_per_frame,
                 summary.cuts);
        ++written;
      }
    }
    WriteFileAtomic(ctx.output_dir / "corrupt.csv", csv.str());
    ctx.ReportMetric("sets_written", written);
    ctx.ReportMetric("sets_skipped", skipped);
  }

 private:
  CorruptOptions options_;
};

}  // namespace

void RegisterCorruptTask(Registry<Task>& registry) {
  registry.Register("corrupt", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<CorruptTask>(DecodeCorruptOptions(node));
  });
}

}  // namespace soma
