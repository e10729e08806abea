// How each DUT sits in the station (docs/simulator.md "Several DUTs"): the
// Earth rate of a horizontal axis from its heading, and the rate table seen
// by two DUTs on different table axes, the second as much as the first.
// Without noise and with K = 1 every sample is exact, so each axis's last
// sample is checked against the physics written out here: the table axis
// sees the table's rate and the vertical Earth rate, a horizontal axis with
// a heading h sees Ω cos φ cos(h + table position) and no table rate, one
// without a heading its bias alone.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "gyrotherm/config/config.h"
#include "gyrotherm/sim/dut_model.h"
#include "gyrotherm/sim/options.h"
#include "gyrotherm/sim/simulator.h"
#include "sim_test_util.h"

namespace gyrotherm::sim {
namespace {

using namespace std::chrono_literals;
using test_util::wait_for;

constexpr double kMountingLatitudeDeg = 31.9;
constexpr double kDegToRad = M_PI / 180.0;
// Ω_E's components in local north and up, written out rather than taken
// from the code under test.
const double kNorthEarthDph = 15.041067 * std::cos(kMountingLatitudeDeg * kDegToRad);
const double kUpEarthDph = 15.041067 * std::sin(kMountingLatitudeDeg * kDegToRad);

// A: table axis z (up), x and y horizontal with headings. B: table axis x
// (up), y horizontal with a heading, z horizontal without one.
constexpr const char* kMountingStation = R"([station]
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
protocol = "kvh1750"
rate_hz = 10
axes = ["x", "y", "z"]
orientation = { z = "up", x = "horizontal", y = "horizontal" }
heading_deg = { x = 30.0, y = 300.0 }
primary_axis = "z"
table_axis = "z"
[[dut]]
serial = "B-2"
protocol = "kvh1750"
rate_hz = 10
axes = ["x", "y", "z"]
orientation = { x = "up", y = "horizontal", z = "horizontal" }
heading_deg = { y = 135.0 }
primary_axis = "x"
table_axis = "x"
[table]
profile = "acutrol"
host = "127.0.0.1"
port = 9878
max_rate_dps = 500.0
max_accel_dps2 = 1000.0
[simulator]
endpoints_file = "unused"
seed = 3
[simulator.thermal]
control_noise_c = 0.0
probe_noise_c = 0.0
[simulator.gyro]
bias_dph = 0.0
white_noise_dph = 0.0
bias_instability_dph = 0.0
[simulator.scale_factor]
k_ppm = 0.0
k_tc_ppm_per_c = 0.0
asymmetry_ppm = 0.0
nonlinearity_ppm = 0.0
[simulator.dut.A-1.x]
bias_dph = 5.0
[simulator.dut.A-1.y]
bias_dph = -3.0
[simulator.dut.A-1.z]
bias_dph = 2.0
[simulator.dut.B-2.x]
bias_dph = 1.0
[simulator.dut.B-2.y]
bias_dph = 4.0
[simulator.dut.B-2.z]
bias_dph = -2.0
)";

class DutMountingTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char dir_template[] = "/tmp/gyrotherm-mounting-test-XXXXXX";
    ASSERT_NE(::mkdtemp(dir_template), nullptr);
    dir_ = dir_template;
  }
  void TearDown() override {
    sim_.reset();
    std::filesystem::remove_all(dir_);
  }
  void start(const std::string& text = kMountingStation) {
    auto config = config::parse_station_config(text, "mounting.toml");
    ASSERT_TRUE(config.ok()) << config.error().message;
    config_ = std::move(config).value();
    SimulatorOverrides overrides;
    overrides.endpoints_file = dir_ + "/endpoints.toml";
    overrides.truth_file = dir_ + "/truth.json";
    auto options = read_simulator_options(config_, overrides);
    ASSERT_TRUE(options.ok()) << options.error().message;
    auto sim = Simulator::create(config_, *options, &clock_);
    ASSERT_TRUE(sim.ok()) << sim.error().message;
    sim_ = std::move(sim).value();
    Status s = sim_->start();
    ASSERT_TRUE(s.ok()) << s.error().message;
  }
  void advance(double dt_s) {
    clock_.advance(dt_s);
    const double target_s = clock_.now_s() - 1e-6;
    ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= target_s; }, 10s));
  }
  void acl(const std::string& line) {
    const AclReply r = sim_->table_acl(line);
    ASSERT_EQ(r.code, 0) << line << " -> " << r.payload;
  }
  // Each axis's last sample against the physics at the table's rate and
  // position now.
  void expect_physics(const std::string& when) {
    const SimulatorStatus s = sim_->status();
    ASSERT_EQ(s.duts.size(), 2u);
    const double table_dph = s.table.state.rate_dps * 3600.0;
    const double p = s.table.state.position_deg;
    const auto horizontal = [&](double heading_deg) {
      return kNorthEarthDph * std::cos((heading_deg + p) * kDegToRad);
    };
    const auto& a = s.duts[0].last_rates_dph;
    const auto& b = s.duts[1].last_rates_dph;
    const double tol = 1e-9 * std::max(1.0, std::abs(table_dph));
    EXPECT_NEAR(a[2], table_dph + kUpEarthDph + 2.0, tol) << when << ": A z (table axis)";
    EXPECT_NEAR(a[0], 5.0 + horizontal(30.0), 1e-9) << when << ": A x";
    EXPECT_NEAR(a[1], -3.0 + horizontal(300.0), 1e-9) << when << ": A y";
    EXPECT_NEAR(b[0], table_dph + kUpEarthDph + 1.0, tol) << when << ": B x (table axis)";
    EXPECT_NEAR(b[1], 4.0 + horizontal(135.0), 1e-9) << when << ": B y";
    EXPECT_NEAR(b[2], -2.0, 1e-9) << when << ": B z (no heading: east-west)";
  }

  std::string dir_;
  config::StationConfig config_;
  ManualClock clock_;
  std::unique_ptr<Simulator> sim_;
};

TEST_F(DutMountingTest, EachDutsTableAxisSeesTheTableAndItsHorizontalAxesTurnWithIt) {
  ASSERT_NO_FATAL_FAILURE(start());
  ASSERT_TRUE(sim_->has_table());
  advance(1.0);
  ASSERT_NEAR(sim_->status().table.state.position_deg, 0.0, 1e-12);
  expect_physics("at rest at 0°");

  // To 90° and held: the horizontal axes' Earth rate turned by 90°.
  acl(":U:L ON;:I:R;:D:P 1,90;:M:P 1;:I:C 1");
  advance(20.0);
  ASSERT_NEAR(sim_->status().table.state.position_deg, 90.0, 1e-3);
  ASSERT_NEAR(sim_->status().table.state.rate_dps, 0.0, 1e-6);
  expect_physics("at rest at 90°");

  // Spinning at 10 °/s: both table axes see 36 000 °/h, the others none of it.
  acl(":D:R 1,10;:M:R 1");
  advance(2.0);
  ASSERT_NEAR(sim_->status().table.state.rate_dps, 10.0, 1e-9);
  expect_physics("at 10 °/s");
  advance(7.3);
  expect_physics("at 10 °/s, later");
}

TEST_F(DutMountingTest, TruthNamesEachAxisHeadingTableAndEarthRateAtPositionZero) {
  ASSERT_NO_FATAL_FAILURE(start());
  std::ifstream in(dir_ + "/truth.json");
  ASSERT_TRUE(in);
  const auto truth = nlohmann::json::parse(in);
  const auto& a = truth["duts"][0]["axes"];
  const auto& b = truth["duts"][1]["axes"];
  EXPECT_EQ(truth["duts"][1]["table_axis"], "x");
  EXPECT_EQ(a["z"]["on_table"], true);
  EXPECT_EQ(b["x"]["on_table"], true);
  EXPECT_EQ(a["x"]["on_table"], false);
  EXPECT_EQ(a["x"]["heading_deg"], 30.0);
  EXPECT_EQ(a["x"]["turns_with_table"], true);
  EXPECT_NEAR(a["x"]["earth_rate_dph"].get<double>(), kNorthEarthDph * std::cos(30.0 * kDegToRad),
              1e-12);
  EXPECT_NEAR(b["y"]["earth_rate_dph"].get<double>(), kNorthEarthDph * std::cos(135.0 * kDegToRad),
              1e-12);
  EXPECT_TRUE(b["z"]["heading_deg"].is_null());
  EXPECT_EQ(b["z"]["earth_rate_dph"], 0.0);
  EXPECT_EQ(b["z"]["turns_with_table"], false);
  EXPECT_NEAR(b["x"]["earth_rate_dph"].get<double>(), kUpEarthDph, 1e-12);
}

// Without a table a horizontal axis keeps its heading's Earth rate; the
// frames' mean (noise on) carries Ω cos φ cos h.
TEST(DutModelHeading, HorizontalAxisMeanCarriesCosLatitudeCosHeading) {
  const std::string station(kMountingStation);
  auto config = config::parse_station_config(
      station.substr(0, station.find("[table]")) + "[simulator]\nendpoints_file = \"unused\"\n",
      "mounting.toml");
  ASSERT_TRUE(config.ok()) << config.error().message;
  const config::DutSection& dut = config->duts[0];
  DutSimParams params;
  params.serial = dut.serial;
  for (auto& axis : params.axes) axis.white_noise_dph = 0.5;
  params.axes[0].bias_dph = 5.0;
  ThermalParams thermal;
  DutShell shell(thermal, {}, 0.0, 11);
  auto model = DutModel::create(dut, 0, params, config->station, std::nullopt, {}, {1, 2, 3}, 4);
  ASSERT_TRUE(model.ok()) << model.error().message;
  EXPECT_FALSE(model->axis_model(0).turns_with_table());  // no table
  std::vector<uint8_t> bytes;
  double sum_x = 0, sum_y = 0;
  const int n = 36000;  // an hour at 10 Hz: σ of the mean 0.5 / √3600 °/h
  for (int i = 0; i < n; ++i) {
    const DutSample s = model->next_frame(shell.truth(), {}, bytes);
    sum_x += s.rate_dph[0];
    sum_y += s.rate_dph[1];
    bytes.clear();
  }
  EXPECT_NEAR(sum_x / n, 5.0 + kNorthEarthDph * std::cos(30.0 * kDegToRad), 0.05);
  EXPECT_NEAR(sum_y / n, kNorthEarthDph * std::cos(300.0 * kDegToRad), 0.05);
}

}  // namespace
}  // namespace gyrotherm::sim
