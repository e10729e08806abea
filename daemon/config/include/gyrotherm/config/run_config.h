// The station config as each run stores it (runs.config_json and
// run_duts.config_json, as JSON laid out like station.toml), and what a
// run's stored config says, read back leniently. Next to the TOML reader
// (config.h), so that a new key is written and read back in one library.
// The overload that reads a storage::RunRecord is in run_analysis.h
// (calibration): the config library does not link storage.
#pragma once

#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>

namespace gyrotherm::config {

struct StationConfig;
struct DutSection;

// The configuration a run is stored with (runs.config_json): the station
// config in force, as loaded at start-up and completed with the defaults,
// as a JSON object laid out like the TOML file ({"station": {"name": ...},
// "analysis": {"ma_window": 101, ...}, ...}); API tokens are replaced by
// "<redacted>" (the lists keep their length).
// The DUTs are under "duts", one object per [[dut]] as dut_config_json().
nlohmann::json run_config_json(const StationConfig& config);
// One [[dut]] as stored (runs.config_json "duts", run_duts.config_json):
// {"serial", "model", "protocol", "device", "baud", "parity", "unit",
// "output", "rate_hz", "axes": [..], "primary_axis", "table_axis",
// "orientation": {"z": "up", "x": "horizontal", ...} (every analysed axis),
// "heading_deg": {"x": 90.0, ...} (the horizontal axes given one),
// "silent_timeout_s", "probes": {"top_channel", "side_channel"} | null,
// "ascii": {...} | null}. What analysed_axes() reads back.
nlohmann::json dut_config_json(const DutSection& dut);

// What a run's stored station config says under [analysis] and [station]
// name: runs.config_json (JSON), or for runs stored before schema v6
// runs.config_toml (the config file's TOML text). Read leniently: a config
// that is missing or does not parse, or a key of the wrong type, leaves the
// value unset. The text overload takes either (JSON when it starts with '{').
struct RunConfig {
  std::optional<double> bin_s, l0_window_s, derivative_window_s;
  std::optional<int> ma_window, compare_smooth_points;
  std::optional<std::string> model;
  std::optional<std::string> allan_taus;
  std::string station_name;
  // [table]: whether the run had one, and how the gyro sits on it.
  bool table_present = false;
  std::optional<std::string> table_sensitive_axis;
  std::optional<double> table_heading_at_zero_deg;
  std::optional<double> table_rest_rate_dps;
  // [analysis] rate points and [quality] (schema v11 runs store them).
  std::optional<double> rate_guard_s, rate_flatness_sigma, rate_flatness_ppm;
  std::optional<double> min_coverage, k_min, k_max, max_nonlinearity_ppm, max_residual_ratio;
  // [gyro] rate_hz: the output rate of a run without DUT records.
  std::optional<double> gyro_rate_hz;
};
RunConfig read_run_config(const std::string& text);

}  // namespace gyrotherm::config
