#include "gyrotherm/drivers/kvh1750.h"

#include <algorithm>
#include <bit>
#include <boost/crc.hpp>
#include <cstring>
#include <string>

namespace gyrotherm::drivers {
namespace {

constexpr std::size_t kHeaderSize = kKvh1750Header.size();
constexpr std::size_t kCrcOffset = 32;

void put_u32_be(uint8_t* p, uint32_t v) {
  p[0] = static_cast<uint8_t>(v >> 24);
  p[1] = static_cast<uint8_t>(v >> 16);
  p[2] = static_cast<uint8_t>(v >> 8);
  p[3] = static_cast<uint8_t>(v);
}

uint32_t get_u32_be(const uint8_t* p) {
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | uint32_t{p[3]};
}

float get_f32_be(const uint8_t* p) { return std::bit_cast<float>(get_u32_be(p)); }

GyroFrame decode_frame(const uint8_t* p) {
  GyroFrame f;
  for (int i = 0; i < 3; ++i) f.gyro[i] = get_f32_be(p + 4 + 4 * i);
  for (int i = 0; i < 3; ++i) f.accel[i] = get_f32_be(p + 16 + 4 * i);
  f.status = p[28];
  f.seq = p[29];
  f.temp_c = static_cast<int16_t>((uint16_t{p[30]} << 8) | uint16_t{p[31]});
  return f;
}

// Number of leading bytes of `p[0..n)` that match the header (n < 4 allowed).
std::size_t header_match(const uint8_t* p, std::size_t n) {
  const std::size_t m = std::min(n, kHeaderSize);
  for (std::size_t i = 0; i < m; ++i) {
    if (p[i] != kKvh1750Header[i]) return i;
  }
  return m;
}

}  // namespace

uint32_t crc32_mpeg2(std::span<const uint8_t> bytes) {
  boost::crc_optimal<32, 0x04C11DB7, 0xFFFFFFFF, 0, false, false> crc;
  crc.process_bytes(bytes.data(), bytes.size());
  return crc.checksum();
}

std::array<uint8_t, kKvh1750FrameSize> encode_kvh1750(const GyroFrame& frame) {
  std::array<uint8_t, kKvh1750FrameSize> out{};
  std::copy(kKvh1750Header.begin(), kKvh1750Header.end(), out.begin());
  for (int i = 0; i < 3; ++i) put_u32_be(&out[4 + 4 * i], std::bit_cast<uint32_t>(frame.gyro[i]));
  for (int i = 0; i < 3; ++i) {
    put_u32_be(&out[16 + 4 * i], std::bit_cast<uint32_t>(frame.accel[i]));
  }
  out[28] = frame.status;
  out[29] = frame.seq;
  const auto temp = static_cast<uint16_t>(frame.temp_c);
  out[30] = static_cast<uint8_t>(temp >> 8);
  out[31] = static_cast<uint8_t>(temp);
  put_u32_be(&out[kCrcOffset], crc32_mpeg2(std::span(out.data(), kCrcOffset)));
  return out;
}

void Kvh1750Parser::feed(std::span<const uint8_t> bytes, std::vector<GyroFrame>& out) {
  buf_.insert(buf_.end(), bytes.begin(), bytes.end());
  const uint8_t* data = buf_.data();
  const std::size_t size = buf_.size();
  std::size_t pos = 0;
  while (pos < size) {
    const std::size_t avail = size - pos;
    const std::size_t matched = header_match(data + pos, avail);
    if (matched < std::min(avail, kHeaderSize)) {
      // Not a header start: discard this byte and jump to the next candidate.
      const void* next = std::memchr(data + pos + 1, kKvh1750Header[0], size - pos - 1);
      const std::size_t next_pos =
          next ? static_cast<std::size_t>(static_cast<const uint8_t*>(next) - data) : size;
      counters_.bytes_skipped += next_pos - pos;
      pos = next_pos;
      continue;
    }
    if (avail < kKvh1750FrameSize) break;  // header (or its prefix) at the tail: wait for more
    const uint8_t* frame = data + pos;
    if (crc32_mpeg2(std::span(frame, kCrcOffset)) != get_u32_be(frame + kCrcOffset)) {
      ++counters_.crc_failures;
      ++counters_.bytes_skipped;
      if (counters_.last_reject.empty()) counters_.last_reject = "frame CRC-32 mismatch";
      ++pos;
      continue;
    }
    const GyroFrame f = decode_frame(frame);
    guard_.push(
        f, f.seq % kKvh1750SeqModulo, kKvh1750FrameSize, [] { return "frame"; }, out, counters_);
    pos += kKvh1750FrameSize;
  }
  // Whatever remains is shorter than a frame and starts with (a prefix of) the
  // header, so the buffer never holds more than kKvh1750FrameSize - 1 bytes
  // between calls.
  buf_.erase(buf_.begin(), buf_.begin() + static_cast<std::ptrdiff_t>(pos));
}

void Kvh1750Parser::reset() {
  counters_.bytes_skipped += buf_.size();  // a partial frame is discarded too
  buf_.clear();
  guard_.reset(counters_);
}

Result<std::unique_ptr<FrameParser>> make_frame_parser(std::string_view protocol) {
  if (protocol == "kvh1750") return std::unique_ptr<FrameParser>(new Kvh1750Parser());
  return Error::Permanent("unknown gyro protocol '" + std::string(protocol) +
                          "' (supported: kvh1750)");
}

}  // namespace gyrotherm::drivers
