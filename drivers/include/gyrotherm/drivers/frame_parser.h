// Gyro frame parsing: bytes in, validated frames out.
//
// Parsers take bytes, never device paths: unit tests feed them from memory,
// the GyroReader feeds them from a serial port or pty. A parser never emits a
// frame that failed its integrity check.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"

namespace gyrotherm::drivers {

// One decoded gyro frame, values as sent by the device.
struct GyroFrame {
  std::array<float, 3> gyro{};   // X, Y, Z: rate or delta angle, rad or deg (per config)
  std::array<float, 3> accel{};  // X, Y, Z, g
  uint8_t status = 0;            // bits 0-2 gyro X/Y/Z valid, bits 4-6 accel valid
  uint8_t seq = 0;               // sequence counter
  int16_t temp_c = 0;            // device temperature, °C
};

struct ParserCounters {
  uint64_t frames_ok = 0;      // frames that passed the integrity check and were emitted
  uint64_t crc_failures = 0;   // candidate frames (header found) whose CRC did not match
  uint64_t bytes_skipped = 0;  // bytes discarded while searching for a valid frame
  uint64_t sequence_gaps = 0;  // times the counter did not follow the previous frame's
  uint64_t frames_missed = 0;  // frames missing according to the counter jumps
  // Frames dropped because their counter jumped and the next frame did not
  // confirm the jump (sequence_guard.h); their bytes are in bytes_skipped.
  uint64_t sequence_rejects = 0;
  // Why the last discarded input was discarded ("" if none): a CRC mismatch,
  // or for text lines the field or checksum at fault.
  std::string last_reject;
};

class FrameParser {
 public:
  virtual ~FrameParser() = default;
  // Consumes `bytes` (any split: partial frames are kept for the next call)
  // and appends every complete, valid frame to `out` in stream order.
  virtual void feed(std::span<const uint8_t> bytes, std::vector<GyroFrame>& out) = 0;
  // Forgets buffered partial bytes and the last sequence number (after the
  // port was reopened: the next frame does not count as a gap). Keeps counters.
  virtual void reset() = 0;
  virtual const ParserCounters& counters() const = 0;
};

// Supported: "kvh1750". Unknown name: permanent error naming it.
Result<std::unique_ptr<FrameParser>> make_frame_parser(std::string_view protocol);

}  // namespace gyrotherm::drivers
