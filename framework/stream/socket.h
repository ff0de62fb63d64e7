// A small TCP socket wrapper for `soma stream`: every wait is a poll() with a
// timeout, so a silent or vanished peer ends in an IoError instead of a hang.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

namespace soma {

/// An owned TCP socket (IPv4). Move-only; closes on destruction.
class TcpSocket {
 public:
  TcpSocket() = default;
  explicit TcpSocket(int fd) : fd_(fd) {}
  ~TcpSocket();
  TcpSocket(TcpSocket&& other) noexcept;
  TcpSocket& operator=(TcpSocket&& other) noexcept;
  TcpSocket(const TcpSocket&) = delete;
  TcpSocket& operator=(const TcpSocket&) = delete;

  /// A listening socket on `host` (dotted IPv4, e.g. 127.0.0.1 or 0.0.0.0)
  /// and `port` (0: an ephemeral port, see LocalPort()). IoError on failure.
  static TcpSocket Listen(const std::string& host, int port);
  /// Connects to `host`:`port` within `timeout_s`; IoError otherwise.
  static TcpSocket Connect(const std::string& host, int port, double timeout_s);

  /// Waits up to `timeout_s` for a client; IoError naming `what` on timeout.
  TcpSocket Accept(double timeout_s, const std::string& what) const;
  /// The bound port.
  int LocalPort() const;

  /// Reads exactly `buffer.size()` bytes unless the peer closes first.
  /// Returns the bytes read (fewer than asked only when the peer closed).
  /// IoError naming `what` when no byte arrives for `timeout_s` seconds or
  /// on a socket error.
  size_t ReadFull(std::span<uint8_t> buffer,
                  double timeout_s,
                  const std::string& what);
  /// Writes all of `bytes`; IoError naming `what` if the peer is gone or the
  /// socket does not drain within `timeout_s`.
  void WriteAll(std::span<const uint8_t> bytes,
                double timeout_s,
                const std::string& what);
  /// True if a read would not block (data, or the peer closed) within
  /// `timeout_s` (0: now).
  bool Readable(double timeout_s) const;

  bool is_open() const { return fd_ >= 0; }
  void Close();
  /// shutdown(SHUT_RDWR): wakes a thread blocked reading this socket.
  void Shutdown();

 private:
  int fd_ = -1;
};

}  // namespace soma
