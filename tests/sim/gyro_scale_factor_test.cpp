// The gyro on the rate table: its output at two temperatures and at ± rates
// against the truth formula evaluated here from the truth file's numbers
// (the model is noise-free with its noise figures at zero), the scale
// factor, its temperature coefficient and asymmetry recovered from outputs,
// and the precision the KVH frame's float32 keeps at 500 °/s.
#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/sim/gyro_model.h"

namespace gyrotherm::sim {
namespace {

constexpr double kLatitudeDeg = 31.9;

GyroModel noise_free_gyro(drivers::AngleUnit unit = drivers::AngleUnit::kDeg,
                          SensitiveAxis axis = SensitiveAxis::kAlongTable) {
  GyroParams p;
  p.bias_dph = 2.0;
  p.temp_coeffs = {0.05};
  p.white_noise_dph = 0;
  p.bias_instability_dph = 0;
  drivers::GyroFormat f;
  f.unit = unit;
  f.axis = 0;
  f.rate_hz = 100;
  GyroModel g(p, f,
              analysis::earth_rate_component_dph(kLatitudeDeg, analysis::AxisOrientation::kUp), 11);
  TableMount mount;
  mount.axis = axis;
  mount.latitude_deg = kLatitudeDeg;
  mount.heading_at_zero_deg = 30;
  mount.full_scale_dps = 1000;
  g.enable_table(ScaleFactorParams{}, mount);
  return g;
}

ThermalTruth at(double case_c) {
  ThermalTruth t;
  t.case_c = case_c;
  return t;
}

// The truth file's formula, written out from its parameters.
double truth_formula_dph(const nlohmann::json& truth, double case_c, double table_dps) {
  const auto& sf = truth["scale_factor"];
  const double omega = table_dps * 3600 + truth["earth_rate_dph"].get<double>();
  const double s = omega >= 0 ? 1 : -1;
  const double k =
      (1 + (sf["k_ppm"].get<double>() +
            sf["k_tc_ppm_per_c"].get<double>() * (case_c - sf["reference_temp_c"].get<double>())) *
               1e-6) *
      (1 + s * sf["asymmetry_ppm"].get<double>() / 2 * 1e-6);
  const double fs = sf["full_scale_dps"].get<double>() * 3600;
  const double bias =
      truth["bias_dph"].get<double>() + truth["temp_coeffs"][0].get<double>() * case_c;
  return k * omega * (1 + sf["nonlinearity_ppm"].get<double>() * 1e-6 * std::abs(omega) / fs) +
         bias;
}

TEST(GyroScaleFactorTest, OutputFollowsTheTruthFormulaAtTwoTemperaturesAndBothSigns) {
  GyroModel g = noise_free_gyro();
  const nlohmann::json truth = nlohmann::json::parse(g.truth_json(11));
  ASSERT_TRUE(truth.contains("scale_factor"));
  EXPECT_EQ(truth["scale_factor"]["k_ppm"], 150.0);
  EXPECT_EQ(truth["scale_factor"]["sensitive_axis"], "along_table");
  for (double case_c : {10.0, 50.0}) {
    for (double rate_dps : {-500.0, -100.0, 100.0, 500.0}) {
      const double expected = truth_formula_dph(truth, case_c, rate_dps);
      const double got = g.next_rate_dph(at(case_c), TableInput{rate_dps, 0});
      EXPECT_NEAR(got, expected, std::abs(expected) * 1e-13) << case_c << " C, " << rate_dps;
    }
  }
}

// Recovered from outputs: K+ and K− from ±Ω at one temperature, the
// temperature coefficient from K at 10 and 50 °C (the nonlinearity term is
// the same at both, so it cancels in the ratios).
TEST(GyroScaleFactorTest, AsymmetryAndTemperatureCoefficientRecoveredFromOutputs) {
  GyroModel g = noise_free_gyro();
  const double earth = g.earth_rate_dph();
  auto k_of = [&](double case_c, double rate_dps) {
    const double zero = 2.0 + 0.05 * case_c;  // bias(T), known here
    return (g.next_rate_dph(at(case_c), TableInput{rate_dps, 0}) - zero) /
           (rate_dps * 3600 + earth);
  };
  const double kp = k_of(20, 100), km = k_of(20, -100);
  EXPECT_NEAR((kp - km) / (0.5 * (kp + km)) * 1e6, 30.0, 1e-3);  // asymmetry_ppm
  const double k10 = k_of(10, 100), k50 = k_of(50, 100);
  EXPECT_NEAR((k50 - k10) / 40 / ((kp + km) / 2) * 1e6, 20.0, 0.01);  // ppm/°C
}

// float32 keeps 24 bits: a relative step of 2^-24 ≈ 6e-8 (0.06 ppm) at any
// magnitude, in °/s or rad/s alike, so 500 °/s keeps ppm precision.
TEST(GyroScaleFactorTest, FrameKeepsPpmPrecisionAt500DegreesPerSecond) {
  for (auto unit : {drivers::AngleUnit::kDeg, drivers::AngleUnit::kRad}) {
    GyroModel g = noise_free_gyro(unit);
    const drivers::GyroFrame f = g.next_frame(at(35), TableInput{500, 0});
    const double sent_dph = drivers::to_rate_dph(f.gyro[0], g.format());
    EXPECT_NEAR(sent_dph / g.last_rate_dph() - 1, 0, 1.2e-7);
  }
}

TEST(GyroScaleFactorTest, RadialAxisSeesTheEarthRateTurnWithThePosition) {
  GyroModel g = noise_free_gyro(drivers::AngleUnit::kDeg, SensitiveAxis::kRadial);
  const double horizontal = 15.041067 * std::cos(kLatitudeDeg * M_PI / 180);
  EXPECT_NEAR(g.earth_projection_dph(0), horizontal * std::cos(30 * M_PI / 180), 1e-12);
  EXPECT_NEAR(g.earth_projection_dph(60), 0, 1e-12);  // heading 30 + 60 = east
  EXPECT_NEAR(g.earth_projection_dph(150), -horizontal, 1e-12);
  GyroModel along = noise_free_gyro();
  EXPECT_EQ(along.earth_projection_dph(150), along.earth_rate_dph());
}

TEST(GyroScaleFactorTest, WithoutATableNothingChanges) {
  GyroParams p;
  p.white_noise_dph = 0;
  drivers::GyroFormat f;
  GyroModel g(p, f, 7.95, 1);
  EXPECT_FALSE(g.on_table());
  EXPECT_EQ(g.next_rate_dph(at(40), TableInput{500, 0}), 7.95);
  EXPECT_FALSE(nlohmann::json::parse(g.truth_json(1)).contains("scale_factor"));
}

}  // namespace
}  // namespace gyrotherm::sim
