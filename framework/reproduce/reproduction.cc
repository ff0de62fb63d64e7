#include "framework/reproduce/reproduction.h"

#include "framework/config/ledger.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/process.h"
#include "framework/core/progress.h"
#include "framework/core/random.h"
#include "framework/core/timer.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <deque>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <tuple>

namespace soma {
namespace {

namespace fs = std::filesystem;

std::string Hash8(const std::vector<std::string>& parts) {
  std::string joined;
  for (const std::string& p : parts) joined += p + "\n";
  return fmt::format("{:016x}", Fnv1a64(joined)).substr(0, 8);
}

/// A readable directory name for a list of overrides.
std::string Slug(const std::vector<std::string>& overrides) {
  std::string slug;
  for (const std::string& o : overrides) {
    if (!slug.empty()) slug += '_';
    for (char c : o) {
      const bool keep = std::isalnum(static_cast<unsigned char>(c)) ||
                        c == '.' || c == '-' || c == '_';
      slug += keep ? c : '-';
    }
  }
  if (slug.empty()) slug = "base";
  if (slug.size() > 48) slug.resize(48);
  return slug;
}

std::string Mode(const AblationTest& test) {
  return test.tracklet ? "tracklet" : "perframe";
}

/// "" or "_<hash of the overrides>": tells apart the directories of tests
/// that differ only in extra overrides.
std::string OverridesSuffix(const std::vector<std::string>& overrides) {
  return overrides.empty() ? std::string() : "_" + Hash8(overrides);
}

fs::path CorruptDir(const AblationTest& test,
                    const ReproductionOptions& options) {
  return options.root / "testdata" /
         fmt::format("{}_{}_seed{}{}",
                     fs::path(test.take).stem().string(),
                     test.setting,
                     options.test_seed,
                     OverridesSuffix(test.corrupt_overrides));
}

std::string RunDirArg(const fs::path& dir) {
  return "hydra.run.dir=" + dir.string();
}

/// A `soma` run finished successfully: `metrics.yaml` and no `error.txt`.
bool RunDirDone(const fs::path& run_dir) {
  return fs::exists(run_dir / "metrics.yaml") &&
         !fs::exists(run_dir / "error.txt");
}

std::map<std::string, double> ReadMetrics(const fs::path& run_dir) {
  std::map<std::string, double> metrics;
  const fs::path path = run_dir / "metrics.yaml";
  if (!fs::exists(path)) return metrics;
  const ConfigNode node = ParseYaml(ReadFile(path), path.string());
  if (!node.IsMap()) return metrics;
  for (const auto& [name, value] : node.entries()) {
    if (value.IsScalar() && !value.IsNull() && !value.IsString()) {
      metrics[name] = value.AsDouble();
    }
  }
  return metrics;
}

/// The one-line error a failed command left, or a generic line.
std::string CommandError(const PlannedCommand& command, int exit_code) {
  const fs::path error = command.run_dir / "error.txt";
  std::string text;
  if (fs::exists(error)) {
    text = ReadFile(error);
    while (!text.empty() && text.back() == '\n') text.pop_back();
  } else {
    text = fmt::format("exit code {} (log: {})",
                       exit_code,
                       (command.run_dir / "stdout.txt").string());
  }
  return fmt::format("{}: {}", command.name, text);
}

/// Removes what a previous, unfinished attempt left that would make the
/// command look done or failed (the run dir itself is kept: a training
/// resumes from its checkpoints).
void PrepareRunDir(const PlannedCommand& command) {
  CreateDirectories(command.run_dir);
  std::error_code ec;
  fs::remove(command.run_dir / "error.txt", ec);
  fs::remove(command.run_dir / "metrics.yaml", ec);
}

ProcessSpec Spec(const PlannedCommand& command) {
  return {command.argv, command.run_dir / "stdout.txt"};
}

/// The ledger's metrics of a model: the training's and each test's.
std::map<std::string, double> ModelMetrics(const PlannedModel& model) {
  std::map<std::string, double> out;
  for (const auto& [name, value] : ReadMetrics(model.dir)) {
    if (name == "val_acc" || name == "val_f1" || name == "epochs") {
      out["train/" + name] = value;
    }
  }
  for (const auto& [test, dir] : model.eval_dirs) {
    const auto metrics = ReadMetrics(dir);
    for (const char* key : {"acc_mean", "f1_mean"}) {
      if (const auto it = metrics.find(key); it != metrics.end()) {
        out[test + "/" + key] = it->second;
      }
    }
  }
  return out;
}

/// The model's variant is one `options.only_variants` selects.
/// The shared test data (the corruptions); nothing can be evaluated without
/// it. A failure throws.
void RunCorruptions(const ReproductionPlan& plan, ProgressBar* bar) {
  for (const PlannedCommand& c : plan.corrupt) {
    if (c.Done()) continue;
    PrepareRunDir(c);
    const int code = RunProcess(Spec(c));
    if (code != 0) throw Error(CommandError(c, code));
    if (bar != nullptr) bar->Update(1, c.name);
  }
}

/// Where a model's SLURM task appends the wall time of each start.
constexpr char kChainWallFile[] = "slurm_wall_s";

/// The summed wall time of a model's SLURM starts (0 if none recorded).
double ChainWallSeconds(const PlannedModel& model) {
  double sum = 0;
  std::ifstream in(model.dir / kChainWallFile);
  double value = 0;
  while (in >> value) sum += value;
  return sum;
}

/// The last line of the model's SLURM stderr that names a failed command
/// (written by its chain script), or empty.
std::string ChainFailure(const PlannedModel& model) {
  std::string found;
  fs::file_time_type newest;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(model.dir, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("slurm-", 0) != 0 || e.path().extension() != ".err") {
      continue;
    }
    const auto t = e.last_write_time(ec);
    if (!found.empty() && t <= newest) continue;
    std::ifstream in(e.path());
    std::string line, last;
    while (std::getline(in, line)) {
      if (line.rfind("soma reproduce: ", 0) == 0 &&
          line.find(" failed: ") != std::string::npos) {
        last = line.substr(16);
      }
    }
    if (!last.empty()) {
      found = last;
      newest = t;
    }
  }
  return found;
}

bool Selected(const PlannedModel& model, const ReproductionOptions& options) {
  const auto& only = options.only_variants;
  return only.empty() ||
         std::find(only.begin(), only.end(), model.variant) != only.end();
}

/// Submits `todo`'s models as one job array (see RunReproductionOnSlurm) and
/// marks them pending in the ledger.
SlurmSubmission SubmitModels(const ReproductionPlan& plan,
                             const std::vector<size_t>& todo,
                             const SlurmLauncherOptions& slurm) {
  const fs::path chains = plan.dir / ".slurm" / "models";
  CreateDirectories(chains);
  SbatchScriptSpec spec;
  spec.sweep_dir = fs::absolute(plan.dir).lexically_normal();
  spec.job_name = "soma-" + spec.sweep_dir.filename().string();
  spec.workdir = fs::current_path();
  spec.executable = "bash";
  for (size_t i : todo) {
    const PlannedModel& m = plan.models[i];
    const fs::path chain =
        fs::absolute(chains / fmt::format("{}.sh", i)).lexically_normal();
    WriteFileAtomic(chain, ModelChainScript(m));
    spec.tasks.push_back({static_cast<int>(i),
                          fs::absolute(m.dir).lexically_normal(),
                          {chain.string()}});
  }
  // Throws with sbatch's message; the ledger is untouched then.
  SlurmSubmission submission = SubmitSlurmArray(slurm, spec);
  {
    LedgerLock lock(plan.dir);
    Ledger ledger = Ledger::Load(plan.dir);
    for (size_t i : todo) {
      LedgerEntry& entry = ledger.Entry(static_cast<int>(i));
      entry.status = JobStatus::kPending;
      entry.error.clear();
      ++entry.attempts;
    }
    ledger.Save();
  }
  SOMA_LOG(INFO,
           "reproduce: submitted SLURM array job {} ({} models: {}); script "
           "{}",
           submission.array_job_id,
           todo.size(),
           ArrayIndexList(submission.nums),
           submission.script);
  return submission;
}

/// Brings model `num`'s ledger entry up to date with its plan (a new budget
/// resets it) and, if the model finished, marks it `done` with its metrics.
/// Returns whether it is done; the status of an unfinished model is left to
/// the caller.
bool SyncLedgerEntry(const PlannedModel& m, int num, Ledger& ledger) {
  LedgerEntry& entry = ledger.Entry(num);
  if (entry.config_hash != m.LedgerKey()) {
    entry = LedgerEntry{};
    entry.num = num;
  }
  entry.overrides = m.train_overrides;
  entry.config_hash = m.LedgerKey();
  entry.dir = m.dir.string();
  if (m.Done()) {
    entry.status = JobStatus::kDone;
    entry.error.clear();
    entry.metrics = ModelMetrics(m);
    return true;
  }
  return false;
}

}  // namespace

std::string ModelChainScript(const PlannedModel& model) {
  std::string s =
      "#!/bin/bash\n"
      "# Generated by soma reproduce (hydra/launcher=slurm): the commands of "
      "one model.\n"
      "set -u\n"
      // The array task's environment is for `soma -m`; these are not sweeps.
      "unset SOMA_SWEEP_JOB SOMA_SWEEP_DIR\n"
      // Each start's wall time, one line per attempt (the ledger's sum).
      "wall_file=" +
      ShellQuote((fs::absolute(model.dir).lexically_normal() / kChainWallFile)
                     .string()) +
      "\n"
      "t0=$(date +%s.%N)\n"
      "trap 'awk -v a=\"$t0\" -v b=\"$(date +%s.%N)\" "
      "\"BEGIN {printf \\\"%.3f\\\\n\\\", b - a}\" >> \"$wall_file\"' EXIT\n"
      "child=\n"
      "trap '[[ -n $child ]] && kill -TERM \"$child\" 2>/dev/null' TERM INT\n"
      // The wrapper's SIGUSR1 (preemption): a training checkpoints and stops.
      "trap '[[ -n $child ]] && kill -USR1 \"$child\" 2>/dev/null' USR1\n"
      "run() {  # run NAME RUN_DIR ARGV...\n"
      "  local name=$1 dir=$2 rc\n"
      "  shift 2\n"
      "  if [[ -f $dir/metrics.yaml && ! -f $dir/error.txt ]]; then\n"
      "    echo \"soma reproduce: $name: done already\"\n"
      "    return 0\n"
      "  fi\n"
      "  mkdir -p \"$dir\" && rm -f \"$dir/error.txt\" \"$dir/metrics.yaml\"\n"
      "  echo \"soma reproduce: $name\"\n"
      "  \"$@\" >\"$dir/stdout.txt\" 2>&1 &\n"
      "  child=$!\n"
      "  wait \"$child\"\n"
      "  while kill -0 \"$child\" 2>/dev/null; do wait \"$child\"; done\n"
      "  wait \"$child\"\n"
      "  rc=$?\n"
      "  child=\n"
      "  if ((rc > 128)); then\n"
      "    echo \"soma reproduce: $name stopped by signal $((rc - 128))"
      " (log: $dir/stdout.txt)\" >&2\n"
      "    exit \"$rc\"\n"
      "  fi\n"
      "  if ((rc != 0)) || [[ ! -f $dir/metrics.yaml || -f $dir/error.txt ]];"
      " then\n"
      "    local error=\"exit code $rc\"\n"
      "    [[ -f $dir/error.txt ]] && error=$(head -c 2000 \"$dir/error.txt\" |"
      " tr '\\n' ' ')\n"
      "    error=${error% }\n"
      "    echo \"soma reproduce: $name failed: $error (log: $dir/stdout.txt)\""
      " >&2\n"
      "    ((rc != 0)) || rc=1\n"
      "    exit \"$rc\"\n"
      "  fi\n"
      "}\n";
  for (const PlannedCommand& c : model.commands) {
    s += "run " + ShellQuote(c.name) + " " +
         ShellQuote(fs::absolute(c.run_dir).lexically_normal().string());
    for (const std::string& a : c.argv) s += " " + ShellQuote(a);
    s += "\n";
  }
  return s;
}

bool PlannedCommand::Done() const { return RunDirDone(run_dir); }

bool PlannedModel::Done() const {
  return std::all_of(commands.begin(),
                     commands.end(),
                     [](const PlannedCommand& c) { return c.Done(); });
}

std::string PlannedModel::LedgerKey() const {
  return fmt::format("{}/{}", hash, seed);
}

ReproductionPlan PlanReproduction(const AblationSpec& spec,
                                  const ReproductionOptions& options) {
  ReproductionPlan plan;
  // Keyed by the budget: a reproduction under another budget (e.g. another
  // marker layout) trains other models and keeps its own ledger.
  plan.dir = options.root / (spec.name + "-" + Hash8(options.budget));
  plan.seeds = options.seeds > 0 ? options.seeds : spec.seeds;
  const std::string exe = options.executable.string();

  std::set<fs::path> corrupt_dirs;
  for (const AblationTest& test : spec.tests) {
    const fs::path dir = CorruptDir(test, options);
    if (!corrupt_dirs.insert(dir).second) continue;
    PlannedCommand command;
    command.name = fmt::format("corrupt {} {}", test.take, test.setting);
    command.run_dir = dir;
    command.argv = {
        exe,
        "corrupt",
        fmt::format("task.files=[{}]", (options.data_dir / test.take).string()),
        fmt::format("task.settings=[{}]", test.setting),
        fmt::format("seed={}", options.test_seed)};
    command.argv.insert(command.argv.end(),
                        test.corrupt_overrides.begin(),
                        test.corrupt_overrides.end());
    command.argv.push_back(RunDirArg(dir));
    plan.corrupt.push_back(command);
  }

  // Seed-major order: every variant gets its first seed before any gets a
  // second, so a partial table already has every row.
  for (int seed = 0; seed < plan.seeds; ++seed) {
    for (const AblationVariant& variant : spec.variants) {
      if (!variant.skip.empty()) continue;
      std::vector<std::string> overrides = options.budget;
      overrides.insert(
          overrides.end(), variant.overrides.begin(), variant.overrides.end());
      const std::string hash = Hash8(overrides);
      const fs::path variant_dir =
          options.root / "models" / (Slug(variant.overrides) + "-" + hash);
      PlannedModel model;
      model.variant = variant.name;
      model.seed = seed;
      model.hash = hash;
      model.train_overrides = overrides;
      model.train_overrides.push_back(fmt::format("seed={}", seed));
      model.dir = variant_dir / fmt::format("seed{}", seed);

      PlannedCommand train;
      train.name = fmt::format("train {} seed {}", variant.name, seed);
      train.run_dir = model.dir;
      train.argv = {exe, "train"};
      train.argv.insert(train.argv.end(),
                        model.train_overrides.begin(),
                        model.train_overrides.end());
      const bool sets_threads = std::any_of(
          overrides.begin(), overrides.end(), [](const std::string& o) {
            const size_t key = o.find_first_not_of('+');  // ++threads=...
            return key != std::string::npos &&
                   o.compare(key, 8, "threads=") == 0;
          });
      if (options.train_threads > 0 && !sets_threads) {
        // Not part of the model's key: the thread count changes float
        // rounding only.
        train.argv.push_back(fmt::format("threads={}", options.train_threads));
      }
      train.argv.push_back(RunDirArg(model.dir));
      model.commands.push_back(train);

      const fs::path checkpoint = model.dir / "checkpoints" / "best.pt";
      for (const AblationTest& test : spec.tests) {
        if (!variant.Evaluates(test.name)) continue;
        const std::string stem = fs::path(test.take).stem().string();
        std::vector<std::string> test_overrides = test.corrupt_overrides;
        test_overrides.insert(test_overrides.end(),
                              test.eval_overrides.begin(),
                              test.eval_overrides.end());
        test_overrides.insert(test_overrides.end(),
                              test.label_overrides.begin(),
                              test.label_overrides.end());
        const fs::path test_dir = model.dir / "tests" /
                                  fmt::format("{}_{}_{}_seed{}{}",
                                              stem,
                                              test.setting,
                                              Mode(test),
                                              options.test_seed,
                                              OverridesSuffix(test_overrides));
        const fs::path corrupted = CorruptDir(test, options) / test.setting;
        PlannedCommand label;
        label.name = fmt::format(
            "label {} seed {} on {}", variant.name, seed, test.name);
        label.run_dir = test_dir / "label";
        label.argv = {exe,
                      "label",
                      "task.input=" + (corrupted / (stem + ".c3d")).string(),
                      "task.checkpoint=" + checkpoint.string(),
                      fmt::format("task.tracklet={}", test.tracklet),
                      fmt::format("task.inference.seed={}", options.test_seed),
                      "threads=1"};
        label.argv.insert(label.argv.end(),
                          test.label_overrides.begin(),
                          test.label_overrides.end());
        label.argv.push_back(RunDirArg(label.run_dir));
        PlannedCommand eval;
        eval.name =
            fmt::format("eval {} seed {} on {}", variant.name, seed, test.name);
        eval.run_dir = test_dir / "eval";
        eval.argv = {
            exe,
            "eval",
            "task.gt=" + (corrupted / (stem + ".h5")).string(),
            "task.rec=" + (label.run_dir / (stem + "_labeled.c3d")).string()};
        eval.argv.insert(eval.argv.end(),
                         test.eval_overrides.begin(),
                         test.eval_overrides.end());
        eval.argv.push_back(RunDirArg(eval.run_dir));
        model.commands.push_back(label);
        model.commands.push_back(eval);
        model.eval_dirs[test.name] = eval.run_dir;
      }
      plan.models.push_back(std::move(model));
    }
  }
  return plan;
}

fs::path ProgressReportDir(const ReproductionPlan& plan) {
  return plan.dir / "report";
}

void WriteCommandsScript(const ReproductionPlan& plan,
                         const fs::path& working_dir) {
  std::ostringstream sh;
  sh << "#!/usr/bin/env bash\n"
        "# Every command of this reproduction, in the order `soma reproduce`\n"
        "# runs them (models may run in parallel). A command whose run dir\n"
        "# holds metrics.yaml and no error.txt is done and is skipped.\n"
        "set -euo pipefail\n";
  sh << "cd " << ShellQuote(std::vector<std::string>{working_dir.string()})
     << "\n\n";
  for (const PlannedCommand& c : plan.corrupt) {
    sh << ShellQuote(c.argv) << "\n";
  }
  for (const PlannedModel& model : plan.models) {
    sh << "\n# " << model.variant << " seed " << model.seed << "\n";
    for (const PlannedCommand& c : model.commands) {
      sh << ShellQuote(c.argv) << "\n";
    }
  }
  CreateDirectories(plan.dir);
  WriteFileAtomic(plan.dir / "commands.sh", sh.str());
}

double EstimateSecondsLeft(std::vector<double> finished_model_s,
                           const std::vector<double>& running_elapsed_s,
                           size_t queued_models,
                           int jobs) {
  if (finished_model_s.empty() || jobs < 1) return -1;
  std::sort(finished_model_s.begin(), finished_model_s.end());
  const size_t n = finished_model_s.size();
  const double median =
      n % 2 == 1
          ? finished_model_s[n / 2]
          : 0.5 * (finished_model_s[n / 2 - 1] + finished_model_s[n / 2]);
  // Each slot's time until it is free: first what its running model has
  // left, then the queued models, each to the slot free first.
  std::vector<double> free_at(
      std::max<size_t>(static_cast<size_t>(jobs), running_elapsed_s.size()),
      0.0);
  for (size_t k = 0; k < running_elapsed_s.size(); ++k) {
    free_at[k] = std::max(median - running_elapsed_s[k], 0.0);
  }
  for (size_t k = 0; k < queued_models; ++k) {
    *std::min_element(free_at.begin(), free_at.end()) += median;
  }
  return *std::max_element(free_at.begin(), free_at.end());
}

ReproductionRun RunReproduction(
    const ReproductionPlan& plan,
    const ReproductionOptions& options,
    bool progress,
    const std::function<void()>& on_model_finished) {
  CreateDirectories(plan.dir);
  int64_t pending = 0;
  for (const PlannedCommand& c : plan.corrupt) pending += !c.Done();
  for (const PlannedModel& m : plan.models) {
    for (const PlannedCommand& c : m.commands) pending += !c.Done();
  }
  SOMA_LOG(INFO,
           "reproduce: {} models ({} commands to run), {} at a time; runs "
           "under {}",
           plan.models.size(),
           pending,
           options.jobs,
           options.root.string());
  ProgressBar bar(pending,
                  {.label = "reproduce",
                   .unit = "commands",
                   .plain_interval_s = 60,
                   .enabled = progress});

  RunCorruptions(plan, &bar);

  Ledger ledger = Ledger::Load(plan.dir);
  ReproductionRun run;
  struct Slot {
    size_t model = 0;
    size_t command = 0;
  };
  // Wall time of each model trained in this run, for the estimate of the
  // time left.
  std::map<size_t, Timer> model_timers;
  std::vector<double> finished_model_s;
  std::deque<size_t> queue;
  for (size_t i = 0; i < plan.models.size(); ++i) {
    const PlannedModel& m = plan.models[i];
    if (SyncLedgerEntry(m, static_cast<int>(i), ledger)) {
      ++run.models_done;
    } else {
      ledger.Entry(static_cast<int>(i)).status = JobStatus::kPending;
      if (Selected(m, options)) queue.push_back(i);
    }
  }
  ledger.Save();
  if (!options.only_variants.empty()) {
    SOMA_LOG(INFO,
             "reproduce: only variants {}: {} unfinished models run now, the "
             "others stay pending",
             fmt::join(options.only_variants, ", "),
             queue.size());
  }

  ProcessPool pool(options.jobs);
  std::map<int64_t, Slot> running;  // process id -> slot
  // Starts the next unfinished command of `slot.model`; false if none left.
  auto start_next = [&](Slot slot) {
    const PlannedModel& m = plan.models[slot.model];
    while (slot.command < m.commands.size() &&
           m.commands[slot.command].Done()) {
      ++slot.command;
    }
    if (slot.command == m.commands.size()) return false;
    const PlannedCommand& c = m.commands[slot.command];
    PrepareRunDir(c);
    SOMA_LOG(INFO, "reproduce: {}", c.name);
    running[pool.Start(Spec(c))] = slot;
    return true;
  };
  auto finish_model = [&](size_t i, bool ok, const std::string& error) {
    LedgerEntry& entry = ledger.Entry(static_cast<int>(i));
    entry.status = ok ? JobStatus::kDone : JobStatus::kFailed;
    entry.error = error;
    entry.metrics = ModelMetrics(plan.models[i]);
    ledger.Save();
    if (ok) {
      ++run.models_done;
      if (const auto timer = model_timers.find(i);
          timer != model_timers.end()) {
        finished_model_s.push_back(timer->second.ElapsedSeconds());
      }
    } else {
      ++run.models_failed;
      run.errors.push_back(error);
      SOMA_LOG(ERROR, "reproduce: {}", error);
    }
    model_timers.erase(i);
    std::vector<double> running_elapsed_s;
    running_elapsed_s.reserve(model_timers.size());
    for (const auto& [model, timer] : model_timers) {
      running_elapsed_s.push_back(timer.ElapsedSeconds());
    }
    const double left = EstimateSecondsLeft(
        finished_model_s, running_elapsed_s, queue.size(), options.jobs);
    const bool more = !running_elapsed_s.empty() || !queue.empty();
    SOMA_LOG(INFO,
             "reproduce: {} of {} models done{}",
             run.models_done,
             plan.models.size(),
             left < 0 || !more
                 ? std::string()
                 : fmt::format("; about {} left ({} running, {} queued)",
                               FormatDuration(left),
                               running_elapsed_s.size(),
                               queue.size()));
    if (on_model_finished) on_model_finished();
  };
  auto fill = [&]() {
    while (pool.num_running() < pool.max_parallel() && !queue.empty()) {
      const size_t i = queue.front();
      queue.pop_front();
      LedgerEntry& entry = ledger.Entry(static_cast<int>(i));
      entry.status = JobStatus::kRunning;
      ++entry.attempts;
      ledger.Save();
      // A model whose training is done has only its quick evaluations left:
      // it would pull the median model time towards 0.
      if (!plan.models[i].commands.front().Done()) {
        model_timers.emplace(i, Timer());
      }
      if (!start_next({i, 0})) finish_model(i, true, "");
    }
  };

  fill();
  while (std::optional<ProcessResult> result = pool.WaitAny()) {
    const Slot slot = running.at(result->id);
    running.erase(result->id);
    const PlannedModel& m = plan.models[slot.model];
    const PlannedCommand& c = m.commands[slot.command];
    LedgerEntry& entry = ledger.Entry(static_cast<int>(slot.model));
    entry.wall_time_s += result->wall_time_s;
    bar.Update(1, c.name);
    if (result->exit_code != 0 || !c.Done()) {
      finish_model(slot.model, false, CommandError(c, result->exit_code));
    } else {
      SOMA_LOG(INFO,
               "reproduce: {} finished in {:.0f} s",
               c.name,
               result->wall_time_s);
      if (!start_next({slot.model, slot.command + 1})) {
        finish_model(slot.model, true, "");
      } else {
        ledger.Save();
      }
    }
    fill();
  }
  bar.Finish();
  for (const LedgerEntry& e : ledger.entries()) run.compute_s += e.wall_time_s;
  return run;
}

ReproductionRun RunReproductionOnSlurm(
    const ReproductionPlan& plan,
    const ReproductionOptions& options,
    const SlurmLauncherOptions& slurm,
    const std::function<void()>& on_model_finished) {
  CreateDirectories(plan.dir);
  SOMA_LOG(INFO,
           "reproduce: {} models on SLURM (hydra/launcher=slurm); runs under "
           "{}",
           plan.models.size(),
           options.root.string());
  RunCorruptions(plan, nullptr);

  ReproductionRun run;
  std::vector<size_t> todo;
  {
    LedgerLock lock(plan.dir);
    Ledger ledger = Ledger::Load(plan.dir);
    for (size_t i = 0; i < plan.models.size(); ++i) {
      const PlannedModel& m = plan.models[i];
      if (SyncLedgerEntry(m, static_cast<int>(i), ledger)) {
        ++run.models_done;
      } else if (Selected(m, options)) {
        todo.push_back(i);
      } else {
        ledger.Entry(static_cast<int>(i)).status = JobStatus::kPending;
      }
    }
    ledger.Save();
  }
  // Models still queued or running from an earlier submission (e.g. with
  // wait=false) are waited for, not submitted twice.
  std::vector<size_t> queued;
  if (!todo.empty() && fs::exists(plan.dir / ".slurm" / "submissions.yaml")) {
    std::set<int> in_slurm;
    for (const SweepJobState& st : QuerySweepState(plan.dir, false)) {
      if (st.state == "pending" || st.state == "running") {
        in_slurm.insert(st.entry.num);
      }
    }
    std::vector<size_t> submit;
    for (size_t i : todo) {
      (in_slurm.count(static_cast<int>(i)) ? queued : submit).push_back(i);
    }
    todo = submit;
  }
  if (todo.empty() && queued.empty()) {
    SOMA_LOG(INFO, "reproduce: every model is done, nothing to submit");
    return run;
  }
  if (!queued.empty()) {
    std::vector<int> nums(queued.begin(), queued.end());
    SOMA_LOG(INFO,
             "reproduce: models {} are still in SLURM's queue from an earlier "
             "submission; not submitting them again",
             ArrayIndexList(nums));
  }
  SlurmSubmission submission;
  if (!todo.empty()) submission = SubmitModels(plan, todo, slurm);
  for (size_t i : queued) submission.nums.push_back(static_cast<int>(i));
  std::sort(submission.nums.begin(), submission.nums.end());
  if (submission.array_job_id.empty()) submission.array_job_id = "(earlier)";
  if (!slurm.wait) {
    SOMA_LOG(INFO,
             "reproduce: not waiting (hydra.launcher.wait=false); run the same "
             "command again to wait for the models and write the table");
    return run;
  }
  Timer timer;
  // A model's commands do not write the ledger: it is done when they are.
  const SlurmJobEndedOk ended_ok = [&](LedgerEntry& entry) {
    if (entry.num < 0 || entry.num >= static_cast<int>(plan.models.size())) {
      return false;
    }
    const PlannedModel& m = plan.models[entry.num];
    if (!m.Done()) return false;
    entry.metrics = ModelMetrics(m);
    entry.wall_time_s = ChainWallSeconds(m);
    return true;
  };
  WaitForSlurmJobs(plan.dir, submission, slurm, ended_ok);
  // The failed models: the failing command, its error and log from the
  // model's SLURM stderr, into the ledger.
  Ledger ledger;
  {
    LedgerLock lock(plan.dir);
    ledger = Ledger::Load(plan.dir);
    for (int num : submission.nums) {
      LedgerEntry& e = ledger.Entry(num);
      const PlannedModel& m = plan.models[num];
      if (e.status == JobStatus::kDone) continue;
      e.wall_time_s = ChainWallSeconds(m);
      const std::string failure = ChainFailure(m);
      if (!failure.empty() && e.error.find(failure) == std::string::npos) {
        e.error = failure + "; " + e.error;
      }
    }
    ledger.Save();
  }
  run.models_done = 0;
  for (size_t i = 0; i < plan.models.size(); ++i) {
    run.models_done += plan.models[i].Done();
  }
  for (int num : submission.nums) {
    const LedgerEntry* e = ledger.Find(num);
    if (e == nullptr || e->status == JobStatus::kDone) continue;
    ++run.models_failed;
    const std::string error = fmt::format(
        "{} seed {}: {}",
        plan.models[num].variant,
        plan.models[num].seed,
        e->status == JobStatus::kFailed ? e->error
                                        : std::string(ToString(e->status)));
    run.errors.push_back(error);
    SOMA_LOG(ERROR, "reproduce: {}", error);
  }
  for (const LedgerEntry& e : ledger.entries()) run.compute_s += e.wall_time_s;
  SOMA_LOG(INFO,
           "reproduce: SLURM array {} ended after {:.0f} s: {} of {} models "
           "done, {} failed",
           submission.array_job_id,
           timer.ElapsedSeconds(),
           run.models_done,
           plan.models.size(),
           run.models_failed);
  if (on_model_finished) on_model_finished();
  return run;
}

bool AdoptUnkeyedLedger(const ReproductionPlan& plan,
                        const fs::path& unkeyed_dir) {
  if (fs::exists(plan.dir) || !fs::exists(unkeyed_dir / "jobs.yaml")) {
    return false;
  }
  std::set<std::string> hashes;
  for (const PlannedModel& m : plan.models) {
    hashes.insert(m.LedgerKey());
  }
  const Ledger ledger = Ledger::Load(unkeyed_dir);
  const std::vector<LedgerEntry>& entries = ledger.entries();
  if (std::none_of(entries.begin(), entries.end(), [&](const LedgerEntry& e) {
        return hashes.count(e.config_hash) > 0;
      })) {
    return false;
  }
  std::error_code error;
  fs::rename(unkeyed_dir, plan.dir, error);
  if (error) {
    throw IoError(fmt::format("{}: could not move the ledger to {}: {}",
                              unkeyed_dir.string(),
                              plan.dir.string(),
                              error.message()));
  }
  return true;
}

ReproductionRun SummarizeLedger(const ReproductionPlan& plan) {
  ReproductionRun run;
  const Ledger ledger = Ledger::Load(plan.dir);
  for (size_t i = 0; i < plan.models.size(); ++i) {
    const PlannedModel& m = plan.models[i];
    run.models_done += m.Done();
    if (const LedgerEntry* e = ledger.Find(static_cast<int>(i))) {
      run.compute_s += e->wall_time_s;
      if (e->status == JobStatus::kFailed) {
        ++run.models_failed;
        run.errors.push_back(e->error);
      }
    }
  }
  return run;
}

std::vector<std::string> TrainingMachines(const ReproductionPlan& plan) {
  std::map<std::string, int> count;
  for (const PlannedModel& m : plan.models) {
    if (m.commands.empty() || !m.commands.front().Done()) continue;
    const fs::path file = m.dir / ".hydra" / "hydra.yaml";
    std::string machine = "no provenance";
    std::optional<ConfigNode> root;
    if (fs::is_regular_file(file)) {
      try {
        root = ParseYaml(ReadFile(file), file.string());
      } catch (const Error&) {
        machine = "unreadable provenance";
      }
    }
    if (root) {
      const ConfigNode* p = root->FindPath("hydra.runtime.provenance");
      auto text = [p](const char* key) -> std::string {
        const ConfigNode* n = p != nullptr ? p->Find(key) : nullptr;
        return n != nullptr && n->IsScalar() && !n->IsNull() ? n->text() : "";
      };
      const std::string host = text("host");
      const std::string cpu = text("cpu");
      machine = fmt::format("{}, {}",
                            host.empty() ? "unknown host" : host,
                            cpu.empty() ? "CPU not recorded" : cpu);
    }
    ++count[machine];
  }
  std::vector<std::pair<std::string, int>> sorted(count.begin(), count.end());
  std::stable_sort(sorted.begin(), sorted.end(), [](auto& a, auto& b) {
    return a.second > b.second;
  });
  std::vector<std::string> machines;
  machines.reserve(sorted.size());
  for (const auto& [machine, n] : sorted) {
    machines.push_back(
        fmt::format("{}: {} model{}", machine, n, n == 1 ? "" : "s"));
  }
  return machines;
}

std::vector<CellResult> CollectResults(const AblationSpec& spec,
                                       const ReproductionPlan& plan) {
  std::vector<CellResult> cells;
  for (const AblationVariant& variant : spec.variants) {
    for (const AblationTest& test : spec.tests) {
      if (!variant.Evaluates(test.name)) continue;
      for (const std::string& metric : ReproductionMetrics()) {
        CellResult cell;
        cell.variant = variant.name;
        cell.test = test.name;
        cell.metric = metric;
        cell.seeds_planned = variant.skip.empty() ? plan.seeds : 0;
        for (const PlannedModel& m : plan.models) {
          if (m.variant != variant.name) continue;
          const fs::path& dir = m.eval_dirs.at(test.name);
          if (!RunDirDone(dir)) continue;
          const auto metrics = ReadMetrics(dir);
          const auto mean = metrics.find(metric + "_mean");
          const auto std = metrics.find(metric + "_std");
          if (mean == metrics.end() || std == metrics.end()) {
            throw IoError(fmt::format(
                "{}: no {}_mean/{}_std; not a `soma eval` run directory",
                (dir / "metrics.yaml").string(),
                metric,
                metric));
          }
          cell.seed_means.push_back(100.0 * mean->second);
          cell.seed_frame_stds.push_back(100.0 * std->second);
          cell.seeds.push_back(m.seed);
        }
        cells.push_back(std::move(cell));
      }
    }
  }
  return cells;
}

int WriteWorstFramesMarkdown(const AblationSpec& spec,
                             const ReproductionPlan& plan,
                             int per_evaluation,
                             const fs::path& path) {
  const fs::path base = fs::absolute(path).parent_path();
  const auto link = [&](const fs::path& target) {
    return fs::absolute(target).lexically_relative(base).generic_string();
  };
  std::ostringstream md;
  md << "# " << spec.name << ": the worst frames of each evaluation\n\n"
     << "Per trained model and test, the " << per_evaluation
     << " frames with the lowest per-frame accuracy (`soma eval`'s "
        "per_frame.csv), each a link into the `soma view` page of the "
        "labelled output against the ground truth at that frame (red: wrong "
        "labels, orange: ghosts labelled as markers, rings: missed markers; "
        "README \"Look at the labels\"). Evaluations without a page (made "
        "before `soma view` existed, or with task.view=false) link their "
        "eval.md.\n\n"
     << "| variant | seed | test | accuracy (mean over frames) | worst frames "
        "|\n|---|---|---|---|---|\n";
  int rows = 0;
  for (const PlannedModel& m : plan.models) {
    for (const AblationTest& test : spec.tests) {
      const auto dir_it = m.eval_dirs.find(test.name);
      if (dir_it == m.eval_dirs.end() || !RunDirDone(dir_it->second)) continue;
      const fs::path& dir = dir_it->second;
      // run,frame,pairs,accuracy,... rows of the first output (run 0).
      std::vector<std::tuple<double, long, long>> frames;
      if (fs::exists(dir / "per_frame.csv")) {
        std::istringstream in(ReadFile(dir / "per_frame.csv"));
        std::string line;
        std::getline(in, line);
        while (std::getline(in, line)) {
          std::istringstream row(line);
          std::string run, frame, pairs, accuracy;
          if (!std::getline(row, run, ',') || !std::getline(row, frame, ',') ||
              !std::getline(row, pairs, ',') ||
              !std::getline(row, accuracy, ',')) {
            continue;
          }
          if (run != "0") continue;
          frames.emplace_back(
              std::stod(accuracy), std::stol(frame), std::stol(pairs));
        }
      }
      std::sort(frames.begin(), frames.end());
      fs::path page;
      if (fs::is_directory(dir / "view")) {
        for (const auto& entry : fs::directory_iterator(dir / "view")) {
          if (entry.path().extension() == ".html" &&
              (page.empty() || entry.path() < page)) {
            page = entry.path();
          }
        }
      }
      const auto metrics = ReadMetrics(dir);
      const auto mean = metrics.find("acc_mean");
      std::string worst;
      for (size_t i = 0;
           i < frames.size() && static_cast<int>(i) < per_evaluation &&
           std::get<0>(frames[i]) < 1.0;
           ++i) {
        const auto& [accuracy, frame, pairs] = frames[i];
        worst += fmt::format(
            "{}[{}]({}) {:.1f}% of {}",
            worst.empty() ? "" : ", ",
            frame,
            page.empty() ? link(dir / "eval.md")
                         : fmt::format("{}#frame={}", link(page), frame),
            100.0 * accuracy,
            pairs);
      }
      if (worst.empty()) {
        worst = frames.empty() ? "no per_frame.csv" : "every frame 100%";
      }
      md << fmt::format("| {} | {} | {} | {} | {} ([eval.md]({})) |\n",
                        m.variant,
                        m.seed,
                        test.name,
                        mean == metrics.end()
                            ? std::string("-")
                            : fmt::format("{:.2f}%", 100.0 * mean->second),
                        worst,
                        link(dir / "eval.md"));
      ++rows;
    }
  }
  WriteFileAtomic(path, md.str());
  return rows;
}

int WriteTrainingCurvesCsv(const ReproductionPlan& plan, const fs::path& path) {
  static const std::vector<std::string> kColumns = {
      "epoch", "train_loss", "val_loss", "val_acc", "val_f1"};
  const auto split = [](const std::string& line) {
    std::vector<std::string> fields;
    std::string field;
    std::istringstream in(line);
    while (std::getline(in, field, ',')) fields.push_back(field);
    return fields;
  };
  std::ostringstream csv;
  csv << "variant,seed,epoch,train_loss,val_loss,val_acc,val_f1\n";
  int rows = 0;
  for (const PlannedModel& m : plan.models) {
    const fs::path file = m.dir / "metrics.csv";
    if (!fs::exists(file)) continue;
    std::istringstream in(ReadFile(file));
    std::string line;
    std::getline(in, line);
    const std::vector<std::string> header = split(line);
    std::vector<size_t> index;
    for (const std::string& column : kColumns) {
      const auto it = std::find(header.begin(), header.end(), column);
      if (it == header.end()) {
        throw IoError(
            fmt::format("{}: no column '{}' (not a `soma train` metrics.csv)",
                        file.string(),
                        column));
      }
      index.push_back(static_cast<size_t>(it - header.begin()));
    }
    while (std::getline(in, line)) {
      const std::vector<std::string> fields = split(line);
      if (fields.empty()) continue;
      csv << m.variant << ',' << m.seed;
      for (size_t i : index) csv << ',' << (i < fields.size() ? fields[i] : "");
      csv << '\n';
      ++rows;
    }
  }
  WriteFileAtomic(path, csv.str());
  return rows;
}

}  // namespace soma
