// The `allan` table (schema v4): Database::put_allan / allan round trips,
// replacement by (run, step, taus), what cannot be stored, the migration of
// a v3 file, and reads from other connections and with sqlite3's json1.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "migrations.h"
#include "numbers.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::TempDir;

using gyrotherm::testing::kNaN;
constexpr double kInf = std::numeric_limits<double>::infinity();

int64_t make_run(Database& db) {
  RunRecord r;
  r.schedule_name = "paper-table1";
  r.state = "completed";
  r.started_utc = "2026-11-21T05:38:43.120Z";
  auto id = db.create_run(r);
  EXPECT_TRUE(id.ok()) << id.error().message;
  return id.ok() ? *id : 0;
}

int64_t make_segment(Database& db, int64_t run_id, int index) {
  SegmentRecord s;
  s.run_id = run_id;
  s.index = index;
  s.kind = "soak";
  s.label = "soak";
  s.setpoint_c = 20;
  s.state = "completed";
  auto id = db.create_segment(s);
  EXPECT_TRUE(id.ok()) << id.error().message;
  return id.ok() ? *id : 0;
}

// Every field set, with values whose decimal form is not short: the JSON
// curve must give back the same doubles bit for bit.
AllanRecord full_record(int64_t run_id, int64_t segment_id, int segment_index) {
  AllanRecord a;
  a.run_id = run_id;
  a.segment_id = segment_id;
  a.segment_index = segment_index;
  a.t_from_s = 1234.0009765625;
  a.t_to_s = 8434.1;
  a.taus = "octave";
  a.tau0_s = 0.001;
  a.n_samples = 7'200'000;
  a.tau_s = {0.001, 0.002, 1.0 / 3.0, 4096.000000000001, 1e300};
  a.adev_dph = {0.1, 5e-324, 2.2250738585072014e-308, 0.0031622776601683794,
                1.7976931348623157e308};
  a.adev_lo_dph = {0.09, 0.0, -0.0, 0.0029999999999999996, 1e-5};
  a.adev_hi_dph = {0.11, 1e-17, 123456789.12345679, 0.0033, 7.0};
  a.angle_random_walk_dprh = 0.0123456789012345;
  a.bias_instability_dph = 0.0047619047619047615;
  a.bias_instability_tau_s = 512.0;
  a.rate_random_walk_dphprh = 0.98765432109876;
  a.bias_instability_method = "minimum / 0.664";
  a.inputs_json = R"({"windows":[[1234.0009765625,8434.1]],"taus":"octave"})";
  a.computed_utc = "2026-11-21T07:00:00.000Z";
  return a;
}

void expect_same(const AllanRecord& got, const AllanRecord& want) {
  EXPECT_EQ(got.run_id, want.run_id);
  EXPECT_EQ(got.segment_id, want.segment_id);
  EXPECT_EQ(got.segment_index, want.segment_index);
  EXPECT_EQ(got.t_from_s, want.t_from_s);
  EXPECT_EQ(got.t_to_s, want.t_to_s);
  EXPECT_EQ(got.taus, want.taus);
  EXPECT_EQ(got.tau0_s, want.tau0_s);
  EXPECT_EQ(got.n_samples, want.n_samples);
  EXPECT_EQ(got.tau_s, want.tau_s);
  EXPECT_EQ(got.adev_dph, want.adev_dph);
  EXPECT_EQ(got.adev_lo_dph, want.adev_lo_dph);
  EXPECT_EQ(got.adev_hi_dph, want.adev_hi_dph);
  EXPECT_EQ(got.angle_random_walk_dprh, want.angle_random_walk_dprh);
  EXPECT_EQ(got.bias_instability_dph, want.bias_instability_dph);
  EXPECT_EQ(got.bias_instability_tau_s, want.bias_instability_tau_s);
  EXPECT_EQ(got.rate_random_walk_dphprh, want.rate_random_walk_dphprh);
  EXPECT_EQ(got.bias_instability_method, want.bias_instability_method);
  EXPECT_EQ(got.inputs_json, want.inputs_json);
  EXPECT_EQ(got.computed_utc, want.computed_utc);
}

TEST(Allan, RoundTripOfEveryField) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = make_run(db);
  const AllanRecord full = full_record(run, make_segment(db, run, 2), 2);
  auto id = db.put_allan(full);
  ASSERT_TRUE(id.ok()) << id.error().message;

  // Unset noise terms, no segment, no inputs, no time stamp, an empty curve.
  AllanRecord sparse;
  sparse.run_id = run;
  sparse.segment_index = 5;
  sparse.taus = "decade";
  sparse.tau0_s = 1.0;
  sparse.n_samples = 1;
  auto sparse_id = db.put_allan(sparse);
  ASSERT_TRUE(sparse_id.ok()) << sparse_id.error().message;
  EXPECT_NE(*id, *sparse_id);

  auto rows = db.allan(run);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->size(), 2u);
  EXPECT_EQ((*rows)[0].id, *id);
  expect_same((*rows)[0], full);

  const AllanRecord& s = (*rows)[1];
  EXPECT_EQ(s.id, *sparse_id);
  EXPECT_EQ(s.segment_id, 0);
  EXPECT_TRUE(s.tau_s.empty() && s.adev_dph.empty() && s.adev_lo_dph.empty() &&
              s.adev_hi_dph.empty());
  EXPECT_FALSE(s.angle_random_walk_dprh.has_value());
  EXPECT_FALSE(s.bias_instability_dph.has_value());
  EXPECT_FALSE(s.bias_instability_tau_s.has_value());
  EXPECT_FALSE(s.rate_random_walk_dphprh.has_value());
  EXPECT_EQ(s.bias_instability_method, "minimum / 0.664");
  EXPECT_EQ(s.inputs_json, "{}");
  EXPECT_EQ(s.computed_utc.size(), 24u) << s.computed_utc;  // stamped now

  // In SQL: unset values are NULL, not 0.
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM allan WHERE segment_index = 5 AND segment_id IS NULL "
                      "AND angle_random_walk_dprh IS NULL AND bias_instability_dph IS NULL AND "
                      "bias_instability_tau_s IS NULL AND rate_random_walk_dphprh IS NULL"),
            1);
}

TEST(Allan, ReplacesTheSameRunStepAndTausOnly) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = make_run(db);
  const int64_t other_run = make_run(db);
  const int64_t seg = make_segment(db, run, 1);
  AllanRecord a = full_record(run, seg, 1);
  auto first = db.put_allan(a);
  ASSERT_TRUE(first.ok()) << first.error().message;

  // Recomputed: the row is replaced in place (same id), every column updated.
  AllanRecord b = a;
  b.t_to_s = 9000.5;
  b.tau0_s = 0.002;
  b.n_samples = 42;
  b.tau_s = {0.002, 0.004};
  b.adev_dph = {0.2, 0.1};
  b.adev_lo_dph = {0.19, 0.09};
  b.adev_hi_dph = {0.21, 0.11};
  b.angle_random_walk_dprh.reset();
  b.bias_instability_dph = 0.5;
  b.bias_instability_tau_s.reset();
  b.rate_random_walk_dphprh.reset();
  b.bias_instability_method = "other";
  b.segment_id = 0;
  b.inputs_json = R"({"again":true})";
  b.computed_utc = "2026-11-22T00:00:00.000Z";
  auto second = db.put_allan(b);
  ASSERT_TRUE(second.ok()) << second.error().message;
  EXPECT_EQ(*second, *first);
  auto rows = db.allan(run);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->size(), 1u);
  expect_same((*rows)[0], b);

  // Another tau set, another step, another run: rows of their own.
  AllanRecord c = b;
  c.taus = "all";
  AllanRecord d = b;
  d.segment_index = 2;
  AllanRecord e = b;
  e.run_id = other_run;
  for (const AllanRecord* r : {&c, &d, &e}) {
    auto id = db.put_allan(*r);
    ASSERT_TRUE(id.ok()) << id.error().message;
    EXPECT_NE(*id, *first);
  }
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM allan"), 4);
  rows = db.allan(run);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->size(), 3u);
  expect_same((*rows)[0], c);  // step 1, 'all'
  expect_same((*rows)[1], b);  // step 1, 'octave'
  expect_same((*rows)[2], d);  // step 2
}

TEST(Allan, OrderedByStepThenTausAndOnlyTheRunAsked) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = make_run(db);
  const int64_t other = make_run(db);
  const std::pair<int, const char*> keys[] = {{3, "octave"}, {0, "octave"}, {10, "all"},
                                              {3, "all"},    {0, "decade"}, {2, "octave"}};
  for (const auto& [index, taus] : keys) {
    AllanRecord a = full_record(run, 0, index);
    a.taus = taus;
    ASSERT_TRUE(db.put_allan(a).ok());
    a.run_id = other;
    ASSERT_TRUE(db.put_allan(a).ok());
  }
  auto rows = db.allan(run);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  std::vector<std::pair<int, std::string>> got;
  for (const AllanRecord& r : *rows) {
    EXPECT_EQ(r.run_id, run);
    got.emplace_back(r.segment_index, r.taus);
  }
  const std::vector<std::pair<int, std::string>> want = {
      {0, "decade"}, {0, "octave"}, {2, "octave"}, {3, "all"}, {3, "octave"}, {10, "all"}};
  EXPECT_EQ(got, want);
  auto none = db.allan(other + 1);
  ASSERT_TRUE(none.ok()) << none.error().message;
  EXPECT_TRUE(none->empty());
}

// A rejected record names the run, the step and the field, and stores nothing.
void expect_rejected(Database& db, const AllanRecord& a, const std::string& field) {
  auto id = db.put_allan(a);
  ASSERT_FALSE(id.ok()) << "stored a record with a bad " << field;
  const std::string& msg = id.error().message;
  EXPECT_NE(msg.find(field), std::string::npos) << msg;
  EXPECT_NE(
      msg.find("run " + std::to_string(a.run_id) + " step " + std::to_string(a.segment_index)),
      std::string::npos)
      << msg;
  EXPECT_NE(msg.find(db.path()), std::string::npos) << msg;
  EXPECT_FALSE(id.error().transient);
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM allan"), 0) << msg;
}

TEST(Allan, RejectsNonFiniteNumbersNamingFieldAndIndex) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = make_run(db);
  const AllanRecord good = full_record(run, 0, 3);

  AllanRecord a = good;
  a.adev_lo_dph[2] = kNaN;
  expect_rejected(db, a, "adev_lo_dph[2] is nan");
  a = good;
  a.tau_s[0] = kInf;
  expect_rejected(db, a, "tau_s[0] is inf");
  a = good;
  a.adev_hi_dph[4] = -kInf;
  expect_rejected(db, a, "adev_hi_dph[4] is -inf");
  a = good;
  a.adev_dph[1] = kNaN;
  expect_rejected(db, a, "adev_dph[1]");

  // Noise terms: unset is fine, set to NaN/inf is a mistake upstream.
  a = good;
  a.bias_instability_dph = kNaN;
  expect_rejected(db, a, "bias_instability_dph is nan");
  a = good;
  a.rate_random_walk_dphprh = kInf;
  expect_rejected(db, a, "rate_random_walk_dphprh is inf");
  a = good;
  a.tau0_s = kNaN;
  expect_rejected(db, a, "tau0_s is nan");

  ASSERT_TRUE(db.put_allan(good).ok());
}

TEST(Allan, RejectsCurveArraysOfDifferentLengths) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = make_run(db);
  const AllanRecord good = full_record(run, 0, 1);

  AllanRecord a = good;
  a.adev_hi_dph.pop_back();
  expect_rejected(db, a, "adev_hi_dph has 4 values but tau_s has 5");
  a = good;
  a.adev_dph.push_back(1.0);
  expect_rejected(db, a, "adev_dph has 6 values but tau_s has 5");
  a = good;
  a.tau_s.clear();
  expect_rejected(db, a, "adev_dph has 5 values but tau_s has 0");
  a = good;
  a.adev_lo_dph.clear();
  expect_rejected(db, a, "adev_lo_dph has 0 values");

  a = good;
  a.inputs_json = "{windows: 1";
  expect_rejected(db, a, "inputs_json");
  a = good;
  a.taus = "";
  expect_rejected(db, a, "taus");
}

TEST(Allan, UnknownRunOrSegmentIsAnError) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = make_run(db);
  auto no_run = db.put_allan(full_record(run + 7, 0, 0));
  ASSERT_FALSE(no_run.ok());
  EXPECT_NE(no_run.error().message.find("run " + std::to_string(run + 7)), std::string::npos)
      << no_run.error().message;
  EXPECT_NE(no_run.error().message.find("FOREIGN KEY"), std::string::npos)
      << no_run.error().message;
  EXPECT_FALSE(db.put_allan(full_record(run, 999, 0)).ok());
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM allan"), 0);
}

// The curve is valid JSON that sqlite3's json functions read as documented
// in docs/storage.md.
TEST(Allan, CurveIsReadableWithJsonEach) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = make_run(db);
  ASSERT_TRUE(db.put_allan(full_record(run, 0, 4)).ok());
  EXPECT_EQ(query_int(db.handle(), "SELECT json_valid(curve_json) FROM allan"), 1);
  EXPECT_EQ(query_text(db.handle(), "SELECT substr(curve_json, 1, 23) FROM allan"),
            R"({"tau_s":[0.001,0.002,0)");
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT group_concat(json_type(curve_json, '$.' || k.value), ',') FROM "
                       "allan, json_each('[\"tau_s\",\"adev_dph\",\"adev_lo_dph\","
                       "\"adev_hi_dph\"]') k"),
            "array,array,array,array");
  const std::string sql = R"sql(
SELECT group_concat(printf('%g:%g:%g:%g', t.value, a.value, lo.value, hi.value), ' ')
FROM allan,
     json_each(allan.curve_json, '$.tau_s') t
     JOIN json_each(allan.curve_json, '$.adev_dph') a ON a.key = t.key
     JOIN json_each(allan.curve_json, '$.adev_lo_dph') lo ON lo.key = t.key
     JOIN json_each(allan.curve_json, '$.adev_hi_dph') hi ON hi.key = t.key
WHERE allan.run_id = 1 AND allan.segment_index = 4 AND allan.taus = 'octave'
ORDER BY t.key)sql";
  EXPECT_EQ(query_text(db.handle(), sql),
            "0.001:0.1:0.09:0.11 0.002:4.94066e-324:0:1e-17 0.333333:2.22507e-308:0:1.23457e+08 "
            "4096:0.00316228:0.003:0.0033 1e+300:1.79769e+308:1e-05:7");
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT json_array_length(curve_json, '$.adev_hi_dph') FROM "
                      "allan"),
            5);
}

TEST(Allan, CorruptedCurveIsAnErrorNamingTheRow) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = make_run(db);
  auto id = db.put_allan(full_record(run, 0, 0));
  ASSERT_TRUE(id.ok()) << id.error().message;
  ASSERT_TRUE(db.exec(R"(UPDATE allan SET curve_json = '{"tau_s":[1,2],"adev_dph":[1],)"
                      R"("adev_lo_dph":[1,2],"adev_hi_dph":[1,2]}')")
                  .ok());
  auto rows = db.allan(run);
  ASSERT_FALSE(rows.ok());
  EXPECT_NE(rows.error().message.find("allan row " + std::to_string(*id)), std::string::npos)
      << rows.error().message;
  EXPECT_NE(rows.error().message.find("'adev_dph' has 1 values"), std::string::npos)
      << rows.error().message;

  ASSERT_TRUE(db.exec("UPDATE allan SET curve_json = '{\"tau_s\":[1,null]}'").ok());
  rows = db.allan(run);
  ASSERT_FALSE(rows.ok());
  EXPECT_NE(rows.error().message.find("'tau_s'[1] is not a number"), std::string::npos)
      << rows.error().message;
}

// Another connection (the HTTP readers, the CLI) sees committed rows; a
// read-only one too, and a replacement as soon as it is committed.
TEST(Allan, ReadersOnOtherConnectionsSeeTheRows) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database writer = open_ok(path);
  Database reader = open_ok(path);
  auto read_only = Database::open_read_only(path);
  ASSERT_TRUE(read_only.ok()) << read_only.error().message;
  const int64_t run = make_run(writer);
  ASSERT_TRUE(reader.allan(run).ok());
  EXPECT_TRUE(reader.allan(run)->empty());

  AllanRecord a = full_record(run, make_segment(writer, run, 1), 1);
  ASSERT_TRUE(writer.put_allan(a).ok());
  for (Database* db : {&reader, &*read_only}) {
    auto rows = db->allan(run);
    ASSERT_TRUE(rows.ok()) << rows.error().message;
    ASSERT_EQ(rows->size(), 1u);
    expect_same((*rows)[0], a);
  }
  a.adev_dph[0] = 0.125;
  ASSERT_TRUE(writer.put_allan(a).ok());
  auto rows = read_only->allan(run);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->size(), 1u);
  EXPECT_EQ((*rows)[0].adev_dph[0], 0.125);
}

// A file written by schema 3 (created by the v1-v3 scripts, as an older build
// left it) opens, gains the allan table (and v5's) and keeps every row.
TEST(Allan, MigratesASchema3DatabaseKeepingItsRows) {
  TempDir dir;
  const std::string path = dir.file("v3.db");
  ASSERT_GE(internal::migrations().size(), 4u);
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    const std::string sql =
        std::string("CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);") +
        internal::migrations()[0].sql + internal::migrations()[1].sql +
        internal::migrations()[2].sql +
        "INSERT INTO meta VALUES('schema_version', '3');"
        "INSERT INTO meta VALUES('created_utc', '2026-01-01T00:00:00.000Z');"
        "INSERT INTO meta VALUES('queue_hold', 'stopped');"
        "INSERT INTO runs(schedule_name, state, started_utc, queue_id) "
        "  VALUES('old', 'completed', '2026-01-02T00:00:00.000Z', 1);"
        "INSERT INTO segments(run_id, idx, kind, setpoint_c, state) "
        "  VALUES(1, 0, 'soak', -40, 'completed');"
        "INSERT INTO acquisition_windows VALUES(1, 1, 100.0, 7300.0);"
        "INSERT INTO events(run_id, t_s, wall_utc, kind, message) "
        "  VALUES(1, 5.5, '2026-01-02T00:00:05.500Z', 'info', 'hello');"
        "INSERT INTO segment_stats(segment_id, run_id, segment_index, setpoint_c, n, "
        "  bias_mean_dph, computed_utc) VALUES(1, 1, 0, -40, 7200, 1.25, 'x');"
        "INSERT INTO gyro_samples VALUES(1, 0.5, 3, 0.75, 119, 21);"
        "INSERT INTO gyro_rollup VALUES(1, 0, 5, 1, 0.5, 1, 0.75, 0.75, 0.75);"
        "INSERT INTO temperature_samples VALUES(1, 0.5, -40, -39.5, -39.9, -40.1);"
        "INSERT INTO fits(model, form, n, coefficients_json, standard_errors_json, "
        "  inputs_json, computed_utc) VALUES('T1', 'paper', 8, '{\"T1\":0.5}', "
        "  '{\"T1\":0.1}', '{}', 'y');"
        "INSERT INTO fit_runs VALUES(1, 1);";
    char* err = nullptr;
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, &err), SQLITE_OK) << err;
    sqlite3_close(raw);
  }
  {
    auto ro = Database::open_read_only(path);
    ASSERT_FALSE(ro.ok());
    EXPECT_NE(ro.error().message.find(
                  fmt::format("schema version 3, older than this build's {}", kSchemaVersion)),
              std::string::npos)
        << ro.error().message;
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  const auto count = [&](const char* table) {
    return query_int(db.handle(), std::string("SELECT count(*) FROM ") + table);
  };
  for (const char* table : {"runs", "segments", "acquisition_windows", "events", "segment_stats",
                            "temperature_samples", "fits", "fit_runs"}) {
    EXPECT_EQ(count(table), 1) << table;
  }
  EXPECT_EQ(*db.count_gyro_samples(1), 1);  // moved into chunks (v9)
  EXPECT_EQ(count("allan"), 0);
  EXPECT_EQ(count("exports"), 0);
  EXPECT_EQ(count("export_runs"), 0);
  EXPECT_EQ(query_text(db.handle(), "SELECT value FROM meta WHERE key = 'created_utc'"),
            "2026-01-01T00:00:00.000Z");
  EXPECT_EQ(query_text(db.handle(), "SELECT value FROM meta WHERE key = 'queue_hold'"), "stopped");
  auto runs = db.runs();
  ASSERT_TRUE(runs.ok()) << runs.error().message;
  ASSERT_EQ(runs->size(), 1u);
  EXPECT_EQ((*runs)[0].schedule_name, "old");
  EXPECT_EQ((*runs)[0].queue_id, 1);
  auto segs = db.segments(1);
  ASSERT_TRUE(segs.ok()) << segs.error().message;
  ASSERT_EQ(segs->size(), 1u);
  EXPECT_EQ((*segs)[0].setpoint_c, -40);
  EXPECT_EQ((*segs)[0].windows, (std::vector<std::pair<double, double>>{{100.0, 7300.0}}));
  auto stats = db.segment_stats(1);
  ASSERT_TRUE(stats.ok()) << stats.error().message;
  ASSERT_EQ(stats->size(), 1u);
  EXPECT_EQ((*stats)[0].bias_mean_dph, 1.25);
  auto gyro = db.gyro_samples(1, 0, 1);
  ASSERT_TRUE(gyro.ok()) << gyro.error().message;
  ASSERT_EQ(gyro->size(), 1u);
  EXPECT_EQ((*gyro)[0].rate_dph, 0.75);
  auto fits = db.fits(1);
  ASSERT_TRUE(fits.ok()) << fits.error().message;
  ASSERT_EQ(fits->size(), 1u);
  EXPECT_EQ((*fits)[0].coefficients_json, R"({"T1":0.5})");

  // The new table works on the migrated file, tied to the old segment.
  AllanRecord a = full_record(1, 1, 0);
  ASSERT_TRUE(db.put_allan(a).ok());
  auto rows = db.allan(1);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->size(), 1u);
  expect_same((*rows)[0], a);
  EXPECT_EQ(
      query_text(db.handle(),
                 "SELECT name FROM sqlite_master WHERE type = 'index' AND tbl_name = 'allan'"),
      "allan_by_run");
}

}  // namespace
}  // namespace gyrotherm::storage
