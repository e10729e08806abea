// The record of calibration exports (schema v5, tables `exports` and
// `export_runs`): round trips, one export per nightly slot, a run in at most
// one live nightly export, the runs still to export, finish_export's errors,
// all-or-nothing begin_export, and the migration of a v4 file.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <cmath>
#include <limits>
#include <regex>
#include <string>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "migrations.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::TempDir;

// 2026-03-28 02:00 CET and the night before.
constexpr double kSlot = 1774659600.0;
constexpr double kSlotBefore = 1774573200.0;

int64_t make_export_run(Database& db, const std::string& state = "completed") {
  RunRecord r;
  r.schedule_name = "paper-table1";
  r.state = state;
  r.started_utc = "2026-03-27T18:00:00.000Z";
  auto id = db.create_run(r);
  EXPECT_TRUE(id.ok()) << id.error().message;
  return id.ok() ? *id : 0;
}

ExportRecord nightly(double slot_unix_s, std::vector<int64_t> run_ids) {
  ExportRecord e;
  e.kind = "nightly";
  e.slot_unix_s = slot_unix_s;
  e.directory = "/var/lib/gyrotherm/exports/nightly";
  e.run_ids = std::move(run_ids);
  return e;
}

ExportRecord manual(std::vector<int64_t> run_ids) {
  ExportRecord e;
  e.kind = "manual";
  e.directory = "/home/tech/report";
  e.run_ids = std::move(run_ids);
  return e;
}

int64_t begin_ok(Database& db, const ExportRecord& e) {
  auto id = db.begin_export(e);
  EXPECT_TRUE(id.ok()) << id.error().message;
  return id.ok() ? *id : 0;
}

void finish_ok(Database& db, int64_t id, std::string_view state,
               const std::vector<std::string>& files = {}, std::string_view message = "") {
  Status s = db.finish_export(id, state, files, message);
  EXPECT_TRUE(s.ok()) << s.error().message;
}

ExportRecord read_ok(Database& db, int64_t id) {
  auto e = db.export_record(id);
  EXPECT_TRUE(e.ok()) << e.error().message;
  if (!e.ok() || !e->has_value()) {
    ADD_FAILURE() << "no export " << id;
    return {};
  }
  return **e;
}

std::vector<int64_t> not_exported(Database& db) {
  auto ids = db.runs_not_exported();
  EXPECT_TRUE(ids.ok()) << ids.error().message;
  return ids.ok() ? *ids : std::vector<int64_t>{-1};
}

// The call fails permanently with a message that names the file and holds
// every one of `parts`.
template <typename R>
void expect_error(const R& result, const std::string& path, std::vector<std::string> parts) {
  ASSERT_FALSE(result.ok());
  const Error& e = result.error();
  EXPECT_FALSE(e.transient) << e.message;
  EXPECT_NE(e.message.find(path), std::string::npos) << e.message;
  for (const std::string& part : parts) {
    EXPECT_NE(e.message.find(part), std::string::npos) << "'" << part << "' in: " << e.message;
  }
}

long long count(Database& db, const std::string& table) {
  return query_int(db.handle(), "SELECT count(*) FROM " + table);
}

const std::regex kUtc(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z)");

TEST(Exports, RoundTripOfBothKinds) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const int64_t r1 = make_export_run(db), r2 = make_export_run(db), r3 = make_export_run(db);

  ExportRecord n = nightly(kSlot, {r3, r1, r3});  // unordered, a duplicate
  n.slot_local = "2026-03-28 02:00 CET";
  n.started_utc = "2026-03-28T01:00:00.250Z";
  n.state = "done";            // ignored: a new export is writing
  n.files = {"ignored.html"};  // set by finish_export
  n.finished_utc = "ignored";
  const int64_t nid = begin_ok(db, n);

  ExportRecord got = read_ok(db, nid);
  EXPECT_EQ(got.id, nid);
  EXPECT_EQ(got.kind, "nightly");
  EXPECT_EQ(got.slot_unix_s, kSlot);
  EXPECT_EQ(got.slot_local, "2026-03-28 02:00 CET");
  EXPECT_EQ(got.state, "writing");
  EXPECT_EQ(got.directory, n.directory);
  EXPECT_EQ(got.run_ids, (std::vector<int64_t>{r1, r3}));
  EXPECT_TRUE(got.files.empty());
  EXPECT_EQ(got.started_utc, "2026-03-28T01:00:00.250Z");
  EXPECT_EQ(got.finished_utc, "");
  EXPECT_EQ(got.message, "");
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM exports WHERE finished_utc IS NULL AND "
                      "files_json = '[]'"),
            1);

  const std::vector<std::string> files = {"report.html", "stats/table1.csv", "coefficients.json",
                                          "coefficients.h", "Résumé ünïcode.txt"};
  finish_ok(db, nid, "done", files, "2 runs, 5 files");
  got = read_ok(db, nid);
  EXPECT_EQ(got.state, "done");
  EXPECT_EQ(got.files, files);
  EXPECT_EQ(got.message, "2 runs, 5 files");
  EXPECT_TRUE(std::regex_match(got.finished_utc, kUtc)) << got.finished_utc;
  EXPECT_EQ(got.run_ids, (std::vector<int64_t>{r1, r3}));
  // The files are a JSON array that sqlite3 can read.
  EXPECT_EQ(query_text(db.handle(), "SELECT json_extract(files_json, '$[1]') FROM exports"),
            "stats/table1.csv");

  ExportRecord m = manual({r2});
  m.message = "for the customer";
  const int64_t mid = begin_ok(db, m);
  EXPECT_GT(mid, nid);
  got = read_ok(db, mid);
  EXPECT_EQ(got.kind, "manual");
  EXPECT_FALSE(got.slot_unix_s.has_value());
  EXPECT_EQ(got.slot_local, "");
  EXPECT_EQ(got.state, "writing");
  EXPECT_EQ(got.run_ids, (std::vector<int64_t>{r2}));
  EXPECT_TRUE(std::regex_match(got.started_utc, kUtc)) << got.started_utc;  // stamped now
  EXPECT_EQ(got.message, "for the customer");
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM exports WHERE kind = 'manual' AND "
                      "slot_unix_s IS NULL"),
            1);
  finish_ok(db, mid, "failed", {}, "disk full");
  got = read_ok(db, mid);
  EXPECT_EQ(got.state, "failed");
  EXPECT_TRUE(got.files.empty());
  EXPECT_EQ(got.message, "disk full");

  // Newest first, from another (read-only) connection too.
  auto ro = Database::open_read_only(path);
  ASSERT_TRUE(ro.ok()) << ro.error().message;
  auto all = ro->exports();
  ASSERT_TRUE(all.ok()) << all.error().message;
  ASSERT_EQ(all->size(), 2u);
  EXPECT_EQ((*all)[0].id, mid);
  EXPECT_EQ((*all)[0].run_ids, (std::vector<int64_t>{r2}));
  EXPECT_EQ((*all)[1].id, nid);
  EXPECT_EQ((*all)[1].files, files);
  EXPECT_EQ((*all)[1].run_ids, (std::vector<int64_t>{r1, r3}));

  auto none = db.export_record(mid + 100);
  ASSERT_TRUE(none.ok()) << none.error().message;
  EXPECT_FALSE(none->has_value());
}

TEST(Exports, EmptyDatabaseHasNoExports) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  auto all = db.exports();
  ASSERT_TRUE(all.ok()) << all.error().message;
  EXPECT_TRUE(all->empty());
  EXPECT_TRUE(not_exported(db).empty());
  auto last = db.last_nightly_slot_unix_s();
  ASSERT_TRUE(last.ok()) << last.error().message;
  EXPECT_FALSE(last->has_value());
}

TEST(Exports, ANightlySlotIsExportedOnce) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const int64_t r1 = make_export_run(db), r2 = make_export_run(db);
  ExportRecord first = nightly(kSlot, {r1});
  first.slot_local = "2026-03-28 02:00 CET";
  const int64_t id = begin_ok(db, first);
  finish_ok(db, id, "done", {"report.html"}, "ok");
  const ExportRecord before = read_ok(db, id);

  // Whatever the state of the first, and with other runs.
  for (const char* state : {"done", "failed"}) {
    SCOPED_TRACE(state);
    if (std::string(state) == "failed") {
      ASSERT_TRUE(db.exec("UPDATE exports SET state = 'failed'").ok());
    }
    ExportRecord again = nightly(kSlot, {r2});
    again.slot_local = "2026-03-28 02:00 CET";
    expect_error(db.begin_export(again), path,
                 {"slot 1774659600 (2026-03-28 02:00 CET)", "already has export 1", state});
    EXPECT_EQ(count(db, "exports"), 1);
    EXPECT_EQ(count(db, "export_runs"), 1);
  }
  ExportRecord after = read_ok(db, id);
  EXPECT_EQ(after.slot_unix_s, before.slot_unix_s);
  EXPECT_EQ(after.run_ids, before.run_ids);
  EXPECT_EQ(after.files, before.files);
  EXPECT_EQ(after.started_utc, before.started_utc);
  EXPECT_EQ(after.finished_utc, before.finished_utc);

  // Other slots and manual exports are not affected.
  EXPECT_GT(begin_ok(db, nightly(kSlotBefore, {r2})), id);
  EXPECT_GT(begin_ok(db, manual({r1})), id);

  // The unique index holds for sqlite3 users too.
  EXPECT_FALSE(db.exec("INSERT INTO exports(kind, slot_unix_s, state, directory, started_utc) "
                       "VALUES('nightly', 1774659600.0, 'writing', '/x', 'now')")
                   .ok());
}

TEST(Exports, ARunIsInOneLiveNightlyExport) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const int64_t a = make_export_run(db), b = make_export_run(db), c = make_export_run(db);

  const int64_t held = begin_ok(db, nightly(kSlotBefore, {a, b}));
  // Writing: refused for another nightly export, naming the run and export.
  expect_error(db.begin_export(nightly(kSlot, {c, b})), path,
               {"run 2 is already in nightly export 1", "slot 1774573200", "writing"});
  finish_ok(db, held, "done");
  expect_error(db.begin_export(nightly(kSlot, {a})), path,
               {"run 1 is already in nightly export 1", "done"});
  EXPECT_EQ(count(db, "exports"), 1);
  // A manual export may take any run, and does not hold it.
  const int64_t m = begin_ok(db, manual({a, b, c}));
  EXPECT_EQ(read_ok(db, m).run_ids, (std::vector<int64_t>{a, b, c}));
  const int64_t c_nightly = begin_ok(db, nightly(kSlot, {c}));
  EXPECT_EQ(read_ok(db, c_nightly).run_ids, (std::vector<int64_t>{c}));

  // A failed nightly export lets go of its runs.
  const int64_t d = make_export_run(db);
  const int64_t failed = begin_ok(db, nightly(kSlot + 86400, {d}));
  expect_error(db.begin_export(nightly(kSlot + 2 * 86400, {d})), path,
               {"run 4 is already in nightly export", std::to_string(failed)});
  finish_ok(db, failed, "failed", {}, "disk full");
  const int64_t retry = begin_ok(db, nightly(kSlot + 2 * 86400, {d}));
  EXPECT_EQ(read_ok(db, retry).run_ids, (std::vector<int64_t>{d}));
  // ...and the retry now holds it.
  expect_error(db.begin_export(nightly(kSlot + 3 * 86400, {d})), path,
               {"run 4 is already in nightly export " + std::to_string(retry)});
}

TEST(Exports, RunsNotExported) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t done_run = make_export_run(db);
  const int64_t failed_run = make_export_run(db, "failed");
  const int64_t running = make_export_run(db, "acquiring");
  const int64_t writing_run = make_export_run(db);
  const int64_t in_failed_export = make_export_run(db);
  const int64_t manual_only = make_export_run(db);
  const int64_t fresh = make_export_run(db);
  const int64_t interrupted = make_export_run(db, "interrupted");
  EXPECT_EQ(not_exported(db),
            (std::vector<int64_t>{done_run, writing_run, in_failed_export, manual_only, fresh}));

  finish_ok(db, begin_ok(db, nightly(kSlotBefore, {done_run, failed_run})), "done");
  begin_ok(db, nightly(kSlot, {writing_run}));  // still writing
  finish_ok(db, begin_ok(db, nightly(kSlot + 86400, {in_failed_export, running})), "failed");
  finish_ok(db, begin_ok(db, manual({manual_only, interrupted})), "done");
  begin_ok(db, manual({fresh}));
  EXPECT_EQ(not_exported(db), (std::vector<int64_t>{in_failed_export, manual_only, fresh}));

  // A run that completes later (it was running) is still to export.
  ASSERT_TRUE(db.set_run_state(running, "completed", true).ok());
  EXPECT_EQ(not_exported(db),
            (std::vector<int64_t>{running, in_failed_export, manual_only, fresh}));
}

TEST(Exports, LastNightlySlotIsTheLatestOfAnyState) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const auto last = [&]() -> std::optional<double> {
    auto s = db.last_nightly_slot_unix_s();
    EXPECT_TRUE(s.ok()) << s.error().message;
    return s.ok() ? *s : std::optional<double>(-1.0);
  };
  EXPECT_EQ(last(), std::nullopt);
  begin_ok(db, manual({}));
  EXPECT_EQ(last(), std::nullopt);
  const int64_t later = begin_ok(db, nightly(kSlot + 0.5, {}));
  EXPECT_EQ(last(), kSlot + 0.5);
  finish_ok(db, later, "failed", {}, "disk full");
  EXPECT_EQ(last(), kSlot + 0.5);
  // An earlier slot caught up afterwards does not move it back.
  finish_ok(db, begin_ok(db, nightly(kSlotBefore, {})), "done");
  EXPECT_EQ(last(), kSlot + 0.5);
  finish_ok(db, begin_ok(db, nightly(kSlot + 86400, {})), "done");
  EXPECT_EQ(last(), kSlot + 86400);
}

TEST(Exports, BeginExportRefusesBadRecords) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const int64_t run = make_export_run(db);

  ExportRecord e = nightly(kSlot, {run});
  e.kind = "weekly";
  expect_error(db.begin_export(e), path, {"kind 'weekly'"});
  e.kind = "";
  expect_error(db.begin_export(e), path, {"kind ''"});

  e = nightly(kSlot, {run});
  e.slot_unix_s.reset();
  expect_error(db.begin_export(e), path, {"nightly export needs its slot"});
  for (double bad :
       {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
    e.slot_unix_s = bad;
    expect_error(db.begin_export(e), path, {"slot_unix_s is", "finite"});
  }

  e = manual({run});
  e.slot_unix_s = kSlot;
  expect_error(db.begin_export(e), path, {"manual export has no slot"});

  e = nightly(kSlot, {run});
  e.directory = "";
  expect_error(db.begin_export(e), path, {"directory is empty"});
  e = manual({run});
  e.directory = "";
  expect_error(db.begin_export(e), path, {"directory is empty"});

  expect_error(db.begin_export(nightly(kSlot, {run, 42})), path, {"no run with id 42"});
  expect_error(db.begin_export(manual({-3, run})), path, {"no run with id -3"});

  EXPECT_EQ(count(db, "exports"), 0);
  EXPECT_EQ(count(db, "export_runs"), 0);
  EXPECT_EQ(not_exported(db), (std::vector<int64_t>{run}));
}

// A begin_export that fails after its exports row was inserted leaves
// nothing behind: the slot stays free, the runs unexported.
TEST(Exports, AFailedBeginExportLeavesNoRows) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const int64_t a = make_export_run(db), b = make_export_run(db);
  ASSERT_TRUE(db.exec("CREATE TEMP TRIGGER refuse_b BEFORE INSERT ON export_runs "
                      "WHEN NEW.run_id = 2 BEGIN SELECT RAISE(ABORT, 'no run 2 today'); END")
                  .ok());
  expect_error(db.begin_export(nightly(kSlot, {a, b})), path,
               {"nightly export of slot 1774659600", "no run 2 today"});
  EXPECT_EQ(count(db, "exports"), 0);
  EXPECT_EQ(count(db, "export_runs"), 0);
  EXPECT_EQ(not_exported(db), (std::vector<int64_t>{a, b}));
  auto last = db.last_nightly_slot_unix_s();
  ASSERT_TRUE(last.ok()) << last.error().message;
  EXPECT_FALSE(last->has_value());

  // No transaction was left open: the same slot works once the cause is gone.
  ASSERT_TRUE(db.exec("DROP TRIGGER refuse_b").ok());
  const int64_t id = begin_ok(db, nightly(kSlot, {a, b}));
  EXPECT_EQ(read_ok(db, id).run_ids, (std::vector<int64_t>{a, b}));
  EXPECT_EQ(not_exported(db), std::vector<int64_t>{});
}

TEST(Exports, FinishExportErrors) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const int64_t run = make_export_run(db);
  const int64_t id = begin_ok(db, nightly(kSlot, {run}));

  expect_error(db.finish_export(99, "done", {}, ""), path, {"export 99", "no such export"});
  for (const char* state : {"writing", "aborted", ""}) {
    expect_error(db.finish_export(id, state, {}, ""), path,
                 {"export 1 as '" + std::string(state) + "'", "'done' or 'failed'"});
  }
  expect_error(db.finish_export(id, "done", {"report.html", ""}, ""), path, {"files[1] is empty"});
  expect_error(db.finish_export(id, "done", {"/tmp/report.html"}, ""), path,
               {"files[0] '/tmp/report.html' is absolute"});
  expect_error(db.finish_export(id, "done", {std::string("bad\xff.html")}, ""), path,
               {"not valid UTF-8"});
  ExportRecord still = read_ok(db, id);
  EXPECT_EQ(still.state, "writing");
  EXPECT_EQ(still.finished_utc, "");
  EXPECT_TRUE(still.files.empty());

  // Finished once: a second finish is refused and changes nothing (a failed
  // export turned done would hold runs another export has taken since).
  finish_ok(db, id, "failed", {}, "disk full");
  const ExportRecord failed = read_ok(db, id);
  expect_error(db.finish_export(id, "done", {"report.html"}, "ok"), path,
               {"export 1", "already failed", failed.finished_utc});
  const ExportRecord after = read_ok(db, id);
  EXPECT_EQ(after.state, "failed");
  EXPECT_EQ(after.message, "disk full");
  EXPECT_TRUE(after.files.empty());
}

TEST(Exports, CorruptFilesJsonIsAnErrorNotACrash) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const int64_t id = begin_ok(db, manual({}));
  ASSERT_TRUE(db.exec("UPDATE exports SET files_json = '{\"a\": 1}'").ok());
  expect_error(db.exports(), path, {"export " + std::to_string(id), "files_json"});
  ASSERT_TRUE(db.exec("UPDATE exports SET files_json = '[1]'").ok());
  expect_error(db.export_record(id), path, {"element 0 is not a string"});
}

// The documented query (docs/storage.md, "Example queries"): which runs were
// in which export.
TEST(Exports, DocumentedQueryListsRunsPerExport) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t a = make_export_run(db), b = make_export_run(db);
  ExportRecord n = nightly(kSlot, {a, b});
  n.slot_local = "2026-03-28 02:00 CET";
  finish_ok(db, begin_ok(db, n), "done", {"report.html"});
  begin_ok(db, manual({b}));
  const std::string sql = R"sql(
SELECT e.id AS export, e.kind, e.slot_local, e.state, e.finished_utc,
       group_concat(r.run_id, ',') AS runs
FROM exports e LEFT JOIN export_runs r ON r.export_id = e.id
GROUP BY e.id ORDER BY e.id DESC;
)sql";
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(db.handle(), sql.c_str(), -1, &st, nullptr), SQLITE_OK)
      << sqlite3_errmsg(db.handle());
  std::vector<std::string> rows;
  while (sqlite3_step(st) == SQLITE_ROW) {
    const auto text = [&](int c) {
      const unsigned char* p = sqlite3_column_text(st, c);
      return p != nullptr ? std::string(reinterpret_cast<const char*>(p)) : std::string("NULL");
    };
    rows.push_back(text(0) + " " + text(1) + " " + text(3) + " " + text(5));
  }
  sqlite3_finalize(st);
  EXPECT_EQ(rows, (std::vector<std::string>{"2 manual writing 2", "1 nightly done 1,2"}));

  EXPECT_EQ(query_text(db.handle(),
                       "SELECT group_concat(e.id || ':' || e.kind, ' ') FROM export_runs r "
                       "JOIN exports e ON e.id = r.export_id WHERE r.run_id = 2"),
            "1:nightly 2:manual");
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT e.directory || '/' || f.value AS file FROM exports e, "
                       "json_each(e.files_json) f WHERE e.id = 1 ORDER BY f.key"),
            "/var/lib/gyrotherm/exports/nightly/report.html");
  const int64_t c = make_export_run(db);
  EXPECT_EQ(query_int(db.handle(), R"sql(
SELECT id FROM runs
WHERE state = 'completed' AND id NOT IN (
  SELECT r.run_id FROM export_runs r JOIN exports e ON e.id = r.export_id
  WHERE e.kind = 'nightly' AND e.state IN ('writing', 'done'))
ORDER BY id;
)sql"),
            c);
}

// A file written by schema 4 opens, gains the two (empty) export tables with
// their indexes, keeps every row, and its old runs can be exported.
TEST(Exports, MigratesASchema4DatabaseKeepingItsRows) {
  TempDir dir;
  const std::string path = dir.file("v4.db");
  ASSERT_GE(internal::migrations().size(), 5u);
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    std::string sql = "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);";
    for (int v = 0; v < 4; ++v) sql += internal::migrations()[v].sql;
    sql +=
        "INSERT INTO meta VALUES('schema_version', '4');"
        "INSERT INTO meta VALUES('created_utc', '2026-01-01T00:00:00.000Z');"
        "INSERT INTO runs(schedule_name, state, started_utc) "
        "  VALUES('old', 'completed', '2026-01-02T00:00:00.000Z');"
        "INSERT INTO runs(schedule_name, state, started_utc) "
        "  VALUES('old', 'failed', '2026-01-03T00:00:00.000Z');"
        "INSERT INTO segments(run_id, idx, kind, setpoint_c, state) "
        "  VALUES(1, 0, 'soak', -40, 'completed');"
        "INSERT INTO segment_stats(segment_id, run_id, segment_index, setpoint_c, n, "
        "  bias_mean_dph, computed_utc) VALUES(1, 1, 0, -40, 7200, 1.25, 'x');"
        "INSERT INTO gyro_samples VALUES(1, 0.5, 3, 0.75, 119, 21);"
        "INSERT INTO allan(run_id, segment_id, segment_index, taus, n_samples, curve_json, "
        "  inputs_json, computed_utc) VALUES(1, 1, 0, 'octave', 10, "
        "  '{\"tau_s\":[1],\"adev_dph\":[0.5],\"adev_lo_dph\":[0.4],\"adev_hi_dph\":[0.6]}', "
        "  '{}', 'z');";
    char* err = nullptr;
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, &err), SQLITE_OK) << err;
    sqlite3_close(raw);
  }
  {
    auto ro = Database::open_read_only(path);
    ASSERT_FALSE(ro.ok());
    EXPECT_NE(ro.error().message.find(
                  fmt::format("schema version 4, older than this build's {}", kSchemaVersion)),
              std::string::npos)
        << ro.error().message;
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  for (const char* table : {"segments", "segment_stats", "allan"}) {
    EXPECT_EQ(count(db, table), 1) << table;
  }
  EXPECT_EQ(*db.count_gyro_samples(1), 1);  // moved into chunks (v9)
  EXPECT_EQ(count(db, "runs"), 2);
  EXPECT_EQ(count(db, "exports"), 0);
  EXPECT_EQ(count(db, "export_runs"), 0);
  EXPECT_EQ(query_text(db.handle(), "SELECT value FROM meta WHERE key = 'created_utc'"),
            "2026-01-01T00:00:00.000Z");
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT group_concat(name, ' ') FROM (SELECT name FROM sqlite_master "
                       "WHERE type = 'index' AND tbl_name IN ('exports', 'export_runs') AND "
                       "sql IS NOT NULL ORDER BY name)"),
            "export_runs_by_run exports_nightly_slot");
  auto allan = db.allan(1);
  ASSERT_TRUE(allan.ok()) << allan.error().message;
  ASSERT_EQ(allan->size(), 1u);
  EXPECT_EQ((*allan)[0].adev_dph, std::vector<double>{0.5});

  // Every completed run of the old file is still to export, and can be.
  EXPECT_EQ(not_exported(db), std::vector<int64_t>{1});
  finish_ok(db, begin_ok(db, nightly(kSlot, {1})), "done", {"report.html"});
  EXPECT_TRUE(not_exported(db).empty());
  // Opening again does not migrate twice.
  Database again = open_ok(path);
  EXPECT_EQ(*again.schema_version(), kSchemaVersion);
  EXPECT_EQ(count(again, "exports"), 1);
}

}  // namespace
}  // namespace gyrotherm::storage
