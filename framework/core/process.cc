#include "framework/core/process.h"

#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

namespace soma {
namespace {

double NowSeconds() {
  return std::chrono::duration<double>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

int ExitCode(int status) {
  if (WIFEXITED(status)) return WEXITSTATUS(status);
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return 255;
}

}  // namespace

ProcessPool::ProcessPool(int max_parallel)
    : max_parallel_(std::max(max_parallel, 1)) {}

ProcessPool::~ProcessPool() {
  for (const Child& child : running_) ::kill(child.pid, SIGTERM);
  for (const Child& child : running_) {
    int status = 0;
    while (::waitpid(child.pid, &status, 0) < 0 && errno == EINTR) {
    }
  }
}

int64_t ProcessPool::Start(const ProcessSpec& spec) {
  if (spec.argv.empty()) {
    throw InternalError("ProcessPool::Start: empty argv");
  }
  if (::access(spec.argv[0].c_str(), X_OK) != 0) {
    throw IoError(fmt::format("{}: not an executable file", spec.argv[0]));
  }
  while (num_running() >= max_parallel_) finished_.push_back(Reap());

  // Everything the child needs is prepared before fork(): between fork() and
  // exec() only async-signal-safe calls are allowed.
  int log_fd = -1;
  if (!spec.log_path.empty()) {
    if (spec.log_path.has_parent_path()) {
      CreateDirectories(spec.log_path.parent_path());
    }
    log_fd = ::open(
        spec.log_path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
    if (log_fd < 0) {
      throw IoError(fmt::format("{}: cannot open the log file: {}",
                                spec.log_path.string(),
                                std::strerror(errno)));
    }
  }
  std::vector<char*> argv;
  argv.reserve(spec.argv.size() + 1);
  for (const std::string& arg : spec.argv) {
    argv.push_back(const_cast<char*>(arg.c_str()));
  }
  argv.push_back(nullptr);
  const pid_t parent = ::getpid();

  const pid_t pid = ::fork();
  if (pid < 0) {
    if (log_fd >= 0) ::close(log_fd);
    throw IoError(fmt::format("fork() failed: {}", std::strerror(errno)));
  }
  if (pid == 0) {
    ::prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (::getppid() != parent) ::_exit(127);  // the parent died already
    if (log_fd >= 0) {
      ::dup2(log_fd, STDOUT_FILENO);
      ::dup2(log_fd, STDERR_FILENO);
    }
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  if (log_fd >= 0) ::close(log_fd);
  running_.push_back({pid, next_id_, NowSeconds()});
  return next_id_++;
}

ProcessResult ProcessPool::Reap() {
  int status = 0;
  pid_t pid = -1;
  while (true) {
    pid = ::waitpid(-1, &status, 0);
    if (pid >= 0 || errno != EINTR) break;
  }
  if (pid < 0) {
    throw InternalError(
        fmt::format("waitpid() failed: {}", std::strerror(errno)));
  }
  const auto it = std::find_if(running_.begin(),
                               running_.end(),
                               [pid](const Child& c) { return c.pid == pid; });
  if (it == running_.end()) return Reap();  // not one of ours
  ProcessResult result{it->id, ExitCode(status), NowSeconds() - it->start_s};
  running_.erase(it);
  return result;
}

std::optional<ProcessResult> ProcessPool::WaitAny() {
  if (!finished_.empty()) {
    const ProcessResult result = finished_.front();
    finished_.erase(finished_.begin());
    return result;
  }
  if (running_.empty()) return std::nullopt;
  return Reap();
}

int RunProcess(const ProcessSpec& spec) {
  ProcessPool pool(1);
  pool.Start(spec);
  return pool.WaitAny()->exit_code;
}

std::filesystem::path CurrentExecutable() {
  std::error_code ec;
  std::filesystem::path path =
      std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) {
    throw IoError(
        fmt::format("/proc/self/exe: cannot resolve the running "
                    "executable: {}",
                    ec.message()));
  }
  return path;
}

std::string ShellQuote(const std::vector<std::string>& argv) {
  std::string out;
  for (const std::string& arg : argv) {
    if (!out.empty()) out += ' ';
    const bool plain =
        !arg.empty() && std::all_of(arg.begin(), arg.end(), [](char c) {
          return std::isalnum(static_cast<unsigned char>(c)) ||
                 std::strchr("_-./=:,+@%", c) != nullptr;
        });
    if (plain) {
      out += arg;
      continue;
    }
    out += '\'';
    for (char c : arg) {
      if (c == '\'') {
        out += "'\\''";
      } else {
        out += c;
      }
    }
    out += '\'';
  }
  return out;
}

}  // namespace soma
