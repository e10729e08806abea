#include "gyrotherm/sim/options.h"

#include <fmt/format.h>

#include <cmath>

#include "gyrotherm/core/time_scale.h"
#include "gyrotherm/core/toml_reader.h"

namespace gyrotherm::sim {
namespace {

void read_coeffs(TableReader& t, std::string_view key, std::vector<double>& out) {
  const toml::array* a = t.array(key);
  if (!a) return;
  std::vector<double> values;
  for (const auto& node : *a) {
    if (auto i = node.value_exact<int64_t>()) {
      values.push_back(static_cast<double>(*i));
    } else if (auto d = node.value_exact<double>(); d && std::isfinite(*d)) {
      values.push_back(*d);
    } else {
      t.error(key, "must be an array of finite numbers");
      return;
    }
  }
  if (values.size() > 8) {
    t.error(key, fmt::format("has {} entries (at most 8: orders 1..8)", values.size()));
    return;
  }
  out = std::move(values);
}

void read_thermal(TableReader t, ThermalParams& p) {
  p.air_tau_s = t.number_in("air_tau_s", p.air_tau_s, 0, 1e6);
  p.case_tau_s = t.number_in("case_tau_s", p.case_tau_s, 0, 1e6);
  p.max_ramp_c_per_min = t.number_in("max_ramp_c_per_min", p.max_ramp_c_per_min, 1e-3, 1000);
  p.control_noise_c = t.number_in("control_noise_c", p.control_noise_c, 0, 20);
  p.control_noise_tau_s = t.number_in("control_noise_tau_s", p.control_noise_tau_s, 0.1, 1e6);
  p.gradient_c_per_c_per_min =
      t.number_in("gradient_c_per_c_per_min", p.gradient_c_per_c_per_min, -100, 100);
  p.gradient_offset_c = t.number_in("gradient_offset_c", p.gradient_offset_c, -50, 50);
  p.gradient_tau_s = t.number_in("gradient_tau_s", p.gradient_tau_s, 0, 1e6);
  p.probe_noise_c = t.number_in("probe_noise_c", p.probe_noise_c, 0, 10);
  p.probe_quantum_c = t.number_in("probe_quantum_c", p.probe_quantum_c, 0, 10);
  t.finish();
}

void read_gyro(TableReader t, GyroParams& p) {
  p.bias_dph = t.number_in("bias_dph", p.bias_dph, -1e5, 1e5);
  read_coeffs(t, "temp_coeffs", p.temp_coeffs);
  read_coeffs(t, "rate_coeffs", p.rate_coeffs);
  read_coeffs(t, "gradient_coeffs", p.gradient_coeffs);
  p.white_noise_dph = t.number_in("white_noise_dph", p.white_noise_dph, 0, 1e5);
  p.bias_instability_dph = t.number_in("bias_instability_dph", p.bias_instability_dph, 0, 1e5);
  p.bias_instability_tau_s =
      t.number_in("bias_instability_tau_s", p.bias_instability_tau_s, 1e-3, 1e8);
  p.rate_random_walk_dph_per_sqrt_h =
      t.number_in("rate_random_walk_dph_per_sqrt_h", p.rate_random_walk_dph_per_sqrt_h, 0, 1e5);
  p.accel_noise_g = t.number_in("accel_noise_g", p.accel_noise_g, 0, 10);
  t.finish();
}

void read_table(TableReader t, TableParams& p) {
  p.max_rate_dps = t.number_in("max_rate_dps", p.max_rate_dps, 1e-3, 1e5);
  p.max_accel_dps2 = t.number_in("max_accel_dps2", p.max_accel_dps2, 1e-3, 1e6);
  p.max_jerk_dps3 = t.number_in("max_jerk_dps3", p.max_jerk_dps3, 1e-3, 1e8);
  p.trip_rate_dps = t.number_in("trip_rate_dps", p.trip_rate_dps, 1e-3, 2e5);
  p.rate_noise_rel = t.number_in("rate_noise_rel", p.rate_noise_rel, 0, 0.1);
  if (auto h =
          t.choice("reply_header", {"ascii", "binary-le", "binary-be", "line"}, std::nullopt)) {
    p.reply_header = *h;
  }
  t.finish();
}

void read_scale_factor(TableReader t, ScaleFactorParams& p) {
  p.k_ppm = t.number_in("k_ppm", p.k_ppm, -1e5, 1e5);
  p.k_tc_ppm_per_c = t.number_in("k_tc_ppm_per_c", p.k_tc_ppm_per_c, -1e4, 1e4);
  p.reference_temp_c = t.number_in("reference_temp_c", p.reference_temp_c, -100, 200);
  p.asymmetry_ppm = t.number_in("asymmetry_ppm", p.asymmetry_ppm, -1e5, 1e5);
  p.nonlinearity_ppm = t.number_in("nonlinearity_ppm", p.nonlinearity_ppm, -1e5, 1e5);
  t.finish();
}

}  // namespace

bool SimulatorOptions::IsValid(std::string* error) const {
  if (!thermal.IsValid(error) || !gyro.IsValid(error) || !table.IsValid(error) ||
      !scale_factor.IsValid(error)) {
    return false;
  }
  auto fail = [&](std::string msg) {
    if (error) *error = std::move(msg);
    return false;
  };
  if (modbus_port < 0 || modbus_port > 65535) {
    return fail(fmt::format("modbus_port = {} is not a TCP port (0..65535)", modbus_port));
  }
  if (table_port < 0 || table_port > 65535) {
    return fail(fmt::format("table_port = {} is not a TCP port (0..65535)", table_port));
  }
  if (!(time_scale >= kMinTimeScale && time_scale <= kMaxTimeScale)) {
    return fail(
        fmt::format("time scale {:g} must be in [{:g}, {:g}] (above {:g} the daemon "
                    "cannot keep up with the gyro stream; see docs/simulator.md)",
                    time_scale, kMinTimeScale, kMaxTimeScale, kMaxTimeScale));
  }
  if (!(gyro_format.rate_hz >= 0.1 && gyro_format.rate_hz <= 10000)) {
    return fail(fmt::format("gyro rate_hz = {} must be in [0.1, 10000]", gyro_format.rate_hz));
  }
  if (control_socket.size() > kMaxControlSocketPath) {
    return fail(
        fmt::format("control_socket '{}' is {} bytes long; a Unix socket path holds at most {}",
                    control_socket, control_socket.size(), kMaxControlSocketPath));
  }
  if (gyro_format.axis < 0 || gyro_format.axis > 2) return fail("gyro axis must be x, y or z");
  return true;
}

Result<SimulatorOptions> read_simulator_options(const daemon::StationConfig& config,
                                                const SimulatorOverrides& overrides) {
  SimulatorOptions o;
  o.gyro_format = config.gyro.format;
  TomlErrors errors(config.source_path);
  const toml::table* simulator = config.simulator_table ? &*config.simulator_table : nullptr;
  if (simulator) {
    TableReader t(*simulator, "simulator", errors);
    if (auto f = t.string("endpoints_file")) o.endpoints_file = *f;
    if (auto f = t.string("truth_file")) o.truth_file = *f;
    if (auto f = t.string("gyro_link")) o.gyro_link = *f;
    if (auto f = t.string("control_socket")) o.control_socket = *f;
    if (auto p = t.integer("modbus_port")) {
      if (*p < 0 || *p > 65535)
        t.error("modbus_port", fmt::format("{} is not a TCP port", *p));
      else
        o.modbus_port = static_cast<int>(*p);
    }
    if (auto p = t.integer("table_port")) {
      if (*p < 0 || *p > 65535)
        t.error("table_port", fmt::format("{} is not a TCP port", *p));
      else
        o.table_port = static_cast<int>(*p);
    }
    if (auto s = t.integer("seed")) {
      if (*s < 0)
        t.error("seed", "must be a non-negative integer");
      else
        o.seed = static_cast<uint64_t>(*s);
    }
    if (auto u = t.choice("chamber_units", {"C", "F"}, std::nullopt)) {
      o.chamber_units =
          *u == "C" ? drivers::TemperatureUnit::kCelsius : drivers::TemperatureUnit::kFahrenheit;
    }
    o.thermal.initial_temp_c = t.number_in("initial_temp_c", o.thermal.initial_temp_c, -100, 200);
    if (auto th = t.table("thermal")) read_thermal(*th, o.thermal);
    if (auto g = t.table("gyro")) read_gyro(*g, o.gyro);
    if (auto tb = t.table("table")) read_table(*tb, o.table);
    if (auto sf = t.table("scale_factor")) read_scale_factor(*sf, o.scale_factor);
    if (auto n = t.integer("pending_frames_limit")) {
      if (*n < 0 || *n > 10'000'000)
        t.error("pending_frames_limit", "must be in [0, 10000000]");
      else
        o.pending_frames_limit = static_cast<std::size_t>(*n);
    }
    t.finish();
  }
  if (overrides.time_scale) o.time_scale = *overrides.time_scale;
  if (overrides.endpoints_file) o.endpoints_file = *overrides.endpoints_file;
  if (overrides.truth_file) o.truth_file = *overrides.truth_file;
  if (overrides.control_socket) o.control_socket = *overrides.control_socket;
  if (overrides.seed) o.seed = *overrides.seed;
  if (overrides.rate_hz) o.gyro_format.rate_hz = *overrides.rate_hz;
  if (overrides.table_port) o.table_port = *overrides.table_port;
  o.serve_table = overrides.serve_table || config.table.has_value();
  // Keys already reported above kept their defaults, so what IsValid() finds
  // now comes from the overrides or from combinations of keys.
  std::string message = errors.joined();
  if (std::string why; !o.IsValid(&why)) message += fmt::format("simulator options: {}\n", why);
  if (!message.empty()) return Error::Permanent(message);
  return o;
}

}  // namespace gyrotherm::sim
