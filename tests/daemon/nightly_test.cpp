// Nightly export schedule: local time of day in a time zone, across
// daylight-saving changes and downtime. References: hand-computed instants
// (commented) and, for the POSIX rule, the system's tz database through
// localtime_r with TZ set (tzdata).
#include "gyrotherm/config/nightly.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <string>

#include "utc_time.h"

namespace gyrotherm::config {
namespace {

using test::utc;

const char* const kBerlin = "CET-1CEST,M3.5.0,M10.5.0/3";

TimeZone berlin() {
  auto z = TimeZone::posix(kBerlin);
  EXPECT_TRUE(z.ok()) << z.error().message;
  return *z;
}

TEST(Nightly, ParsesLocalTimesAndNamesBadOnes) {
  auto t = parse_local_time_of_day("02:30");
  ASSERT_TRUE(t.ok());
  EXPECT_EQ(t->hour, 2);
  EXPECT_EQ(t->minute, 30);
  for (const char* bad : {"", "2:30", "24:00", "12:60", "ab:cd", "02:30:00", "02-30"}) {
    auto r = parse_local_time_of_day(bad);
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_NE(r.error().message.find(std::string("\"") + bad + "\""), std::string::npos)
        << r.error().message;
  }
  auto z = TimeZone::posix("not a zone,,");
  ASSERT_FALSE(z.ok());
  EXPECT_NE(z.error().message.find("not a zone"), std::string::npos) << z.error().message;
}

TEST(Nightly, NextSlotIsStrictlyLaterAndDaily) {
  const TimeZone utc0 = TimeZone::fixed(0);
  const LocalTimeOfDay at{2, 0};
  EXPECT_EQ(next_slot_unix_s(utc(2026, 11, 21, 10), at, utc0), utc(2026, 11, 22, 2));
  EXPECT_EQ(next_slot_unix_s(utc(2026, 11, 22, 1, 59), at, utc0), utc(2026, 11, 22, 2));
  EXPECT_EQ(next_slot_unix_s(utc(2026, 11, 22, 2), at, utc0), utc(2026, 11, 23, 2));
  // UTC+5:30: 02:00 local is 20:30 UTC the day before.
  const TimeZone india = TimeZone::fixed(19800);
  EXPECT_EQ(next_slot_unix_s(utc(2026, 11, 21, 10), at, india), utc(2026, 11, 21, 20, 30));
}

TEST(Nightly, SpringForwardGapRunsAtTheEndOfTheGap) {
  const TimeZone zone = berlin();
  const LocalTimeOfDay at{2, 30};
  // 2026-03-28 (CET, UTC+1): 02:30 local = 01:30 UTC.
  const double sat = next_slot_unix_s(utc(2026, 3, 27, 12), at, zone);
  EXPECT_EQ(sat, utc(2026, 3, 28, 1, 30));
  // 2026-03-29: clocks jump 02:00 CET -> 03:00 CEST at 01:00 UTC; 02:30 does
  // not exist, the export runs at 03:00 CEST = 01:00 UTC.
  const double sun = next_slot_unix_s(sat, at, zone);
  EXPECT_EQ(sun, utc(2026, 3, 29, 1, 0));
  // 2026-03-30 (CEST, UTC+2): 02:30 local = 00:30 UTC; a 23.5 h night.
  const double mon = next_slot_unix_s(sun, at, zone);
  EXPECT_EQ(mon, utc(2026, 3, 30, 0, 30));
}

TEST(Nightly, FallBackOverlapRunsOnceAtTheEarlierInstant) {
  const TimeZone zone = berlin();
  const LocalTimeOfDay at{2, 30};
  // 2026-10-25: 03:00 CEST -> 02:00 CET at 01:00 UTC; 02:30 local happens at
  // 00:30 UTC (CEST) and again at 01:30 UTC (CET): the export runs at 00:30.
  const double sun = next_slot_unix_s(utc(2026, 10, 24, 12), at, zone);
  EXPECT_EQ(sun, utc(2026, 10, 25, 0, 30));
  // Not again at 01:30 UTC the same night: next is Monday 02:30 CET.
  EXPECT_EQ(next_slot_unix_s(sun, at, zone), utc(2026, 10, 26, 1, 30));
  EXPECT_EQ(next_slot_unix_s(utc(2026, 10, 25, 1, 0), at, zone), utc(2026, 10, 26, 1, 30));
}

TEST(Nightly, PosixRuleMatchesTheSystemTzDatabase) {
  if (!std::filesystem::exists("/usr/share/zoneinfo/Europe/Berlin") ||
      !std::filesystem::exists("/usr/share/zoneinfo/Australia/Sydney")) {
    GTEST_SKIP() << "tzdata not installed (scripts/install-deps installs it)";
  }
  const char* old_tz = std::getenv("TZ");
  const std::string saved = old_tz ? old_tz : "";
  struct Case {
    const char* iana;
    const char* posix;
  };
  for (const Case& c :
       {Case{"Europe/Berlin", kBerlin}, Case{"Australia/Sydney", "AEST-10AEDT,M10.1.0,M4.1.0/3"}}) {
    setenv("TZ", c.iana, 1);
    tzset();
    const TimeZone system = TimeZone::system_local();
    auto rule = TimeZone::posix(c.posix);
    ASSERT_TRUE(rule.ok()) << rule.error().message;
    // Every 15 minutes of 2026 and 2027.
    int checked = 0;
    for (double t = utc(2026, 1, 1, 0); t < utc(2028, 1, 1, 0); t += 900, ++checked) {
      ASSERT_EQ(rule->offset_s(t), system.offset_s(t)) << c.iana << " at unix " << t;
    }
    EXPECT_EQ(checked, 2 * 365 * 96);
  }
  if (old_tz) {
    setenv("TZ", saved.c_str(), 1);
  } else {
    unsetenv("TZ");
  }
  tzset();
}

// Boost's POSIX rule parser trusts its input ("A-1B,1,/" read past the end
// of the string; found by the config fuzz target): rules are checked first.
TEST(Nightly, PosixRulesAreCheckedBeforeBoostReadsThem) {
  for (const char* good : {"UTC0", "CET-1CEST,M3.5.0,M10.5.0/3", "AEST-10AEDT,M10.1.0,M4.1.0/3",
                           "EST5EDT,M3.2.0/2:00:00,M11.1.0/2:00:00", "IST-5:30",
                           "NZST-12NZDT-13,M9.5.0,M4.1.0/3", "ABC+3DEF,J60/2,J300"}) {
    auto zone = TimeZone::posix(good);
    EXPECT_TRUE(zone.ok()) << good << ": " << (zone.ok() ? "" : zone.error().message);
  }
  auto ist = TimeZone::posix("IST-5:30");
  ASSERT_TRUE(ist.ok());
  EXPECT_EQ(ist->offset_s(0), 5 * 3600 + 30 * 60);
  for (const char* bad :
       {"", "A-1B,1,/", "Mars/Olympus", "CET", "CET-1CEST", "CET-25", "CET-1CEST,M13.5.0,M10.5.0",
        "CET-1CEST,M3.6.0,M10.5.0", "CET-1CEST,J0,J365", "CET-1CEST,M3.5.0",
        "CET-1CEST,M3.5.0,M10.5.0/x", "CET-1:60", "CET-1CEST,M3.5.0,M10.5.0 trailing", "C1",
        // Mixed forms (Boost reads the end in the start's form and asserts)
        // and the zero-based n form (Boost mis-reads it); found by fuzzing.
        "utn5IchDDDD0,M10.5.0/3,6", "CET-1CEST,M3.5.0,J300", "CET-1CEST,J60,M10.5.0",
        "CET-1CEST,59,300"}) {
    auto zone = TimeZone::posix(bad);
    ASSERT_FALSE(zone.ok()) << bad;
    EXPECT_NE(zone.error().message.find(std::string("\"") + bad + "\""), std::string::npos)
        << zone.error().message;
  }
}

TEST(Nightly, DowntimeOverSeveralSlotsGivesOneCatchUpExport) {
  const TimeZone zone = berlin();
  const LocalTimeOfDay at{2, 0};
  const double monday_slot = utc(2026, 11, 23, 1);  // 02:00 CET
  // Running on Monday at 10:00 local: nothing due.
  EXPECT_FALSE(due_slot_unix_s(monday_slot, 0, utc(2026, 11, 23, 9), at, zone).has_value());
  // Down from Monday until Thursday 05:00 local: one export, for Thursday's slot.
  auto due = due_slot_unix_s(monday_slot, 0, utc(2026, 11, 26, 4), at, zone);
  ASSERT_TRUE(due.has_value());
  EXPECT_EQ(*due, utc(2026, 11, 26, 1));
  // Once it is recorded, nothing more is due until Friday 02:00.
  EXPECT_FALSE(due_slot_unix_s(*due, 0, utc(2026, 11, 27, 0, 59), at, zone).has_value());
  EXPECT_EQ(due_slot_unix_s(*due, 0, utc(2026, 11, 27, 1), at, zone), utc(2026, 11, 27, 1));
  // Never exported: slots count from the first start.
  const double first_start = utc(2026, 11, 23, 12);
  EXPECT_FALSE(
      due_slot_unix_s(std::nullopt, first_start, utc(2026, 11, 24, 0, 59), at, zone).has_value());
  EXPECT_EQ(due_slot_unix_s(std::nullopt, first_start, utc(2026, 11, 24, 1), at, zone),
            utc(2026, 11, 24, 1));
}

}  // namespace
}  // namespace gyrotherm::config
