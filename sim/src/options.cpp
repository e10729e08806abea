#include "gyrotherm/sim/options.h"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <cmath>

#include "gyrotherm/core/time_scale.h"
#include "gyrotherm/core/toml_reader.h"

namespace gyrotherm::sim {
namespace {

// The array's values, when every one is a finite number (integers too).
std::optional<std::vector<double>> finite_numbers(const toml::array& a) {
  std::vector<double> values;
  for (const auto& node : a) {
    if (auto i = node.value_exact<int64_t>()) {
      values.push_back(static_cast<double>(*i));
    } else if (auto d = node.value_exact<double>(); d && std::isfinite(*d)) {
      values.push_back(*d);
    } else {
      return std::nullopt;
    }
  }
  return values;
}

void read_coeffs(TableReader& t, std::string_view key, std::vector<double>& out) {
  const toml::array* a = t.array(key);
  if (!a) return;
  auto finite = finite_numbers(*a);
  if (!finite) {
    t.error(key, "must be an array of finite numbers");
    return;
  }
  std::vector<double> values = std::move(*finite);
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

// A number that may be absent: nullopt then (and when it is bad, reported).
std::optional<double> optional_in(TableReader& t, std::string_view key, double lo, double hi) {
  const auto v = t.number(key);
  if (!v) return std::nullopt;
  if (*v < lo || *v > hi) {
    t.error(key, fmt::format("{} is out of range: must be in [{}, {}]", *v, lo, hi));
    return std::nullopt;
  }
  return v;
}

std::optional<std::vector<double>> optional_coeffs(TableReader& t, std::string_view key) {
  if (!t.raw().contains(key)) return std::nullopt;
  const toml::array* a = t.array(key);
  if (!a) return std::nullopt;  // wrong type, reported
  auto finite = finite_numbers(*a);
  if (!finite) {
    t.error(key, "must be an array of finite numbers");
    return std::nullopt;
  }
  std::vector<double> values = std::move(*finite);
  if (values.size() > 8) {
    t.error(key, fmt::format("has {} entries (at most 8: orders 1..8)", values.size()));
    return std::nullopt;
  }
  return values;
}

// The GyroParams keys of a [simulator.dut.SN] (or .x) table; the caller
// finishes the table.
void read_gyro_overrides(TableReader& t, GyroOverrides& g) {
  g.bias_dph = optional_in(t, "bias_dph", -1e5, 1e5);
  g.temp_coeffs = optional_coeffs(t, "temp_coeffs");
  g.rate_coeffs = optional_coeffs(t, "rate_coeffs");
  g.gradient_coeffs = optional_coeffs(t, "gradient_coeffs");
  g.white_noise_dph = optional_in(t, "white_noise_dph", 0, 1e5);
  g.bias_instability_dph = optional_in(t, "bias_instability_dph", 0, 1e5);
  g.bias_instability_tau_s = optional_in(t, "bias_instability_tau_s", 1e-3, 1e8);
  g.rate_random_walk_dph_per_sqrt_h = optional_in(t, "rate_random_walk_dph_per_sqrt_h", 0, 1e5);
}

// A [lo, hi] range of [simulator.randomize]: two finite numbers, lo <= hi,
// both in [min, max].
std::optional<DrawRange> read_range(TableReader& t, std::string_view key, double min, double max) {
  if (!t.raw().contains(key)) return std::nullopt;
  const toml::array* a = t.array(key);
  if (!a) return std::nullopt;  // wrong type, reported
  const std::vector<double> v = finite_numbers(*a).value_or(std::vector<double>{});
  if (v.size() != 2) {
    t.error(key, "must be [lo, hi]: two finite numbers");
    return std::nullopt;
  }
  if (v[0] < min || v[1] > max || v[0] > v[1]) {
    t.error(key, fmt::format("[{}, {}] is not a range within [{}, {}] (lo <= hi)", v[0], v[1], min,
                             max));
    return std::nullopt;
  }
  return DrawRange{v[0], v[1]};
}

void read_randomize(TableReader t, RandomizeRanges& r) {
  r.white_noise_dph = read_range(t, "white_noise_dph", 0, 1e5);
  r.bias_instability_dph = read_range(t, "bias_instability_dph", 0, 1e5);
  r.rate_random_walk_dph_per_sqrt_h = read_range(t, "rate_random_walk_dph_per_sqrt_h", 0, 1e5);
  r.case_tau_s = read_range(t, "case_tau_s", 0, 1e6);
  r.air_tau_s = read_range(t, "air_tau_s", 0, 1e6);
  r.control_noise_c = read_range(t, "control_noise_c", 0, 20);
  t.finish();
}

// A DUT's draws, always ten in the same order whichever ranges are set.
void apply_randomize(const RandomizeRanges& ranges, uint64_t seed, int position, DutSimParams& r) {
  std::mt19937_64 rng(derive_seed(seed, kRandomizeStream + static_cast<uint64_t>(position)));
  const auto take = [&rng](const std::optional<DrawRange>& range, double& value) {
    std::mt19937_64 copy = rng;
    rng.discard(1);
    if (range) value = range->draw(copy);
  };
  for (GyroParams& p : r.axes) {
    take(ranges.white_noise_dph, p.white_noise_dph);
    take(ranges.bias_instability_dph, p.bias_instability_dph);
    take(ranges.rate_random_walk_dph_per_sqrt_h, p.rate_random_walk_dph_per_sqrt_h);
  }
  double case_tau_s = r.case_params.case_tau_s.value_or(0);
  take(ranges.case_tau_s, case_tau_s);
  if (ranges.case_tau_s) r.case_params.case_tau_s = case_tau_s;
}

}  // namespace

ThermalParams resolve_thermal_params(const SimulatorOptions& options) {
  ThermalParams p = options.thermal;
  std::mt19937_64 rng(derive_seed(options.seed, kChamberRandomizeStream));
  const auto take = [&rng](const std::optional<DrawRange>& range, double& value) {
    std::mt19937_64 copy = rng;
    rng.discard(1);
    if (range) value = range->draw(copy);
  };
  take(options.randomize.air_tau_s, p.air_tau_s);
  take(options.randomize.control_noise_c, p.control_noise_c);
  return p;
}

namespace {

void read_dut_overrides(TableReader& t, DutOverrides& d) {
  read_gyro_overrides(t, d.all);
  d.accel_noise_g = optional_in(t, "accel_noise_g", 0, 10);
  d.internal_temp_offset_c = optional_in(t, "internal_temp_offset_c", -50, 50);
  d.probe_offset_c = optional_in(t, "probe_offset_c", -50, 50);
  d.case_params.case_tau_s = optional_in(t, "case_tau_s", 0, 1e6);
  d.case_params.gradient_c_per_c_per_min = optional_in(t, "gradient_c_per_c_per_min", -100, 100);
  d.case_params.gradient_offset_c = optional_in(t, "gradient_offset_c", -50, 50);
  d.case_params.gradient_tau_s = optional_in(t, "gradient_tau_s", 0, 1e6);
  for (std::size_t i = 0; i < 3; ++i) {
    if (auto axis = t.table(kAxisNames[i])) {
      read_gyro_overrides(*axis, d.axis[i]);
      axis->finish();
    }
  }
}

// [simulator.dut.SN] tables, or [[simulator.dut]] entries with serial; each
// must name a DUT of the station (the serials of `duts`), once.
void read_duts(TableReader& simulator, const std::vector<config::DutSection>& duts,
               std::vector<DutOverrides>& out) {
  const toml::node* node = simulator.raw().get("dut");
  if (!node) return;
  simulator.skip("dut");
  auto known = [&](const std::string& serial) {
    return std::any_of(duts.begin(), duts.end(),
                       [&](const config::DutSection& d) { return d.serial == serial; });
  };
  auto serial_list = [&] {
    std::string list;
    for (const auto& d : duts) list += (list.empty() ? "'" : ", '") + d.serial + "'";
    return list;
  };
  auto add = [&](TableReader& r, std::string serial, TableReader& parent, std::string_view key) {
    if (!known(serial)) {
      parent.error(key, fmt::format("no [[dut]] with serial '{}' (the station's DUTs: {})", serial,
                                    serial_list()));
      return;
    }
    if (std::any_of(out.begin(), out.end(),
                    [&](const DutOverrides& o) { return o.serial == serial; })) {
      parent.error(key, fmt::format("DUT '{}' is given twice", serial));
      return;
    }
    DutOverrides d;
    d.serial = std::move(serial);
    read_dut_overrides(r, d);
    r.finish();
    out.push_back(std::move(d));
  };
  TomlErrors& errors = simulator.errors();
  if (const toml::table* tables = node->as_table()) {
    TableReader parent(*tables, simulator.key_path("dut"), errors);
    for (const auto& [key, value] : *tables) {
      const std::string serial(key.str());
      if (!value.is_table()) {
        parent.skip(serial);
        parent.error(serial, "must be a table ([simulator.dut.SERIAL])");
        continue;
      }
      parent.skip(serial);
      TableReader r(*value.as_table(), parent.key_path(serial), errors);
      add(r, serial, parent, serial);
    }
    return;
  }
  if (const toml::array* entries = node->as_array()) {
    for (std::size_t i = 0; i < entries->size(); ++i) {
      const toml::table* entry = (*entries)[i].as_table();
      const std::string path = fmt::format("{}[{}]", simulator.key_path("dut"), i);
      if (!entry) {
        errors.add(simulator.line_of("dut"), path, "must be a table ([[simulator.dut]])");
        continue;
      }
      TableReader r(*entry, path, errors);
      auto serial = r.required_string("serial");
      if (!serial) continue;
      add(r, *serial, r, "serial");
    }
    return;
  }
  simulator.error("dut", "must be tables [simulator.dut.SERIAL] or [[simulator.dut]] entries");
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

void GyroOverrides::apply(GyroParams& p) const {
  if (bias_dph) p.bias_dph = *bias_dph;
  if (temp_coeffs) p.temp_coeffs = *temp_coeffs;
  if (rate_coeffs) p.rate_coeffs = *rate_coeffs;
  if (gradient_coeffs) p.gradient_coeffs = *gradient_coeffs;
  if (white_noise_dph) p.white_noise_dph = *white_noise_dph;
  if (bias_instability_dph) p.bias_instability_dph = *bias_instability_dph;
  if (bias_instability_tau_s) p.bias_instability_tau_s = *bias_instability_tau_s;
  if (rate_random_walk_dph_per_sqrt_h) {
    p.rate_random_walk_dph_per_sqrt_h = *rate_random_walk_dph_per_sqrt_h;
  }
}

Status parse_rate_hz_options(const std::vector<std::string>& values,
                             SimulatorOverrides& overrides) {
  for (const std::string& value : values) {
    const std::size_t eq = value.rfind('=');
    const std::string serial = eq == std::string::npos ? "" : value.substr(0, eq);
    const std::string_view hz_text =
        eq == std::string::npos ? std::string_view(value) : std::string_view(value).substr(eq + 1);
    if (eq != std::string::npos && serial.empty()) {
      return Error::Permanent(fmt::format(
          "--rate-hz '{}': no serial before '=' (HZ for every DUT, SERIAL=HZ for one)", value));
    }
    double hz = 0;
    const auto [end, ec] = std::from_chars(hz_text.data(), hz_text.data() + hz_text.size(), hz);
    if (hz_text.empty() || ec != std::errc() || end != hz_text.data() + hz_text.size() ||
        !std::isfinite(hz)) {
      return Error::Permanent(
          fmt::format("--rate-hz '{}': '{}' is not a number of Hz (HZ for every DUT, SERIAL=HZ "
                      "for one)",
                      value, hz_text));
    }
    if (hz < kMinRateHz || hz > kMaxRateHz) {
      return Error::Permanent(fmt::format("--rate-hz '{}': {:g} Hz is outside [{:g}, {:g}]", value,
                                          hz, kMinRateHz, kMaxRateHz));
    }
    if (eq == std::string::npos) {
      if (overrides.rate_hz) {
        return Error::Permanent(
            fmt::format("--rate-hz '{}': every DUT's rate is already given ({:g} Hz)", value,
                        *overrides.rate_hz));
      }
      overrides.rate_hz = hz;
      continue;
    }
    for (const auto& [s, given_hz] : overrides.dut_rate_hz) {
      if (s == serial) {
        return Error::Permanent(fmt::format("--rate-hz '{}': DUT '{}' is already given ({:g} Hz)",
                                            value, serial, given_hz));
      }
    }
    overrides.dut_rate_hz.emplace_back(serial, hz);
  }
  return Status::Ok();
}

std::string unknown_rate_hz_serial(const std::vector<std::pair<std::string, double>>& per_dut,
                                   const std::vector<config::DutSection>& duts) {
  for (const auto& [serial, hz] : per_dut) {
    if (config::find_dut(duts, serial)) continue;
    std::string list;
    for (const auto& d : duts) list += (list.empty() ? "'" : ", '") + d.serial + "'";
    return fmt::format("--rate-hz '{}={:g}': no [[dut]] with serial '{}' (the station's DUTs: {})",
                       serial, hz, serial, list);
  }
  return "";
}

double dut_rate_hz(const SimulatorOptions& options, const config::DutSection& dut) {
  for (const auto& [serial, hz] : options.dut_rate_hz) {
    if (serial == dut.serial) return hz;
  }
  return options.rate_hz.value_or(dut.link.rate_hz);
}

DutSimParams resolve_dut_params(const SimulatorOptions& options, const config::DutSection& dut,
                                int position) {
  DutSimParams r;
  r.serial = dut.serial;
  r.accel_noise_g = options.gyro.accel_noise_g;
  // Probes a little apart from the station's pair, and from each other.
  r.probe_offset_c = 0.05 * (position + 1);
  const DutOverrides* o = nullptr;
  for (const auto& d : options.dut_overrides) {
    if (d.serial == dut.serial) o = &d;
  }
  const int primary = primary_axis_index(dut);
  int k = 1;  // rank among the non-primary axes
  for (std::size_t i = 0; i < 3; ++i) {
    GyroParams& p = r.axes[i];
    p = options.gyro;
    bool given = false;
    if (o) {
      o->all.apply(p);
      o->axis[i].apply(p);
      given = o->all.bias_dph || o->axis[i].bias_dph;
    }
    r.bias_given[i] = given;
    if (!given) {
      const int rank = static_cast<int>(i) == primary ? 0 : k++;
      r.bias_offset_dph[i] = kDefaultDutBiasStepDph * position + kDefaultAxisBiasStepDph * rank;
      p.bias_dph += r.bias_offset_dph[i];
    } else if (static_cast<int>(i) != primary) {
      ++k;
    }
  }
  if (o) {
    if (o->accel_noise_g) r.accel_noise_g = *o->accel_noise_g;
    if (o->internal_temp_offset_c) r.internal_temp_offset_c = *o->internal_temp_offset_c;
    if (o->probe_offset_c) r.probe_offset_c = *o->probe_offset_c;
    r.case_params = o->case_params;
  }
  apply_randomize(options.randomize, options.seed, position, r);
  return r;
}

uint64_t derive_seed(uint64_t seed, uint64_t stream) {
  uint64_t z = seed + 0x9E3779B97F4A7C15ULL * (stream + 1);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

double DrawRange::draw(std::mt19937_64& rng) const {
  // 53 random bits in [0, 1): the same on every standard library.
  const double u = static_cast<double>(rng() >> 11) * 0x1.0p-53;
  if (lo > 0) return lo * std::pow(hi / lo, u);
  return lo + (hi - lo) * u;
}

bool SimulatorOptions::is_valid(std::string* why) const {
  if (!thermal.is_valid(why) || !gyro.is_valid(why) || !table.is_valid(why) ||
      !scale_factor.is_valid(why)) {
    return false;
  }
  auto fail = [&](std::string msg) {
    if (why) *why = std::move(msg);
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
  if (!(gyro_format.rate_hz >= kMinRateHz && gyro_format.rate_hz <= kMaxRateHz)) {
    return fail(fmt::format("gyro rate_hz = {} must be in [{:g}, {:g}]", gyro_format.rate_hz,
                            kMinRateHz, kMaxRateHz));
  }
  if (rate_hz && !(*rate_hz >= kMinRateHz && *rate_hz <= kMaxRateHz)) {
    return fail(
        fmt::format("--rate-hz {} must be in [{:g}, {:g}]", *rate_hz, kMinRateHz, kMaxRateHz));
  }
  for (const auto& [serial, hz] : dut_rate_hz) {
    if (!(hz >= kMinRateHz && hz <= kMaxRateHz)) {
      return fail(fmt::format("--rate-hz {}={} must be in [{:g}, {:g}]", serial, hz, kMinRateHz,
                              kMaxRateHz));
    }
  }
  if (control_socket.size() > kMaxControlSocketPath) {
    return fail(
        fmt::format("control_socket '{}' is {} bytes long; a Unix socket path holds at most {}",
                    control_socket, control_socket.size(), kMaxControlSocketPath));
  }
  if (gyro_format.axis < 0 || gyro_format.axis > 2) return fail("gyro axis must be x, y or z");
  return true;
}

Result<SimulatorOptions> read_simulator_options(const config::StationConfig& config,
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
    read_duts(t, simulated_duts(config), o.dut_overrides);
    if (auto r = t.table("randomize")) read_randomize(*r, o.randomize);
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
  if (overrides.scaled_clock) o.shared_clock = false;
  if (overrides.truth_file) o.truth_file = *overrides.truth_file;
  if (overrides.control_socket) o.control_socket = *overrides.control_socket;
  if (overrides.seed) o.seed = *overrides.seed;
  o.rate_hz = overrides.rate_hz;
  o.dut_rate_hz = overrides.dut_rate_hz;
  const std::vector<config::DutSection> duts = simulated_duts(config);
  std::string message;
  if (const std::string why = unknown_rate_hz_serial(o.dut_rate_hz, duts); !why.empty()) {
    message += why + "\n";
  }
  // "The gyro" of the older interface: the first DUT, at the rate it is served.
  if (!duts.empty()) o.gyro_format.rate_hz = dut_rate_hz(o, duts.front());
  if (overrides.table_port) o.table_port = *overrides.table_port;
  o.serve_table = overrides.serve_table || config.table.has_value();
  // Keys already reported above kept their defaults, so what is_valid() finds
  // now comes from the overrides or from combinations of keys.
  message = errors.joined() + message;
  if (std::string why; !o.is_valid(&why)) message += fmt::format("simulator options: {}\n", why);
  if (!message.empty()) return Error::Permanent(message);
  return o;
}

}  // namespace gyrotherm::sim
