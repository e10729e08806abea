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
  auto config = config::parse_station_config(text, "/nonexistent/demo.toml");
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
  auto config = config::load_station_config(path);
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

// --rate-hz HZ (every DUT) and SERIAL=HZ (one DUT, winning), in any order.
TEST(RateHzOption, ParsesEveryDutAndOneDutValues) {
  SimulatorOverrides ov;
  ASSERT_TRUE(parse_rate_hz_options({"TS-7=2.5", "20", "17-0043=1e3"}, ov).ok());
  EXPECT_EQ(ov.rate_hz, 20.0);
  EXPECT_EQ(ov.dut_rate_hz,
            (std::vector<std::pair<std::string, double>>{{"TS-7", 2.5}, {"17-0043", 1000.0}}));
  SimulatorOverrides none;
  ASSERT_TRUE(parse_rate_hz_options({}, none).ok());
  EXPECT_FALSE(none.rate_hz);
  EXPECT_TRUE(none.dut_rate_hz.empty());
  // A serial holding '=' splits at the last one.
  SimulatorOverrides odd;
  ASSERT_TRUE(parse_rate_hz_options({"A=B=5"}, odd).ok());
  EXPECT_EQ(odd.dut_rate_hz, (std::vector<std::pair<std::string, double>>{{"A=B", 5.0}}));
}

TEST(RateHzOption, BadValuesAreErrorsNamingTheValue) {
  const std::pair<std::vector<std::string>, std::string> bad[] = {
      {{"fast"}, "--rate-hz 'fast': 'fast' is not a number of Hz"},
      {{"20Hz"}, "--rate-hz '20Hz': '20Hz' is not a number of Hz"},
      {{"nan"}, "--rate-hz 'nan': 'nan' is not a number of Hz"},
      {{""}, "--rate-hz '': '' is not a number of Hz"},
      {{"TS-7="}, "--rate-hz 'TS-7=': '' is not a number of Hz"},
      {{"TS-7=x"}, "--rate-hz 'TS-7=x': 'x' is not a number of Hz"},
      {{"=5"}, "--rate-hz '=5': no serial before '='"},
      {{"0.05"}, "--rate-hz '0.05': 0.05 Hz is outside [0.1, 10000]"},
      {{"TS-7=20000"}, "--rate-hz 'TS-7=20000': 20000 Hz is outside [0.1, 10000]"},
      {{"-10"}, "--rate-hz '-10': -10 Hz is outside [0.1, 10000]"},
      {{"20", "30"}, "--rate-hz '30': every DUT's rate is already given (20 Hz)"},
      {{"A=1", "B=2", "A=3"}, "--rate-hz 'A=3': DUT 'A' is already given (1 Hz)"},
  };
  for (const auto& [values, expected] : bad) {
    SimulatorOverrides ov;
    const Status st = parse_rate_hz_options(values, ov);
    ASSERT_FALSE(st.ok()) << expected;
    EXPECT_EQ(st.error().message.rfind(expected, 0), 0u) << st.error().message;
  }
}

TEST(RateHzOption, ResolvesEachDutsRateAndRefusesAnUnknownSerial) {
  auto config = config::parse_station_config(demo_text(), "demo.toml");
  ASSERT_TRUE(config.ok()) << config.error().message;
  const auto& duts = config->duts;
  ASSERT_EQ(duts.size(), 3u);
  const auto rates = [&](const SimulatorOptions& o) {
    std::vector<double> out;
    for (const auto& d : duts) out.push_back(dut_rate_hz(o, d));
    return out;
  };
  // Nothing given: each DUT's [[dut]] rate_hz.
  auto plain = read_simulator_options(*config);
  ASSERT_TRUE(plain.ok()) << plain.error().message;
  EXPECT_EQ(rates(*plain), (std::vector<double>{10.0, 10.0, 10.0}));
  // Every DUT, then one DUT over it; the first DUT's is "the gyro's".
  SimulatorOverrides ov;
  ASSERT_TRUE(parse_rate_hz_options({"25", "TS-7=5"}, ov).ok());
  auto both = read_simulator_options(*config, ov);
  ASSERT_TRUE(both.ok()) << both.error().message;
  EXPECT_EQ(rates(*both), (std::vector<double>{25.0, 25.0, 5.0}));
  EXPECT_EQ(both->gyro_format.rate_hz, 25.0);
  // Only one DUT: the others keep their own.
  SimulatorOverrides one;
  ASSERT_TRUE(parse_rate_hz_options({"17-0042=50"}, one).ok());
  auto first = read_simulator_options(*config, one);
  ASSERT_TRUE(first.ok()) << first.error().message;
  EXPECT_EQ(rates(*first), (std::vector<double>{50.0, 10.0, 10.0}));
  EXPECT_EQ(first->gyro_format.rate_hz, 50.0);

  SimulatorOverrides unknown;
  ASSERT_TRUE(parse_rate_hz_options({"NOPE=5"}, unknown).ok());
  EXPECT_EQ(unknown_rate_hz_serial(unknown.dut_rate_hz, duts),
            "--rate-hz 'NOPE=5': no [[dut]] with serial 'NOPE' (the station's DUTs: '17-0042', "
            "'17-0043', 'TS-7')");
  auto refused = read_simulator_options(*config, unknown);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("no [[dut]] with serial 'NOPE'"), std::string::npos)
      << refused.error().message;
  EXPECT_EQ(unknown_rate_hz_serial(ov.dut_rate_hz, duts), "");
}

}  // namespace
}  // namespace gyrotherm::sim
