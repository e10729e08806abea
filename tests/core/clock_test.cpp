#include "gyrotherm/core/clock.h"

#include <gtest/gtest.h>

#include <regex>

namespace gyrotherm {
namespace {

TEST(ManualClock, MovesOnlyWhenTold) {
  ManualClock clock(100.0, 50.0);
  EXPECT_DOUBLE_EQ(clock.now_s(), 100.0);
  clock.advance(7200.0);
  EXPECT_DOUBLE_EQ(clock.now_s(), 7300.0);
  EXPECT_DOUBLE_EQ(clock.time_scale(), 50.0);
}

TEST(Clock, WallDurationDividesByScale) {
  ManualClock clock(0.0, 1000.0);
  // A two-hour soak at --time-scale 1000 takes 7.2 s of wall time.
  EXPECT_EQ(clock.wall_duration(7200.0), std::chrono::milliseconds(7200));
}

TEST(ScaledClock, RunsFasterThanWallTimeAndIsMonotonic) {
  ScaledClock clock(1000.0, 10.0);
  const double a = clock.now_s();
  const auto wall_start = std::chrono::steady_clock::now();
  while (std::chrono::steady_clock::now() - wall_start < std::chrono::milliseconds(5)) {
  }
  const double b = clock.now_s();
  EXPECT_GE(a, 10.0);
  // At least 5 ms of wall time passed: at least 5 s of station time.
  EXPECT_GE(b - a, 5.0);
}

TEST(WallTime, IsIsoUtcWithMilliseconds) {
  const std::string s = wall_time_utc_iso();
  EXPECT_TRUE(std::regex_match(s, std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z)"))) << s;
}

}  // namespace
}  // namespace gyrotherm
