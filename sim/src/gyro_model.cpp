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

bool GyroParams::IsValid(std::string* error) const {
  auto bad = [&](const char* name, double v, double lo, double hi) {
    if (std::isfinite(v) && v >= lo && v <= hi) return false;
    if (error)
      *error = fmt::format("{} = {} is out of range: must be in [{}, {}]", name, v, lo, hi);
    return true;
  };
  auto bad_coeffs = [&](const char* name, const std::vector<double>& c) {
    if (c.size() > 8) {
      if (error) *error = fmt::format("{} has {} entries (at most 8)", name, c.size());
      return true;
    }
    for (double v : c) {
      if (!std::isfinite(v)) {
        if (error) *error = fmt::format("{} holds a value that is not finite", name);
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

double GyroModel::next_rate_dph(const ThermalTruth& truth) {
  ++samples_;
  gm_bias_dph_ = gm_a_ * gm_bias_dph_ + gm_drive_dph_ * normal_(rng_);
  if (rrw_step_dph_ > 0) rrw_dph_ += rrw_step_dph_ * normal_(rng_);
  last_rate_dph_ = model_rate_dph(truth.case_c, truth.case_rate_c_per_s, truth.gradient_c) +
                   white_sample_std_dph_ * normal_(rng_) + gm_bias_dph_ + rrw_dph_;
  return last_rate_dph_;
}

double GyroModel::to_output(double rate_dph) const {
  double v = units::dph_to_dps(rate_dph);
  if (format_.unit == drivers::AngleUnit::kRad) v = units::deg_to_rad(v);
  if (format_.kind == drivers::OutputKind::kDeltaAngle) v *= sample_period_s();
  return v;
}

drivers::GyroFrame GyroModel::next_frame(const ThermalTruth& truth) {
  drivers::GyroFrame f;
  const double rate_dph = next_rate_dph(truth);
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
  j["seed"] = seed;
  return j.dump(2) + "\n";
}

}  // namespace gyrotherm::sim
