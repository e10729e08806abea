#include "gyrotherm/sim/thermal_plant.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numeric>
#include <vector>

#include "gyrotherm/analysis/table1.h"

namespace gyrotherm::sim {
namespace {

ThermalParams quiet_params() {
  ThermalParams p;
  p.initial_temp_c = 23.0;
  p.control_noise_c = 0;
  p.probe_noise_c = 0;
  p.probe_quantum_c = 0;
  return p;
}

TEST(ThermalParams, RejectsOutOfRange) {
  ThermalParams p;
  std::string why;
  EXPECT_TRUE(p.is_valid(&why)) << why;
  p.case_tau_s = -1;
  EXPECT_FALSE(p.is_valid(&why));
  EXPECT_NE(why.find("case_tau_s"), std::string::npos) << why;
}

TEST(ThermalPlant, AirFollowsStepWithRampLimitAndLag) {
  ThermalParams p = quiet_params();
  p.air_tau_s = 120;
  p.max_ramp_c_per_min = 5;
  ThermalPlant plant(p, 1);
  const double dt = 0.1;
  const double ramp_c_per_s = 5.0 / 60.0;
  double previous_air = plant.truth().air_c;
  double max_air_rate = 0;
  for (int i = 1; i <= 1200; ++i) {  // 120 s
    plant.step(dt, 43.0);
    max_air_rate = std::max(max_air_rate, (plant.truth().air_c - previous_air) / dt);
    previous_air = plant.truth().air_c;
    if (i == 600) {
      EXPECT_NEAR(plant.truth().ramped_setpoint_c, 23.0 + 60 * ramp_c_per_s, 1e-9);
    }
  }
  // A ramp of slope a through a first-order lag: 23 + a (t - tau (1 - e^(-t/tau))).
  const double expected = 23.0 + ramp_c_per_s * (120 - 120 * (1 - std::exp(-1.0)));
  EXPECT_NEAR(plant.truth().air_c, expected, 0.02);
  EXPECT_LE(max_air_rate, ramp_c_per_s + 1e-9);         // never faster than the ramp
  for (int i = 0; i < 8400; ++i) plant.step(dt, 43.0);  // to t = 960 s: ramp done at 240 s
  EXPECT_DOUBLE_EQ(plant.truth().ramped_setpoint_c, 43.0);
  // The ramp ended at 240 s with the air a tau (1 - e^-2) behind; 6 tau later
  // e^-6 of that is left.
  const double behind_at_ramp_end = ramp_c_per_s * 120 * (1 - std::exp(-2.0));
  EXPECT_NEAR(plant.truth().air_c, 43.0 - behind_at_ramp_end * std::exp(-6.0), 0.003);
}

TEST(ThermalPlant, CaseCoversSixtyThreePercentOfAStepAfterOneTau) {
  ThermalParams p = quiet_params();
  p.air_tau_s = 0;              // the air jumps ...
  p.max_ramp_c_per_min = 1000;  // ... within a second
  p.case_tau_s = 900;
  ThermalPlant plant(p, 1);
  for (int i = 0; i < 9000; ++i) plant.step(0.1, 33.0);
  // 1 - e^-1 = 63.2 % of the 10 °C step; ±1 % for the second the air takes.
  EXPECT_NEAR((plant.truth().case_c - 23.0) / 10.0, 1 - std::exp(-1.0), 0.01);
  for (int i = 0; i < 18000; ++i) plant.step(0.1, 33.0);
  EXPECT_NEAR((plant.truth().case_c - 23.0) / 10.0, 1 - std::exp(-3.0), 0.01);
}

// With gradient_tau_s the gradient follows its target (offset + k x case
// rate) through a first-order lag: run the same plant with and without the
// lag and compare the lagged gradient with a first-order filter of the
// unlagged one (the same step sequence gives the same case trajectory).
TEST(ThermalPlant, GradientLagsItsTargetByGradientTau) {
  ThermalParams p = quiet_params();
  p.max_ramp_c_per_min = 1.0;
  p.gradient_c_per_c_per_min = 1.0;
  p.gradient_offset_c = 0.05;
  ThermalPlant instant(p, 1);
  p.gradient_tau_s = 600.0;
  ThermalPlant lagged(p, 1);
  const double dt_s = 0.1;
  double filtered_c = 0.05;  // starts at the offset, as the plant does
  double max_gap_c = 0;
  for (int i = 0; i < 36000; ++i) {  // heat for an hour
    instant.step(dt_s, 60.0);
    lagged.step(dt_s, 60.0);
    ASSERT_DOUBLE_EQ(lagged.truth().case_c, instant.truth().case_c);
    filtered_c += (instant.truth().gradient_c - filtered_c) * -std::expm1(-dt_s / 600.0);
    max_gap_c = std::max(max_gap_c, instant.truth().gradient_c - lagged.truth().gradient_c);
    ASSERT_NEAR(lagged.truth().gradient_c, filtered_c, 1e-12) << "step " << i;
  }
  EXPECT_GT(max_gap_c, 0.1) << "the lag is visible while the heating rate grows";
  EXPECT_NEAR(lagged.truth().top_c - lagged.truth().side_c, lagged.truth().gradient_c, 1e-9);
  ThermalParams bad = p;
  bad.gradient_tau_s = -1;
  std::string why;
  EXPECT_FALSE(bad.is_valid(&why));
  EXPECT_NE(why.find("gradient_tau_s"), std::string::npos) << why;
}

TEST(ThermalPlant, GradientFollowsHeatingAndCoolingRate) {
  ThermalParams p = quiet_params();
  p.max_ramp_c_per_min = 1.0;
  p.gradient_c_per_c_per_min = 0.3;
  p.gradient_offset_c = 0.05;
  ThermalPlant plant(p, 1);
  // Heat at 1 °C/min for 30 min; the case rate approaches 1 °C/min.
  double case_before = 0;
  for (int i = 0; i < 18000; ++i) {
    if (i == 17990) case_before = plant.truth().case_c;
    plant.step(0.1, 60.0);
  }
  // Rate from the case trajectory itself (1 s finite difference), °C/min.
  const double heating_c_per_min = (plant.truth().case_c - case_before) * 60.0;
  EXPECT_GT(heating_c_per_min, 0.7);
  EXPECT_NEAR(plant.truth().gradient_c, 0.05 + 0.3 * heating_c_per_min, 0.003);
  EXPECT_NEAR(plant.truth().top_c - plant.truth().side_c, plant.truth().gradient_c, 1e-9);
  EXPECT_NEAR((plant.truth().top_c + plant.truth().side_c) / 2, plant.truth().case_c, 1e-9);

  // Cool: the gradient turns negative (0.05 - 0.3 x ~0.7 < 0).
  for (int i = 0; i < 18000; ++i) {
    if (i == 17990) case_before = plant.truth().case_c;
    plant.step(0.1, -20.0);
  }
  const double cooling_c_per_min = (plant.truth().case_c - case_before) * 60.0;
  EXPECT_LT(cooling_c_per_min, -0.7);
  EXPECT_LT(plant.truth().gradient_c, 0.0);
  EXPECT_NEAR(plant.truth().gradient_c, 0.05 + 0.3 * cooling_c_per_min, 0.003);

  // Settled: only the offset is left.
  ThermalPlant settled(p, 1);
  for (int i = 0; i < 1000; ++i) settled.step(0.1, 23.0);
  EXPECT_NEAR(settled.truth().gradient_c, 0.05, 1e-9);
}

TEST(ThermalPlant, ReadingsAreNoisyAndQuantised) {
  ThermalParams p = quiet_params();
  p.probe_noise_c = 0.02;
  p.probe_quantum_c = 0.01;
  ThermalPlant plant(p, 7);
  std::vector<double> errors;
  for (int i = 0; i < 20000; ++i) {
    plant.step(0.1, 23.0);
    const double top = plant.readings().top_c;
    EXPECT_NEAR(top / 0.01, std::round(top / 0.01), 1e-6) << top;
    errors.push_back(top - plant.truth().top_c);
  }
  // White noise 0.02 plus quantisation (0.01 / sqrt(12)); 20000 samples give
  // the std to ~0.5 %, so ±5 % is far outside chance.
  const double expected_std = std::sqrt(0.02 * 0.02 + 0.01 * 0.01 / 12);
  EXPECT_NEAR(analysis::std_ddof1(errors), expected_std, 0.05 * expected_std);
  EXPECT_NEAR(analysis::mean(errors), 0.0, 0.001);  // SE 0.00015
}

TEST(ThermalPlant, ControlNoiseWandersSlowly) {
  ThermalParams p = quiet_params();
  p.control_noise_c = 0.5;
  p.control_noise_tau_s = 60;
  ThermalPlant plant(p, 3);
  std::vector<double> noise;  // sampled every second for 20 000 s (~330 correlation times)
  for (int i = 0; i < 200000; ++i) {
    plant.step(0.1, 23.0);
    if (i % 10 == 9) noise.push_back(plant.truth().air_c - 23.0);
  }
  // Stationary std = amplitude / 2 = 0.25 °C; with ~170 independent stretches
  // the estimate is good to ~6 % (1 sigma); ±20 % allowed.
  EXPECT_NEAR(analysis::std_ddof1(noise), 0.25, 0.05);
  // Band-limited, not white: one second apart the noise is still almost the
  // same (AR(1) coefficient e^(-1/60) = 0.983).
  const double m = analysis::mean(noise);
  double num = 0, den = 0;
  for (std::size_t i = 0; i + 1 < noise.size(); ++i) num += (noise[i] - m) * (noise[i + 1] - m);
  for (double v : noise) den += (v - m) * (v - m);
  EXPECT_GT(num / den, 0.95);
  // The case filters it: its excursions are much smaller than the air's.
  EXPECT_LT(std::abs(plant.truth().case_c - 23.0), 0.3);
}

TEST(ThermalPlant, DeterministicGivenSeed) {
  ThermalParams p;  // all noise on
  ThermalPlant a(p, 42), b(p, 42), c(p, 43);
  for (int i = 0; i < 1000; ++i) {
    a.step(0.1, 30.0);
    b.step(0.1, 30.0);
    c.step(0.1, 30.0);
  }
  EXPECT_EQ(a.truth().air_c, b.truth().air_c);
  EXPECT_EQ(a.readings().top_c, b.readings().top_c);
  EXPECT_NE(a.truth().air_c, c.truth().air_c);
}

TEST(ThermalPlant, ControllerRampLimitNeverExceedsPlantLimit) {
  ThermalParams p = quiet_params();
  p.max_ramp_c_per_min = 2.0;
  ThermalPlant plant(p, 1);
  plant.set_ramp_limit_c_per_min(1.0);
  for (int i = 0; i < 600; ++i) plant.step(0.1, 60.0);
  EXPECT_NEAR(plant.truth().ramped_setpoint_c, 24.0, 1e-9);
  plant.set_ramp_limit_c_per_min(10.0);  // capped at 2 °C/min
  for (int i = 0; i < 600; ++i) plant.step(0.1, 60.0);
  EXPECT_NEAR(plant.truth().ramped_setpoint_c, 26.0, 1e-9);
}

TEST(ThermalPlant, ForcedAirRunsAwayAtTheMaxRampAndComesBackWhenReleased) {
  ThermalParams p = quiet_params();
  p.air_tau_s = 120;
  p.max_ramp_c_per_min = 5;
  ThermalPlant plant(p, 1);
  plant.set_ramp_limit_c_per_min(1.0);  // the controller's ramp setting does not hold it back
  plant.force_air_c(80.0);
  ASSERT_EQ(plant.forced_air_c(), 80.0);
  const double runaway_c_per_s = 5.0 / 60.0;
  for (int i = 0; i < 1200; ++i) plant.step(0.1, 23.0);  // 120 s, set point held at 23
  EXPECT_NEAR(plant.truth().ramped_setpoint_c, 23.0 + 120 * runaway_c_per_s, 1e-9);
  // The usual lag: 23 + a (t - tau (1 - e^(-t/tau))), as for a set point step.
  EXPECT_NEAR(plant.truth().air_c, 23.0 + runaway_c_per_s * 120 * std::exp(-1.0), 0.02);
  for (int i = 0; i < 12000; ++i) plant.step(0.1, 23.0);  // to 1320 s: at 80 since 684 s
  EXPECT_DOUBLE_EQ(plant.truth().ramped_setpoint_c, 80.0);
  // 10 °C behind when the ramp ended; 5.3 tau later 0.05 °C is left.
  EXPECT_NEAR(plant.truth().air_c, 80.0, 0.1);

  // Released: back towards the requested set point at the controller's own
  // ramp limit (1 °C/min).
  plant.force_air_c(std::nullopt);
  EXPECT_FALSE(plant.forced_air_c());
  for (int i = 0; i < 600; ++i) plant.step(0.1, 23.0);
  EXPECT_NEAR(plant.truth().ramped_setpoint_c, 79.0, 1e-9);

  // Forced below the set point too; a non-finite target is a release.
  plant.force_air_c(-10.0);
  plant.step(60.0, 23.0);
  EXPECT_NEAR(plant.truth().ramped_setpoint_c, 74.0, 1e-9);
  plant.force_air_c(std::numeric_limits<double>::quiet_NaN());
  EXPECT_FALSE(plant.forced_air_c());
}

}  // namespace
}  // namespace gyrotherm::sim
