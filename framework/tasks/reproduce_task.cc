// `soma reproduce <name>`: runs one paper table or figure from its ablation
// spec (ablations/<name>.yaml) and writes results/<name>.md and .csv — our
// numbers over training seeds beside the paper's, with the paper's claims
// checked. Resumable: re-running the same command skips every finished
// command and resumes interrupted trainings (framework/reproduce/
// reproduction.h). `task.mode=plan` only writes commands.sh; `report` only
// rebuilds the table from what has finished.
#include "framework/config/decode.h"
#include "framework/core/build_info.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/process.h"
#include "framework/core/provenance.h"
#include "framework/core/resources.h"
#include "framework/registry/registry.h"
#include "framework/reproduce/reproduction.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <optional>
#include <thread>

namespace soma {
namespace {

namespace fs = std::filesystem;

struct ReproduceTaskOptions {
  std::string ablation;
  std::string ablations_dir = "ablations";
  std::string results_dir = "results";
  std::string mode = "run";  // run | plan | report
  ReproductionOptions reproduction;
};

/// `dir` as given if it exists (relative to the working directory), else
/// the same path under the resource root (framework/core/resources.h: the
/// checkout or install this binary belongs to).
fs::path LocateDir(const std::string& dir) {
  if (fs::is_directory(dir) || fs::path(dir).is_absolute()) return dir;
  const fs::path in_home = FindResourceRoot() / dir;
  return fs::is_directory(in_home) ? in_home : fs::path(dir);
}

class ReproduceTask : public Task {
 public:
  explicit ReproduceTask(ReproduceTaskOptions options)
      : options_(std::move(options)) {}

  void Run(const ConfigNode&, RunContext& ctx) override {
    const AblationSpec spec = ApplyBudget(
        LoadAblationSpec(options_.ablation, LocateDir(options_.ablations_dir)),
        options_.reproduction.budget);
    ReproductionOptions reproduction = options_.reproduction;
    reproduction.executable = CurrentExecutable();
    // hydra/launcher=slurm: the models go to SLURM, each training with the
    // array task's CPUs as its threads.
    std::optional<SlurmLauncherOptions> slurm;
    if (const ConfigNode* name = ctx.hydra.FindPath("launcher.name");
        name != nullptr && name->IsString() && name->AsString() == "slurm") {
      slurm = DecodeSlurmLauncherOptions(ctx.hydra.at("launcher"));
      reproduction.train_threads = slurm->cpus_per_task;
    }
    for (const std::string& v : reproduction.only_variants) {
      if (std::none_of(spec.variants.begin(),
                       spec.variants.end(),
                       [&](const AblationVariant& a) { return a.name == v; })) {
        throw ConfigError(fmt::format(
            "Invalid configuration. task.variants: '{}' is not a variant of "
            "{}",
            v,
            spec.name));
      }
    }
    const ReproductionPlan plan = PlanReproduction(spec, reproduction);
    if (const fs::path unkeyed = reproduction.root / spec.name;
        AdoptUnkeyedLedger(plan, unkeyed)) {
      SOMA_LOG(INFO,
               "reproduce {}: moved the ledger {} to {} (ledgers are keyed by "
               "task.budget now)",
               spec.name,
               unkeyed.string(),
               plan.dir.string());
    }
    WriteCommandsScript(plan, fs::current_path());
    SOMA_LOG(INFO,
             "reproduce {}: {} variants x {} seeds, {} tests; commands in {}",
             spec.name,
             spec.variants.size(),
             plan.seeds,
             spec.tests.size(),
             (plan.dir / "commands.sh").string());
    if (options_.mode == "plan") return;

    const ReportContext context = MakeContext(ctx, reproduction, plan);
    // The table is rewritten after every model, so an interrupted
    // reproduction leaves a (marked) partial table behind. While models
    // train it goes to the ledger directory, outside the tracked tree: a
    // report rewritten in results/ would make every later training of this
    // reproduction record the checkout as dirty (its provenance's git diff
    // holding only the report). results/ gets the table once, at the end.
    auto write_report = [&](const fs::path& results) {
      ReportContext now = context;
      const ReproductionRun ledger = SummarizeLedger(plan);
      now.compute_s = ledger.compute_s;
      now.models_done = ledger.models_done;
      now.trained_on = TrainingMachines(plan);
      const std::vector<CellResult> cells = CollectResults(spec, plan);
      CreateDirectories(results);
      WriteResultsCsv(spec, cells, results / (spec.name + ".csv"));
      WriteSeedsCsv(spec, cells, results / (spec.name + "_seeds.csv"));
      WriteResultsMarkdown(spec, cells, now, results / (spec.name + ".md"));
      if (!spec.claims.empty()) {
        WriteClaimsCsv(spec, cells, results / (spec.name + "_claims.csv"));
      }
      WriteTrainingCurvesCsv(plan, results / (spec.name + "_curves.csv"));
      WriteWorstFramesMarkdown(
          spec, plan, 5, results / (spec.name + "_worst_frames.md"));
      return now;
    };
    const fs::path progress = ProgressReportDir(plan);
    auto write_progress = [&] { write_report(progress); };
    if (options_.mode == "run") {
      SOMA_LOG(INFO,
               "reproduce {}: the table so far is rewritten after every model "
               "in {}; {} gets it when the run ends",
               spec.name,
               progress.string(),
               options_.results_dir);
    }
    const ReproductionRun run =
        options_.mode != "run" ? SummarizeLedger(plan)
        : slurm
            ? RunReproductionOnSlurm(plan, reproduction, *slurm, write_progress)
            : RunReproduction(plan, reproduction, true, write_progress);
    const ReportContext final_context = write_report(options_.results_dir);
    SOMA_LOG(INFO,
             "reproduce {}: {} of {} models done; wrote {}/{}.md and .csv",
             spec.name,
             final_context.models_done,
             final_context.models_planned,
             options_.results_dir,
             spec.name);
    ctx.ReportMetric("models_done", final_context.models_done);
    ctx.ReportMetric("models_planned", final_context.models_planned);
    ctx.ReportMetric("models_failed", run.models_failed);
    ctx.ReportMetric("compute_h", final_context.compute_s / 3600.0);
    if (run.models_failed > 0) {
      throw Error(fmt::format(
          "reproduce {}: {} model(s) failed (table written with what "
          "finished); first: {}",
          spec.name,
          run.models_failed,
          run.errors.front()));
    }
  }

 private:
  ReportContext MakeContext(const RunContext& ctx,
                            const ReproductionOptions& reproduction,
                            const ReproductionPlan& plan) const {
    ReportContext context;
    std::vector<std::string> args;
    for (const std::string& o : ctx.overrides) {
      if (o == "task=reproduce") continue;
      if (o == "task.ablation=" + options_.ablation) continue;
      // Where the log went and whether this call only rebuilt the table do
      // not change the numbers: the command shown is the one that makes them.
      // Nor does which rows this call ran (task.variants).
      if (o.rfind("hydra.", 0) == 0 || o.rfind("task.mode=", 0) == 0 ||
          o.rfind("task.variants=", 0) == 0) {
        continue;
      }
      args.push_back(o);
    }
    context.command = fmt::format("soma reproduce {}{}{}",
                                  options_.ablation,
                                  args.empty() ? "" : " ",
                                  fmt::join(args, " "));
    const GitState git = QueryGit();
    context.commit = git.available
                         ? git.sha.substr(0, 12) + (git.dirty ? "-dirty" : "")
                         : "unknown";
    context.date = IsoNow();
    const std::string cpu = CpuModel();
    context.machine = fmt::format("{}, {} ({} hardware threads)",
                                  HostName(),
                                  cpu.empty() ? "CPU unknown" : cpu,
                                  std::thread::hardware_concurrency());
    context.budget = reproduction.budget;
    context.data_dir = reproduction.data_dir.string();
    context.models_planned = static_cast<int>(plan.models.size());
    context.seeds = plan.seeds;
    return context;
  }

  ReproduceTaskOptions options_;
};

}  // namespace

void RegisterReproduceTask(Registry<Task>& registry) {
  registry.Register("reproduce", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    ReproduceTaskOptions o;
    reader.Require("ablation", &o.ablation);
    reader.Read("ablations_dir", &o.ablations_dir);
    reader.Read("results_dir", &o.results_dir);
    reader.Read("mode", &o.mode);
    reader.Check("mode",
                 o.mode == "run" || o.mode == "plan" || o.mode == "report",
                 "run, plan or report");
    std::string root = o.reproduction.root.string();
    reader.Read("root", &root);
    o.reproduction.root = root;
    std::string data_dir = o.reproduction.data_dir.string();
    reader.Read("data_dir", &data_dir);
    o.reproduction.data_dir = data_dir;
    reader.Read("budget", &o.reproduction.budget);
    if (const ConfigNode* seeds = reader.Child("seeds");
        seeds != nullptr && !seeds->IsNull()) {
      o.reproduction.seeds = static_cast<int>(seeds->AsInt());
      reader.Check("seeds", o.reproduction.seeds >= 1, "null or >= 1");
    }
    reader.Read("jobs", &o.reproduction.jobs);
    reader.Check("jobs", o.reproduction.jobs >= 1, "jobs >= 1");
    o.reproduction.train_threads =
        std::max(1,
                 static_cast<int>(std::thread::hardware_concurrency()) /
                     o.reproduction.jobs);
    reader.Read("test_seed", &o.reproduction.test_seed);
    if (const ConfigNode* only = reader.Child("variants");
        only != nullptr && !only->IsNull()) {
      reader.ReadOneOrMore("variants", &o.reproduction.only_variants);
    }
    reader.Finish();
    return std::make_unique<ReproduceTask>(std::move(o));
  });
}

}  // namespace soma
