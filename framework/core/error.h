// Error types of the framework and the SOMA_CHECK family of macros.
//
// Every error that reaches the user is one line: what went wrong, where (file,
// key path, byte offset) and what was expected. Library code throws; the CLI
// (RunHydraApp) catches, logs and returns a non-zero exit code.
#pragma once

#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>

namespace soma {

/// Base class of every error thrown by the framework.
class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

/// A malformed, inconsistent or incomplete configuration (YAML, overrides,
/// interpolation, unknown component name).
class ConfigError : public Error {
 public:
  explicit ConfigError(const std::string& message) : Error(message) {}
};

/// `???` read through a typed accessor: `MissingMandatoryValue: <full.key>`.
class MissingMandatoryValue : public ConfigError {
 public:
  explicit MissingMandatoryValue(const std::string& message)
      : ConfigError(message) {}
};

/// An interpolation that names a key that does not exist.
class InterpolationKeyError : public ConfigError {
 public:
  explicit InterpolationKeyError(const std::string& message)
      : ConfigError(message) {}
};

/// Reading or writing a file failed or the file content is invalid.
class IoError : public Error {
 public:
  explicit IoError(const std::string& message) : Error(message) {}
};

/// Tensor or array dimensions do not match what an operation expects.
class ShapeError : public Error {
 public:
  explicit ShapeError(const std::string& message) : Error(message) {}
};

/// A broken invariant inside the framework (a bug, not a user error).
class InternalError : public Error {
 public:
  explicit InternalError(const std::string& message) : Error(message) {}
};

namespace internal {

/// Collects a streamed message and throws `E` from its destructor. Used by
/// SOMA_CHECK so that `SOMA_CHECK(x > 0) << "x=" << x;` reads naturally.
template <typename E>
class CheckThrower {
 public:
  CheckThrower(const char* file, int line, const char* expr) {
    std::string_view path(file);
    const size_t slash = path.rfind('/');
    if (slash != std::string_view::npos) path.remove_prefix(slash + 1);
    stream_ << "[" << path << ":" << line << "] Check failed: " << expr;
    first_ = true;
  }
  CheckThrower(const CheckThrower&) = delete;
  CheckThrower& operator=(const CheckThrower&) = delete;
  // Throwing is this destructor's job (noexcept(false)): the message is
  // complete only at the end of the full expression that streamed into it.
  // NOLINTNEXTLINE(bugprone-exception-escape)
  [[noreturn]] ~CheckThrower() noexcept(false) { throw E(stream_.str()); }

  template <typename T>
  CheckThrower& operator<<(const T& value) {
    if (first_) {
      stream_ << " ";
      first_ = false;
    }
    stream_ << value;
    return *this;
  }

 private:
  std::ostringstream stream_;
  bool first_ = true;
};

}  // namespace internal
}  // namespace soma

/// Throws soma::InternalError with `[file:line] Check failed: cond <message>`.
#define SOMA_CHECK(cond)                                   \
  if (cond) {                                              \
  } else                                                   \
    ::soma::internal::CheckThrower<::soma::InternalError>( \
        __FILE__, __LINE__, #cond)

/// Like SOMA_CHECK but throws the given error type (e.g. soma::IoError).
#define SOMA_CHECK_T(ErrorType, cond) \
  if (cond) {                         \
  } else                              \
    ::soma::internal::CheckThrower<ErrorType>(__FILE__, __LINE__, #cond)

#define SOMA_CHECK_EQ(a, b) \
  SOMA_CHECK((a) == (b)) << (a) << " vs " << (b) << " "
#define SOMA_CHECK_NE(a, b) \
  SOMA_CHECK((a) != (b)) << (a) << " vs " << (b) << " "
#define SOMA_CHECK_LT(a, b) SOMA_CHECK((a) < (b)) << (a) << " vs " << (b) << " "
#define SOMA_CHECK_LE(a, b) \
  SOMA_CHECK((a) <= (b)) << (a) << " vs " << (b) << " "
#define SOMA_CHECK_GT(a, b) SOMA_CHECK((a) > (b)) << (a) << " vs " << (b) << " "
#define SOMA_CHECK_GE(a, b) \
  SOMA_CHECK((a) >= (b)) << (a) << " vs " << (b) << " "
