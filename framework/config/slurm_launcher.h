// The SLURM launcher of `soma -m ... hydra/launcher=slurm` (issue #24): the
// sweep's jobs that are not `done` in the ledger are submitted as one `sbatch`
// job array; each array task runs `soma` with its job's overrides in its own
// job directory, and a bash wrapper records the job's exit status there. The
// ledger (`jobs.yaml`) stays the single source of truth: the job process
// itself marks its entry running/done/failed under the ledger lock, and a
// task that vanished from `squeue` without doing so is failed.
// Also `soma sweep status|cancel <sweep_dir>`.
#pragma once

#include "framework/config/ledger.h"
#include "framework/config/node.h"

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace soma {

/// The `hydra.launcher` node of `hydra/launcher=slurm`
/// (configs/hydra/launcher/slurm.yaml).
struct SlurmLauncherOptions {
  bool wait = true;  // false: submit and return
  double poll_interval_s =
      10;  // wait=true: seconds between ledger/squeue looks
  int array_parallelism = 256;   // --array=...%N
  std::string partition;         // --partition (empty: cluster default)
  int cpus_per_task = 1;         // --cpus-per-task
  std::optional<double> mem_gb;  // --mem=<N>G
  int timeout_min = 60;          // --time, minutes
  std::string gres;              // --gres
  std::string account;           // --account
  std::string qos;               // --qos
  std::string constraint;        // --constraint
  int signal_delay_s = 120;      // --signal=B:USR1@N (0: none)
  /// On SIGUSR1 (the --signal above, or `scancel --signal=USR1 -b` to
  /// preempt): pass it on to soma (a training checkpoints at its next batch
  /// and stops), then `scontrol requeue` the task (#SBATCH --requeue), which
  /// resumes from its checkpoint. SIGTERM (scancel) only stops.
  bool requeue = true;
  std::vector<std::string> setup;  // shell lines before soma
  /// Extra `#SBATCH --key=value` lines, in config order.
  std::vector<std::pair<std::string, std::string>> additional_parameters;

  /// Throws ConfigError naming the offending `hydra.launcher.<key>`.
  void Validate() const;
};

/// Decodes a resolved `hydra.launcher` node; unknown keys are an error.
SlurmLauncherOptions DecodeSlurmLauncherOptions(const ConfigNode& launcher);

/// One array task = one job of the sweep.
struct SlurmArrayTask {
  int num = 0;                         // hydra.job.num = SLURM_ARRAY_TASK_ID
  std::filesystem::path dir;           // the job's output directory
  std::vector<std::string> overrides;  // the job's overrides, verbatim
};

/// What the generated script runs.
struct SbatchScriptSpec {
  std::string job_name = "soma";    // --job-name
  std::filesystem::path sweep_dir;  // absolute
  std::filesystem::path workdir;    // --chdir: the submitting directory
  std::string executable;           // absolute path of `soma`
  std::vector<std::string>
      base_args;  // flags before the overrides (-m, -cn ...)
  std::vector<SlurmArrayTask> tasks;  // sorted by num, non-empty
};

/// Environment variables that make `soma -m` run exactly one job of a sweep
/// (the array task's job): its number and the sweep directory.
inline constexpr char kSweepJobEnv[] = "SOMA_SWEEP_JOB";
inline constexpr char kSweepDirEnv[] = "SOMA_SWEEP_DIR";
/// The file the wrapper writes into the job directory: the exit status.
inline constexpr char kExitStatusFile[] = "slurm_exit_status";

/// `'text'` for bash, with embedded single quotes escaped.
std::string ShellQuote(std::string_view text);

/// The sbatch script of the job array: #SBATCH lines from the options, the
/// setup lines, a `case` from SLURM_ARRAY_TASK_ID to the job's directory and
/// command, and the wrapper that forwards SIGTERM and SIGUSR1 to soma,
/// requeues the task after SIGUSR1 (with `requeue`) and otherwise writes
/// soma's exit status to
/// `<job dir>/slurm_exit_status`. Pure; throws nothing.
std::string MakeSbatchScript(const SlurmLauncherOptions& options,
                             const SbatchScriptSpec& spec);

/// `0-3`, `1,3,5-7`: the --array index list of sorted job numbers.
std::string ArrayIndexList(const std::vector<int>& nums);

/// One submitted array: recorded in `<sweep_dir>/.slurm/submissions.yaml`.
struct SlurmSubmission {
  std::string array_job_id;
  std::vector<int> nums;
  std::string script;
};

/// Writes the script into `<sweep_dir>/.slurm/`, links each task's output
/// directory, removes stale exit-status files and runs `sbatch --parsable`.
/// Throws Error with sbatch's own message (and the jobs) if sbatch is missing
/// or refuses the array; the ledger is not touched.
SlurmSubmission SubmitSlurmArray(const SlurmLauncherOptions& options,
                                 const SbatchScriptSpec& spec);

/// A job's state as `soma sweep status` shows it.
struct SweepJobState {
  LedgerEntry entry;
  std::string state;     // done | running | pending | failed
  std::string slurm_id;  // <array job id>_<task>, empty if never submitted
  std::string detail;    // error, SLURM state, wall time
  std::string log;       // the job's log file
};

/// Decides whether a job that SLURM no longer lists and that did not record
/// its end in the ledger finished after all (e.g. `soma reproduce`'s model
/// chains, whose commands do not write the reproduction's ledger); it may
/// fill the entry's metrics and wall time. Empty: it did not.
using SlurmJobEndedOk = std::function<bool(LedgerEntry& entry)>;

/// The ledger joined with `squeue`. With `record` (under the ledger lock), a
/// job that SLURM no longer lists and that did not record its end is written
/// to the ledger as done if `ended_ok` says so, else as failed, with the exit
/// status its wrapper left.
std::vector<SweepJobState> QuerySweepState(
    const std::filesystem::path& sweep_dir,
    bool record,
    const SlurmJobEndedOk& ended_ok = {});

/// Polls until none of the submission's jobs is pending or running. SIGINT
/// or SIGTERM cancels the array (scancel) and marks the unfinished jobs
/// failed; returns false then, true otherwise.
bool WaitForSlurmJobs(const std::filesystem::path& sweep_dir,
                      const SlurmSubmission& submission,
                      const SlurmLauncherOptions& options,
                      const SlurmJobEndedOk& ended_ok = {});

/// Cancels the sweep's pending and running SLURM jobs and, once they have
/// left the queue (at most 60 s: a task that was starting may record itself
/// running until then), marks them failed in the ledger; returns the job
/// numbers cancelled.
std::vector<int> CancelSlurmSweep(const std::filesystem::path& sweep_dir,
                                  const std::string& reason);

/// `slurm:` provenance of a job run under SLURM (job id, array job/task id,
/// node, restart count), or null outside SLURM.
ConfigNode SlurmProvenance();

/// `soma sweep status <dir>` / `soma sweep cancel <dir>`; returns the exit
/// code (0 ok, 1 error or failed jobs in status, 2 usage).
int RunSweepCommand(const std::vector<std::string>& args);

}  // namespace soma
