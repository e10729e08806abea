// The station with a rate table (tests/station/fake_table.h) on manual
// clocks: the table follows each step's demand, stops before the chamber
// goes to its safe set point (servo off after), stops while a run is held,
// trips its interlock on a fault, which the station resets (bounded), is
// not spun up again behind the operator's back, is left alone when idle
// once safe, is not waited for at shutdown when it does not answer, and is
// recorded at every tick.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "station/station_rig.h"
#include "test_time.h"

namespace gyrotherm::testing {
namespace {

using namespace std::chrono_literals;

std::string table_config(const std::string& db_path) {
  return rig_config_toml(db_path) +
         "[table]\nprofile = \"acutrol\"\nmax_rate_dps = 500\nmax_accel_dps2 = 100\n"
         "rest_rate_dps = 0.01\n";
}

// A soak with the table held at 90°, then a hold spinning at +100 °/s.
constexpr const char* kStaticThenSpin = R"(
name = "static then spin"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 2
table = { mode = "static", position_deg = 90.0 }
[[step]]
type = "hold"
setpoint_c = 23.0
duration_min = 30
table_rate_dps = 100.0
)";

class StationTableTest : public TempDirTest {
 protected:
  StationTableTest() : TempDirTest("gyrotherm-station-table") {}

  // Ticks until the table spins at `rate_dps` (within 0.5 °/s).
  void until_spinning(StationRig& rig, double rate_dps) {
    ASSERT_TRUE(
        rig.step_until([&] { return std::abs(rig.table.state().rate_dps - rate_dps) < 0.5; }, 3600))
        << "table rate " << rig.table.state().rate_dps << ", state " << rig.state();
  }
};

TEST_F(StationTableTest, EachStepGetsItsDemandAndEveryTickIsRecorded) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.open();
  const int64_t queued = rig.queue(kStaticThenSpin);
  ASSERT_NE(queued, 0);
  ASSERT_TRUE(rig.step_until([&] { return rig.state() == "acquiring"; }, 3600));
  auto s = rig.table.state();
  EXPECT_EQ(s.mode, drivers::TableMode::kPosition);
  EXPECT_DOUBLE_EQ(s.demand_position_deg, 90.0);
  until_spinning(rig, 100.0);
  EXPECT_EQ(rig.table.state().mode, drivers::TableMode::kRate);
  const auto status = rig.station->status();
  ASSERT_TRUE(status.table.has_value());
  ASSERT_TRUE(status.table->state.has_value());
  EXPECT_NEAR(status.table->state->rate_dps, 100.0, 0.5);
  EXPECT_EQ(status.table->demand.mode, schedules::TableDemandMode::kRate);

  // The run's table rows: one per control tick (1 s), demand beside the reading.
  const int64_t run_id = *status.run_id;
  auto db = storage::Database::open(rig.db_path(), rig.wall);
  ASSERT_TRUE(db.ok()) << db.error().message;
  std::vector<TableSample> rows;
  ASSERT_TRUE(wait_for_condition(
      [&] {
        // The tick that saw the table at rate is the last one.
        auto r = db->table_samples(run_id, 0.0, status.t_run_s + 0.5);
        if (!r.ok()) return false;
        rows = *r;
        return !rows.empty() && rows.back().t_s >= status.t_run_s;
      },
      20s))
      << rows.size() << " table rows";
  for (std::size_t i = 1; i < rows.size(); ++i) {
    ASSERT_LE(rows[i].t_s - rows[i - 1].t_s, 1.0 + 1e-9) << "gap before row " << i;
  }
  EXPECT_EQ(rows.back().demand_mode, "rate");
  EXPECT_DOUBLE_EQ(rows.back().demand_rate_dps, 100.0);
  EXPECT_EQ(rows.back().mode, "rate");
  EXPECT_EQ(rows.front().demand_mode, "static");
}

// The safe state's order (docs/testing.md): table stop, the chamber's safe
// set point (the rig's 21 °C, apart from the schedule's 23 °C), then servo
// off once at rest.
void expect_safe_state_order(const std::vector<std::string>& log) {
  auto index_of = [&](const std::string& entry) {
    auto it = std::find(log.begin(), log.end(), entry);
    return it == log.end() ? std::ptrdiff_t{-1} : it - log.begin();
  };
  const auto stop = index_of("table stop");
  const auto safe = index_of("setpoint 21");
  const auto off = index_of("table servo off");
  ASSERT_GE(stop, 0) << ::testing::PrintToString(log);
  ASSERT_GE(safe, 0) << ::testing::PrintToString(log);
  ASSERT_GE(off, 0) << ::testing::PrintToString(log);
  EXPECT_LT(stop, safe) << ::testing::PrintToString(log);
  EXPECT_LT(safe, off) << ::testing::PrintToString(log);
}

TEST_F(StationTableTest, AbortWhileSpinningStopsTheTableBeforeTheChamberGoesSafe) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.open();
  rig.queue(kStaticThenSpin);
  until_spinning(rig, 100.0);
  rig.plant->change([](FakePlant::State& s) { s.log.clear(); });
  ASSERT_FALSE(rig.station->control("abort", "bench").refusal);
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 600));
  // At rest, servo off, within the deceleration time (100 °/s at 100 °/s²).
  ASSERT_TRUE(rig.step_until(
      [&] { return rig.table.state().interlock == drivers::TableInterlock::kOpen; }, 30));
  EXPECT_LT(std::abs(rig.table.state().rate_dps), 0.01);
  expect_safe_state_order(rig.plant->state().log);
  // Then the operator panel is handed back (ACL `:U:L OFF`).
  {
    const auto log = rig.plant->state().log;
    const auto at = [&](const std::string& entry) {
      return std::find(log.begin(), log.end(), entry);
    };
    ASSERT_NE(at("table release"), log.end()) << ::testing::PrintToString(log);
    EXPECT_GT(at("table release"), at("table servo off")) << ::testing::PrintToString(log);
    EXPECT_FALSE(rig.table.state().remote);
  }
}

// Item 4: a run that completes while spinning ends in the same order.
TEST_F(StationTableTest, AtTheNormalEndTheTableStopsBeforeTheChamberGoesSafe) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.open();
  rig.queue(R"(
name = "spin 2 min"
[[step]]
type = "hold"
setpoint_c = 23.0
duration_min = 2
table_rate_dps = 100.0
)");
  until_spinning(rig, 100.0);
  const int64_t run_id = *rig.station->status().run_id;
  rig.plant->change([](FakePlant::State& s) { s.log.clear(); });
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 600));
  EXPECT_EQ(rig.reply(rig.station->run(run_id)).at("state"), "completed");
  ASSERT_TRUE(rig.step_until(
      [&] { return rig.table.state().interlock == drivers::TableInterlock::kOpen; }, 30));
  expect_safe_state_order(rig.plant->state().log);
}

TEST_F(StationTableTest, PauseStopsTheTableAndResumeSpinsItUpAgain) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.open();
  rig.queue(kStaticThenSpin);
  until_spinning(rig, 100.0);
  ASSERT_FALSE(rig.station->control("pause", "bench").refusal);
  ASSERT_TRUE(rig.step_until([&] { return std::abs(rig.table.state().rate_dps) < 0.01; }, 60))
      << rig.table.state().rate_dps;
  for (int i = 0; i < 30; ++i) rig.step();
  EXPECT_LT(std::abs(rig.table.state().rate_dps), 0.01) << "the table stays stopped while paused";
  ASSERT_FALSE(rig.station->control("resume", "bench").refusal);
  until_spinning(rig, 100.0);
}

// Items 5 and 7: a latched fault is reset while the run is held (an event
// each); the run does not abort, and the table is not spun up again until
// the operator resumes ([table] respin_after_fault = false, the default).
TEST_F(StationTableTest, ALatchedFaultIsResetWhileTheRunIsHeldAndTheRunWaitsForResume) {
  StationRig rig(dir_,
                 table_config(dir_ / "station.db") + "[interlocks]\ntable_fault_grace_min = 1.0\n");
  rig.open();
  rig.queue(kStaticThenSpin);
  until_spinning(rig, 100.0);
  const int64_t run_id = *rig.station->status().run_id;
  const std::size_t commands_before = rig.table.commands().size();
  rig.table.fault();
  ASSERT_TRUE(rig.step_until(
      [&] { return rig.table.state().interlock != drivers::TableInterlock::kFault; }, 30))
      << "the fault was never reset";
  // Past the interlock's grace: held, not aborted.
  for (int i = 0; i < 120; ++i) rig.step();
  EXPECT_EQ(rig.state(), "paused");
  EXPECT_EQ(rig.reply(rig.station->run(run_id)).at("state"), "paused");
  EXPECT_TRUE(rig.has_event(run_id, "table", "latched fault reset, 1 of 3 (fake fault)"));
  EXPECT_TRUE(rig.has_event(run_id, "table", "the controller faulted the axis: fake fault"));
  EXPECT_TRUE(rig.has_event(run_id, "interlock", "`gyrotherm table reset`"))
      << "the fault's message says what to do";
  const auto commands = rig.table.commands();
  for (std::size_t i = commands_before; i < commands.size(); ++i) {
    EXPECT_EQ(commands[i].rfind("rate", 0), std::string::npos)
        << "spun up again without the operator: " << ::testing::PrintToString(commands);
  }
  EXPECT_LT(std::abs(rig.table.state().rate_dps), 0.01);
  ASSERT_FALSE(rig.station->control("resume", "bench").refusal);
  until_spinning(rig, 100.0);
  EXPECT_EQ(rig.state(), "settling") << "the hold waits for the table at rate";
}

// Item 5: resets are bounded; a fault that stays aborts the run when the
// interlock's grace runs out, and the events say so.
TEST_F(StationTableTest, AFaultThatStaysIsResetThreeTimesThenItsGraceAbortsTheRun) {
  StationRig rig(dir_,
                 table_config(dir_ / "station.db") + "[interlocks]\ntable_fault_grace_min = 2.0\n");
  rig.open();
  rig.queue(kStaticThenSpin);
  until_spinning(rig, 100.0);
  const int64_t run_id = *rig.station->status().run_id;
  rig.table.change([](FakeTable::State& s) { s.sticky_fault = true; });
  rig.table.fault();
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 600));
  EXPECT_EQ(rig.reply(rig.station->run(run_id)).at("state"), "failed");
  const auto commands = rig.table.commands();
  EXPECT_EQ(std::count(commands.begin(), commands.end(), "reset"), 3)
      << ::testing::PrintToString(commands);
  for (int n = 1; n <= 3; ++n) {
    EXPECT_TRUE(rig.has_event(run_id, "table", fmt::format("latched fault reset, {} of 3", n)));
  }
  EXPECT_TRUE(rig.has_event(run_id, "table", "the fault stays after 3 resets"));
  EXPECT_TRUE(rig.has_event(run_id, "state", "interlock table_fault still tripped after 2 min"));
}

// Item 7: with [table] respin_after_fault the run goes on by itself, and a
// soak turning the table acquires again only once the table is back at rate.
TEST_F(StationTableTest, WithRespinAfterFaultTheSoakAcquiresAgainOnlyAtRate) {
  StationRig rig(dir_, table_config(dir_ / "station.db") + "respin_after_fault = true\n");
  rig.open();
  rig.queue(R"(
name = "spinning soak"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 5
table_rate_dps = 100.0
)");
  ASSERT_TRUE(rig.step_until([&] { return rig.state() == "acquiring"; }, 3600));
  const int64_t run_id = *rig.station->status().run_id;
  for (int i = 0; i < 60; ++i) rig.step();
  rig.table.fault();
  ASSERT_TRUE(rig.step_until([&] { return std::abs(rig.table.state().rate_dps) < 0.01; }, 30));
  // Spun up again without the operator; the first tick it is at rate.
  until_spinning(rig, 100.0);
  ASSERT_TRUE(
      rig.step_until([&] { return std::abs(rig.table.state().rate_dps - 100.0) <= 0.05; }, 30));
  const double at_rate_s = rig.station->status().t_run_s;
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 3600));
  const auto run = rig.reply(rig.station->run(run_id));
  EXPECT_EQ(run.at("state"), "completed");
  const auto& windows = run.at("segments")[0].at("windows");
  ASSERT_EQ(windows.size(), 2u) << run.dump();
  EXPECT_GE(windows[1][0].get<double>(), at_rate_s + 1.0 - 1e-6)
      << "acquisition went on before the table was at rate for at_rate_hold_s";
  double acquired_s = 0;
  for (const auto& w : windows) acquired_s += w[1].get<double>() - w[0].get<double>();
  EXPECT_NEAR(acquired_s, 300.0, 1.0);
  EXPECT_TRUE(rig.has_event(run_id, "table", "respin_after_fault"));
}

// Item 7: the controller reset (or restarted) under a spinning run: no fault
// to see, the servo simply open. The run pauses; nothing that would move
// the table is sent until the operator resumes.
TEST_F(StationTableTest, AControllerResetUnderASpinningRunPausesIt) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.open();
  rig.queue(kStaticThenSpin);
  until_spinning(rig, 100.0);
  const int64_t run_id = *rig.station->status().run_id;
  const std::size_t commands_before = rig.table.commands().size();
  rig.table.change([](FakeTable::State& s) {
    s.interlock = drivers::TableInterlock::kOpen;
    s.mode = drivers::TableMode::kOff;
  });
  for (int i = 0; i < 30; ++i) rig.step();
  EXPECT_EQ(rig.state(), "paused");
  const auto commands = rig.table.commands();
  for (std::size_t i = commands_before; i < commands.size(); ++i) {
    EXPECT_TRUE(commands[i] == "stop" || commands[i] == "servo off")
        << "moved again without the operator: " << ::testing::PrintToString(commands);
  }
  EXPECT_LT(std::abs(rig.table.state().rate_dps), 0.01);
  EXPECT_TRUE(rig.has_event(run_id, "table", "the table left rate +100 °/s: mode off"));
  ASSERT_FALSE(rig.station->control("resume", "bench").refusal);
  until_spinning(rig, 100.0);
}

// An interruption seen as a run aborts is the aborted run's: the next run
// does not pause for it.
TEST_F(StationTableTest, AnInterruptionDoesNotOutliveItsRun) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.open();
  rig.queue(kStaticThenSpin);
  until_spinning(rig, 100.0);
  const int64_t first = *rig.station->status().run_id;
  ASSERT_FALSE(rig.station->control("abort", "bench").refusal);
  rig.table.fault();  // read by the tick that goes on aborting
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 60));
  EXPECT_EQ(rig.reply(rig.station->run(first)).at("state"), "failed");
  ASSERT_FALSE(rig.station->control("table-reset", "bench").refusal);
  ASSERT_FALSE(rig.station->control("resume", "bench").refusal);  // the abort held the queue
  rig.queue(kStaticThenSpin);
  ASSERT_TRUE(
      rig.step_until([&] { return rig.station->status().run_id.value_or(first) != first; }, 10));
  for (int i = 0; i < 5; ++i) rig.step();
  EXPECT_NE(rig.state(), "paused");
  EXPECT_FALSE(rig.has_event(*rig.station->status().run_id, "table", "faulted"));
}

// Item 5: the operator's reset, through the station (REST: POST
// /api/v1/control/table-reset; `gyrotherm table reset` when the daemon runs).
TEST_F(StationTableTest, TheOperatorResetsAFaultThroughTheStation) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.open();
  rig.step();
  rig.table.fault();
  rig.step();
  const auto r = rig.station->control("table-reset", "bench");
  ASSERT_FALSE(r.refusal) << r.refusal->message;
  EXPECT_NE(r.body.at("message").get<std::string>().find("fault reset sent"), std::string::npos);
  EXPECT_EQ(rig.table.state().interlock, drivers::TableInterlock::kOpen);
  const auto commands = rig.table.commands();
  EXPECT_EQ(std::count(commands.begin(), commands.end(), "reset"), 1);
  EXPECT_NE(rig.station->status().last_event.find("table: fault reset by the operator (bench)"),
            std::string::npos);

  rig.table.change([](FakeTable::State& s) { s.silent = true; });
  const auto silent = rig.station->control("table-reset", "bench");
  ASSERT_TRUE(silent.refusal.has_value());
  EXPECT_EQ(silent.refusal->kind, station::Refusal::Kind::kUnavailable);
  EXPECT_NE(silent.refusal->message.find("no answer"), std::string::npos);
  rig.table.change([](FakeTable::State& s) { s.silent = false; });

  StationRig no_table(dir_ / "b");
  std::filesystem::create_directories(dir_ / "b");
  no_table.open();
  const auto refused = no_table.station->control("table-reset", "bench");
  ASSERT_TRUE(refused.refusal.has_value());
  EXPECT_EQ(refused.refusal->kind, station::Refusal::Kind::kConflict);
  EXPECT_NE(refused.refusal->message.find("no rate table"), std::string::npos);
}

// Item 8: an idle station makes an Aerosmith safe once and then leaves it
// alone; it always reads as servoed, so "servoed" does not mean "ours".
TEST_F(StationTableTest, AnIdleAerosmithIsMadeSafeOnceAndLeftAlone) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.table.change([](FakeTable::State& s) {
    s.aero = true;
    s.interlock = drivers::TableInterlock::kClosed;
  });
  rig.open();
  for (int i = 0; i < 60; ++i) rig.step();
  auto commands = rig.table.commands();
  EXPECT_EQ(commands, (std::vector<std::string>{"stop", "servo off"}));
  // A jog from the front panel: not the station's to stop.
  rig.table.change([](FakeTable::State& s) { s.panel_jog_dps = 10.0; });
  for (int i = 0; i < 30; ++i) rig.step();
  EXPECT_NEAR(rig.table.state().rate_dps, 10.0, 1e-9);
  EXPECT_EQ(rig.table.commands(), commands) << ::testing::PrintToString(rig.table.commands());

  // A run makes it ours again: at its end, safe once more, then left alone.
  rig.table.change([](FakeTable::State& s) { s.panel_jog_dps.reset(); });
  rig.queue(R"(
name = "spin"
[[step]]
type = "hold"
setpoint_c = 23.0
duration_min = 1
table_rate_dps = 100.0
)");
  ASSERT_TRUE(rig.step_until([&] { return rig.station->status().run_id.has_value(); }, 5));
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 600));
  ASSERT_TRUE(rig.step_until([&] { return std::abs(rig.table.state().rate_dps) < 0.01; }, 30));
  for (int i = 0; i < 5; ++i) rig.step();
  commands = rig.table.commands();
  EXPECT_EQ(std::count(commands.begin(), commands.end(), "stop"), 2)
      << ::testing::PrintToString(commands);
  for (int i = 0; i < 60; ++i) rig.step();
  EXPECT_EQ(rig.table.commands(), commands) << ::testing::PrintToString(rig.table.commands());
  // Nor does the daemon stopping stop a jog.
  rig.table.change([](FakeTable::State& s) { s.panel_jog_dps = 10.0; });
  rig.step();
  rig.close();
  EXPECT_EQ(rig.table.commands(), commands) << ::testing::PrintToString(rig.table.commands());
  EXPECT_NEAR(rig.table.state().rate_dps, 10.0, 1e-9);
}

// Item 6: at shutdown a table that does not answer is not waited for, and
// the log says its state is unknown rather than guessing it.
TEST_F(StationTableTest, StoppingWithATableThatNeverAnsweredDoesNotWaitForIt) {
  LogCapture log;
  {
    StationRig rig(dir_, table_config(dir_ / "station.db"));
    rig.table.change([](FakeTable::State& s) { s.silent = true; });
    rig.open();
    for (int i = 0; i < 3; ++i) rig.step();
    const auto started = std::chrono::steady_clock::now();
    rig.close();
    // The old wait was 30 s of 100 ms polls.
    EXPECT_LT(std::chrono::steady_clock::now() - started, scaled(10s));
  }
  const std::string text = log.text();
  EXPECT_NE(text.find("table: no answer at shutdown (table: no answer (fake)); its state is "
                      "unknown (it never answered since the daemon started)"),
            std::string::npos)
      << text;
  EXPECT_EQ(text.find("servo on"), std::string::npos) << text;
}

// Item 4 at shutdown: a table still stopping when the daemon stops (here
// one a dead daemon had left spinning, stopped at the first tick) is
// stopped, the chamber gets its safe set point, and only then, at rest,
// does the servo go off.
TEST_F(StationTableTest, StoppingTheDaemonSendsTheSafeSetPointBeforeTheServoGoesOff) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.table.change([](FakeTable::State& s) {
    s.interlock = drivers::TableInterlock::kClosed;
    s.mode = drivers::TableMode::kRate;
    s.demand_rate_dps = 100.0;
    s.rate_dps = 100.0;
  });
  rig.open();
  rig.step();
  ASSERT_EQ(rig.table.commands(), std::vector<std::string>{"stop"});
  rig.close();
  EXPECT_LT(std::abs(rig.table.state().rate_dps), 0.01);
  EXPECT_EQ(rig.table.state().interlock, drivers::TableInterlock::kOpen);
  expect_safe_state_order(rig.plant->state().log);
}

TEST_F(StationTableTest, StoppingTheDaemonLeavesTheTableAtRestAndServoOff) {
  StationRig rig(dir_, table_config(dir_ / "station.db"));
  rig.open();
  rig.queue(kStaticThenSpin);
  until_spinning(rig, 100.0);
  rig.plant->change([](FakePlant::State& s) { s.log.clear(); });
  // No control loop is left at shutdown: the station waits for the table
  // itself (the rig moves the fake table in wall time meanwhile).
  rig.close();
  EXPECT_LT(std::abs(rig.table.state().rate_dps), 0.01);
  EXPECT_EQ(rig.table.state().interlock, drivers::TableInterlock::kOpen);
  expect_safe_state_order(rig.plant->state().log);
}

}  // namespace
}  // namespace gyrotherm::testing
