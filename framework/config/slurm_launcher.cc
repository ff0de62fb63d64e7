#include "framework/config/slurm_launcher.h"

#include "framework/config/decode.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/provenance.h"

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <map>
#include <poll.h>
#include <pwd.h>
#include <set>
#include <sstream>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

namespace soma {
namespace {

namespace fs = std::filesystem;

constexpr char kSlurmDir[] = ".slurm";
constexpr char kSubmissionsFile[] = "submissions.yaml";

// ---------------------------------------------------------------------------
// Running SLURM's client tools

struct CommandResult {
  int exit_code = -1;  // 127: could not be executed
  std::string out;
  std::string err;
};

/// The executable `name` on PATH, or empty.
std::string FindOnPath(const std::string& name) {
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path ? path : "");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    if (dir.empty()) dir = ".";
    const fs::path candidate = fs::path(dir) / name;
    if (::access(candidate.c_str(), X_OK) == 0) return candidate.string();
  }
  return {};
}

/// Runs argv (no shell), capturing stdout and stderr.
CommandResult RunCommand(const std::vector<std::string>& argv) {
  int out_pipe[2], err_pipe[2];
  if (::pipe(out_pipe) != 0 || ::pipe(err_pipe) != 0) {
    throw InternalError("pipe() failed");
  }
  std::fflush(stdout);
  std::fflush(stderr);
  const pid_t pid = ::fork();
  if (pid < 0) throw InternalError("fork() failed");
  if (pid == 0) {
    ::dup2(out_pipe[1], STDOUT_FILENO);
    ::dup2(err_pipe[1], STDERR_FILENO);
    ::close(out_pipe[0]);
    ::close(err_pipe[0]);
    ::close(out_pipe[1]);
    ::close(err_pipe[1]);
    std::vector<char*> args;
    args.reserve(argv.size() + 1);
    for (const std::string& a : argv)
      args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    ::execvp(args[0], args.data());
    const std::string message =
        fmt::format("cannot execute '{}': {}\n", argv[0], std::strerror(errno));
    (void)!::write(STDERR_FILENO, message.data(), message.size());
    ::_exit(127);
  }
  ::close(out_pipe[1]);
  ::close(err_pipe[1]);
  CommandResult result;
  pollfd fds[2] = {{out_pipe[0], POLLIN, 0}, {err_pipe[0], POLLIN, 0}};
  std::string* sinks[2] = {&result.out, &result.err};
  int open_fds = 2;
  char buffer[4096];
  while (open_fds > 0) {
    if (::poll(fds, 2, -1) < 0) {
      if (errno == EINTR) continue;
      break;
    }
    for (int i = 0; i < 2; ++i) {
      if (fds[i].fd < 0 || fds[i].revents == 0) continue;
      const ssize_t n = ::read(fds[i].fd, buffer, sizeof(buffer));
      if (n > 0) {
        sinks[i]->append(buffer, static_cast<size_t>(n));
      } else if (n == 0 || errno != EINTR) {
        ::close(fds[i].fd);
        fds[i].fd = -1;
        --open_fds;
      }
    }
  }
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  result.exit_code =
      WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return result;
}

std::string Trim(std::string text) {
  while (!text.empty() && std::isspace(static_cast<unsigned char>(text.back())))
    text.pop_back();
  size_t start = 0;
  while (start < text.size() &&
         std::isspace(static_cast<unsigned char>(text[start])))
    ++start;
  return text.substr(start);
}

/// stderr's lines joined into one line (SLURM prints `sbatch: error: ...`).
std::string OneLine(const std::string& text) {
  std::string out;
  std::stringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) {
    line = Trim(line);
    if (line.empty()) continue;
    out += (out.empty() ? "" : " ") + line;
  }
  return out;
}

void RequireTool(const std::string& tool) {
  if (FindOnPath(tool).empty()) {
    throw Error(fmt::format(
        "The SLURM launcher needs '{}' on PATH and it is not there (install "
        "SLURM's client tools, e.g. Debian's slurm-client); nothing was "
        "submitted",
        tool));
  }
}

// ---------------------------------------------------------------------------
// Submissions record

fs::path SubmissionsPath(const fs::path& sweep_dir) {
  return sweep_dir / kSlurmDir / kSubmissionsFile;
}

std::vector<SlurmSubmission> LoadSubmissions(const fs::path& sweep_dir) {
  std::vector<SlurmSubmission> out;
  const fs::path path = SubmissionsPath(sweep_dir);
  if (!fs::exists(path)) return out;
  const ConfigNode root = ParseYaml(ReadFile(path), path.string());
  const ConfigNode* list = root.Find("submissions");
  if (list == nullptr || !list->IsList()) {
    throw IoError(
        fmt::format("Malformed '{}': no submissions list", path.string()));
  }
  for (const ConfigNode& item : list->items()) {
    SlurmSubmission s;
    s.array_job_id = item.at("array_job_id").text();
    s.script = item.at("script").AsString();
    for (const ConfigNode& n : item.at("jobs").items()) {
      s.nums.push_back(static_cast<int>(n.AsInt()));
    }
    out.push_back(std::move(s));
  }
  return out;
}

void AppendSubmission(const fs::path& sweep_dir, const SlurmSubmission& s) {
  std::vector<SlurmSubmission> all = LoadSubmissions(sweep_dir);
  all.push_back(s);
  ConfigNode list = ConfigNode::EmptyList();
  for (const SlurmSubmission& item : all) {
    ConfigNode node = ConfigNode::EmptyMap();
    node.Set("array_job_id", ConfigNode::LiteralString(item.array_job_id));
    ConfigNode jobs = ConfigNode::EmptyList();
    for (int n : item.nums) jobs.Append(ConfigNode(n));
    node.Set("jobs", jobs);
    node.Set("script", ConfigNode::LiteralString(item.script));
    list.Append(node);
  }
  ConfigNode root = ConfigNode::EmptyMap();
  root.Set("submissions", list);
  WriteFileAtomic(SubmissionsPath(sweep_dir), DumpYaml(root));
}

/// Job number -> the array job id of its latest submission.
std::map<int, std::string> LatestArrayIds(const fs::path& sweep_dir) {
  std::map<int, std::string> ids;
  for (const SlurmSubmission& s : LoadSubmissions(sweep_dir)) {
    for (int n : s.nums) ids[n] = s.array_job_id;
  }
  return ids;
}

// ---------------------------------------------------------------------------
// squeue

struct QueuedTask {
  std::string state;  // SLURM's state, e.g. PENDING, RUNNING
};

/// (array job id, task id) -> state of this user's array tasks still known to
/// the controller. Throws Error with squeue's message if it fails.
std::map<std::pair<std::string, int>, QueuedTask> QueryQueue() {
  RequireTool("squeue");
  std::string user = std::to_string(::getuid());
  if (const passwd* pw = ::getpwuid(::getuid())) user = pw->pw_name;
  const CommandResult r =
      RunCommand({"squeue", "-h", "-r", "-u", user, "-o", "%F|%K|%T"});
  if (r.exit_code != 0) {
    throw Error(fmt::format("squeue failed: {}", OneLine(r.err + r.out)));
  }
  std::map<std::pair<std::string, int>, QueuedTask> out;
  std::stringstream lines(r.out);
  std::string line;
  while (std::getline(lines, line)) {
    const size_t a = line.find('|');
    const size_t b = line.find('|', a == std::string::npos ? a : a + 1);
    if (a == std::string::npos || b == std::string::npos) continue;
    const std::string task = line.substr(a + 1, b - a - 1);
    if (task.empty() || !std::isdigit(static_cast<unsigned char>(task[0])))
      continue;  // "N/A": not an array task
    out[{line.substr(0, a), std::stoi(task)}] = {Trim(line.substr(b + 1))};
  }
  return out;
}

std::string StateFromQueue(const std::string& slurm_state) {
  if (slurm_state == "PENDING" || slurm_state == "REQUEUED" ||
      slurm_state == "REQUEUE_HOLD" || slurm_state == "REQUEUE_FED") {
    return "pending";
  }
  return "running";  // RUNNING, CONFIGURING, COMPLETING, SUSPENDED, ...
}

std::optional<int> ReadExitStatus(const fs::path& job_dir) {
  const fs::path path = job_dir / kExitStatusFile;
  if (!fs::exists(path)) return std::nullopt;
  try {
    return std::stoi(Trim(ReadFile(path)));
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

std::string SlurmErrFile(const fs::path& job_dir) {
  // The newest slurm-*.err beside the job's log.
  std::string newest;
  fs::file_time_type newest_time;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(job_dir, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("slurm-", 0) != 0 || e.path().extension() != ".err")
      continue;
    const auto t = e.last_write_time(ec);
    if (newest.empty() || t > newest_time) {
      newest = e.path().string();
      newest_time = t;
    }
  }
  return newest;
}

}  // namespace

// ---------------------------------------------------------------------------
// Options

void SlurmLauncherOptions::Validate() const {
  auto fail = [](const std::string& key,
                 const std::string& value,
                 const std::string& constraint) {
    throw ConfigError(
        fmt::format("Invalid configuration. hydra.launcher.{} = {}. Violated "
                    "constraint: {}",
                    key,
                    value,
                    constraint));
  };
  if (!(poll_interval_s > 0)) {
    fail("poll_interval_s",
         fmt::format("{}", poll_interval_s),
         "poll_interval_s > 0");
  }
  if (array_parallelism < 1) {
    fail("array_parallelism",
         std::to_string(array_parallelism),
         "array_parallelism >= 1");
  }
  if (cpus_per_task < 1) {
    fail("cpus_per_task", std::to_string(cpus_per_task), "cpus_per_task >= 1");
  }
  if (mem_gb && !(*mem_gb > 0)) {
    fail("mem_gb", fmt::format("{}", *mem_gb), "mem_gb > 0 or null");
  }
  if (timeout_min < 1) {
    fail("timeout_min", std::to_string(timeout_min), "timeout_min >= 1");
  }
  if (signal_delay_s < 0) {
    fail("signal_delay_s",
         std::to_string(signal_delay_s),
         "signal_delay_s >= 0");
  }
  for (const auto& [key, value] : additional_parameters) {
    if (key.empty() || key.find_first_of(" \t\n=") != std::string::npos ||
        value.find('\n') != std::string::npos) {
      fail("additional_parameters." + key,
           value,
           "a key without spaces or '=' and a one-line value");
    }
  }
  for (const std::string& line : setup) {
    if (line.find('\n') != std::string::npos) {
      fail("setup", line, "one shell line per list item");
    }
  }
}

SlurmLauncherOptions DecodeSlurmLauncherOptions(const ConfigNode& launcher) {
  ConfigReader reader(launcher);
  SlurmLauncherOptions options;
  auto read_optional_string = [&](std::string_view key, std::string* out) {
    const ConfigNode* child = reader.Child(key);
    if (child == nullptr || child->IsNull()) return;
    *out = child->IsString() ? child->AsString() : child->text();
  };
  reader.Ignore("name");
  reader.Ignore("n_jobs");
  reader.Read("wait", &options.wait);
  reader.Read("poll_interval_s", &options.poll_interval_s);
  reader.Read("array_parallelism", &options.array_parallelism);
  read_optional_string("partition", &options.partition);
  reader.Read("cpus_per_task", &options.cpus_per_task);
  if (const ConfigNode* mem = reader.Child("mem_gb"); mem && !mem->IsNull()) {
    options.mem_gb = mem->AsDouble();
  }
  reader.Read("timeout_min", &options.timeout_min);
  read_optional_string("gres", &options.gres);
  read_optional_string("account", &options.account);
  read_optional_string("qos", &options.qos);
  read_optional_string("constraint", &options.constraint);
  reader.Read("signal_delay_s", &options.signal_delay_s);
  reader.Read("requeue", &options.requeue);
  reader.Read("setup", &options.setup);
  if (const ConfigNode* extra = reader.Child("additional_parameters");
      extra && !extra->IsNull()) {
    if (!extra->IsMap()) {
      throw ConfigError(fmt::format(
          "Invalid configuration. hydra.launcher.additional_parameters = {}. "
          "Expected a map of sbatch option: value",
          extra->Describe()));
    }
    for (const auto& [key, value] : extra->entries()) {
      options.additional_parameters.emplace_back(
          key, value.IsString() ? value.AsString() : value.text());
    }
  }
  reader.Finish();
  options.Validate();
  return options;
}

// ---------------------------------------------------------------------------
// The script

std::string ShellQuote(std::string_view text) {
  std::string out = "'";
  for (char c : text) {
    if (c == '\'') {
      out += "'\\''";
    } else {
      out += c;
    }
  }
  return out + "'";
}

std::string ArrayIndexList(const std::vector<int>& nums) {
  std::string out;
  for (size_t i = 0; i < nums.size();) {
    size_t j = i;
    while (j + 1 < nums.size() && nums[j + 1] == nums[j] + 1) ++j;
    if (!out.empty()) out += ",";
    out += j == i ? std::to_string(nums[i])
                  : fmt::format("{}-{}", nums[i], nums[j]);
    i = j + 1;
  }
  return out;
}

std::string MakeSbatchScript(const SlurmLauncherOptions& options,
                             const SbatchScriptSpec& spec) {
  std::vector<int> nums;
  for (const SlurmArrayTask& t : spec.tasks) nums.push_back(t.num);
  const fs::path tasks_dir = spec.sweep_dir / kSlurmDir / "tasks";
  std::string s = "#!/bin/bash\n";
  auto sbatch = [&](const std::string& line) { s += "#SBATCH " + line + "\n"; };
  sbatch("--job-name=" + spec.job_name);
  sbatch(fmt::format(
      "--array={}%{}", ArrayIndexList(nums), options.array_parallelism));
  sbatch("--chdir=" + spec.workdir.string());
  // .slurm/tasks/<num> links to the job's directory: SLURM's own stdout and
  // stderr land beside the job's log.
  sbatch("--output=" + (tasks_dir / "%a" / "slurm-%A_%a.out").string());
  sbatch("--error=" + (tasks_dir / "%a" / "slurm-%A_%a.err").string());
  sbatch("--open-mode=append");
  sbatch("--nodes=1");
  sbatch("--ntasks=1");
  sbatch(fmt::format("--cpus-per-task={}", options.cpus_per_task));
  sbatch(fmt::format("--time={}", options.timeout_min));
  if (options.mem_gb) {
    sbatch(fmt::format("--mem={}M", std::llround(*options.mem_gb * 1024)));
  }
  if (!options.partition.empty()) sbatch("--partition=" + options.partition);
  if (!options.gres.empty()) sbatch("--gres=" + options.gres);
  if (!options.account.empty()) sbatch("--account=" + options.account);
  if (!options.qos.empty()) sbatch("--qos=" + options.qos);
  if (!options.constraint.empty()) sbatch("--constraint=" + options.constraint);
  if (options.signal_delay_s > 0) {
    sbatch(fmt::format("--signal=B:USR1@{}", options.signal_delay_s));
  }
  if (options.requeue) sbatch("--requeue");
  for (const auto& [key, value] : options.additional_parameters) {
    std::string flag = key;
    std::replace(flag.begin(), flag.end(), '_', '-');
    std::string arg = "--" + flag;
    if (!value.empty()) arg.append("=").append(value);
    sbatch(arg);
  }
  s += "# Generated by soma (hydra/launcher=slurm) for the sweep in\n# " +
       spec.sweep_dir.string() + "\n";
  s += "set -u\n";
  for (const std::string& line : options.setup) s += line + "\n";
  s += "case \"${SLURM_ARRAY_TASK_ID:-}\" in\n";
  for (const SlurmArrayTask& t : spec.tasks) {
    s += fmt::format(
        "  {})\n    job_dir={}\n    overrides=(",
        t.num,
        ShellQuote(fs::absolute(t.dir).lexically_normal().string()));
    for (size_t i = 0; i < t.overrides.size(); ++i) {
      if (i > 0) s += ' ';
      s += ShellQuote(t.overrides[i]);
    }
    s += ")\n    ;;\n";
  }
  s += "  *)\n    echo \"soma: no job for array task "
       "'${SLURM_ARRAY_TASK_ID:-}'\" >&2\n    exit 2\n    ;;\nesac\n";
  s += "rm -f \"$job_dir/" + std::string(kExitStatusFile) + "\"\n";
  s += "export " + std::string(kSweepDirEnv) + "=" +
       ShellQuote(spec.sweep_dir.string()) + "\n";
  s += "export " + std::string(kSweepJobEnv) + "=\"$SLURM_ARRAY_TASK_ID\"\n";
  s += ShellQuote(spec.executable);
  for (const std::string& a : spec.base_args) s += " " + ShellQuote(a);
  s += " \"${overrides[@]}\" &\n";
  // scancel's SIGTERM reaches this shell: pass it on to soma and wait for its
  // own exit status. SIGUSR1 (--signal=B:USR1, or scancel --signal=USR1 -b)
  // is passed on to soma too: a training checkpoints at its next batch and
  // stops (any other task dies of it, keeping its last checkpoint, which
  // atomic writes keep valid); with requeue the task then goes back to the
  // queue and the next start resumes. (Requeueing on SIGTERM would turn
  // every scancel into a requeue.)
  s += "child=$!\n"
       "requeue=0\n"
       "trap 'kill -TERM \"$child\" 2>/dev/null' TERM INT\n"
       "trap 'requeue=1; kill -USR1 \"$child\" 2>/dev/null' USR1\n"
       // A trapped signal interrupts `wait` (status 128+n); wait until soma
       // has ended, then once more for its own status (bash keeps it).
       "wait \"$child\"\n"
       "while kill -0 \"$child\" 2>/dev/null; do\n"
       "  wait \"$child\"\n"
       "done\n"
       "wait \"$child\"\n"
       "rc=$?\n";
  if (options.requeue) {
    s += "if ((requeue)); then\n"
         "  if scontrol requeue \"$SLURM_JOB_ID\"; then\n"
         "    echo \"soma: SIGUSR1: stopped job $SOMA_SWEEP_JOB (status $rc),"
         " requeued SLURM job $SLURM_JOB_ID; it resumes from its checkpoint\""
         " >&2\n"
         "    exit 0\n"
         "  fi\n"
         "  echo \"soma: SIGUSR1: scontrol requeue $SLURM_JOB_ID failed\" >&2\n"
         "fi\n";
  }
  s += "printf '%s\\n' \"$rc\" > \"$job_dir/" + std::string(kExitStatusFile) +
       ".tmp\" && mv -f \"$job_dir/" + std::string(kExitStatusFile) +
       ".tmp\" \"$job_dir/" + std::string(kExitStatusFile) + "\"\n";
  s += "exit \"$rc\"\n";
  return s;
}

// ---------------------------------------------------------------------------
// Submitting

SlurmSubmission SubmitSlurmArray(const SlurmLauncherOptions& options,
                                 const SbatchScriptSpec& spec) {
  SOMA_CHECK(!spec.tasks.empty()) << "SubmitSlurmArray without jobs";
  RequireTool("sbatch");
  std::vector<int> nums;
  for (const SlurmArrayTask& t : spec.tasks) nums.push_back(t.num);
  const fs::path slurm_dir = spec.sweep_dir / kSlurmDir;
  const fs::path tasks_dir = slurm_dir / "tasks";
  CreateDirectories(tasks_dir);
  for (const SlurmArrayTask& t : spec.tasks) {
    const fs::path dir = fs::absolute(t.dir).lexically_normal();
    CreateDirectories(dir);
    const fs::path link = tasks_dir / std::to_string(t.num);
    std::error_code ec;
    fs::remove(link, ec);
    fs::create_directory_symlink(dir, link, ec);
    if (ec) {
      throw IoError(
          fmt::format("Cannot link '{}' to the job directory '{}': {}",
                      link.string(),
                      dir.string(),
                      ec.message()));
    }
    // A previous attempt's exit status must not stand for this one (the
    // wrapper also removes it when the task starts); put back if sbatch fails.
    if (fs::exists(dir / kExitStatusFile)) {
      fs::rename(dir / kExitStatusFile,
                 dir / (std::string(kExitStatusFile) + ".previous"),
                 ec);
    }
  }
  const std::string stamp = IsoNow();
  std::string safe_stamp = stamp;
  std::replace_if(
      safe_stamp.begin(),
      safe_stamp.end(),
      [](char c) { return !std::isalnum(static_cast<unsigned char>(c)); },
      '-');
  const fs::path script = slurm_dir / ("array-" + safe_stamp + ".sbatch");
  WriteFileAtomic(script, MakeSbatchScript(options, spec));

  const CommandResult r = RunCommand({"sbatch", "--parsable", script.string()});
  const std::string id = Trim(r.out.substr(0, r.out.find(';')));
  const bool submitted = r.exit_code == 0 && !id.empty() &&
                         std::all_of(id.begin(), id.end(), [](char c) {
                           return std::isdigit(static_cast<unsigned char>(c));
                         });
  if (!submitted) {
    for (const SlurmArrayTask& t : spec.tasks) {
      const fs::path previous =
          t.dir / (std::string(kExitStatusFile) + ".previous");
      std::error_code ec;
      if (fs::exists(previous))
        fs::rename(previous, t.dir / kExitStatusFile, ec);
    }
    throw Error(fmt::format(
        "sbatch refused the job array of jobs [{}] (script {}): {}; nothing "
        "was submitted",
        ArrayIndexList(nums),
        script.string(),
        OneLine(r.err + r.out).empty()
            ? fmt::format("exit status {}", r.exit_code)
            : OneLine(r.err + r.out)));
  }
  SlurmSubmission submission;
  submission.array_job_id = id;
  submission.nums = nums;
  submission.script = script.string();
  AppendSubmission(spec.sweep_dir, submission);
  return submission;
}

// ---------------------------------------------------------------------------
// State

std::vector<SweepJobState> QuerySweepState(const fs::path& sweep_dir,
                                           bool record,
                                           const SlurmJobEndedOk& ended_ok) {
  if (!fs::exists(sweep_dir / "jobs.yaml")) {
    throw IoError(fmt::format("'{}' is not a sweep directory (no jobs.yaml)",
                              sweep_dir.string()));
  }
  const std::map<int, std::string> array_ids = LatestArrayIds(sweep_dir);
  // Query SLURM only when some job is not finished in the ledger.
  std::optional<std::map<std::pair<std::string, int>, QueuedTask>> queue;
  std::optional<LedgerLock> lock;
  if (record) lock.emplace(sweep_dir);
  Ledger ledger = Ledger::Load(sweep_dir);
  bool changed = false;
  std::vector<SweepJobState> out;
  for (const LedgerEntry& entry : ledger.entries()) {
    SweepJobState st;
    st.entry = entry;
    st.log =
        entry.dir.empty() ? "" : (fs::path(entry.dir) / "soma.log").string();
    const auto id = array_ids.find(entry.num);
    if (id != array_ids.end()) {
      st.slurm_id = fmt::format("{}_{}", id->second, entry.num);
    }
    if (entry.status == JobStatus::kDone) {
      st.state = "done";
      st.detail = fmt::format("{:.1f}s", entry.wall_time_s);
    } else if (entry.status == JobStatus::kFailed) {
      st.state = "failed";
      st.detail = entry.error;
    } else if (id == array_ids.end()) {
      st.state = std::string(ToString(entry.status));
      st.detail = "not submitted to SLURM";
    } else {
      if (!queue) queue = QueryQueue();
      const auto q = queue->find({id->second, entry.num});
      if (q != queue->end()) {
        st.state = StateFromQueue(q->second.state);
        st.detail = "SLURM: " + q->second.state;
      } else if (LedgerEntry done = entry; ended_ok && ended_ok(done)) {
        // It finished without writing the ledger itself.
        st.entry = done;
        st.state = "done";
        st.detail = "finished";
        if (record) {
          LedgerEntry& e = ledger.Entry(entry.num);
          e = done;
          e.status = JobStatus::kDone;
          e.error.clear();
          changed = true;
        }
      } else {
        // SLURM is done with it but the job did not record its end.
        const std::optional<int> rc = ReadExitStatus(entry.dir);
        const std::string err = SlurmErrFile(entry.dir);
        st.state = "failed";
        st.detail =
            rc ? fmt::format(
                     "the job exited with status {}{}{}",
                     *rc,
                     *rc == 0 ? " without recording its end"
                     : *rc > 128
                         ? fmt::format(" (signal {}: cancelled, timed out or "
                                       "killed)",
                                       *rc - 128)
                         : "",
                     err.empty() ? "" : "; see " + err)
               : fmt::format(
                     "the SLURM task ended without an exit status (cancelled, "
                     "timed out or killed){}",
                     err.empty() ? "" : "; see " + err);
        if (record) {
          LedgerEntry& e = ledger.Entry(entry.num);
          e.status = JobStatus::kFailed;
          e.error = st.detail;
          changed = true;
        }
      }
    }
    out.push_back(std::move(st));
  }
  if (changed) ledger.Save();
  return out;
}

bool WaitForSlurmJobs(const fs::path& sweep_dir,
                      const SlurmSubmission& submission,
                      const SlurmLauncherOptions& options,
                      const SlurmJobEndedOk& ended_ok) {
  sigset_t signals, previous;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, &previous);
  const std::set<int> mine(submission.nums.begin(), submission.nums.end());
  std::string last_report;
  bool interrupted = false;
  int squeue_failures = 0;
  while (true) {
    std::map<std::string, int> counts;
    bool unfinished = false;
    try {
      for (const SweepJobState& st :
           QuerySweepState(sweep_dir, true, ended_ok)) {
        if (!mine.count(st.entry.num)) continue;
        ++counts[st.state];
        if (st.state == "pending" || st.state == "running") unfinished = true;
      }
      squeue_failures = 0;
    } catch (const Error& e) {
      // A controller restart or a network hiccup: retry a few times.
      if (++squeue_failures >= 5) {
        pthread_sigmask(SIG_SETMASK, &previous, nullptr);
        throw;
      }
      SOMA_LOG(WARNING, "{} (retrying)", e.what());
      unfinished = true;
    }
    const std::string report = fmt::format(
        "SLURM array {}: {} done, {} running, {} pending, {} failed",
        submission.array_job_id,
        counts["done"],
        counts["running"],
        counts["pending"],
        counts["failed"]);
    if (report != last_report && !counts.empty()) {
      SOMA_LOG(INFO, "{}", report);
      last_report = report;
    }
    if (!unfinished) break;
    const double interval = options.poll_interval_s;
    timespec timeout{
        static_cast<time_t>(interval),
        static_cast<long>((interval - static_cast<time_t>(interval)) * 1e9)};
    const int sig = sigtimedwait(&signals, nullptr, &timeout);
    if (sig == SIGINT || sig == SIGTERM) {
      SOMA_LOG(WARNING,
               "Interrupted: cancelling SLURM array {}",
               submission.array_job_id);
      CancelSlurmSweep(sweep_dir,
                       "cancelled (the submitting soma was interrupted)");
      interrupted = true;
      break;
    }
  }
  pthread_sigmask(SIG_SETMASK, &previous, nullptr);
  return !interrupted;
}

std::vector<int> CancelSlurmSweep(const fs::path& sweep_dir,
                                  const std::string& reason) {
  RequireTool("scancel");
  std::vector<int> cancelled;
  std::map<std::string, std::vector<int>> by_array;
  for (const SweepJobState& st : QuerySweepState(sweep_dir, true)) {
    if (st.state != "pending" && st.state != "running") continue;
    if (st.slurm_id.empty()) continue;
    by_array[st.slurm_id.substr(0, st.slurm_id.find('_'))].push_back(
        st.entry.num);
  }
  for (const auto& [array_id, nums] : by_array) {
    std::vector<std::string> argv = {"scancel"};
    for (int n : nums) argv.push_back(fmt::format("{}_{}", array_id, n));
    const CommandResult r = RunCommand(argv);
    if (r.exit_code != 0) {
      throw Error(fmt::format(
          "scancel failed for array {}: {}", array_id, OneLine(r.err + r.out)));
    }
    cancelled.insert(cancelled.end(), nums.begin(), nums.end());
  }
  // scancel only asks: a task that was starting can still record itself
  // running in the ledger before its SIGTERM lands (it takes the ledger lock
  // after this process lets go of it). Mark the ledger once the cancelled
  // tasks have left the queue, so that no task's own write comes after it.
  auto still_queued = [&] {
    try {
      const auto queue = QueryQueue();
      for (const auto& [array_id, nums] : by_array) {
        for (int n : nums) {
          if (queue.count({array_id, n}) > 0) return true;
        }
      }
      return false;
    } catch (const Error& e) {
      SOMA_LOG(WARNING, "{} (after scancel)", e.what());
      return true;
    }
  };
  constexpr auto kLeaveQueueTimeout = std::chrono::seconds(60);
  const auto deadline = std::chrono::steady_clock::now() + kLeaveQueueTimeout;
  while (!cancelled.empty() && still_queued()) {
    if (std::chrono::steady_clock::now() > deadline) {
      SOMA_LOG(WARNING,
               "Cancelled SLURM tasks still queued after {} s: marking them "
               "failed in the ledger now",
               kLeaveQueueTimeout.count());
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  if (!cancelled.empty()) {
    LedgerLock lock(sweep_dir);
    Ledger ledger = Ledger::Load(sweep_dir);
    for (int n : cancelled) {
      LedgerEntry& e = ledger.Entry(n);
      if (e.status == JobStatus::kDone || e.status == JobStatus::kFailed)
        continue;
      e.status = JobStatus::kFailed;
      e.error = reason;
    }
    ledger.Save();
  }
  return cancelled;
}

ConfigNode SlurmProvenance() {
  const char* job_id = std::getenv("SLURM_JOB_ID");
  if (job_id == nullptr) return ConfigNode::Null();
  ConfigNode node = ConfigNode::EmptyMap();
  for (const auto& [key, var] :
       std::vector<std::pair<const char*, const char*>>{
           {"job_id", "SLURM_JOB_ID"},
           {"array_job_id", "SLURM_ARRAY_JOB_ID"},
           {"array_task_id", "SLURM_ARRAY_TASK_ID"},
           {"node", "SLURMD_NODENAME"},
           {"partition", "SLURM_JOB_PARTITION"},
           {"restart_count", "SLURM_RESTART_COUNT"}}) {
    const char* value = std::getenv(var);
    node.Set(key,
             value ? ConfigNode::LiteralString(value) : ConfigNode::Null());
  }
  return node;
}

// ---------------------------------------------------------------------------
// soma sweep status|cancel

int RunSweepCommand(const std::vector<std::string>& args) {
  if (args.size() != 2 || (args[0] != "status" && args[0] != "cancel")) {
    std::fputs(
        "Usage: soma sweep status <sweep_dir>   jobs done/running/pending/"
        "failed (ledger + squeue)\n"
        "       soma sweep cancel <sweep_dir>   scancel the sweep's unfinished "
        "SLURM jobs\n",
        stderr);
    return 2;
  }
  const fs::path sweep_dir = args[1];
  try {
    if (args[0] == "cancel") {
      const std::vector<int> nums =
          CancelSlurmSweep(sweep_dir, "cancelled (soma sweep cancel)");
      std::vector<std::string> text;
      text.reserve(nums.size());
      for (int n : nums) text.push_back(std::to_string(n));
      std::fputs(nums.empty()
                     ? "Nothing to cancel: no job of the sweep is pending or "
                       "running\n"
                     : fmt::format("Cancelled {} job(s): {}\n",
                                   nums.size(),
                                   fmt::join(text, ", "))
                           .c_str(),
                 stdout);
      return 0;
    }
    const std::vector<SweepJobState> states = QuerySweepState(sweep_dir, false);
    std::map<std::string, int> counts;
    std::string out = fmt::format(
        "{:<5} {:<8} {:<12} {}\n", "job", "state", "slurm", "overrides");
    for (const SweepJobState& st : states) {
      ++counts[st.state];
      out += fmt::format("{:<5} {:<8} {:<12} {}\n",
                         st.entry.num,
                         st.state,
                         st.slurm_id.empty() ? "-" : st.slurm_id,
                         fmt::join(st.entry.overrides, " "));
      if (st.state == "failed") {
        out += fmt::format("      {}\n      log: {}\n", st.detail, st.log);
      }
    }
    out += fmt::format("{} jobs: {} done, {} running, {} pending, {} failed\n",
                       states.size(),
                       counts["done"],
                       counts["running"],
                       counts["pending"],
                       counts["failed"]);
    std::fputs(out.c_str(), stdout);
    return counts["failed"] > 0 ? 1 : 0;
  } catch (const Error& e) {
    std::fprintf(stderr, "Error: %s\n", e.what());
    return 1;
  }
}

}  // namespace soma
