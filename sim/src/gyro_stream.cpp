#include "gyrotherm/sim/gyro_stream.h"

#include <sys/inotify.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>

namespace gyrotherm::sim {

GyroStream::GyroStream(std::size_t frame_size, std::size_t pending_frames_limit)
    : frame_size_(std::max<std::size_t>(frame_size, 1)),
      pending_limit_bytes_(frame_size_ * std::max<std::size_t>(pending_frames_limit, 1)) {}

GyroStream::~GyroStream() { close(); }

Status GyroStream::open() {
  close();
  auto pty = drivers::Pty::open(/*nonblocking_master=*/true);
  if (!pty.ok()) return pty.error();
  pty_.emplace(std::move(pty).value());
  watch_readers();
  return Status::Ok();
}

// Opens by others from now on count as readers; the Pty's own slave
// descriptor was opened before the watch and does not.
void GyroStream::watch_readers() {
  stats_.readers = -1;
  inotify_fd_ = ::inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
  if (inotify_fd_ < 0) return;
  if (::inotify_add_watch(inotify_fd_, pty_->slave_path().c_str(), IN_OPEN | IN_CLOSE) < 0) {
    ::close(inotify_fd_);
    inotify_fd_ = -1;
    return;
  }
  stats_.readers = 0;
}

void GyroStream::update_readers() {
  if (inotify_fd_ < 0) return;
  alignas(inotify_event) char buf[4096];
  for (;;) {
    const ssize_t n = ::read(inotify_fd_, buf, sizeof buf);
    if (n <= 0) return;
    for (ssize_t off = 0; off < n;) {
      const auto* e = reinterpret_cast<const inotify_event*>(buf + off);
      if (e->mask & IN_Q_OVERFLOW) {
        // Lost count: stop guessing and always write from now on.
        ::close(inotify_fd_);
        inotify_fd_ = -1;
        stats_.readers = -1;
        return;
      }
      if (e->mask & IN_OPEN) ++stats_.readers;
      if (e->mask & IN_CLOSE) stats_.readers = std::max(0, stats_.readers - 1);
      off += static_cast<ssize_t>(sizeof(inotify_event) + e->len);
    }
  }
}

// No reader: what waits in our buffer and in the kernel's is dropped.
void GyroStream::discard_backlog() {
  stats_.frames_dropped_no_reader += (pending_.size() - pending_offset_) / frame_size_;
  pending_.clear();
  pending_offset_ = 0;
  stats_.pending_bytes = 0;
  ::tcflush(pty_->slave_fd(), TCIFLUSH);
}

void GyroStream::close() {
  if (inotify_fd_ >= 0) ::close(inotify_fd_);
  inotify_fd_ = -1;
  stats_.readers = -1;
  if (!pty_) return;
  const std::size_t unsent = pending_.size() - pending_offset_;
  stats_.frames_dropped_closed += unsent / frame_size_;
  pending_.clear();
  pending_offset_ = 0;
  stats_.pending_bytes = 0;
  pty_.reset();
}

void GyroStream::write_frames(std::span<const uint8_t> bytes) { write_frames(bytes, {}); }

void GyroStream::write_frames(std::span<const uint8_t> bytes,
                              std::span<const std::size_t> frame_sizes) {
  const std::size_t frames = frame_sizes.empty() ? bytes.size() / frame_size_ : frame_sizes.size();
  if (!pty_) {
    stats_.frames_dropped_closed += frames;
    return;
  }
  update_readers();
  if (stats_.readers == 0) {
    stats_.frames_dropped_no_reader += frames;
    discard_backlog();
    return;
  }
  flush();
  const std::size_t queued = pending_.size() - pending_offset_;
  const std::size_t room = pending_limit_bytes_ > queued ? pending_limit_bytes_ - queued : 0;
  std::size_t take = 0;
  std::size_t take_bytes = 0;
  if (frame_sizes.empty()) {
    take = std::min(frames, room / frame_size_);
    take_bytes = take * frame_size_;
  } else {
    while (take < frames && take_bytes + frame_sizes[take] <= room)
      take_bytes += frame_sizes[take++];
  }
  if (pending_offset_ > 0 && pending_offset_ == pending_.size()) {
    pending_.clear();
    pending_offset_ = 0;
  }
  pending_.insert(pending_.end(), bytes.begin(),
                  bytes.begin() + static_cast<std::ptrdiff_t>(take_bytes));
  stats_.frames_queued += take;
  stats_.frames_dropped_full += frames - take;
  flush();
}

void GyroStream::flush() {
  if (!pty_ || held_) return;
  while (pending_offset_ < pending_.size()) {
    const ssize_t n = ::write(pty_->master_fd(), pending_.data() + pending_offset_,
                              pending_.size() - pending_offset_);
    if (n > 0) {
      pending_offset_ += static_cast<std::size_t>(n);
      stats_.bytes_written += static_cast<uint64_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) break;
    // EIO or similar: the pty is unusable; drop what waits, keep the pty.
    ++stats_.write_errors;
    stats_.frames_dropped_closed += (pending_.size() - pending_offset_) / frame_size_;
    pending_offset_ = pending_.size();
    break;
  }
  if (pending_offset_ == pending_.size()) {
    pending_.clear();
    pending_offset_ = 0;
  } else if (pending_offset_ > pending_limit_bytes_) {
    pending_.erase(pending_.begin(),
                   pending_.begin() + static_cast<std::ptrdiff_t>(pending_offset_));
    pending_offset_ = 0;
  }
  stats_.pending_bytes = pending_.size() - pending_offset_;
}

}  // namespace gyrotherm::sim
