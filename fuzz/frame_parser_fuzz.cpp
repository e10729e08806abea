// Fuzzes the KVH 1750 frame parser (drivers/frame_parser.h, kvh1750.h).
//
// The input is a script: each op appends raw bytes, a valid frame built from
// fuzz bytes with encode_kvh1750, or such a frame with one bit flipped, so
// the stream holds real frames among noise (a fuzzer alone seldom finds a
// CRC). The stream is fed once whole and once in fuzz-chosen chunks.
// Checked: both give the same frames and counters; every frame emitted
// carries a good CRC and sits in the stream byte for byte; every byte is
// either in a frame, skipped, or still buffered (< one frame).
#include <fuzzer/FuzzedDataProvider.h>

#include <algorithm>
#include <cstring>
#include <vector>

#include "fuzz_check.h"
#include "gyrotherm/drivers/kvh1750.h"

using namespace gyrotherm::drivers;

namespace {

GyroFrame frame_from(FuzzedDataProvider& in) {
  GyroFrame f;
  for (auto& g : f.gyro) g = in.ConsumeFloatingPoint<float>();
  for (auto& a : f.accel) a = in.ConsumeFloatingPoint<float>();
  f.status = in.ConsumeIntegral<uint8_t>();
  f.seq = in.ConsumeIntegral<uint8_t>();
  f.temp_c = in.ConsumeIntegral<int16_t>();
  return f;
}

bool same_counters(const ParserCounters& a, const ParserCounters& b) {
  return a.frames_ok == b.frames_ok && a.crc_failures == b.crc_failures &&
         a.bytes_skipped == b.bytes_skipped && a.sequence_gaps == b.sequence_gaps &&
         a.frames_missed == b.frames_missed && a.sequence_rejects == b.sequence_rejects;
}

bool same_frame(const GyroFrame& a, const GyroFrame& b) {
  // Compared as bytes: NaN payloads must survive too.
  return encode_kvh1750(a) == encode_kvh1750(b);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider in(data, size);
  std::vector<uint8_t> stream;
  std::vector<std::size_t> chunks;
  while (in.remaining_bytes() > 0 && stream.size() < 64 * 1024) {
    switch (in.ConsumeIntegralInRange<int>(0, 4)) {
      case 0: {  // raw bytes
        const auto raw = in.ConsumeBytes<uint8_t>(in.ConsumeIntegralInRange<std::size_t>(0, 64));
        stream.insert(stream.end(), raw.begin(), raw.end());
        break;
      }
      case 1:
      case 2: {  // a valid frame
        const auto bytes = encode_kvh1750(frame_from(in));
        stream.insert(stream.end(), bytes.begin(), bytes.end());
        break;
      }
      case 3: {  // a frame with one bit flipped
        auto bytes = encode_kvh1750(frame_from(in));
        const auto bit = in.ConsumeIntegralInRange<std::size_t>(0, bytes.size() * 8 - 1);
        bytes[bit / 8] ^= static_cast<uint8_t>(1u << (bit % 8));
        stream.insert(stream.end(), bytes.begin(), bytes.end());
        break;
      }
      case 4:  // where the next chunk boundary falls
        chunks.push_back(in.ConsumeIntegralInRange<std::size_t>(0, 80));
        break;
    }
  }

  Kvh1750Parser whole;
  std::vector<GyroFrame> whole_frames;
  whole.feed(stream, whole_frames);

  auto made = make_frame_parser("kvh1750");
  FUZZ_CHECK(made.ok());
  FrameParser& split = **made;
  std::vector<GyroFrame> split_frames;
  std::size_t pos = 0;
  for (std::size_t c : chunks) {
    const std::size_t n = std::min(c, stream.size() - pos);
    split.feed(std::span(stream.data() + pos, n), split_frames);
    pos += n;
  }
  split.feed(std::span(stream.data() + pos, stream.size() - pos), split_frames);

  const ParserCounters& c = whole.counters();
  FUZZ_CHECK(same_counters(c, split.counters()));
  FUZZ_CHECK(whole_frames.size() == split_frames.size());
  for (std::size_t i = 0; i < whole_frames.size(); ++i) {
    FUZZ_CHECK(same_frame(whole_frames[i], split_frames[i]));
  }

  FUZZ_CHECK(c.frames_ok == whole_frames.size());
  FUZZ_CHECK(c.sequence_gaps <= c.frames_ok);
  FUZZ_CHECK(c.frames_missed >= c.sequence_gaps);
  FUZZ_CHECK(c.frames_missed <= c.sequence_gaps * (kKvh1750SeqModulo - 1));
  // Unaccounted: a partial frame buffered, and a frame whose counter jumped,
  // held until the next frame confirms it (sequence_guard.h).
  const uint64_t accounted = c.bytes_skipped + c.frames_ok * kKvh1750FrameSize;
  FUZZ_CHECK(accounted <= stream.size());
  FUZZ_CHECK(stream.size() - accounted < 2 * kKvh1750FrameSize);

  // Frames appear in stream order, each a verbatim, CRC-valid slice of it.
  std::size_t search_from = 0;
  for (const GyroFrame& f : whole_frames) {
    const auto bytes = encode_kvh1750(f);  // with its CRC: so the stream's slice had it
    const auto it = std::search(stream.begin() + static_cast<std::ptrdiff_t>(search_from),
                                stream.end(), bytes.begin(), bytes.end());
    FUZZ_CHECK(it != stream.end());
    search_from = static_cast<std::size_t>(it - stream.begin()) + kKvh1750FrameSize;
  }

  // reset() discards the partial tail: then every byte is accounted for.
  whole.reset();
  FUZZ_CHECK(whole.counters().bytes_skipped + c.frames_ok * kKvh1750FrameSize == stream.size());
  std::vector<GyroFrame> none;
  whole.feed({}, none);
  FUZZ_CHECK(none.empty());
  return 0;
}
