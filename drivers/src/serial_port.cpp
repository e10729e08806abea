#include "gyrotherm/drivers/serial_port.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <poll.h>
#include <sys/file.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <optional>

namespace gyrotherm::drivers {
namespace {

std::optional<speed_t> baud_constant(int baud) {
  switch (baud) {
    case 1200:
      return B1200;
    case 2400:
      return B2400;
    case 4800:
      return B4800;
    case 9600:
      return B9600;
    case 19200:
      return B19200;
    case 38400:
      return B38400;
    case 57600:
      return B57600;
    case 115200:
      return B115200;
    case 230400:
      return B230400;
#ifdef B460800
    case 460800:
      return B460800;
#endif
#ifdef B500000
    case 500000:
      return B500000;
#endif
#ifdef B576000
    case 576000:
      return B576000;
#endif
#ifdef B921600
    case 921600:
      return B921600;
#endif
#ifdef B1000000
    case 1000000:
      return B1000000;
#endif
#ifdef B1152000
    case 1152000:
      return B1152000;
#endif
#ifdef B1500000
    case 1500000:
      return B1500000;
#endif
#ifdef B2000000
    case 2000000:
      return B2000000;
#endif
#ifdef B2500000
    case 2500000:
      return B2500000;
#endif
#ifdef B3000000
    case 3000000:
      return B3000000;
#endif
#ifdef B3500000
    case 3500000:
      return B3500000;
#endif
#ifdef B4000000
    case 4000000:
      return B4000000;
#endif
    default:
      return std::nullopt;
  }
}

std::string errno_text(int err) { return std::strerror(err); }

}  // namespace

Result<Parity> parse_parity(std::string_view s) {
  if (s == "none") return Parity::kNone;
  if (s == "even") return Parity::kEven;
  if (s == "odd") return Parity::kOdd;
  return Error::Permanent(fmt::format("unknown parity '{}' (expected one of: none, even, odd)", s));
}

bool serial_line_in_use(const Error& e) {
  return e.message.find(kSerialLineInUse) != std::string::npos;
}

Result<SerialPort> SerialPort::open(const SerialOptions& options) {
  const auto speed = baud_constant(options.baud);
  if (!speed) {
    return Error::Permanent(
        fmt::format("serial device {}: unsupported baud rate {} (standard rates 1200 ... 4000000)",
                    options.device, options.baud));
  }
  const int fd = ::open(options.device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    const int err = errno;
    std::string msg =
        fmt::format("serial device {}: cannot open: {}", options.device, errno_text(err));
    // A permission problem will not fix itself; a missing or busy device may come back.
    if (err == EACCES || err == EPERM) return Error::Permanent(std::move(msg));
    return Error::Transient(std::move(msg));
  }
  // One reader per line: frames a second reader takes are lost to the first.
  // flock, not TIOCEXCL: a flock dies with its holder, whereas TIOCEXCL
  // outlives a crashed holder on a pty the simulator keeps open (locking the
  // restarted daemon out) and does not stop root.
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    ::close(fd);
    if (err == EWOULDBLOCK) {
      return Error::Transient(fmt::format("serial device {}: {} (a running gyrothermd?)",
                                          options.device, kSerialLineInUse));
    }
    return Error::Transient(
        fmt::format("serial device {}: cannot lock: {}", options.device, errno_text(err)));
  }
  SerialPort port(fd, options.device);
  if (!::isatty(fd)) return port;  // a FIFO or similar: nothing to configure

  termios tio{};
  if (::tcgetattr(fd, &tio) != 0) {
    return Error::Transient(
        fmt::format("serial device {}: tcgetattr failed: {}", options.device, errno_text(errno)));
  }
  ::cfmakeraw(&tio);
  tio.c_cflag |= CLOCAL | CREAD;
  tio.c_cflag &= ~static_cast<tcflag_t>(CSTOPB | CRTSCTS | PARENB | PARODD);
  tio.c_iflag &= ~static_cast<tcflag_t>(IXON | IXOFF | IXANY | INPCK);
  if (options.parity != Parity::kNone) {
    tio.c_cflag |= PARENB;
    tio.c_iflag |= INPCK;
    if (options.parity == Parity::kOdd) tio.c_cflag |= PARODD;
  }
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  ::cfsetispeed(&tio, *speed);
  ::cfsetospeed(&tio, *speed);
  if (::tcsetattr(fd, TCSANOW, &tio) != 0) {
    return Error::Transient(
        fmt::format("serial device {}: tcsetattr failed: {}", options.device, errno_text(errno)));
  }
  return port;
}

SerialPort::SerialPort(SerialPort&& other) noexcept
    : fd_(other.fd_), device_(std::move(other.device_)) {
  other.fd_ = -1;
}

SerialPort& SerialPort::operator=(SerialPort&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = other.fd_;
    device_ = std::move(other.device_);
    other.fd_ = -1;
  }
  return *this;
}

SerialPort::~SerialPort() {
  if (fd_ >= 0) ::close(fd_);
}

std::size_t SerialPort::pending_bytes() const {
  int n = 0;
  if (fd_ < 0 || ::ioctl(fd_, FIONREAD, &n) != 0 || n < 0) return 0;
  return static_cast<std::size_t>(n);
}

Result<std::size_t> SerialPort::read(std::span<uint8_t> buf, std::chrono::milliseconds timeout) {
  if (fd_ < 0) return Error::Permanent("serial port is closed");
  pollfd pfd{fd_, POLLIN, 0};
  const int rc = ::poll(&pfd, 1, static_cast<int>(timeout.count()));
  if (rc == 0) return std::size_t{0};
  if (rc < 0) {
    if (errno == EINTR) return std::size_t{0};
    return Error::Transient(
        fmt::format("serial device {}: poll failed: {}", device_, errno_text(errno)));
  }
  if (pfd.revents & POLLNVAL) {
    return Error::Transient(fmt::format("serial device {}: invalid descriptor", device_));
  }
  if (pfd.revents & POLLIN) {
    const ssize_t n = ::read(fd_, buf.data(), buf.size());
    if (n > 0) return static_cast<std::size_t>(n);
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) {
      return std::size_t{0};
    }
    // Readable but 0 bytes (end of file) or EIO (pty master closed): hang-up.
    const std::string cause = n == 0 ? std::string("end of file") : errno_text(errno);
    return Error::Transient(fmt::format("serial device {}: hang-up ({})", device_, cause));
  }
  // POLLHUP or POLLERR without data.
  return Error::Transient(fmt::format("serial device {}: hang-up ({})", device_,
                                      (pfd.revents & POLLHUP) ? "POLLHUP" : "POLLERR"));
}

Status SerialPort::write(std::span<const uint8_t> bytes, std::chrono::milliseconds timeout) {
  if (fd_ < 0) return Error::Permanent("serial port is closed");
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd_, bytes.data() + done, bytes.size() - done);
    if (n > 0) {
      done += static_cast<std::size_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          deadline - std::chrono::steady_clock::now());
      pollfd pfd{fd_, POLLOUT, 0};
      const int rc = left.count() > 0 ? ::poll(&pfd, 1, static_cast<int>(left.count())) : 0;
      if (rc == 0) {
        return Error::Transient(fmt::format("serial device {}: write timed out after {:g} s",
                                            device_, timeout.count() / 1000.0));
      }
      if (rc > 0 && !(pfd.revents & POLLOUT)) {
        return Error::Transient(fmt::format("serial device {}: hang-up while writing", device_));
      }
      continue;
    }
    return Error::Transient(
        fmt::format("serial device {}: write failed: {}", device_, errno_text(errno)));
  }
  return Status::Ok();
}

}  // namespace gyrotherm::drivers
