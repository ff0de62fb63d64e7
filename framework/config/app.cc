#include "framework/config/app.h"

#include "framework/config/compose.h"
#include "framework/config/interpolation.h"
#include "framework/config/ledger.h"
#include "framework/config/override.h"
#include "framework/config/slurm_launcher.h"
#include "framework/config/sweep.h"
#include "framework/config/yaml_io.h"
#include "framework/core/build_info.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/provenance.h"
#include "framework/core/random.h"
#include "framework/core/timer.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <map>
#include <optional>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

namespace soma {
namespace {

namespace fs = std::filesystem;

constexpr int kExitOk = 0;
constexpr int kExitError = 1;
constexpr int kExitUsage = 2;

/// A usage error (bad flag): printed with a pointer to --help, exit code 2.
class UsageError : public Error {
 public:
  explicit UsageError(const std::string& message) : Error(message) {}
};

struct CliArgs {
  std::string config_path;               // -cp
  std::string config_name;               // -cn
  std::vector<std::string> config_dirs;  // -cd
  std::optional<std::string> cfg;        // --cfg job|hydra|all
  bool resolve = false;                  // --resolve
  std::string package;                   // -p
  std::optional<std::string> info;       // --info [what]
  bool multirun = false;                 // -m
  bool help = false;                     // --help
  std::vector<std::string> overrides;
};

CliArgs ParseArgs(const std::vector<std::string>& args,
                  std::string_view default_config_dir,
                  std::string_view default_config_name) {
  CliArgs cli;
  cli.config_path = std::string(default_config_dir);
  cli.config_name = std::string(default_config_name);
  auto take_value = [&](size_t& i,
                        std::string_view flag,
                        const std::optional<std::string>& inline_value) {
    if (inline_value) return *inline_value;
    if (i + 1 >= args.size()) {
      throw UsageError(fmt::format("Flag '{}' needs a value", flag));
    }
    return args[++i];
  };
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& arg = args[i];
    if (arg.empty() || arg[0] != '-') {
      cli.overrides.push_back(arg);
      continue;
    }
    std::string flag = arg;
    std::optional<std::string> inline_value;
    if (const size_t eq = arg.find('=');
        eq != std::string::npos && arg.rfind("--", 0) == 0) {
      flag = arg.substr(0, eq);
      inline_value = arg.substr(eq + 1);
    }
    if (flag == "-h" || flag == "--help") {
      cli.help = true;
    } else if (flag == "-m" || flag == "--multirun") {
      cli.multirun = true;
    } else if (flag == "-cp" || flag == "--config-path") {
      cli.config_path = take_value(i, flag, inline_value);
    } else if (flag == "-cn" || flag == "--config-name") {
      cli.config_name = take_value(i, flag, inline_value);
    } else if (flag == "-cd" || flag == "--config-dir") {
      cli.config_dirs.push_back(take_value(i, flag, inline_value));
    } else if (flag == "-c" || flag == "--cfg") {
      const std::string what = take_value(i, flag, inline_value);
      if (what != "job" && what != "hydra" && what != "all") {
        throw UsageError(fmt::format(
            "--cfg expects one of job, hydra, all; got '{}'", what));
      }
      cli.cfg = what;
    } else if (flag == "--resolve") {
      cli.resolve = true;
    } else if (flag == "-p" || flag == "--package") {
      cli.package = take_value(i, flag, inline_value);
    } else if (flag == "-i" || flag == "--info") {
      std::string what = "all";
      if (inline_value) {
        what = *inline_value;
      } else if (i + 1 < args.size() && !args[i + 1].empty() &&
                 args[i + 1][0] != '-' &&
                 args[i + 1].find('=') == std::string::npos) {
        what = args[++i];
      }
      static const char* kInfos[] = {
          "all", "defaults", "defaults-tree", "searchpath", "config"};
      if (std::find(std::begin(kInfos), std::end(kInfos), what) ==
          std::end(kInfos)) {
        throw UsageError(fmt::format(
            "--info expects one of all, defaults, defaults-tree, searchpath, "
            "config; got '{}'",
            what));
      }
      cli.info = what;
    } else {
      throw UsageError(fmt::format("Unknown flag '{}'", arg));
    }
  }
  if (cli.resolve && !cli.cfg) {
    throw UsageError("--resolve is only meaningful with --cfg job|hydra|all");
  }
  return cli;
}

std::vector<std::string> SearchPath(const CliArgs& cli) {
  std::vector<std::string> path{cli.config_path};
  path.insert(path.end(), cli.config_dirs.begin(), cli.config_dirs.end());
  return path;
}

ComposeRequest MakeRequest(const CliArgs& cli,
                           std::vector<Override> overrides,
                           RunMode mode,
                           bool allow_sweeps) {
  ComposeRequest request;
  request.search_path = SearchPath(cli);
  request.config_name = cli.config_name;
  request.overrides = std::move(overrides);
  request.mode = mode;
  request.allow_sweeps = allow_sweeps;
  request.job_name = "soma";
  return request;
}

std::string ResolveToString(const ConfigNode& root, std::string_view path) {
  const ConfigNode value = Select(root, path, DefaultResolvers());
  if (value.IsString()) return value.AsString();
  if (value.IsInt()) return std::to_string(value.AsInt());
  throw ConfigError(
      fmt::format("{} must be a string, got {}", path, value.Describe()));
}

std::string ConfigHash(const ConfigNode& root) {
  return fmt::format("{:016x}", Fnv1a64(DumpYaml(TaskConfig(root))));
}

std::vector<std::string> TaskOverrides(const ConfigNode& root) {
  std::vector<std::string> out;
  if (const ConfigNode* list = root.FindPath("hydra.overrides.task");
      list && list->IsList()) {
    for (const ConfigNode& item : list->items()) out.push_back(item.text());
  }
  return out;
}

ConfigNode StringList(const std::vector<std::string>& items) {
  ConfigNode list = ConfigNode::EmptyList();
  for (const std::string& item : items) {
    list.Append(ConfigNode::LiteralString(item));
  }
  return list;
}

/// Adds the run-time facts of a job to its hydra node.
void SetJobRuntime(ConfigNode& root,
                   const CliArgs& cli,
                   int job_num,
                   const fs::path& output_dir) {
  root.SetPath("hydra.job.num", job_num);
  root.SetPath("hydra.job.id",
               ConfigNode::LiteralString(std::to_string(job_num)));
  root.SetPath("hydra.job.config_name",
               ConfigNode::LiteralString(cli.config_name));
  root.SetPath("hydra.runtime.output_dir",
               ConfigNode::LiteralString(
                   fs::absolute(output_dir).lexically_normal().string()));
  root.SetPath("hydra.runtime.cwd",
               ConfigNode::LiteralString(fs::current_path().string()));
}

int ThreadsFor(const ConfigNode& task_cfg, int n_parallel) {
  int threads = 0;
  if (const ConfigNode* node = task_cfg.Find("threads");
      node && node->IsInt()) {
    threads = static_cast<int>(node->AsInt());
  }
  if (threads <= 0) {
    threads =
        static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  }
  return std::max(1, threads / std::max(1, n_parallel));
}

ConfigNode ProvenanceNode(
    const GitState& git,
    const std::string& start_time,
    const std::optional<std::pair<std::string, double>>& end,
    int threads) {
  ConfigNode node = ConfigNode::EmptyMap();
  const BuildInfo build = GetBuildInfo();
  node.Set("somalab_version", ConfigNode::LiteralString(build.version));
  node.Set("git_sha",
           ConfigNode::LiteralString(git.available ? git.sha : "unknown"));
  node.Set("git_dirty", git.dirty);
  node.Set("build_commit", ConfigNode::LiteralString(build.git_commit));
  node.Set("compiler", ConfigNode::LiteralString(build.compiler));
  node.Set("build_type", ConfigNode::LiteralString(build.build_type));
  ConfigNode libs = ConfigNode::EmptyMap();
  for (const auto& [name, version] : build.libraries) {
    libs.Set(name, ConfigNode::LiteralString(version));
  }
  node.Set("libraries", libs);
  node.Set("host", ConfigNode::LiteralString(HostName()));
  node.Set("cpu", ConfigNode::LiteralString(CpuModel()));
  node.Set("threads", threads);
  if (ConfigNode slurm = SlurmProvenance(); !slurm.IsNull()) {
    node.Set("slurm", std::move(slurm));
  }
  node.Set("start_time", ConfigNode::LiteralString(start_time));
  if (end) {
    node.Set("end_time", ConfigNode::LiteralString(end->first));
    node.Set("wall_time_s", end->second);
  } else {
    node.Set("end_time", ConfigNode::Null());
    node.Set("wall_time_s", ConfigNode::Null());
  }
  return node;
}

std::string DumpHydraNode(const ConfigNode& hydra) {
  ConfigNode wrapper = ConfigNode::EmptyMap();
  wrapper.Set("hydra", hydra);
  return DumpYaml(wrapper);
}

struct JobOutcome {
  bool ok = false;
  std::string error;
  std::map<std::string, double> metrics;
  double wall_time_s = 0;
};

/// Runs one job in this process: writes `.hydra/`, opens the job log, runs the
/// task, catches its errors, writes metrics. Never throws soma::Error.
JobOutcome RunJob(ConfigNode root,
                  const ConfigNode& resolved,
                  const fs::path& output_dir,
                  int job_num,
                  int threads,
                  const GitState& git,
                  const TaskFn& task) {
  JobOutcome outcome;
  Timer timer;
  const std::string start_time = IsoNow();
  const std::string job_name = root.at("hydra").at("job").at("name").AsString();
  fs::path hydra_dir;
  try {
    CreateDirectories(output_dir);
    const ConfigNode* subdir = root.FindPath("hydra.output_subdir");
    if (subdir != nullptr && !subdir->IsNull()) {
      hydra_dir = output_dir / subdir->AsString();
      CreateDirectories(hydra_dir);
      root.SetPath("hydra.runtime.provenance",
                   ProvenanceNode(git, start_time, std::nullopt, threads));
      WriteFileAtomic(hydra_dir / "config.yaml", DumpYaml(TaskConfig(root)));
      WriteFileAtomic(hydra_dir / "hydra.yaml",
                      DumpHydraNode(root.at("hydra")));
      WriteFileAtomic(hydra_dir / "overrides.yaml",
                      DumpYaml(StringList(TaskOverrides(root))));
      if (git.dirty && !git.diff.empty()) {
        WriteFileAtomic(hydra_dir / "git.diff", git.diff);
      }
    }
  } catch (const Error& e) {
    outcome.error = e.what();
    return outcome;
  }

  Logger::OpenFile((output_dir / (job_name + ".log")).string());
  RunContext ctx;
  ctx.output_dir = fs::absolute(output_dir).lexically_normal();
  ctx.job_name = job_name;
  ctx.job_num = job_num;
  ctx.overrides = TaskOverrides(root);
  ctx.num_threads = threads;
  try {
    ctx.hydra = resolved.at("hydra");
    const ConfigNode task_cfg = TaskConfig(resolved);
    if (const ConfigNode* seed = task_cfg.Find("seed"); seed && seed->IsInt()) {
      ctx.seed = static_cast<uint64_t>(seed->AsInt());
    }
    SOMA_LOG(INFO, "Job {} started in {}", job_num, ctx.output_dir.string());
    if (const std::string mismatch =
            BuildCommitMismatch(GetBuildInfo().git_commit, git);
        !mismatch.empty()) {
      SOMA_LOG(WARNING, "{}", mismatch);
    }
    task(task_cfg, ctx);
    outcome.ok = true;
  } catch (const Error& e) {
    outcome.error = e.what();
  } catch (const std::exception& e) {
    outcome.error = fmt::format("Internal error: {}", e.what());
  }
  outcome.wall_time_s = timer.ElapsedSeconds();
  outcome.metrics = ctx.metrics();
  if (outcome.ok) {
    SOMA_LOG(INFO, "Job {} finished in {:.2f}s", job_num, outcome.wall_time_s);
  } else {
    SOMA_LOG(ERROR, "Job {} failed: {}", job_num, outcome.error);
  }
  Logger::CloseFile();

  try {
    if (!outcome.metrics.empty()) {
      ConfigNode metrics = ConfigNode::EmptyMap();
      for (const auto& [name, value] : outcome.metrics)
        metrics.Set(name, value);
      WriteFileAtomic(output_dir / "metrics.yaml", DumpYaml(metrics));
    }
    if (!outcome.ok)
      WriteFileAtomic(output_dir / "error.txt", outcome.error + "\n");
    if (!hydra_dir.empty()) {
      root.SetPath("hydra.runtime.provenance",
                   ProvenanceNode(git,
                                  start_time,
                                  std::make_pair(IsoNow(), outcome.wall_time_s),
                                  threads));
      WriteFileAtomic(hydra_dir / "hydra.yaml",
                      DumpHydraNode(root.at("hydra")));
    }
  } catch (const Error& e) {
    if (outcome.ok) {
      outcome.ok = false;
      outcome.error = e.what();
    }
  }
  return outcome;
}

/// Reads back what a forked job left in its directory.
JobOutcome ReadOutcome(const fs::path& output_dir, bool ok, double wall) {
  JobOutcome outcome;
  outcome.ok = ok;
  outcome.wall_time_s = wall;
  try {
    if (fs::exists(output_dir / "metrics.yaml")) {
      const ConfigNode metrics =
          ParseYaml(ReadFile(output_dir / "metrics.yaml"),
                    (output_dir / "metrics.yaml").string());
      for (const auto& [name, value] : metrics.entries()) {
        outcome.metrics[name] = value.AsDouble();
      }
    }
    if (!ok) {
      outcome.error = fs::exists(output_dir / "error.txt")
                          ? ReadFile(output_dir / "error.txt")
                          : "the job process died without an error message";
      while (!outcome.error.empty() && outcome.error.back() == '\n') {
        outcome.error.pop_back();
      }
    }
  } catch (const Error& e) {
    outcome.ok = false;
    outcome.error = e.what();
  }
  return outcome;
}

void PrintConfig(const CliArgs& cli, ConfigNode root) {
  if (cli.resolve) root = Resolve(root, DefaultResolvers());
  ConfigNode selected;
  if (*cli.cfg == "job") {
    selected = TaskConfig(root);
  } else if (*cli.cfg == "hydra") {
    selected = ConfigNode::EmptyMap();
    selected.Set("hydra", root.at("hydra"));
  } else {
    selected = root;
  }
  if (!cli.package.empty()) {
    const ConfigNode* sub = selected.FindPath(cli.package);
    if (sub == nullptr) {
      throw ConfigError(fmt::format(
          "--package: no key '{}' in the {} config", cli.package, *cli.cfg));
    }
    std::fputs(fmt::format("# @package {}\n", cli.package).c_str(), stdout);
    selected = *sub;
  }
  // A resolved config prints its strings' values, `${` unescaped (Hydra).
  DumpOptions options;
  options.escape_interpolations = !cli.resolve;
  std::fputs(DumpYaml(selected, options).c_str(), stdout);
}

void PrintInfo(const CliArgs& cli, const ComposeResult& result) {
  const std::string& what = *cli.info;
  std::string out;
  if (what == "all" || what == "searchpath") {
    out += "Config search path\n******************\n";
    for (const std::string& root : result.search_path)
      out += "  " + root + "\n";
    out += "\n";
  }
  if (what == "all" || what == "defaults" || what == "defaults-tree") {
    out += FormatDefaultsList(result) + "\n";
  }
  if (what == "all" || what == "config") {
    out += "Config\n******\n" + DumpYaml(TaskConfig(result.root));
  }
  std::fputs(out.c_str(), stdout);
}

void PrintHelp(const CliArgs& cli) {
  std::string out = fmt::format(
      "soma {} — SOMA (ICCV 2021) reproduction framework\n\n"
      "Usage: soma [COMMAND] [FLAGS] [OVERRIDES]\n\n"
      "Overrides follow Hydra's grammar: key=value, +key=value (add), "
      "++key=value (add or set),\n~key (delete), group=option (select a "
      "config group option).\n\n"
      "Flags:\n"
      "  -h, --help                 this help\n"
      "  -m, --multirun             run a sweep: a=1,2 b=range(3) "
      "c=glob(*)\n"
      "  -c, --cfg job|hydra|all    print the composed config and exit\n"
      "      --resolve              with --cfg: resolve interpolations first\n"
      "  -p, --package PKG          with --cfg: print only this subtree\n"
      "  -i, --info [WHAT]          all, defaults, defaults-tree, searchpath, "
      "config\n"
      "  -cp, --config-path DIR     primary config directory (default: "
      "configs)\n"
      "  -cn, --config-name NAME    primary config name (default: config)\n"
      "  -cd, --config-dir DIR      extra config search root\n\n",
      SOMA_VERSION_STRING);
  try {
    std::vector<std::string> roots = SearchPath(cli);
    ConfigRepository repo(roots);
    out +=
        "== Configuration groups ==\n"
        "Compose your configuration from those groups (group=option)\n\n";
    for (const std::string& group : repo.Groups()) {
      const std::vector<std::string> options = repo.Options(group);
      if (options.empty()) continue;
      out += fmt::format("{}: {}\n", group, fmt::join(options, ", "));
    }
    const ComposeResult result =
        Compose(MakeRequest(cli,
                            ParseOverrides(cli.overrides),
                            RunMode::kRun,
                            /*allow_sweeps=*/true));
    out +=
        "\n== Config ==\nOverride anything in the config (foo.bar=value)\n\n";
    out += DumpYaml(TaskConfig(result.root));
  } catch (const Error& e) {
    out += fmt::format("(cannot show the configuration: {})\n", e.what());
  }
  std::fputs(out.c_str(), stdout);
}

bool WantsMultirun(const CliArgs& cli, const std::vector<Override>& overrides) {
  if (cli.multirun) return true;
  for (const Override& o : overrides) {
    if (o.key == "hydra.mode" && o.value && o.value->IsString() &&
        o.value->AsString() == "MULTIRUN") {
      return true;
    }
  }
  return false;
}

int RunSingle(const CliArgs& cli,
              const std::vector<Override>& overrides,
              const TaskFn& task) {
  ComposeResult result =
      Compose(MakeRequest(cli, overrides, RunMode::kRun, false));
  ConfigNode root = std::move(result.root);
  const fs::path output_dir = ResolveToString(root, "hydra.run.dir");
  SetJobRuntime(root, cli, 0, output_dir);
  // Resolve before anything is written: a cycle or a dangling reference fails
  // without leaving a half-made run directory.
  const ConfigNode resolved = Resolve(root, DefaultResolvers());
  const int threads = ThreadsFor(TaskConfig(resolved), 1);
  const JobOutcome outcome =
      RunJob(root, resolved, output_dir, 0, threads, QueryGit(), task);
  if (!outcome.ok) {
    std::fprintf(
        stderr,
        "Error executing job with overrides: [%s]: %s\n",
        fmt::format("{}", fmt::join(TaskOverrides(root), ", ")).c_str(),
        outcome.error.c_str());
    return kExitError;
  }
  return kExitOk;
}

struct PlannedJob {
  int num = 0;
  std::vector<std::string> overrides;
  ConfigNode root;
  ConfigNode resolved;
  fs::path dir;
  std::string hash;
};

/// `hydra.launcher.name`: basic (also when absent), local or slurm.
std::string LauncherKind(const ConfigNode& root) {
  const ConfigNode* target = root.FindPath("hydra.launcher.name");
  if (target == nullptr || target->IsNull()) return "basic";
  std::string kind = target->IsString() ? target->AsString() : target->text();
  if (kind != "basic" && kind != "local" && kind != "slurm") {
    throw ConfigError(fmt::format(
        "Unknown launcher hydra.launcher.name = {}; available launchers: "
        "basic, local, slurm (select one with hydra/launcher=<name>)",
        kind));
  }
  return kind;
}

/// The job an array task of the SLURM launcher runs.
struct ArrayTask {
  int num = 0;         // $SOMA_SWEEP_JOB
  fs::path sweep_dir;  // $SOMA_SWEEP_DIR
};

/// The array task this process is (from its environment, which is then
/// cleared so that processes the job starts are not array tasks), or nullopt
/// in an ordinary multirun.
std::optional<ArrayTask> ArrayTaskFromEnv() {
  const char* text = std::getenv(kSweepJobEnv);
  if (text == nullptr || *text == '\0') return std::nullopt;
  char* end = nullptr;
  const long num = std::strtol(text, &end, 10);
  if (*end != '\0' || num < 0 || std::getenv(kSweepDirEnv) == nullptr) {
    throw UsageError(fmt::format(
        "{}='{}' must be a job number and come with {} (set by the SLURM "
        "launcher's script)",
        kSweepJobEnv,
        text,
        kSweepDirEnv));
  }
  ArrayTask task{static_cast<int>(num), fs::path(std::getenv(kSweepDirEnv))};
  ::unsetenv(kSweepJobEnv);
  ::unsetenv(kSweepDirEnv);
  return task;
}

/// An array task of the SLURM launcher: runs its one job in this process and
/// records it in the ledger under the ledger lock (other tasks write too).
int RunArrayTask(const PlannedJob& job,
                 const fs::path& sweep_dir,
                 const TaskFn& task) {
  {
    LedgerLock lock(sweep_dir);
    Ledger ledger = Ledger::Load(sweep_dir);
    LedgerEntry& entry = ledger.Entry(job.num);
    entry.overrides = job.overrides;
    entry.config_hash = job.hash;
    entry.dir = job.dir.string();
    entry.status = JobStatus::kRunning;
    entry.error.clear();
    entry.metrics.clear();
    ++entry.attempts;
    ledger.Save();
  }
  SOMA_LOG(INFO, "#{} : {}", job.num, fmt::join(job.overrides, " "));
  const int threads = ThreadsFor(TaskConfig(job.resolved), 1);
  const JobOutcome outcome = RunJob(
      job.root, job.resolved, job.dir, job.num, threads, QueryGit(), task);
  LedgerLock lock(sweep_dir);
  Ledger ledger = Ledger::Load(sweep_dir);
  LedgerEntry& entry = ledger.Entry(job.num);
  entry.status = outcome.ok ? JobStatus::kDone : JobStatus::kFailed;
  entry.error = outcome.error;
  entry.metrics = outcome.metrics;
  entry.wall_time_s = outcome.wall_time_s;
  ledger.Save();
  WriteSummary(sweep_dir, SummarizeBySeed(ledger.entries()));
  if (!outcome.ok) {
    std::fprintf(stderr,
                 "Error executing job with overrides: [%s]: %s\n",
                 fmt::format("{}", fmt::join(job.overrides, ", ")).c_str(),
                 outcome.error.c_str());
    return kExitError;
  }
  return kExitOk;
}

/// The flags that make an array task's `soma` compose like this one.
std::vector<std::string> ArrayTaskArgs(const CliArgs& cli) {
  std::vector<std::string> args = {
      "-m",
      "-cp",
      fs::absolute(cli.config_path).lexically_normal().string(),
      "-cn",
      cli.config_name};
  for (const std::string& dir : cli.config_dirs) {
    args.push_back("-cd");
    args.push_back(fs::absolute(dir).lexically_normal().string());
  }
  return args;
}

/// The SLURM launcher: submits `todo` as one job array and marks it pending
/// in the ledger; with wait=false returns the exit code at once, else waits
/// for the array (SIGINT cancels it), lists the failures with their logs and
/// returns nullopt for the usual summary.
std::optional<int> LaunchOnSlurm(const CliArgs& cli,
                                 const fs::path& sweep_dir,
                                 const std::vector<PlannedJob>& jobs,
                                 const std::vector<const PlannedJob*>& todo) {
  const ConfigNode& hydra = jobs.front().resolved.at("hydra");
  const SlurmLauncherOptions options =
      DecodeSlurmLauncherOptions(hydra.at("launcher"));
  SbatchScriptSpec spec;
  spec.sweep_dir = fs::absolute(sweep_dir).lexically_normal();
  spec.job_name = "soma-" + spec.sweep_dir.filename().string();
  spec.workdir = fs::current_path();
  spec.executable = fs::read_symlink("/proc/self/exe").string();
  spec.base_args = ArrayTaskArgs(cli);
  for (const PlannedJob* job : todo) {
    spec.tasks.push_back(
        {job->num, fs::absolute(job->dir).lexically_normal(), job->overrides});
  }
  // Throws with sbatch's message; the ledger is untouched then.
  const SlurmSubmission submission = SubmitSlurmArray(options, spec);
  {
    LedgerLock lock(sweep_dir);
    Ledger ledger = Ledger::Load(sweep_dir);
    for (const SlurmArrayTask& t : spec.tasks) {
      LedgerEntry& entry = ledger.Entry(t.num);
      entry.overrides = t.overrides;
      entry.config_hash = jobs[t.num].hash;
      entry.dir = t.dir.string();
      entry.status = JobStatus::kPending;
      entry.error.clear();
      entry.metrics.clear();
    }
    ledger.Save();
  }
  SOMA_LOG(INFO,
           "Submitted SLURM array job {} (jobs {}); script {}",
           submission.array_job_id,
           ArrayIndexList(submission.nums),
           submission.script);
  if (!options.wait) {
    std::fputs(fmt::format("{}\n", spec.sweep_dir.string()).c_str(), stdout);
    SOMA_LOG(INFO,
             "Not waiting (hydra.launcher.wait=false): soma sweep status {}",
             spec.sweep_dir.string());
    return kExitOk;
  }
  WaitForSlurmJobs(sweep_dir, submission, options);
  const std::string log_name = hydra.at("job").at("name").AsString() + ".log";
  const Ledger ledger = Ledger::Load(sweep_dir);
  for (const LedgerEntry& entry : ledger.entries()) {
    if (entry.status == JobStatus::kDone) continue;
    SOMA_LOG(ERROR,
             "Job {} {}: log {}",
             entry.num,
             ToString(entry.status),
             (fs::path(entry.dir) / log_name).string());
  }
  return std::nullopt;
}

int RunMultirun(const CliArgs& cli,
                const std::vector<Override>& overrides,
                const TaskFn& task) {
  // Sweep-level composition (validates the structure; records raw sweeps).
  ComposeResult sweep =
      Compose(MakeRequest(cli, overrides, RunMode::kMultirun, true));
  sweep.root.SetPath("hydra.job.config_name",
                     ConfigNode::LiteralString(cli.config_name));
  ConfigRepository repo(sweep.search_path);
  const std::vector<std::vector<std::string>> job_overrides =
      ExpandSweep(sweep.root, overrides, repo);
  const std::optional<ArrayTask> array_task = ArrayTaskFromEnv();
  if (array_task && job_overrides.size() != 1) {
    throw ConfigError(fmt::format(
        "An array task must run exactly one job; its overrides make {}",
        job_overrides.size()));
  }
  const fs::path sweep_dir =
      array_task ? array_task->sweep_dir
                 : fs::path(ResolveToString(sweep.root, "hydra.sweep.dir"));
  int n_jobs = 1;
  if (const ConfigNode* n = sweep.root.FindPath("hydra.launcher.n_jobs");
      n && n->IsInt()) {
    n_jobs = std::max<int>(1, static_cast<int>(n->AsInt()));
  }

  // Every job's composition is validated before any job runs.
  std::vector<PlannedJob> jobs;
  for (size_t i = 0; i < job_overrides.size(); ++i) {
    PlannedJob job;
    job.num = array_task ? array_task->num : static_cast<int>(i);
    job.overrides = job_overrides[i];
    try {
      job.root = Compose(MakeRequest(cli,
                                     ParseOverrides(job.overrides),
                                     RunMode::kMultirun,
                                     false))
                     .root;
      job.root.SetPath("hydra.sweep.dir",
                       ConfigNode::LiteralString(sweep_dir.string()));
      job.root.SetPath("hydra.job.num", job.num);
      job.dir = sweep_dir / ResolveToString(job.root, "hydra.sweep.subdir");
      SetJobRuntime(job.root, cli, job.num, job.dir);
      job.resolved = Resolve(job.root, DefaultResolvers());
      job.hash = ConfigHash(job.root);
    } catch (const Error& e) {
      throw ConfigError(
          fmt::format("Job {} with overrides [{}] does not compose: {}",
                      i,
                      fmt::join(job.overrides, ", "),
                      e.what()));
    }
    jobs.push_back(std::move(job));
  }

  if (array_task) return RunArrayTask(jobs.front(), sweep_dir, task);
  const std::string launcher = LauncherKind(jobs.front().resolved);

  CreateDirectories(sweep_dir);
  WriteFileAtomic(sweep_dir / "multirun.yaml", DumpYaml(sweep.root));
  Ledger ledger = Ledger::Load(sweep_dir);
  SOMA_LOG(INFO,
           "Launching {} jobs in {} ({})",
           jobs.size(),
           sweep_dir.string(),
           launcher == "slurm" ? std::string("as a SLURM job array")
                               : fmt::format("{} at a time", n_jobs));

  const GitState git = QueryGit();
  std::vector<const PlannedJob*> todo;
  for (const PlannedJob& job : jobs) {
    if (ledger.IsDone(job.num, job.hash)) {
      SOMA_LOG(INFO,
               "#{} : {} (done, skipped)",
               job.num,
               fmt::join(job.overrides, " "));
      continue;
    }
    todo.push_back(&job);
  }

  auto start = [&](const PlannedJob& job) {
    LedgerEntry& entry = ledger.Entry(job.num);
    entry.overrides = job.overrides;
    entry.config_hash = job.hash;
    entry.dir = job.dir.string();
    entry.status = JobStatus::kRunning;
    entry.error.clear();
    entry.metrics.clear();
    ++entry.attempts;
    ledger.Save();
    SOMA_LOG(INFO, "#{} : {}", job.num, fmt::join(job.overrides, " "));
  };
  auto finish = [&](const PlannedJob& job, const JobOutcome& outcome) {
    LedgerEntry& entry = ledger.Entry(job.num);
    entry.status = outcome.ok ? JobStatus::kDone : JobStatus::kFailed;
    entry.error = outcome.error;
    entry.metrics = outcome.metrics;
    entry.wall_time_s = outcome.wall_time_s;
    ledger.Save();
  };

  if (launcher == "slurm") {
    if (!todo.empty()) {
      if (const std::optional<int> rc =
              LaunchOnSlurm(cli, sweep_dir, jobs, todo)) {
        return *rc;
      }
      ledger = Ledger::Load(sweep_dir);
    }
  } else if (n_jobs == 1) {
    for (const PlannedJob* job : todo) {
      start(*job);
      const int threads = ThreadsFor(TaskConfig(job->resolved), 1);
      finish(*job,
             RunJob(job->root,
                    job->resolved,
                    job->dir,
                    job->num,
                    threads,
                    git,
                    task));
    }
  } else {
    // Parallel local launcher: one forked process per job, n_jobs at a time.
    std::map<pid_t, std::pair<const PlannedJob*, Timer>> running;
    size_t next = 0;
    while (next < todo.size() || !running.empty()) {
      while (next < todo.size() && static_cast<int>(running.size()) < n_jobs) {
        const PlannedJob* job = todo[next++];
        start(*job);
        std::fflush(stdout);
        std::fflush(stderr);
        const pid_t pid = ::fork();
        if (pid < 0)
          throw InternalError("fork() failed for the parallel launcher");
        if (pid == 0) {
          const int threads = ThreadsFor(TaskConfig(job->resolved), n_jobs);
          const JobOutcome outcome = RunJob(
              job->root, job->resolved, job->dir, job->num, threads, git, task);
          std::fflush(stdout);
          std::fflush(stderr);
          ::_exit(outcome.ok ? 0 : 1);
        }
        running.emplace(pid, std::make_pair(job, Timer()));
      }
      int status = 0;
      const pid_t pid = ::waitpid(-1, &status, 0);
      if (pid < 0) break;
      auto it = running.find(pid);
      if (it == running.end()) continue;
      const bool ok = WIFEXITED(status) && WEXITSTATUS(status) == 0;
      finish(
          *it->second.first,
          ReadOutcome(
              it->second.first->dir, ok, it->second.second.ElapsedSeconds()));
      running.erase(it);
    }
  }

  WriteSummary(sweep_dir, SummarizeBySeed(ledger.entries()));
  std::vector<const LedgerEntry*> failures;
  for (const LedgerEntry& entry : ledger.entries()) {
    if (entry.status != JobStatus::kDone) failures.push_back(&entry);
  }
  if (failures.empty()) {
    SOMA_LOG(INFO,
             "All {} jobs done; ledger {}, summary {}",
             jobs.size(),
             (sweep_dir / "jobs.csv").string(),
             (sweep_dir / "summary.md").string());
    return kExitOk;
  }
  for (const LedgerEntry* f : failures) {
    SOMA_LOG(ERROR,
             "Job {} [{}] {}: {}",
             f->num,
             fmt::join(f->overrides, ", "),
             ToString(f->status),
             f->error);
  }
  std::fprintf(
      stderr,
      "Error executing job with overrides: [%s]: %s (%zu of %zu jobs failed; "
      "see %s)\n",
      fmt::format("{}", fmt::join(failures.front()->overrides, ", ")).c_str(),
      failures.front()->error.c_str(),
      failures.size(),
      jobs.size(),
      (sweep_dir / "jobs.csv").c_str());
  return kExitError;
}

}  // namespace

int RunHydraApp(const std::vector<std::string>& args,
                std::string_view default_config_dir,
                std::string_view default_config_name,
                const TaskFn& task) {
  try {
    const CliArgs cli =
        ParseArgs(args, default_config_dir, default_config_name);
    if (cli.help) {
      PrintHelp(cli);
      return kExitOk;
    }
    const std::vector<Override> overrides = ParseOverrides(cli.overrides);
    const bool multirun = WantsMultirun(cli, overrides);
    if (cli.cfg || cli.info) {
      const ComposeResult result =
          Compose(MakeRequest(cli,
                              overrides,
                              multirun ? RunMode::kMultirun : RunMode::kRun,
                              /*allow_sweeps=*/multirun));
      if (cli.cfg) PrintConfig(cli, result.root);
      if (cli.info) PrintInfo(cli, result);
      return kExitOk;
    }
    return multirun ? RunMultirun(cli, overrides, task)
                    : RunSingle(cli, overrides, task);
  } catch (const UsageError& e) {
    std::fprintf(stderr, "Error: %s. Run 'soma --help' for usage.\n", e.what());
    return kExitUsage;
  } catch (const Error& e) {
    std::fprintf(stderr, "Error: %s\n", e.what());
    return kExitError;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "Internal error: %s\n", e.what());
    return kExitError;
  }
}

int RunHydraApp(int argc,
                char** argv,
                std::string_view default_config_dir,
                std::string_view default_config_name,
                const TaskFn& task) {
  std::vector<std::string> args(argv + 1, argv + argc);
  return RunHydraApp(args, default_config_dir, default_config_name, task);
}

}  // namespace soma
