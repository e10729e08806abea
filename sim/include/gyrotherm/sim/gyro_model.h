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
// With a rate table (enable_table(); the simulator does it when it serves a
// table), the input the gyro sees is the table's true rate plus the Earth
// rate projected on the sensitive axis, through a scale factor:
//   Ω   = table_rate_dps · 3600 + earth_projection_dph            (°/h)
//   K   = (1 + (k_ppm + k_tc_ppm_per_c · (T − reference_temp_c)) · 1e-6)
//         · (1 ± asymmetry_ppm / 2 · 1e-6)      (+ for Ω ≥ 0, − for Ω < 0)
//   rate = K · Ω · (1 + nonlinearity_ppm · 1e-6 · |Ω| / Ω_fs)
//        + bias_dph + the three polynomials + noise
// with Ω_fs the table's maximum rate in °/h. earth_projection_dph is
// earth_rate_dph() for a sensitive axis along the table's axis, and
// Ω_E · cos(latitude) · cos(heading_at_zero_deg + position) for a radial
// one. Without a table the formula above (no scale factor) holds.
//
// An axis off the table's spin axis of a DUT on the table (turn_with_table())
// is horizontal and turns with the table: no table rate reaches it, and its
// Earth rate is Ω_E · cos(latitude) · cos(heading + position) at each sample
// instead of the fixed earth_rate_dph (which is its value at position 0).
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
  bool is_valid(std::string* why) const;
};

// [simulator.scale_factor]: the scale-factor truth (see the formula above).
struct ScaleFactorParams {
  double k_ppm = 150.0;            // K − 1 at reference_temp_c, ppm
  double k_tc_ppm_per_c = 20.0;    // dK/dT, ppm/°C
  double reference_temp_c = 20.0;  // T where K − 1 = k_ppm
  double asymmetry_ppm = 30.0;     // (K+ − K−) / K̄, ppm
  double nonlinearity_ppm = 40.0;  // quadratic-in-|Ω| deviation at full scale, ppm

  bool is_valid(std::string* why) const;
};

// How the gyro's sensitive axis sits on the table ([table] sensitive_axis).
enum class SensitiveAxis { kAlongTable, kRadial };

struct TableMount {
  SensitiveAxis axis = SensitiveAxis::kAlongTable;
  double latitude_deg = 0;
  double heading_at_zero_deg = 0;  // azimuth of the sensitive axis at position 0
  double full_scale_dps = 1000;    // Ω_fs, the table's max rate
};

// What the gyro sees of the table at a sample.
struct TableInput {
  double rate_dps = 0;  // true rate
  double position_deg = 0;
};

inline constexpr uint8_t kGyroStatusAllValid = 0x77;  // gyro X/Y/Z and accel X/Y/Z valid

class GyroModel {
 public:
  // `format` sets the output (unit, rate or delta angle, axis, rate_hz > 0).
  GyroModel(GyroParams params, drivers::GyroFormat format, double earth_rate_dph, uint64_t seed);

  // The noise-free part (Earth rate, bias and the three polynomials), °/h.
  double model_rate_dph(double case_c, double case_rate_c_per_s, double gradient_c) const;

  // Puts the gyro on a rate table: from now on next_rate_dph() and
  // next_frame() take a TableInput and apply the scale factor.
  void enable_table(ScaleFactorParams sf, TableMount mount);
  // A horizontal sensitive axis pointing at azimuth `heading_deg` (clockwise
  // from north) at table position 0, turning with the table but not along
  // its spin axis: its Earth rate follows TableInput::position_deg (see
  // above); the table's rate does not reach it. Not with enable_table().
  void turn_with_table(double latitude_deg, double heading_deg);
  bool turns_with_table() const { return turning_; }
  // The Earth rate the sensitive axis sees at table position `position_deg`,
  // °/h, off the table's spin axis: earth_rate_dph(), or for an axis that
  // turns with the table its projection at that position.
  double earth_rate_at_dph(double position_deg) const;
  bool on_table() const { return on_table_; }
  // K at case temperature `case_c` for an input of sign `positive`.
  double scale_factor(double case_c, bool positive) const;
  // Earth rate on the sensitive axis, °/h, at table position `position_deg`.
  double earth_projection_dph(double position_deg) const;
  // The noise-free output on the table, °/h.
  double model_rate_on_table_dph(const ThermalTruth& truth, const TableInput& table) const;

  // One sample of the sensitive axis, °/h, noise included; advances the
  // noise processes by one sample period (1 / rate_hz station seconds).
  // `table` is ignored unless on_table().
  double next_rate_dph(const ThermalTruth& truth, const TableInput& table = {});

  // One KVH 1750 frame: the sensitive axis carries next_rate_dph() in the
  // configured output; the other two axes carry white noise only; accel is
  // (0, 0, 1 g) + noise; status 0x77; seq counts 0..127; temp_c is the
  // rounded case temperature.
  drivers::GyroFrame next_frame(const ThermalTruth& truth, const TableInput& table = {});

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
  // output format, units, the formula and the seed; on a table also
  // "scale_factor" (every parameter, the mount and the formula).
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
  bool on_table_ = false;
  bool turning_ = false;  // turn_with_table()
  double turning_latitude_deg_ = 0;
  double turning_heading_deg_ = 0;
  ScaleFactorParams sf_;
  TableMount mount_;
  uint8_t seq_ = 0;
  uint64_t samples_ = 0;
};

}  // namespace gyrotherm::sim
