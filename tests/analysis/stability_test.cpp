// StabilityWindow: the soak gate's view of the last window_s seconds.
#include "gyrotherm/analysis/stability.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace gyrotherm::analysis {
namespace {

TEST(StabilityWindow, FillsAfterWindowAtOneHertz) {
  StabilityWindow w(600.0);
  EXPECT_FALSE(w.full());
  EXPECT_TRUE(std::isnan(w.slope_per_s()));
  for (int t = 0; t < 599; ++t) w.push(t, 20.0);
  EXPECT_FALSE(w.full());  // span 598 s + 1 s spacing < 600
  EXPECT_TRUE(std::isnan(w.slope_per_s()));
  w.push(599, 20.0);
  EXPECT_TRUE(w.full());  // span 599 s, within one spacing of 600
  EXPECT_EQ(w.slope_per_s(), 0.0);
}

TEST(StabilityWindow, KeepsOnlyTheLastWindow) {
  StabilityWindow w(10.0);
  for (int t = 0; t <= 100; ++t) w.push(t, t);
  EXPECT_EQ(w.size(), 11u);  // t = 90 ... 100
  EXPECT_EQ(w.span_s(), 10.0);
  EXPECT_EQ(w.max_abs_dev(100.0), 10.0);
}

TEST(StabilityWindow, SlopeOfARampInUnitsPerSecond) {
  // Shell creeping at 0.03 °C/min, above a 0.02 °C/min gate; station time ~1e5 s.
  StabilityWindow w(600.0);
  const double rate_c_per_s = 0.03 / 60.0;
  for (int i = 0; i <= 1200; ++i) w.push(1e5 + 0.5 * i, 40.0 + rate_c_per_s * 0.5 * i);
  ASSERT_TRUE(w.full());
  EXPECT_NEAR(w.slope_per_s(), rate_c_per_s, 1e-12);
  EXPECT_GT(std::abs(w.slope_per_s()) * 60.0, 0.02);
}

TEST(StabilityWindow, SlopeIgnoresSamplesThatLeftTheWindow) {
  StabilityWindow w(100.0);
  for (int t = 0; t < 100; ++t) w.push(t, 2.0 * t);  // steep ramp
  for (int t = 100; t <= 300; ++t) w.push(t, 7.0);   // then flat
  ASSERT_TRUE(w.full());
  EXPECT_EQ(w.slope_per_s(), 0.0);
  EXPECT_EQ(w.max_abs_dev(7.0), 0.0);
}

TEST(StabilityWindow, MaxAbsDev) {
  StabilityWindow w(60.0);
  EXPECT_TRUE(std::isnan(w.max_abs_dev(0.0)));
  w.push(0, 59.8);
  w.push(1, 60.3);
  w.push(2, 60.1);
  EXPECT_NEAR(w.max_abs_dev(60.0), 0.3, 1e-12);
  EXPECT_NEAR(w.max_abs_dev(60.5), 0.7, 1e-12);
  EXPECT_TRUE(std::isnan(w.max_abs_dev(std::numeric_limits<double>::quiet_NaN())));
}

TEST(StabilityWindow, SameTimeReplacesEarlierTimeRestarts) {
  StabilityWindow w(10.0);
  for (int t = 0; t <= 10; ++t) w.push(t, 1.0);
  ASSERT_TRUE(w.full());
  w.push(10, 5.0);  // same time: replaces
  EXPECT_EQ(w.size(), 11u);
  EXPECT_EQ(w.max_abs_dev(1.0), 4.0);
  w.push(3, 1.0);  // clock went back: start again
  EXPECT_EQ(w.size(), 1u);
  EXPECT_FALSE(w.full());
}

TEST(StabilityWindow, NonFiniteSampleClears) {
  StabilityWindow w(10.0);
  for (int t = 0; t <= 10; ++t) w.push(t, 1.0);
  ASSERT_TRUE(w.full());
  w.push(11, std::numeric_limits<double>::quiet_NaN());
  EXPECT_EQ(w.size(), 0u);
  EXPECT_FALSE(w.full());
  w.push(12, 1.0);
  EXPECT_EQ(w.size(), 1u);
}

TEST(StabilityWindow, ClearEmpties) {
  StabilityWindow w(10.0);
  for (int t = 0; t <= 20; ++t) w.push(t, 1.0);
  w.clear();
  EXPECT_EQ(w.size(), 0u);
  EXPECT_FALSE(w.full());
  EXPECT_TRUE(std::isnan(w.slope_per_s()));
}

}  // namespace
}  // namespace gyrotherm::analysis

namespace gyrotherm::analysis {
namespace {

TEST(StabilityWindowMean, AveragesTheKeptValuesOnly) {
  StabilityWindow w(10.0);
  EXPECT_TRUE(std::isnan(w.mean()));
  for (int i = 0; i < 30; ++i) w.push(i, i < 15 ? 100.0 : 2.0 * i);
  // Kept: t = 19..29 (samples at most 10 s older than the newest), values
  // 38..58 step 2: mean 48. The early values of 100 are gone.
  EXPECT_DOUBLE_EQ(w.mean(), 48.0);
}

}  // namespace
}  // namespace gyrotherm::analysis
