// Child processes: run commands (argv, no shell) with their output captured in
// a log file, several at a time. Used by `soma reproduce` to run the `soma`
// commands of a reproduction (train, corrupt, label, eval) exactly as a user
// would type them.
//
//   ProcessPool pool(2);
//   pool.Start({.argv = {"/bin/echo", "hi"}, .log_path = "echo.log"});
//   while (std::optional<ProcessResult> r = pool.WaitAny()) { ... }
//
// Children get SIGTERM when the parent dies (Linux PR_SET_PDEATHSIG) and when
// the pool is destroyed with children still running, so an interrupted
// reproduction leaves no orphan trainings behind.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <sys/types.h>
#include <vector>

namespace soma {

/// One command: `argv[0]` is the executable path (not searched in PATH).
struct ProcessSpec {
  std::vector<std::string> argv;
  /// stdout and stderr are appended to this file (created with its parent
  /// directories); empty = inherit the parent's.
  std::filesystem::path log_path;
};

struct ProcessResult {
  int64_t id = 0;  // the value Start() returned
  /// The exit status (0 = success); 128 + signal number when killed.
  int exit_code = 0;
  double wall_time_s = 0;
};

class ProcessPool {
 public:
  explicit ProcessPool(int max_parallel);
  ProcessPool(const ProcessPool&) = delete;
  ProcessPool& operator=(const ProcessPool&) = delete;
  /// Terminates (SIGTERM) and reaps children that are still running.
  ~ProcessPool();

  /// Starts `spec`; first waits for a slot when `max_parallel` children run
  /// (the finished child is then reported by the next WaitAny()). IoError if
  /// the log file cannot be opened or the executable does not exist.
  int64_t Start(const ProcessSpec& spec);

  /// Blocks until a child finishes; nullopt when none is running or
  /// finished-but-unreported.
  std::optional<ProcessResult> WaitAny();

  int num_running() const { return static_cast<int>(running_.size()); }
  int max_parallel() const { return max_parallel_; }

 private:
  struct Child {
    pid_t pid = 0;
    int64_t id = 0;
    double start_s = 0;
  };
  ProcessResult Reap();  // waits for one running child

  int max_parallel_;
  int64_t next_id_ = 0;
  std::vector<Child> running_;
  std::vector<ProcessResult> finished_;  // reaped while waiting for a slot
};

/// Runs one command to completion; returns its exit code.
int RunProcess(const ProcessSpec& spec);

/// The absolute path of the running executable (/proc/self/exe).
std::filesystem::path CurrentExecutable();

/// `argv` as a copy-pasteable shell line (arguments quoted where needed).
std::string ShellQuote(const std::vector<std::string>& argv);

}  // namespace soma
