#include "gyrotherm/sim/gyro_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <numeric>
#include <vector>

#include "gyrotherm/analysis/table1.h"

namespace gyrotherm::sim {
namespace {

// The demo truth ([simulator.gyro] in config/demo.toml).
GyroParams demo_params() {
  GyroParams p;
  p.bias_dph = 0.05;
  p.temp_coeffs = {0.004, -8.0e-5};
  p.rate_coeffs = {12.0};
  p.gradient_coeffs = {0.5};
  p.white_noise_dph = 1.0;
  p.bias_instability_dph = 0.0;
  return p;
}

drivers::GyroFormat format_hz(double rate_hz) {
  drivers::GyroFormat f;
  f.rate_hz = rate_hz;
  return f;
}

ThermalTruth truth_at(double case_c, double rate_c_per_s, double gradient_c) {
  ThermalTruth t;
  t.case_c = case_c;
  t.case_rate_c_per_s = rate_c_per_s;
  t.gradient_c = gradient_c;
  return t;
}

// Earth rate on an up axis at the paper's latitude, written out here rather
// than taken from the analysis module.
const double kEarthDph = 15.041067 * std::sin(31.9 * std::numbers::pi / 180.0);

TEST(GyroModel, ModelRateIsEarthPlusTruthPolynomial) {
  GyroModel model(demo_params(), format_hz(10), kEarthDph, 1);
  const double expected = kEarthDph + 0.05 + 0.004 * 40 - 8.0e-5 * 1600 + 12.0 * 0.01 + 0.5 * 0.3;
  EXPECT_NEAR(model.model_rate_dph(40.0, 0.01, 0.3), expected, 1e-12);
  EXPECT_NEAR(kEarthDph, 7.95, 0.01);
}

TEST(GyroModel, OneSecondMeansHaveWhiteNoiseStdAndTheModelMean) {
  const double rate_hz = 100;
  GyroModel model(demo_params(), format_hz(rate_hz), kEarthDph, 5);
  const ThermalTruth truth = truth_at(40.0, 0.01, 0.3);
  std::vector<double> means;  // 2000 one-second means
  for (int s = 0; s < 2000; ++s) {
    double sum = 0;
    for (int i = 0; i < rate_hz; ++i) sum += model.next_rate_dph(truth);
    means.push_back(sum / rate_hz);
  }
  // std of 2000 means: relative standard error 1/sqrt(2 x 2000) = 1.6 %;
  // ±6 % is ~4 sigma.
  EXPECT_NEAR(analysis::std_ddof1(means), 1.0, 0.06);
  // Mean: standard error 1 / sqrt(2000) = 0.022 °/h; ±0.1 is ~4.5 sigma.
  EXPECT_NEAR(analysis::mean(means), model.model_rate_dph(40.0, 0.01, 0.3), 0.1);
}

TEST(GyroModel, BiasInstabilityIsGaussMarkovWithStatedStd) {
  GyroParams p;
  p.white_noise_dph = 0;
  p.bias_instability_dph = 0.5;
  p.bias_instability_tau_s = 10;
  GyroModel model(p, format_hz(10), 0.0, 9);
  std::vector<double> x;
  for (int i = 0; i < 100000; ++i) x.push_back(model.next_rate_dph(truth_at(0, 0, 0)));
  // 10 000 s = 1000 correlation times: the std is good to ~3 %; ±10 % allowed.
  EXPECT_NEAR(analysis::std_ddof1(x), 0.5, 0.05);
  const double m = analysis::mean(x);
  double num = 0, den = 0;
  for (std::size_t i = 0; i + 1 < x.size(); ++i) num += (x[i] - m) * (x[i + 1] - m);
  for (double v : x) den += (v - m) * (v - m);
  EXPECT_NEAR(num / den, std::exp(-0.1 / 10), 0.005);  // AR(1) coefficient
}

TEST(GyroModel, RateRandomWalkGrowsWithSquareRootOfTime) {
  GyroParams p;
  p.white_noise_dph = 0;
  p.rate_random_walk_dph_per_sqrt_h = 6.0;  // °/h/√h
  std::vector<double> after_one_hour;
  for (uint64_t seed = 0; seed < 300; ++seed) {
    GyroModel model(p, format_hz(1), 0.0, seed);
    double last = 0;
    for (int i = 0; i < 3600; ++i) last = model.next_rate_dph(truth_at(0, 0, 0));
    after_one_hour.push_back(last);
  }
  // 300 walks: the std across them is good to ~4 %; ±15 % allowed.
  EXPECT_NEAR(analysis::std_ddof1(after_one_hour), 6.0, 0.9);
}

TEST(GyroModel, ConvertsToConfiguredOutput) {
  drivers::GyroFormat f = format_hz(100);
  f.unit = drivers::AngleUnit::kDeg;
  f.kind = drivers::OutputKind::kRate;
  EXPECT_NEAR(GyroModel(GyroParams{}, f, 0, 1).to_output(3600.0), 1.0, 1e-12);  // °/s
  f.unit = drivers::AngleUnit::kRad;
  EXPECT_NEAR(GyroModel(GyroParams{}, f, 0, 1).to_output(3600.0), std::numbers::pi / 180, 1e-15);
  f.kind = drivers::OutputKind::kDeltaAngle;  // rad per sample at 100 Hz
  EXPECT_NEAR(GyroModel(GyroParams{}, f, 0, 1).to_output(3600.0), std::numbers::pi / 180 / 100,
              1e-15);
  // The drivers' conversion reads it back.
  EXPECT_NEAR(
      drivers::to_rate_dph(static_cast<float>(GyroModel(GyroParams{}, f, 0, 1).to_output(8.0)), f),
      8.0, 1e-5);
}

TEST(GyroModel, FramesCarryTheAxisSequenceStatusAndTemperature) {
  GyroParams p = demo_params();
  drivers::GyroFormat f = format_hz(10);
  f.axis = 1;  // y
  f.unit = drivers::AngleUnit::kDeg;
  GyroModel model(p, f, kEarthDph, 3);
  const ThermalTruth truth = truth_at(36.6, 0, 0.05);
  double sum_y_dph = 0, sum_x_dph = 0;
  for (int i = 0; i < 300; ++i) {
    const drivers::GyroFrame frame = model.next_frame(truth);
    EXPECT_EQ(frame.seq, i % 128);
    EXPECT_EQ(frame.status, 0x77);
    EXPECT_EQ(frame.temp_c, 37);
    EXPECT_NEAR(frame.accel[2], 1.0, 0.01);
    EXPECT_NEAR(frame.accel[0], 0.0, 0.01);
    EXPECT_NEAR(drivers::to_rate_dph(frame.gyro[1], f), model.last_rate_dph(), 1e-3);
    sum_y_dph += drivers::to_rate_dph(frame.gyro[1], f);
    sum_x_dph += drivers::to_rate_dph(frame.gyro[0], f);
  }
  // Per-sample std sqrt(10) °/h: the 300-sample means are within ~0.18 °/h (1 sigma).
  EXPECT_NEAR(sum_y_dph / 300, model.model_rate_dph(36.6, 0, 0.05), 1.0);
  EXPECT_NEAR(sum_x_dph / 300, 0.0, 1.0);
}

TEST(GyroModel, DeterministicGivenSeed) {
  GyroParams p = demo_params();
  p.bias_instability_dph = 0.02;
  GyroModel a(p, format_hz(10), kEarthDph, 11), b(p, format_hz(10), kEarthDph, 11),
      c(p, format_hz(10), kEarthDph, 12);
  const ThermalTruth truth = truth_at(23, 0, 0.05);
  bool all_equal = true, any_differs = false;
  for (int i = 0; i < 100; ++i) {
    const double ra = a.next_rate_dph(truth);
    all_equal = all_equal && ra == b.next_rate_dph(truth);
    any_differs = any_differs || ra != c.next_rate_dph(truth);
  }
  EXPECT_TRUE(all_equal);
  EXPECT_TRUE(any_differs);
}

TEST(GyroModel, TruthJsonNamesTheModel) {
  GyroModel model(demo_params(), format_hz(10), kEarthDph, 1);
  const std::string json = model.truth_json(1);
  for (const char* key :
       {"\"earth_rate_dph\"", "\"bias_dph\"", "\"temp_coeffs\"", "\"rate_coeffs\"",
        "\"gradient_coeffs\"", "\"white_noise_dph\"", "\"bias_instability_dph\"", "\"rate_hz\"",
        "\"units\"", "\"formula\"", "\"seed\""}) {
    EXPECT_NE(json.find(key), std::string::npos) << key;
  }
}

}  // namespace
}  // namespace gyrotherm::sim
