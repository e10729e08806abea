// Pseudo-terminal pair for the simulator and for tests.
//
// The master side plays the device (the simulator writes gyro frames to it);
// the slave path is what a SerialPort opens, as it would a real UART. The
// Pty also keeps its own slave descriptor open, set raw (cfmakeraw), so the
// line discipline never echoes or translates bytes and the pair stays alive
// while a reader closes and reopens the slave. Closing the master is a
// hang-up for every reader of the slave.
#pragma once

#include <cstdint>
#include <span>
#include <string>

#include "gyrotherm/core/result.h"

namespace gyrotherm::drivers {

// Move-only owner of a master/slave descriptor pair.
class Pty {
 public:
  // Opens a new pair. With `nonblocking_master` the master descriptor has
  // O_NONBLOCK (write_master() still writes everything, waiting as needed).
  static Result<Pty> open(bool nonblocking_master = false);

  Pty(Pty&& other) noexcept;
  Pty& operator=(Pty&& other) noexcept;
  Pty(const Pty&) = delete;
  Pty& operator=(const Pty&) = delete;
  ~Pty();  // closes both descriptors

  int master_fd() const { return master_fd_; }
  int slave_fd() const { return slave_fd_; }
  // e.g. "/dev/pts/7"; gone once both descriptors are closed.
  const std::string& slave_path() const { return slave_path_; }

  // Writes all of `bytes` to the master, waiting up to `timeout_ms` (wall)
  // in total when the slave's input queue is full (the timeout only holds
  // for a non-blocking master). Transient error on timeout or when the
  // master is closed.
  Status write_master(std::span<const uint8_t> bytes, int timeout_ms = 1000);
  // Hang-up: readers of the slave see POLLHUP / EIO. Also closes our slave.
  void close_master();

 private:
  Pty(int master_fd, int slave_fd, std::string slave_path)
      : master_fd_(master_fd), slave_fd_(slave_fd), slave_path_(std::move(slave_path)) {}
  void close_all();

  int master_fd_ = -1;
  int slave_fd_ = -1;
  std::string slave_path_;
};

}  // namespace gyrotherm::drivers
