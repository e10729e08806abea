// RateTableModel in station time: limits, hand-computed profile times, the
// position integral, the measurement noise, the velocity trip and the latch.
#include "gyrotherm/sim/rate_table_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace gyrotherm::sim {
namespace {

using drivers::TableInterlock;
using drivers::TableMode;

constexpr double kDt = 1e-3;  // = the model's substep: one step is one substep

RateTableModel spinning_table(double rate_dps, uint64_t seed = 7) {
  RateTableModel t(TableParams{}, seed);
  EXPECT_EQ(t.set_rate_demand(rate_dps), TableCommandResult::kOk);
  EXPECT_EQ(t.set_mode(TableMode::kRate), TableCommandResult::kOk);
  EXPECT_EQ(t.close_interlock(), TableCommandResult::kOk);
  return t;
}

// Steps until the true rate is within 1e-9 of `rate_dps`; the time, or -1.
double time_to_reach(RateTableModel& t, double rate_dps, double limit_s = 10) {
  for (int i = 1; i * kDt <= limit_s; ++i) {
    t.step(kDt);
    if (std::abs(t.rate_dps() - rate_dps) < 1e-9) return i * kDt;
  }
  return -1;
}

TEST(RateTableModelTest, AccelerationAndJerkLimitsHoldThroughASpinUpAndBack) {
  const TableParams p;
  RateTableModel t = spinning_table(500);
  double prev_a = 0;
  double peak_a = 0;
  for (int i = 0; i < 3000; ++i) {
    if (i == 1500) {
      ASSERT_EQ(t.set_rate_demand(-300), TableCommandResult::kOk);
    }
    t.step(kDt);
    const double a = t.accel_dps2();
    ASSERT_LE(std::abs(a), p.max_accel_dps2 * (1 + 1e-12)) << "step " << i;
    ASSERT_LE(std::abs(a - prev_a) / kDt, p.max_jerk_dps3 * (1 + 1e-9)) << "step " << i;
    peak_a = std::max(peak_a, std::abs(a));
    prev_a = a;
  }
  EXPECT_NEAR(t.rate_dps(), -300, 1e-9);
  EXPECT_NEAR(peak_a, p.max_accel_dps2, 1e-9);  // the limit is reached, not just respected
}

// By hand, J = 5000 °/s³, A = 1000 °/s²: reaching Δv = 100 °/s needs
// A²/J = 200 °/s > Δv of jerk ramps, so the acceleration is a triangle of
// peak sqrt(J Δv) = 707 °/s² and the time 2 sqrt(Δv / J) = 0.28284 s.
// Δv = 500 °/s: A/J + Δv/A = 0.2 + 0.5 = 0.7 s (trapezoid).
TEST(RateTableModelTest, TimesToReachARateAreTheHandComputedOnesWithinOneStep) {
  RateTableModel t = spinning_table(100);
  EXPECT_NEAR(time_to_reach(t, 100), 2 * std::sqrt(100.0 / 5000.0), kDt);
  RateTableModel u = spinning_table(500);
  EXPECT_NEAR(time_to_reach(u, 500), 0.2 + 0.5, kDt);
}

TEST(RateTableModelTest, PositionIntegratesTheRateOverAWholeTurn) {
  RateTableModel t = spinning_table(36);
  ASSERT_GT(time_to_reach(t, 36), 0);
  const double start_unwrapped = t.unwrapped_position_deg();
  const double start = t.position_deg();
  for (int i = 0; i < 10000; ++i) t.step(kDt);  // 10 s at 36 °/s = one turn
  EXPECT_NEAR(t.unwrapped_position_deg() - start_unwrapped, 360.0, 1e-9);
  EXPECT_NEAR(t.position_deg(), start, 1e-9);
  EXPECT_GE(t.position_deg(), 0.0);
  EXPECT_LT(t.position_deg(), 360.0);
}

// σ of (measured / true − 1) over 20000 samples has a relative standard
// error of 1/sqrt(2 · 20000) = 0.5 %: ±10 % is 20 standard errors.
TEST(RateTableModelTest, MeasuredRateNoiseHasTheConfiguredRelativeSigma) {
  RateTableModel t = spinning_table(250);
  ASSERT_GT(time_to_reach(t, 250), 0);
  std::vector<double> rel;
  for (int i = 0; i < 20000; ++i) {
    t.step(kDt);
    rel.push_back(t.measured_rate_dps() / t.rate_dps() - 1);
  }
  double mean = 0;
  for (double r : rel) mean += r;
  mean /= rel.size();
  double var = 0;
  for (double r : rel) var += (r - mean) * (r - mean);
  const double sigma = std::sqrt(var / (rel.size() - 1));
  EXPECT_NEAR(sigma, 1e-4, 1e-5);
  EXPECT_NEAR(mean, 0, 5 * 1e-4 / std::sqrt(20000.0));
}

TEST(RateTableModelTest, SameSeedSameMeasurements) {
  RateTableModel a = spinning_table(100, 3);
  RateTableModel b = spinning_table(100, 3);
  for (int i = 0; i < 500; ++i) {
    a.step(kDt);
    b.step(kDt);
    ASSERT_EQ(a.measured_rate_dps(), b.measured_rate_dps());
  }
}

TEST(RateTableModelTest, OverSpeedTripsFaultsAndCoastsDownAtTheAccelerationLimit) {
  RateTableModel t = spinning_table(100);
  ASSERT_GT(time_to_reach(t, 100), 0);
  ASSERT_EQ(t.set_trip_rate(50), TableCommandResult::kOk);
  t.step(kDt);  // the trip, then coasting from the next substep on
  EXPECT_EQ(t.state().interlock, TableInterlock::kFault);
  EXPECT_EQ(t.state().mode, TableMode::kOff);
  EXPECT_NE(t.state().fault.find("velocity trip"), std::string::npos) << t.state().fault;
  const double rate_at_trip = t.rate_dps();
  for (int i = 0; i < 50; ++i) t.step(kDt);
  EXPECT_NEAR(t.rate_dps(), rate_at_trip - 1000 * 0.050, 1e-9);
  for (int i = 0; i < 60; ++i) t.step(kDt);
  EXPECT_EQ(t.rate_dps(), 0.0);
}

TEST(RateTableModelTest, FaultIsLatchedUntilResetAndClosingFromFaultIsRefused) {
  RateTableModel t = spinning_table(10);
  t.trip("test");
  EXPECT_EQ(t.close_interlock(), TableCommandResult::kRefused);
  for (int i = 0; i < 1000; ++i) t.step(kDt);
  EXPECT_EQ(t.state().interlock, TableInterlock::kFault);
  EXPECT_EQ(t.state().fault, "test");
  t.reset_faults();
  EXPECT_EQ(t.state().interlock, TableInterlock::kOpen);
  EXPECT_EQ(t.state().fault, "");
  EXPECT_EQ(t.close_interlock(), TableCommandResult::kOk);
  EXPECT_EQ(t.state().interlock, TableInterlock::kClosed);
}

TEST(RateTableModelTest, OffModeDeceleratesToRestAndStaysServoed) {
  RateTableModel t = spinning_table(100);
  ASSERT_GT(time_to_reach(t, 100), 0);
  ASSERT_EQ(t.set_mode(TableMode::kOff), TableCommandResult::kOk);
  EXPECT_NEAR(time_to_reach(t, 0), 2 * std::sqrt(100.0 / 5000.0), kDt);
  EXPECT_EQ(t.state().interlock, TableInterlock::kClosed);
}

TEST(RateTableModelTest, RateDemandBeyondTheLimitIsRefusedAndOneInOffModeWaits) {
  RateTableModel t(TableParams{}, 1);
  EXPECT_EQ(t.set_rate_demand(1000.5), TableCommandResult::kOutOfRange);
  EXPECT_EQ(t.set_rate_demand(40), TableCommandResult::kOk);
  ASSERT_EQ(t.close_interlock(), TableCommandResult::kOk);
  for (int i = 0; i < 1000; ++i) t.step(kDt);
  EXPECT_EQ(t.rate_dps(), 0.0);  // off mode: the demand is stored only
  ASSERT_EQ(t.set_mode(TableMode::kRate), TableCommandResult::kOk);
  EXPECT_GT(time_to_reach(t, 40), 0);
  ASSERT_EQ(t.set_rate_limit(20), TableCommandResult::kOk);
  EXPECT_EQ(t.set_rate_demand(30), TableCommandResult::kOutOfRange);
}

TEST(RateTableModelTest, PositionModeTakesTheShortestPathAndHolds) {
  RateTableModel t(TableParams{}, 1);
  ASSERT_EQ(t.set_position_demand(350), TableCommandResult::kOk);
  ASSERT_EQ(t.set_mode(TableMode::kPosition), TableCommandResult::kOk);
  ASSERT_EQ(t.close_interlock(), TableCommandResult::kOk);
  for (int i = 0; i < 20000; ++i) {
    t.step(kDt);
    ASSERT_LE(t.rate_dps(), 1e-12) << "0 -> 350 is 10 degrees backwards";
  }
  EXPECT_NEAR(t.position_deg(), 350, 1e-6);
  ASSERT_EQ(t.set_position_demand(10), TableCommandResult::kOk);
  double overshoot = 0;
  for (int i = 0; i < 20000; ++i) {
    t.step(kDt);
    ASSERT_GE(t.rate_dps(), -1e-12) << "350 -> 10 is 20 degrees forwards";
    overshoot = std::max(overshoot, shortest_angle_deg(10, t.position_deg()));
  }
  EXPECT_NEAR(t.position_deg(), 10, 1e-6);
  EXPECT_EQ(t.rate_dps(), 0.0);
  EXPECT_LT(overshoot, 1e-3);
}

TEST(RateTableModelTest, AnglesWrap) {
  EXPECT_EQ(wrap_360(-10), 350);
  EXPECT_EQ(wrap_360(720), 0);
  EXPECT_EQ(shortest_angle_deg(350, 10), 20);
  EXPECT_EQ(shortest_angle_deg(10, 350), -20);
}

}  // namespace
}  // namespace gyrotherm::sim
