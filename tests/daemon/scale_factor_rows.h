// Scale-factor rows for report and export tests: three sequences of a gyro
// with a known K(T), bias(T) and a small quadratic nonlinearity, fitted by
// the analysis library (analysis/scale_factor.h) and stored as the daemon's
// run analysis stores them (storage schema v7), with the fits kept as the
// reference the rendered numbers are checked against.
#pragma once

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/analysis/scale_factor.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::test {

struct StoredScaleFactor {
  std::vector<storage::ScaleFactorPointRecord> points;  // as given to the database
  std::vector<storage::ScaleFactorFitRecord> fits;
  storage::ScaleFactorTemperatureFitRecord temperature_fit;
  // The library's results: per sequence (1, 2, 3), the points in the order
  // of `points` of that sequence, and the fit over temperature.
  std::vector<analysis::ScaleFactorFit> sequence_fits;
  std::vector<std::vector<analysis::RatePoint>> sequence_points;
  analysis::ScaleFactorTemperatureFit over_temperature;
};

inline std::string json_numbers(const std::vector<double>& v) {
  std::string out = "[";
  for (std::size_t i = 0; i < v.size(); ++i) out += fmt::format("{}{:.17g}", i ? "," : "", v[i]);
  return out + "]";
}

// Sequences 1-3 at −20, 20 and 60 °C: rates ±1, ±10, ±100, ±500 °/s, two
// repetitions (the 60 °C sequence one, so it has no repeatability), output
// = K(T)·Ω + B(T) + 4e-9·Ω² + a repetition-dependent 1e-6·Ω, and each point
// measured a little off its demanded rate. Stores them for `run_id`.
inline StoredScaleFactor store_scale_factor_rows(storage::Database& db, int64_t run_id) {
  StoredScaleFactor out;
  const double temperatures_c[] = {-20.0, 20.0, 60.0};
  const double rates_dps[] = {-500, -100, -10, -1, 1, 10, 100, 500};
  std::vector<analysis::ScaleFactorAtTemperature> plateaus;
  for (int seq = 1; seq <= 3; ++seq) {
    const double t_c = temperatures_c[seq - 1];
    const double k = 1.0000125 + 40e-6 * (t_c - 20) / 80 + 3e-10 * (t_c - 20) * (t_c - 20);
    const double bias_dps = (4.5 + 0.012 * (t_c - 20)) / 3600.0;
    std::vector<analysis::RatePoint> rp;
    const int repetitions = seq == 3 ? 1 : 2;
    for (int rep = 1; rep <= repetitions; ++rep) {
      for (double rate : rates_dps) {
        storage::ScaleFactorPointRecord p;
        p.sf_sequence = seq;
        p.repetition = rep;
        p.rate_dps = rate;
        p.measured_rate_dps = rate * (1 + 2e-7);
        p.output_dps = k * rate + bias_dps + 4e-9 * rate * rate + 1e-6 * (rep - 1.5) * rate;
        p.n = 1000 + rep;
        p.temperature_c = t_c + 0.01 * rep;
        p.duration_s = 360.0 / std::abs(rate) * 3;
        p.turns = 3;
        out.points.push_back(p);
        rp.push_back({.rate_dps = p.rate_dps,
                      .output_dps = p.output_dps,
                      .repetition = rep,
                      .temperature_c = p.temperature_c,
                      .n = static_cast<std::size_t>(p.n),
                      .duration_s = p.duration_s});
      }
    }
    auto fit = analysis::fit_scale_factor(rp);
    EXPECT_TRUE(fit.ok()) << fit.error().message;
    if (!fit.ok()) return out;
    storage::ScaleFactorFitRecord f;
    f.sf_sequence = seq;
    f.temperature_c = fit->temperature_mean_c;
    f.k = fit->k;
    f.k_se = fit->k_std_error;
    f.bias_dps = fit->bias_dps;
    f.nonlinearity_ppm = fit->nonlinearity_ppm;
    f.nonlinearity_fs_ppm = fit->nonlinearity_fs_ppm;
    f.asymmetry_ppm = fit->asymmetry_ppm;
    f.repeatability_ppm = fit->repeatability_ppm;
    f.n_points = static_cast<int64_t>(fit->points);
    f.created_utc = "2026-11-24T00:00:00.000Z";
    out.fits.push_back(f);
    plateaus.push_back(
        {.temperature_c = fit->temperature_mean_c, .k = fit->k, .bias_dph = fit->bias_dph});
    out.sequence_fits.push_back(*fit);
    out.sequence_points.push_back(rp);
  }
  auto over = analysis::fit_scale_factor_over_temperature(plateaus, 2);
  EXPECT_TRUE(over.ok()) << over.error().message;
  if (!over.ok()) return out;
  out.over_temperature = *over;
  std::vector<double> bias_dps;
  for (double b : over->bias_coefficients_dph) bias_dps.push_back(b / 3600.0);
  out.temperature_fit.order = over->order;
  out.temperature_fit.t_centre_c = over->temperature_mean_c;
  out.temperature_fit.k_coeffs_json = json_numbers(over->k_coefficients);
  out.temperature_fit.bias_coeffs_json = json_numbers(bias_dps);
  out.temperature_fit.k_ppm_per_c = over->sf_temperature_coefficient_ppm_per_c;
  out.temperature_fit.bias_dph_per_c = over->bias_temperature_coefficient_dph_per_c;
  out.temperature_fit.created_utc = "2026-11-24T00:00:00.000Z";
  const Status st = db.store_scale_factor(run_id, out.points, out.fits, out.temperature_fit);
  EXPECT_TRUE(st.ok()) << st.error().message;
  return out;
}

}  // namespace gyrotherm::test
