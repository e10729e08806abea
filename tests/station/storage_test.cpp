// The station and its database file: deleted under a running station, a
// dead sample writer, a final commit that fails at a run's end, a damaged
// file at start, and the writer's per-run state (station_rig.h: a real
// SQLite file, fake devices, manual clocks).
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include "gyrotherm/storage/database.h"
#include "station/station_rig.h"
#include "test_time.h"

namespace gyrotherm::testing {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

// One soak with a 2-minute acquisition.
constexpr const char* kShortSoak = R"(
name = "short soak"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 2
)";

constexpr const char* kLongSoakSchedule = R"(
name = "long soak"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
settle_timeout_min = 30
acquire_min = 10
)";

class StationStorageTest : public TempDirTest {
 protected:
  StationStorageTest() : TempDirTest("gyrotherm-station-storage") {}

  int64_t until_acquiring(StationRig& rig) {
    EXPECT_TRUE(rig.step_until([&] { return rig.state() == "acquiring"; }, 3600))
        << "state " << rig.state();
    return rig.station->status().run_id.value_or(0);
  }
  static std::optional<std::string> interlock(StationRig& rig, std::string_view kind) {
    for (const auto& i : rig.station->status().interlocks) {
      if (i.kind == kind) return i.message;
    }
    return std::nullopt;
  }
  // A message published on the event stream ("event {...}", "state {...}")
  // that starts with `what` and contains `text`.
  static bool published(StationRig& rig, std::string_view what, std::string_view text) {
    for (const auto& p : rig.published()) {
      if (p.starts_with(what) && p.find(text) != std::string::npos) return true;
    }
    return false;
  }
  // Events of `run_id` in the file, read after the station is gone.
  std::vector<storage::EventRecord> file_events(int64_t run_id) {
    auto db = storage::Database::open_read_only((dir_ / "station.db").string());
    EXPECT_TRUE(db.ok()) << db.error().message;
    if (!db) return {};
    auto events = db->events(run_id);
    EXPECT_TRUE(events.ok());
    return events ? *events : std::vector<storage::EventRecord>{};
  }
  static int count(const std::vector<storage::EventRecord>& events, std::string_view kind,
                   std::string_view text) {
    int n = 0;
    for (const auto& e : events) {
      n += e.kind == kind && e.message.find(text) != std::string::npos;
    }
    return n;
  }
};

// `rm station.db` under a running station: an event at once, storage fails
// (the run holds, then fails after storage_failing's grace), nothing is
// written to the deleted file, no file is made in its place and no other run
// starts.
TEST_F(StationStorageTest, DatabaseDeletedUnderTheStationTripsStorageFailing) {
  const std::string db = (dir_ / "station.db").string();
  StationRig rig(dir_, rig_config_toml(db) + "[interlocks]\nstorage_failing_grace_min = 1\n");
  rig.open();
  rig.queue(kLongSoakSchedule);
  rig.queue(kLongSoakSchedule);
  const int64_t run_id = until_acquiring(rig);
  ASSERT_NE(run_id, 0);
  ASSERT_TRUE(fs::remove(db));
  rig.step();
  EXPECT_TRUE(published(rig, "event", "the database file was deleted while open"));
  EXPECT_TRUE(published(rig, "event", db));
  EXPECT_TRUE(published(rig, "event", "restart gyrothermd"));

  ASSERT_TRUE(rig.step_until([&] { return interlock(rig, "storage_failing").has_value(); }, 30))
      << "state " << rig.state();
  EXPECT_EQ(rig.state(), "suspended");
  EXPECT_NE(interlock(rig, "storage_failing")->find("deleted while open"), std::string::npos)
      << *interlock(rig, "storage_failing");
  // The writer's commits into the deleted file are refused too.
  EXPECT_TRUE(wait_for_condition(
      [&] {
        const auto s = rig.station->status().storage;
        return s.consecutive_failures > 0 &&
               s.last_error.find("not committed: the database file was deleted") !=
                   std::string::npos;
      },
      10s))
      << rig.station->status().storage.last_error;

  ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 600));
  EXPECT_TRUE(published(rig, "state", R"("to":"failed")"));
  for (int i = 0; i < 5; ++i) rig.step();
  EXPECT_FALSE(rig.station->status().run_id.has_value()) << "no run into a lost file";
  EXPECT_FALSE(fs::exists(db)) << "nothing made a new file in its place";
  EXPECT_EQ(fs::file_size(db + "-wal"), 0u) << "the old file's log was emptied into it";
}

// The sample writer's thread dies (an exception on it): storage fails.
TEST_F(StationStorageTest, DeadSampleWriterTripsStorageFailing) {
  StationRig rig(dir_);
  std::atomic<bool> kill{false};
  rig.on_commit = [&](double) {
    if (kill) throw std::runtime_error("killed by the test");
  };
  rig.open();
  rig.queue(kLongSoakSchedule);
  ASSERT_NE(until_acquiring(rig), 0);
  kill = true;
  rig.step();
  ASSERT_TRUE(wait_for_condition([&] { return rig.station->status().storage.thread_failed; }, 10s));
  ASSERT_TRUE(rig.step_until([&] { return interlock(rig, "storage_failing").has_value(); }, 30))
      << "state " << rig.state();
  EXPECT_EQ(rig.state(), "suspended");
  EXPECT_NE(interlock(rig, "storage_failing")->find("sample writer stopped: killed by the test"),
            std::string::npos)
      << *interlock(rig, "storage_failing");
}

// The disk fills in the last seconds of a run (before storage_failing's
// timeout): the run completes, but its end records that its last samples
// were not committed and it is not analysed, not even after a restart.
TEST_F(StationStorageTest, FailedFinalCommitIsRecordedAndTheRunIsNotAnalysed) {
  int64_t run_id = 0;
  {
    StationRig rig(dir_);
    rig.open();
    rig.queue(kShortSoak);
    run_id = until_acquiring(rig);
    ASSERT_NE(run_id, 0);
    for (int i = 0; i < 115; ++i) rig.step();  // of the 120 s acquisition
    ASSERT_TRUE(rig.station->status().run_id.has_value());
    rig.disk().set_full(true);
    ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 9));
    EXPECT_TRUE(published(rig, "state", R"("to":"completed")"));
    rig.close();  // the analysis worker finishes what it was given
  }
  auto events = file_events(run_id);
  EXPECT_EQ(count(events, "interlock", "storage_failing"), 0) << "the disk filled at the end only";
  EXPECT_EQ(count(events, "error", "the final commit of its samples failed"), 1);
  EXPECT_EQ(count(events, "error", "database or disk is full (bench)"), 1);
  EXPECT_EQ(count(events, "analysis", "analysis not run: the run's samples are incomplete"), 1);
  EXPECT_EQ(count(events, "analysis", "analysis stored"), 0);

  {
    StationRig again(dir_);  // a restart analyses completed runs without analysis
    again.open();
    again.step();
    again.close();
  }
  EXPECT_EQ(count(file_events(run_id), "analysis", "analysis stored"), 0);
}

// A completed run's state in the sample writer goes once its samples are in.
TEST_F(StationStorageTest, EndedRunsReleaseTheWritersState) {
  StationRig rig(dir_);
  rig.open();
  for (int run = 0; run < 3; ++run) {
    rig.queue(kShortSoak);
    ASSERT_TRUE(rig.step_until([&] { return rig.station->status().run_id.has_value(); }, 5));
    EXPECT_EQ(rig.station->status().storage.runs_held, 0u) << "the run before was released";
    ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 3600));
    ASSERT_TRUE(
        wait_for_condition([&] { return rig.station->status().storage.runs_held == 0; }, 10s))
        << rig.station->status().storage.runs_held << " runs held after run " << run + 1;
  }
}

// A damaged database is refused when the station is created, naming it.
TEST_F(StationStorageTest, DamagedDatabaseIsRefusedAtStart) {
  const std::string db = (dir_ / "station.db").string();
  int64_t root = 0, page_size = 0;
  {
    auto d = storage::Database::open(db);
    ASSERT_TRUE(d.ok()) << d.error().message;
    for (int i = 0; i < 20; ++i) ASSERT_TRUE(d->queue_add("s", "s.toml", "[[step]]\n", false).ok());
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(d->handle(),
                                 "SELECT rootpage, (SELECT page_size FROM pragma_page_size) FROM "
                                 "sqlite_master WHERE name = 'queue'",
                                 -1, &st, nullptr),
              SQLITE_OK);
    ASSERT_EQ(sqlite3_step(st), SQLITE_ROW);
    root = sqlite3_column_int64(st, 0);
    page_size = sqlite3_column_int64(st, 1);
    sqlite3_finalize(st);
  }
  {
    std::fstream f(db, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp((root - 1) * page_size + 8);
    const std::string garbage(64, '\xff');
    f.write(garbage.data(), static_cast<std::streamsize>(garbage.size()));
  }
  auto cfg = config::parse_station_config(rig_config_toml(db), "rig.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  auto plant = std::make_shared<FakePlant>();
  station::StationDevices devices;
  devices.chamber = std::make_unique<FakeChamber>(plant);
  devices.probes = std::make_unique<FakeProbes>(plant);
  devices.duts.push_back(std::make_unique<FakeGyro>(plant, 10.0));
  ManualClock clock{1000.0, 1.0};
  ManualWallClock wall{1.8e9};
  auto station = station::Station::create(*cfg, std::move(devices), {clock, wall}, {});
  ASSERT_FALSE(station.ok()) << "a damaged database was accepted";
  EXPECT_NE(station.error().message.find(db), std::string::npos) << station.error().message;
  EXPECT_NE(station.error().message.find("the database is damaged: PRAGMA quick_check"),
            std::string::npos)
      << station.error().message;
}

}  // namespace
}  // namespace gyrotherm::testing
