// The simulated gyro's serial line: KVH 1750 frames written to the master of
// a pseudo-terminal (drivers::Pty); the daemon opens the slave path as it
// would a UART.
//
// Writing never blocks: the master is non-blocking, bytes the pty does not
// take yet wait in a bounded pending buffer, and once that holds
// `pending_frames_limit` frames new frames are dropped whole (and counted),
// so a slow reader never stalls the simulation and the stream stays
// frame-aligned.
//
// Like a real UART, the line does not store frames while nobody listens:
// opens and closes of the slave are watched (inotify), and while no reader
// has it open, frames are dropped (counted) and the slave's input queue is
// flushed, so a reader that opens the line late gets current frames, not
// minutes-old ones from the kernel's buffer. If the watch cannot be set up,
// frames are always written. Not thread-safe.
//
// Frames of varying length (ASCII lines) are written with their sizes; the
// counters of frames dropped from the pending buffer (reader gone, pty
// closed) then count bytes / `frame_size`, the nominal size.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/pty.h"

namespace gyrotherm::sim {

struct GyroStreamStats {
  uint64_t frames_queued = 0;             // frames accepted into the stream
  uint64_t frames_dropped_full = 0;       // dropped: pending buffer full (reader too slow)
  uint64_t frames_dropped_closed = 0;     // dropped: pty closed (fault injection) or write error
  uint64_t frames_dropped_no_reader = 0;  // dropped: nobody had the slave open
  int readers = -1;                       // processes with the slave open; -1 = unknown
  uint64_t bytes_written = 0;             // bytes the pty took
  uint64_t write_errors = 0;
  std::size_t pending_bytes = 0;
};

class GyroStream {
 public:
  GyroStream(std::size_t frame_size, std::size_t pending_frames_limit);
  ~GyroStream();
  GyroStream(const GyroStream&) = delete;
  GyroStream& operator=(const GyroStream&) = delete;

  // Opens a new pty (a new slave path). Closes the previous one, if any.
  // Transient error when no pty can be allocated.
  Status open();
  // Hang-up: readers see POLLHUP / EIO; pending bytes are dropped.
  void close();
  bool is_open() const { return pty_.has_value(); }
  std::string slave_path() const { return pty_ ? pty_->slave_path() : std::string(); }

  // Queues `bytes` (a whole number of frames) and writes what the pty takes.
  void write_frames(std::span<const uint8_t> bytes);
  // The same for frames of the given sizes (their sum is bytes.size()); a
  // full buffer drops whole frames.
  void write_frames(std::span<const uint8_t> bytes, std::span<const std::size_t> frame_sizes);
  // Writes pending bytes, as far as the pty takes them (none while held).
  void flush();
  // Held: frames queue here (up to the pending limit, like a reader that
  // does not read) and reach the line only when released, as one backlog.
  void set_held(bool held) { held_ = held; }
  bool held() const { return held_; }

  const GyroStreamStats& stats() const { return stats_; }

 private:
  void watch_readers();
  void update_readers();
  void discard_backlog();

  std::size_t frame_size_;
  std::size_t pending_limit_bytes_;
  std::optional<drivers::Pty> pty_;
  std::vector<uint8_t> pending_;
  std::size_t pending_offset_ = 0;  // bytes of pending_ already written
  bool held_ = false;
  int inotify_fd_ = -1;
  GyroStreamStats stats_;
};

}  // namespace gyrotherm::sim
