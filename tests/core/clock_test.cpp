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

TEST(WallClock, StationWallClockFollowsTheStationClock) {
  ManualClock station(500.0, 200.0);
  StationWallClock wall(station, 1774745400.0);  // 2026-03-29T00:50:00Z
  EXPECT_DOUBLE_EQ(wall.unix_now_s(), 1774745400.0);
  station.advance(3600.0);  // one station hour: one wall hour of the simulated day
  EXPECT_DOUBLE_EQ(wall.unix_now_s(), 1774749000.0);
  ManualWallClock manual(10.0);
  manual.advance(5.0);
  EXPECT_DOUBLE_EQ(manual.unix_now_s(), 15.0);
  const double real = SystemWallClock().unix_now_s();
  EXPECT_GT(real, 1.7e9);  // after 2023
}

TEST(UtcIso, FormatsAndParsesBack) {
  EXPECT_EQ(utc_iso(0.0), "1970-01-01T00:00:00.000Z");
  EXPECT_EQ(utc_iso(1774745400.125), "2026-03-29T00:50:00.125Z");
  EXPECT_EQ(utc_iso(-0.5), "1969-12-31T23:59:59.500Z");
  // Rounding to the millisecond carries into the seconds.
  EXPECT_EQ(utc_iso(1774745400.9996), "2026-03-29T00:50:01.000Z");
  for (double t : {0.0, 1774745400.125, 1795316400.0, 951782400.0 /* 2000-02-29 */}) {
    auto back = parse_utc_iso(utc_iso(t));
    ASSERT_TRUE(back.ok()) << back.error().message;
    EXPECT_DOUBLE_EQ(*back, t);
  }
}

TEST(UtcIso, ParsesDatesOffsetsAndFractions) {
  const auto at = [](const char* text) {
    auto r = parse_utc_iso(text);
    EXPECT_TRUE(r.ok()) << text << ": " << (r.ok() ? "" : r.error().message);
    return r.ok() ? *r : -1.0;
  };
  EXPECT_DOUBLE_EQ(at("2026-03-29"), 1774742400.0);
  EXPECT_DOUBLE_EQ(at("2026-03-29T00:50Z"), 1774745400.0);
  EXPECT_DOUBLE_EQ(at("2026-03-29T00:50:00"), 1774745400.0);
  EXPECT_DOUBLE_EQ(at("2026-03-29 02:50:00+02:00"), 1774745400.0);
  EXPECT_DOUBLE_EQ(at("2026-03-28T19:50:00-0500"), 1774745400.0);
  EXPECT_DOUBLE_EQ(at("2026-03-29T00:50:00.25Z"), 1774745400.25);
}

TEST(UtcIso, RefusesWhatIsNotADateNamingIt) {
  for (const char* bad : {"", "yesterday", "2026-3-29", "2026-13-01", "2026-02-30",
                          "2026-03-29T25:00Z", "2026-03-29T00:50:00Zjunk", "2026-03-29T00",
                          "2026-03-29T00:50:00.Z", "2026-03-29T00:50+2"}) {
    auto r = parse_utc_iso(bad);
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_NE(r.error().message.find(std::string("\"") + bad + "\""), std::string::npos)
        << r.error().message;
  }
}

}  // namespace
}  // namespace gyrotherm
