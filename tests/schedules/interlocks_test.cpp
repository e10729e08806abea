// The interlock table (interlocks.h, kInterlockDefinitions) walked row by row:
// what every interlock must have, so that a new row is checked without a new
// test. Each row's messages and hysteresis are tested in sequencer_test.cpp.
#include "gyrotherm/schedules/interlocks.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <functional>
#include <iterator>
#include <limits>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "test_files.h"

namespace gyrotherm::schedules {
namespace {

namespace fs = std::filesystem;
using testing::read_text;

// The default grace of each interlock as docs/schedules.md's "Interlocks"
// table gives it (`| `name` | trips when | N min |`), in minutes.
std::map<std::string, double> documented_grace_min() {
  std::istringstream doc(read_text(fs::path(GYROTHERM_SOURCE_DIR) / "docs/schedules.md"));
  const std::regex row(R"(^\| `([a-z_]+)` \|.*\| ([0-9.]+) min \|\s*$)");
  std::map<std::string, double> out;
  bool in_section = false;
  for (std::string line; std::getline(doc, line);) {
    if (line.rfind("### ", 0) == 0) in_section = line == "### Interlocks";
    std::smatch m;
    if (in_section && std::regex_match(line, m, row)) out[m[1]] = std::stod(m[2]);
  }
  return out;
}

// Readings of a station at 30 °C with every device answering, its rate
// table at rest.
const Readings kNominal = [] {
  Readings r{30.0, 30.05, 29.95};
  r.table_present = true;
  r.table_rate_dps = 0.0;
  r.table_position_deg = 90.0;
  return r;
}();

// Readings that trip each interlock that has a check. A new row needs one
// here: the table test fails without it.
const std::map<InterlockKind, Readings>& tripping_readings() {
  static const std::map<InterlockKind, Readings> readings = [] {
    std::map<InterlockKind, Readings> m;
    m[InterlockKind::kOutOfLimits] = Readings{63.0, 30.0, 30.0};
    m[InterlockKind::kProbeDisagreement] = Readings{30.0, 31.5, 28.5};
    auto edit = [&](InterlockKind kind, auto change) {
      Readings r = kNominal;
      change(r);
      m[kind] = r;
    };
    edit(InterlockKind::kChamberSilent, [](Readings& r) { r.chamber_silent_s = 11; });
    edit(InterlockKind::kProbesSilent, [](Readings& r) { r.probes_silent_s = 11; });
    edit(InterlockKind::kGyroLost, [](Readings& r) { r.gyro_silent_s = 6; });
    edit(InterlockKind::kChamberAlarm, [](Readings& r) { r.chamber_alarm = true; });
    edit(InterlockKind::kStorageFailing, [](Readings& r) { r.storage_failing_s = 11; });
    edit(InterlockKind::kTableFault, [](Readings& r) {
      r.table_fault = true;
      r.table_fault_text = "axis 1 over-speed";
    });
    edit(InterlockKind::kTableSilent, [](Readings& r) {
      r.table_rate_dps.reset();
      r.table_position_deg.reset();
      r.table_silent_s = 11;
    });
    return m;
  }();
  return readings;
}

TEST(InterlockTable, EveryKindHasAUniqueNameThatRoundTrips) {
  std::set<std::string_view> names;
  for (int k = 0; k < kInterlockKindCount; ++k) {
    const auto kind = static_cast<InterlockKind>(k);
    const InterlockDefinition& d = kInterlockDefinitions[k];
    SCOPED_TRACE(std::string(d.name));
    EXPECT_EQ(d.kind, kind);
    EXPECT_FALSE(d.name.empty());
    EXPECT_TRUE(names.insert(d.name).second) << "name used twice";
    EXPECT_EQ(to_string(kind), d.name);
    EXPECT_EQ(parse_interlock_kind(d.name), kind);
  }
  EXPECT_EQ(parse_interlock_kind("meteor"), std::nullopt);
  EXPECT_EQ(parse_interlock_kind(""), std::nullopt);
  EXPECT_EQ(to_string(static_cast<InterlockKind>(kInterlockKindCount)), "?");
}

TEST(InterlockTable, DefaultGraceIsTheDocumentedOne) {
  const auto documented = documented_grace_min();
  EXPECT_EQ(documented.size(), static_cast<std::size_t>(kInterlockKindCount))
      << "docs/schedules.md, Interlocks: one row per interlock";
  const std::string api_md = read_text(fs::path(GYROTHERM_SOURCE_DIR) / "docs/api.md");
  const InterlockOptions options;
  for (const InterlockDefinition& d : kInterlockDefinitions) {
    SCOPED_TRACE(std::string(d.name));
    EXPECT_GT(d.default_grace_min, 0) << "0 would abort at the first trip";
    const auto it = documented.find(std::string(d.name));
    ASSERT_NE(it, documented.end()) << "not in docs/schedules.md's Interlocks table";
    EXPECT_DOUBLE_EQ(d.default_grace_min, it->second);
    EXPECT_DOUBLE_EQ(options.grace_for(d.kind), 60.0 * it->second) << "InterlockOptions{}";
    EXPECT_NE(api_md.find(fmt::format("`{}`", d.name)), std::string::npos)
        << "not in docs/api.md's Interlock kinds";
  }
}

TEST(InterlockTable, EachCheckTripsOnItsReadingsAndIsQuietOnNominalOnes) {
  const InterlockOptions o;
  bool none[kInterlockKindCount] = {};
  bool all[kInterlockKindCount];
  std::fill(std::begin(all), std::end(all), true);
  EXPECT_TRUE(evaluate_interlocks(kNominal, o, none).empty());
  EXPECT_TRUE(evaluate_interlocks(kNominal, o, all).empty());
  for (const InterlockDefinition& d : kInterlockDefinitions) {
    SCOPED_TRACE(std::string(d.name));
    ASSERT_NE(d.can_clear, nullptr);
    if (d.kind == InterlockKind::kSettleTimeout) {
      // Tripped by the sequencer from the step's clock, cleared by the gate.
      EXPECT_EQ(d.check, nullptr);
      EXPECT_FALSE(readings_can_clear(d.kind, kNominal));
      continue;
    }
    ASSERT_NE(d.check, nullptr) << "only settle_timeout is tripped outside the table";
    EXPECT_EQ(d.check(kNominal, o, false), std::nullopt);
    EXPECT_EQ(d.check(kNominal, o, true), std::nullopt) << "nominal readings clear it";
    EXPECT_TRUE(readings_can_clear(d.kind, kNominal)) << "else it could never clear";
    const auto bad = tripping_readings().find(d.kind);
    ASSERT_NE(bad, tripping_readings().end()) << "add readings that trip it to this test";
    const auto message = d.check(bad->second, o, false);
    ASSERT_TRUE(message.has_value());
    EXPECT_FALSE(message->empty());
    // evaluate_interlocks runs the row's check, and only it trips.
    const auto conditions = evaluate_interlocks(bad->second, o, none);
    ASSERT_EQ(conditions.size(), 1u);
    EXPECT_EQ(conditions[0].kind, d.kind);
    EXPECT_EQ(conditions[0].message, *message);
  }
}

// The table rows: they trip only on a station with a table, say what the
// controller says, and clear only on a tick with a table reading.
TEST(InterlockTable, TableRowsTripAndClear) {
  const InterlockOptions o;
  bool none[kInterlockKindCount] = {};
  bool all[kInterlockKindCount];
  std::fill(std::begin(all), std::end(all), true);

  Readings fault = kNominal;
  fault.table_fault = true;
  auto c = evaluate_interlocks(fault, o, none);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].kind, InterlockKind::kTableFault);
  EXPECT_EQ(c[0].message,
            "the rate table's interlock is in fault; the station resets it once the table is at "
            "rest (at most 3 times); if the fault stays, clear its cause at the table and run "
            "`gyrotherm table reset`");
  fault.table_fault_text = "axis 1 over-speed";
  // What the controller says, and what to do.
  EXPECT_EQ(evaluate_interlocks(fault, o, none).at(0).message,
            "the rate table's interlock is in fault: axis 1 over-speed; the station resets it "
            "once the table is at rest (at most 3 times); if the fault stays, clear its cause at "
            "the table and run `gyrotherm table reset`");
  fault.table_present = false;  // a station without a table
  EXPECT_TRUE(evaluate_interlocks(fault, o, none).empty());
  // Cleared (the station reset the latched fault): nothing holds, and a
  // reading of the table can show it.
  EXPECT_TRUE(evaluate_interlocks(kNominal, o, all).empty());
  EXPECT_TRUE(readings_can_clear(InterlockKind::kTableFault, kNominal));
  Readings no_reply = kNominal;
  no_reply.table_rate_dps.reset();
  EXPECT_FALSE(readings_can_clear(InterlockKind::kTableFault, no_reply));

  // Silent: beyond table_timeout_s (10 s by default), not at it.
  Readings silent = no_reply;
  silent.table_silent_s = 10;
  EXPECT_TRUE(evaluate_interlocks(silent, o, none).empty());
  silent.table_silent_s = 12;
  c = evaluate_interlocks(silent, o, none);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].kind, InterlockKind::kTableSilent);
  EXPECT_NE(c[0].message.find("rate table controller silent for 12 s (timeout 10 s)"),
            std::string::npos)
      << c[0].message;
  silent.table_present = false;
  EXPECT_TRUE(evaluate_interlocks(silent, o, none).empty());
  EXPECT_FALSE(readings_can_clear(InterlockKind::kTableSilent, no_reply));
  EXPECT_TRUE(readings_can_clear(InterlockKind::kTableSilent, kNominal));
}

TEST(InterlockOptions, Validity) {
  std::string why;
  EXPECT_TRUE(InterlockOptions{}.is_valid(&why)) << why;
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  // Each bad value, the field its message must name.
  const std::vector<std::pair<std::function<void(InterlockOptions&)>, std::string>> bad = {
      {[](InterlockOptions& o) { o.min_temp_c = kNaN; }, "min_temp_c"},
      {[](InterlockOptions& o) { o.max_temp_c = o.min_temp_c; }, "max_temp_c"},
      {[](InterlockOptions& o) { o.limit_margin_c = -0.1; }, "limit_margin_c"},
      {[](InterlockOptions& o) { o.hysteresis_c = -0.1; }, "hysteresis_c"},
      {[](InterlockOptions& o) { o.probe_disagreement_c = 0; }, "probe_disagreement_c"},
      {[](InterlockOptions& o) { o.hysteresis_c = o.probe_disagreement_c; }, "hysteresis_c"},
      {[](InterlockOptions& o) { o.chamber_timeout_s = 0; }, "chamber_timeout_s"},
      {[](InterlockOptions& o) { o.probes_timeout_s = -1; }, "probes_timeout_s"},
      {[](InterlockOptions& o) { o.gyro_timeout_s = kNaN; }, "gyro_timeout_s"},
      {[](InterlockOptions& o) { o.storage_timeout_s = 0; }, "storage_timeout_s"},
      {[](InterlockOptions& o) { o.table_timeout_s = std::numeric_limits<double>::infinity(); },
       "table_timeout_s"},
      {[](InterlockOptions& o) { o.grace_s[static_cast<int>(InterlockKind::kGyroLost)] = -1; },
       "grace_s[gyro_lost]"},
      {[](InterlockOptions& o) { o.grace_s[kInterlockKindCount - 1] = kNaN; },
       fmt::format("grace_s[{}]", kInterlockDefinitions[kInterlockKindCount - 1].name)},
  };
  for (const auto& [spoil, field] : bad) {
    InterlockOptions o;
    spoil(o);
    why.clear();
    EXPECT_FALSE(o.is_valid(&why)) << field;
    EXPECT_NE(why.find(field), std::string::npos) << field << ": " << why;
    EXPECT_FALSE(o.is_valid(nullptr)) << field;
  }
  // 0 is a sharp limit or an immediate abort: both allowed.
  InterlockOptions sharp;
  sharp.limit_margin_c = sharp.hysteresis_c = 0;
  sharp.grace_s.fill(0);
  EXPECT_TRUE(sharp.is_valid(&why)) << why;
}

}  // namespace
}  // namespace gyrotherm::schedules
