// The station's run controller on fake devices and manual clocks
// (station_rig.h): whole runs, pause, each interlock, crash resume and the
// queue's races, each in milliseconds of wall time. The same behaviours are
// tested end to end, through the simulator, in tests/integration.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <future>
#include <limits>
#include <optional>
#include <set>
#include <thread>
#include <vector>

#include "gyrotherm/calibration/report.h"
#include "gyrotherm/storage/database.h"
#include "station/station_rig.h"
#include "test_time.h"

namespace gyrotherm::testing {
namespace {

using namespace std::chrono_literals;

// A soak at the chamber's starting temperature, a ramp, a soak.
constexpr const char* kSoakRampSoak = R"(
name = "soak-ramp-soak"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 2
[[step]]
type = "ramp"
target_c = 25.0
rate_c_per_min = 1.0
[[step]]
type = "soak"
setpoint_c = 25.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 2
)";

// One soak with a long acquisition, for what happens in the middle of one.
constexpr const char* kLongSoak = R"(
name = "long soak"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 10
)";

// The messages of the events of `kind` recorded outside any run, in order.
std::vector<std::string> messages_outside_runs(const std::string& db_path,
                                               const std::string& kind) {
  std::vector<std::string> out;
  sqlite3* db = nullptr;
  if (sqlite3_open_v2(db_path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) != SQLITE_OK) {
    ADD_FAILURE() << "cannot open " << db_path;
    sqlite3_close(db);
    return out;
  }
  sqlite3_stmt* st = nullptr;
  const char* sql = "SELECT message FROM events WHERE kind = ?1 AND run_id IS NULL ORDER BY id";
  if (sqlite3_prepare_v2(db, sql, -1, &st, nullptr) == SQLITE_OK) {
    sqlite3_bind_text(st, 1, kind.c_str(), -1, SQLITE_TRANSIENT);
    while (sqlite3_step(st) == SQLITE_ROW) {
      out.emplace_back(reinterpret_cast<const char*>(sqlite3_column_text(st, 0)));
    }
  } else {
    ADD_FAILURE() << sqlite3_errmsg(db);
  }
  sqlite3_finalize(st);
  sqlite3_close(db);
  return out;
}

class StationUnitTest : public TempDirTest {
 protected:
  StationUnitTest() : TempDirTest("gyrotherm-station") {}

  // Waits (wall, with a deadline) for the analysis thread's Table I rows.
  nlohmann::json wait_for_stats(StationRig& rig, int64_t run_id, std::size_t rows) {
    nlohmann::json stats;
    if (wait_for_condition(
            [&] {
              stats = rig.reply(rig.station->run_stats(run_id));
              return stats.size() >= rows;
            },
            20s)) {
      return stats;
    }
    ADD_FAILURE() << "run " << run_id << ": " << stats.size() << " Table I rows, not " << rows;
    return stats;
  }

  // Ticks until the run is acquiring (the gate held); its run id.
  int64_t until_acquiring(StationRig& rig) {
    EXPECT_TRUE(rig.step_until([&] { return rig.state() == "acquiring"; }, 3600))
        << "state " << rig.state();
    return rig.station->status().run_id.value_or(0);
  }
};

TEST_F(StationUnitTest, SoakRampSoakRunCompletesWithItsRecordsAndTableI) {
  StationRig rig(dir_);
  rig.open();
  rig.queue(kSoakRampSoak);
  ASSERT_TRUE(rig.step_until([&] { return rig.station->status().run_id.has_value(); }, 5));
  const int64_t run_id = *rig.station->status().run_id;
  std::set<std::string> states;
  ASSERT_TRUE(rig.step_until(
      [&] {
        states.insert(rig.state());
        return rig.station->idle() && !rig.station->status().run_id;
      },
      4 * 3600));
  EXPECT_TRUE(states.count("settling") && states.count("acquiring") && states.count("ramping"))
      << "states seen: " << states.size();

  const auto run = rig.reply(rig.station->run(run_id));
  EXPECT_EQ(run.at("state"), "completed");
  ASSERT_EQ(run.at("segments").size(), 3u);
  for (const auto& seg : run.at("segments")) EXPECT_EQ(seg.at("state"), "completed") << seg;
  // The ramp's window is its whole time: 2 °C at 1 °C/min.
  const auto& ramp = run.at("segments")[1];
  EXPECT_NEAR(ramp.at("t_acquire_end_s").get<double>() - ramp.at("t_acquire_start_s").get<double>(),
              120.0, 1.0);

  // One Table I row per soak: 2 min (in 1 s bins of the 10 Hz samples), at
  // the soak's temperature, with the gyro's bias and its temperature term.
  const auto stats = wait_for_stats(rig, run_id, 2);
  ASSERT_EQ(stats.size(), 2u);
  const double setpoints_c[] = {23.0, 25.0};
  for (std::size_t i = 0; i < 2; ++i) {
    SCOPED_TRACE(i);
    EXPECT_GE(stats[i].at("n").get<int64_t>(), 119);
    EXPECT_LE(stats[i].at("n").get<int64_t>(), 121);
    EXPECT_NEAR(stats[i].at("temp_mean_c").get<double>(), setpoints_c[i], 0.5);
    EXPECT_NEAR(stats[i].at("bias_mean_dph").get<double>(), 1.5 + 0.01 * (setpoints_c[i] - 23.0),
                0.01);
  }
  // The run ended at the safe set point (the rig's 21 °C: neither the last
  // soak's 25 °C nor the 23 °C the chamber started at); the wall clock
  // stamped its rows, Table I's included.
  EXPECT_EQ(stats[0].at("computed_utc").get<std::string>().substr(0, 4), "2027");
  EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, 21.0);
  EXPECT_EQ(run.at("started_utc").get<std::string>().substr(0, 4), "2027");
}

TEST_F(StationUnitTest, PauseHoldsTheSetPointAndStopsTheAcquisitionClock) {
  StationRig rig(dir_);
  rig.open();
  // At 24 °C: apart from the chamber's start (23 °C) and the safe set point
  // (21 °C), so the set point held is the schedule's.
  rig.queue(R"(
name = "long soak at 24"
[[step]]
type = "soak"
setpoint_c = 24.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 10
)");
  const int64_t run_id = until_acquiring(rig);
  ASSERT_NE(run_id, 0);
  auto r = rig.station->control("pause", "bench");
  ASSERT_FALSE(r.refusal) << r.refusal->message;
  const int writes_before = rig.plant->state().setpoint_writes;
  for (int i = 0; i < 300; ++i) rig.step();
  EXPECT_EQ(rig.state(), "paused");
  EXPECT_TRUE(rig.station->status().paused);
  EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, 24.0);
  // Held, re-asserted now and then, never moved.
  EXPECT_LE(rig.plant->state().setpoint_writes - writes_before, 300 / 30 + 1);
  ASSERT_FALSE(rig.station->control("resume", "bench").refusal);
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 3600));
  const auto run = rig.reply(rig.station->run(run_id));
  EXPECT_EQ(run.at("state"), "completed");
  const auto& seg = run.at("segments")[0];
  EXPECT_NEAR(seg.at("paused_s").get<double>(), 300.0, 2.0);
  // The pause is left out: acquisition windows add up to 10 min.
  double acquired_s = 0;
  for (const auto& w : seg.at("windows")) acquired_s += w[1].get<double>() - w[0].get<double>();
  EXPECT_NEAR(acquired_s, 600.0, 1.0);
  EXPECT_TRUE(rig.has_event(run_id, "operator", "") || rig.has_event(run_id, "state", "bench"));
}

// One interlock: what trips it on the bench, and how it is undone.
struct InterlockCase {
  const char* kind;
  std::function<void(StationRig&)> trip;
  std::function<void(StationRig&)> clear;
};

void PrintTo(const InterlockCase& c, std::ostream* os) { *os << c.kind; }

class StationInterlockTest : public StationUnitTest,
                             public ::testing::WithParamInterface<InterlockCase> {};

TEST_P(StationInterlockTest, TripsSuspendsTheRunAndClears) {
  const InterlockCase& c = GetParam();
  StationRig rig(dir_);
  rig.open();
  rig.queue(kLongSoak);
  const int64_t run_id = until_acquiring(rig);
  ASSERT_NE(run_id, 0);
  c.trip(rig);
  auto tripped = [&] {
    for (const auto& i : rig.station->status().interlocks) {
      if (i.kind == c.kind) return true;
    }
    return false;
  };
  ASSERT_TRUE(rig.step_until(tripped, 120)) << c.kind << " did not trip; state " << rig.state();
  EXPECT_EQ(rig.state(), "suspended");
  const double setpoint_c = rig.plant->state().setpoint_c;
  for (int i = 0; i < 20; ++i) rig.step();
  EXPECT_EQ(rig.state(), "suspended");
  EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, setpoint_c) << "the set point is held";
  c.clear(rig);
  ASSERT_TRUE(rig.step_until([&] { return !tripped(); }, 600)) << c.kind << " did not clear";
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 7200));
  const auto run = rig.reply(rig.station->run(run_id));
  EXPECT_EQ(run.at("state"), "completed");
  EXPECT_TRUE(rig.has_event(run_id, "interlock", c.kind)) << c.kind;
}

INSTANTIATE_TEST_SUITE_P(
    EachKind, StationInterlockTest,
    ::testing::Values(
        InterlockCase{"out_of_limits",
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.force_air_c = 70.0; });
                      },
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.force_air_c.reset(); });
                      }},
        InterlockCase{"probe_disagreement",
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.side_offset_c = 3.0; });
                      },
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.side_offset_c = 0; });
                      }},
        InterlockCase{"chamber_silent",
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.chamber_silent = true; });
                      },
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.chamber_silent = false; });
                      }},
        InterlockCase{"probes_silent",
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.probes_silent = true; });
                      },
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.probes_silent = false; });
                      }},
        InterlockCase{"gyro_lost", [](StationRig& r) { r.gyro().muted = true; },
                      [](StationRig& r) { r.gyro().muted = false; }},
        InterlockCase{"chamber_alarm",
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.chamber_alarm = true; });
                      },
                      [](StationRig& r) {
                        r.plant->change([](FakePlant::State& s) { s.chamber_alarm = false; });
                      }}),
    [](const ::testing::TestParamInfo<InterlockCase>& info) {
      return std::string(info.param.kind);
    });

// A full disk: the writer's commits fail, storage_failing suspends the run
// (after [interlocks] storage timeout), the samples wait in memory; when
// the disk takes writes again they are all committed and the run goes on.
TEST_F(StationUnitTest, StorageFailingSuspendsTheRunAndLosesNoSample) {
  StationRig rig(dir_);
  rig.open();
  rig.queue(kLongSoak);
  const int64_t run_id = until_acquiring(rig);
  ASSERT_NE(run_id, 0);
  const double full_from_s = rig.station->status().t_run_s;
  rig.disk().set_full(true);
  auto tripped = [&] {
    for (const auto& i : rig.station->status().interlocks) {
      if (i.kind == "storage_failing") return true;
    }
    return false;
  };
  ASSERT_TRUE(rig.step_until(tripped, 120)) << "state " << rig.state();
  EXPECT_EQ(rig.state(), "suspended");
  for (int i = 0; i < 30; ++i) rig.step();
  EXPECT_GT(rig.station->status().storage.pending, 300u) << "the samples wait in memory";
  const double full_to_s = rig.station->status().t_run_s;
  rig.disk().set_full(false);
  // The writer commits on its own thread, in wall time: the interlock can
  // clear once a commit has succeeded since the start.
  ASSERT_TRUE(wait_for_condition(
      [&] {
        const auto storage = rig.station->status().storage;
        return storage.commits > 0 && storage.pending == 0;
      },
      20s));
  ASSERT_TRUE(rig.step_until([&] { return !tripped(); }, 120));
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 3600));
  EXPECT_EQ(rig.reply(rig.station->run(run_id)).at("state"), "completed");
  EXPECT_TRUE(rig.has_event(run_id, "interlock", "storage_failing"));
  // Every 10 Hz sample of the full spell is in the file (its chunks).
  auto file = storage::Database::open_read_only(rig.db_path());
  ASSERT_TRUE(file.ok()) << file.error().message;
  const double inf = std::numeric_limits<double>::infinity();
  auto spell =
      file->gyro_samples(run_id, std::nextafter(full_from_s, inf), std::nextafter(full_to_s, inf));
  ASSERT_TRUE(spell.ok()) << spell.error().message;
  const auto stored = static_cast<int64_t>(spell->size());
  EXPECT_NEAR(static_cast<double>(stored), (full_to_s - full_from_s) * 10.0, 1.0);
}

// settle_timeout is the sequencer's: the gate never held in time. It does
// not clear by itself; its grace ends the run.
TEST_F(StationUnitTest, SettleTimeoutTripsAndItsGraceAbortsTheRun) {
  StationRig rig(dir_, rig_config_toml((dir_ / "station.db").string()) +
                           "[interlocks]\nsettle_timeout_grace_min = 2\n");
  rig.open();
  rig.plant->change([](FakePlant::State& s) { s.force_air_c = 26.0; });  // ignores the set point
  rig.queue(R"(
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
settle_timeout_min = 3
acquire_min = 2
)");
  ASSERT_TRUE(rig.step_until([&] { return rig.station->status().run_id.has_value(); }, 5));
  const int64_t run_id = *rig.station->status().run_id;
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 3600));
  rig.step();  // the status's queue fields are those of the tick before
  EXPECT_EQ(rig.reply(rig.station->run(run_id)).at("state"), "failed");
  EXPECT_TRUE(rig.has_event(run_id, "interlock", "settle_timeout"));
  // A failed run holds the queue; the chamber went to the safe set point
  // (21 °C, not the soak's 23 °C).
  EXPECT_TRUE(rig.station->status().queue_held);
  EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, 21.0);
}

// What a kill -9 leaves: the database as committed at one moment (a copy
// taken by SQLite from another connection, VACUUM INTO), the process gone.
// The next station resumes the run from its checkpoint, counting the
// downtime from the wall clock, and credits acquisition only up to the last
// committed gyro sample.
TEST_F(StationUnitTest, CrashResumeFromTheCheckpoint) {
  const std::string crashed_db = (dir_ / "crashed.db").string();
  int64_t run_id = 0;
  double wall_at_crash = 0, acquired_before_s = 0;
  {
    StationRig rig(dir_);
    rig.open();
    rig.queue(kLongSoak);
    run_id = until_acquiring(rig);
    ASSERT_NE(run_id, 0);
    for (int i = 0; i < 240; ++i) rig.step();  // 4 of the 10 min
    acquired_before_s = 240;
    // The kill comes after the writer committed what it was handed (else
    // nothing of the 4 min is in the file, and all 10 are acquired again).
    ASSERT_TRUE(
        wait_for_condition([&] { return rig.station->status().storage.pending == 0; }, 20s));
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open(rig.db_path().c_str(), &db), SQLITE_OK);
    const std::string sql = "VACUUM INTO '" + crashed_db + "'";
    char* err = nullptr;
    const int rc = sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &err);
    EXPECT_EQ(rc, SQLITE_OK) << (err ? err : "");
    sqlite3_free(err);
    sqlite3_close(db);
    wall_at_crash = rig.wall.unix_now_s();
  }  // this station is closed normally, but its file is not used again

  StationRig rig(dir_, rig_config_toml(crashed_db));
  rig.wall.set(wall_at_crash + 90.0);  // down for 90 s of wall time
  rig.open();
  EXPECT_EQ(rig.station->status().run_id.value_or(0), run_id) << "the run resumes";
  rig.step();
  EXPECT_EQ(rig.state(), "acquiring");
  EXPECT_TRUE(rig.has_event(run_id, "resume", "daemon restarted"));
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 3600));
  EXPECT_EQ(rig.reply(rig.station->run(run_id)).at("state"), "completed");
  // Table I holds the whole 10 min: what was committed before the crash and
  // what was acquired after, without the downtime.
  const auto stats = wait_for_stats(rig, run_id, 1);
  ASSERT_EQ(stats.size(), 1u);
  EXPECT_GE(stats[0].at("n").get<int64_t>(), 599) << "acquired before: " << acquired_before_s;
  EXPECT_LE(stats[0].at("n").get<int64_t>(), 601);
  const auto run = rig.reply(rig.station->run(run_id));
  const auto& windows = run.at("segments")[0].at("windows");
  ASSERT_EQ(windows.size(), 2u) << "the downtime splits the acquisition: " << run.dump();
  EXPECT_NEAR(windows[0][1].get<double>() - windows[0][0].get<double>(), acquired_before_s, 1.5);
  EXPECT_GE(windows[1][0].get<double>() - windows[0][1].get<double>(), 89.0);
}

// The HTTP thread adds and removes entries while the control loop claims
// them: every entry runs once or stays queued, a removed one never runs, and
// the queue's count matches the database.
TEST_F(StationUnitTest, QueueAddAndRemoveRaceTheClaim) {
  StationRig rig(dir_);
  rig.open();
  constexpr const char* kHold = R"(
[[step]]
type = "hold"
setpoint_c = 23.0
duration_min = 0.05
)";
  std::atomic<bool> done{false};
  std::atomic<int> added{0}, removed{0}, refused_removals{0};
  std::thread http([&] {
    for (int i = 0; i < 60; ++i) {
      auto r = rig.station->queue_add(kHold, "race.toml", false);
      if (r.refusal) continue;
      ++added;
      const int64_t id = r.body.at("id").get<int64_t>();
      if (i % 3 == 0) {
        auto rm = rig.station->queue_remove(id);
        if (rm.refusal) {
          ++refused_removals;
        } else {
          ++removed;
        }
      }
      std::this_thread::yield();
    }
    done = true;
  });
  while (!done) rig.step(1.0);
  http.join();
  ASSERT_TRUE(
      rig.step_until([&] { return rig.station->idle() && !rig.station->status().run_id; }, 3600));
  EXPECT_EQ(added.load(), 60);
  const auto runs = rig.reply(rig.station->runs());
  std::set<int64_t> queue_ids;
  for (const auto& r : runs) {
    ASSERT_FALSE(r.at("queue_id").is_null());
    EXPECT_TRUE(queue_ids.insert(r.at("queue_id").get<int64_t>()).second) << "ran twice: " << r;
    EXPECT_EQ(r.at("state"), "completed") << r;
  }
  EXPECT_EQ(static_cast<int>(runs.size()), added.load() - removed.load());
  EXPECT_EQ(rig.station->status().queue_length, 0);
  const auto queue = rig.reply(rig.station->queue_list());
  EXPECT_TRUE(queue.at("entries").empty()) << queue.dump();
}

// Station::post_event (the lab relay's events): from any thread, recorded
// in order by the control loop at its next tick, under the run in progress
// if any, published on the stream; bounded (the oldest dropped, said).
TEST_F(StationUnitTest, PostedEventsAreRecordedByTheControlLoop) {
  StationRig rig(dir_);
  rig.open();
  const auto lab_events = [&](bool outside_runs) {
    sqlite3* db = nullptr;
    EXPECT_EQ(sqlite3_open_v2(rig.db_path().c_str(), &db, SQLITE_OPEN_READONLY, nullptr),
              SQLITE_OK);
    sqlite3_stmt* st = nullptr;
    const std::string sql = std::string("SELECT message FROM events WHERE kind = 'lab' AND ") +
                            (outside_runs ? "run_id IS NULL" : "run_id IS NOT NULL") +
                            " ORDER BY id";
    EXPECT_EQ(sqlite3_prepare_v2(db, sql.c_str(), -1, &st, nullptr), SQLITE_OK);
    std::vector<std::string> out;
    while (sqlite3_step(st) == SQLITE_ROW) {
      out.emplace_back(reinterpret_cast<const char*>(sqlite3_column_text(st, 0)));
    }
    sqlite3_finalize(st);
    sqlite3_close(db);
    return out;
  };
  std::thread poster([&] {
    for (int i = 0; i < 20; ++i) rig.station->post_event("lab", fmt::format("lab: message {}", i));
  });
  poster.join();
  EXPECT_TRUE(lab_events(true).empty()) << "recorded before the control loop ticked";
  rig.step();
  const auto idle = lab_events(true);
  ASSERT_EQ(idle.size(), 20u);
  for (int i = 0; i < 20; ++i) EXPECT_EQ(idle[i], fmt::format("lab: message {}", i));
  EXPECT_EQ(rig.station->status().last_event, "lab: message 19");
  bool published = false;
  for (const auto& p : rig.published()) published |= p.find("lab: message 7") != std::string::npos;
  EXPECT_TRUE(published);

  rig.queue(kLongSoak);
  const int64_t run_id = until_acquiring(rig);
  ASSERT_NE(run_id, 0);
  rig.station->post_event("lab", "lab: during the run");
  rig.step();
  EXPECT_TRUE(rig.has_event(run_id, "lab", "lab: during the run"));

  // More than the queue holds between two ticks: the oldest go, and an
  // event says how many.
  for (int i = 0; i < 1005; ++i) rig.station->post_event("lab", fmt::format("lab: flood {}", i));
  rig.step();
  const auto flood = lab_events(false);
  ASSERT_EQ(flood.size(), 1001u);
  EXPECT_EQ(flood[1], "lab: flood 5");
  EXPECT_EQ(flood.back(), "lab: flood 1004");
  EXPECT_TRUE(rig.has_event(run_id, "error", "5 posted events dropped"));
}

// The status's lab object comes from StationHooks::lab_status (none: null),
// the free bytes of the database's file system from statvfs.
TEST_F(StationUnitTest, StatusShowsTheRelayAndTheFreeSpace) {
  {
    StationRig rig(dir_);
    rig.open();
    const station::StatusSnapshot s = rig.station->status();
    EXPECT_FALSE(s.lab.has_value());
    ASSERT_TRUE(s.storage_free_bytes.has_value());
    ASSERT_TRUE(s.storage_size_bytes.has_value());
    EXPECT_GT(*s.storage_free_bytes, 0);
    EXPECT_GE(*s.storage_size_bytes, *s.storage_free_bytes);
    const nlohmann::json j = station::to_json(s);
    EXPECT_TRUE(j.at("lab").is_null());
    EXPECT_EQ(j.at("storage").at("free_bytes"), *s.storage_free_bytes);
  }
  StationRig rig(dir_);
  std::atomic<int> calls{0};
  rig.lab_status = [&calls] {
    ++calls;
    lab::RelayStatus r;
    r.station_id = "st-07";
    r.server = "lab-db:5432/lab as st07";
    r.state = "backoff";
    r.pending = 42;
    r.errors_total = 3;
    r.retry_in_s = 8;
    r.last_error = "connection refused";
    return std::optional(r);
  };
  rig.open();
  const station::StatusSnapshot s = rig.station->status();
  ASSERT_TRUE(s.lab.has_value());
  EXPECT_GE(calls.load(), 1);
  const nlohmann::json j = station::to_json(s).at("lab");
  EXPECT_EQ(j.at("station_id"), "st-07");
  EXPECT_EQ(j.at("state"), "backoff");
  EXPECT_EQ(j.at("pending"), 42);
  EXPECT_EQ(j.at("errors_total"), 3);
  EXPECT_EQ(j.at("retry_in_s"), 8.0);
  EXPECT_TRUE(j.at("last_lag_s").is_null());
  EXPECT_EQ(j.at("last_error"), "connection refused");
}

// A soak is credited for the time its gyro's samples cover, not for the
// clock: a few seconds of silence (short of gyro_lost) leave the window open
// that much longer, and Table I still has the whole acquisition.
TEST_F(StationUnitTest, ASoakIsCreditedForItsDataNotForTheClock) {
  StationRig rig(dir_);
  rig.open();
  rig.queue(kLongSoak);
  const int64_t run_id = until_acquiring(rig);
  ASSERT_NE(run_id, 0);
  for (int i = 0; i < 100; ++i) rig.step();
  rig.gyro().muted = true;  // 4 s of frames lost
  for (int i = 0; i < 4; ++i) rig.step();
  rig.gyro().muted = false;
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 3600));
  const auto stats = wait_for_stats(rig, run_id, 1);
  ASSERT_EQ(stats.size(), 1u);
  EXPECT_GE(stats[0].at("n").get<int64_t>(), 599);
  EXPECT_LE(stats[0].at("n").get<int64_t>(), 601);
  const auto run = rig.reply(rig.station->run(run_id));
  const auto& windows = run.at("segments")[0].at("windows");
  double window_s = 0;
  for (const auto& w : windows) window_s += w[1].get<double>() - w[0].get<double>();
  EXPECT_NEAR(window_s, 604.0, 1.01) << run.dump();
}

// A kill -9 between a soak's end and the checkpoint that says so leaves the
// soak recorded completed and the checkpoint still in it. The next station
// goes on with the next step: the soak is not acquired again, its Table I
// row is not doubled, and no segment is left running.
// A step's end, the next step's start and the checkpoint that says so are
// one transaction: with checkpoints refused (a trigger standing for a crash
// between the writes), the first soak is not recorded completed either;
// once they are taken, both are written.
TEST_F(StationUnitTest, AStepChangeIsWrittenWithItsCheckpointOrNotAtAll) {
  StationRig rig(dir_);
  rig.open();
  rig.queue(R"(
name = "two soaks"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 2
[[step]]
type = "soak"
setpoint_c = 25.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 2
)");
  const int64_t run_id = until_acquiring(rig);
  ASSERT_NE(run_id, 0);
  sqlite3* raw = nullptr;
  ASSERT_EQ(sqlite3_open(rig.db_path().c_str(), &raw), SQLITE_OK);
  sqlite3_busy_timeout(raw, 5000);
  const auto exec = [&](const char* sql) {
    char* err = nullptr;
    const int rc = sqlite3_exec(raw, sql, nullptr, nullptr, &err);
    EXPECT_EQ(rc, SQLITE_OK) << (err ? err : "");
    sqlite3_free(err);
  };
  exec(
      "CREATE TRIGGER no_checkpoint BEFORE UPDATE OF resume_json ON runs "
      "BEGIN SELECT RAISE(ABORT, 'checkpoint refused (test)'); END");
  const auto first_segment_state = [&] {
    auto db = storage::Database::open_read_only(rig.db_path());
    EXPECT_TRUE(db.ok());
    auto segs = db->segments(run_id);
    EXPECT_TRUE(segs.ok() && !segs->empty());
    return segs.ok() && !segs->empty() ? segs->front().state : std::string();
  };
  ASSERT_TRUE(
      rig.step_until([&] { return rig.station->status().step_index.value_or(-1) == 1; }, 600));
  for (int i = 0; i < 5; ++i) rig.step();
  EXPECT_EQ(first_segment_state(), "running")
      << "the step's end is not written without its checkpoint";
  exec("DROP TRIGGER no_checkpoint");
  sqlite3_close(raw);
  rig.step();
  EXPECT_EQ(first_segment_state(), "completed");
  auto db = storage::Database::open_read_only(rig.db_path());
  ASSERT_TRUE(db.ok());
  auto run = db->run(run_id);
  ASSERT_TRUE(run.ok());
  const auto cp = nlohmann::json::parse(run->resume_json, nullptr, false);
  ASSERT_TRUE(cp.is_object()) << run->resume_json;
  EXPECT_EQ(cp.value("step_index", -1), 1) << run->resume_json;
}

// A run's end is written after its last step's end, in the same
// transaction: a reader that sees the run completed (the turntable crash
// test read /runs/1 so, on a loaded machine) never finds a step still
// running. A trigger notes, at the moment the run's state becomes terminal,
// how many of its segments are still "running".
TEST_F(StationUnitTest, ARunsEndIsWrittenAfterItsLastStepsEnd) {
  StationRig rig(dir_);
  rig.open();
  sqlite3* raw = nullptr;
  ASSERT_EQ(sqlite3_open(rig.db_path().c_str(), &raw), SQLITE_OK);
  sqlite3_busy_timeout(raw, 5000);
  const auto exec = [&](const char* sql) {
    char* err = nullptr;
    const int rc = sqlite3_exec(raw, sql, nullptr, nullptr, &err);
    EXPECT_EQ(rc, SQLITE_OK) << (err ? err : "");
    sqlite3_free(err);
  };
  exec("CREATE TABLE test_run_ends(run_id INTEGER, state TEXT, running_segments INTEGER)");
  exec(
      "CREATE TRIGGER test_run_end AFTER UPDATE OF state ON runs "
      "WHEN NEW.state IN ('completed', 'aborted', 'failed', 'interrupted') "
      "BEGIN INSERT INTO test_run_ends SELECT NEW.id, NEW.state, "
      "(SELECT count(*) FROM segments WHERE run_id = NEW.id AND state = 'running'); END");
  rig.queue(kSoakRampSoak);
  ASSERT_TRUE(rig.step_until([&] { return rig.station->status().run_id.has_value(); }, 5));
  const int64_t run_id = *rig.station->status().run_id;
  ASSERT_TRUE(rig.step_until([&] { return rig.station->idle() && !rig.station->status().run_id; },
                             4 * 3600));
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(raw, "SELECT run_id, state, running_segments FROM test_run_ends", -1,
                               &st, nullptr),
            SQLITE_OK);
  int ends = 0;
  while (sqlite3_step(st) == SQLITE_ROW) {
    ++ends;
    EXPECT_EQ(sqlite3_column_int64(st, 0), run_id);
    EXPECT_STREQ(reinterpret_cast<const char*>(sqlite3_column_text(st, 1)), "completed");
    EXPECT_EQ(sqlite3_column_int(st, 2), 0) << "the run was written completed with a step running";
  }
  sqlite3_finalize(st);
  sqlite3_close(raw);
  EXPECT_EQ(ends, 1);
}

TEST_F(StationUnitTest, ACheckpointOlderThanItsStepsEndDoesNotRunTheStepAgain) {
  constexpr const char* kTwoSoaks = R"(
name = "two soaks"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 2
[[step]]
type = "soak"
setpoint_c = 25.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 2
)";
  const std::string crashed_db = (dir_ / "crashed.db").string();
  int64_t run_id = 0;
  double wall_at_crash = 0;
  {
    StationRig rig(dir_);
    rig.open();
    rig.queue(kTwoSoaks);
    run_id = until_acquiring(rig);
    ASSERT_NE(run_id, 0);
    for (int i = 0; i < 60; ++i) rig.step();
    auto db = storage::Database::open_read_only(rig.db_path());
    ASSERT_TRUE(db.ok());
    auto run = db->run(run_id);
    ASSERT_TRUE(run.ok()) << run.error().message;
    const std::string checkpoint_in_soak1 = run->resume_json;
    ASSERT_FALSE(checkpoint_in_soak1.empty());
    // Into the second soak (settling), the first recorded completed.
    ASSERT_TRUE(
        rig.step_until([&] { return rig.station->status().step_index.value_or(-1) == 1; }, 600));
    ASSERT_TRUE(
        wait_for_condition([&] { return rig.station->status().storage.pending == 0; }, 20s));
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(rig.db_path().c_str(), &raw), SQLITE_OK);
    const std::string sql = "VACUUM INTO '" + crashed_db + "'";
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK);
    sqlite3_close(raw);
    // What the crash left: the first soak completed, the checkpoint older.
    ASSERT_EQ(sqlite3_open(crashed_db.c_str(), &raw), SQLITE_OK);
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(
        sqlite3_prepare_v2(raw, "UPDATE runs SET resume_json = ? WHERE id = ?", -1, &st, nullptr),
        SQLITE_OK);
    sqlite3_bind_text(st, 1, checkpoint_in_soak1.c_str(), -1, SQLITE_TRANSIENT);
    sqlite3_bind_int64(st, 2, run_id);
    EXPECT_EQ(sqlite3_step(st), SQLITE_DONE);
    sqlite3_finalize(st);
    sqlite3_close(raw);
    wall_at_crash = rig.wall.unix_now_s();
  }

  StationRig rig(dir_, rig_config_toml(crashed_db));
  rig.wall.set(wall_at_crash + 5.0);
  rig.open();
  ASSERT_EQ(rig.station->status().run_id.value_or(0), run_id);
  rig.step();
  EXPECT_EQ(rig.station->status().step_index.value_or(-1), 1)
      << "the run goes on with the second soak";
  EXPECT_TRUE(rig.has_event(run_id, "resume", "is not run again"));
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 3600));
  EXPECT_EQ(rig.reply(rig.station->run(run_id)).at("state"), "completed");
  const auto stats = wait_for_stats(rig, run_id, 2);
  EXPECT_EQ(stats.size(), 2u) << stats.dump(2);
  const auto run = rig.reply(rig.station->run(run_id));
  std::set<int> completed_steps;
  for (const auto& seg : run.at("segments")) {
    EXPECT_NE(seg.at("state"), "running") << run.dump(2);
    if (seg.at("state") == "completed") completed_steps.insert(seg.at("index").get<int>());
  }
  EXPECT_EQ(completed_steps, (std::set<int>{0, 1})) << run.dump(2);
}

// Issue "Safe states that hold", item 1: a run that ends while the chamber
// does not answer leaves the safe set point owed; idle ticks write it, at
// most once a tick, until the chamber takes it, and say so.
TEST_F(StationUnitTest, AChamberSilentAtTheEndOfARunGetsTheSafeSetPointWhenItAnswers) {
  StationRig rig(dir_);
  rig.open();
  rig.queue(R"(
name = "hold 40"
[[step]]
type = "hold"
setpoint_c = 40.0
duration_min = 3
)");
  ASSERT_TRUE(rig.step_until([&] { return rig.station->status().run_id.has_value(); }, 5));
  const int64_t run_id = *rig.station->status().run_id;
  ASSERT_TRUE(rig.step_until([&] { return rig.station->status().t_run_s >= 177; }, 600));
  EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, 40.0);
  rig.plant->change([](FakePlant::State& s) { s.chamber_silent = true; });
  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 20));
  EXPECT_EQ(rig.reply(rig.station->run(run_id)).at("state"), "completed");
  for (int i = 0; i < 4; ++i) rig.step();
  EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, 40.0) << "the chamber did not answer";
  EXPECT_TRUE(rig.has_event(run_id, "error", "without the chamber taking the safe set point 21"));
  // Answering again, but refusing writes a while (a controller in local
  // mode): one write a tick, no more.
  rig.plant->change([](FakePlant::State& s) {
    s.chamber_silent = false;
    s.refuse_setpoint = true;
  });
  const int attempts = rig.plant->state().setpoint_write_attempts;
  for (int i = 0; i < 4; ++i) rig.step();
  EXPECT_EQ(rig.plant->state().setpoint_write_attempts - attempts, 4);
  EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, 40.0);

  rig.plant->change([](FakePlant::State& s) { s.refuse_setpoint = false; });
  rig.step();
  EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, 21.0) << "written at the first tick it answers";
  EXPECT_NE(rig.station->status().last_event.find("set point 21 °C taken after"), std::string::npos)
      << rig.station->status().last_event;
  // Taken: not written again while idle.
  const int writes = rig.plant->state().setpoint_writes;
  for (int i = 0; i < 60; ++i) rig.step();
  EXPECT_EQ(rig.plant->state().setpoint_writes, writes);
}

// Item 2: the log and the events say whether the safe set point was written
// when the daemon stops.
TEST_F(StationUnitTest, StoppingSaysWhetherTheChamberTookTheSafeSetPoint) {
  {
    LogCapture log;
    {
      StationRig rig(dir_);
      rig.open();
      rig.step();
      rig.close();
      EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, 21.0);
    }
    EXPECT_NE(log.text().find("stopped (rig closed); chamber set point 21 °C written"),
              std::string::npos)
        << log.text();
  }
  LogCapture log;
  {
    StationRig rig(dir_);
    rig.open();
    rig.step();
    rig.plant->change([](FakePlant::State& s) { s.chamber_silent = true; });
    rig.close();
    EXPECT_DOUBLE_EQ(rig.plant->state().setpoint_c, 23.0) << "never written";
  }
  const std::string text = log.text();
  EXPECT_EQ(text.find("chamber set point 21 °C written"), std::string::npos) << text;
  EXPECT_NE(text.find("the chamber did NOT take the safe set point 21 °C (chamber: no answer"),
            std::string::npos)
      << text;
  bool said = false;
  for (const auto& message : messages_outside_runs((dir_ / "station.db").string(), "error")) {
    said |= message.find("did not take the safe set point 21 °C") != std::string::npos;
  }
  EXPECT_TRUE(said) << "an event of kind error says so";
}

// Item 15: the DUT probes' events are recorded under the run lock, as the
// HTTP thread's are: while the control loop records one, an operator
// command waits.
TEST_F(StationUnitTest, DutProbeEventsAreRecordedUnderTheRunLock) {
  StationRig rig(dir_);
  rig.dut_plant = std::make_shared<FakePlant>();
  std::future<station::Reply> command;
  std::optional<bool> command_done_meanwhile;
  rig.on_publish = [&](std::string_view event, const nlohmann::json& data) {
    if (event != "event" || command_done_meanwhile) return;
    if (data.value("message", "").find("probes: no answer") == std::string::npos) return;
    // On the control thread, inside the recording of the event.
    command = std::async(std::launch::async, [&] { return rig.station->control("pause", "race"); });
    command_done_meanwhile = command.wait_for(scaled(1s)) == std::future_status::ready;
  };
  rig.open();
  rig.step();
  rig.dut_plant->change([](FakePlant::State& s) { s.probes_silent = true; });
  rig.step();
  ASSERT_TRUE(command_done_meanwhile.has_value()) << "no probe event published";
  EXPECT_FALSE(*command_done_meanwhile)
      << "an operator command ran while the control loop recorded an event";
  const station::Reply reply = command.get();
  ASSERT_TRUE(reply.refusal.has_value());
  EXPECT_EQ(reply.refusal->message, "no run in progress to pause");
}

// Item 16: status() reads what the control loop left; it never waits on a
// device, even one the control loop is blocked on.
TEST_F(StationUnitTest, StatusDoesNotWaitForAChamberThatDoesNotAnswer) {
  StationRig rig(dir_);
  rig.open();
  rig.step();
  rig.chamber().block();
  std::thread control([&] { rig.step(); });
  const bool blocked = wait_for_condition([&] { return rig.chamber().waiting(); }, 10s);
  std::future<station::StatusSnapshot> status;
  if (blocked) {
    status = std::async(std::launch::async, [&] { return rig.station->status(); });
  }
  // The chamber stays blocked for as long as this waits: any wait in status()
  // on the chamber would run into it.
  const bool answered = blocked && status.wait_for(scaled(5s)) == std::future_status::ready;
  rig.chamber().release();
  control.join();
  ASSERT_TRUE(blocked) << "the control tick never reached the chamber";
  EXPECT_TRUE(answered) << "status() waited on the chamber";
  EXPECT_GT(status.get().chamber.requests, 0u) << "the chamber's health is the last tick's";
}

// A soak's settle is forecast while it settles (docs/api.md, "Progress"):
// 23 -> 33 °C on a plant whose air lags 60 s and whose shell lags the air by
// 600 s; the stability gate (0.02 °C/min over 10 min, ± 0.5 °C) holds about
// 2 700 s in. Early in the rise the forecast says there is not enough
// curvature; a third of the way it predicts, and its median lands within
// 5 % of the time the gate really held (measured: 2 720 s against 2 730; the
// noise-free plant leaves no spread, so P10 = P50 = P90). The one soak is the
// run's last settle, so the run's ETA is the forecast plus the acquisition. Acquiring, the forecast
// is gone. Station time stands still while the test waits (wall, with a deadline) for the
// forecast's thread.
TEST_F(StationUnitTest, ASettlingSoakIsForecastAndTheForecastComesTrue) {
  StationRig rig(dir_);
  rig.plant->change([](FakePlant::State& s) {
    s.air_tau_s = 60;
    s.shell_tau_s = 600;
  });
  rig.open();
  rig.queue(R"(
name = "forecast"
[[step]]
type = "soak"
setpoint_c = 33.0
stability_window_min = 10
settle_timeout_min = 300
acquire_min = 5
)");
  ASSERT_TRUE(rig.step_until([&] { return rig.state() == "settling"; }, 30)) << rig.state();
  const double start_s = rig.station->status().t_run_s;
  // A forecast made over the data of the last minute (one is made every
  // minute of station time; more ticks at the same station time take the
  // thread's result), not one the fast ticks left behind.
  const auto forecast_now = [&](const std::string& verdict) {
    std::optional<station::Progress> p;
    const bool seen = wait_for_condition(
        [&] {
          rig.step(0);
          p = rig.station->status().progress;
          return p->settle && p->settle->verdict == verdict && p->settle->age_s < 70;
        },
        30s);
    EXPECT_TRUE(seen) << "no '" << verdict << "' forecast; last: "
                      << (p && p->settle ? p->settle->verdict + ": " + p->settle->note : "none");
    return p;
  };
  ASSERT_TRUE(rig.step_until([&] { return rig.station->status().t_run_s - start_s >= 130; }, 200));
  const auto early = forecast_now("not_enough_curvature");
  ASSERT_TRUE(early && early->settle);
  EXPECT_FALSE(early->settle->p50_s);
  EXPECT_FALSE(early->run_eta_s);

  ASSERT_TRUE(
      rig.step_until([&] { return rig.station->status().t_run_s - start_s >= 1000; }, 1000));
  ASSERT_EQ(rig.state(), "settling");
  const auto mid = forecast_now("predicted");
  ASSERT_TRUE(mid && mid->settle && mid->settle->p10_s && mid->settle->p50_s && mid->settle->p90_s)
      << (mid && mid->settle ? mid->settle->verdict + " " + mid->settle->note + " p10 " +
                                   std::to_string(mid->settle->p10_s.value_or(-1)) + " p50 " +
                                   std::to_string(mid->settle->p50_s.value_or(-1)) + " p90 " +
                                   std::to_string(mid->settle->p90_s.value_or(-1))
                             : "no forecast");
  const double now_s = rig.station->status().t_run_s;
  const double p50_at_s = now_s + *mid->settle->p50_s;
  EXPECT_LE(*mid->settle->p10_s, *mid->settle->p50_s);
  EXPECT_LE(*mid->settle->p50_s, *mid->settle->p90_s);
  ASSERT_TRUE(mid->run_eta_s && mid->run_eta_p10_s && mid->run_eta_p90_s);
  EXPECT_DOUBLE_EQ(*mid->run_eta_s, *mid->settle->p50_s + 300);
  EXPECT_DOUBLE_EQ(*mid->run_eta_p90_s, *mid->settle->p90_s + 300);
  const nlohmann::json j = station::to_json(rig.station->status());
  EXPECT_TRUE(j.at("progress").at("settle").is_object()) << j.at("progress").dump();

  ASSERT_TRUE(rig.step_until([&] { return rig.state() == "acquiring"; }, 6000, 5));
  const double settled_s = rig.station->status().t_run_s;
  EXPECT_NEAR(p50_at_s - start_s, settled_s - start_s, 0.05 * (settled_s - start_s))
      << "forecast at " << now_s - start_s << " s: P10 " << *mid->settle->p10_s << " P50 "
      << *mid->settle->p50_s << " P90 " << *mid->settle->p90_s << " s from then";
  EXPECT_FALSE(rig.station->status().progress.settle);
  EXPECT_TRUE(rig.station->status().progress.run_eta_s);
}

// Adaptive soaks (docs/schedules.md, "Adaptive soaks"). White noise of
// 1 °/h per frame at 10 Hz is 0.316 °/h in 1 s means: U95(T) = 1.96 x 0.316 /
// sqrt(T) reaches 0.03 °/h at T = 426 s; the axis is judged every 2 min of
// acquiring, so the soak ends at the first judgement past that (480 s, or a
// judgement later when the fit's own noise puts U95 above the target),
// long before its 60 min cap; why is stored with the segment and in the
// events, and while it acquires the status shows the axis's projection.
TEST_F(StationUnitTest, AnAdaptiveSoakEndsWhenItsBiasIsKnownToTheTarget) {
  StationRig rig(dir_);
  rig.open();
  rig.gyro().noise_dph = 1.0;
  const int64_t run_id = rig.queue(R"(
name = "adaptive"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
acquire = { target_u95_dph = 0.03, min_min = 2, max_min = 60 }
)");
  ASSERT_TRUE(rig.step_until([&] { return rig.state() == "acquiring"; }, 600)) << rig.state();
  const double acquiring_s = rig.station->status().t_run_s;
  ASSERT_TRUE(rig.step_until(
      [&] {
        return rig.station->status().t_run_s - acquiring_s >= 250 || rig.state() != "acquiring";
      },
      600));
  ASSERT_EQ(rig.state(), "acquiring");
  const station::Progress mid = rig.station->status().progress;
  ASSERT_TRUE(mid.acquire) << "no judgement after 250 s of acquiring";
  ASSERT_EQ(mid.acquire->axes.size(), 1u);
  const auto& axis = mid.acquire->axes.front();
  EXPECT_EQ(axis.verdict, "continue") << axis.note;
  ASSERT_TRUE(axis.reach_s && axis.u95_dph) << axis.note;
  EXPECT_NEAR(*axis.reach_s, 426, 0.35 * 426) << axis.note;
  EXPECT_GT(*axis.u95_dph, 0.03);
  ASSERT_TRUE(mid.step_planned_s && mid.acquire->planned_s);
  EXPECT_LT(*mid.step_planned_s, 3600) << "the projection, not the cap, is the step's plan";
  const nlohmann::json j = station::to_json(rig.station->status());
  EXPECT_EQ(j.at("progress").at("acquire").at("axes").at(0).at("verdict"), "continue")
      << j.at("progress").dump();
  // The projection judged, from 60 s to the cap: falling through the target
  // at the reach (white noise: U95 ∝ 1/√T), its value now the axis's U95.
  ASSERT_EQ(axis.projection.size(), 41u);
  EXPECT_DOUBLE_EQ(axis.projection.front().t_s, 60);
  EXPECT_NEAR(axis.projection.back().t_s, 3600, 1e-6);
  for (std::size_t i = 1; i < axis.projection.size(); ++i) {
    EXPECT_LT(axis.projection[i].u95_dph, axis.projection[i - 1].u95_dph) << i;
    const auto& p = axis.projection[i];
    if (p.t_s < *axis.reach_s / 1.2) {
      EXPECT_GT(p.u95_dph, 0.03) << p.t_s;
    }
    if (p.t_s > *axis.reach_s * 1.2) {
      EXPECT_LT(p.u95_dph, 0.03) << p.t_s;
    }
  }
  EXPECT_EQ(j.at("progress").at("acquire").at("axes").at(0).at("projection").size(), 41u);

  ASSERT_TRUE(rig.step_until([&] { return rig.station->idle() && !rig.station->status().run_id; },
                             3 * 3600));
  const auto run = rig.reply(rig.station->run(run_id));
  EXPECT_EQ(run.at("state"), "completed");
  const nlohmann::json seg = run.at("segments").at(0);
  const std::string stop = seg.at("acquire_stop").get<std::string>();
  EXPECT_EQ(stop.rfind("target reached: U95 <= 0.03 °/h on every gated axis", 0), 0u) << stop;
  const double acquired_s =
      seg.at("t_acquire_end_s").get<double>() - seg.at("t_acquire_start_s").get<double>();
  EXPECT_GE(acquired_s, 400) << stop;
  EXPECT_LE(acquired_s, 1000) << stop;
  EXPECT_TRUE(rig.has_event(run_id, "acquisition", "acquisition ended after")) << stop;

  // The run's report says it under its Table I.
  auto db = storage::Database::open_read_only(rig.db_path());
  ASSERT_TRUE(db) << db.error().message;
  auto report = calibration::collect_run_report(*db, run_id, {});
  ASSERT_TRUE(report) << report.error().message;
  EXPECT_EQ(report->acquire_stops.at(0), stop);
  bool said = false;
  for (const auto& f : calibration::render_run_files(*report, {})) {
    if (f.path.ends_with("report.html")) {
      said = f.content.find("Adaptive soak, step 1: target reached") != std::string::npos;
    }
  }
  EXPECT_TRUE(said) << "the report does not say why the adaptive soak ended";
}

// A rate random walk (K = 6 °/h/√h) makes the mean's uncertainty grow with
// the soak's length beyond a few seconds: 0.01 °/h is out of reach, and the
// soak ends at its minimum with the floor said, not at its cap.
TEST_F(StationUnitTest, AnAdaptiveSoakWhoseTargetIsOutOfReachEndsAndSaysWhy) {
  StationRig rig(dir_);
  rig.open();
  rig.gyro().noise_dph = 0.5;
  rig.gyro().walk_dphprh = 6.0;
  const int64_t run_id = rig.queue(R"(
name = "out of reach"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
acquire = { target_u95_dph = 0.01, min_min = 10, max_min = 120 }
)");
  ASSERT_TRUE(rig.step_until([&] { return rig.station->idle() && !rig.station->status().run_id; },
                             4 * 3600));
  const auto run = rig.reply(rig.station->run(run_id));
  EXPECT_EQ(run.at("state"), "completed");
  const nlohmann::json seg = run.at("segments").at(0);
  const std::string stop = seg.at("acquire_stop").get<std::string>();
  EXPECT_NE(stop.find("out of reach"), std::string::npos) << stop;
  EXPECT_NE(stop.find("floor = "), std::string::npos) << stop;
  const double acquired_s =
      seg.at("t_acquire_end_s").get<double>() - seg.at("t_acquire_start_s").get<double>();
  EXPECT_NEAR(acquired_s, 600, 5) << "ends at its minimum: " << stop;
}

// The chamber's prior (docs/schedules.md, "Planned duration and
// progress"): the first run, ramping with a soak still to settle, has no
// ETA; by the third, the soaks of the first two (and its own first) have
// settled, and the ramp's ETA is the fixed time plus the median of those
// settles (P10/P90 from theirs); the run ends inside that band. While run 1
// runs, the two queued entries have no time either; later they do.
TEST_F(StationUnitTest, PastSettlesGiveTheEtaOfSoaksNotYetForecast) {
  StationRig rig(dir_);
  rig.open();
  for (int i = 0; i < 3; ++i) rig.queue(kSoakRampSoak);
  const auto ramping_in = [&](int64_t run_id) {
    std::optional<station::Progress> p;
    EXPECT_TRUE(rig.step_until(
        [&] {
          const auto s = rig.station->status();
          if (s.run_id == run_id && s.progress.phase == "ramping") p = s.progress;
          return p.has_value();
        },
        4 * 3600))
        << "run " << run_id << " never ramped";
    return p;
  };
  const auto first = ramping_in(1);
  ASSERT_TRUE(first);
  EXPECT_FALSE(first->run_eta_s);
  EXPECT_EQ(first->run_eta_basis, "");
  EXPECT_FALSE(first->queue_eta_s);

  const auto third = ramping_in(3);
  ASSERT_TRUE(third);
  const double ramp_s = rig.station->status().t_run_s;
  std::vector<double> settles_s;
  for (int64_t run_id = 1; run_id <= 3; ++run_id) {
    const nlohmann::json run = rig.reply(rig.station->run(run_id));
    for (const auto& seg : run.at("segments")) {
      if (seg.at("kind") == "soak" && seg.at("t_settled_s").is_number()) {
        settles_s.push_back(seg.at("t_settled_s").get<double>() -
                            seg.at("t_start_s").get<double>());
      }
    }
  }
  ASSERT_EQ(settles_s.size(), 5u);
  std::sort(settles_s.begin(), settles_s.end());
  EXPECT_EQ(third->run_eta_basis, "prior");
  EXPECT_EQ(third->prior_settles, 5);
  ASSERT_TRUE(third->run_eta_s && third->run_eta_p10_s && third->run_eta_p90_s);
  EXPECT_NEAR(*third->run_eta_s, third->run_remaining_fixed_s + settles_s[2], 1e-9);
  EXPECT_LE(*third->run_eta_p10_s, *third->run_eta_s);
  EXPECT_GE(*third->run_eta_p90_s, *third->run_eta_s);

  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 3600));
  const auto run = rig.reply(rig.station->run(3));
  const double ended_s = run.at("segments").back().at("t_end_s").get<double>();
  EXPECT_GE(ended_s - ramp_s, *third->run_eta_p10_s - 2) << "ETA " << *third->run_eta_s;
  EXPECT_LE(ended_s - ramp_s, *third->run_eta_p90_s + 2) << "ETA " << *third->run_eta_s;
}

}  // namespace
}  // namespace gyrotherm::testing
