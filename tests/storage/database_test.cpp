#include "gyrotherm/storage/database.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <regex>
#include <set>
#include <thread>

#include "gyrotherm/storage/sample_writer.h"
#include "migrations.h"
#include "numbers.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using testing::integrity_ok;
using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::TempDir;

using gyrotherm::testing::kNaN;

RunRecord sample_run() {
  RunRecord r;
  r.schedule_name = "paper-table1";
  r.state = "ramping";
  r.started_utc = "2026-11-21T05:38:43.120Z";
  r.time_scale = 1000.0;
  r.latitude_deg = 31.9;
  r.orientation = "up";
  r.config_json = R"({"station":{"name":"lab-2"}})";
  return r;
}

TEST(Database, OpenCreatesTheCurrentSchemaInWalMode) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  auto version = db.schema_version();
  ASSERT_TRUE(version.ok()) << version.error().message;
  EXPECT_EQ(*version, kSchemaVersion);
  EXPECT_EQ(kSchemaVersion, 14);
  EXPECT_EQ(query_text(db.handle(), "PRAGMA journal_mode"), "wal");
  EXPECT_EQ(query_int(db.handle(), "PRAGMA synchronous"), 1);  // NORMAL
  EXPECT_EQ(query_int(db.handle(), "PRAGMA foreign_keys"), 1);
  EXPECT_EQ(query_int(db.handle(), "PRAGMA busy_timeout"), 5000);
  EXPECT_TRUE(
      std::regex_match(query_text(db.handle(), "SELECT value FROM meta WHERE key='created_utc'"),
                       std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z)")));

  std::set<std::string> tables;
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(db.handle(), "SELECT name FROM sqlite_master WHERE type='table'", -1,
                               &st, nullptr),
            SQLITE_OK);
  while (sqlite3_step(st) == SQLITE_ROW) {
    tables.insert(reinterpret_cast<const char*>(sqlite3_column_text(st, 0)));
  }
  sqlite3_finalize(st);
  const std::set<std::string> expected = {"meta",
                                          "runs",
                                          "schedules",
                                          "queue",
                                          "segments",
                                          "temperature_samples",
                                          "events",
                                          "segment_stats",
                                          "acquisition_windows",
                                          "fits",
                                          "fit_runs",
                                          "allan",
                                          "exports",
                                          "export_runs",
                                          "table_samples",
                                          "scale_factor_points",
                                          "scale_factor_fits",
                                          "scale_factor_temperature_fits",
                                          "duts",
                                          "run_duts",
                                          "channels",
                                          "sample_chunks",
                                          "channel_rollup",
                                          "outbox",
                                          "sqlite_sequence"};
  EXPECT_EQ(tables, expected);
}

TEST(Database, ReopenIsIdempotent) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  std::string created;
  int64_t run_id = 0;
  {
    Database db = open_ok(path);
    created = query_text(db.handle(), "SELECT value FROM meta WHERE key='created_utc'");
    auto id = db.create_run(sample_run());
    ASSERT_TRUE(id.ok()) << id.error().message;
    run_id = *id;
  }
  for (int i = 0; i < 2; ++i) {
    Database db = open_ok(path);
    EXPECT_EQ(*db.schema_version(), kSchemaVersion);
    EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM meta"), 2);
    EXPECT_EQ(query_text(db.handle(), "SELECT value FROM meta WHERE key='created_utc'"), created);
    auto run = db.run(run_id);
    ASSERT_TRUE(run.ok()) << run.error().message;
    EXPECT_EQ(run->schedule_name, "paper-table1");
  }
}

TEST(Database, ConcurrentFirstOpensMigrateOnce) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  std::vector<std::string> errors(4);
  std::vector<std::thread> threads;
  for (std::size_t i = 0; i < errors.size(); ++i) {
    threads.emplace_back([&, i] {
      auto db = Database::open(path);
      if (!db) errors[i] = db.error().message;
    });
  }
  for (auto& t : threads) t.join();
  for (const auto& e : errors) EXPECT_EQ(e, "");
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
}

TEST(Database, NewerSchemaIsRefusedWithAClearMessage) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  {
    Database db = open_ok(path);
    ASSERT_TRUE(db.exec(fmt::format("UPDATE meta SET value='{}' WHERE key='schema_version'",
                                    kSchemaVersion + 1))
                    .ok());
  }
  auto db = Database::open(path);
  ASSERT_FALSE(db.ok());
  EXPECT_FALSE(db.error().transient);
  EXPECT_NE(db.error().message.find(path), std::string::npos) << db.error().message;
  EXPECT_NE(db.error().message.find(fmt::format("schema version {}, newer than this build's {}",
                                                kSchemaVersion + 1, kSchemaVersion)),
            std::string::npos)
      << db.error().message;

  auto ro = Database::open_read_only(path);
  ASSERT_FALSE(ro.ok());
  EXPECT_NE(ro.error().message.find(fmt::format("schema version {}", kSchemaVersion + 1)),
            std::string::npos)
      << ro.error().message;
}

TEST(Database, RefusesAnotherApplicationsDatabase) {
  TempDir dir;
  const std::string path = dir.file("other.db");
  sqlite3* raw = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(raw, "CREATE TABLE customers(id INTEGER)", nullptr, nullptr, nullptr),
            SQLITE_OK);
  sqlite3_close(raw);
  auto db = Database::open(path);
  ASSERT_FALSE(db.ok());
  EXPECT_NE(db.error().message.find("not a gyrotherm database"), std::string::npos)
      << db.error().message;
}

TEST(Database, OpenErrorsNameTheFile) {
  TempDir dir;
  const std::string missing = dir.file("no-such-dir/station.db");
  auto db = Database::open(missing);
  ASSERT_FALSE(db.ok());
  EXPECT_NE(db.error().message.find(missing), std::string::npos) << db.error().message;

  auto ro = Database::open_read_only(dir.file("absent.db"));
  ASSERT_FALSE(ro.ok());
  EXPECT_NE(ro.error().message.find("absent.db"), std::string::npos) << ro.error().message;
}

TEST(Database, ReadOnlyConnectionReadsButDoesNotWrite) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database rw = open_ok(path);
  const int64_t run_id = *rw.create_run(sample_run());

  auto ro = Database::open_read_only(path);
  ASSERT_TRUE(ro.ok()) << ro.error().message;
  EXPECT_EQ(*ro->schema_version(), kSchemaVersion);
  auto run = ro->run(run_id);
  ASSERT_TRUE(run.ok()) << run.error().message;
  EXPECT_EQ(run->state, "ramping");
  Status s = ro->set_run_state(run_id, "failed", true);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find(path), std::string::npos) << s.error().message;
  EXPECT_NE(s.error().message.find("readonly"), std::string::npos) << s.error().message;
}

// Reads inside read_consistently() see one committed state: a write another
// connection commits in between shows only after it (the HTTP thread's
// answers of several reads while the analysis thread stores results).
TEST(Database, ReadConsistentlySeesOneCommittedState) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database reader = open_ok(path);
  Database writer = open_ok(path);
  const int64_t first = *writer.create_run(sample_run());
  std::size_t before = 0, inside = 0;
  const Status read = reader.read_consistently([&]() -> Status {
    auto runs = reader.runs();
    if (!runs) return runs.error();
    before = runs->size();
    // Another connection commits a run between the two reads.
    if (auto id = writer.create_run(sample_run()); !id) return id.error();
    runs = reader.runs();
    if (!runs) return runs.error();
    inside = runs->size();
    return Status::Ok();
  });
  ASSERT_TRUE(read.ok()) << read.error().message;
  EXPECT_EQ(before, 1u);
  EXPECT_EQ(inside, 1u) << "the second read saw the other connection's commit";
  EXPECT_EQ(reader.runs()->size(), 2u);
  EXPECT_EQ(reader.run(first)->id, first);
  // A failing body's error comes back; the connection reads on.
  const Status failed =
      reader.read_consistently([]() -> Status { return Error::Transient("body failed"); });
  ASSERT_FALSE(failed.ok());
  EXPECT_EQ(failed.error().message, "body failed");
  EXPECT_EQ(reader.runs()->size(), 2u);
}

TEST(Database, RunRoundTrip) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  RunRecord in = sample_run();
  in.latitude_deg = kNaN;  // unknown latitude is stored as NULL
  auto id = db.create_run(in);
  ASSERT_TRUE(id.ok()) << id.error().message;

  auto out = db.run(*id);
  ASSERT_TRUE(out.ok()) << out.error().message;
  EXPECT_EQ(out->id, *id);
  EXPECT_EQ(out->schedule_name, in.schedule_name);
  EXPECT_EQ(out->state, in.state);
  EXPECT_EQ(out->started_utc, in.started_utc);
  EXPECT_EQ(out->ended_utc, "");
  EXPECT_EQ(out->time_scale, 1000.0);
  EXPECT_TRUE(std::isnan(out->latitude_deg));
  EXPECT_EQ(out->orientation, "up");
  EXPECT_EQ(out->config_json, in.config_json);
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM runs WHERE latitude_deg IS NULL"), 1);

  ASSERT_TRUE(db.set_run_state(*id, "completed", true).ok());
  out = db.run(*id);
  EXPECT_EQ(out->state, "completed");
  EXPECT_TRUE(std::regex_match(out->ended_utc, std::regex(R"(\d{4}-.*Z)"))) << out->ended_utc;
  ASSERT_TRUE(db.set_run_state(*id, "settling", false).ok());
  EXPECT_EQ(db.run(*id)->ended_utc, "");

  RunRecord second = sample_run();
  second.started_utc = "";  // filled with the current wall time
  const int64_t id2 = *db.create_run(second);
  auto all = db.runs();
  ASSERT_TRUE(all.ok());
  ASSERT_EQ(all->size(), 2u);
  EXPECT_EQ((*all)[0].id, *id);
  EXPECT_EQ((*all)[1].id, id2);
  EXPECT_FALSE((*all)[1].started_utc.empty());

  auto missing = db.run(999);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("no run with id 999"), std::string::npos);
  Status s = db.set_run_state(999, "failed", true);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("no such run"), std::string::npos) << s.error().message;
}

TEST(Database, SegmentRoundTripWithUnsetTimes) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const int64_t run_id = *db.create_run(sample_run());

  SegmentRecord soak;
  soak.run_id = run_id;
  soak.index = 1;
  soak.kind = "soak";
  soak.label = "soak 20 °C (step 1)";
  soak.setpoint_c = 20.0;
  soak.ramp_rate_c_per_min = kNaN;
  soak.t_start_s = 3600.5;
  soak.state = "running";
  SegmentRecord ramp = soak;
  ramp.index = 0;
  ramp.kind = "ramp";
  ramp.label = "ramp to -14.6 °C";
  ramp.setpoint_c = -14.6;
  ramp.ramp_rate_c_per_min = 1.5;
  ramp.t_start_s = 0;

  auto soak_id = db.create_segment(soak);
  ASSERT_TRUE(soak_id.ok()) << soak_id.error().message;
  auto ramp_id = db.create_segment(ramp);
  ASSERT_TRUE(ramp_id.ok()) << ramp_id.error().message;

  auto segs = db.segments(run_id);
  ASSERT_TRUE(segs.ok()) << segs.error().message;
  ASSERT_EQ(segs->size(), 2u);
  EXPECT_EQ((*segs)[0].id, *ramp_id);  // ordered by index
  EXPECT_EQ((*segs)[0].ramp_rate_c_per_min, 1.5);
  const SegmentRecord& s = (*segs)[1];
  EXPECT_EQ(s.id, *soak_id);
  EXPECT_EQ(s.run_id, run_id);
  EXPECT_EQ(s.index, 1);
  EXPECT_EQ(s.kind, "soak");
  EXPECT_EQ(s.label, soak.label);
  EXPECT_EQ(s.setpoint_c, 20.0);
  EXPECT_TRUE(std::isnan(s.ramp_rate_c_per_min));
  EXPECT_EQ(s.t_start_s, 3600.5);
  EXPECT_EQ(s.t_settled_s, std::nullopt);
  EXPECT_EQ(s.t_acquire_start_s, std::nullopt);
  EXPECT_EQ(s.t_acquire_end_s, std::nullopt);
  EXPECT_EQ(s.t_end_s, std::nullopt);
  EXPECT_EQ(s.paused_s, 0.0);
  EXPECT_EQ(s.state, "running");

  SegmentRecord done = s;
  done.t_settled_s = 5000.25;
  done.t_acquire_start_s = 5000.25;
  done.t_acquire_end_s = 12200.25;
  done.t_end_s = 12200.5;
  done.paused_s = 30.0;
  done.state = "completed";
  done.windows = {{5000.25, 6000.0}, {6030.0, 12200.25}};
  ASSERT_TRUE(db.update_segment(done).ok());
  const SegmentRecord back = (*db.segments(run_id))[1];
  EXPECT_EQ(back.windows, done.windows);
  EXPECT_TRUE((*db.segments(run_id))[0].windows.empty());
  EXPECT_EQ(back.t_settled_s, 5000.25);
  EXPECT_EQ(back.t_acquire_start_s, 5000.25);
  EXPECT_EQ(back.t_acquire_end_s, 12200.25);
  EXPECT_EQ(back.t_end_s, 12200.5);
  EXPECT_EQ(back.paused_s, 30.0);
  EXPECT_EQ(back.state, "completed");

  done.id = 12345;
  Status missing = db.update_segment(done);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("no such segment"), std::string::npos);

  SegmentRecord orphan = soak;
  orphan.run_id = 777;  // foreign key: no such run
  auto bad = db.create_segment(orphan);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find(path), std::string::npos) << bad.error().message;
  EXPECT_NE(bad.error().message.find("FOREIGN KEY constraint failed"), std::string::npos)
      << bad.error().message;
}

TEST(Database, EventRoundTrip) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run_id = *db.create_run(sample_run());

  EventRecord station;
  station.kind = "info";
  station.message = "daemon started";
  ASSERT_TRUE(db.add_event(station).ok());

  EventRecord transition;
  transition.run_id = run_id;
  transition.t_s = 5000.25;
  transition.wall_utc = "2026-11-21T07:02:03.004Z";
  transition.kind = "state";
  transition.from_state = "settling";
  transition.to_state = "acquiring";
  transition.message = "stability gate held for 10 min";
  auto id1 = db.add_event(transition);
  ASSERT_TRUE(id1.ok()) << id1.error().message;
  EventRecord interlock;
  interlock.run_id = run_id;
  interlock.t_s = kNaN;
  interlock.kind = "interlock";
  interlock.message = "probes disagree by 3.1 °C";
  auto id2 = db.add_event(interlock);
  ASSERT_TRUE(id2.ok());

  auto events = db.events(run_id);
  ASSERT_TRUE(events.ok()) << events.error().message;
  ASSERT_EQ(events->size(), 2u);
  const EventRecord& a = (*events)[0];
  EXPECT_EQ(a.id, *id1);
  EXPECT_EQ(a.run_id, run_id);
  EXPECT_EQ(a.t_s, 5000.25);
  EXPECT_EQ(a.wall_utc, transition.wall_utc);
  EXPECT_EQ(a.kind, "state");
  EXPECT_EQ(a.from_state, "settling");
  EXPECT_EQ(a.to_state, "acquiring");
  EXPECT_EQ(a.message, transition.message);
  const EventRecord& b = (*events)[1];
  EXPECT_EQ(b.id, *id2);
  EXPECT_TRUE(std::isnan(b.t_s));
  EXPECT_FALSE(b.wall_utc.empty());
  EXPECT_EQ(b.from_state, "");
  EXPECT_EQ(b.to_state, "");

  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM events WHERE run_id IS NULL"), 1);
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM events WHERE from_state IS NULL AND run_id IS NULL"),
            1);
}

TEST(Database, SegmentStatsRoundTripAndReplace) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run1 = *db.create_run(sample_run());
  const int64_t run2 = *db.create_run(sample_run());
  SegmentRecord seg;
  seg.kind = "soak";
  seg.state = "completed";
  seg.run_id = run2;
  seg.index = 0;
  const int64_t seg_run2 = *db.create_segment(seg);
  seg.run_id = run1;
  seg.index = 3;
  const int64_t seg3 = *db.create_segment(seg);
  seg.index = 1;
  const int64_t seg1 = *db.create_segment(seg);

  SegmentStatsRecord row;
  row.segment_id = seg3;
  row.run_id = run1;
  row.segment_index = 3;
  row.setpoint_c = 20.0;
  row.n = 7200;
  row.duration_s = 7200.0;
  row.temp_mean_c = 19.87;
  row.bias_mean_dph = 8.1234;
  row.bias_std_dph = 1.01;
  row.bias_std_ma_dph = 0.105;
  row.bias_mean_earth_removed_dph = 0.1734;
  row.bin_s = 1.0;
  row.ma_window = 101;
  row.earth_rate_dph = 7.95;
  row.t_from_s = 5000.0;
  row.t_to_s = 12200.0;
  row.computed_utc = "2026-11-21T09:00:00.000Z";
  row.bias_u = BiasUncertainty{.u_dph = 0.0123,
                               .expanded_dph = 0.0246,
                               .k = 2.0,
                               .dof = std::numeric_limits<double>::infinity(),
                               .floor_dph = 0.004,
                               .random_walk_dominated = true};
  const Status put = db.put_segment_stats(row);
  ASSERT_TRUE(put.ok()) << put.error().message;

  SegmentStatsRecord short_window = row;  // fewer points than the MA window
  short_window.segment_id = seg1;
  short_window.segment_index = 1;
  short_window.n = 50;
  short_window.bias_std_ma_dph = kNaN;
  short_window.bias_u.reset();
  short_window.bias_u_note = "no noise model: too few taus";
  ASSERT_TRUE(db.put_segment_stats(short_window).ok());

  SegmentStatsRecord other_run = row;
  other_run.segment_id = seg_run2;
  other_run.run_id = run2;
  other_run.segment_index = 0;
  ASSERT_TRUE(db.put_segment_stats(other_run).ok());

  auto rows = db.segment_stats(run1);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->size(), 2u);
  EXPECT_EQ((*rows)[0].segment_id, seg1);  // ordered by segment index
  EXPECT_EQ((*rows)[0].n, 50);
  EXPECT_TRUE(std::isnan((*rows)[0].bias_std_ma_dph));
  EXPECT_FALSE((*rows)[0].bias_u);
  EXPECT_EQ((*rows)[0].bias_u_note, "no noise model: too few taus");
  const SegmentStatsRecord& r = (*rows)[1];
  ASSERT_TRUE(r.bias_u);
  EXPECT_EQ(r.bias_u->u_dph, 0.0123);
  EXPECT_EQ(r.bias_u->expanded_dph, 0.0246);
  EXPECT_EQ(r.bias_u->k, 2.0);
  EXPECT_EQ(r.bias_u->dof, kMaxStoredDof);  // infinite dof is stored capped
  EXPECT_EQ(r.bias_u->floor_dph, 0.004);
  EXPECT_TRUE(r.bias_u->random_walk_dominated);
  EXPECT_EQ(r.bias_u_note, "");
  EXPECT_EQ(r.segment_id, seg3);
  EXPECT_EQ(r.run_id, run1);
  EXPECT_EQ(r.segment_index, 3);
  EXPECT_EQ(r.setpoint_c, 20.0);
  EXPECT_EQ(r.n, 7200);
  EXPECT_EQ(r.duration_s, 7200.0);
  EXPECT_EQ(r.temp_mean_c, 19.87);
  EXPECT_EQ(r.bias_mean_dph, 8.1234);
  EXPECT_EQ(r.bias_std_dph, 1.01);
  EXPECT_EQ(r.bias_std_ma_dph, 0.105);
  EXPECT_EQ(r.bias_mean_earth_removed_dph, 0.1734);
  EXPECT_EQ(r.bin_s, 1.0);
  EXPECT_EQ(r.ma_window, 101);
  EXPECT_EQ(r.earth_rate_dph, 7.95);
  EXPECT_EQ(r.t_from_s, 5000.0);
  EXPECT_EQ(r.t_to_s, 12200.0);
  EXPECT_EQ(r.computed_utc, row.computed_utc);

  row.bias_mean_dph = 9.5;  // recomputed: replaces, does not add
  ASSERT_TRUE(db.put_segment_stats(row).ok());
  rows = db.segment_stats(run1);
  ASSERT_EQ(rows->size(), 2u);
  EXPECT_EQ((*rows)[1].bias_mean_dph, 9.5);

  auto all = db.segment_stats(std::nullopt);
  ASSERT_TRUE(all.ok());
  ASSERT_EQ(all->size(), 3u);
  EXPECT_EQ((*all)[0].run_id, run1);
  EXPECT_EQ((*all)[2].run_id, run2);
}

TEST(Database, ExecReportsTheStatement) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  Status s = db.exec("SELECT * FROM no_such_table");
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find(path), std::string::npos);
  EXPECT_NE(s.error().message.find("no such table: no_such_table"), std::string::npos)
      << s.error().message;
}

}  // namespace
}  // namespace gyrotherm::storage

namespace gyrotherm::storage {
namespace {

std::vector<int64_t> queued_ids(Database& db) {
  std::vector<int64_t> ids;
  const auto entries = db.queue_entries();
  for (const auto& e : *entries) {
    if (e.state == "queued") ids.push_back(e.id);
  }
  return ids;
}

TEST(Queue, AddListMoveRemoveClaimFinish) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  std::vector<int64_t> ids;
  for (const char* name : {"a", "b", "c", "d"}) {
    auto e = db.queue_add(name, std::string("config/schedules/") + name + ".toml",
                          std::string("name = \"") + name + "\"", name[0] == 'b');
    ASSERT_TRUE(e.ok()) << e.error().message;
    EXPECT_EQ(e->state, "queued");
    EXPECT_EQ(e->schedule_name, name);
    EXPECT_EQ(e->position, static_cast<int>(ids.size()));
    ids.push_back(e->id);
  }
  EXPECT_TRUE(db.queue_entry(ids[1])->value().ignore_failures);
  EXPECT_FALSE(db.queue_entry(ids[0])->value().ignore_failures);
  EXPECT_EQ(queued_ids(db), ids);

  ASSERT_TRUE(*db.queue_move(ids[3], 0));
  EXPECT_EQ(queued_ids(db), (std::vector<int64_t>{ids[3], ids[0], ids[1], ids[2]}));
  ASSERT_TRUE(*db.queue_move(ids[3], 99));  // past the end: last
  EXPECT_EQ(queued_ids(db), ids);
  ASSERT_TRUE(*db.queue_move(ids[0], 2));
  EXPECT_EQ(queued_ids(db), (std::vector<int64_t>{ids[1], ids[2], ids[0], ids[3]}));
  int pos = 0;
  const auto entries = db.queue_entries();
  for (const auto& e : *entries) EXPECT_EQ(e.position, pos++);

  ASSERT_TRUE(*db.queue_remove(ids[2]));
  EXPECT_FALSE(*db.queue_remove(ids[2])) << "already removed";
  EXPECT_FALSE(*db.queue_move(ids[2], 0));
  EXPECT_EQ(db.queue_entry(ids[2])->value().state, "removed");
  EXPECT_EQ(queued_ids(db), (std::vector<int64_t>{ids[1], ids[0], ids[3]}));

  const int64_t run_id = *db.create_run(RunRecord{});
  ASSERT_TRUE(*db.queue_claim(ids[1], run_id));
  EXPECT_FALSE(*db.queue_claim(ids[1], run_id)) << "claimed once";
  EXPECT_FALSE(*db.queue_remove(ids[1])) << "a running entry is not removed";
  auto all = *db.queue_entries();
  ASSERT_EQ(all.size(), 3u);
  EXPECT_EQ(all[0].id, ids[1]) << "the running entry comes first";
  EXPECT_EQ(all[0].state, "running");
  EXPECT_EQ(all[0].run_id, run_id);
  EXPECT_EQ(all[1].position, 0);
  ASSERT_TRUE(db.queue_finish(ids[1], "completed").ok());
  EXPECT_EQ(db.queue_entries()->size(), 2u);
  EXPECT_FALSE(db.queue_entry(999)->has_value());

  ASSERT_TRUE(*db.queue_claim(ids[0], run_id));
  ASSERT_TRUE(db.queue_requeue(ids[0]).ok());
  EXPECT_EQ(queued_ids(db), (std::vector<int64_t>{ids[0], ids[3]}));
}

// A database whose table pages are overwritten fails the integrity check:
// the check reads the rows. (Database::exec("PRAGMA integrity_check") says
// ok on the same file: it discards the rows.)
TEST(Database, IntegrityCheckFailsOnACorruptedFile) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  std::vector<int64_t> leaves;  // the events' last leaf pages
  int64_t page_size = 0;
  {
    Database db = open_ok(path);
    EXPECT_TRUE(integrity_ok(db)) << "a fresh file is sound";
    ASSERT_TRUE(db.exec("BEGIN").ok());
    for (int i = 0; i < 2000; ++i) {
      EventRecord ev;
      ev.kind = "info";
      ev.message = fmt::format("event {} {}", i, std::string(200, 'x'));
      ASSERT_TRUE(db.add_event(ev).ok());
    }
    ASSERT_TRUE(db.exec("COMMIT").ok());
    EXPECT_TRUE(integrity_ok(db));
    page_size = query_int(db.handle(), "PRAGMA page_size");
    const std::string list = query_text(
        db.handle(),
        "SELECT group_concat(pageno) FROM (SELECT pageno FROM dbstat WHERE name = 'events' AND "
        "pagetype = 'leaf' ORDER BY pageno DESC LIMIT 8)");
    for (std::size_t at = 0; at < list.size();) {
      std::size_t end = list.find(',', at);
      if (end == std::string::npos) end = list.size();
      leaves.push_back(std::stoll(list.substr(at, end - at)));
      at = end + 1;
    }
  }  // the last connection closes: the WAL is checkpointed into the file
  ASSERT_FALSE(std::filesystem::exists(path + "-wal"));
  ASSERT_EQ(leaves.size(), 8u);
  {
    // Garbage over the middle of the events' last leaf pages (their
    // headers and cells; which pages they are depends on what the schema's
    // migrations left free), the schema and every interior page untouched.
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    const std::string garbage(static_cast<std::size_t>(page_size / 2), '\x5a');
    for (int64_t page : leaves) {  // pageno counts from 1
      f.seekp(static_cast<std::streamoff>((page - 1) * page_size + 100));
      f.write(garbage.data(), static_cast<std::streamsize>(garbage.size()));
    }
    ASSERT_TRUE(f.good());
  }
  Database db = open_ok(path);
  EXPECT_TRUE(db.exec("PRAGMA integrity_check").ok()) << "exec cannot tell";
  EXPECT_FALSE(integrity_ok(db));
  auto rows = db.integrity_check();
  if (rows) {
    EXPECT_NE(*rows, std::vector<std::string>{"ok"});
    EXPECT_FALSE(rows->empty());
  }
  auto quick = db.integrity_check(/*quick=*/true);
  EXPECT_TRUE(!quick || *quick != std::vector<std::string>{"ok"}) << "quick_check too";
}

// An entry removed before its run starts leaves no run row.
TEST(Queue, StartingARemovedEntryCreatesNoRun) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const QueueEntry e = *db.queue_add("a", "a.toml", "name = \"a\"", false);
  ASSERT_TRUE(*db.queue_remove(e.id));
  RunRecord rec = sample_run();
  auto started = db.queue_start_run(e.id, rec);
  ASSERT_TRUE(started.ok()) << started.error().message;
  EXPECT_FALSE(started->has_value());
  EXPECT_TRUE(db.runs()->empty()) << "no phantom run";

  const QueueEntry b = *db.queue_add("b", "b.toml", "name = \"b\"", false);
  started = db.queue_start_run(b.id, rec);
  ASSERT_TRUE(started.ok() && started->has_value());
  const RunRecord run = *db.run(**started);
  EXPECT_EQ(run.queue_id, b.id);
  EXPECT_EQ(run.schedule_id, b.schedule_id);
  EXPECT_EQ(run.config_json, rec.config_json);
  const QueueEntry running = **db.queue_entry(b.id);
  EXPECT_EQ(running.state, "running");
  EXPECT_EQ(running.run_id, **started);
  EXPECT_FALSE(db.queue_start_run(b.id, rec)->has_value()) << "started once";
  EXPECT_EQ(db.runs()->size(), 1u);
}

// The HTTP thread adds and removes entries while the control thread starts
// runs, each on its own connection: every run row belongs to the entry it
// started, none is left behind by an entry removed under it.
TEST(Queue, StartRunAgainstConcurrentRemoveLeavesNoPhantomRun) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database api = open_ok(path);
  Database control = open_ok(path);
  constexpr int kEntries = 1500;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  std::atomic<bool> done{false};
  std::atomic<int> removed{0};
  std::thread http([&] {
    for (int i = 0; i < kEntries && std::chrono::steady_clock::now() < deadline; ++i) {
      auto e = api.queue_add(fmt::format("s{}", i), "", "name = \"s\"", false);
      if (!e) continue;
      if (auto r = api.queue_remove(e->id); r && *r) ++removed;
    }
    done = true;
  });
  int started = 0;
  while (!done) {
    auto entries = control.queue_entries();
    if (!entries) continue;
    for (const auto& e : *entries) {
      if (e.state != "queued") continue;
      auto run = control.queue_start_run(e.id, sample_run());
      if (run && *run) {
        ++started;
        ASSERT_TRUE(control.queue_finish(e.id, "completed").ok());
      }
      break;
    }
  }
  http.join();
  auto runs = *control.runs();
  int phantoms = 0;
  for (const auto& r : runs) {
    ASSERT_TRUE(r.queue_id.has_value());
    const auto entry = *control.queue_entry(*r.queue_id);
    if (!entry || entry->run_id != r.id || entry->state == "removed") ++phantoms;
  }
  EXPECT_EQ(phantoms, 0) << runs.size() << " runs, " << started << " started, " << removed
                         << " entries removed";
  EXPECT_EQ(static_cast<int>(runs.size()), started);
  EXPECT_GT(removed.load(), 0) << "the race was exercised";
}

TEST(Queue, SurvivesReopen) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  int64_t id = 0;
  {
    Database db = open_ok(path);
    id = db.queue_add("paper-table1", "p.toml", "[[step]]\ntype = \"soak\"\n", true)->id;
    ASSERT_TRUE(db.set_meta("queue_hold", "stopped by operator").ok());
  }
  Database db = open_ok(path);
  auto entries = *db.queue_entries();
  ASSERT_EQ(entries.size(), 1u);
  EXPECT_EQ(entries[0].id, id);
  EXPECT_EQ(entries[0].toml_text, "[[step]]\ntype = \"soak\"\n");
  EXPECT_EQ(entries[0].source_path, "p.toml");
  EXPECT_EQ(db.meta("queue_hold")->value_or(""), "stopped by operator");
  ASSERT_TRUE(db.delete_meta("queue_hold").ok());
  EXPECT_FALSE(db.meta("queue_hold")->has_value());
}

TEST(Database, CheckpointAndLastSample) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  RunRecord rec;
  rec.schedule_name = "x";
  rec.state = "queued";
  rec.queue_id = 5;
  const int64_t run_id = *db.create_run(rec);
  EXPECT_EQ(db.run(run_id)->queue_id, 5);
  EXPECT_FALSE(db.run(run_id)->checkpoint_wall_unix_s.has_value());
  ASSERT_TRUE(db.set_run_checkpoint(run_id, R"({"t_s":1})", 1.7e9).ok());
  EXPECT_EQ(db.run(run_id)->resume_json, R"({"t_s":1})");
  EXPECT_EQ(db.run(run_id)->checkpoint_wall_unix_s, 1.7e9);

  EXPECT_FALSE(db.last_sample_t_s(run_id)->has_value());
  ASSERT_TRUE(db.exec(fmt::format("INSERT INTO temperature_samples(run_id, t_s) VALUES({0}, 12.5);",
                                  run_id))
                  .ok());
  EXPECT_EQ(*db.last_sample_t_s(run_id), 12.5);
  EXPECT_FALSE(db.last_gyro_sample_t_s(run_id)->has_value()) << "temperatures are not gyro data";
  {
    auto writer = SampleWriter::start(db.path());
    ASSERT_TRUE(writer.ok()) << writer.error().message;
    const GyroSample g{.t_s = 13.25, .rate_dph = 1.5, .seq = 1, .status = 119, .temp_c = 20};
    (*writer)->push_gyro(run_id, std::span(&g, 1));
    ASSERT_TRUE((*writer)->flush().ok());
  }
  EXPECT_EQ(*db.last_sample_t_s(run_id), 13.25);
  EXPECT_EQ(*db.last_gyro_sample_t_s(run_id), 13.25);
  // The control loop's temperatures run ahead of a lagging gyro stream.
  ASSERT_TRUE(db.exec(fmt::format("INSERT INTO temperature_samples(run_id, t_s) VALUES({0}, 90.0);",
                                  run_id))
                  .ok());
  EXPECT_EQ(*db.last_sample_t_s(run_id), 90.0);
  EXPECT_EQ(*db.last_gyro_sample_t_s(run_id), 13.25);
}

// A database written by schema 1 opens with its data and gains schema 2.
TEST(Database, MigratesASchema1Database) {
  TempDir dir;
  const std::string path = dir.file("v1.db");
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    const std::string sql =
        std::string("CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);") +
        internal::migrations()[0].sql +
        "INSERT INTO meta VALUES('schema_version', '1');"
        "INSERT INTO runs(schedule_name, state, started_utc) VALUES('old', 'completed', 'x');";
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK);
    sqlite3_close(raw);
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  auto runs = db.runs();
  ASSERT_TRUE(runs.ok()) << runs.error().message;
  ASSERT_EQ(runs->size(), 1u);
  EXPECT_EQ((*runs)[0].schedule_name, "old");
  EXPECT_FALSE((*runs)[0].queue_id.has_value());
  EXPECT_TRUE(db.queue_add("n", "", "", false).ok());
}

// Schema 6: what versions 1-5 stored in runs.config_json (the config file's
// TOML text) moves to runs.config_toml, readable as before; JSON stays in
// config_json, which refuses anything but JSON from then on.
TEST(Database, MigratesStoredTomlConfigToItsOwnColumn) {
  TempDir dir;
  const std::string path = dir.file("v5.db");
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    std::string sql = "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);";
    for (const auto& m : internal::migrations()) {
      if (m.version <= 5) sql += m.sql;
    }
    sql +=
        "INSERT INTO meta VALUES('schema_version', '5');"
        "INSERT INTO runs(schedule_name, state, started_utc, config_json) VALUES('toml', "
        "'completed', 'x', '[station]\nname = \"lab-1\"\n[analysis]\nma_window = 51\n');"
        "INSERT INTO runs(schedule_name, state, started_utc, config_json) VALUES('json', "
        "'completed', 'x', '{\"station\":{\"name\":\"lab-2\"}}');"
        "INSERT INTO runs(schedule_name, state, started_utc) VALUES('none', 'completed', 'x');";
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(raw);
    sqlite3_close(raw);
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  auto runs = *db.runs();
  ASSERT_EQ(runs.size(), 3u);
  EXPECT_EQ(runs[0].config_json, "");
  EXPECT_EQ(runs[0].config_toml, "[station]\nname = \"lab-1\"\n[analysis]\nma_window = 51\n");
  EXPECT_EQ(runs[1].config_json, R"({"station":{"name":"lab-2"}})");
  EXPECT_EQ(runs[1].config_toml, "");
  EXPECT_EQ(runs[2].config_json, "");
  EXPECT_EQ(runs[2].config_toml, "");
  EXPECT_TRUE(integrity_ok(db));

  RunRecord toml = sample_run();
  toml.config_json = "[station]\nname = \"x\"\n";
  auto refused = db.create_run(toml);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("runs.config_json must be JSON"), std::string::npos)
      << refused.error().message;
  EXPECT_FALSE(db.exec("UPDATE runs SET config_json = 'name = 1' WHERE id = 2").ok());
}

}  // namespace
}  // namespace gyrotherm::storage
