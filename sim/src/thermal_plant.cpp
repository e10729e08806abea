#include "gyrotherm/sim/thermal_plant.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace gyrotherm::sim {
namespace {

// Fraction of the way a first-order lag with time constant tau_s moves
// towards a constant input over dt_s.
double lag_fraction(double dt_s, double tau_s) {
  return tau_s > 0 ? -std::expm1(-dt_s / tau_s) : 1.0;
}

}  // namespace

bool ThermalParams::is_valid(std::string* why) const {
  auto bad = [&](const char* name, double v, double lo, double hi) {
    if (std::isfinite(v) && v >= lo && v <= hi) return false;
    if (why) *why = fmt::format("{} = {} is out of range: must be in [{}, {}]", name, v, lo, hi);
    return true;
  };
  return !(bad("initial_temp_c", initial_temp_c, -100, 200) ||
           bad("air_tau_s", air_tau_s, 0, 1e6) || bad("case_tau_s", case_tau_s, 0, 1e6) ||
           bad("max_ramp_c_per_min", max_ramp_c_per_min, 1e-3, 1000) ||
           bad("control_noise_c", control_noise_c, 0, 20) ||
           bad("control_noise_tau_s", control_noise_tau_s, 0.1, 1e6) ||
           bad("gradient_c_per_c_per_min", gradient_c_per_c_per_min, -100, 100) ||
           bad("gradient_offset_c", gradient_offset_c, -50, 50) ||
           bad("gradient_tau_s", gradient_tau_s, 0, 1e6) ||
           bad("probe_noise_c", probe_noise_c, 0, 10) ||
           bad("probe_quantum_c", probe_quantum_c, 0, 10));
}

ThermalPlant::ThermalPlant(const ThermalParams& params, uint64_t seed)
    : params_(params),
      rng_(seed),
      ramp_limit_c_per_min_(params.max_ramp_c_per_min),
      clean_air_c_(params.initial_temp_c) {
  truth_.ramped_setpoint_c = params.initial_temp_c;
  truth_.air_c = params.initial_temp_c;
  truth_.case_c = params.initial_temp_c;
  truth_.gradient_c = params.gradient_offset_c;
  truth_.top_c = truth_.case_c + truth_.gradient_c / 2;
  truth_.side_c = truth_.case_c - truth_.gradient_c / 2;
  readings_.top_c = read_probe(truth_.top_c);
  readings_.side_c = read_probe(truth_.side_c);
}

void ThermalPlant::set_ramp_limit_c_per_min(double rate_c_per_min) {
  ramp_limit_c_per_min_ = rate_c_per_min > 0 ? std::min(rate_c_per_min, params_.max_ramp_c_per_min)
                                             : params_.max_ramp_c_per_min;
}

void ThermalPlant::force_air_c(std::optional<double> target_c) {
  if (target_c && !std::isfinite(*target_c)) target_c.reset();
  forced_air_c_ = target_c;
}

void ThermalPlant::step(double dt_s, double setpoint_c) {
  if (!(dt_s > 0)) return;
  t_s_ += dt_s;

  // Controller ramp (a runaway one ramps to its own target as fast as it can).
  const double target_c = forced_air_c_ ? *forced_air_c_ : setpoint_c;
  const double rate_c_per_min = forced_air_c_ ? params_.max_ramp_c_per_min : ramp_limit_c_per_min_;
  const double max_step_c = rate_c_per_min / 60.0 * dt_s;
  double& ramped = truth_.ramped_setpoint_c;
  ramped += std::clamp(target_c - ramped, -max_step_c, max_step_c);

  // Air: lag behind the ramped set point, plus OU control noise with
  // stationary std control_noise_c / 2 (exact AR(1) discretisation).
  clean_air_c_ += (ramped - clean_air_c_) * lag_fraction(dt_s, params_.air_tau_s);
  const double sigma_c = params_.control_noise_c / 2;
  if (sigma_c > 0) {
    const double a = std::exp(-dt_s / params_.control_noise_tau_s);
    noise_c_ = a * noise_c_ + sigma_c * std::sqrt(1 - a * a) * normal_(rng_);
  }
  truth_.air_c = clean_air_c_ + noise_c_;

  // Case: lag behind the air; its rate is the lag's derivative at the end of
  // the step, (air - case) / tau.
  const double previous_case_c = truth_.case_c;
  truth_.case_c += (truth_.air_c - truth_.case_c) * lag_fraction(dt_s, params_.case_tau_s);
  truth_.case_rate_c_per_s = params_.case_tau_s > 0
                                 ? (truth_.air_c - truth_.case_c) / params_.case_tau_s
                                 : (truth_.case_c - previous_case_c) / dt_s;

  const double gradient_target_c = params_.gradient_offset_c + params_.gradient_c_per_c_per_min *
                                                                   truth_.case_rate_c_per_s * 60.0;
  truth_.gradient_c +=
      (gradient_target_c - truth_.gradient_c) * lag_fraction(dt_s, params_.gradient_tau_s);
  truth_.top_c = truth_.case_c + truth_.gradient_c / 2;
  truth_.side_c = truth_.case_c - truth_.gradient_c / 2;
  readings_.top_c = read_probe(truth_.top_c);
  readings_.side_c = read_probe(truth_.side_c);
}

double ThermalPlant::read_probe(double true_c) {
  double v = true_c;
  if (params_.probe_noise_c > 0) v += params_.probe_noise_c * normal_(rng_);
  if (params_.probe_quantum_c > 0) {
    v = std::round(v / params_.probe_quantum_c) * params_.probe_quantum_c;
  }
  return v;
}

}  // namespace gyrotherm::sim
