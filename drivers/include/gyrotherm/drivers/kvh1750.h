// KVH 1750 IMU "Format A" frames (docs/devices.md).
//
// 36 bytes, big-endian: header FE 81 FF 55; gyro X/Y/Z float32; accel X/Y/Z
// float32 (g); status byte; sequence counter 0..127 (wraps); int16
// temperature °C; CRC-32/MPEG-2 over bytes 0..31 (poly 0x04C11DB7, init
// 0xFFFFFFFF, no reflection, xorout 0), computed with Boost.CRC.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "gyrotherm/drivers/frame_parser.h"
#include "gyrotherm/drivers/sequence_guard.h"

namespace gyrotherm::drivers {

inline constexpr std::size_t kKvh1750FrameSize = 36;
inline constexpr std::array<uint8_t, 4> kKvh1750Header{0xFE, 0x81, 0xFF, 0x55};
inline constexpr uint8_t kKvh1750SeqModulo = 128;

uint32_t crc32_mpeg2(std::span<const uint8_t> bytes);

// Serialises a frame, header and CRC included. Used by the simulator and tests.
std::array<uint8_t, kKvh1750FrameSize> encode_kvh1750(const GyroFrame& frame);

// Resynchronising parser. A candidate frame (header match) whose CRC fails
// advances the search by one byte, not a whole frame, so a lost byte costs at
// most the frame it hit. The counter (mod 128) is judged by SequenceGuard: a
// frame that jumps is emitted once the next frame confirms the jump, and
// dropped (sequence_rejects) when it does not.
class Kvh1750Parser final : public FrameParser {
 public:
  void feed(std::span<const uint8_t> bytes, std::vector<GyroFrame>& out) override;
  void reset() override;
  const ParserCounters& counters() const override { return counters_; }

 private:
  std::vector<uint8_t> buf_;
  ParserCounters counters_;
  SequenceGuard<GyroFrame> guard_{kKvh1750SeqModulo};
};

}  // namespace gyrotherm::drivers
