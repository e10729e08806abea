#include "gyrotherm/core/files.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>

namespace gyrotherm {

namespace {

// fsync of a directory, so a rename inside it is durable.
bool sync_directory(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return false;
  const bool ok = ::fsync(fd) == 0;
  ::close(fd);
  return ok;
}

}  // namespace

Status write_file_atomically(const std::string& path, std::string_view content) {
  namespace fs = std::filesystem;
  const fs::path target(path);
  const fs::path dir = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::string tmpl = (dir / fmt::format(".{}.tmp-XXXXXX", target.filename().string())).string();
  const int fd = ::mkstemp(tmpl.data());
  if (fd < 0) {
    return Error::Permanent(fmt::format("{}: cannot create a temporary file in {}: {}", path,
                                        dir.string(), std::strerror(errno)));
  }
  auto give_up = [&](const char* what) {
    const std::string reason = std::strerror(errno);
    ::close(fd);
    ::unlink(tmpl.c_str());
    return Error::Permanent(fmt::format("{}: cannot {}: {}", path, what, reason));
  };
  std::size_t done = 0;
  while (done < content.size()) {
    const ssize_t n = ::write(fd, content.data() + done, content.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      return give_up("write");
    }
    done += static_cast<std::size_t>(n);
  }
  ::fchmod(fd, 0644);
  if (::fsync(fd) != 0) return give_up("sync");
  if (::close(fd) != 0) {
    const std::string reason = std::strerror(errno);
    ::unlink(tmpl.c_str());
    return Error::Permanent(fmt::format("{}: cannot write: {}", path, reason));
  }
  if (::rename(tmpl.c_str(), path.c_str()) != 0) {
    const std::string reason = std::strerror(errno);
    ::unlink(tmpl.c_str());
    return Error::Permanent(fmt::format("{}: cannot rename the temporary file: {}", path, reason));
  }
  return Status::Ok();
}

Status write_file_creating_folders(const std::string& path, std::string_view content) {
  namespace fs = std::filesystem;
  const fs::path target(path);
  if (target.has_parent_path()) {
    std::error_code ec;
    fs::create_directories(target.parent_path(), ec);
    if (ec) {
      return Error::Permanent(fmt::format("{}: cannot create the folder {}: {}", path,
                                          target.parent_path().string(), ec.message()));
    }
  }
  return write_file_atomically(path, content);
}

Status rename_directory_durably(const std::string& from, const std::string& to) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::exists(to, ec)) {
    return Error::Permanent(fmt::format("cannot move {} to {}: {} exists", from, to, to));
  }
  if (!sync_directory(from)) {
    return Error::Permanent(fmt::format("cannot sync {}: {}", from, std::strerror(errno)));
  }
  if (::rename(from.c_str(), to.c_str()) != 0) {
    return Error::Permanent(
        fmt::format("cannot move {} to {}: {}", from, to, std::strerror(errno)));
  }
  const fs::path parent = fs::path(to).has_parent_path() ? fs::path(to).parent_path() : ".";
  sync_directory(parent.string());
  return Status::Ok();
}

std::string format_bytes(std::size_t bytes) {
  if (bytes >= (1u << 20) && bytes % (1u << 20) == 0) return fmt::format("{} MiB", bytes >> 20);
  if (bytes >= (1u << 10) && bytes % (1u << 10) == 0) return fmt::format("{} KiB", bytes >> 10);
  return fmt::format("{} bytes", bytes);
}

Result<std::string> read_bounded_file(const std::string& path, std::size_t max_bytes) {
  // O_NONBLOCK: opening a FIFO with no writer must not block; it is refused
  // below anyway.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
  if (fd < 0) {
    return Error::Permanent(fmt::format("{}: cannot open file: {}", path, std::strerror(errno)));
  }
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    return Error::Permanent(fmt::format("{}: cannot read file: {}", path, std::strerror(errno)));
  }
  if (S_ISDIR(st.st_mode)) {
    return Error::Permanent(fmt::format("{}: is a directory, not a file", path));
  }
  if (!S_ISREG(st.st_mode)) {
    const char* what = S_ISCHR(st.st_mode)    ? "a character device"
                       : S_ISBLK(st.st_mode)  ? "a block device"
                       : S_ISFIFO(st.st_mode) ? "a FIFO (named pipe)"
                       : S_ISSOCK(st.st_mode) ? "a socket"
                                              : "not a regular file";
    return Error::Permanent(fmt::format("{}: is {}, not a regular file; give a file", path, what));
  }
  auto too_large = [&](std::size_t seen) {
    return Error::Permanent(
        fmt::format("{}: is {} bytes, over the limit of {}", path, seen, format_bytes(max_bytes)));
  };
  if (static_cast<std::size_t>(st.st_size) > max_bytes) {
    return too_large(static_cast<std::size_t>(st.st_size));
  }
  std::string content;
  content.resize(max_bytes + 1);
  std::size_t got = 0;
  while (got < content.size()) {
    const ssize_t n = ::read(fd, content.data() + got, content.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      return Error::Permanent(fmt::format("{}: cannot read file: {}", path, std::strerror(errno)));
    }
    if (n == 0) break;
    got += static_cast<std::size_t>(n);
  }
  if (got > max_bytes) return too_large(got);
  content.resize(got);
  return content;
}

}  // namespace gyrotherm
