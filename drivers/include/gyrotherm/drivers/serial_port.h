// A serial line in raw mode (POSIX termios): real UART or pseudo-terminal.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"

namespace gyrotherm::drivers {

enum class Parity { kNone, kEven, kOdd };

struct SerialOptions {
  std::string device;  // e.g. /dev/ttyUSB0 or a pty's slave path
  int baud = 921600;
  Parity parity = Parity::kNone;
};

Result<Parity> parse_parity(std::string_view s);  // "none", "even", "odd"

// In the error of an open refused because another process holds the line.
inline constexpr std::string_view kSerialLineInUse = "in use by another process";
bool serial_line_in_use(const Error& e);

// Owns the file descriptor. Move-only.
class SerialPort {
 public:
  // Opens `device` non-blocking, raw 8 data bits, given parity, 1 stop bit,
  // no flow control, and holds it exclusively (flock LOCK_EX, released on
  // close or exit): a line another process holds is a transient error
  // (serial_line_in_use()). Errors name the device and the cause; a missing device
  // is transient (it may come back), an unsupported baud rate permanent.
  static Result<SerialPort> open(const SerialOptions& options);

  SerialPort(SerialPort&& other) noexcept;
  SerialPort& operator=(SerialPort&& other) noexcept;
  SerialPort(const SerialPort&) = delete;
  SerialPort& operator=(const SerialPort&) = delete;
  ~SerialPort();

  // Waits up to `timeout` (wall) for data and reads what is there into
  // `buf`. Returns 0 bytes on timeout. A hang-up (pty closed by the other
  // side, USB adapter unplugged) is a transient error: close and reopen.
  Result<std::size_t> read(std::span<uint8_t> buf, std::chrono::milliseconds timeout);
  // Bytes received and not yet read (FIONREAD); 0 when it cannot tell.
  std::size_t pending_bytes() const;
  // Writes all of `bytes`, waiting up to `timeout` in all while the line's
  // output queue is full (a transient error after that).
  Status write(std::span<const uint8_t> bytes,
               std::chrono::milliseconds timeout = std::chrono::seconds(1));

  int fd() const { return fd_; }
  const std::string& device() const { return device_; }

 private:
  SerialPort(int fd, std::string device) : fd_(fd), device_(std::move(device)) {}
  int fd_ = -1;
  std::string device_;
};

}  // namespace gyrotherm::drivers
