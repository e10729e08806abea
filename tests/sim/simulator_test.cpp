// The simulator in-process on loopback: a libmodbus client for the chamber
// and the probe module, a raw reader on the pty's slave for the gyro frames.
#include "gyrotherm/sim/simulator.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <modbus/modbus.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>

#include "gyrotherm/config/sim_endpoints.h"
#include "gyrotherm/drivers/kvh1750.h"
#include "sim_test_util.h"
#include "test_time.h"

namespace gyrotherm::sim {
namespace {

using namespace test_util;

// Reads the gyro line as the daemon would: slave path, raw, KVH parser.
class PtyReader {
 public:
  explicit PtyReader(const std::string& path) {
    fd_ = ::open(path.c_str(), O_RDONLY | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd_ >= 0) {
      termios tio{};
      ::tcgetattr(fd_, &tio);
      ::cfmakeraw(&tio);
      ::tcsetattr(fd_, TCSANOW, &tio);
    }
  }
  ~PtyReader() {
    if (fd_ >= 0) ::close(fd_);
  }
  bool ok() const { return fd_ >= 0; }

  // Reads and parses until `pred` holds, the line hangs up, or the timeout.
  template <class Pred>
  bool read_until(Pred pred, std::chrono::milliseconds timeout = 3000ms) {
    const auto deadline = SteadyClock::now() + timeout;
    uint8_t buf[4096];
    while (!pred() && !hung_up_ && SteadyClock::now() < deadline) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 10) <= 0) continue;
      const ssize_t n = ::read(fd_, buf, sizeof buf);
      if (n > 0) {
        parser_.feed(std::span<const uint8_t>(buf, static_cast<std::size_t>(n)), frames_);
      } else if (n < 0 && errno != EAGAIN && errno != EINTR) {
        hung_up_ = true;  // EIO: the master is gone
      } else if (p.revents & POLLHUP) {
        hung_up_ = true;
      }
    }
    return pred();
  }

  const std::vector<drivers::GyroFrame>& frames() const { return frames_; }
  const drivers::ParserCounters& counters() const { return parser_.counters(); }
  bool hung_up() const { return hung_up_; }

 private:
  int fd_ = -1;
  drivers::Kvh1750Parser parser_;
  std::vector<drivers::GyroFrame> frames_;
  bool hung_up_ = false;
};

class SimulatorTest : public SimFixture {};

TEST_F(SimulatorTest, WritesEndpointsAndTruthAndRemovesEndpointsOnStop) {
  ASSERT_NO_FATAL_FAILURE(start());
  auto ep = config::read_sim_endpoints(options_.endpoints_file);
  ASSERT_TRUE(ep.ok()) << ep.error().message;
  EXPECT_EQ(ep->modbus_host, "127.0.0.1");
  EXPECT_EQ(ep->modbus_port, port());
  EXPECT_GT(ep->modbus_port, 0);
  EXPECT_EQ(ep->gyro_device, sim_->endpoints().gyro_device);
  EXPECT_TRUE(std::filesystem::exists(ep->gyro_device));
  EXPECT_EQ(ep->pid, static_cast<long>(::getpid()));
  EXPECT_EQ(ep->control_socket, options_.control_socket);
  EXPECT_TRUE(std::filesystem::exists(ep->control_socket));

  std::ifstream truth_in(options_.truth_file);
  const auto truth = nlohmann::json::parse(truth_in);
  EXPECT_NEAR(truth["earth_rate_dph"].get<double>(), 7.95, 0.01);
  EXPECT_EQ(truth["temp_coeffs"].get<std::vector<double>>(), (std::vector<double>{0.004, -8e-5}));
  EXPECT_EQ(truth["seed"].get<uint64_t>(), 1u);
  EXPECT_DOUBLE_EQ(truth["rate_hz"].get<double>(), 10.0);

  sim_->stop();
  EXPECT_FALSE(std::filesystem::exists(options_.endpoints_file));
  EXPECT_FALSE(std::filesystem::exists(options_.control_socket));
  EXPECT_TRUE(std::filesystem::exists(options_.truth_file));
}

TEST_F(SimulatorTest, ChamberOverModbusReadsAirAndTakesSetPoint) {
  ASSERT_NO_FATAL_FAILURE(start());
  const auto& map = config_.chamber.map;
  ModbusClient client(port(), chamber_unit());
  const auto pv = client.read(map.process_value);
  ASSERT_TRUE(pv) << modbus_strerror(errno);
  EXPECT_NEAR(*pv, 23.0, 1.5);  // control noise std 0.25 °C
  EXPECT_NEAR(*pv, sim_->status().truth.air_c, 0.2);
  const auto sp = client.read(map.setpoint);
  ASSERT_TRUE(sp);
  EXPECT_DOUBLE_EQ(*sp, 23.0);
  // A second connection is served while the first stays open.
  ModbusClient probes(port(), probes_unit());
  EXPECT_TRUE(probes.read(config_.probes.top));
  EXPECT_TRUE(client.read(map.process_value));
  EXPECT_EQ(sim_->status().modbus.active_connections, 2u);

  ASSERT_TRUE(client.write(map.setpoint, 40.0)) << modbus_strerror(errno);
  EXPECT_TRUE(wait_for([&] { return sim_->status().setpoint_c == 40.0; }));
  EXPECT_EQ(client.read(map.setpoint).value_or(0), 40.0);
  // The controller ramps towards it (5 °C/min: 1 °C in 12 station s).
  EXPECT_TRUE(wait_for([&] { return sim_->status().truth.ramped_setpoint_c > 24.0; }));

  // Out of range: refused with exception 3 (illegal data value), not taken.
  ASSERT_FALSE(client.write(map.setpoint, 500.0));
  EXPECT_EQ(errno, EMBXILVAL) << modbus_strerror(errno);
  EXPECT_EQ(sim_->status().setpoint_writes_rejected, 1u);
  EXPECT_EQ(client.read(map.setpoint).value_or(0), 40.0);
  EXPECT_EQ(sim_->status().setpoint_c, 40.0);
}

TEST_F(SimulatorTest, ProbeModuleOverModbusAndUnknownUnit) {
  ASSERT_NO_FATAL_FAILURE(start());
  ModbusClient client(port(), probes_unit());
  const auto top = client.read(config_.probes.top);
  const auto side = client.read(config_.probes.side);
  ASSERT_TRUE(top && side) << modbus_strerror(errno);
  EXPECT_NEAR(*top, 23.0, 1.0);
  EXPECT_NEAR(*side, 23.0, 1.0);
  EXPECT_NEAR(*top, sim_->status().readings.top_c, 0.2);

  client.set_unit(9);
  EXPECT_FALSE(client.read(config_.probes.top));
  EXPECT_EQ(errno, EMBXGTAR);
  EXPECT_EQ(sim_->status().modbus.unknown_unit_requests, 1u);
}

TEST_F(SimulatorTest, GyroFramesOnThePtyPassCrcWithConsecutiveSequence) {
  ASSERT_NO_FATAL_FAILURE(start());
  PtyReader reader(sim_->endpoints().gyro_device);
  ASSERT_TRUE(reader.ok());
  ASSERT_TRUE(reader.read_until([&] { return reader.frames().size() >= 200; }));
  EXPECT_EQ(reader.counters().crc_failures, 0u);
  EXPECT_EQ(reader.counters().sequence_gaps, 0u);
  double sum_dph = 0;
  const auto& frames = reader.frames();
  for (std::size_t i = 0; i < frames.size(); ++i) {
    if (i > 0) {
      EXPECT_EQ(frames[i].seq, (frames[i - 1].seq + 1) % 128);
    }
    EXPECT_EQ(frames[i].status, 0x77);
    EXPECT_EQ(frames[i].temp_c, 23);
    sum_dph += drivers::to_rate_dph(frames[i].gyro[2], options_.gyro_format);
  }
  // Earth 7.95 + bias 0.05 + 0.004 x 23 - 8e-5 x 23² + 0.5 x 0.05 = 8.08 °/h;
  // per-sample std sqrt(10) °/h: the mean of 200 is good to 0.22 °/h (1 sigma).
  EXPECT_NEAR(sum_dph / static_cast<double>(frames.size()), 8.08, 1.0);
}

TEST_F(SimulatorTest, CorruptedAndDroppedFramesReachTheReaderAsSuch) {
  ASSERT_NO_FATAL_FAILURE(start());
  PtyReader reader(sim_->endpoints().gyro_device);
  ASSERT_TRUE(reader.read_until([&] { return reader.frames().size() >= 10; }));

  sim_->set_frame_corruption_rate(1.0);
  EXPECT_TRUE(reader.read_until([&] { return reader.counters().crc_failures >= 20; }));
  sim_->set_frame_corruption_rate(0.0);
  EXPECT_GE(sim_->status().frames_fault_corrupted, 20u);
  const std::size_t after_corruption = reader.frames().size();
  EXPECT_TRUE(reader.read_until([&] { return reader.frames().size() >= after_corruption + 20; }));

  // Corrupted frames were gaps too; count from here.
  const auto gaps_before = reader.counters().sequence_gaps;
  const auto missed_before = reader.counters().frames_missed;
  sim_->set_frame_drop_rate(0.5);
  EXPECT_TRUE(
      reader.read_until([&] { return reader.counters().sequence_gaps >= gaps_before + 10; }));
  sim_->set_frame_drop_rate(0.0);
  const auto missed = reader.counters().frames_missed - missed_before;
  EXPECT_GE(missed, 10u);
  EXPECT_GE(sim_->status().frames_fault_dropped, missed);
  EXPECT_EQ(reader.counters().crc_failures, sim_->status().frames_fault_corrupted);
}

TEST_F(SimulatorTest, ModbusDownClosesTheLinkAndComesBack) {
  ASSERT_NO_FATAL_FAILURE(start());
  ModbusClient client(port(), chamber_unit(), 0.2);
  ASSERT_TRUE(client.read(config_.chamber.map.process_value));

  sim_->set_modbus_down(true);
  EXPECT_TRUE(wait_for([&] {
    client.connect();
    return !client.read(config_.chamber.map.process_value);
  }));
  EXPECT_TRUE(wait_for([&] { return sim_->status().modbus.refused_connections >= 1; }));

  sim_->set_modbus_down(false);
  EXPECT_TRUE(wait_for([&] {
    client.connect();
    return client.read(config_.chamber.map.process_value).has_value();
  }));
}

TEST_F(SimulatorTest, ModbusReplyDelay) {
  ASSERT_NO_FATAL_FAILURE(start());
  ModbusClient client(port(), chamber_unit(), 1.0);
  sim_->set_modbus_reply_delay_s(0.2);
  const auto before = SteadyClock::now();
  EXPECT_TRUE(client.read(config_.chamber.map.process_value));
  EXPECT_GE(SteadyClock::now() - before, 200ms);

  ModbusClient impatient(port(), chamber_unit(), 0.05);
  EXPECT_FALSE(impatient.read(config_.chamber.map.process_value));
  EXPECT_EQ(errno, ETIMEDOUT);

  sim_->set_modbus_reply_delay_s(0);
  ModbusClient fresh(port(), chamber_unit(), 1.0);
  const auto t0 = SteadyClock::now();
  EXPECT_TRUE(fresh.read(config_.chamber.map.process_value));
  EXPECT_LT(SteadyClock::now() - t0, 150ms);
}

TEST_F(SimulatorTest, ClosedPtyHangsUpAndReopenedPtyStreamsOnItsNewPath) {
  ASSERT_NO_FATAL_FAILURE(start());
  PtyReader old_reader(sim_->endpoints().gyro_device);
  ASSERT_TRUE(old_reader.read_until([&] { return old_reader.frames().size() >= 5; }));
  const std::string old_target = std::filesystem::read_symlink(options_.gyro_link).string();
  sim_->close_pty();
  EXPECT_TRUE(old_reader.read_until([&] { return old_reader.hung_up(); }));
  EXPECT_TRUE(wait_for([&] { return sim_->status().stream.frames_dropped_closed > 0; }));
  // While the line is down the link names no device: the closed pty's
  // number is free for any process to take, and a reader reopening the
  // link must not find that one's line.
  EXPECT_FALSE(std::filesystem::is_symlink(std::filesystem::symlink_status(options_.gyro_link)));

  ASSERT_TRUE(sim_->reopen_pty().ok());
  const std::string path = sim_->endpoints().gyro_device;
  // The stable link follows the new pty, as /dev/serial/by-id/... would.
  EXPECT_EQ(path, options_.gyro_link);
  EXPECT_NE(std::filesystem::read_symlink(options_.gyro_link).string(), old_target);
  auto ep = config::read_sim_endpoints(options_.endpoints_file);
  ASSERT_TRUE(ep.ok());
  EXPECT_EQ(ep->gyro_device, path);
  PtyReader reader(path);
  EXPECT_TRUE(reader.read_until([&] { return reader.frames().size() >= 20; }));
  EXPECT_EQ(reader.counters().crc_failures, 0u);
}

TEST_F(SimulatorTest, StalledProbeKeepsItsValue) {
  options_.thermal.probe_noise_c = 0.5;  // readings change on every step
  ASSERT_NO_FATAL_FAILURE(start());
  sim_->stall_probe(ProbeRole::kTop, true);
  const double frozen = sim_->status().readings.top_c;
  const double t = sim_->status().t_s;
  ASSERT_TRUE(wait_for([&] { return sim_->status().t_s > t + 5; }));
  EXPECT_EQ(sim_->status().readings.top_c, frozen);
  ModbusClient client(port(), probes_unit());
  EXPECT_NEAR(client.read(config_.probes.top).value_or(-99), frozen, 0.051);  // int16 x 0.1
  sim_->stall_probe(ProbeRole::kTop, false);
  EXPECT_TRUE(wait_for([&] { return sim_->status().readings.top_c != frozen; }));
}

// demo.toml asks for 0.01 °C probes, but the generic profile's registers
// hold int16 x 0.1: the readings the status shows are what a client reads.
TEST_F(SimulatorTest, ProbeReadingsAreWhatTheRegistersHold) {
  ASSERT_EQ(config_.probes.top.type, drivers::RegisterType::kInt16);
  ASSERT_DOUBLE_EQ(config_.probes.top.scale, 0.1);
  ManualClock& clock = manual_clock_;
  ASSERT_NO_FATAL_FAILURE(start(&clock));
  ModbusClient client(port(), probes_unit());
  for (int k = 1; k <= 5; ++k) {
    clock.advance(37.0);
    ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= 37.0 * k - 1e-6; }));
    const auto readings = sim_->status().readings;
    // Published just after the step.
    ASSERT_TRUE(wait_for([&] {
      return client.read(config_.probes.top) == readings.top_c &&
             client.read(config_.probes.side) == readings.side_c;
    })) << "status top "
        << readings.top_c << " side " << readings.side_c << ", registers top "
        << client.read(config_.probes.top).value_or(-99) << " side "
        << client.read(config_.probes.side).value_or(-99);
  }
}

// Watlow's ramp action enumeration: Off is 62, not 0. A ramp rate with the
// action Off leaves the chamber's own ramp; Set Point Change (1647) applies it.
TEST_F(SimulatorTest, RampActionFollowsWatlowsEnumeration) {
  const auto& map = config_.chamber.map;
  ASSERT_TRUE(map.ramp_action && map.ramp_rate && map.ramp_scale);
  ManualClock& clock = manual_clock_;
  ASSERT_NO_FATAL_FAILURE(start(&clock));
  ModbusClient client(port(), chamber_unit());
  ASSERT_TRUE(client.write(*map.ramp_scale, 57));   // Minutes
  ASSERT_TRUE(client.write(*map.ramp_rate, 1.0));   // 1 °C/min
  ASSERT_TRUE(client.write(*map.ramp_action, 62));  // Off
  ASSERT_TRUE(client.write(map.setpoint, 40.0));
  ASSERT_TRUE(wait_for([&] { return sim_->status().setpoint_c == 40.0; }));
  clock.advance(60.0);
  ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= 60.0 - 1e-6; }));
  // The plant's 5 °C/min from 23 °C: 28 °C after a minute.
  EXPECT_NEAR(sim_->status().truth.ramped_setpoint_c, 28.0, 0.2);

  ASSERT_TRUE(client.write(*map.ramp_action, 1647));  // Set Point Change
  // The reply goes out before the simulator takes the write in.
  ASSERT_TRUE(wait_for([&] { return sim_->status().ramp_limit_c_per_min == 1.0; }));
  clock.advance(60.0);
  ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= 120.0 - 1e-6; }));
  EXPECT_NEAR(sim_->status().truth.ramped_setpoint_c, 29.0, 0.2);  // 1 °C/min
}

TEST_F(SimulatorTest, ManualClockStepsExactly) {
  ManualClock& clock = manual_clock_;
  clock.set(1000.0);
  ASSERT_NO_FATAL_FAILURE(start(&clock));
  clock.advance(600.0);
  ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= 600.0 - 1e-6; }));
  const auto s = sim_->status();
  EXPECT_NEAR(s.t_s, 600.0, 1e-6);
  EXPECT_EQ(s.frames_generated, 6000u);  // 10 Hz
  EXPECT_EQ(s.lag_s, 0.0);
}

TEST_F(SimulatorTest, KeepsUpAtTimeScale1000With10Hz) {
  // A speed check of the optimised build: under the sanitizers (which set
  // GYROTHERM_TEST_TIME_FACTOR) the pty reader alone falls behind 10 000
  // frames per wall second on a busy machine, whatever the simulator does.
  if (gyrotherm::testing::time_factor() > 1) {
    GTEST_SKIP() << "speed check: not meaningful in a sanitized build (time factor "
                 << gyrotherm::testing::time_factor() << ")";
  }
  options_.time_scale = 1000;  // 10 000 frames per wall second
  ASSERT_NO_FATAL_FAILURE(start());
  PtyReader reader(sim_->endpoints().gyro_device);
  ASSERT_TRUE(reader.read_until([&] { return sim_->status().t_s >= 1000.0; }, 4000ms));
  const auto s = sim_->status();
  EXPECT_LT(s.lag_s, 20.0);  // station s, i.e. 20 ms of wall time
  EXPECT_GE(s.frames_generated, 10000u);
  EXPECT_EQ(s.stream.frames_dropped_full, 0u);
  EXPECT_LE(reader.frames().size(), s.stream.frames_queued);
  // Everything queued by then arrives: nothing is lost between the simulator
  // and the line. (How much is still in flight at that moment depends on how
  // busy the machine is: a reader starved for 0.2 s is 2 000 frames behind.)
  const uint64_t queued = s.stream.frames_queued;
  EXPECT_TRUE(reader.read_until([&] { return reader.frames().size() >= queued; }, 10000ms))
      << reader.frames().size() << " of " << queued << " frames arrived";
  EXPECT_EQ(reader.counters().crc_failures, 0u);
  EXPECT_EQ(reader.counters().sequence_gaps, 0u);
}

TEST_F(SimulatorTest, FramesWhileNobodyListensAreNotStored) {
  ASSERT_NO_FATAL_FAILURE(start());
  ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= 30.0; }));  // 300 frames, no reader
  EXPECT_EQ(sim_->status().stream.readers, 0);
  EXPECT_GE(sim_->status().stream.frames_dropped_no_reader, 250u);
  EXPECT_EQ(sim_->status().stream.frames_queued, 0u);

  PtyReader reader(sim_->endpoints().gyro_device);
  ASSERT_TRUE(reader.read_until([&] { return reader.frames().size() >= 20; }));
  EXPECT_EQ(sim_->status().stream.readers, 1);
  // The first frame is current: every frame before it was dropped unsent.
  const uint64_t dropped = sim_->status().stream.frames_dropped_no_reader;
  EXPECT_EQ(reader.frames().front().seq, dropped % 128);
  EXPECT_EQ(reader.counters().crc_failures, 0u);
  EXPECT_EQ(reader.counters().sequence_gaps, 0u);
}

}  // namespace
}  // namespace gyrotherm::sim
