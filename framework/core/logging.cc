#include "framework/core/logging.h"

#include <chrono>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <mutex>
#include <sys/time.h>

namespace soma {
namespace {

struct LogState {
  std::mutex mutex;
  std::ofstream file;
  LogLevel console_level = LogLevel::kInfo;
  std::string name = "soma";
};

LogState& State() {
  static LogState state;  // The logger sink: process-wide by design.
  return state;
}

}  // namespace

std::string_view ToString(LogLevel level) {
  switch (level) {
    case LogLevel::kDebug:
      return "DEBUG";
    case LogLevel::kInfo:
      return "INFO";
    case LogLevel::kWarning:
      return "WARNING";
    case LogLevel::kError:
      return "ERROR";
  }
  return "UNKNOWN";
}

std::string LogTimestamp() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t seconds = std::chrono::system_clock::to_time_t(now);
  const auto millis = std::chrono::duration_cast<std::chrono::milliseconds>(
                          now.time_since_epoch())
                          .count() %
                      1000;
  std::tm local{};
  localtime_r(&seconds, &local);
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%d %H:%M:%S", &local);
  return fmt::format("{},{:03d}", buffer, static_cast<int>(millis));
}

void Logger::Write(LogLevel level,
                   std::string_view logger,
                   std::string_view message) {
  LogState& state = State();
  std::lock_guard<std::mutex> lock(state.mutex);
  const std::string line =
      fmt::format("[{}][{}][{}] - {}\n",
                  LogTimestamp(),
                  logger.empty() ? std::string_view{state.name} : logger,
                  ToString(level),
                  message);
  if (level >= state.console_level) {
    std::fputs(line.c_str(), stderr);
    std::fflush(stderr);
  }
  if (state.file.is_open()) {
    state.file << line;
    state.file.flush();
  }
}

void Logger::OpenFile(const std::string& path) {
  LogState& state = State();
  std::lock_guard<std::mutex> lock(state.mutex);
  if (state.file.is_open()) state.file.close();
  state.file.open(path, std::ios::app);
}

void Logger::CloseFile() {
  LogState& state = State();
  std::lock_guard<std::mutex> lock(state.mutex);
  if (state.file.is_open()) state.file.close();
}

void Logger::SetConsoleLevel(LogLevel level) {
  LogState& state = State();
  std::lock_guard<std::mutex> lock(state.mutex);
  state.console_level = level;
}

void Logger::SetName(std::string name) {
  LogState& state = State();
  std::lock_guard<std::mutex> lock(state.mutex);
  state.name = std::move(name);
}

}  // namespace soma
