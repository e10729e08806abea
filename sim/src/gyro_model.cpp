#include "gyrotherm/sim/gyro_model.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "gyrotherm/core/units.h"
#include "gyrotherm/drivers/kvh1750.h"

namespace gyrotherm::sim {
namespace {

// Σ coeffs[i] · x^(i+1), Horner.
double poly_without_constant(const std::vector<double>& coeffs, double x) {
  double acc = 0;
  for (auto it = coeffs.rbegin(); it != coeffs.rend(); ++it) acc = (acc + *it) * x;
  return acc;
}

}  // namespace

bool GyroParams::is_valid(std::string* why) const {
  auto bad = [&](const char* name, double v, double lo, double hi) {
    if (std::isfinite(v) && v >= lo && v <= hi) return false;
    if (why) *why = fmt::format("{} = {} is out of range: must be in [{}, {}]", name, v, lo, hi);
    return true;
  };
  auto bad_coeffs = [&](const char* name, const std::vector<double>& c) {
    if (c.size() > 8) {
      if (why) *why = fmt::format("{} has {} entries (at most 8)", name, c.size());
      return true;
    }
    for (double v : c) {
      if (!std::isfinite(v)) {
        if (why) *why = fmt::format("{} holds a value that is not finite", name);
        return true;
      }
    }
    return false;
  };
  return !(bad("bias_dph", bias_dph, -1e5, 1e5) || bad_coeffs("temp_coeffs", temp_coeffs) ||
           bad_coeffs("rate_coeffs", rate_coeffs) ||
           bad_coeffs("gradient_coeffs", gradient_coeffs) ||
           bad("white_noise_dph", white_noise_dph, 0, 1e5) ||
           bad("bias_instability_dph", bias_instability_dph, 0, 1e5) ||
           bad("bias_instability_tau_s", bias_instability_tau_s, 1e-3, 1e8) ||
           bad("rate_random_walk_dph_per_sqrt_h", rate_random_walk_dph_per_sqrt_h, 0, 1e5) ||
           bad("accel_noise_g", accel_noise_g, 0, 10));
}

bool ScaleFactorParams::is_valid(std::string* why) const {
  auto bad = [&](const char* name, double v, double lo, double hi) {
    if (std::isfinite(v) && v >= lo && v <= hi) return false;
    if (why) {
      *why =
          fmt::format("scale_factor {} = {} is out of range: must be in [{}, {}]", name, v, lo, hi);
    }
    return true;
  };
  return !(bad("k_ppm", k_ppm, -1e5, 1e5) || bad("k_tc_ppm_per_c", k_tc_ppm_per_c, -1e4, 1e4) ||
           bad("reference_temp_c", reference_temp_c, -100, 200) ||
           bad("asymmetry_ppm", asymmetry_ppm, -1e5, 1e5) ||
           bad("nonlinearity_ppm", nonlinearity_ppm, -1e5, 1e5));
}

GyroModel::GyroModel(GyroParams params, drivers::GyroFormat format, double earth_rate_dph,
                     uint64_t seed)
    : params_(std::move(params)), format_(format), earth_rate_dph_(earth_rate_dph), rng_(seed) {
  const double dt_s = sample_period_s();
  white_sample_std_dph_ = params_.white_noise_dph * std::sqrt(format_.rate_hz);
  gm_a_ = std::exp(-dt_s / params_.bias_instability_tau_s);
  gm_drive_dph_ = params_.bias_instability_dph * std::sqrt(1 - gm_a_ * gm_a_);
  rrw_step_dph_ =
      params_.rate_random_walk_dph_per_sqrt_h * std::sqrt(dt_s / units::kSecondsPerHour);
  gm_bias_dph_ = params_.bias_instability_dph * normal_(rng_);
}

double GyroModel::model_rate_dph(double case_c, double case_rate_c_per_s, double gradient_c) const {
  return earth_rate_dph_ + params_.bias_dph + poly_without_constant(params_.temp_coeffs, case_c) +
         poly_without_constant(params_.rate_coeffs, case_rate_c_per_s) +
         poly_without_constant(params_.gradient_coeffs, gradient_c);
}

void GyroModel::enable_table(ScaleFactorParams sf, TableMount mount) {
  on_table_ = true;
  sf_ = sf;
  mount_ = mount;
}

void GyroModel::turn_with_table(double latitude_deg, double heading_deg) {
  turning_ = true;
  turning_latitude_deg_ = latitude_deg;
  turning_heading_deg_ = heading_deg;
}

double GyroModel::earth_rate_at_dph(double position_deg) const {
  if (!turning_) return earth_rate_dph_;
  return units::kEarthRateDph * std::cos(units::deg_to_rad(turning_latitude_deg_)) *
         std::cos(units::deg_to_rad(turning_heading_deg_ + position_deg));
}

double GyroModel::scale_factor(double case_c, bool positive) const {
  const double k = 1.0 + (sf_.k_ppm + sf_.k_tc_ppm_per_c * (case_c - sf_.reference_temp_c)) * 1e-6;
  return k * (1.0 + (positive ? 0.5 : -0.5) * sf_.asymmetry_ppm * 1e-6);
}

double GyroModel::earth_projection_dph(double position_deg) const {
  if (mount_.axis == SensitiveAxis::kAlongTable) return earth_rate_dph_;
  return units::kEarthRateDph * std::cos(units::deg_to_rad(mount_.latitude_deg)) *
         std::cos(units::deg_to_rad(mount_.heading_at_zero_deg + position_deg));
}

double GyroModel::model_rate_on_table_dph(const ThermalTruth& truth,
                                          const TableInput& table) const {
  const double input_dph =
      table.rate_dps * units::kSecondsPerHour + earth_projection_dph(table.position_deg);
  const double full_scale_dph = mount_.full_scale_dps * units::kSecondsPerHour;
  const double k = scale_factor(truth.case_c, input_dph >= 0);
  const double sensed =
      k * input_dph * (1.0 + sf_.nonlinearity_ppm * 1e-6 * std::abs(input_dph) / full_scale_dph);
  // model_rate_dph() less its Earth rate: the bias and the polynomials.
  return sensed + model_rate_dph(truth.case_c, truth.case_rate_c_per_s, truth.gradient_c) -
         earth_rate_dph_;
}

double GyroModel::next_rate_dph(const ThermalTruth& truth, const TableInput& table) {
  ++samples_;
  gm_bias_dph_ = gm_a_ * gm_bias_dph_ + gm_drive_dph_ * normal_(rng_);
  if (rrw_step_dph_ > 0) rrw_dph_ += rrw_step_dph_ * normal_(rng_);
  double model = 0;
  if (on_table_) {
    model = model_rate_on_table_dph(truth, table);
  } else if (turning_) {
    // model_rate_dph() with the Earth rate at the table's position.
    model = model_rate_dph(truth.case_c, truth.case_rate_c_per_s, truth.gradient_c) -
            earth_rate_dph_ + earth_rate_at_dph(table.position_deg);
  } else {
    model = model_rate_dph(truth.case_c, truth.case_rate_c_per_s, truth.gradient_c);
  }
  last_rate_dph_ = model + white_sample_std_dph_ * normal_(rng_) + gm_bias_dph_ + rrw_dph_;
  return last_rate_dph_;
}

double GyroModel::to_output(double rate_dph) const {
  double v = units::dph_to_dps(rate_dph);
  if (format_.unit == drivers::AngleUnit::kRad) v = units::deg_to_rad(v);
  if (format_.kind == drivers::OutputKind::kDeltaAngle) v *= sample_period_s();
  return v;
}

drivers::GyroFrame GyroModel::next_frame(const ThermalTruth& truth, const TableInput& table) {
  drivers::GyroFrame f;
  const double rate_dph = next_rate_dph(truth, table);
  for (int axis = 0; axis < 3; ++axis) {
    const double v = axis == format_.axis ? rate_dph : white_sample_std_dph_ * normal_(rng_);
    f.gyro[static_cast<std::size_t>(axis)] = static_cast<float>(to_output(v));
  }
  for (int axis = 0; axis < 3; ++axis) {
    f.accel[static_cast<std::size_t>(axis)] =
        static_cast<float>((axis == 2 ? 1.0 : 0.0) + params_.accel_noise_g * normal_(rng_));
  }
  f.status = kGyroStatusAllValid;
  f.seq = seq_;
  seq_ = static_cast<uint8_t>((seq_ + 1) % drivers::kKvh1750SeqModulo);
  f.temp_c = static_cast<int16_t>(std::clamp(std::lround(truth.case_c), -32768L, 32767L));
  return f;
}

std::string GyroModel::formula() {
  return "rate_dph = earth_rate_dph + bias_dph"
         " + sum_i temp_coeffs[i] * T^(i+1)"
         " + sum_j rate_coeffs[j] * (dT/dt)^(j+1)"
         " + sum_k gradient_coeffs[k] * dT_gradient^(k+1)"
         " + white noise + bias instability + rate random walk;"
         " T = gyro case temperature (degC), dT/dt = case temperature rate (degC/s),"
         " dT_gradient = true top - side probe temperature (degC)";
}

std::string GyroModel::truth_json(uint64_t seed) const {
  static constexpr const char* kAxes[] = {"x", "y", "z"};
  nlohmann::json j;
  j["earth_rate_dph"] = earth_rate_dph_;
  j["bias_dph"] = params_.bias_dph;
  j["temp_coeffs"] = params_.temp_coeffs;
  j["rate_coeffs"] = params_.rate_coeffs;
  j["gradient_coeffs"] = params_.gradient_coeffs;
  j["white_noise_dph"] = params_.white_noise_dph;
  j["bias_instability_dph"] = params_.bias_instability_dph;
  j["bias_instability_tau_s"] = params_.bias_instability_tau_s;
  j["rate_random_walk_dph_per_sqrt_h"] = params_.rate_random_walk_dph_per_sqrt_h;
  j["rate_hz"] = format_.rate_hz;
  j["units"] = {{"rate", "deg/h"},
                {"T", "degC"},
                {"dT/dt", "degC/s"},
                {"gradient", "degC"},
                {"temp_coeffs", "deg/h per degC^(i+1)"},
                {"rate_coeffs", "deg/h per (degC/s)^(j+1)"},
                {"gradient_coeffs", "deg/h per degC^(k+1)"}};
  j["output"] = {
      {"unit", format_.unit == drivers::AngleUnit::kRad ? "rad" : "deg"},
      {"kind", format_.kind == drivers::OutputKind::kRate ? "rate" : "delta"},
      {"axis", kAxes[std::clamp(format_.axis, 0, 2)]},
  };
  j["formula"] = formula();
  if (on_table_) {
    j["scale_factor"] = {
        {"k_ppm", sf_.k_ppm},
        {"k_tc_ppm_per_c", sf_.k_tc_ppm_per_c},
        {"reference_temp_c", sf_.reference_temp_c},
        {"asymmetry_ppm", sf_.asymmetry_ppm},
        {"nonlinearity_ppm", sf_.nonlinearity_ppm},
        {"full_scale_dps", mount_.full_scale_dps},
        {"sensitive_axis", mount_.axis == SensitiveAxis::kRadial ? "radial" : "along_table"},
        {"latitude_deg", mount_.latitude_deg},
        {"heading_at_zero_deg", mount_.heading_at_zero_deg},
        // K(T) = k0 + k1 (T - reference_temp_c), for the sign-averaged K.
        {"K_of_T", {{"k0", 1.0 + sf_.k_ppm * 1e-6}, {"k1_per_c", sf_.k_tc_ppm_per_c * 1e-6}}},
        {"formula",
         "Omega_dph = table_rate_dps*3600 + earth_projection_dph; "
         "K = (1 + (k_ppm + k_tc_ppm_per_c*(T - reference_temp_c))*1e-6) * "
         "(1 + s*asymmetry_ppm/2*1e-6), s = +1 if Omega >= 0 else -1; "
         "rate_dph = K*Omega*(1 + nonlinearity_ppm*1e-6*|Omega|/Omega_fs) + bias_dph + "
         "polynomials + noise; Omega_fs = full_scale_dps*3600; "
         "earth_projection_dph = earth_rate_dph (along_table) or "
         "15.041067*cos(latitude)*cos(heading_at_zero_deg + position_deg) (radial); "
         "T = gyro case temperature (degC); the table's true rate enters, not its measured one"},
        {"asymmetry_definition", "(K+ - K-)/K_mean, ppm"},
        {"nonlinearity_definition",
         "output deviates from K*Omega by K*Omega*nonlinearity_ppm*1e-6*|Omega|/Omega_fs: "
         "at full scale the relative deviation is nonlinearity_ppm; it is even in Omega, so a "
         "straight-line fit over +-Omega_fs leaves residuals of that shape"},
    };
  }
  j["seed"] = seed;
  return j.dump(2) + "\n";
}

}  // namespace gyrotherm::sim
