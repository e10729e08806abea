// AsciiLineProtocol (drivers/protocol.h) fed from memory, and the KVH 1750
// protocol's channels with their invalid bits.
//
// Checksums below were computed independently with Python, not with the
// code under test:
//   NMEA:  functools.reduce(operator.xor, LINE[1:])          (the '$' excluded)
//   CRC16: binascii.crc_hqx(LINE, 0xFFFF)                    (CRC-16/CCITT-FALSE)
//   "$GYR,0,0.01,9.80665,25.5,4"    NMEA 4D  CRC16 9273
//   "$GYR,1,-0.02,9.8,26,0x0"       NMEA 33  CRC16 D8A0
//   "$GYR,3,1e-3,-9.80665,27,0x07"  NMEA 54  CRC16 91B2
#include "gyrotherm/drivers/ascii_line.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "gyrotherm/drivers/kvh1750.h"
#include "gyrotherm/drivers/protocol.h"

namespace gyrotherm::drivers {
namespace {

AsciiColumn col(std::string name, ChannelKind kind, std::string unit, std::string axis = "") {
  return AsciiColumn{std::move(name), kind, std::move(unit), std::move(axis)};
}

// $GYR,<seq>,<gyro_z deg/s>,<accel_z m/s^2>,<temp degC>,<status>; gyro z
// valid when status bit 2 is set.
AsciiLineOptions gyr(std::string checksum) {
  AsciiLineOptions o;
  o.prefix = "$GYR,";
  o.columns = {col("seq", ChannelKind::kOther, ""), col("gyro_z", ChannelKind::kRate, "deg/s", "z"),
               col("accel_z", ChannelKind::kAccel, "m/s^2", "z"),
               col("temp_c", ChannelKind::kTemperature, "degC"),
               col("status", ChannelKind::kStatus, "")};
  o.seq_column = 0;
  o.seq_modulo = 256;
  o.checksum = std::move(checksum);
  o.valid_bits = {{"z", 0x4}};
  return o;
}

std::unique_ptr<AsciiLineProtocol> make(const AsciiLineOptions& o, double rate_hz = 100.0) {
  auto p = AsciiLineProtocol::create(o, rate_hz);
  if (!p.ok()) {
    ADD_FAILURE() << p.error().message;
    return nullptr;
  }
  return std::move(p).value();
}

std::vector<DutFrame> feed(DutProtocol& p, std::string_view bytes) {
  std::vector<DutFrame> out;
  p.feed(std::span(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()), out);
  return out;
}

bool same(double a, double b) { return (std::isnan(a) && std::isnan(b)) || a == b; }

void expect_same_frames(const std::vector<DutFrame>& a, const std::vector<DutFrame>& b,
                        const std::string& where) {
  ASSERT_EQ(a.size(), b.size()) << where;
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].seq, b[i].seq) << where << " frame " << i;
    for (std::size_t c = 0; c < kMaxChannels; ++c) {
      EXPECT_TRUE(same(a[i].raw[c], b[i].raw[c])) << where << " frame " << i << " ch " << c;
    }
  }
}

void expect_same_counters(const ParserCounters& a, const ParserCounters& b,
                          const std::string& where) {
  EXPECT_EQ(a.frames_ok, b.frames_ok) << where;
  EXPECT_EQ(a.crc_failures, b.crc_failures) << where;
  EXPECT_EQ(a.bytes_skipped, b.bytes_skipped) << where;
  EXPECT_EQ(a.sequence_gaps, b.sequence_gaps) << where;
  EXPECT_EQ(a.frames_missed, b.frames_missed) << where;
  EXPECT_EQ(a.sequence_rejects, b.sequence_rejects) << where;
  EXPECT_EQ(a.last_reject, b.last_reject) << where;
}

TEST(AsciiLine, NmeaLinesWithValidBitsAndHexStatus) {
  auto p = make(gyr("nmea"));
  ASSERT_TRUE(p);
  EXPECT_EQ(p->seq_modulo(), 256u);
  const auto f = feed(*p,
                      "$GYR,0,0.01,9.80665,25.5,4*4D\r\n"
                      "$GYR,1,-0.02,9.8,26,0x0*33\n"
                      "$GYR,3,1e-3,-9.80665,27,0x07*54\r"
                      "$GYR,4,1e-3,-9.80665,27,0x07*53\r");  // confirms the jump to 3
  ASSERT_EQ(f.size(), 4u);
  // Raw values as sent: deg/s and m/s^2 (channels' scales make deg/h and g).
  EXPECT_EQ(f[0].seq, 0u);
  EXPECT_EQ(f[0].raw[0], 0.01);
  EXPECT_EQ(f[0].raw[1], 9.80665);
  EXPECT_EQ(f[0].raw[2], 25.5);
  EXPECT_EQ(f[0].raw[3], 4.0);
  EXPECT_TRUE(std::isnan(f[1].raw[0]));  // status 0: gyro z flagged invalid
  EXPECT_EQ(f[1].raw[1], 9.8);           // accel has no valid bit configured
  EXPECT_EQ(f[1].raw[3], 0.0);
  EXPECT_EQ(f[2].seq, 3u);
  EXPECT_EQ(f[2].raw[0], 1e-3);
  EXPECT_EQ(f[2].raw[3], 7.0);
  const ParserCounters& c = p->counters();
  EXPECT_EQ(c.frames_ok, 4u);
  EXPECT_EQ(c.sequence_gaps, 1u);  // 1 -> 3
  EXPECT_EQ(c.frames_missed, 1u);
  EXPECT_EQ(c.crc_failures, 0u);
  EXPECT_EQ(c.bytes_skipped, 0u);
  EXPECT_EQ(c.last_reject, "");
  EXPECT_NEAR(p->channels()[0].scale * f[0].raw[0], 36.0, 1e-12);  // 0.01 deg/s = 36 deg/h
}

TEST(AsciiLine, Crc16LinesAndBadChecksums) {
  auto p = make(gyr("crc16"));
  ASSERT_TRUE(p);
  auto f = feed(*p,
                "$GYR,0,0.01,9.80665,25.5,4*9273\r\n"
                "$GYR,1,-0.02,9.8,26,0x0*d8a0\r\n");  // lower-case hex accepted
  ASSERT_EQ(f.size(), 2u);
  // One bit changed in the payload (0.01 -> 0.03): the CRC no longer matches.
  const std::string bad = "$GYR,0,0.03,9.80665,25.5,4*9273";
  f = feed(*p, bad + "\r\n");
  EXPECT_TRUE(f.empty());
  EXPECT_EQ(p->counters().crc_failures, 1u);
  EXPECT_EQ(p->counters().bytes_skipped, bad.size());
  EXPECT_NE(p->counters().last_reject.find("checksum *9273 does not match"), std::string::npos)
      << p->counters().last_reject;
  // An NMEA checksum on a CRC-16 line: not four hex digits (malformed, not a CRC failure).
  f = feed(*p, "$GYR,0,0.01,9.80665,25.5,4*4D\r\n");
  EXPECT_TRUE(f.empty());
  EXPECT_EQ(p->counters().crc_failures, 1u);
  EXPECT_NE(p->counters().last_reject.find("not 4 hex digits"), std::string::npos);
  // No checksum at all.
  f = feed(*p, "$GYR,0,0.01,9.80665,25.5,4\r\n");
  EXPECT_TRUE(f.empty());
  EXPECT_NE(p->counters().last_reject.find("no checksum"), std::string::npos);

  auto n = make(gyr("nmea"));
  ASSERT_TRUE(n);
  f = feed(*n, "$GYR,0,0.01,9.80665,25.5,4*4C\n");  // 4D expected
  EXPECT_TRUE(f.empty());
  EXPECT_EQ(n->counters().crc_failures, 1u);
  EXPECT_NE(n->counters().last_reject.find("*4C does not match the line's 4D"), std::string::npos)
      << n->counters().last_reject;
}

TEST(AsciiLine, MalformedLinesAreCountedWithTheirReason) {
  auto p = make(gyr("none"));
  ASSERT_TRUE(p);
  struct Case {
    std::string line;
    std::string reason;
  };
  const std::vector<Case> cases{
      {"GYR,0,1,2,3,4", "does not start with the prefix '$GYR,'"},
      {"$GYR,0,1,2,3", "4 fields, expected 5"},
      {"$GYR,0,1,2,3,4,5", "6 fields, expected 5"},
      {"$GYR,0,abc,2,3,4", "column 1 'gyro_z': 'abc' is not a number"},
      {"$GYR,0,1,2,3,4.5", "column 4 'status': '4.5' is not a status word"},
      {"$GYR,256,1,2,3,4", "column 0 'seq' (sequence): '256' is not a counter 0..255"},
      {"$GYR,-1,1,2,3,4", "column 0 'seq'"},
      {"$GYR,0,1,,3,4", "column 2 'accel_z': '' is not a number"},
      {"$GYR,0,1,2,3,0xZZ", "column 4 'status'"},
      {std::string("$GYR,0,1\x01,2,3,4"), "'1\\x01' is not a number"},
  };
  uint64_t skipped = 0;
  for (const Case& c : cases) {
    const auto f = feed(*p, c.line + "\n");
    EXPECT_TRUE(f.empty()) << c.line;
    skipped += c.line.size();
    EXPECT_EQ(p->counters().bytes_skipped, skipped) << c.line;
    EXPECT_NE(p->counters().last_reject.find(c.reason), std::string::npos)
        << p->counters().last_reject << " (expected: " << c.reason << ")";
  }
  EXPECT_EQ(p->counters().frames_ok, 0u);
  EXPECT_EQ(p->counters().crc_failures, 0u);
  // Blanks around fields, a '+' sign, and non-finite numbers (NaN) are fine
  // (8 confirms 7, the stream's first).
  const auto f = feed(*p, "$GYR, 7 ,+1.5,\tnan, inf ,0x04\n\n\r\n$GYR,8,1,2,3,4\n");
  ASSERT_EQ(f.size(), 2u);
  EXPECT_EQ(f[0].seq, 7u);
  EXPECT_EQ(f[0].raw[0], 1.5);
  EXPECT_TRUE(std::isnan(f[0].raw[1]));
  EXPECT_TRUE(std::isnan(f[0].raw[2]));
  EXPECT_EQ(p->counters().bytes_skipped, skipped);  // empty lines are not skipped bytes
}

TEST(AsciiLine, WhitespaceDelimiterSkippedColumnsAndNoCounter) {
  AsciiLineOptions o;
  o.delimiter = "whitespace";
  o.columns = {col("-", ChannelKind::kOther, ""), col("gx", ChannelKind::kRate, "rad", "x"),
               col("gy", ChannelKind::kRate, "deg/h", "y"),
               col("t", ChannelKind::kTemperature, "degC")};
  auto p = make(o, 200.0);
  ASSERT_TRUE(p);
  EXPECT_EQ(p->seq_modulo(), 0u);
  ASSERT_EQ(p->channels().size(), 3u);
  const auto f = feed(*p, "  12:00:01   1e-6\t-3.25  20 \r\nTIME 2e-6 -3.5 21\n");
  ASSERT_EQ(f.size(), 2u);
  EXPECT_EQ(f[0].seq, 0u);
  EXPECT_EQ(f[0].raw[0], 1e-6);
  EXPECT_EQ(f[0].raw[1], -3.25);
  EXPECT_EQ(f[0].raw[2], 20.0);
  EXPECT_EQ(f[1].raw[0], 2e-6);
  // rad per sample at 200 Hz: 1e-6 rad x 200 /s = 2e-4 rad/s = 41.2529612 deg/h
  EXPECT_NEAR(p->channels()[0].scale * f[0].raw[0], 41.252961249419, 1e-9);
  EXPECT_EQ(p->counters().sequence_gaps, 0u);

  // Semicolons, tab delimiter: empty fields are refused (not merged).
  o.delimiter = "\t";
  auto t = make(o);
  ASSERT_TRUE(t);
  EXPECT_EQ(feed(*t, "x\t1\t2\t3\n").size(), 1u);
  EXPECT_TRUE(feed(*t, "x\t1\t\t2\t3\n").empty());
  EXPECT_NE(t->counters().last_reject.find("5 fields, expected 4"), std::string::npos);
}

TEST(AsciiLine, CounterWrapsAtItsModuloOrAt2To32) {
  AsciiLineOptions o;
  o.columns = {col("n", ChannelKind::kOther, ""), col("r", ChannelKind::kRate, "deg/h", "z")};
  o.seq_column = 0;
  o.seq_modulo = 256;
  auto p = make(o);
  ASSERT_TRUE(p);
  EXPECT_EQ(feed(*p, "254,1\n255,1\n0,1\n3,1\n4,1\n").size(), 5u);
  EXPECT_EQ(p->counters().sequence_gaps, 1u);
  EXPECT_EQ(p->counters().frames_missed, 2u);  // 1 and 2
  p->reset();                                  // a new stream: its first counter is no gap
  EXPECT_EQ(feed(*p, "100,1\n101,1\n").size(), 2u);
  EXPECT_EQ(p->counters().sequence_gaps, 1u);

  o.seq_modulo = 0;  // a 32-bit counter
  auto q = make(o);
  ASSERT_TRUE(q);
  EXPECT_EQ(q->seq_modulo(), uint64_t{1} << 32);
  const auto f = feed(*q, "4294967295,1\n0,1\n4294967296,1\n");
  ASSERT_EQ(f.size(), 2u);
  EXPECT_EQ(f[0].seq, 4294967295u);
  EXPECT_EQ(q->counters().sequence_gaps, 0u);
  EXPECT_NE(q->counters().last_reject.find("not a counter"), std::string::npos);
}

// A line that passes the 8-bit NMEA checksum by chance (1 in 256) but whose
// counter contradicts both neighbours is dropped: neither its value (0.5
// deg/s, 1800 deg/h) is emitted nor its jump counted as missed frames (the
// repeated counter 1 read as 65535 lost frames before). Checksums by Python.
TEST(AsciiLine, AForgedLineBetweenGoodOnesIsDroppedNotCountedAsMissed) {
  AsciiLineOptions o = gyr("nmea");
  o.seq_modulo = 65536;
  auto p = make(o);
  ASSERT_TRUE(p);
  const std::string forged_repeat = "$GYR,1,0.5,9.8,25,4*66";
  const std::string forged_wild = "$GYR,40000,0.5,9.8,25,4*63";
  const auto f = feed(*p,
                      "$GYR,65534,0.001,9.8,25,4*62\r\n"
                      "$GYR,65535,0.001,9.8,25,4*63\r\n"
                      "$GYR,0,0.001,9.8,25,4*63\r\n"
                      "$GYR,1,0.001,9.8,25,4*62\r\n" +
                          forged_repeat + "\r\n" + "$GYR,2,0.001,9.8,25,4*61\r\n" + forged_wild +
                          "\r\n" + "$GYR,3,0.001,9.8,25,4*60\r\n");
  ASSERT_EQ(f.size(), 6u) << p->counters().last_reject;
  const std::vector<uint64_t> seqs{65534, 65535, 0, 1, 2, 3};
  for (std::size_t i = 0; i < f.size(); ++i) {
    EXPECT_EQ(f[i].seq, seqs[i]) << i;
    EXPECT_EQ(f[i].raw[0], 0.001) << i;
  }
  const ParserCounters& c = p->counters();
  EXPECT_EQ(c.frames_ok, 6u);
  EXPECT_EQ(c.sequence_rejects, 2u);
  EXPECT_EQ(c.sequence_gaps, 0u);
  EXPECT_EQ(c.frames_missed, 0u);
  EXPECT_EQ(c.crc_failures, 0u);
  EXPECT_EQ(c.bytes_skipped, forged_repeat.size() + forged_wild.size());
  EXPECT_NE(c.last_reject.find(forged_wild), std::string::npos) << c.last_reject;
  EXPECT_NE(c.last_reject.find("counter 40000 jumps from 2"), std::string::npos) << c.last_reject;
}

// A real loss: the line after the jump continues from it, so the jump is
// taken and the skipped counters are counted missed. The jumping line waits
// for that confirmation; two jumps in a row confirm each other in order.
TEST(AsciiLine, AJumpConfirmedByTheNextLineCountsTheFramesBetweenAsMissed) {
  AsciiLineOptions o = gyr("nmea");
  auto p = make(o);
  ASSERT_TRUE(p);
  auto f = feed(*p,
                "$GYR,1,0.001,9.8,25,4*62\n"
                "$GYR,2,0.001,9.8,25,4*61\n"
                "$GYR,9,0.001,9.8,25,4*6A\n");
  ASSERT_EQ(f.size(), 2u);  // 9 waits for the next line
  EXPECT_EQ(p->counters().frames_missed, 0u);
  f = feed(*p, "$GYR,10,0.001,9.8,25,4*52\n");
  ASSERT_EQ(f.size(), 2u);
  EXPECT_EQ(f[0].seq, 9u);
  EXPECT_EQ(f[1].seq, 10u);
  EXPECT_EQ(p->counters().sequence_gaps, 1u);
  EXPECT_EQ(p->counters().frames_missed, 6u);  // 3..8

  // 10 -> 15 -> 16 after a gap confirmed by 15 itself: 11..14 lost.
  f = feed(*p,
           "$GYR,15,0.001,9.8,25,4*57\n"
           "$GYR,16,0.001,9.8,25,4*54\n");
  ASSERT_EQ(f.size(), 2u);
  EXPECT_EQ(p->counters().sequence_gaps, 2u);
  EXPECT_EQ(p->counters().frames_missed, 6u + 4u);

  // Two jumps in a row (2 -> 9 -> 15, then 16): both real, in order.
  auto q = make(o);
  ASSERT_TRUE(q);
  f = feed(*q,
           "$GYR,1,0.001,9.8,25,4*62\n"
           "$GYR,2,0.001,9.8,25,4*61\n"
           "$GYR,9,0.001,9.8,25,4*6A\n"
           "$GYR,15,0.001,9.8,25,4*57\n"
           "$GYR,16,0.001,9.8,25,4*54\n");
  ASSERT_EQ(f.size(), 5u);
  EXPECT_EQ(q->counters().sequence_gaps, 2u);
  EXPECT_EQ(q->counters().frames_missed, 6u + 5u);
  EXPECT_EQ(q->counters().sequence_rejects, 0u);
}

// A jump still waiting for its confirmation when the port is reopened was
// never confirmed: dropped, and the new stream's first line anchors anew.
TEST(AsciiLine, AnUnconfirmedJumpIsDroppedAtReopen) {
  auto p = make(gyr("nmea"));
  ASSERT_TRUE(p);
  EXPECT_EQ(feed(*p,
                 "$GYR,1,0.001,9.8,25,4*62\n"
                 "$GYR,2,0.001,9.8,25,4*61\n"
                 "$GYR,9,0.001,9.8,25,4*6A\n")
                .size(),
            2u);
  p->reset();
  const ParserCounters& c = p->counters();
  EXPECT_EQ(c.sequence_rejects, 1u);
  EXPECT_EQ(c.frames_missed, 0u);
  EXPECT_NE(c.last_reject.find("reopened"), std::string::npos) << c.last_reject;
  EXPECT_EQ(c.bytes_skipped, std::string("$GYR,9,0.001,9.8,25,4*6A").size());
  EXPECT_EQ(feed(*p,
                 "$GYR,15,0.001,9.8,25,4*57\n"
                 "$GYR,16,0.001,9.8,25,4*54\n")
                .size(),
            2u);
  EXPECT_EQ(c.sequence_gaps, 0u);
}

// The same stream, with every line end (CR, LF, CRLF), garbage, bad
// checksums and a too-long line, split in two at every byte boundary and fed
// byte by byte: the same frames and counters as fed whole.
TEST(AsciiLine, SplitAtEveryByteBoundaryGivesTheSameResult) {
  const AsciiLineOptions o = gyr("nmea");
  std::string stream =
      "\x01\x02garbage\xFF\r\n"
      "$GYR,0,0.01,9.80665,25.5,4*4D\r\n"
      "$GYR,1,-0.02,9.8,26,0x0*33\n"
      "$GYR,1,-0.02,9.8,26,0x0*34\r"  // bad checksum
      "$GYR,3,1e-3,-9.80665,27,0x07*54\r\n"
      "$GYR,3,1e-3,";
  stream += std::string(5000, 'A');  // too long: dropped to its end
  stream += "\n$GYR,0,0.01,9.80665,25.5,4*4D\n$GYR,1,-0.02,9.8,26,0x0*33\n";
  stream += "$GYR,1,-0.02";  // partial tail

  auto whole = make(o);
  ASSERT_TRUE(whole);
  const auto expected = feed(*whole, stream);
  ASSERT_EQ(expected.size(), 5u);
  const ParserCounters& c = whole->counters();
  EXPECT_EQ(c.frames_ok, 5u);
  EXPECT_EQ(c.crc_failures, 1u);
  EXPECT_EQ(c.sequence_gaps, 2u);  // 1 -> 3, 3 -> 0
  // garbage (10) + bad line (26) + the long line (12 + 5000)
  EXPECT_EQ(c.bytes_skipped, 10u + 26u + 12u + 5000u);
  EXPECT_NE(c.last_reject.find("longer than 4096 bytes"), std::string::npos);

  for (std::size_t k = 0; k <= stream.size(); k += (k < 300 || k > 5100 ? 1 : 97)) {
    auto split = make(o);
    std::vector<DutFrame> got = feed(*split, std::string_view(stream).substr(0, k));
    const auto rest = feed(*split, std::string_view(stream).substr(k));
    got.insert(got.end(), rest.begin(), rest.end());
    const std::string where = "split at " + std::to_string(k);
    expect_same_frames(expected, got, where);
    expect_same_counters(c, split->counters(), where);
    if (HasFailure()) return;
  }
  auto bytewise = make(o);
  std::vector<DutFrame> got;
  for (char ch : stream) {
    const auto f = feed(*bytewise, std::string_view(&ch, 1));
    got.insert(got.end(), f.begin(), f.end());
  }
  expect_same_frames(expected, got, "byte by byte");
  expect_same_counters(c, bytewise->counters(), "byte by byte");

  // reset() discards the partial tail ("$GYR,1,-0.02": 12 bytes).
  whole->reset();
  EXPECT_EQ(whole->counters().bytes_skipped, c.bytes_skipped);  // c is a reference
  EXPECT_EQ(whole->counters().bytes_skipped, 10u + 26u + 12u + 5000u + 12u);
}

TEST(AsciiLine, EncodedLinesParseBackExactly) {
  for (const std::string checksum : {"none", "nmea", "crc16"}) {
    AsciiLineOptions o = gyr(checksum);
    auto p = make(o);
    ASSERT_TRUE(p);
    std::string stream;
    std::vector<std::vector<double>> sent;
    for (uint32_t i = 0; i < 300; ++i) {
      const std::vector<double> v{0.1 * i - 7.3, 9.80665 + 1e-9 * i, 20.0 + i / 3.0, double(i % 8)};
      sent.push_back(v);
      stream += encode_ascii_line(o, v, i);
    }
    const auto f = feed(*p, stream);
    ASSERT_EQ(f.size(), 300u) << checksum << ": " << p->counters().last_reject;
    for (uint32_t i = 0; i < 300; ++i) {
      EXPECT_EQ(f[i].seq, i % 256);
      for (std::size_t c = 0; c < 4; ++c) {
        // gyro_z is NaN where status bit 2 (valid) is clear.
        const double want = (c == 0 && !(i % 8 & 4)) ? std::nan("") : sent[i][c];
        EXPECT_TRUE(same(f[i].raw[c], want)) << checksum << " line " << i << " ch " << c;
      }
    }
    EXPECT_EQ(p->counters().sequence_gaps, 0u);  // 255 -> 0 is the wrap
  }
}

TEST(Kvh1750Protocol, ChannelsWithInvalidBitsAsNaN) {
  DutLink link;
  link.rate_hz = 1000.0;
  auto made = make_dut_protocol(link);
  ASSERT_TRUE(made.ok()) << made.error().message;
  DutProtocol& p = **made;
  EXPECT_EQ(p.seq_modulo(), 128u);
  ASSERT_EQ(p.channels().size(), 8u);

  GyroFrame g;
  g.gyro = {1e-4f, -2e-4f, 3e-4f};
  g.accel = {0.01f, -0.02f, 1.0f};
  g.status = 0x35;  // gyro X, Z valid (bits 0, 2); accel X, Y valid (bits 4, 5)
  g.seq = 127;
  g.temp_c = -12;
  const auto bytes = encode_kvh1750(g);
  std::vector<DutFrame> out;
  p.feed(bytes, out);
  g.seq = 0;
  g.status = 0x77;
  const auto bytes2 = encode_kvh1750(g);
  p.feed(bytes2, out);
  ASSERT_EQ(out.size(), 2u);
  const DutFrame& f = out[0];
  EXPECT_EQ(f.seq, 127u);
  EXPECT_EQ(f.raw[0], static_cast<double>(1e-4f));
  EXPECT_TRUE(std::isnan(f.raw[1]));
  EXPECT_EQ(f.raw[2], static_cast<double>(3e-4f));
  EXPECT_EQ(f.raw[3], static_cast<double>(0.01f));
  EXPECT_EQ(f.raw[4], static_cast<double>(-0.02f));
  EXPECT_TRUE(std::isnan(f.raw[5]));
  EXPECT_EQ(f.raw[6], 0x35);
  EXPECT_EQ(f.raw[7], -12.0);
  for (std::size_t c = 0; c < 6; ++c) EXPECT_FALSE(std::isnan(out[1].raw[c])) << c;
  EXPECT_EQ(p.counters().sequence_gaps, 0u);  // 127 -> 0 wraps
  // 1e-4 rad/s in deg/h: 1e-4 * 180/pi * 3600 = 20.6264806 (float32 input)
  EXPECT_NEAR(p.channels()[0].scale * f.raw[0], 20.6264806, 1e-5);
}

}  // namespace
}  // namespace gyrotherm::drivers

namespace gyrotherm::drivers {
namespace {

// docs/devices.md's example line and options. CRC computed with Python:
// binascii.crc_hqx(b"$GYR,17,0.00421,-0.0012,9.80712,24.75,0x07", 0xFFFF) == 0x5498
TEST(AsciiLine, TheDocumentedExampleParses) {
  AsciiLineOptions o;
  o.prefix = "$GYR,";
  o.checksum = "crc16";
  o.seq_column = 0;
  o.seq_modulo = 10000;
  o.columns = {col("seq", ChannelKind::kOther, ""),
               col("gyro_x", ChannelKind::kRate, "deg/s", "x"),
               col("gyro_y", ChannelKind::kRate, "deg/s", "y"),
               col("accel_z", ChannelKind::kAccel, "m/s^2", "z"),
               col("temp_c", ChannelKind::kTemperature, "degC"),
               col("status", ChannelKind::kStatus, "")};
  o.valid_bits = {{"x", 1}, {"y", 2}};
  auto p = make(o, 200.0);
  ASSERT_TRUE(p);
  // The next line (18, CRC by Python: D076) confirms the stream's first.
  const auto f = feed(*p,
                      "$GYR,17,0.00421,-0.0012,9.80712,24.75,0x07*5498\r\n"
                      "$GYR,18,0.00421,-0.0012,9.80712,24.75,0x07*D076\r\n");
  ASSERT_EQ(f.size(), 2u) << p->counters().last_reject;
  EXPECT_EQ(f[0].seq, 17u);
  EXPECT_EQ(f[0].raw[0], 0.00421);
  EXPECT_EQ(f[0].raw[1], -0.0012);
  EXPECT_EQ(f[0].raw[4], 7.0);
  EXPECT_NEAR(p->channels()[0].scale * f[0].raw[0], 15.156, 1e-12);  // 0.00421 deg/s in deg/h
}

}  // namespace
}  // namespace gyrotherm::drivers
