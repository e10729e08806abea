// Several simulated DUTs (docs/simulator.md, "Several DUTs"): each [[dut]]
// on its own pty, in its own protocol (two KVH 1750 in different units and
// outputs, one ASCII test set), decoded by the drivers' DutSource
// (make_dut_source) into every channel; each axis's mean against an
// independent reference (Earth rate from the latitude and orientation plus
// the configured or default bias); the truth file; per-DUT faults over the
// control socket; per-DUT probes on the probe module; [simulator.dut]
// errors.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <random>
#include <regex>
#include <set>
#include <string>
#include <vector>

#include "gyrotherm/config/config.h"
#include "gyrotherm/config/sim_endpoints.h"
#include "gyrotherm/drivers/dut_link.h"
#include "gyrotherm/drivers/registers.h"
#include "gyrotherm/sim/control_server.h"
#include "gyrotherm/sim/options.h"
#include "gyrotherm/sim/simulator.h"
#include "sim_test_util.h"

namespace gyrotherm::sim {
namespace {

using namespace std::chrono_literals;
using test_util::wait_for;

constexpr double kLatitudeDeg = 31.9;
// Ω_E · sin φ, written out here rather than taken from the code under test.
const double kVerticalEarthDph = 15.041067 * std::sin(kLatitudeDeg * M_PI / 180.0);
// A horizontal axis at heading h (clockwise from north): Ω_E · cos φ · cos h.
double horizontal_earth_dph(double heading_deg) {
  return 15.041067 * std::cos(kLatitudeDeg * M_PI / 180.0) * std::cos(heading_deg * M_PI / 180.0);
}

// Two KVH 1750 (rad/s rate; deg delta angles) and an ASCII test set. A has
// its own bias per axis and its own probes and case; B takes the defaults
// (position 1: +1 °/h, +0.25 and +0.5 on its non-primary axes); C one bias
// for every axis.
constexpr const char* kStation = R"([station]
latitude_deg = 31.9
orientation = "up"
[chamber]
port = 0
unit_id = 1
profile = "watlow-f4t"
[probes]
port = 0
unit_id = 2
profile = "generic"
channels = { top = 0, side = 1 }
[[dut]]
serial = "A-1"
model = "KVH 1750"
protocol = "kvh1750"
unit = "rad"
output = "rate"
rate_hz = 100
axes = ["x", "y", "z"]
orientation = { z = "up", x = "horizontal", y = "horizontal" }
heading_deg = { x = 30.0, y = 300.0 }
primary_axis = "z"
probes = { top_channel = 4, side_channel = 5 }
[[dut]]
serial = "B-2"
model = "KVH 1750"
protocol = "kvh1750"
unit = "deg"
output = "delta"
rate_hz = 100
axes = ["x"]
orientation = { x = "up" }
primary_axis = "x"
[[dut]]
serial = "TS-7"
model = "rate test set"
protocol = "ascii"
rate_hz = 50
orientation = { y = "down" }
heading_deg = { x = 180.0 }
primary_axis = "y"
[dut.ascii]
delimiter = ","
prefix = "$GYR,"
checksum = "nmea"
seq_column = "n"
seq_modulo = 65536
columns = [
  { name = "n" },
  { name = "rate_x", kind = "rate", unit = "deg/h", axis = "x" },
  { name = "rate_y", kind = "rate", unit = "deg/s", axis = "y" },
  { name = "temp", kind = "temperature", unit = "degC" },
  { name = "flags", kind = "status" },
]
valid_bits = { x = 1, y = 2 }
[simulator]
endpoints_file = "unused"
seed = 7
[simulator.thermal]
control_noise_c = 0.0
probe_noise_c = 0.0
[simulator.gyro]
bias_dph = 0.0
white_noise_dph = 0.1
bias_instability_dph = 0.0
accel_noise_g = 1e-4
[simulator.dut.A-1]
case_tau_s = 300.0
probe_offset_c = 0.2
[simulator.dut.A-1.x]
bias_dph = 5.0
[simulator.dut.A-1.y]
bias_dph = -3.0
[simulator.dut.A-1.z]
bias_dph = 2.0
[simulator.dut.TS-7]
bias_dph = 0.7
)";

// The expected mean of each rate axis, °/h: Earth projection + bias. B's y
// and z are horizontal without a heading (not among its axes): east–west, 0.
const std::map<std::string, std::map<std::string, double>> kExpectedRateDph = {
    {"A-1",
     {{"x", horizontal_earth_dph(30.0) + 5.0},
      {"y", horizontal_earth_dph(300.0) - 3.0},
      {"z", kVerticalEarthDph + 2.0}}},
    {"B-2", {{"x", kVerticalEarthDph + 1.0}, {"y", 1.25}, {"z", 1.5}}},
    {"TS-7", {{"x", horizontal_earth_dph(180.0) + 0.7}, {"y", -kVerticalEarthDph + 0.7}}},
};
// Gravity per accelerometer (only the KVH carry them).
const std::map<std::string, std::map<std::string, double>> kExpectedAccelG = {
    {"A-1", {{"x", 0.0}, {"y", 0.0}, {"z", 1.0}}},
    {"B-2", {{"x", 1.0}, {"y", 0.0}, {"z", 0.0}}},
};

class MultiDutTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char dir_template[] = "/tmp/gyrotherm-multidut-test-XXXXXX";
    ASSERT_NE(::mkdtemp(dir_template), nullptr);
    dir_ = dir_template;
    auto config = config::parse_station_config(kStation, "multi.toml");
    ASSERT_TRUE(config.ok()) << config.error().message;
    config_ = std::move(config).value();
    SimulatorOverrides overrides;
    overrides.time_scale = 20;
    overrides.endpoints_file = dir_ + "/endpoints.toml";
    overrides.truth_file = dir_ + "/truth.json";
    auto options = read_simulator_options(config_, overrides);
    ASSERT_TRUE(options.ok()) << options.error().message;
    options_ = *options;
    options_.gyro_link = dir_ + "/gyro-pty";
    options_.control_socket = dir_ + "/sim.sock";
  }
  void TearDown() override {
    sources_.clear();
    sim_.reset();
    std::filesystem::remove_all(dir_);
  }
  void start() {
    auto sim = Simulator::create(config_, options_);
    ASSERT_TRUE(sim.ok()) << sim.error().message;
    sim_ = std::move(sim).value();
    Status s = sim_->start();
    ASSERT_TRUE(s.ok()) << s.error().message;
  }

  // Frames of one DUT, decoded by the drivers' reader on the DUT's device.
  struct Collected {
    std::vector<ChannelSpec> channels;
    std::mutex mu;
    std::vector<DutFrame> frames;
    std::size_t size() {
      std::lock_guard lock(mu);
      return frames.size();
    }
  };
  Collected& read_dut(const std::string& serial) {
    const auto ep = sim_->endpoints();
    std::string device;
    for (const auto& [s, d] : ep.dut_devices) {
      if (s == serial) device = d;
    }
    EXPECT_FALSE(device.empty()) << serial;
    const config::DutSection* dut = config::find_dut(config_.duts, serial);
    EXPECT_NE(dut, nullptr);
    drivers::DutLink link = dut->link;
    link.serial.device = device;
    auto source = drivers::make_dut_source(link, clock_);
    EXPECT_TRUE(source.ok()) << source.error().message;
    auto& c = collected_[serial];
    c = std::make_unique<Collected>();
    c->channels = (*source)->channels();
    Collected* target = c.get();
    (*source)->start([target](std::span<const DutFrame> batch) {
      std::lock_guard lock(target->mu);
      target->frames.insert(target->frames.end(), batch.begin(), batch.end());
    });
    sources_[serial] = std::move(source).value();
    return *c;
  }
  // Mean of a channel's physical values over the frames.
  static double mean_of(Collected& c, const std::string& name) {
    std::lock_guard lock(c.mu);
    std::size_t index = c.channels.size();
    for (std::size_t i = 0; i < c.channels.size(); ++i) {
      if (c.channels[i].name == name) index = i;
    }
    EXPECT_LT(index, c.channels.size()) << name;
    if (index == c.channels.size()) return NAN;
    double sum = 0;
    std::size_t n = 0;
    for (const DutFrame& f : c.frames) {
      const double v = f.raw[index];
      if (std::isnan(v)) continue;
      sum += v * c.channels[index].scale;
      ++n;
    }
    return n ? sum / static_cast<double>(n) : NAN;
  }
  static std::string channel_of(const Collected& c, ChannelKind kind, const std::string& axis) {
    for (const auto& ch : c.channels) {
      if (ch.kind == kind && ch.axis == axis) return ch.name;
    }
    return "";
  }

  std::string dir_;
  config::StationConfig config_;
  SimulatorOptions options_;
  ScaledClock clock_{20};
  // For tests that step time by hand; outlives the simulator's threads.
  ManualClock manual_clock_;
  std::unique_ptr<Simulator> sim_;
  std::map<std::string, std::unique_ptr<Collected>> collected_;
  std::map<std::string, std::unique_ptr<drivers::DutSource>> sources_;
};

TEST_F(MultiDutTest, EachDutOnItsOwnPtyDecodesToItsOwnTruth) {
  start();
  const auto ep = sim_->endpoints();
  ASSERT_EQ(ep.dut_devices.size(), 3u);
  EXPECT_EQ(ep.dut_devices[0].first, "A-1");
  EXPECT_EQ(ep.dut_devices[0].second, options_.gyro_link);  // the first DUT: gyro_link
  EXPECT_EQ(ep.gyro_device, options_.gyro_link);
  EXPECT_EQ(ep.dut_devices[1].second, options_.gyro_link + "-B-2");
  EXPECT_EQ(ep.dut_devices[2].second, options_.gyro_link + "-TS-7");
  for (const auto& [serial, device] : ep.dut_devices) {
    EXPECT_TRUE(std::filesystem::is_symlink(device)) << device;
  }
  // The endpoints file round-trips them (the daemon's reader).
  auto file = config::read_sim_endpoints(options_.endpoints_file);
  ASSERT_TRUE(file.ok()) << file.error().message;
  EXPECT_EQ(file->dut_devices, ep.dut_devices);

  // 60 station seconds at 100 Hz (50 Hz for the test set): the mean of a
  // 0.1 °/h-per-√s white noise over 60 s has σ = 0.013 °/h; tolerance 0.08
  // (6σ), finer than the 0.25 °/h default axis offsets.
  const std::map<std::string, std::size_t> wanted = {{"A-1", 6000}, {"B-2", 6000}, {"TS-7", 3000}};
  for (const auto& [serial, n] : wanted) read_dut(serial);
  ASSERT_TRUE(wait_for(
      [&] {
        for (const auto& [serial, n] : wanted) {
          if (collected_[serial]->size() < n) return false;
        }
        return true;
      },
      30s))
      << "A " << collected_["A-1"]->size() << " B " << collected_["B-2"]->size() << " TS "
      << collected_["TS-7"]->size();
  for (auto& [serial, source] : sources_) source->stop();

  for (const auto& [serial, axes] : kExpectedRateDph) {
    Collected& c = *collected_[serial];
    for (const auto& [axis, expected] : axes) {
      const std::string name = channel_of(c, ChannelKind::kRate, axis);
      ASSERT_FALSE(name.empty()) << serial << " " << axis;
      EXPECT_NEAR(mean_of(c, name), expected, 0.08) << serial << " " << name;
    }
  }
  for (const auto& [serial, axes] : kExpectedAccelG) {
    Collected& c = *collected_[serial];
    for (const auto& [axis, expected] : axes) {
      EXPECT_NEAR(mean_of(c, channel_of(c, ChannelKind::kAccel, axis)), expected, 1e-3)
          << serial << " accel " << axis;
    }
    // Every channel valid, the internal temperature the case's (23 °C held).
    EXPECT_EQ(mean_of(c, "status"), 0x77) << serial;
    EXPECT_NEAR(mean_of(c, "temp_c"), 23.0, 0.5) << serial;
  }
  // The test set: its status column holds both valid bits, its temperature
  // the case's with decimals.
  EXPECT_EQ(mean_of(*collected_["TS-7"], "flags"), 3.0);
  EXPECT_NEAR(mean_of(*collected_["TS-7"], "temp"), 23.0, 0.1);
  // No frame was lost or rejected on any line.
  for (auto& [serial, source] : sources_) {
    const auto h = source->health();
    EXPECT_EQ(h.parser.crc_failures, 0u) << serial;
    EXPECT_EQ(h.invalid_samples, 0u) << serial;
  }

  // The status names every DUT with its device.
  const SimulatorStatus st = sim_->status();
  ASSERT_EQ(st.duts.size(), 3u);
  EXPECT_EQ(st.duts[2].serial, "TS-7");
  EXPECT_EQ(st.duts[2].device, options_.gyro_link + "-TS-7");
  EXPECT_GT(st.duts[2].frames_generated, 3000u);
  const auto j = nlohmann::json::parse(status_json(st));
  EXPECT_EQ(j["duts"].size(), 3u);
  EXPECT_EQ(j["duts"][1]["serial"], "B-2");
}

TEST_F(MultiDutTest, TruthFileHasEveryDutAndAxisAndTodaysKeysForTheFirst) {
  start();
  std::ifstream in(options_.truth_file);
  ASSERT_TRUE(in) << options_.truth_file;
  const auto truth = nlohmann::json::parse(in);
  // Today's keys: the first DUT's primary axis (A-1 z).
  EXPECT_DOUBLE_EQ(truth["bias_dph"].get<double>(), 2.0);
  EXPECT_NEAR(truth["earth_rate_dph"].get<double>(), kVerticalEarthDph, 1e-9);
  EXPECT_EQ(truth["output"]["axis"], "z");
  ASSERT_EQ(truth["duts"].size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    const auto& d = truth["duts"][i];
    const std::string serial = d["serial"];
    EXPECT_EQ(d["position"], static_cast<int>(i));
    for (const auto& [axis, expected] : kExpectedRateDph.at(serial)) {
      const auto& a = d["axes"][axis];
      EXPECT_NEAR(a["earth_rate_dph"].get<double>() + a["bias_dph"].get<double>(), expected, 1e-9)
          << serial << " " << axis;
      // No temperature terms: the static mean is the same at every soak.
      for (const auto& s : a["static"]) {
        EXPECT_NEAR(s["mean_dph"].get<double>(), expected, 1e-9) << serial << " " << axis;
        EXPECT_NEAR(s["bias_earth_removed_dph"].get<double>(),
                    expected - a["earth_rate_dph"].get<double>(), 1e-9);
      }
    }
  }
  EXPECT_EQ(truth["duts"][0]["case"]["own"], true);
  EXPECT_EQ(truth["duts"][0]["case"]["case_tau_s"], 300.0);
  EXPECT_EQ(truth["duts"][1]["case"]["own"], false);
  EXPECT_EQ(truth["duts"][1]["axes"]["y"]["bias_default"], true);
  EXPECT_EQ(truth["duts"][2]["axes"]["y"]["orientation"], "down");
  EXPECT_EQ(truth["duts"][0]["axes"]["x"]["heading_deg"], 30.0);
  EXPECT_EQ(truth["duts"][2]["axes"]["x"]["heading_deg"], 180.0);
  EXPECT_TRUE(truth["duts"][1]["axes"]["y"]["heading_deg"].is_null());
  EXPECT_EQ(truth["duts"][0]["rate_hz"], 100.0);
  EXPECT_EQ(truth["duts"][2]["rate_hz"], 50.0);
}

// --rate-hz 40 sets every DUT's rate, --rate-hz TS-7=20 the test set's: each
// DUT's frames come at its rate (counted over 10 station seconds on a
// manual clock), the truth file and the endpoints say so, and a reader set
// up from the endpoints decodes B's delta angles (angle per sample: the
// rate matters) to its truth.
TEST_F(MultiDutTest, RateHzSetsEveryDutAndOneBySerial) {
  SimulatorOverrides overrides;
  ASSERT_TRUE(parse_rate_hz_options({"TS-7=20", "40"}, overrides).ok());
  overrides.time_scale = 20;  // as SetUp's: the pending-frame limit is 5 wall s of frames
  overrides.endpoints_file = options_.endpoints_file;
  overrides.truth_file = options_.truth_file;
  auto options = read_simulator_options(config_, overrides);
  ASSERT_TRUE(options.ok()) << options.error().message;
  const std::string link = options_.gyro_link;
  options_ = *options;
  options_.gyro_link = link;
  EXPECT_DOUBLE_EQ(options_.gyro_format.rate_hz, 40.0);  // the first DUT's, as served
  ManualClock& manual = manual_clock_;
  auto sim = Simulator::create(config_, options_, &manual);
  ASSERT_TRUE(sim.ok()) << sim.error().message;
  sim_ = std::move(sim).value();
  ASSERT_TRUE(sim_->start().ok());

  // The endpoints name each DUT's rate; the daemon's config takes them.
  auto ep = config::read_sim_endpoints(options_.endpoints_file);
  ASSERT_TRUE(ep.ok()) << ep.error().message;
  EXPECT_EQ(ep->dut_rates_hz, (std::vector<std::pair<std::string, double>>{
                                  {"A-1", 40.0}, {"B-2", 40.0}, {"TS-7", 20.0}}));
  config::StationConfig served = config_;
  config::apply_sim_endpoints(served, *ep);
  EXPECT_EQ(served.duts[0].link.rate_hz, 40.0);
  EXPECT_EQ(served.duts[1].link.rate_hz, 40.0);
  EXPECT_EQ(served.duts[2].link.rate_hz, 20.0);
  EXPECT_EQ(served.gyro.format.rate_hz, 40.0);
  std::ifstream in(options_.truth_file);
  ASSERT_TRUE(in);
  const auto truth = nlohmann::json::parse(in);
  EXPECT_EQ(truth["rate_hz"], 40.0);
  EXPECT_EQ(truth["duts"][1]["rate_hz"], 40.0);
  EXPECT_EQ(truth["duts"][2]["rate_hz"], 20.0);

  // B read as the daemon would read it: its line and rate from the endpoints.
  config_ = served;
  Collected& b = read_dut("B-2");
  ASSERT_TRUE(wait_for([&] { return sim_->status().duts[1].stream.readers > 0; }));
  for (int k = 1; k <= 10; ++k) {
    manual.advance(1.0);
    ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= k - 1e-6; }));
  }
  const SimulatorStatus st = sim_->status();
  EXPECT_EQ(st.duts[0].frames_generated, 400u);
  EXPECT_EQ(st.duts[1].frames_generated, 400u);
  EXPECT_EQ(st.duts[2].frames_generated, 200u);
  ASSERT_TRUE(wait_for([&] { return b.size() >= 400; }, 10s)) << b.size();
  sources_["B-2"]->stop();
  EXPECT_EQ(b.size(), 400u);
  // 10 s of 0.1 °/h-per-√s white noise: σ of the mean 0.03 °/h. At a wrong
  // rate (the config's 100 Hz) the delta angles would read 2.5 times too large.
  EXPECT_NEAR(mean_of(b, channel_of(b, ChannelKind::kRate, "x")),
              kExpectedRateDph.at("B-2").at("x"), 0.2);
}

TEST_F(MultiDutTest, FaultsHitOnlyTheirDut) {
  start();
  for (const char* serial : {"A-1", "B-2", "TS-7"}) read_dut(serial);
  ASSERT_TRUE(wait_for([&] {
    return collected_["A-1"]->size() > 100 && collected_["B-2"]->size() > 100 &&
           collected_["TS-7"]->size() > 50;
  }));
  // Every frame of B corrupted, every line of the test set too: their
  // readers reject them, A's frames keep arriving intact.
  EXPECT_EQ(handle_control_line(*sim_, "gyro corrupt B-2 1"), "ok");
  EXPECT_EQ(handle_control_line(*sim_, "frames corrupt 1 TS-7"), "ok");
  // Once corrupted frames flow (those already on the lines are read first),
  // B's and the test set's readers take no more frames; A's go on.
  ASSERT_TRUE(wait_for([&] {
    const auto st = sim_->status();
    return st.duts[1].frames_fault_corrupted > 20 && st.duts[2].frames_fault_corrupted > 20;
  }));
  ASSERT_TRUE(wait_for([&] { return sources_["B-2"]->health().parser.crc_failures > 20; }));
  const auto a0 = sources_["A-1"]->health();
  const auto b0 = sources_["B-2"]->health();
  const auto t0 = sources_["TS-7"]->health();
  const uint64_t corrupted0 = sim_->status().duts[2].frames_fault_corrupted;
  ASSERT_TRUE(wait_for([&] {
    return sources_["A-1"]->health().samples > a0.samples + 200 &&
           sim_->status().duts[2].frames_fault_corrupted > corrupted0 + 100;
  }));
  EXPECT_EQ(sources_["A-1"]->health().parser.crc_failures, a0.parser.crc_failures);
  EXPECT_EQ(sources_["B-2"]->health().samples, b0.samples);
  EXPECT_GT(sources_["B-2"]->health().parser.crc_failures, b0.parser.crc_failures);
  EXPECT_EQ(sources_["TS-7"]->health().samples, t0.samples);
  const auto st = sim_->status();
  EXPECT_EQ(st.duts[0].frame_corruption_rate, 0.0);
  EXPECT_EQ(st.duts[1].frame_corruption_rate, 1.0);
  EXPECT_EQ(st.duts[2].frame_corruption_rate, 1.0);
  EXPECT_EQ(st.faults.frame_corruption_rate, 0.0);  // the first DUT's, as before

  // Without a serial: the first DUT.
  EXPECT_EQ(handle_control_line(*sim_, "frames drop 0.5"), "ok");
  EXPECT_EQ(sim_->status().duts[0].frame_drop_rate, 0.5);
  EXPECT_EQ(sim_->status().duts[1].frame_drop_rate, 0.0);

  // Closing the test set's line hangs up only it.
  EXPECT_EQ(handle_control_line(*sim_, "gyro close TS-7"), "ok");
  auto s2 = sim_->status();
  EXPECT_FALSE(s2.duts[2].pty_open);
  EXPECT_TRUE(s2.duts[0].pty_open);
  EXPECT_TRUE(s2.duts[1].pty_open);
  const auto j = nlohmann::json::parse(status_json(s2));
  EXPECT_EQ(j["duts"][2]["faults_active"], (nlohmann::json{"pty_closed", "frames_corrupt"}));
  EXPECT_EQ(j["duts"][1]["faults_active"], (nlohmann::json{"frames_corrupt"}));
  // Reopened: a new pty behind the same link, named in the reply.
  const std::string reply = handle_control_line(*sim_, "gyro reopen TS-7");
  ASSERT_EQ(reply.rfind("ok ", 0), 0u) << reply;
  const auto r = nlohmann::json::parse(reply.substr(3));
  EXPECT_EQ(r["serial"], "TS-7");
  EXPECT_EQ(r["device"], options_.gyro_link + "-TS-7");
  EXPECT_EQ(r["gyro_device"], options_.gyro_link);
  EXPECT_TRUE(sim_->status().duts[2].pty_open);

  // An unknown serial changes nothing and names the served ones.
  const std::string unknown = handle_control_line(*sim_, "gyro close XX");
  EXPECT_EQ(unknown, "error no DUT with serial 'XX'; the simulator serves 'A-1', 'B-2', 'TS-7'");
  EXPECT_TRUE(sim_->status().duts[0].pty_open);
}

TEST_F(MultiDutTest, DutProbesReadTheirOwnShellPlusAnOffset) {
  // A's case lags the air by 300 s, the plant's by 900 s: after a step
  // of the set point A's probes are well ahead of the station's.
  start();
  test_util::ModbusClient probes(sim_->endpoints().modbus_port, config_.probes.endpoint.unit_id);
  auto top = drivers::probe_channel_spec("generic", 4);
  auto side = drivers::probe_channel_spec("generic", 5);
  ASSERT_TRUE(top.ok() && side.ok());
  ASSERT_TRUE(wait_for([&] { return probes.read(*top).has_value(); }));
  // At 23 °C (no control noise) A's probes read 23 ± gradient/2 + 0.2.
  const auto st0 = sim_->status();
  ASSERT_TRUE(st0.duts[0].probe_readings.has_value());
  EXPECT_FALSE(st0.duts[1].probe_readings.has_value());
  EXPECT_NEAR(*probes.read(*top), 23.0 + 0.05 / 2 + 0.2, 0.051);
  EXPECT_NEAR(*probes.read(*side), 23.0 - 0.05 / 2 + 0.2, 0.051);

  sim_->set_setpoint_c(40.0);
  // 600 station s (30 wall s at ×20 would be long: wait on the condition).
  ASSERT_TRUE(wait_for(
      [&] {
        const auto st = sim_->status();
        return st.duts[0].shell.case_c > st.truth.case_c + 1.0;
      },
      20s));
  const auto st = sim_->status();
  EXPECT_GT(st.duts[0].shell.case_c, st.duts[1].shell.case_c + 1.0);
  EXPECT_DOUBLE_EQ(st.duts[1].shell.case_c, st.truth.case_c);  // B shares the plant's case
  // The registers hold A's shell + offset (0.1 °C resolution), not the plant's.
  ASSERT_TRUE(wait_for([&] {
    const auto now = sim_->status();
    const auto r = probes.read(*top);
    return r && std::abs(*r - (now.duts[0].shell.top_c + 0.2)) < 0.3;
  }));
}

Result<SimulatorOptions> options_for(const std::string& simulator_part) {
  const std::string text =
      std::string(kStation).substr(0, std::string(kStation).find("[simulator]")) + simulator_part;
  auto config = config::parse_station_config(text, "multi.toml");
  if (!config.ok()) return config.error();
  return read_simulator_options(*config);
}

TEST(MultiDutOptions, ArrayFormAndErrorsNamingTheKey) {
  // [[simulator.dut]] with serial, per-axis tables inside.
  auto o = options_for(R"([simulator]
endpoints_file = "x"
[[simulator.dut]]
serial = "B-2"
bias_dph = 4.0
internal_temp_offset_c = 3.5
[simulator.dut.y]
white_noise_dph = 0.5
)");
  ASSERT_TRUE(o.ok()) << o.error().message;
  ASSERT_EQ(o->dut_overrides.size(), 1u);
  EXPECT_EQ(o->dut_overrides[0].serial, "B-2");
  EXPECT_EQ(o->dut_overrides[0].all.bias_dph, 4.0);
  EXPECT_EQ(o->dut_overrides[0].axis[1].white_noise_dph, 0.5);
  auto config = config::parse_station_config(kStation, "multi.toml");
  ASSERT_TRUE(config.ok());
  const DutSimParams p = resolve_dut_params(*o, config->duts[1], 1);
  EXPECT_EQ(p.axes[0].bias_dph, 4.0);  // given: no default offset
  EXPECT_EQ(p.axes[2].bias_dph, 4.0);
  EXPECT_EQ(p.axes[1].white_noise_dph, 0.5);
  EXPECT_EQ(p.axes[0].white_noise_dph, 1.0);
  EXPECT_EQ(p.internal_temp_offset_c, 3.5);
  // Defaults by position and axis rank (C: primary y).
  const DutSimParams c = resolve_dut_params(*o, config->duts[2], 2);
  EXPECT_EQ(c.axes[1].bias_dph, 2.0);
  EXPECT_EQ(c.axes[0].bias_dph, 2.25);
  EXPECT_EQ(c.axes[2].bias_dph, 2.5);

  const std::pair<std::string, std::string> bad[] = {
      {"[simulator.dut.NOPE]\nbias_dph = 1\n",
       "simulator.dut.NOPE: no [[dut]] with serial 'NOPE' (the station's DUTs: 'A-1', 'B-2', "
       "'TS-7')"},
      {"[simulator.dut.A-1]\nbias = 1\n", "simulator.dut.A-1.bias"},
      {"[simulator.dut.A-1.w]\nbias_dph = 1\n", "simulator.dut.A-1.w"},
      {"[simulator.dut.A-1]\ncase_tau_s = -5\n",
       "simulator.dut.A-1.case_tau_s: -5 is out of range"},
      {"[simulator.dut.A-1.x]\ntemp_coeffs = [1, \"a\"]\n",
       "simulator.dut.A-1.x.temp_coeffs: must be an array of finite numbers"},
      {"[[simulator.dut]]\nbias_dph = 1\n", "simulator.dut[0].serial: missing"},
      {"[[simulator.dut]]\nserial = \"A-1\"\n[[simulator.dut]]\nserial = \"A-1\"\n",
       "DUT 'A-1' is given twice"},
  };
  for (const auto& [part, expected] : bad) {
    auto r = options_for("[simulator]\nendpoints_file = \"x\"\n" + part);
    ASSERT_FALSE(r.ok()) << part;
    EXPECT_NE(r.error().message.find(expected), std::string::npos)
        << part << " -> " << r.error().message;
    EXPECT_NE(r.error().message.find("multi.toml:"), std::string::npos) << r.error().message;
  }
}

// [simulator.randomize]: each DUT axis's noise and each DUT's case drawn by
// the seed, within the ranges, the same for the same seed, and listed in the
// truth file as drawn.
TEST(MultiDutOptions, RandomizeDrawsEachDutsNoiseAndCaseByTheSeed) {
  const std::string ranges = R"([simulator]
endpoints_file = "x"
seed = 7
[simulator.randomize]
white_noise_dph = [0.01, 1.0]
bias_instability_dph = [0, 0.05]
rate_random_walk_dph_per_sqrt_h = [0.001, 0.01]
case_tau_s = [600, 2400]
)";
  auto o = options_for(ranges);
  ASSERT_TRUE(o.ok()) << o.error().message;
  auto config = config::parse_station_config(kStation, "multi.toml");
  ASSERT_TRUE(config.ok());
  std::vector<DutSimParams> drawn;
  for (int p = 0; p < 3; ++p) {
    drawn.push_back(resolve_dut_params(*o, config->duts[static_cast<std::size_t>(p)], p));
  }
  std::set<double> whites;
  for (const auto& d : drawn) {
    for (const auto& a : d.axes) {
      EXPECT_GE(a.white_noise_dph, 0.01);
      EXPECT_LE(a.white_noise_dph, 1.0);
      EXPECT_GE(a.bias_instability_dph, 0.0);
      EXPECT_LE(a.bias_instability_dph, 0.05);
      EXPECT_GE(a.rate_random_walk_dph_per_sqrt_h, 0.001);
      EXPECT_LE(a.rate_random_walk_dph_per_sqrt_h, 0.01);
      whites.insert(a.white_noise_dph);
    }
    ASSERT_TRUE(d.case_params.case_tau_s);
    EXPECT_GE(*d.case_params.case_tau_s, 600.0);
    EXPECT_LE(*d.case_params.case_tau_s, 2400.0);
  }
  EXPECT_EQ(whites.size(), 9u) << "every DUT axis draws its own";
  // The same seed draws the same; another seed, others.
  const DutSimParams again = resolve_dut_params(*o, config->duts[1], 1);
  EXPECT_EQ(again.axes[2].white_noise_dph, drawn[1].axes[2].white_noise_dph);
  EXPECT_EQ(again.case_params.case_tau_s, drawn[1].case_params.case_tau_s);
  o->seed = 8;
  const DutSimParams other = resolve_dut_params(*o, config->duts[1], 1);
  EXPECT_NE(other.axes[2].white_noise_dph, drawn[1].axes[2].white_noise_dph);
  // A DUT draws the same whatever other ranges are set (ten draws each).
  auto white_only = options_for(
      "[simulator]\nendpoints_file = \"x\"\nseed = 7\n[simulator.randomize]\n"
      "white_noise_dph = [0.01, 1.0]\n");
  ASSERT_TRUE(white_only.ok()) << white_only.error().message;
  const DutSimParams w = resolve_dut_params(*white_only, config->duts[2], 2);
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(w.axes[i].white_noise_dph, drawn[2].axes[i].white_noise_dph);
    EXPECT_EQ(w.axes[i].rate_random_walk_dph_per_sqrt_h,
              white_only->gyro.rate_random_walk_dph_per_sqrt_h);
  }

  // The chamber's plant: its air lag and control noise, from a stream of
  // their own (the DUTs' draws above did not move).
  auto chamber = options_for(ranges + "air_tau_s = [60, 300]\ncontrol_noise_c = [0.1, 0.5]\n");
  ASSERT_TRUE(chamber.ok()) << chamber.error().message;
  const ThermalParams plant = resolve_thermal_params(*chamber);
  EXPECT_GE(plant.air_tau_s, 60.0);
  EXPECT_LE(plant.air_tau_s, 300.0);
  EXPECT_GE(plant.control_noise_c, 0.1);
  EXPECT_LE(plant.control_noise_c, 0.5);
  EXPECT_EQ(resolve_thermal_params(*chamber).air_tau_s, plant.air_tau_s);
  EXPECT_EQ(resolve_dut_params(*chamber, config->duts[1], 1).axes[2].white_noise_dph,
            drawn[1].axes[2].white_noise_dph);
  chamber->seed = 8;
  EXPECT_NE(resolve_thermal_params(*chamber).air_tau_s, plant.air_tau_s);
  EXPECT_EQ(resolve_thermal_params(*o).air_tau_s, o->thermal.air_tau_s)
      << "no range: as configured";

  const std::pair<std::string, std::string> bad[] = {
      {"air_tau_s = [300, 60]\n", "simulator.randomize.air_tau_s: [300, 60] is not a range"},
      {"white_noise_dph = [1.0, 0.5]\n",
       "simulator.randomize.white_noise_dph: [1, 0.5] is not a range"},
      {"case_tau_s = [600]\n", "simulator.randomize.case_tau_s: must be [lo, hi]"},
      {"bias_instability_dph = [-1, 2]\n", "simulator.randomize.bias_instability_dph: [-1, 2]"},
      {"rate_random_walk_dph_per_sqrt_h = [0, \"a\"]\n",
       "simulator.randomize.rate_random_walk_dph_per_sqrt_h: must be [lo, hi]"},
      {"bias_dph = [0, 1]\n", "simulator.randomize.bias_dph: unknown key"},
  };
  for (const auto& [line, expected] : bad) {
    auto r = options_for("[simulator]\nendpoints_file = \"x\"\n[simulator.randomize]\n" + line);
    ASSERT_FALSE(r.ok()) << line;
    EXPECT_NE(r.error().message.find(expected), std::string::npos)
        << line << " -> " << r.error().message;
    EXPECT_TRUE(std::regex_search(r.error().message,
                                  std::regex(R"(multi\.toml:[0-9]+: simulator\.randomize\.)")))
        << r.error().message;
  }
}

// A range is log-uniform from lo > 0 (the median draw is the geometric
// mean), uniform from 0 (the median is the middle), fixed when lo = hi.
TEST(MultiDutOptions, ARangeDrawsLogUniformlyAboveZeroAndUniformlyFromZero) {
  std::mt19937_64 rng(20261130);
  const DrawRange log_range{0.001, 0.1}, linear{0.0, 2.0}, fixed{0.25, 0.25};
  int below_geometric = 0, below_middle = 0;
  const int n = 20'000;
  for (int i = 0; i < n; ++i) {
    const double a = log_range.draw(rng);
    ASSERT_GE(a, 0.001);
    ASSERT_LE(a, 0.1);
    if (a < 0.01) ++below_geometric;
    const double b = linear.draw(rng);
    ASSERT_GE(b, 0.0);
    ASSERT_LE(b, 2.0);
    if (b < 1.0) ++below_middle;
    ASSERT_EQ(fixed.draw(rng), 0.25);
  }
  // Binomial spread of the count: ±0.35 % at one sigma.
  EXPECT_NEAR(static_cast<double>(below_geometric) / n, 0.5, 0.015);
  EXPECT_NEAR(static_cast<double>(below_middle) / n, 0.5, 0.015);
}

TEST_F(MultiDutTest, TruthFileListsWhatTheRangesDrew) {
  options_.randomize.white_noise_dph = DrawRange{0.02, 0.2};
  options_.randomize.case_tau_s = DrawRange{600, 2400};
  options_.randomize.air_tau_s = DrawRange{60, 300};
  start();
  std::ifstream in(options_.truth_file);
  ASSERT_TRUE(in) << options_.truth_file;
  const auto truth = nlohmann::json::parse(in);
  EXPECT_EQ(truth["randomize"]["white_noise_dph"], nlohmann::json::array({0.02, 0.2}));
  EXPECT_EQ(truth["randomize"]["case_tau_s"], nlohmann::json::array({600.0, 2400.0}));
  EXPECT_EQ(truth["randomize"]["air_tau_s"], nlohmann::json::array({60.0, 300.0}));
  EXPECT_FALSE(truth["randomize"].contains("bias_instability_dph"));
  EXPECT_EQ(truth["chamber"]["air_tau_s"].get<double>(),
            resolve_thermal_params(options_).air_tau_s);
  ASSERT_EQ(truth["duts"].size(), config_.duts.size());
  for (std::size_t p = 0; p < config_.duts.size(); ++p) {
    const DutSimParams want = resolve_dut_params(options_, config_.duts[p], static_cast<int>(p));
    const auto& d = truth["duts"][p];
    for (std::size_t i = 0; i < 3; ++i) {
      EXPECT_EQ(d["axes"][kAxisNames[i]]["white_noise_dph"].get<double>(),
                want.axes[i].white_noise_dph)
          << p << " " << kAxisNames[i];
    }
    EXPECT_EQ(d["case"]["case_tau_s"].get<double>(), *want.case_params.case_tau_s);
    EXPECT_EQ(d["case"]["own"], true);
  }
}

}  // namespace
}  // namespace gyrotherm::sim
