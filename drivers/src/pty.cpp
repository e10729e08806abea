#include "gyrotherm/drivers/pty.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>

namespace gyrotherm::drivers {

Result<Pty> Pty::open(bool nonblocking_master) {
  int flags = O_RDWR | O_NOCTTY | O_CLOEXEC;
  if (nonblocking_master) flags |= O_NONBLOCK;
  const int master = ::posix_openpt(flags);
  if (master < 0) {
    return Error::Transient(fmt::format("posix_openpt failed: {}", std::strerror(errno)));
  }
  auto fail = [master](const char* what) {
    const int err = errno;
    ::close(master);
    return Error::Transient(fmt::format("pty: {} failed: {}", what, std::strerror(err)));
  };
  if (::grantpt(master) != 0) return fail("grantpt");
  if (::unlockpt(master) != 0) return fail("unlockpt");
  char name[128];
  if (::ptsname_r(master, name, sizeof name) != 0) return fail("ptsname");
  const int slave = ::open(name, O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (slave < 0) return fail("opening the slave");
  termios tio{};
  if (::tcgetattr(slave, &tio) == 0) {
    ::cfmakeraw(&tio);
    tio.c_cflag |= CLOCAL | CREAD;
    tio.c_cc[VMIN] = 0;
    tio.c_cc[VTIME] = 0;
  }
  if (::tcsetattr(slave, TCSANOW, &tio) != 0) {
    const int err = errno;
    ::close(slave);
    errno = err;
    return fail("setting the slave raw");
  }
  return Pty(master, slave, name);
}

Pty::Pty(Pty&& other) noexcept
    : master_fd_(other.master_fd_),
      slave_fd_(other.slave_fd_),
      slave_path_(std::move(other.slave_path_)) {
  other.master_fd_ = -1;
  other.slave_fd_ = -1;
}

Pty& Pty::operator=(Pty&& other) noexcept {
  if (this != &other) {
    close_all();
    master_fd_ = other.master_fd_;
    slave_fd_ = other.slave_fd_;
    slave_path_ = std::move(other.slave_path_);
    other.master_fd_ = -1;
    other.slave_fd_ = -1;
  }
  return *this;
}

Pty::~Pty() { close_all(); }

void Pty::close_all() { close_master(); }

void Pty::close_master() {
  if (master_fd_ >= 0) ::close(master_fd_);
  if (slave_fd_ >= 0) ::close(slave_fd_);
  master_fd_ = -1;
  slave_fd_ = -1;
}

Status Pty::write_master(std::span<const uint8_t> bytes, int timeout_ms) {
  if (master_fd_ < 0) return Error::Transient("pty master is closed");
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(master_fd_, bytes.data() + done, bytes.size() - done);
    if (n > 0) {
      done += static_cast<std::size_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) {
      return Error::Transient(
          fmt::format("pty {}: write failed: {}", slave_path_, std::strerror(errno)));
    }
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      return Error::Transient(fmt::format("pty {}: write timed out ({} of {} bytes written)",
                                          slave_path_, done, bytes.size()));
    }
    pollfd pfd{master_fd_, POLLOUT, 0};
    ::poll(&pfd, 1, static_cast<int>(left.count()));
  }
  return Status::Ok();
}

}  // namespace gyrotherm::drivers
