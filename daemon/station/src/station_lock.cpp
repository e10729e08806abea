#include "gyrotherm/station/station_lock.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <sstream>
#include <thread>

namespace gyrotherm::station {
namespace {

// The lock file's text: "pid N\n" and, once the API listens, "api URL\n".
StationOwner parse_owner(int fd) {
  StationOwner owner;
  std::string text;
  char buf[512];
  for (off_t at = 0;;) {
    const ssize_t n = ::pread(fd, buf, sizeof buf, at);
    if (n <= 0) break;
    text.append(buf, static_cast<std::size_t>(n));
    at += n;
    if (text.size() > 4096) break;
  }
  std::istringstream in(text);
  for (std::string key; in >> key;) {
    if (key == "pid") in >> owner.pid;
    if (key == "api") in >> owner.api_url;
  }
  return owner;
}

Status write_all(int fd, const std::string& text) {
  if (::ftruncate(fd, 0) != 0 || ::pwrite(fd, text.data(), text.size(), 0) < 0) {
    return Error::Transient(std::strerror(errno));
  }
  return Status::Ok();
}

}  // namespace

std::string station_lock_path(const std::string& db_path) {
  // The database's real path: two configs naming one file through a
  // symlink, "..", or a relative path from another directory must meet at
  // one lock (a second daemon on the file would interrupt the first's run).
  std::error_code ec;
  const std::filesystem::path real = std::filesystem::weakly_canonical(db_path, ec);
  return (ec || real.empty() ? db_path : real.string()) + ".lock";
}

Result<StationLock> StationLock::acquire(const std::string& db_path, double wait_s) {
  const std::string path = station_lock_path(db_path);
  if (const auto parent = std::filesystem::path(path).parent_path(); !parent.empty()) {
    std::error_code ec;  // as the database does; a failure shows in open() below
    std::filesystem::create_directories(parent, ec);
  }
  const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    return Error::Permanent(
        fmt::format("station lock {}: cannot open: {}", path, std::strerror(errno)));
  }
  const auto deadline =
      std::chrono::steady_clock::now() +
      std::chrono::milliseconds(static_cast<int64_t>(std::max(0.0, wait_s) * 1000));
  while (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    if (err == EINTR) continue;
    if (err != EWOULDBLOCK || std::chrono::steady_clock::now() >= deadline) {
      const StationOwner owner = parse_owner(fd);
      ::close(fd);
      if (err != EWOULDBLOCK) {
        return Error::Permanent(
            fmt::format("station lock {}: cannot lock: {}", path, std::strerror(err)));
      }
      return Error::Permanent(
          fmt::format("station lock {}: the station is run by another gyrothermd{} (one daemon per "
                      "database)",
                      path, owner.pid > 0 ? fmt::format(" (pid {})", owner.pid) : std::string()));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  StationLock lock(fd, path);
  if (Status s = write_all(fd, fmt::format("pid {}\n", ::getpid())); !s.ok()) {
    return Error::Permanent(
        fmt::format("station lock {}: cannot write: {}", path, s.error().message));
  }
  return lock;
}

StationLock::StationLock(StationLock&& other) noexcept
    : fd_(other.fd_), path_(std::move(other.path_)) {
  other.fd_ = -1;
}

StationLock::~StationLock() {
  if (fd_ >= 0) ::close(fd_);  // releases the flock
}

void StationLock::note_api(const std::string& url) {
  if (fd_ >= 0) (void)write_all(fd_, fmt::format("pid {}\napi {}\n", ::getpid(), url));
}

std::optional<StationOwner> station_owner(const std::string& db_path) {
  const std::string path = station_lock_path(db_path);
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0)
    return std::nullopt;  // never run here (or not readable: the daemon's own check stands)
  // A shared lock can be had only while no daemon holds the exclusive one.
  if (::flock(fd, LOCK_SH | LOCK_NB) == 0) {
    ::close(fd);
    return std::nullopt;
  }
  std::optional<StationOwner> owner;
  if (errno == EWOULDBLOCK) owner = parse_owner(fd);
  ::close(fd);
  return owner;
}

}  // namespace gyrotherm::station
