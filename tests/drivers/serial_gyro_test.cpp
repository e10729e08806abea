// SerialPort and GyroReader through real pseudo-terminals.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/drivers/kvh1750.h"
#include "gyrotherm/drivers/pty.h"
#include "gyrotherm/drivers/serial_port.h"
#include "test_time.h"

namespace gyrotherm::drivers {
namespace {

using namespace std::chrono_literals;

// Polls `cond` until it holds or 5 s (wall, stretched by
// GYROTHERM_TEST_TIME_FACTOR) pass.
bool wait_for_gyro(const std::function<bool()>& cond, std::chrono::milliseconds limit = 5000ms) {
  return testing::wait_for_condition(cond, limit);
}

Pty open_gyro_pty() {
  auto pty = Pty::open(/*nonblocking_master=*/true);
  if (!pty.ok()) {
    ADD_FAILURE() << pty.error().message;
    std::abort();
  }
  return std::move(pty).value();
}

GyroFrame frame(uint8_t seq, float z, uint8_t status = 0x77) {
  GyroFrame f;
  f.gyro = {0.5f, -0.5f, z};
  f.accel = {0.0f, 0.0f, -1.0f};
  f.status = status;
  f.seq = seq;
  f.temp_c = 25;
  return f;
}

void send(Pty& pty, const GyroFrame& f) {
  const auto bytes = encode_kvh1750(f);
  const Status s = pty.write_master(bytes);
  ASSERT_TRUE(s.ok()) << s.error().message;
}

// Collects what the reader's sink receives.
class GyroCollector {
 public:
  GyroReader::Sink sink() {
    return [this](std::span<const GyroSample> batch) {
      std::lock_guard lock(mu_);
      samples_.insert(samples_.end(), batch.begin(), batch.end());
    };
  }
  std::size_t size() const {
    std::lock_guard lock(mu_);
    return samples_.size();
  }
  std::vector<GyroSample> samples() const {
    std::lock_guard lock(mu_);
    return samples_;
  }

 private:
  mutable std::mutex mu_;
  std::vector<GyroSample> samples_;
};

class TempDir {
 public:
  TempDir() {
    std::string tmpl = (std::filesystem::temp_directory_path() / "gyrotherm-XXXXXX").string();
    path_ = ::mkdtemp(tmpl.data()) ? tmpl : "";
  }
  ~TempDir() {
    if (!path_.empty()) std::filesystem::remove_all(path_);
  }
  std::filesystem::path path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// Atomically points `link` at `target`.
void point_symlink(const std::filesystem::path& link, const std::string& target) {
  const auto tmp = link.string() + ".new";
  std::filesystem::remove(tmp);
  std::filesystem::create_symlink(target, tmp);
  std::filesystem::rename(tmp, link);
}

TEST(ToRateDph, Conversions) {
  GyroFormat f;
  f.unit = AngleUnit::kDeg;
  f.kind = OutputKind::kRate;
  EXPECT_DOUBLE_EQ(to_rate_dph(0.25f, f), 900.0);  // 0.25 °/s
  f.unit = AngleUnit::kRad;
  EXPECT_NEAR(to_rate_dph(1.0f, f), 180.0 / M_PI * 3600.0, 1e-9);
  f.kind = OutputKind::kDeltaAngle;
  f.unit = AngleUnit::kDeg;
  f.rate_hz = 100;
  EXPECT_NEAR(to_rate_dph(0.001f, f), 360.0, 1e-4);  // 1 m° per 10 ms sample = 0.1 °/s
  f.unit = AngleUnit::kRad;
  f.rate_hz = 1000;
  EXPECT_NEAR(to_rate_dph(1e-6f, f), 1e-3 * 180.0 / M_PI * 3600.0, 1e-6);
}

TEST(SerialPort, ReadsAndWritesThroughAPty) {
  Pty pty = open_gyro_pty();
  auto port = SerialPort::open({pty.slave_path(), 921600, Parity::kNone});
  ASSERT_TRUE(port.ok()) << port.error().message;

  std::array<uint8_t, 64> buf{};
  auto none = port->read(buf, 10ms);
  ASSERT_TRUE(none.ok());
  EXPECT_EQ(*none, 0u);

  // Bytes a cooked line discipline would translate or swallow.
  const std::vector<uint8_t> raw = {0x0D, 0x0A, 0x03, 0x11, 0x13, 0x7F, 0x00, 0xFF};
  ASSERT_TRUE(pty.write_master(raw).ok());
  std::vector<uint8_t> got;
  ASSERT_TRUE(wait_for_gyro([&] {
    auto n = port->read(buf, 20ms);
    if (n.ok()) got.insert(got.end(), buf.begin(), buf.begin() + *n);
    return got.size() >= raw.size();
  }));
  EXPECT_EQ(got, raw);

  ASSERT_TRUE(port->write(raw).ok());
  std::vector<uint8_t> back;
  ASSERT_TRUE(wait_for_gyro([&] {
    const ssize_t n = ::read(pty.master_fd(), buf.data(), buf.size());
    if (n > 0) back.insert(back.end(), buf.begin(), buf.begin() + n);
    return back.size() >= raw.size();
  }));
  EXPECT_EQ(back, raw);
}

TEST(SerialPort, OpenErrors) {
  auto missing = SerialPort::open({"/dev/gyrotherm-no-such-tty", 921600, Parity::kNone});
  ASSERT_FALSE(missing.ok());
  EXPECT_TRUE(missing.error().transient);
  EXPECT_NE(missing.error().message.find("/dev/gyrotherm-no-such-tty"), std::string::npos);

  Pty pty = open_gyro_pty();
  auto bad_baud = SerialPort::open({pty.slave_path(), 12345, Parity::kNone});
  ASSERT_FALSE(bad_baud.ok());
  EXPECT_FALSE(bad_baud.error().transient);
  EXPECT_NE(bad_baud.error().message.find("12345"), std::string::npos);

  EXPECT_TRUE(SerialPort::open({pty.slave_path(), 19200, Parity::kEven}).ok());
  EXPECT_EQ(*parse_parity("odd"), Parity::kOdd);
  EXPECT_FALSE(parse_parity("mark").ok());
}

// Issue 15 item 13: a second reader of the gyro line took frames from the
// daemon's. The line is held exclusively; the holder's close frees it.
TEST(SerialPort, OneHolderPerLine) {
  Pty pty = open_gyro_pty();
  std::optional<SerialPort> first;
  {
    auto port = SerialPort::open({pty.slave_path(), 921600, Parity::kNone});
    ASSERT_TRUE(port.ok()) << port.error().message;
    first.emplace(std::move(*port));
  }
  auto second = SerialPort::open({pty.slave_path(), 921600, Parity::kNone});
  ASSERT_FALSE(second.ok()) << "a second reader opened the line";
  EXPECT_TRUE(second.error().transient);
  EXPECT_TRUE(serial_line_in_use(second.error())) << second.error().message;
  EXPECT_NE(second.error().message.find(pty.slave_path()), std::string::npos);

  first.reset();
  auto third = SerialPort::open({pty.slave_path(), 921600, Parity::kNone});
  EXPECT_TRUE(third.ok()) << third.error().message;
}

TEST(SerialPort, HangUpIsATransientError) {
  Pty pty = open_gyro_pty();
  auto port = SerialPort::open({pty.slave_path(), 921600, Parity::kNone});
  ASSERT_TRUE(port.ok());
  pty.close_master();
  std::array<uint8_t, 64> buf{};
  Result<std::size_t> r = std::size_t{0};
  ASSERT_TRUE(wait_for_gyro([&] {
    r = port->read(buf, 20ms);
    return !r.ok();
  }));
  EXPECT_TRUE(r.error().transient);
  EXPECT_NE(r.error().message.find("hang-up"), std::string::npos) << r.error().message;
}

GyroFormat deg_rate_10hz() {
  GyroFormat f;
  f.unit = AngleUnit::kDeg;
  f.kind = OutputKind::kRate;
  f.axis = 2;
  f.rate_hz = 10.0;
  return f;
}

TEST(GyroReader, TimestampsFromTheSampleCounter) {
  Pty pty = open_gyro_pty();
  ManualClock clock(100.0);
  GyroCollector got;
  auto parser = make_frame_parser("kvh1750");
  ASSERT_TRUE(parser.ok());
  GyroReader reader({pty.slave_path(), 921600, Parity::kNone}, deg_rate_10hz(),
                    std::move(parser).value(), clock, got.sink());
  reader.start();
  ASSERT_TRUE(wait_for_gyro([&] { return reader.health().connected; }));

  // 0.01 °/s = 36 °/h. Sequence 0..9, then 11 (10 lost), then an invalid Z.
  for (uint8_t s = 0; s < 10; ++s) send(pty, frame(s, 0.01f));
  send(pty, frame(11, 0.02f));
  send(pty, frame(12, 0.03f, /*status=*/0x73));  // Z gyro invalid
  send(pty, frame(13, 0.04f, /*status=*/0x04));  // only Z valid
  ASSERT_TRUE(
      wait_for_gyro([&] { return got.size() >= 12 && reader.health().invalid_samples >= 1; }));

  const auto s = got.samples();
  ASSERT_EQ(s.size(), 12u);
  for (int i = 0; i < 10; ++i) {
    EXPECT_NEAR(s[i].t_s, 100.0 + 0.1 * i, 1e-9) << i;
    EXPECT_NEAR(s[i].rate_dph, 36.0, 1e-3);
    EXPECT_EQ(s[i].seq, i);
    EXPECT_EQ(s[i].temp_c, 25);
  }
  EXPECT_NEAR(s[10].t_s, 101.1, 1e-9);  // the lost frame keeps its slot
  EXPECT_NEAR(s[10].rate_dph, 72.0, 1e-3);
  EXPECT_NEAR(s[11].t_s, 101.3, 1e-9);
  EXPECT_NEAR(s[11].rate_dph, 144.0, 1e-3);
  EXPECT_EQ(s[11].status, 0x04);

  // Stream stalled for a long time: the next frame, after a silence on the
  // line (the stimulus: 200 ms of wall time without data), re-anchors on the
  // clock.
  clock.set(500.0);
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  send(pty, frame(14, 0.01f));
  ASSERT_TRUE(wait_for_gyro([&] { return got.size() >= 13; }));
  EXPECT_NEAR(got.samples()[12].t_s, 500.0, 1e-9);

  const GyroReaderHealth h = reader.health();
  EXPECT_TRUE(h.connected);
  EXPECT_EQ(h.samples, 13u);
  EXPECT_EQ(h.invalid_samples, 1u);
  EXPECT_EQ(h.parser.frames_ok, 14u);
  EXPECT_EQ(h.parser.sequence_gaps, 1u);
  EXPECT_EQ(h.parser.frames_missed, 1u);
  EXPECT_EQ(h.parser.crc_failures, 0u);
  EXPECT_DOUBLE_EQ(h.last_sample_station_s, 500.0);
  EXPECT_EQ(h.reopens, 0u);
  reader.stop();
  reader.stop();  // idempotent
}

TEST(GyroReader, SurvivesHangUpAndReopensThroughASymlink) {
  TempDir dir;
  ASSERT_FALSE(dir.path().empty());
  const auto link = dir.path() / "gyro";
  Pty first = open_gyro_pty();
  point_symlink(link, first.slave_path());

  ManualClock clock(10.0);
  GyroCollector got;
  GyroReader reader({link.string(), 921600, Parity::kNone}, deg_rate_10hz(),
                    std::make_unique<Kvh1750Parser>(), clock, got.sink());
  reader.start();
  ASSERT_TRUE(wait_for_gyro([&] { return reader.health().connected; }));
  send(first, frame(0, 0.01f));
  send(first, frame(1, 0.01f));
  ASSERT_TRUE(wait_for_gyro([&] { return got.size() >= 2; }));

  first.close_master();
  ASSERT_TRUE(wait_for_gyro([&] {
    const auto h = reader.health();
    return !h.connected && h.read_errors >= 1;
  }));
  EXPECT_FALSE(reader.health().last_error.empty());

  Pty second = open_gyro_pty();
  point_symlink(link, second.slave_path());
  ASSERT_TRUE(wait_for_gyro([&] {
    const auto h = reader.health();
    return h.connected && h.reopens >= 1;
  }));

  // A new stream: its counter starts anywhere and is not a gap after reopen.
  clock.set(20.0);
  send(second, frame(90, 0.02f));
  send(second, frame(91, 0.02f));
  ASSERT_TRUE(wait_for_gyro([&] { return got.size() >= 4; }));
  const auto s = got.samples();
  EXPECT_NEAR(s[2].t_s, 20.0, 1e-9);
  EXPECT_NEAR(s[3].t_s, 20.1, 1e-9);
  EXPECT_NEAR(s[3].rate_dph, 72.0, 1e-3);
  const auto h = reader.health();
  EXPECT_EQ(h.parser.sequence_gaps, 0u);
  EXPECT_EQ(h.samples, 4u);
}

TEST(GyroReader, MissingDeviceKeepsRetryingAndStopsPromptly) {
  ManualClock clock;
  GyroCollector got;
  GyroReader reader({"/dev/gyrotherm-no-such-tty", 921600, Parity::kNone}, deg_rate_10hz(),
                    std::make_unique<Kvh1750Parser>(), clock, got.sink());
  reader.start();
  ASSERT_TRUE(wait_for_gyro([&] { return !reader.health().last_error.empty(); }));
  const auto h = reader.health();
  EXPECT_FALSE(h.connected);
  EXPECT_NE(h.last_error.find("/dev/gyrotherm-no-such-tty"), std::string::npos);
  const auto t0 = std::chrono::steady_clock::now();
  reader.stop();
  EXPECT_LT(std::chrono::steady_clock::now() - t0, testing::scaled(1s));
}

}  // namespace
}  // namespace gyrotherm::drivers

namespace gyrotherm::drivers {
namespace {

// 10 Hz, tolerance 2 s.
TEST(SampleClock, BacklogReadBackToBackKeepsTheSampleClock) {
  SampleClock c(10.0, 2.0);
  EXPECT_DOUBLE_EQ(c.stamp(0, 100.0), 100.0);
  // 300 frames generated over 30 s arrive late, back to back, while the
  // station clock already reads 130 s: no re-anchoring inside the backlog.
  double prev = 100.0;
  for (int i = 1; i <= 300; ++i) {
    const double t = c.stamp(i % 128, 130.0);
    EXPECT_NEAR(t, 100.0 + 0.1 * i, 1e-9) << i;
    EXPECT_GT(t, prev);
    prev = t;
  }
  // The read that empties the line ends with a fresh frame: on time.
  EXPECT_DOUBLE_EQ(c.realign(130.05), 0.0);
}

// A reader stopped (SIGSTOP, or descheduled on a loaded machine) for longer
// than the tolerance comes back to a backlog. Its first frame after the pause
// lags the clock by the whole pause, yet it is no stall: the counter places
// every frame, and nothing moves (before, the first frame after a silent
// read was re-anchored to the clock, leaving a hole as long as the backlog).
TEST(SampleClock, ABacklogAfterTheReaderWasStoppedKeepsItsSlots) {
  SampleClock c(10.0, 2.0);
  c.stamp(0, 100.0);
  c.stamp(1, 100.1);
  EXPECT_DOUBLE_EQ(c.realign(100.1), 0.0);
  // Stopped 60 s; the line holds 600 frames, read 113 at a time.
  for (int i = 2; i <= 601; ++i) {
    EXPECT_NEAR(c.stamp(i % 128, 160.1), 100.0 + 0.1 * i, 1e-9) << i;
  }
  EXPECT_DOUBLE_EQ(c.realign(160.1), 0.0) << "the last frame of the backlog is on time";
}

TEST(SampleClock, AStalledLineRealignsTheReadThatEmptiesItForward) {
  SampleClock c(10.0, 2.0);
  c.stamp(0, 100.0);
  c.stamp(1, 100.1);
  // The line went silent; the next frame comes 60 s later, counted as the
  // next one (the counter cannot tell): the read that brought it moves.
  EXPECT_NEAR(c.stamp(2, 160.0), 100.2, 1e-9);
  EXPECT_NEAR(c.realign(160.0), 59.8, 1e-9);
  EXPECT_NEAR(c.stamp(3, 160.1), 160.1, 1e-9);
  // A short silence within tolerance keeps the sample clock.
  EXPECT_NEAR(c.stamp(4, 161.5), 160.2, 1e-9);
  EXPECT_DOUBLE_EQ(c.realign(161.5), 0.0);
}

// 200 frames lost at once step the 7-bit counter by 200 mod 128 = 72: the
// estimate falls 12.8 s behind. Once that exceeds the tolerance at a read
// that empties the line, the anchor comes back to the clock.
TEST(SampleClock, LossBeyondTheCounterWrapIsCaughtAtTheNextEmptyLine) {
  SampleClock c(10.0, 2.0);
  c.stamp(0, 100.0);
  EXPECT_DOUBLE_EQ(c.realign(100.0), 0.0);
  const double behind = c.stamp(200 % 128, 120.0);
  EXPECT_NEAR(behind, 107.2, 1e-9);
  EXPECT_NEAR(c.realign(120.0), 12.8, 1e-9);
  EXPECT_NEAR(c.stamp(201 % 128, 120.1), 120.1, 1e-9);
}

TEST(SampleClock, AheadOfTheClockComesBackButNeverGoesBackwards) {
  SampleClock c(10.0, 2.0);
  c.stamp(0, 100.0);
  // Frames come twice as fast as configured: the estimate runs ahead.
  double prev = 100.0;
  for (int i = 1; i < 200; ++i) {
    const double t = c.stamp(i % 128, 100.0 + 0.05 * i);
    EXPECT_GT(t, prev) << i;
    EXPECT_LE(t, 100.0 + 0.05 * i + 2.0 + 1e-9) << i;
    prev = t;
  }
}

TEST(SampleClock, CounterGapsKeepTheirSlotsAndWrapCounts) {
  SampleClock c(10.0, 2.0);
  c.stamp(126, 50.0);
  EXPECT_NEAR(c.stamp(127, 50.1), 50.1, 1e-9);
  EXPECT_NEAR(c.stamp(0, 50.2), 50.2, 1e-9);  // wrap
  EXPECT_NEAR(c.stamp(3, 50.5), 50.5, 1e-9);  // two frames missed
  c.reset();
  EXPECT_DOUBLE_EQ(c.stamp(9, 80.0), 80.0);
}

}  // namespace
}  // namespace gyrotherm::drivers
