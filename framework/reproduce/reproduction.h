// A reproduction: the `soma` commands that produce one ablation spec's table,
// planned, run and collected.
//
// Every model (variant × seed) is one job: `soma train` with the
// reproduction's budget and the variant's overrides, then for every test a
// `soma label` of the corrupted take and a `soma eval` against its ground
// truth. The corrupted takes (`soma corrupt`, one per take × setting, fixed
// seed) are made first and shared by every model. Each command runs in its
// own run directory and is done when that directory holds `metrics.yaml` and
// no `error.txt`, so re-running the reproduction skips finished commands and
// resumes an interrupted training from its last checkpoint. Model
// directories are keyed by a hash of their training overrides, so tables that
// share a model (Table 1's B+C+G row and Table 5's base) train it once.
//
//   <root>/models/<slug>-<hash>/seed<k>/        a `soma train` run dir
//       tests/<take>_<setting>_<mode>/label/      `soma label` run dir
//       tests/<take>_<setting>_<mode>/eval/       `soma eval` run dir
//   <root>/testdata/<take>_<setting>_seed<s>/   a `soma corrupt` run dir
//   <root>/<name>-<budget hash>/jobs.yaml, jobs.csv   the ledger (one job
//                                                     per model)
//   <root>/<name>-<budget hash>/commands.sh           every command, in order
//   <root>/<name>-<budget hash>/report/               the table so far,
//                                                     rewritten after every
//                                                     model while it runs
//
// The ledger is keyed by the budget too: the same table under another budget
// (another layout, scale or length) is another set of models with its own
// ledger, and running it leaves the first one's records alone.
#pragma once

#include "framework/config/slurm_launcher.h"
#include "framework/reproduce/ablation_spec.h"
#include "framework/reproduce/report.h"

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <vector>

namespace soma {

struct ReproductionOptions {
  std::filesystem::path root = "results/reproduce";
  std::filesystem::path data_dir = "../shared/data";
  /// Overrides of every training (the model scale and the training length).
  std::vector<std::string> budget = {"scale=cpu", "train.max_epochs=20"};
  int seeds = 0;  // 0: the spec's number of seeds
  int jobs = 2;   // models trained/evaluated at the same time
  /// > 0: every training runs with `threads=<train_threads>` (unless the
  /// budget or the variant sets `threads`), so that `jobs` trainings share
  /// the cores instead of each taking its preset's count (scale=cpu: 2):
  /// OpenMP threads that outnumber the cores spin against each other (two
  /// 2-thread trainings on 2 cores ran 5x slower than two 1-thread ones).
  /// 0: the preset's. The reproduce task sets cores / jobs.
  int train_threads = 0;
  uint64_t test_seed = 0;  // seed of the corruption and of inference
  /// Non-empty: RunReproduction runs only these variants' models (e.g. the
  /// rows that need no training first); the others stay pending.
  std::vector<std::string> only_variants;
  /// The `soma` executable the commands run.
  std::filesystem::path executable;
};

/// One `soma` command with its run directory (`hydra.run.dir`).
struct PlannedCommand {
  std::string name;  // e.g. "train log_softmax seed 1"
  std::vector<std::string> argv;
  std::filesystem::path run_dir;
  /// Finished successfully: `metrics.yaml` and no `error.txt`.
  bool Done() const;
};

struct PlannedModel {
  std::string variant;
  int seed = 0;
  std::vector<std::string> train_overrides;  // budget + variant + seed
  std::string hash;                          // of budget + variant overrides
  std::filesystem::path dir;                 // the training run dir
  std::vector<PlannedCommand> commands;      // train, then label/eval pairs
  std::map<std::string, std::filesystem::path> eval_dirs;  // test -> eval run
  /// Every command is done.
  bool Done() const;
  /// The model's key in the ledger: "<hash>/<seed>".
  std::string LedgerKey() const;
};

struct ReproductionPlan {
  std::filesystem::path dir;  // <root>/<name>-<hash of the budget>
  std::vector<PlannedCommand> corrupt;
  std::vector<PlannedModel> models;  // skipped variants are not planned
  int seeds = 0;
};

/// Pure: builds the commands; touches no file.
ReproductionPlan PlanReproduction(const AblationSpec& spec,
                                  const ReproductionOptions& options);

/// Writes `<plan.dir>/commands.sh`: every command of the plan, in order.
void WriteCommandsScript(const ReproductionPlan& plan,
                         const std::filesystem::path& working_dir);

/// Where a running reproduction rewrites its table after every model:
/// `<plan.dir>/report`, beside the ledger and outside the tracked tree, so
/// that the trainings it starts later record the checkout as it was (a table
/// rewritten in `results/` would make each of them record a dirty tree).
std::filesystem::path ProgressReportDir(const ReproductionPlan& plan);

struct ReproductionRun {
  int models_done = 0;
  int models_failed = 0;
  double compute_s = 0;             // summed wall time, all attempts
  std::vector<std::string> errors;  // one line per failed model
};

/// Runs every command that is not done: the corruptions first (a failure
/// there throws), then the models, `jobs` at a time, each model's commands in
/// order. A failing command fails its model (recorded in the ledger with the
/// command's error) and the others go on.
/// `on_model_finished` (optional) is called after each model finishes or
/// fails, e.g. to rewrite the results table as it fills.
ReproductionRun RunReproduction(
    const ReproductionPlan& plan,
    const ReproductionOptions& options,
    bool progress,
    const std::function<void()>& on_model_finished = {});

/// RunReproduction on a SLURM cluster (`soma reproduce <name>
/// hydra/launcher=slurm`): the corruptions run here first, then the models
/// that are not done go to SLURM as one job array (task id = the model's
/// ledger number), each task running its model's unfinished commands in
/// order (`<plan.dir>/.slurm/models/<num>.sh`, which stops at the first
/// failing command and names its log), with the sweep launcher's resources,
/// preemption and requeue (`options.jobs` does not apply: SLURM schedules).
/// With `slurm.wait` it polls until the array has ended (SIGINT cancels it)
/// and records each model done or failed (with SLURM's stderr, which names
/// the failing command's log) in the ledger; with `wait=false` it returns
/// after submitting. Re-running submits only the models that are not done.
ReproductionRun RunReproductionOnSlurm(
    const ReproductionPlan& plan,
    const ReproductionOptions& options,
    const SlurmLauncherOptions& slurm,
    const std::function<void()>& on_model_finished = {});

/// The bash script one SLURM array task of RunReproductionOnSlurm runs for
/// `model`: its commands in order, each skipped when its run directory is
/// done, started as RunReproduction starts them (stale metrics.yaml and
/// error.txt removed, output to `<run dir>/stdout.txt`); SIGTERM and SIGUSR1
/// are passed on to the running command; the first failing command ends the
/// script with its exit status and a line on stderr naming the command, its
/// error and its log; each run appends its wall time to
/// `<model dir>/slurm_wall_s`.
std::string ModelChainScript(const PlannedModel& model);

/// The wall time a reproduction has left, estimated from the models finished
/// so far: with the median of their times as every model's time, each of the
/// `jobs` slots first finishes its running model (the median less the time
/// it has run, at least 0), then the queued models go, one by one, to the
/// slot free first; the answer is when the last slot is free. Negative
/// (unknown) until a model has finished.
double EstimateSecondsLeft(std::vector<double> finished_model_s,
                           const std::vector<double>& running_elapsed_s,
                           size_t queued_models,
                           int jobs);

/// Reads the finished evaluations: one CellResult per (planned variant, test,
/// metric), plus empty cells for skipped variants.
std::vector<CellResult> CollectResults(const AblationSpec& spec,
                                       const ReproductionPlan& plan);

/// Writes `path` (markdown): per finished evaluation of `plan` (variant,
/// seed, test), its `per_evaluation` lowest-accuracy frames from the eval
/// run's per_frame.csv (first output), each linked into the `soma view`
/// page the evaluation wrote (`<eval run>/view/*.html#frame=N`; its eval.md
/// when it has none), with links relative to `path`'s directory. Returns
/// the evaluations listed.
int WriteWorstFramesMarkdown(const AblationSpec& spec,
                             const ReproductionPlan& plan,
                             int per_evaluation,
                             const std::filesystem::path& path);

/// Where the finished trainings of `plan` ran, from the provenance of each
/// training run (`<run>/.hydra/hydra.yaml`: host and CPU): one entry per
/// machine, "vm, Intel(R) Xeon(R) Processor: 8 models", most models first. A
/// run that recorded no CPU (written before runs recorded it) says "CPU not
/// recorded"; one without the file says "no provenance", one that cannot be
/// parsed "unreadable provenance". A training resumed elsewhere names the
/// machine of its last start (hydra.yaml is rewritten at each start). Empty
/// when nothing is trained.
std::vector<std::string> TrainingMachines(const ReproductionPlan& plan);

/// The training curves of every planned model that has started: one row per
/// (variant, seed, epoch) from its run dir's metrics.csv (columns variant,
/// seed, epoch, train_loss, val_loss, val_acc, val_f1; accuracies as
/// fractions of the synthetic validation set), written to `path`
/// atomically. Models without a metrics.csv are left out. Returns the rows.
int WriteTrainingCurvesCsv(const ReproductionPlan& plan,
                           const std::filesystem::path& path);

/// Ledgers used to live in `<root>/<name>`, whatever the budget. Moves such a
/// directory (`unkeyed_dir`) to `plan.dir` if `plan.dir` does not exist yet
/// and the old ledger records at least one of the plan's models (same
/// training overrides and seed), so that its wall times and attempts are
/// kept. Returns whether it moved.
bool AdoptUnkeyedLedger(const ReproductionPlan& plan,
                        const std::filesystem::path& unkeyed_dir);

/// Models whose every command is done, and the summed wall time recorded in
/// the ledger.
ReproductionRun SummarizeLedger(const ReproductionPlan& plan);

}  // namespace soma
