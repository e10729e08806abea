// make_dut_source(): the DutReader through a real pseudo-terminal, for each
// protocol. Conditions are awaited with deadlines; the station clock is a
// ManualClock, so timestamps are exact.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/paced_clock.h"
#include "gyrotherm/drivers/ascii_line.h"
#include "gyrotherm/drivers/dut_link.h"
#include "gyrotherm/drivers/kvh1750.h"
#include "gyrotherm/drivers/pty.h"
#include "test_time.h"

namespace gyrotherm::drivers {
namespace {

using namespace std::chrono_literals;

bool wait_for(const std::function<bool()>& cond, std::chrono::milliseconds limit = 5000ms) {
  return testing::wait_for_condition(cond, limit);
}

Pty open_pty() {
  auto pty = Pty::open(/*nonblocking_master=*/true);
  if (!pty.ok()) {
    ADD_FAILURE() << pty.error().message;
    std::abort();
  }
  return std::move(pty).value();
}

void send(Pty& pty, std::string_view text) {
  const Status s =
      pty.write_master(std::span(reinterpret_cast<const uint8_t*>(text.data()), text.size()));
  ASSERT_TRUE(s.ok()) << s.error().message;
}

class Collector {
 public:
  DutSource::Sink sink() {
    return [this](std::span<const DutFrame> batch) {
      std::lock_guard lock(mu_);
      frames_.insert(frames_.end(), batch.begin(), batch.end());
    };
  }
  std::size_t size() const {
    std::lock_guard lock(mu_);
    return frames_.size();
  }
  std::vector<DutFrame> frames() const {
    std::lock_guard lock(mu_);
    return frames_;
  }

 private:
  mutable std::mutex mu_;
  std::vector<DutFrame> frames_;
};

AsciiColumn ascii_col(std::string name, ChannelKind kind, std::string unit, std::string axis = "") {
  return AsciiColumn{std::move(name), kind, std::move(unit), std::move(axis)};
}

TEST(DutReader, Kvh1750FramesWithEveryChannel) {
  Pty pty = open_pty();
  ManualClock clock(100.0);
  DutLink link;
  link.serial.device = pty.slave_path();
  link.unit = AngleUnit::kDeg;
  link.rate_hz = 10.0;
  auto source = make_dut_source(link, clock);
  ASSERT_TRUE(source.ok()) << source.error().message;
  DutSource& dut = **source;
  ASSERT_EQ(dut.channels().size(), 8u);
  EXPECT_EQ(dut.channels()[2].name, "gyro_z");
  EXPECT_DOUBLE_EQ(dut.channels()[2].scale, 3600.0);  // deg/s -> deg/h
  Collector got;
  dut.start(got.sink());
  ASSERT_TRUE(wait_for([&] { return dut.health().connected; }));

  // Counter 0..4, then 6 (5 lost), then a frame with gyro Y and accel Z invalid.
  std::string bytes;
  for (uint8_t s : {0, 1, 2, 3, 4, 6, 7}) {
    GyroFrame f;
    f.gyro = {0.01f * s, -0.5f, 0.25f};
    f.accel = {0.0f, 0.0f, -1.0f};
    f.status = s == 7 ? 0x35 : 0x77;
    f.seq = s;
    f.temp_c = 30;
    const auto b = encode_kvh1750(f);
    bytes.append(reinterpret_cast<const char*>(b.data()), b.size());
  }
  bytes += "\xFE\x81noise";  // skipped bytes, not a frame
  send(pty, bytes);
  ASSERT_TRUE(wait_for([&] { return got.size() >= 7 && dut.health().parser.bytes_skipped >= 7; }));

  const auto f = got.frames();
  ASSERT_EQ(f.size(), 7u);
  const std::vector<double> t{100.0, 100.1, 100.2, 100.3, 100.4, 100.6, 100.7};
  for (std::size_t i = 0; i < f.size(); ++i) {
    EXPECT_NEAR(f[i].t_s, t[i], 1e-9) << i;
    EXPECT_EQ(f[i].raw[7], 30.0);
  }
  EXPECT_EQ(f[5].seq, 6u);
  EXPECT_EQ(f[5].raw[0], static_cast<double>(0.06f));
  EXPECT_EQ(f[5].raw[5], -1.0);
  EXPECT_TRUE(std::isnan(f[6].raw[1]));  // gyro Y invalid
  EXPECT_TRUE(std::isnan(f[6].raw[5]));  // accel Z invalid
  EXPECT_EQ(f[6].raw[2], 0.25);
  EXPECT_EQ(f[6].raw[6], 0x35);

  const auto h = dut.health();
  EXPECT_EQ(h.samples, 7u);
  EXPECT_EQ(h.invalid_samples, 1u);
  EXPECT_EQ(h.parser.frames_ok, 7u);
  EXPECT_EQ(h.parser.sequence_gaps, 1u);
  EXPECT_EQ(h.parser.frames_missed, 1u);
  EXPECT_EQ(h.parser.bytes_skipped, 7u);
  EXPECT_NEAR(h.last_sample_station_s, 100.7, 1e-9);
  dut.stop();
  dut.stop();  // idempotent
}

TEST(DutReader, AsciiLinesWithACounter) {
  Pty pty = open_pty();
  ManualClock clock(50.0);
  DutLink link;
  link.serial.device = pty.slave_path();
  link.protocol = "ascii";
  link.rate_hz = 100.0;
  AsciiLineOptions& o = link.ascii;
  o.prefix = "$GYR,";
  o.columns = {ascii_col("seq", ChannelKind::kOther, ""),
               ascii_col("gyro_z", ChannelKind::kRate, "deg/s", "z"),
               ascii_col("status", ChannelKind::kStatus, "")};
  o.seq_column = 0;
  o.seq_modulo = 100;
  o.checksum = "crc16";
  o.valid_bits = {{"z", 1}};
  auto source = make_dut_source(link, clock);
  ASSERT_TRUE(source.ok()) << source.error().message;
  DutSource& dut = **source;
  ASSERT_EQ(dut.channels().size(), 2u);
  Collector got;
  dut.start(got.sink());
  ASSERT_TRUE(wait_for([&] { return dut.health().connected; }));

  // Counter 97..99, 0 (wrap), then 3 (1, 2 lost; 4 confirms it); status 0
  // on 3: NaN.
  std::string text;
  const std::vector<uint32_t> seqs{97, 98, 99, 0, 3, 4};
  for (uint32_t s : seqs) {
    const std::vector<double> v{0.5 + s, s == 3 ? 0.0 : 1.0};
    text += encode_ascii_line(o, v, s);
  }
  text += "$GYR,5,1,1*0000\r\n";  // bad CRC
  send(pty, text);
  ASSERT_TRUE(wait_for([&] { return got.size() >= 6 && dut.health().parser.crc_failures >= 1; }));
  const auto f = got.frames();
  ASSERT_EQ(f.size(), 6u);
  const std::vector<double> t{50.0, 50.01, 50.02, 50.03, 50.06, 50.07};
  for (std::size_t i = 0; i < f.size(); ++i) {
    EXPECT_NEAR(f[i].t_s, t[i], 1e-9) << i;
    EXPECT_EQ(f[i].seq, seqs[i]);
  }
  EXPECT_EQ(f[0].raw[0], 97.5);
  EXPECT_TRUE(std::isnan(f[4].raw[0]));
  const auto h = dut.health();
  EXPECT_EQ(h.samples, 6u);
  EXPECT_EQ(h.invalid_samples, 1u);
  EXPECT_EQ(h.parser.sequence_gaps, 1u);
  EXPECT_EQ(h.parser.frames_missed, 2u);
  EXPECT_NE(h.parser.last_reject.find("checksum *0000"), std::string::npos) << h.parser.last_reject;
  dut.stop();
}

// Through a real pty: a line that passes its checksum but repeats the
// previous counter (read as 65 535 lost frames before) is dropped with its
// value; a real loss (13 -> 20, confirmed by 21) keeps its slots and is
// counted missed.
TEST(DutReader, ALineWhoseCounterContradictsItsNeighboursIsNotStored) {
  Pty pty = open_pty();
  ManualClock clock(50.0);
  DutLink link;
  link.serial.device = pty.slave_path();
  link.protocol = "ascii";
  link.rate_hz = 100.0;
  AsciiLineOptions& o = link.ascii;
  o.prefix = "$GYR,";
  o.columns = {ascii_col("seq", ChannelKind::kOther, ""),
               ascii_col("gyro_z", ChannelKind::kRate, "deg/s", "z")};
  o.seq_column = 0;
  o.seq_modulo = 65536;
  o.checksum = "nmea";
  auto source = make_dut_source(link, clock);
  ASSERT_TRUE(source.ok()) << source.error().message;
  DutSource& dut = **source;
  Collector got;
  dut.start(got.sink());
  ASSERT_TRUE(wait_for([&] { return dut.health().connected; }));

  std::string text;
  for (uint32_t s : {10, 11}) text += encode_ascii_line(o, std::vector<double>{0.001}, s);
  text += encode_ascii_line(o, std::vector<double>{0.5}, 11);  // 1800 deg/h, counter repeated
  for (uint32_t s : {12, 13, 20, 21}) text += encode_ascii_line(o, std::vector<double>{0.001}, s);
  send(pty, text);
  ASSERT_TRUE(wait_for([&] { return got.size() >= 6; }));
  const auto f = got.frames();
  ASSERT_EQ(f.size(), 6u);
  const std::vector<uint64_t> seqs{10, 11, 12, 13, 20, 21};
  const std::vector<double> t{50.0, 50.01, 50.02, 50.03, 50.10, 50.11};
  for (std::size_t i = 0; i < f.size(); ++i) {
    EXPECT_EQ(f[i].seq, seqs[i]) << i;
    EXPECT_NEAR(f[i].t_s, t[i], 1e-9) << i;
    EXPECT_EQ(f[i].raw[0], 0.001) << i;
  }
  const auto h = dut.health();
  EXPECT_EQ(h.samples, 6u);
  EXPECT_EQ(h.parser.sequence_rejects, 1u);
  EXPECT_EQ(h.parser.sequence_gaps, 1u);
  EXPECT_EQ(h.parser.frames_missed, 6u);  // 14..19
  EXPECT_NE(h.parser.last_reject.find("counter 11 jumps from 11"), std::string::npos)
      << h.parser.last_reject;
  dut.stop();
}

// Without a counter each line takes the next slot; a stall is found from the
// station clock (the read that empties the line after a silence re-anchors).
TEST(DutReader, AsciiLinesWithoutACounterUseTheClockRule) {
  Pty pty = open_pty();
  ManualClock clock(10.0);
  DutLink link;
  link.serial.device = pty.slave_path();
  link.protocol = "ascii";
  link.rate_hz = 10.0;
  link.ascii.delimiter = "whitespace";
  link.ascii.columns = {ascii_col("rate", ChannelKind::kRate, "deg/h", "z"),
                        ascii_col("temp_c", ChannelKind::kTemperature, "degC")};
  auto source = make_dut_source(link, clock);
  ASSERT_TRUE(source.ok()) << source.error().message;
  DutSource& dut = **source;
  Collector got;
  dut.start(got.sink());
  ASSERT_TRUE(wait_for([&] { return dut.health().connected; }));

  send(pty, "1.0 20\n2.0 20\r\n3.0 20\r");
  ASSERT_TRUE(wait_for([&] { return got.size() >= 3; }));
  clock.set(100.0);
  std::this_thread::sleep_for(200ms);  // a silence on the line: the stimulus, not a wait
  send(pty, "4.0 21\n");
  ASSERT_TRUE(wait_for([&] { return got.size() >= 4; }));
  const auto f = got.frames();
  ASSERT_EQ(f.size(), 4u);
  EXPECT_NEAR(f[0].t_s, 10.0, 1e-9);
  EXPECT_NEAR(f[1].t_s, 10.1, 1e-9);
  EXPECT_NEAR(f[2].t_s, 10.2, 1e-9);
  EXPECT_NEAR(f[3].t_s, 100.0, 1e-9);
  EXPECT_EQ(f[3].raw[0], 4.0);
  EXPECT_EQ(f[3].raw[1], 21.0);
  EXPECT_EQ(f[3].seq, 0u);
  EXPECT_EQ(dut.health().parser.sequence_gaps, 0u);
  dut.stop();
}

// A reader that was stopped (a daemon stalled, on a scaled clock) comes back
// to a backlog the sender writes as the line takes it: the first piece
// empties the line lagging the clock by the whole stall. It is no jump: the
// next piece lags less. Every frame keeps its counter slot (before, the first
// piece realigned the clock and the rest came "ahead" of it, squeezed 1 us
// apart: 9 509 samples in one run).
TEST(DutReader, ABacklogReadInPiecesKeepsItsCounterSlots) {
  Pty pty = open_pty();
  ManualClock clock(100.0);
  DutLink link;
  link.serial.device = pty.slave_path();
  link.protocol = "ascii";
  link.rate_hz = 10.0;
  link.ascii.delimiter = "whitespace";
  link.ascii.columns = {ascii_col("seq", ChannelKind::kOther, ""),
                        ascii_col("rate", ChannelKind::kRate, "deg/h", "z")};
  link.ascii.seq_column = 0;
  link.ascii.seq_modulo = 128;
  auto source = make_dut_source(link, clock);
  ASSERT_TRUE(source.ok()) << source.error().message;
  DutSource& dut = **source;
  Collector got;
  dut.start(got.sink());
  ASSERT_TRUE(wait_for([&] { return dut.health().connected; }));
  // (A counter is taken once the next frame confirms it: frame 1 lets 0 out.)
  send(pty, "0 1.0\n1 1.0\n");
  ASSERT_TRUE(wait_for([&] { return got.size() >= 1; }));
  // Stopped 60 s: 600 frames wait; they come in 6 pieces of 100 (the last
  // one's extra frame confirms frame 600).
  clock.set(160.0);
  for (int piece = 0; piece < 6; ++piece) {
    std::string text;
    for (int i = 2 + 100 * piece; i <= 100 * (piece + 1) + 1; ++i) {
      text += std::to_string(i % 128) + " 1.0\n";
    }
    send(pty, text);
    std::this_thread::sleep_for(30ms);  // the sender's pace: the stimulus, not a wait
  }
  ASSERT_TRUE(wait_for([&] { return got.size() >= 601; })) << got.size();
  const auto f = got.frames();
  ASSERT_GE(f.size(), 601u);
  for (std::size_t i = 0; i < f.size(); ++i) {
    ASSERT_NEAR(f[i].t_s, 100.0 + 0.1 * static_cast<double>(i), 1e-6) << i;
  }
  dut.stop();
}

// An ASCII line of one rate column (°/h, axis z) on `device`.
DutLink rate_line(const std::string& device) {
  DutLink link;
  link.serial.device = device;
  link.protocol = "ascii";
  link.ascii.columns = {ascii_col("rate", ChannelKind::kRate, "deg/h", "z")};
  return link;
}

TEST(DutReader, HangUpIsSurvivedAndTheMissingDeviceNamed) {
  ManualClock clock(0.0);
  DutLink link = rate_line("/dev/gyrotherm-no-such-dut");
  auto source = make_dut_source(link, clock);
  ASSERT_TRUE(source.ok());
  Collector got;
  (*source)->start(got.sink());
  ASSERT_TRUE(wait_for([&] { return !(*source)->health().last_error.empty(); }));
  EXPECT_NE((*source)->health().last_error.find("/dev/gyrotherm-no-such-dut"), std::string::npos);
  const auto t0 = std::chrono::steady_clock::now();
  (*source)->stop();
  EXPECT_LT(std::chrono::steady_clock::now() - t0, testing::scaled(1s));

  Pty pty = open_pty();
  link.serial.device = pty.slave_path();
  auto second = make_dut_source(link, clock);
  ASSERT_TRUE(second.ok());
  (*second)->start(got.sink());
  ASSERT_TRUE(wait_for([&] { return (*second)->health().connected; }));
  send(pty, "1\n");
  ASSERT_TRUE(wait_for([&] { return got.size() >= 1; }));
  pty.close_master();
  ASSERT_TRUE(wait_for([&] {
    const auto h = (*second)->health();
    return !h.connected && h.read_errors >= 1;
  }));
  (*second)->stop();
}

// A simulator's clock as the reader sees it: station time runs on its own
// (ManualClock); the test reads when each consumer slot was let go.
class RecordingPacedClock final : public PacedClock {
 public:
  double now_s() const override { return clock_.now_s(); }
  double time_scale() const override { return 1.0; }
  std::unique_ptr<ClockConsumer> consumer(std::string_view) const override {
    std::lock_guard lock(mu_);
    ++live_;
    return std::make_unique<Slot>(*this);
  }
  bool wait_until(double t_s, std::chrono::nanoseconds) const override {
    return clock_.now_s() >= t_s;
  }
  uint64_t epoch() const override { return 1; }

  int live() const {
    std::lock_guard lock(mu_);
    return live_;
  }
  std::optional<std::chrono::steady_clock::time_point> last_released() const {
    std::lock_guard lock(mu_);
    return last_released_;
  }

 private:
  struct Slot final : ClockConsumer {
    explicit Slot(const RecordingPacedClock& c) : clock(c) {}
    ~Slot() override {
      std::lock_guard lock(clock.mu_);
      --clock.live_;
      clock.last_released_ = std::chrono::steady_clock::now();
    }
    void consumed(double) override {}
    const RecordingPacedClock& clock;
  };
  ManualClock clock_{0.0};
  mutable std::mutex mu_;
  mutable int live_ = 0;
  mutable std::optional<std::chrono::steady_clock::time_point> last_released_;
};

// A reader whose line hung up lets go of the simulator's clock at once, not
// after its backoff (at least 100 ms before it tries the line again): the
// simulated station's time runs on through an outage, as a real one's does,
// so the outage is in the samples' times whatever the wall-clock timing.
TEST(DutReader, AHungUpLineLetsGoOfTheSimulatorsClockBeforeItsBackoff) {
  RecordingPacedClock clock;
  Pty pty = open_pty();
  auto source = make_dut_source(rate_line(pty.slave_path()), clock);
  ASSERT_TRUE(source.ok());
  Collector got;
  (*source)->start(got.sink());
  ASSERT_TRUE(wait_for([&] { return (*source)->health().connected && clock.live() == 1; }));
  send(pty, "1\n2\n");
  ASSERT_TRUE(wait_for([&] { return got.size() >= 1; }));

  pty.close_master();
  std::string hang_up_error;
  ASSERT_TRUE(wait_for([&] {
    const auto h = (*source)->health();
    hang_up_error = h.last_error;
    return !h.connected && h.read_errors >= 1;
  }));
  // The next error is the reopen's (the pty is gone): it comes after the
  // backoff; the slot was let go before the backoff began.
  ASSERT_TRUE(wait_for([&] { return (*source)->health().last_error != hang_up_error; }));
  const auto reopen_seen = std::chrono::steady_clock::now();
  const auto released = clock.last_released();
  ASSERT_TRUE(released.has_value());
  EXPECT_GE(reopen_seen - *released, 90ms)
      << "the slot was held through the backoff; last error: " << (*source)->health().last_error;
  EXPECT_EQ(clock.live(), 0);
  (*source)->stop();
}

TEST(DutReader, BadLinksAreRefusedByName) {
  ManualClock clock;
  DutLink link;
  link.protocol = "ascii";  // no columns
  auto s = make_dut_source(link, clock);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("ascii columns: none given"), std::string::npos);
  link.protocol = "kvh1750";
  link.rate_hz = 0;
  s = make_dut_source(link, clock);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("rate_hz"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm::drivers
