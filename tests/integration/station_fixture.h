// The simulated station for end-to-end tests: a station config with fast
// thermal lags, a short schedule, and a fixture that runs gyrotherm-sim and
// gyrothermd as real processes in a temporary folder.
#pragma once

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "gyrotherm/cli/http_client.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/sim/simulator.h"
#include "gyrotherm/storage/database.h"
#include "process.h"
#include "storage/test_util.h"
#include "temp_dir_test.h"

namespace gyrotherm::testing {

namespace fs = std::filesystem;

// Each acquisition window with the samples stored in it and its longest
// stretch without one (from the window's start, between samples, to its end):
// where a soak's Table I row lost its bins.
inline std::string window_coverage(storage::Database& db, int64_t run_id,
                                   const std::vector<std::pair<double, double>>& windows) {
  std::string out;
  for (const auto& [from_s, to_s] : windows) {
    auto samples = db.gyro_samples(run_id, from_s, to_s);
    if (!samples.ok()) return "window coverage unknown: " + samples.error().message + "\n";
    double prev_s = from_s, gap_s = 0, gap_at_s = from_s;
    for (const auto& g : *samples) {
      if (g.t_s - prev_s > gap_s) gap_s = g.t_s - prev_s, gap_at_s = prev_s;
      prev_s = g.t_s;
    }
    if (to_s - prev_s > gap_s) gap_s = to_s - prev_s, gap_at_s = prev_s;
    out +=
        fmt::format("window [{:.3f}, {:.3f}] s: {} samples, longest gap {:.3f} s from {:.3f} s\n",
                    from_s, to_s, samples->size(), gap_s, gap_at_s);
  }
  return out;
}

// Seconds of the windows no sample covers, each sample standing for one
// `period_s` after it and one missing sample bridged (how the station
// credits a soak): the stretches a window is longer than its soak by.
inline double uncovered_s(storage::Database& db, int64_t run_id,
                          const std::vector<std::pair<double, double>>& windows, double period_s) {
  double out = 0;
  for (const auto& [from_s, to_s] : windows) {
    auto samples = db.gyro_samples(run_id, from_s, to_s);
    if (!samples.ok() || samples->empty()) {
      out += to_s - from_s;
      continue;
    }
    const auto gap = [&](double a_s, double b_s) {
      return b_s - a_s > 2 * period_s ? b_s - a_s - period_s : 0.0;
    };
    out += gap(from_s - period_s, samples->front().t_s);
    for (std::size_t i = 1; i < samples->size(); ++i) {
      out += gap((*samples)[i - 1].t_s, (*samples)[i].t_s);
    }
    out += gap(samples->back().t_s, to_s);
  }
  return out;
}

inline constexpr double kTimeScale = 200.0;
inline constexpr double kRateHz = 10.0;
inline constexpr double kWhiteNoiseDph = 1.0;
inline constexpr double kLatitudeDeg = 31.9;

// The station: fast thermal lags so a short schedule settles quickly.
inline std::string station_config(const fs::path& dir, int api_port) {
  return fmt::format(R"(
[station]
name = "integration"
latitude_deg = {lat}
orientation = "up"
max_ramp_c_per_min = 3.0
[chamber]
unit_id = 1
profile = "watlow-f4t"
silent_timeout_s = 60.0
[chamber.alarm]
address = 1356
[probes]
unit_id = 2
profile = "generic"
channels = {{ top = 0, side = 1 }}
silent_timeout_s = 60.0
[gyro]
silent_timeout_s = 60.0
unit = "rad"
output = "rate"
axis = "z"
rate_hz = {rate}
[storage]
db = "{dir}/station.db"
commit_interval_s = 0.2
[analysis]
model = "T1+R1+G1"
[api]
port = {port}
tokens = ["integration-token-0123456789"]
[simulator]
endpoints_file = "{dir}/endpoints.toml"
truth_file = "{dir}/truth.json"
gyro_link = "{dir}/gyro-pty"
control_socket = "{dir}/sim.sock"
seed = 7
initial_temp_c = 23.0
[simulator.thermal]
air_tau_s = 20.0
case_tau_s = 60.0
max_ramp_c_per_min = 5.0
control_noise_c = 0.1
[simulator.gyro]
bias_dph = 0.05
temp_coeffs = [0.004]
rate_coeffs = [12.0]
gradient_coeffs = [0.5]
white_noise_dph = {noise}
bias_instability_dph = 0.0
)",
                     fmt::arg("lat", kLatitudeDeg), fmt::arg("rate", kRateHz),
                     fmt::arg("dir", dir.string()), fmt::arg("port", api_port),
                     fmt::arg("noise", kWhiteNoiseDph));
}

inline constexpr const char* kSchedule = R"(
name = "integration"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 2
acquire_min = 6
[[step]]
type = "ramp"
target_c = 26.0
rate_c_per_min = 2.0
[[step]]
type = "soak"
setpoint_c = 26.0
stability_window_min = 2
acquire_min = 6
)";

// A schedule of one soak.
inline std::string soak_schedule(const std::string& name, double setpoint_c, double acquire_min,
                                 double stability_window_min = 2) {
  return fmt::format(R"(name = "{}"
[[step]]
type = "soak"
setpoint_c = {}
stability_window_min = {}
acquire_min = {}
)",
                     name, setpoint_c, stability_window_min, acquire_min);
}

// The database passes PRAGMA integrity_check: its rows are exactly {"ok"}.
using storage::testing::integrity_ok;

class StationTest : public testing::TempDirTest {
 protected:
  StationTest() : TempDirTest("gyrotherm-it") {}
  void SetUp() override {
    TempDirTest::SetUp();
    api_port_ = testing::free_tcp_port();
    write(dir_ / "station.toml", station_config(dir_, api_port_));
    write(dir_ / "schedule.toml", kSchedule);
  }
  void TearDown() override {
    daemon_.reset();
    sim_.reset();
    in_process_sim_.reset();
    TempDirTest::TearDown();
  }

  static void write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }
  // Appends TOML (e.g. an [export] section) to the station config.
  void append_config(const std::string& text) {
    std::ofstream(dir_ / "station.toml", std::ios::app) << "\n" << text << "\n";
  }
  std::string bin(const char* name) const { return std::string(GYROTHERM_BIN_DIR) + "/" + name; }
  std::string url(const std::string& path) const {
    return fmt::format("http://127.0.0.1:{}{}", api_port_, path);
  }

  void start_sim() {
    sim_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{bin("gyrotherm-sim"), "--config", (dir_ / "station.toml").string(),
                                 "--time-scale", fmt::format("{}", time_scale_)},
        (dir_ / "sim.log").string());
    ASSERT_TRUE(
        wait_until([&] { return fs::exists(dir_ / "endpoints.toml"); }, std::chrono::seconds(20)))
        << sim_->log();
  }
  // The simulator in this process, for its fault hooks.
  void start_sim_in_process() {
    auto cfg = config::load_station_config((dir_ / "station.toml").string());
    ASSERT_TRUE(cfg.ok()) << cfg.error().message;
    sim::SimulatorOverrides overrides;
    overrides.time_scale = time_scale_;
    auto options = sim::read_simulator_options(*cfg, overrides);
    ASSERT_TRUE(options.ok()) << options.error().message;
    auto simulator = sim::Simulator::create(*cfg, *options);
    ASSERT_TRUE(simulator.ok()) << simulator.error().message;
    in_process_sim_ = std::move(*simulator);
    ASSERT_TRUE(in_process_sim_->start().ok());
  }
  // Starts gyrothermd; with_schedule queues schedule.toml at start-up.
  void start_daemon(std::vector<std::string> extra = {}, bool with_schedule = true) {
    std::vector<std::string> argv{bin("gyrothermd"), "--config", (dir_ / "station.toml").string(),
                                  "--time-scale", fmt::format("{}", time_scale_)};
    if (with_schedule) {
      argv.push_back("--schedule");
      argv.push_back((dir_ / "schedule.toml").string());
    }
    argv.insert(argv.end(), extra.begin(), extra.end());
    daemon_ = std::make_unique<ChildProcess>(argv, (dir_ / "daemon.log").string());
  }
  std::optional<nlohmann::json> status() {
    auto r =
        cli::http_request("GET", url("/api/v1/status"), "", "", std::chrono::milliseconds(500));
    if (!r || r->status != 200) return std::nullopt;
    return nlohmann::json::parse(r->body, nullptr, false);
  }

  // A request to the daemon; nullopt when it does not answer.
  std::optional<cli::HttpResult> call(const std::string& method, const std::string& path,
                                      const std::string& body = "",
                                      const std::string& token = kToken) {
    auto r = cli::http_request(method, url(path), body, token, std::chrono::seconds(5));
    if (!r) return std::nullopt;
    return *r;
  }
  nlohmann::json get_json(const std::string& path) {
    auto r = call("GET", path, "", "");
    if (!r || r->status != 200) return nullptr;
    return nlohmann::json::parse(r->body, nullptr, false);
  }
  // One fault-injection command through `gyrotherm-sim ctl`; true on "ok".
  bool sim_ctl(const std::string& command) {
    std::vector<std::string> argv{bin("gyrotherm-sim"), "ctl", "--socket",
                                  (dir_ / "sim.sock").string()};
    std::string word;
    for (std::istringstream in(command); in >> word;) argv.push_back(word);
    ChildProcess ctl(argv, (dir_ / "ctl.log").string());
    const auto code = ctl.wait(std::chrono::seconds(10));
    return code && *code == 0;
  }

  static constexpr const char* kToken = "integration-token-0123456789";

  int api_port_ = 0;
  double time_scale_ = kTimeScale;  // of the simulator and daemon started next
  std::unique_ptr<ChildProcess> sim_;
  std::unique_ptr<sim::Simulator> in_process_sim_;
  std::unique_ptr<ChildProcess> daemon_;
};

}  // namespace gyrotherm::testing
