#include "gyrotherm/drivers/byte_link.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <span>

namespace gyrotherm::drivers {

namespace {

using Steady = std::chrono::steady_clock;

// Rounded up: a wait of this many milliseconds does not end before the
// deadline (0 only once it has passed).
int remaining_ms(ByteLink::Deadline deadline) {
  const auto left = std::chrono::ceil<std::chrono::milliseconds>(deadline - Steady::now()).count();
  return left < 0 ? 0 : static_cast<int>(left);
}

// SerialPort's errors start with "serial device <path>: "; the tables name
// the device already.
Error without_device(const Error& e, const std::string& device) {
  const std::string prefix = fmt::format("serial device {}: ", device);
  if (e.message.rfind(prefix, 0) == 0) return Error{e.message.substr(prefix.size()), e.transient};
  return e;
}

}  // namespace

// ---------------------------------------------------------------- TcpLink

TcpLink::TcpLink(TcpLinkOptions options)
    : options_(std::move(options)),
      description_(fmt::format("{}:{}", options_.host, options_.port)) {}

TcpLink::~TcpLink() { close(); }

void TcpLink::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

Status TcpLink::open(Deadline deadline) {
  close();
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  const std::string port = std::to_string(options_.port);
  if (int rc = ::getaddrinfo(options_.host.c_str(), port.c_str(), &hints, &found); rc != 0) {
    return Error::Transient(fmt::format("cannot resolve host: {}", gai_strerror(rc)));
  }
  const double budget_s = std::chrono::duration<double>(deadline - Steady::now()).count();
  std::string last = "no address";
  for (addrinfo* a = found; a != nullptr; a = a->ai_next) {
    int fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, a->ai_protocol);
    if (fd < 0) {
      last = std::strerror(errno);
      continue;
    }
    int rc = ::connect(fd, a->ai_addr, a->ai_addrlen);
    if (rc != 0 && errno == EINPROGRESS) {
      pollfd p{fd, POLLOUT, 0};
      rc = ::poll(&p, 1, remaining_ms(deadline));
      if (rc == 0) {
        last = fmt::format("no connection within {:.2g} s", budget_s);
        ::close(fd);
        continue;
      }
      int err = 0;
      socklen_t len = sizeof err;
      ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len);
      rc = err == 0 ? 0 : -1;
      errno = err;
    }
    if (rc != 0) {
      last = std::strerror(errno);
      ::close(fd);
      continue;
    }
    int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    ::freeaddrinfo(found);
    fd_ = fd;
    return Status::Ok();
  }
  ::freeaddrinfo(found);
  return Error::Transient(fmt::format("cannot connect: {}", last));
}

Status TcpLink::write_all(std::string_view bytes, Deadline deadline) {
  if (fd_ < 0) return Error::Transient("not connected");
  std::size_t sent = 0;
  while (sent < bytes.size()) {
    pollfd p{fd_, POLLOUT, 0};
    const int rc = ::poll(&p, 1, remaining_ms(deadline));
    if (rc == 0) return Error::Transient("could not send in time");
    if (rc < 0 && errno == EINTR) continue;
    const ssize_t n = ::send(fd_, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EAGAIN || errno == EINTR) continue;
      return Error::Transient(fmt::format("send failed: {}", std::strerror(errno)));
    }
    sent += static_cast<std::size_t>(n);
  }
  return Status::Ok();
}

Result<std::size_t> TcpLink::read_some(std::string& into, Deadline deadline) {
  if (fd_ < 0) return Error::Transient("not connected");
  char buf[1024];
  for (;;) {
    pollfd p{fd_, POLLIN, 0};
    const int rc = ::poll(&p, 1, remaining_ms(deadline));
    if (rc == 0) return std::size_t{0};
    if (rc < 0) {
      if (errno == EINTR) continue;
      return Error::Transient(fmt::format("poll failed: {}", std::strerror(errno)));
    }
    const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
    if (n == 0) return Error::Transient("connection closed by the controller");
    if (n < 0) {
      if (errno == EAGAIN || errno == EINTR) continue;
      return Error::Transient(fmt::format("receive failed: {}", std::strerror(errno)));
    }
    into.append(buf, static_cast<std::size_t>(n));
    return static_cast<std::size_t>(n);
  }
}

// ---------------------------------------------------------------- SerialLink

SerialLink::SerialLink(SerialOptions options) : options_(std::move(options)) {}

SerialLink::~SerialLink() = default;

void SerialLink::close() { port_.reset(); }

Status SerialLink::open(Deadline) {
  // Opening a tty does not wait: the deadline has nothing to bound.
  close();
  auto port = SerialPort::open(options_);
  if (!port) return without_device(port.error(), options_.device);
  // Stale input (a late reply to a request of the previous session) and
  // output not yet sent are dropped, so the next exchange starts clean.
  if (::isatty(port->fd())) ::tcflush(port->fd(), TCIOFLUSH);
  port_.emplace(std::move(*port));
  return Status::Ok();
}

Status SerialLink::write_all(std::string_view bytes, Deadline deadline) {
  if (!port_) return Error::Transient("not open");
  const auto st =
      port_->write(std::span(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()),
                   std::chrono::milliseconds(remaining_ms(deadline)));
  if (!st) return without_device(st.error(), options_.device);
  return Status::Ok();
}

Result<std::size_t> SerialLink::read_some(std::string& into, Deadline deadline) {
  if (!port_) return Error::Transient("not open");
  uint8_t buf[1024];
  for (;;) {
    // SerialPort::read also returns 0 on EINTR / EAGAIN before its timeout:
    // only the deadline ends the wait.
    const int left_ms = remaining_ms(deadline);
    auto n = port_->read(buf, std::chrono::milliseconds(left_ms));
    if (!n) return without_device(n.error(), options_.device);
    if (*n > 0) {
      into.append(reinterpret_cast<const char*>(buf), *n);
      return *n;
    }
    if (left_ms == 0) return std::size_t{0};
  }
}

// ---------------------------------------------------------------- choice

Result<std::unique_ptr<ByteLink>> make_table_link(const TableConnection& connection,
                                                  std::string_view name) {
  const std::string transport = table_transport(connection);
  if (transport == "tcp") {
    if (connection.host.empty()) {
      return Error::Permanent(fmt::format("{}: transport tcp: no host given", name));
    }
    if (connection.port < 1 || connection.port > 65535) {
      return Error::Permanent(fmt::format("{}: port {} is not a TCP port", name, connection.port));
    }
    return std::unique_ptr<ByteLink>(
        std::make_unique<TcpLink>(TcpLinkOptions{connection.host, connection.port}));
  }
  if (transport == "serial") {
    if (connection.device.empty()) {
      return Error::Permanent(fmt::format("{}: transport serial: no serial device given", name));
    }
    if (connection.baud <= 0) {
      return Error::Permanent(fmt::format("{}: baud {} (must be positive)", name, connection.baud));
    }
    return std::unique_ptr<ByteLink>(std::make_unique<SerialLink>(
        SerialOptions{connection.device, connection.baud, Parity::kNone}));
  }
  return Error::Permanent(
      fmt::format("{}: transport \"{}\" is none of tcp, serial", name, transport));
}

}  // namespace gyrotherm::drivers
