#include "gyrotherm/sim/dut_model.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "gyrotherm/drivers/ascii_line.h"
#include "gyrotherm/drivers/dut_link.h"
#include "gyrotherm/drivers/kvh1750.h"

namespace gyrotherm::sim {
namespace {

// The fraction of the way a first-order lag of time constant tau_s moves in
// dt_s (ThermalPlant's discretisation: exact for a constant input).
double lag_fraction(double dt_s, double tau_s) {
  return tau_s > 0 ? 1.0 - std::exp(-dt_s / tau_s) : 1.0;
}

double poly_without_constant(const std::vector<double>& coeffs, double x) {
  double acc = 0;
  for (auto it = coeffs.rbegin(); it != coeffs.rend(); ++it) acc = (acc + *it) * x;
  return acc;
}

double gravity_g(analysis::AxisOrientation o) {
  switch (o) {
    case analysis::AxisOrientation::kUp:
      return 1.0;
    case analysis::AxisOrientation::kDown:
      return -1.0;
    case analysis::AxisOrientation::kHorizontal:
      break;
  }
  return 0.0;
}

}  // namespace

int primary_axis_index(const config::DutSection& dut) {
  if (!dut.primary_axis.empty()) return axis_index(dut.primary_axis);
  if (!dut.axes.empty()) return axis_index(dut.axes.back());
  return 2;
}

int axis_index(std::string_view axis) {
  for (int i = 0; i < 3; ++i) {
    if (axis == kAxisNames[static_cast<std::size_t>(i)]) return i;
  }
  return -1;
}

analysis::AxisOrientation axis_orientation(const config::DutSection& dut, int axis,
                                           analysis::AxisOrientation station_orientation) {
  for (const auto& [name, o] : dut.orientation) {
    if (axis_index(name) == axis) return o;
  }
  return axis == primary_axis_index(dut) ? station_orientation
                                         : analysis::AxisOrientation::kHorizontal;
}

std::vector<config::DutSection> simulated_duts(const config::StationConfig& config) {
  if (!config.duts.empty()) return config.duts;
  // [gyro] as one unnamed DUT, as the config reads it (config.h).
  config::DutSection dut;
  dut.serial = config.gyro.serial_number;
  dut.model = config.gyro.model;
  dut.link.serial = config.gyro.serial;
  dut.link.protocol = config.gyro.protocol;
  dut.link.unit = config.gyro.format.unit;
  dut.link.kind = config.gyro.format.kind;
  dut.link.rate_hz = config.gyro.format.rate_hz;
  const std::string axis =
      kAxisNames[static_cast<std::size_t>(std::clamp(config.gyro.format.axis, 0, 2))];
  dut.axes = {axis};
  dut.orientation = {{axis, config.station.orientation}};
  dut.primary_axis = axis;
  dut.table_axis = axis;
  dut.silent_timeout_s = config.gyro.silent_timeout_s;
  return {dut};
}

// ------------------------------------------------------------------ DutShell

DutShell::DutShell(const ThermalParams& plant, const DutCaseParams& own, double probe_offset_c,
                   uint64_t seed)
    : params_(plant), own_(own.own()), probe_offset_c_(probe_offset_c), rng_(seed) {
  if (own.case_tau_s) params_.case_tau_s = *own.case_tau_s;
  if (own.gradient_c_per_c_per_min)
    params_.gradient_c_per_c_per_min = *own.gradient_c_per_c_per_min;
  if (own.gradient_offset_c) params_.gradient_offset_c = *own.gradient_offset_c;
  if (own.gradient_tau_s) params_.gradient_tau_s = *own.gradient_tau_s;
  truth_.ramped_setpoint_c = truth_.air_c = truth_.case_c = params_.initial_temp_c;
  truth_.gradient_c = params_.gradient_offset_c;
  truth_.top_c = truth_.case_c + truth_.gradient_c / 2;
  truth_.side_c = truth_.case_c - truth_.gradient_c / 2;
  readings_ = {read_probe(truth_.top_c), read_probe(truth_.side_c)};
}

void DutShell::step(double dt_s, const ThermalTruth& plant) {
  if (!own_) {
    truth_ = plant;
  } else if (dt_s > 0) {
    // ThermalPlant::step's case and gradient, driven by the same air.
    truth_.ramped_setpoint_c = plant.ramped_setpoint_c;
    truth_.air_c = plant.air_c;
    const double previous_case_c = truth_.case_c;
    truth_.case_c += (truth_.air_c - truth_.case_c) * lag_fraction(dt_s, params_.case_tau_s);
    truth_.case_rate_c_per_s = params_.case_tau_s > 0
                                   ? (truth_.air_c - truth_.case_c) / params_.case_tau_s
                                   : (truth_.case_c - previous_case_c) / dt_s;
    const double target_c = params_.gradient_offset_c +
                            params_.gradient_c_per_c_per_min * truth_.case_rate_c_per_s * 60.0;
    truth_.gradient_c +=
        (target_c - truth_.gradient_c) * lag_fraction(dt_s, params_.gradient_tau_s);
    truth_.top_c = truth_.case_c + truth_.gradient_c / 2;
    truth_.side_c = truth_.case_c - truth_.gradient_c / 2;
  }
  readings_ = {read_probe(truth_.top_c), read_probe(truth_.side_c)};
}

double DutShell::read_probe(double true_c) {
  double v = true_c + probe_offset_c_;
  if (params_.probe_noise_c > 0) v += params_.probe_noise_c * normal_(rng_);
  if (params_.probe_quantum_c > 0) {
    v = std::round(v / params_.probe_quantum_c) * params_.probe_quantum_c;
  }
  return v;
}

// ------------------------------------------------------------------ DutModel

Result<DutModel> DutModel::create(const config::DutSection& dut, int position,
                                  const DutSimParams& params, const config::StationSection& station,
                                  const std::optional<TableMount>& table,
                                  const ScaleFactorParams& scale_factor,
                                  const std::array<uint64_t, 3>& axis_seeds, uint64_t accel_seed) {
  const std::string who =
      dut.serial.empty() ? std::string("the gyro") : fmt::format("DUT '{}'", dut.serial);
  const int primary = primary_axis_index(dut);
  if (primary < 0) {
    return Error::Permanent(
        fmt::format("{}: primary_axis '{}' is not x, y or z", who, dut.primary_axis));
  }
  int table_axis = primary;
  if (!dut.table_axis.empty()) {
    table_axis = axis_index(dut.table_axis);
    if (table_axis < 0) {
      return Error::Permanent(
          fmt::format("{}: table_axis '{}' is not x, y or z", who, dut.table_axis));
    }
  }
  if (!(dut.link.rate_hz >= 0.1 && dut.link.rate_hz <= 10000)) {
    return Error::Permanent(
        fmt::format("{}: rate_hz = {} must be in [0.1, 10000]", who, dut.link.rate_hz));
  }
  std::vector<ChannelSpec> channels;
  if (dut.link.protocol == "ascii") {
    auto c = drivers::dut_channels(dut.link);
    if (!c.ok()) return Error::Permanent(fmt::format("{}: {}", who, c.error().message));
    channels = std::move(c).value();
    if (Status s = drivers::validate_ascii_options(dut.link.ascii); !s.ok()) {
      return Error::Permanent(fmt::format("{}: {}", who, s.error().message));
    }
  } else if (dut.link.protocol != "kvh1750") {
    return Error::Permanent(fmt::format("{}: protocol '{}' cannot be simulated (kvh1750 or ascii)",
                                        who, dut.link.protocol));
  }
  std::vector<GyroModel> axes;
  std::array<AxisSetup, 3> setup;
  for (int i = 0; i < 3; ++i) {
    const auto u = static_cast<std::size_t>(i);
    AxisSetup& s = setup[u];
    s.orientation = axis_orientation(dut, i, station.orientation);
    if (s.orientation == analysis::AxisOrientation::kHorizontal) {
      s.heading_deg = config::axis_heading_deg(dut, kAxisNames[u]);
    }
    s.earth_rate_dph =
        analysis::earth_rate_component_dph(station.latitude_deg, s.orientation, s.heading_deg);
    s.gravity_g = gravity_g(s.orientation);
    drivers::GyroFormat format;
    format.unit = dut.link.unit;
    format.kind = dut.link.kind;
    format.axis = i;
    format.rate_hz = dut.link.rate_hz;
    axes.emplace_back(params.axes[u], format, s.earth_rate_dph, axis_seeds[u]);
    if (table && i == table_axis) {
      // Every DUT is on the table, its table_axis along the spin axis.
      TableMount mount = *table;
      // A radial table axis turns from its own heading when it has one.
      if (s.heading_deg) mount.heading_at_zero_deg = *s.heading_deg;
      axes.back().enable_table(scale_factor, mount);
      s.on_table = true;
    } else if (table && s.heading_deg) {
      // A horizontal axis of a DUT on the table turns with it: no table
      // rate, the Earth rate of its heading at each position.
      axes.back().turn_with_table(station.latitude_deg, *s.heading_deg);
      s.turns_with_table = true;
    }
  }
  return DutModel(dut, position, params, std::move(axes), setup, primary, std::move(channels),
                  accel_seed);
}

DutModel::DutModel(config::DutSection dut, int position, DutSimParams params,
                   std::vector<GyroModel> axes, std::array<AxisSetup, 3> setup, int primary,
                   std::vector<ChannelSpec> channels, uint64_t accel_seed)
    : dut_(std::move(dut)),
      position_(position),
      params_(std::move(params)),
      axes_(std::move(axes)),
      setup_(setup),
      primary_(primary),
      channels_(std::move(channels)),
      accel_rng_(accel_seed) {}

DutSample DutModel::next_frame(const ThermalTruth& shell, const TableInput& table,
                               std::vector<uint8_t>& bytes) {
  DutSample s;
  s.seq = seq_++;
  for (std::size_t i = 0; i < 3; ++i) {
    s.rate_dph[i] = axes_[i].next_rate_dph(shell, table);
    s.accel_g[i] = setup_[i].gravity_g + params_.accel_noise_g * normal_(accel_rng_);
  }
  s.temp_c = shell.case_c + params_.internal_temp_offset_c;
  last_ = s;
  if (!ascii()) {
    drivers::GyroFrame f;
    for (std::size_t i = 0; i < 3; ++i) {
      f.gyro[i] = static_cast<float>(axes_[i].to_output(s.rate_dph[i]));
      f.accel[i] = static_cast<float>(s.accel_g[i]);
    }
    f.status = kGyroStatusAllValid;
    f.seq = static_cast<uint8_t>(s.seq % drivers::kKvh1750SeqModulo);
    f.temp_c = static_cast<int16_t>(std::clamp(std::lround(s.temp_c), -32768L, 32767L));
    const auto frame = drivers::encode_kvh1750(f);
    bytes.insert(bytes.end(), frame.begin(), frame.end());
    return s;
  }
  // ASCII: one value per channel, as sent (physical = raw × scale).
  uint32_t valid = 0;
  for (const auto& [axis, mask] : dut_.link.ascii.valid_bits) valid |= mask;
  std::array<double, kMaxChannels> values{};
  for (std::size_t c = 0; c < channels_.size(); ++c) {
    const ChannelSpec& spec = channels_[c];
    const int a = axis_index(spec.axis);
    const double scale = spec.scale != 0 ? spec.scale : 1.0;
    double v = 0;
    switch (spec.kind) {
      case ChannelKind::kRate:
        if (a >= 0) v = s.rate_dph[static_cast<std::size_t>(a)] / scale;
        break;
      case ChannelKind::kAccel:
        if (a >= 0) v = s.accel_g[static_cast<std::size_t>(a)] / scale;
        break;
      case ChannelKind::kTemperature:
        // A test set prints a few decimals, not float noise.
        v = std::round(s.temp_c * 100.0) / 100.0 / scale;
        break;
      case ChannelKind::kStatus:
        v = static_cast<double>(valid);
        break;
      case ChannelKind::kOther:
        break;
    }
    values[c] = v;
  }
  const std::string line = drivers::encode_ascii_line(
      dut_.link.ascii, std::span<const double>(values.data(), channels_.size()), s.seq);
  bytes.insert(bytes.end(), line.begin(), line.end());
  return s;
}

nlohmann::json DutModel::truth(const DutShell& shell, const std::vector<double>& static_temps_c,
                               bool table_served) const {
  using nlohmann::json;
  json axes = json::object();
  const double steady_gradient_c = shell.params().gradient_offset_c;
  for (std::size_t i = 0; i < 3; ++i) {
    const GyroModel& m = axes_[i];
    const GyroParams& p = m.params();
    const AxisSetup& s = setup_[i];
    json statics = json::array();
    for (double t : static_temps_c) {
      // What a static soak's mean converges to: the model at dT/dt = 0 and
      // the steady gradient; Table I's bias is this less the Earth rate.
      const double mean_dph = s.earth_rate_dph + p.bias_dph +
                              poly_without_constant(p.temp_coeffs, t) +
                              poly_without_constant(p.gradient_coeffs, steady_gradient_c);
      statics.push_back({{"temp_c", t},
                         {"mean_dph", mean_dph},
                         {"bias_earth_removed_dph", mean_dph - s.earth_rate_dph}});
    }
    json a = {
        {"orientation", std::string(analysis::to_string(s.orientation))},
        {"heading_deg", s.heading_deg ? json(*s.heading_deg) : json(nullptr)},
        {"earth_rate_dph", s.earth_rate_dph},
        {"turns_with_table", s.turns_with_table && table_served},
        {"gravity_g", s.gravity_g},
        {"bias_dph", p.bias_dph},
        {"bias_default", !params_.bias_given[i]},
        {"temp_coeffs", p.temp_coeffs},
        {"rate_coeffs", p.rate_coeffs},
        {"gradient_coeffs", p.gradient_coeffs},
        {"white_noise_dph", p.white_noise_dph},
        {"bias_instability_dph", p.bias_instability_dph},
        {"bias_instability_tau_s", p.bias_instability_tau_s},
        {"rate_random_walk_dph_per_sqrt_h", p.rate_random_walk_dph_per_sqrt_h},
        {"on_table", s.on_table && table_served},
        {"static", statics},
    };
    if (s.on_table && table_served) {
      // The scale factor's truth, as the top level's "scale_factor".
      const json full = json::parse(m.truth_json(0));
      a["scale_factor"] = full.at("scale_factor");
    }
    axes[kAxisNames[i]] = std::move(a);
  }
  const ThermalParams& tp = shell.params();
  return {
      {"serial", dut_.serial},
      {"model", dut_.model},
      {"position", position_},
      {"protocol", dut_.link.protocol},
      {"rate_hz", dut_.link.rate_hz},
      {"primary_axis", kAxisNames[static_cast<std::size_t>(primary_)]},
      {"table_axis", dut_.table_axis.empty()
                         ? std::string(kAxisNames[static_cast<std::size_t>(primary_)])
                         : dut_.table_axis},
      {"axes", axes},
      {"accel_noise_g", params_.accel_noise_g},
      {"internal_temp_offset_c", params_.internal_temp_offset_c},
      {"probe_offset_c", params_.probe_offset_c},
      {"case",
       {{"own", shell.own()},
        {"case_tau_s", tp.case_tau_s},
        {"gradient_c_per_c_per_min", tp.gradient_c_per_c_per_min},
        {"gradient_offset_c", tp.gradient_offset_c},
        {"gradient_tau_s", tp.gradient_tau_s}}},
      {"formula",
       "per axis: rate_dph = earth_rate_dph(orientation, heading) + bias_dph + "
       "sum_i temp_coeffs[i]*T^(i+1) "
       "+ sum_j rate_coeffs[j]*(dT/dt)^(j+1) + sum_k gradient_coeffs[k]*dT_gradient^(k+1) + noise "
       "(the table axis: through the scale factor); earth_rate_dph: up 15.041067*sin(lat), "
       "down the negative, horizontal 15.041067*cos(lat)*cos(heading_deg) (no heading: 0), "
       "at table position 0 (turns_with_table: cos(heading_deg + position)); "
       "T, dT/dt, dT_gradient of this DUT's case; "
       "accel_g = gravity_g(orientation) + noise; internal temp = T + internal_temp_offset_c; "
       "static.mean_dph: dT/dt = 0, dT_gradient = case.gradient_offset_c"},
  };
}

}  // namespace gyrotherm::sim
