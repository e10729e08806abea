// Gyro of the simulated station (docs/simulator.md): the "truth" the fits are
// checked against, and the frames that carry it.
//
// Rate of the sensitive axis, °/h, at each output sample:
//   rate = earth_rate + bias_dph
//        + Σ temp_coeffs[i]     · T^(i+1)        T: case temperature, °C
//        + Σ rate_coeffs[j]     · (dT/dt)^(j+1)  dT/dt: case rate, °C/s
//        + Σ gradient_coeffs[k] · ΔT^(k+1)       ΔT: true top - side, °C
//        + white noise + bias instability + rate random walk
// White noise is scaled so that the mean over one second of samples has std
// white_noise_dph (per-sample std = white_noise_dph x sqrt(rate_hz)); bias
// instability is a first-order Gauss-Markov process (stationary std
// bias_instability_dph, correlation time bias_instability_tau_s, started
// from its stationary distribution); the rate random walk grows as
// rate_random_walk_dph_per_sqrt_h x sqrt(hours), starting at 0.
//
// Deterministic given the seed. Not thread-safe.
#pragma once

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/drivers/frame_parser.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/sim/thermal_plant.h"

namespace gyrotherm::sim {

struct GyroParams {
  double bias_dph = 0.0;
  std::vector<double> temp_coeffs;      // °/h per °C^(i+1)
  std::vector<double> rate_coeffs;      // °/h per (°C/s)^(j+1)
  std::vector<double> gradient_coeffs;  // °/h per °C^(k+1)
  double white_noise_dph = 1.0;         // std of a 1 s mean, °/h
  double bias_instability_dph = 0.0;
  double bias_instability_tau_s = 300.0;
  double rate_random_walk_dph_per_sqrt_h = 0.0;
  double accel_noise_g = 1e-4;  // per-sample std of each accelerometer axis

  // False with a message naming the first bad field.
  bool IsValid(std::string* error) const;
};

inline constexpr uint8_t kGyroStatusAllValid = 0x77;  // gyro X/Y/Z and accel X/Y/Z valid

class GyroModel {
 public:
  // `format` sets the output (unit, rate or delta angle, axis, rate_hz > 0).
  GyroModel(GyroParams params, drivers::GyroFormat format, double earth_rate_dph, uint64_t seed);

  // The noise-free part (Earth rate, bias and the three polynomials), °/h.
  double model_rate_dph(double case_c, double case_rate_c_per_s, double gradient_c) const;

  // One sample of the sensitive axis, °/h, noise included; advances the
  // noise processes by one sample period (1 / rate_hz station seconds).
  double next_rate_dph(const ThermalTruth& truth);

  // One KVH 1750 frame: the sensitive axis carries next_rate_dph() in the
  // configured output; the other two axes carry white noise only; accel is
  // (0, 0, 1 g) + noise; status 0x77; seq counts 0..127; temp_c is the
  // rounded case temperature.
  drivers::GyroFrame next_frame(const ThermalTruth& truth);

  // Converts a rate in °/h into the configured output value.
  double to_output(double rate_dph) const;

  double sample_period_s() const { return 1.0 / format_.rate_hz; }
  double earth_rate_dph() const { return earth_rate_dph_; }
  const GyroParams& params() const { return params_; }
  const drivers::GyroFormat& format() const { return format_; }
  uint64_t samples() const { return samples_; }
  double last_rate_dph() const { return last_rate_dph_; }  // of the last next_rate_dph()

  // The model as a human-readable formula (for the truth file).
  static std::string formula();
  // The truth file's JSON: earth rate, bias, coefficients, noise figures,
  // output format, units, the formula and the seed.
  std::string truth_json(uint64_t seed) const;

 private:
  GyroParams params_;
  drivers::GyroFormat format_;
  double earth_rate_dph_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  double white_sample_std_dph_;
  double gm_a_ = 0;  // Gauss-Markov: b' = a b + gm_drive_ ε
  double gm_drive_dph_ = 0;
  double rrw_step_dph_ = 0;
  double gm_bias_dph_ = 0;
  double rrw_dph_ = 0;
  double last_rate_dph_ = 0;
  uint8_t seq_ = 0;
  uint64_t samples_ = 0;
};

}  // namespace gyrotherm::sim
