#include "framework/stream/socket.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <arpa/inet.h>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

namespace soma {
namespace {

std::string Errno() { return std::strerror(errno); }

sockaddr_in Address(const std::string& host, int port) {
  if (port < 0 || port > 65535) {
    throw IoError(fmt::format("tcp: port {} is not in [0, 65535]", port));
  }
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  if (inet_pton(AF_INET, host.c_str(), &addr.sin_addr) != 1) {
    throw IoError(fmt::format(
        "tcp: host '{}' is not a dotted IPv4 address (e.g. 127.0.0.1)", host));
  }
  return addr;
}

int TimeoutMs(double seconds) {
  if (!(seconds >= 0.0)) return 0;
  return static_cast<int>(std::min(seconds * 1000.0, 2.0e9));
}

/// poll() one fd for `events`, retrying on EINTR; true if ready.
bool PollFor(int fd, short events, double timeout_s) {
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::duration<double>(timeout_s);
  for (;;) {
    pollfd p{fd, events, 0};
    const double left = std::chrono::duration<double>(
                            deadline - std::chrono::steady_clock::now())
                            .count();
    const int rc = poll(&p, 1, TimeoutMs(std::max(left, 0.0)));
    if (rc > 0) return true;
    if (rc == 0) return false;
    if (errno != EINTR) throw IoError(fmt::format("tcp: poll: {}", Errno()));
  }
}

}  // namespace

TcpSocket::~TcpSocket() { Close(); }

TcpSocket::TcpSocket(TcpSocket&& other) noexcept : fd_(other.fd_) {
  other.fd_ = -1;
}

TcpSocket& TcpSocket::operator=(TcpSocket&& other) noexcept {
  if (this != &other) {
    Close();
    fd_ = other.fd_;
    other.fd_ = -1;
  }
  return *this;
}

void TcpSocket::Close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

void TcpSocket::Shutdown() {
  if (fd_ >= 0) ::shutdown(fd_, SHUT_RDWR);
}

TcpSocket TcpSocket::Listen(const std::string& host, int port) {
  const sockaddr_in addr = Address(host, port);
  TcpSocket s(::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0));
  if (!s.is_open()) throw IoError(fmt::format("tcp: socket: {}", Errno()));
  const int one = 1;
  setsockopt(s.fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  if (::bind(s.fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)) !=
      0) {
    throw IoError(
        fmt::format("tcp: cannot listen on {}:{}: {}", host, port, Errno()));
  }
  if (::listen(s.fd_, 1) != 0) {
    throw IoError(fmt::format("tcp: listen {}:{}: {}", host, port, Errno()));
  }
  return s;
}

TcpSocket TcpSocket::Connect(const std::string& host,
                             int port,
                             double timeout_s) {
  const sockaddr_in addr = Address(host, port);
  TcpSocket s(::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0));
  if (!s.is_open()) throw IoError(fmt::format("tcp: socket: {}", Errno()));
  int rc =
      ::connect(s.fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr));
  if (rc != 0 && errno != EINPROGRESS) {
    throw IoError(
        fmt::format("tcp: cannot connect to {}:{}: {}", host, port, Errno()));
  }
  if (rc != 0) {
    if (!PollFor(s.fd_, POLLOUT, timeout_s)) {
      throw IoError(fmt::format("tcp: connecting to {}:{} timed out after {}s",
                                host,
                                port,
                                timeout_s));
    }
    int error = 0;
    socklen_t len = sizeof(error);
    getsockopt(s.fd_, SOL_SOCKET, SO_ERROR, &error, &len);
    if (error != 0) {
      throw IoError(fmt::format("tcp: cannot connect to {}:{}: {}",
                                host,
                                port,
                                std::strerror(error)));
    }
  }
  const int flags = fcntl(s.fd_, F_GETFL, 0);
  fcntl(s.fd_, F_SETFL, flags & ~O_NONBLOCK);
  const int one = 1;
  setsockopt(s.fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
  return s;
}

TcpSocket TcpSocket::Accept(double timeout_s, const std::string& what) const {
  if (!PollFor(fd_, POLLIN, timeout_s)) {
    throw IoError(fmt::format("{}: no client connected within {}s (port {})",
                              what,
                              timeout_s,
                              LocalPort()));
  }
  TcpSocket client(::accept4(fd_, nullptr, nullptr, SOCK_CLOEXEC));
  if (!client.is_open()) {
    throw IoError(fmt::format("{}: accept: {}", what, Errno()));
  }
  const int one = 1;
  setsockopt(client.fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
  return client;
}

int TcpSocket::LocalPort() const {
  sockaddr_in addr{};
  socklen_t len = sizeof(addr);
  if (getsockname(fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0) {
    throw IoError(fmt::format("tcp: getsockname: {}", Errno()));
  }
  return ntohs(addr.sin_port);
}

size_t TcpSocket::ReadFull(std::span<uint8_t> buffer,
                           double timeout_s,
                           const std::string& what) {
  size_t done = 0;
  while (done < buffer.size()) {
    if (!PollFor(fd_, POLLIN, timeout_s)) {
      throw IoError(fmt::format(
          "{}: no data for {}s (got {} of {} bytes of the next read); is the "
          "client alive?",
          what,
          timeout_s,
          done,
          buffer.size()));
    }
    const ssize_t n =
        ::recv(fd_, buffer.data() + done, buffer.size() - done, 0);
    if (n == 0) return done;  // the peer closed
    if (n < 0) {
      if (errno == EINTR || errno == EAGAIN) continue;
      if (errno == ECONNRESET) return done;
      throw IoError(fmt::format("{}: recv: {}", what, Errno()));
    }
    done += static_cast<size_t>(n);
  }
  return done;
}

void TcpSocket::WriteAll(std::span<const uint8_t> bytes,
                         double timeout_s,
                         const std::string& what) {
  size_t done = 0;
  while (done < bytes.size()) {
    if (!PollFor(fd_, POLLOUT, timeout_s)) {
      throw IoError(
          fmt::format("{}: the peer did not read for {}s ({} of {} bytes sent)",
                      what,
                      timeout_s,
                      done,
                      bytes.size()));
    }
    const ssize_t n = ::send(fd_,
                             bytes.data() + done,
                             bytes.size() - done,
                             MSG_NOSIGNAL | MSG_DONTWAIT);
    if (n < 0) {
      if (errno == EINTR || errno == EAGAIN) continue;
      throw IoError(fmt::format("{}: send: {}", what, Errno()));
    }
    done += static_cast<size_t>(n);
  }
}

bool TcpSocket::Readable(double timeout_s) const {
  return PollFor(fd_, POLLIN, timeout_s);
}

}  // namespace soma
