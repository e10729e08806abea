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

}  // namespace gyrotherm
