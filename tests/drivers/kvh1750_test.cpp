#include "gyrotherm/drivers/kvh1750.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <random>
#include <vector>

namespace gyrotherm::drivers {
namespace {

using Bytes = std::vector<uint8_t>;

// The example frame of docs/devices.md (bytes 0..31) and its published CRC.
const Bytes kPublished = {0xFE, 0x81, 0xFF, 0x55, 0x37, 0xA9, 0x6A, 0x6E, 0x38, 0x58, 0x6C,
                          0x1F, 0xB7, 0x5B, 0xF8, 0x62, 0xBF, 0x80, 0x3E, 0x78, 0xBB, 0x65,
                          0x0D, 0x28, 0x3B, 0x0A, 0x37, 0xAC, 0x77, 0x3D, 0x00, 0x28};
constexpr uint32_t kPublishedCrc = 0x4BFA34D8;

bool same_frame(const GyroFrame& a, const GyroFrame& b) {
  return std::memcmp(a.gyro.data(), b.gyro.data(), sizeof a.gyro) == 0 &&
         std::memcmp(a.accel.data(), b.accel.data(), sizeof a.accel) == 0 && a.status == b.status &&
         a.seq == b.seq && a.temp_c == b.temp_c;
}

// Payload values chosen so that no 0xFE byte appears inside the frame: byte
// counts of skipped data can then be asserted exactly.
GyroFrame make_frame(uint8_t seq, float z = 1.25e-4f) {
  GyroFrame f;
  f.gyro = {1.0e-5f, -2.0e-5f, z};
  f.accel = {0.001f, -0.002f, -1.0f};
  f.status = 0x77;
  f.seq = seq;
  f.temp_c = 31;
  return f;
}

Bytes encode(const GyroFrame& f) {
  const auto a = encode_kvh1750(f);
  return Bytes(a.begin(), a.end());
}

// (push_back rather than insert: g++ 12 warns falsely on vector range inserts.)
void append(Bytes& dst, std::span<const uint8_t> src) {
  for (uint8_t b : src) dst.push_back(b);
}

Bytes encode_seq(std::initializer_list<uint8_t> seqs) {
  Bytes out;
  for (uint8_t s : seqs) {
    const Bytes b = encode(make_frame(s));
    append(out, b);
  }
  return out;
}

std::vector<GyroFrame> feed_all(Kvh1750Parser& p, const Bytes& bytes) {
  std::vector<GyroFrame> out;
  p.feed(bytes, out);
  return out;
}

TEST(Kvh1750, PublishedExampleCrc) {
  EXPECT_EQ(crc32_mpeg2(kPublished), kPublishedCrc);
  // The standard CRC-32/MPEG-2 check value.
  const std::string check = "123456789";
  EXPECT_EQ(crc32_mpeg2(std::span(reinterpret_cast<const uint8_t*>(check.data()), check.size())),
            0x0376E6E7u);
}

TEST(Kvh1750, PublishedExampleDecodes) {
  Bytes frame = kPublished;
  for (int shift : {24, 16, 8, 0}) frame.push_back(static_cast<uint8_t>(kPublishedCrc >> shift));
  Kvh1750Parser p;
  Bytes stream = frame;
  append(stream, encode(make_frame(0x3E)));  // the next frame confirms the stream's first
  const auto out = feed_all(p, stream);
  ASSERT_EQ(out.size(), 2u);
  const GyroFrame& f = out[0];
  EXPECT_EQ(std::bit_cast<uint32_t>(f.gyro[0]), 0x37A96A6Eu);
  EXPECT_EQ(std::bit_cast<uint32_t>(f.gyro[1]), 0x38586C1Fu);
  EXPECT_EQ(std::bit_cast<uint32_t>(f.gyro[2]), 0xB75BF862u);
  EXPECT_EQ(std::bit_cast<uint32_t>(f.accel[0]), 0xBF803E78u);
  EXPECT_EQ(std::bit_cast<uint32_t>(f.accel[1]), 0xBB650D28u);
  EXPECT_EQ(std::bit_cast<uint32_t>(f.accel[2]), 0x3B0A37ACu);
  EXPECT_NEAR(f.accel[0], -1.0019, 1e-4);  // about -1 g on X
  EXPECT_EQ(f.status, 0x77);
  EXPECT_EQ(f.seq, 0x3D);
  EXPECT_EQ(f.temp_c, 40);
  EXPECT_EQ(p.counters().frames_ok, 2u);
  EXPECT_EQ(p.counters().crc_failures, 0u);
  EXPECT_EQ(p.counters().bytes_skipped, 0u);

  const auto re = encode_kvh1750(f);
  EXPECT_TRUE(std::equal(re.begin(), re.end(), frame.begin()));
}

TEST(Kvh1750, EncodeDecodeRoundTrip) {
  GyroFrame f;
  f.gyro = {-0.5f, 3.0e-7f, 1234.5f};
  f.accel = {0.0f, -0.0f, 9.81f};
  f.status = 0x05;
  f.seq = 127;
  f.temp_c = -21;
  const Bytes b = encode(f);
  ASSERT_EQ(b.size(), kKvh1750FrameSize);
  EXPECT_TRUE(std::equal(kKvh1750Header.begin(), kKvh1750Header.end(), b.begin()));
  EXPECT_EQ(b[30], 0xFF);  // -21 big-endian
  EXPECT_EQ(b[31], 0xEB);
  Kvh1750Parser p;
  Bytes stream = b;
  append(stream, encode(make_frame(0)));  // 127 -> 0 confirms it
  const auto out = feed_all(p, stream);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_TRUE(same_frame(out[0], f));
}

TEST(Kvh1750, FramesSplitAtEverySplitPoint) {
  const Bytes stream = encode_seq({10, 11});
  for (std::size_t split = 0; split <= stream.size(); ++split) {
    Kvh1750Parser p;
    std::vector<GyroFrame> out;
    p.feed(std::span(stream.data(), split), out);
    p.feed(std::span(stream.data() + split, stream.size() - split), out);
    ASSERT_EQ(out.size(), 2u) << "split at " << split;
    EXPECT_TRUE(same_frame(out[0], make_frame(10)));
    EXPECT_TRUE(same_frame(out[1], make_frame(11)));
    EXPECT_EQ(p.counters().bytes_skipped, 0u);
    EXPECT_EQ(p.counters().sequence_gaps, 0u);
  }
  // One byte at a time.
  Kvh1750Parser p;
  std::vector<GyroFrame> out;
  for (uint8_t b : stream) p.feed(std::span(&b, 1), out);
  EXPECT_EQ(out.size(), 2u);
  EXPECT_EQ(p.counters().bytes_skipped, 0u);
}

TEST(Kvh1750, GarbageBeforeAndBetweenFramesIsCountedExactly) {
  const Bytes f0 = encode(make_frame(0));
  const Bytes f1 = encode(make_frame(1));
  Bytes stream = {0x00, 0x13, 0xFE, 0x81, 0x42};  // 5 bytes, with a header prefix
  append(stream, f0);
  const Bytes between = {0xFE, 0xFE, 0x81, 0xFF, 0x00, 0x55, 0x7F};  // 7 bytes
  append(stream, between);
  append(stream, f1);
  stream.push_back(0xFE);  // a trailing header prefix stays buffered, not skipped

  Kvh1750Parser p;
  const auto out = feed_all(p, stream);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_TRUE(same_frame(out[0], make_frame(0)));
  EXPECT_TRUE(same_frame(out[1], make_frame(1)));
  EXPECT_EQ(p.counters().bytes_skipped, 12u);
  EXPECT_EQ(p.counters().crc_failures, 0u);
  EXPECT_EQ(p.counters().sequence_gaps, 0u);

  // The buffered prefix turns out to be garbage too.
  std::vector<GyroFrame> more;
  const Bytes tail = {0x00};
  p.feed(tail, more);
  EXPECT_TRUE(more.empty());
  EXPECT_EQ(p.counters().bytes_skipped, 14u);
}

TEST(Kvh1750, BadCrcIsRejectedAndCounted) {
  Bytes bad = encode(make_frame(3));
  bad[9] ^= 0x10;  // a gyro byte
  Kvh1750Parser p;
  EXPECT_TRUE(feed_all(p, bad).empty());
  EXPECT_EQ(p.counters().crc_failures, 1u);
  EXPECT_EQ(p.counters().frames_ok, 0u);
  // The candidate's first byte, then the 35 others (no header among them).
  EXPECT_EQ(p.counters().bytes_skipped, 36u);

  Bytes bad_crc = encode(make_frame(4));
  bad_crc[35] ^= 0x01;
  EXPECT_TRUE(feed_all(p, bad_crc).empty());
  EXPECT_EQ(p.counters().crc_failures, 2u);

  const auto good = feed_all(p, encode_seq({5, 6}));
  ASSERT_EQ(good.size(), 2u);
  EXPECT_TRUE(same_frame(good[0], make_frame(5)));
}

TEST(Kvh1750, LostByteCostsOnlyTheFrameItHit) {
  Bytes f2 = encode(make_frame(2));
  f2.erase(f2.begin() + 10);
  Bytes stream = encode_seq({0, 1});
  append(stream, f2);
  append(stream, encode_seq({3, 4}));  // 4 confirms the jump 1 -> 3

  Kvh1750Parser p;
  const auto out = feed_all(p, stream);
  ASSERT_EQ(out.size(), 4u);
  EXPECT_TRUE(same_frame(out[0], make_frame(0)));
  EXPECT_TRUE(same_frame(out[1], make_frame(1)));
  EXPECT_TRUE(same_frame(out[2], make_frame(3)));
  EXPECT_TRUE(same_frame(out[3], make_frame(4)));
  EXPECT_EQ(p.counters().crc_failures, 1u);
  EXPECT_EQ(p.counters().bytes_skipped, 35u);
  EXPECT_EQ(p.counters().sequence_gaps, 1u);
  EXPECT_EQ(p.counters().frames_missed, 1u);
}

TEST(Kvh1750, HeaderPatternInsideGarbage) {
  // A fake header with 10 bytes after it: the 36-byte candidate overlaps the
  // real frame, fails its CRC, and the search resumes one byte later.
  Bytes stream = {0x01, 0xFE, 0x81, 0xFF, 0x55};
  stream.resize(stream.size() + 10, 0x22);
  const Bytes f = encode(make_frame(9));
  append(stream, f);
  // A fake header followed by a long run of garbage.
  append(stream, kKvh1750Header);
  stream.resize(stream.size() + 40, 0x33);
  const Bytes g = encode(make_frame(10));
  append(stream, g);

  Kvh1750Parser p;
  const auto out = feed_all(p, stream);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_TRUE(same_frame(out[0], make_frame(9)));
  EXPECT_TRUE(same_frame(out[1], make_frame(10)));
  EXPECT_EQ(p.counters().crc_failures, 2u);
  EXPECT_EQ(p.counters().bytes_skipped, 15u + 44u);
}

TEST(Kvh1750, SequenceWrapIsNotAGap) {
  Kvh1750Parser p;
  EXPECT_EQ(feed_all(p, encode_seq({125, 126, 127, 0, 1})).size(), 5u);
  EXPECT_EQ(p.counters().sequence_gaps, 0u);
  EXPECT_EQ(p.counters().frames_missed, 0u);
}

TEST(Kvh1750, SequenceJumpCountsMissedFrames) {
  Kvh1750Parser p;
  EXPECT_EQ(feed_all(p, encode_seq({4, 5, 8, 9})).size(), 4u);
  EXPECT_EQ(p.counters().sequence_gaps, 1u);
  EXPECT_EQ(p.counters().frames_missed, 2u);
  // Across the wrap: 126 -> 2 misses 127, 0, 1 (2 is confirmed by 3).
  EXPECT_EQ(feed_all(p, encode_seq({10, 126, 2, 3})).size(), 4u);
  EXPECT_EQ(p.counters().sequence_gaps, 3u);
  EXPECT_EQ(p.counters().frames_missed, 2u + 115u + 3u);
  EXPECT_EQ(p.counters().sequence_rejects, 0u);
}

// A frame that passes its CRC but whose counter contradicts both neighbours
// (a forged or corrupted frame, the CRC matching by chance) is dropped: its
// value is not emitted, nothing is counted missed. Also across the wrap.
TEST(Kvh1750, AFrameWhoseCounterContradictsBothNeighboursIsDropped) {
  Kvh1750Parser p;
  Bytes stream = encode_seq({10, 11});
  append(stream, encode(make_frame(99, 0.5f)));  // wild counter and value
  append(stream, encode_seq({12, 126, 127}));
  append(stream, encode(make_frame(127, 0.5f)));  // a repeated counter
  append(stream, encode(make_frame(60, 0.5f)));   // wild again, at the wrap
  append(stream, encode_seq({0, 1}));
  const auto out = feed_all(p, stream);
  const std::vector<uint8_t> seqs{10, 11, 12, 126, 127, 0, 1};
  ASSERT_EQ(out.size(), seqs.size());
  for (std::size_t i = 0; i < out.size(); ++i) {
    EXPECT_EQ(out[i].seq, seqs[i]) << i;
    EXPECT_EQ(out[i].gyro[2], 1.25e-4f) << i;
  }
  const ParserCounters& c = p.counters();
  EXPECT_EQ(c.sequence_rejects, 3u);
  EXPECT_EQ(c.sequence_gaps, 1u);    // 12 -> 126, confirmed by 127
  EXPECT_EQ(c.frames_missed, 113u);  // 13..125
  EXPECT_EQ(c.bytes_skipped, 3u * 36u);
  EXPECT_EQ(c.crc_failures, 0u);
  EXPECT_NE(c.last_reject.find("counter 60 jumps from 127"), std::string::npos) << c.last_reject;
}

// A real loss across the wrap is counted once the next frame confirms it.
TEST(Kvh1750, ARealLossAcrossTheWrapIsCountedOnceConfirmed) {
  Kvh1750Parser p;
  EXPECT_EQ(feed_all(p, encode_seq({124, 125, 2})).size(), 2u);  // 2 waits
  EXPECT_EQ(p.counters().frames_missed, 0u);
  EXPECT_EQ(feed_all(p, encode_seq({3})).size(), 2u);
  EXPECT_EQ(p.counters().sequence_gaps, 1u);
  EXPECT_EQ(p.counters().frames_missed, 4u);  // 126, 127, 0, 1
  EXPECT_EQ(p.counters().sequence_rejects, 0u);
}

TEST(Kvh1750, ResetForgetsSequenceAndPartialFrame) {
  Kvh1750Parser p;
  EXPECT_EQ(feed_all(p, encode_seq({50, 51})).size(), 2u);
  const Bytes partial = encode(make_frame(52));
  std::vector<GyroFrame> out;
  p.feed(std::span(partial.data(), 20), out);
  p.reset();
  EXPECT_EQ(feed_all(p, encode_seq({7, 8})).size(), 2u);  // not a gap after reset
  EXPECT_EQ(p.counters().sequence_gaps, 0u);
  EXPECT_EQ(p.counters().bytes_skipped, 20u);
  EXPECT_EQ(p.counters().frames_ok, 4u);
}

// The first frame of a stream has no predecessor to be judged by: it counts
// once the next frame follows it. A bad first frame is dropped; so is a good
// one when the frame after it was lost (it cannot be told from a bad one).
TEST(Kvh1750, TheFirstFrameCountsOnceTheNextFollowsIt) {
  Kvh1750Parser p;
  EXPECT_TRUE(feed_all(p, encode_seq({40})).empty());
  EXPECT_EQ(feed_all(p, encode_seq({41})).size(), 2u);
  EXPECT_EQ(p.counters().sequence_rejects, 0u);

  Kvh1750Parser q;  // a wild first frame, then the real stream
  Bytes stream = encode(make_frame(99, 0.5f));
  append(stream, encode_seq({3, 4, 5}));
  const auto out = feed_all(q, stream);
  ASSERT_EQ(out.size(), 3u);
  EXPECT_EQ(out[0].seq, 3u);
  EXPECT_EQ(q.counters().sequence_rejects, 1u);
  EXPECT_EQ(q.counters().sequence_gaps, 0u);
  EXPECT_EQ(q.counters().frames_missed, 0u);
  EXPECT_NE(q.counters().last_reject.find("counter 99 starts the stream"), std::string::npos)
      << q.counters().last_reject;
}

// Random corruption: every emitted frame is one that was sent, in order, and
// every frame left intact is emitted (a corrupt candidate only advances the
// search by one byte, so it can never swallow a good frame behind it).
TEST(Kvh1750, RandomCorruptionNeverEmitsACorruptFrame) {
  std::mt19937 rng(20240611);
  std::uniform_real_distribution<double> u01(0, 1);
  std::uniform_int_distribution<int> byte(0, 255);
  std::normal_distribution<float> noise(0.0f, 1e-3f);

  constexpr int kFrames = 3000;
  std::vector<GyroFrame> intact;
  Bytes stream;
  int corrupted = 0;
  for (int i = 0; i < kFrames; ++i) {
    GyroFrame f;
    for (auto& g : f.gyro) g = noise(rng);
    for (auto& a : f.accel) a = noise(rng);
    f.status = static_cast<uint8_t>(byte(rng));
    f.seq = static_cast<uint8_t>(i % kKvh1750SeqModulo);
    f.temp_c = static_cast<int16_t>(byte(rng) - 100);
    Bytes b = encode(f);
    // The first and last two intact: the first frame counts once the next
    // follows it, a jump once the next frame confirms it.
    const double r = i < 2 || i >= kFrames - 2 ? 1.0 : u01(rng);
    if (r < 0.05) {
      b[std::uniform_int_distribution<std::size_t>(0, b.size() - 1)(rng)] ^=
          static_cast<uint8_t>(1 + byte(rng) % 255);
      ++corrupted;
    } else if (r < 0.10) {
      b.erase(b.begin() + std::uniform_int_distribution<long>(0, 35)(rng));
      ++corrupted;
    } else {
      intact.push_back(f);
    }
    append(stream, b);
    if (u01(rng) < 0.05) {  // garbage between frames, sometimes with a fake header
      const int n = std::uniform_int_distribution<int>(1, 60)(rng);
      for (int k = 0; k < n; ++k) stream.push_back(static_cast<uint8_t>(byte(rng)));
      if (u01(rng) < 0.5) append(stream, kKvh1750Header);
    }
  }

  Kvh1750Parser p;
  std::vector<GyroFrame> out;
  std::size_t pos = 0;
  while (pos < stream.size()) {
    const std::size_t n =
        std::min(stream.size() - pos, std::uniform_int_distribution<std::size_t>(1, 200)(rng));
    p.feed(std::span(stream.data() + pos, n), out);
    pos += n;
  }

  ASSERT_EQ(out.size(), intact.size());
  for (std::size_t i = 0; i < out.size(); ++i) {
    ASSERT_TRUE(same_frame(out[i], intact[i])) << "frame " << i;
  }
  const ParserCounters& c = p.counters();
  EXPECT_EQ(c.frames_ok, out.size());
  EXPECT_EQ(c.frames_missed, static_cast<uint64_t>(corrupted));
  EXPECT_GE(c.crc_failures, static_cast<uint64_t>(corrupted) / 2);
  // Every byte fed was emitted in a frame, skipped, or is still buffered.
  const uint64_t accounted = c.frames_ok * kKvh1750FrameSize + c.bytes_skipped;
  EXPECT_LE(accounted, stream.size());
  EXPECT_LT(stream.size() - accounted, kKvh1750FrameSize);
}

TEST(Kvh1750, MakeFrameParser) {
  auto p = make_frame_parser("kvh1750");
  ASSERT_TRUE(p.ok());
  std::vector<GyroFrame> out;
  (*p)->feed(encode_seq({1, 2}), out);
  EXPECT_EQ(out.size(), 2u);

  auto bad = make_frame_parser("nmea");
  ASSERT_FALSE(bad.ok());
  EXPECT_FALSE(bad.error().transient);
  EXPECT_NE(bad.error().message.find("nmea"), std::string::npos);
  EXPECT_NE(bad.error().message.find("kvh1750"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm::drivers
