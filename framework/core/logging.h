// The logging facade: SOMA_LOG(INFO, "fmt {}", x).
//
// Lines go to stderr and, when a run is active, to `<run_dir>/<job>.log`, in
// Hydra's format `[%(asctime)s][%(name)s][%(levelname)s] - %(message)s`. The
// sink is the one piece of process-wide mutable state besides the registries.
#pragma once

#include <fmt/format.h>

#include <string>
#include <string_view>

namespace soma {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarning = 2, kError = 3 };

std::string_view ToString(LogLevel level);

/// Process-wide log sink: console threshold and an optional log file.
class Logger {
 public:
  /// Writes one formatted line to the console (if `level` passes the
  /// threshold) and to the log file (always, when one is open).
  static void Write(LogLevel level,
                    std::string_view logger,
                    std::string_view message);

  /// Opens (appends to) `path` as the log file; closes any previous one.
  static void OpenFile(const std::string& path);
  static void CloseFile();
  static void SetConsoleLevel(LogLevel level);
  /// Logger name shown in `[name]`, Hydra uses the job name (`__main__`).
  static void SetName(std::string name);
};

/// Formats a local time stamp `YYYY-MM-DD HH:MM:SS,mmm` like Python logging.
std::string LogTimestamp();

}  // namespace soma

namespace soma::internal {
inline constexpr LogLevel kLog_DEBUG = LogLevel::kDebug;
inline constexpr LogLevel kLog_INFO = LogLevel::kInfo;
inline constexpr LogLevel kLog_WARNING = LogLevel::kWarning;
inline constexpr LogLevel kLog_ERROR = LogLevel::kError;
}  // namespace soma::internal

/// SOMA_LOG(INFO, "epoch {} loss {:.4f}", epoch, loss); levels DEBUG, INFO,
/// WARNING, ERROR.
#define SOMA_LOG(LEVEL, ...) \
  ::soma::Logger::Write(     \
      ::soma::internal::kLog_##LEVEL, "", ::fmt::format(__VA_ARGS__))
