// Fuzzes the ASCII line protocol (drivers/protocol.h, ascii_line.h).
//
// The input first picks AsciiLineOptions (delimiter, prefix, checksum,
// columns with kinds and units, sequence column and modulo, valid bits);
// options that validate_ascii_options refuses must be refused by create()
// too, and end the input. The rest is a script: raw bytes, lines written by
// encode_ascii_line from fuzz values, such lines with one byte changed,
// line ends (CR, LF, CRLF), a line longer than the bound, and chunk
// boundaries. The stream is fed once whole and once in chunks.
// Checked: both give the same frames and counters; counters are consistent
// (frames_ok = frames, no CRC failure without a checksum, gaps <= frames,
// skipped bytes <= stream); unused raw[] slots stay 0 and status values are
// integers. A stream made only of encoded lines parses back to exactly the
// values written (NaN where a valid bit is clear or the value not finite),
// less the lines the sequence rule drops or still holds.
#include <fuzzer/FuzzedDataProvider.h>

#include <cmath>
#include <string>
#include <vector>

#include "fuzz_check.h"
#include "gyrotherm/drivers/ascii_line.h"
#include "gyrotherm/drivers/protocol.h"

using namespace gyrotherm;
using namespace gyrotherm::drivers;

namespace {

bool same(double a, double b) { return (std::isnan(a) && std::isnan(b)) || a == b; }

bool same_counters(const ParserCounters& a, const ParserCounters& b) {
  return a.frames_ok == b.frames_ok && a.crc_failures == b.crc_failures &&
         a.bytes_skipped == b.bytes_skipped && a.sequence_gaps == b.sequence_gaps &&
         a.frames_missed == b.frames_missed && a.sequence_rejects == b.sequence_rejects &&
         a.last_reject == b.last_reject;
}

AsciiColumn column_from(FuzzedDataProvider& in, int i) {
  static const char* const kRateUnits[] = {"deg/h", "deg/s", "rad/s", "deg", "rad", "rpm"};
  static const char* const kAccelUnits[] = {"g", "mg", "m/s^2", "ft/s^2"};
  static const char* const kAxes[] = {"x", "y", "z", "", "w"};
  AsciiColumn c;
  c.name = in.ConsumeBool() ? "c" + std::to_string(i) : (in.ConsumeBool() ? "-" : "c0");
  c.kind = static_cast<ChannelKind>(in.ConsumeIntegralInRange<int>(0, 4));
  switch (c.kind) {
    case ChannelKind::kRate:
      c.unit = kRateUnits[in.ConsumeIntegralInRange<int>(0, 5)];
      break;
    case ChannelKind::kAccel:
      c.unit = kAccelUnits[in.ConsumeIntegralInRange<int>(0, 3)];
      break;
    case ChannelKind::kTemperature:
      c.unit = in.ConsumeBool() ? "degC" : "K";
      break;
    case ChannelKind::kStatus:
      c.unit = in.ConsumeBool() ? "" : "bits";
      break;
    case ChannelKind::kOther:
      c.unit = "V";
      break;
  }
  c.axis = kAxes[in.ConsumeIntegralInRange<int>(0, 4)];
  return c;
}

AsciiLineOptions options_from(FuzzedDataProvider& in) {
  static const char* const kDelims[] = {",", ";", " ", "\t", "whitespace", "|", ",,", "."};
  static const char* const kPrefixes[] = {"", "$GYR,", "#", "$", "G "};
  static const char* const kChecksums[] = {"none", "nmea", "crc16", "md5"};
  AsciiLineOptions o;
  o.delimiter = kDelims[in.ConsumeIntegralInRange<int>(0, 7)];
  o.prefix = kPrefixes[in.ConsumeIntegralInRange<int>(0, 4)];
  o.checksum = kChecksums[in.ConsumeIntegralInRange<int>(0, 3)];
  const int n = in.ConsumeIntegralInRange<int>(0, 8);
  for (int i = 0; i < n; ++i) o.columns.push_back(column_from(in, i));
  if (in.ConsumeBool()) {
    o.seq_column = in.ConsumeIntegralInRange<int>(-1, 8);
    o.seq_modulo = in.ConsumeBool() ? 0 : in.ConsumeIntegralInRange<uint32_t>(1, 300);
  }
  if (in.ConsumeBool()) {
    static const char* const kAxes[] = {"x", "y", "z", "q"};
    o.valid_bits.emplace_back(kAxes[in.ConsumeIntegralInRange<int>(0, 3)],
                              in.ConsumeIntegral<uint8_t>());
  }
  return o;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider in(data, size);
  const AsciiLineOptions o = options_from(in);
  const bool valid = validate_ascii_options(o).ok();
  auto created = AsciiLineProtocol::create(o, 100.0);
  FUZZ_CHECK(created.ok() == valid);
  if (!valid) return 0;
  AsciiLineProtocol& whole = **created;
  const std::vector<ChannelSpec> channels = whole.channels();
  FUZZ_CHECK(!channels.empty() && channels.size() <= kMaxChannels);

  std::string stream;
  std::vector<std::size_t> chunks;
  std::vector<std::vector<double>> written;  // values of each encoded line, in order
  std::vector<uint32_t> written_seq;
  bool clean = true;  // only intact encoded lines so far
  while (in.remaining_bytes() > 0 && stream.size() < 64 * 1024) {
    switch (in.ConsumeIntegralInRange<int>(0, 6)) {
      case 0: {  // raw bytes
        stream += in.ConsumeRandomLengthString(80);
        clean = false;
        break;
      }
      case 1:
      case 2:
      case 3: {  // an encoded line, perhaps with one byte changed
        std::vector<double> v;
        for (const ChannelSpec& c : channels) {
          v.push_back(c.kind == ChannelKind::kStatus ? in.ConsumeIntegral<uint32_t>()
                                                     : in.ConsumeFloatingPoint<double>());
        }
        const auto seq = in.ConsumeIntegral<uint32_t>();
        std::string line = encode_ascii_line(o, v, seq);
        if (in.ConsumeBool() && in.ConsumeBool()) {
          const auto at = in.ConsumeIntegralInRange<std::size_t>(0, line.size() - 1);
          line[at] = static_cast<char>(in.ConsumeIntegral<uint8_t>());
          clean = false;
        } else {
          written.push_back(v);
          written_seq.push_back(o.seq_modulo ? seq % o.seq_modulo : seq);
        }
        stream += line;
        break;
      }
      case 4: {  // a line end of another kind
        static const char* const kEnds[] = {"\r", "\n", "\r\n"};
        stream += kEnds[in.ConsumeIntegralInRange<int>(0, 2)];
        break;
      }
      case 5:  // a line longer than the bound
        stream +=
            std::string(kAsciiMaxLineBytes + in.ConsumeIntegralInRange<std::size_t>(0, 3), 'A');
        clean = false;
        break;
      case 6:
        chunks.push_back(in.ConsumeIntegralInRange<std::size_t>(0, 200));
        break;
    }
  }
  const auto* bytes = reinterpret_cast<const uint8_t*>(stream.data());

  std::vector<DutFrame> whole_frames;
  whole.feed(std::span(bytes, stream.size()), whole_frames);

  auto split_made = AsciiLineProtocol::create(o, 100.0);
  FUZZ_CHECK(split_made.ok());
  AsciiLineProtocol& split = **split_made;
  std::vector<DutFrame> split_frames;
  std::size_t pos = 0;
  for (std::size_t c : chunks) {
    const std::size_t n = std::min(c, stream.size() - pos);
    split.feed(std::span(bytes + pos, n), split_frames);
    pos += n;
  }
  split.feed(std::span(bytes + pos, stream.size() - pos), split_frames);

  const ParserCounters& c = whole.counters();
  FUZZ_CHECK(same_counters(c, split.counters()));
  FUZZ_CHECK(whole_frames.size() == split_frames.size());
  for (std::size_t i = 0; i < whole_frames.size(); ++i) {
    FUZZ_CHECK(whole_frames[i].seq == split_frames[i].seq);
    for (std::size_t k = 0; k < kMaxChannels; ++k) {
      FUZZ_CHECK(same(whole_frames[i].raw[k], split_frames[i].raw[k]));
    }
  }

  FUZZ_CHECK(c.frames_ok == whole_frames.size());
  FUZZ_CHECK(c.bytes_skipped <= stream.size());
  FUZZ_CHECK(c.sequence_gaps <= c.frames_ok);
  FUZZ_CHECK(c.frames_missed >= c.sequence_gaps);
  if (o.checksum == "none") FUZZ_CHECK(c.crc_failures == 0);
  if (!o.seq_column) FUZZ_CHECK(c.sequence_gaps == 0);
  for (const DutFrame& f : whole_frames) {
    if (!o.seq_column) FUZZ_CHECK(f.seq == 0);
    if (o.seq_modulo != 0) FUZZ_CHECK(f.seq < o.seq_modulo);
    for (std::size_t k = channels.size(); k < kMaxChannels; ++k) FUZZ_CHECK(f.raw[k] == 0.0);
    for (std::size_t k = 0; k < channels.size(); ++k) {
      if (channels[k].kind == ChannelKind::kStatus) {
        FUZZ_CHECK(f.raw[k] >= 0 && f.raw[k] <= 4294967295.0 && f.raw[k] == std::floor(f.raw[k]));
      } else {
        FUZZ_CHECK(!std::isinf(f.raw[k]));
      }
    }
  }

  if (clean) {
    // Every encoded line parses back to what was written, less the lines the
    // sequence rule holds back (drivers/sequence_guard.h): with a counter
    // column, a line that does not follow its predecessor waits for the next
    // one and is dropped (sequence_rejects, its bytes skipped) unless that
    // confirms the jump, and the stream's last unconfirmed line may still be
    // waiting. So the frames are the written lines in order, less at most
    // sequence_rejects + 1 of them (exactly none without a counter).
    FUZZ_CHECK(c.crc_failures == 0);
    if (c.sequence_rejects == 0) FUZZ_CHECK(c.bytes_skipped == 0);
    if (o.seq_column) {
      FUZZ_CHECK(whole_frames.size() + c.sequence_rejects <= written.size());
      FUZZ_CHECK(written.size() - whole_frames.size() - c.sequence_rejects <= 1);
    } else {
      FUZZ_CHECK(whole_frames.size() == written.size());
      FUZZ_CHECK(c.sequence_rejects == 0);
    }
    // Whether frame f is written line i, as parsing must give it back.
    auto parsed_from = [&](const DutFrame& f, std::size_t i) {
      if (o.seq_column && f.seq != written_seq[i]) return false;
      uint32_t status = 0;
      for (std::size_t k = 0; k < channels.size(); ++k) {
        if (channels[k].kind == ChannelKind::kStatus) status = static_cast<uint32_t>(written[i][k]);
      }
      for (std::size_t k = 0; k < channels.size(); ++k) {
        double want = std::isfinite(written[i][k]) ? written[i][k] : NAN;
        for (const auto& [axis, mask] : o.valid_bits) {
          if (channels[k].kind == ChannelKind::kRate && channels[k].axis == axis &&
              (status & mask) != mask) {
            want = NAN;
          }
        }
        if (!same(f.raw[k], want)) return false;
      }
      return true;
    };
    std::size_t line = 0;
    for (const DutFrame& f : whole_frames) {
      while (line < written.size() && !parsed_from(f, line)) ++line;
      FUZZ_CHECK(line < written.size());  // a frame no written line gives, or out of order
      ++line;
    }
  }

  // reset() discards the partial tail; afterwards nothing is buffered.
  whole.reset();
  FUZZ_CHECK(whole.counters().bytes_skipped >= c.bytes_skipped);
  std::vector<DutFrame> none;
  whole.feed(std::span<const uint8_t>(), none);
  FUZZ_CHECK(none.empty());
  return 0;
}
