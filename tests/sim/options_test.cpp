#include "gyrotherm/sim/options.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <regex>

#include "test_files.h"

namespace gyrotherm::sim {
namespace {

std::string demo_text() {
  return testing::read_text(std::string(GYROTHERM_SOURCE_DIR) + "/config/demo.toml");
}

std::string replace(std::string text, const std::string& from, const std::string& to) {
  const auto pos = text.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  if (pos != std::string::npos) text.replace(pos, from.size(), to);
  return text;
}

Result<SimulatorOptions> options_from(const std::string& text,
                                      const SimulatorOverrides& overrides = {}) {
  auto config = daemon::parse_station_config(text, "/nonexistent/demo.toml");
  if (!config.ok()) return config.error();
  return read_simulator_options(*config, overrides);
}

TEST(SimulatorOptions, ErrorsNameTheLineOfTheSimulatorKey) {
  const std::string text =
      "[station]\n[chamber]\n[probes]\n[gyro]\ndevice = \"x\"\n[simulator]\nseed = 1\n"
      "bogus = 2\n[simulator.thermal]\ncase_tau_s = \"slow\"\n";
  auto o = options_from(text);
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("/nonexistent/demo.toml:8: simulator.bogus: unknown key"),
            std::string::npos)
      << o.error().message;
  EXPECT_NE(o.error().message.find(
                "/nonexistent/demo.toml:10: simulator.thermal.case_tau_s: expected a number"),
            std::string::npos)
      << o.error().message;
}

TEST(SimulatorOptions, ReadsEveryDemoKey) {
  auto o = options_from(demo_text());
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(o->endpoints_file, "demo/sim-endpoints.toml");
  EXPECT_EQ(o->truth_file, "demo/sim-truth.json");
  EXPECT_EQ(o->gyro_link, "demo/gyro-pty");
  EXPECT_EQ(o->control_socket, "demo/sim.sock");
  EXPECT_EQ(o->modbus_port, 0);
  EXPECT_EQ(o->seed, 1u);
  EXPECT_DOUBLE_EQ(o->thermal.initial_temp_c, 23.0);
  EXPECT_DOUBLE_EQ(o->thermal.air_tau_s, 120.0);
  EXPECT_DOUBLE_EQ(o->thermal.case_tau_s, 900.0);
  EXPECT_DOUBLE_EQ(o->thermal.max_ramp_c_per_min, 5.0);
  EXPECT_DOUBLE_EQ(o->thermal.control_noise_c, 0.5);
  EXPECT_DOUBLE_EQ(o->thermal.gradient_c_per_c_per_min, 1.0);
  EXPECT_DOUBLE_EQ(o->thermal.gradient_offset_c, 0.05);
  EXPECT_DOUBLE_EQ(o->thermal.gradient_tau_s, 1800.0);
  EXPECT_DOUBLE_EQ(o->thermal.probe_noise_c, 0.02);
  EXPECT_DOUBLE_EQ(o->thermal.probe_quantum_c, 0.01);
  EXPECT_DOUBLE_EQ(o->gyro.bias_dph, 0.05);
  EXPECT_EQ(o->gyro.temp_coeffs, (std::vector<double>{0.004, -8.0e-5}));
  EXPECT_EQ(o->gyro.rate_coeffs, (std::vector<double>{12.0}));
  EXPECT_EQ(o->gyro.gradient_coeffs, (std::vector<double>{0.5}));
  EXPECT_DOUBLE_EQ(o->gyro.white_noise_dph, 1.0);
  EXPECT_DOUBLE_EQ(o->gyro.bias_instability_dph, 0.02);
  EXPECT_DOUBLE_EQ(o->gyro.bias_instability_tau_s, 300.0);
  EXPECT_DOUBLE_EQ(o->gyro.rate_random_walk_dph_per_sqrt_h, 0.0);
  EXPECT_DOUBLE_EQ(o->gyro_format.rate_hz, 10.0);
  EXPECT_EQ(o->gyro_format.axis, 2);
  EXPECT_DOUBLE_EQ(o->time_scale, 1.0);
}

TEST(SimulatorOptions, OverridesWin) {
  SimulatorOverrides ov;
  ov.time_scale = 1000;
  ov.seed = 99;
  ov.rate_hz = 200;
  ov.truth_file = "t.json";
  ov.endpoints_file = "e.toml";
  ov.control_socket = "c.sock";
  auto o = options_from(demo_text(), ov);
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_DOUBLE_EQ(o->time_scale, 1000);
  EXPECT_EQ(o->seed, 99u);
  EXPECT_DOUBLE_EQ(o->gyro_format.rate_hz, 200);
  EXPECT_EQ(o->truth_file, "t.json");
  EXPECT_EQ(o->endpoints_file, "e.toml");
  EXPECT_EQ(o->control_socket, "c.sock");
}

TEST(SimulatorOptions, EveryProblemIsReportedWithFileLineAndKey) {
  std::string text = demo_text();
  text = replace(text, "air_tau_s = 120.0", "air_tau_s = -5.0\nbogus_thermal = 1");
  text = replace(text, "temp_coeffs = [0.004, -8.0e-5]", "temp_coeffs = [0.004, \"x\"]");
  text = replace(text, "seed = 1\n", "seed = 1\nmystery = true\n");
  auto o = options_from(text);
  ASSERT_FALSE(o.ok());
  const std::string& m = o.error().message;
  EXPECT_NE(m.find("demo.toml:"), std::string::npos) << m;
  EXPECT_NE(m.find("simulator.thermal.air_tau_s"), std::string::npos) << m;
  EXPECT_NE(m.find("simulator.thermal.bogus_thermal: unknown key"), std::string::npos) << m;
  EXPECT_NE(m.find("simulator.gyro.temp_coeffs"), std::string::npos) << m;
  EXPECT_NE(m.find("simulator.mystery: unknown key"), std::string::npos) << m;
}

TEST(SimulatorOptions, ErrorsFromAFileCarryLineNumbers) {
  const std::string path = std::filesystem::temp_directory_path() /
                           ("gyrotherm-sim-options-" + std::to_string(::getpid()) + ".toml");
  {
    std::ofstream out(path);
    out << replace(demo_text(), "case_tau_s = 900.0", "case_tau_s = 900.0\nunknown_knob = 3");
  }
  auto config = daemon::load_station_config(path);
  ASSERT_TRUE(config.ok()) << config.error().message;  // [simulator] is not the daemon's
  auto o = read_simulator_options(*config);
  std::filesystem::remove(path);
  ASSERT_FALSE(o.ok());
  EXPECT_TRUE(std::regex_search(
      o.error().message,
      std::regex(R"(\.toml:[0-9]+: simulator\.thermal\.unknown_knob: unknown key)")))
      << o.error().message;
}

TEST(SimulatorOptions, BadOverrideIsAnError) {
  SimulatorOverrides ov;
  ov.time_scale = -1;
  auto o = options_from(demo_text(), ov);
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("time scale"), std::string::npos) << o.error().message;
}

TEST(SimulatorOptions, ControlSocketPathMustFitASocketAddress) {
  SimulatorOverrides ov;
  ov.control_socket = std::string(kMaxControlSocketPath, 'x');
  EXPECT_TRUE(options_from(demo_text(), ov).ok());
  ov.control_socket = std::string(kMaxControlSocketPath + 1, 'x');
  auto o = options_from(demo_text(), ov);
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("control_socket"), std::string::npos) << o.error().message;
  EXPECT_NE(o.error().message.find("at most 107"), std::string::npos) << o.error().message;
}

TEST(SimulatorOptions, ReadsTheTableAndScaleFactorSections) {
  const std::string base = "[station]\n[chamber]\n[probes]\n[gyro]\ndevice = \"x\"\n[simulator]\n";
  auto o = options_from(base +
                        "table_port = 9878\n[simulator.table]\nmax_accel_dps2 = 4200\n"
                        "reply_header = \"binary-be\"\n[simulator.scale_factor]\nk_ppm = -80\n");
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(o->table_port, 9878);
  EXPECT_EQ(o->table.max_accel_dps2, 4200);
  EXPECT_EQ(o->table.max_jerk_dps3, 5000);  // default
  EXPECT_EQ(o->table.reply_header, "binary-be");
  EXPECT_EQ(o->scale_factor.k_ppm, -80);
  EXPECT_FALSE(o->serve_table);  // no [table], no --table
  SimulatorOverrides with_table;
  with_table.serve_table = true;
  with_table.table_port = 0;
  auto t = options_from(base, with_table);
  ASSERT_TRUE(t.ok());
  EXPECT_TRUE(t->serve_table);
  EXPECT_EQ(t->table_port, 0);

  auto bad = options_from(base + "[simulator.table]\nreply_header = \"xml\"\n");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("simulator.table.reply_header"), std::string::npos)
      << bad.error().message;
  auto trip = options_from(base + "[simulator.table]\ntrip_rate_dps = 900\n");
  ASSERT_FALSE(trip.ok());
  EXPECT_NE(trip.error().message.find("trip_rate_dps"), std::string::npos) << trip.error().message;
}

}  // namespace
}  // namespace gyrotherm::sim
