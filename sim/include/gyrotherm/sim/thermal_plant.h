// Thermal plant of the simulated station (docs/simulator.md).
//
// The chamber controller ramps its internal set point towards the requested
// one at most at max_ramp_c_per_min; the chamber air follows that ramped set
// point with a first-order lag (air_tau_s) plus band-limited control noise
// (an Ornstein-Uhlenbeck process, correlation time control_noise_tau_s); the
// gyro case follows the air with its own first-order lag (case_tau_s). The
// true probe gradient top - side grows with the case heating rate:
//   target = gradient_offset_c + gradient_c_per_c_per_min x (case dT/dt in °C/min)
// followed through a first-order lag of gradient_tau_s (heat takes time to
// cross the gyro; 0 = the gradient is the target at once, an exact function
// of the heating rate, so a fit could not tell the two terms apart in one
// run), and top/side = case ± gradient/2. Probe readings add white noise and are
// quantised. Everything is in °C and seconds of station time.
//
// Fault: force_air_c() makes the controller run away: its internal set point
// heads for the forced target at max_ramp_c_per_min (whatever the requested
// set point and the ramp limit), and the air follows it with the usual lag
// and noise. Released, the internal set point ramps back to the requested one.
//
// Pure and deterministic: the same parameters, seed and step sequence give
// the same trajectory. Not thread-safe.
#pragma once

#include <cstdint>
#include <optional>
#include <random>
#include <string>

namespace gyrotherm::sim {

struct ThermalParams {
  double initial_temp_c = 23.0;  // set point, air and case at t = 0
  double air_tau_s = 120.0;      // air lag behind the ramped set point (0 = none)
  double case_tau_s = 900.0;     // case lag behind the air (0 = none)
  double max_ramp_c_per_min = 5.0;
  // Amplitude of the control noise on the air: the stationary std of the
  // noise is control_noise_c / 2, so the air stays within ±control_noise_c of
  // its clean value about 95 % of the time.
  double control_noise_c = 0.5;
  double control_noise_tau_s = 60.0;  // correlation time of the control noise
  double gradient_c_per_c_per_min = 0.3;
  double gradient_offset_c = 0.05;
  double gradient_tau_s = 0.0;    // lag of the gradient behind its target (0 = none)
  double probe_noise_c = 0.02;    // white noise std of each probe reading
  double probe_quantum_c = 0.01;  // reading resolution (0 = none)

  // False with a message naming the first bad field.
  bool is_valid(std::string* why) const;
};

// The plant's true state after the last step.
struct ThermalTruth {
  double ramped_setpoint_c = 0;  // the controller's internal (ramp-limited) set point
  double air_c = 0;              // chamber air, control noise included (= process value)
  double case_c = 0;             // gyro case ("shell") temperature
  double case_rate_c_per_s = 0;  // d(case)/dt
  double gradient_c = 0;         // true top - side
  double top_c = 0;              // true probe temperatures
  double side_c = 0;
};

// Probe readings as the input module reports them: noisy and quantised.
struct ProbeReadings {
  double top_c = 0;
  double side_c = 0;
};

class ThermalPlant {
 public:
  ThermalPlant(const ThermalParams& params, uint64_t seed);

  // Advances the plant by dt_s (> 0) seconds of station time with the
  // controller's requested set point held at setpoint_c over the step.
  // Exact discretisation of the lags for a constant input over the step, so
  // steps up to a few seconds are fine.
  void step(double dt_s, double setpoint_c);

  // Controller ramp limit in °C/min (the chamber's own ramp setting); the
  // effective limit is min(this, params.max_ramp_c_per_min). <= 0 resets to
  // the params' limit.
  void set_ramp_limit_c_per_min(double rate_c_per_min);
  double ramp_limit_c_per_min() const { return ramp_limit_c_per_min_; }

  // Runaway controller: while set, the air is driven to target_c (°C) and the
  // requested set point is ignored; nullopt releases it. A non-finite target
  // releases too.
  void force_air_c(std::optional<double> target_c);
  std::optional<double> forced_air_c() const { return forced_air_c_; }

  double t_s() const { return t_s_; }  // station seconds stepped so far
  const ThermalTruth& truth() const { return truth_; }
  // Readings drawn at the end of the last step.
  const ProbeReadings& readings() const { return readings_; }
  const ThermalParams& params() const { return params_; }

 private:
  double read_probe(double true_c);

  ThermalParams params_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  double ramp_limit_c_per_min_;
  std::optional<double> forced_air_c_;
  double t_s_ = 0;
  double clean_air_c_;
  double noise_c_ = 0;
  ThermalTruth truth_;
  ProbeReadings readings_;
};

}  // namespace gyrotherm::sim
