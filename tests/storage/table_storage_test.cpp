// Schema v7: the rate table's samples and segment columns, and the stored
// scale-factor analysis (docs/storage.md).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <tuple>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "migrations.h"
#include "numbers.h"
#include "test_files.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using namespace std::chrono_literals;
using testing::integrity_ok;
using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::start_ok;
using testing::TempDir;

using gyrotherm::testing::kNaN;

// Deterministic table reading j: t = j * 0.5 s, a rate point at 10 °/s
// whose position wraps through 0/360.
TableSample table_sample(int j) {
  TableSample t;
  t.t_s = j * 0.5;
  t.demand_mode = "rate";
  t.demand_rate_dps = 10.0;
  t.rate_dps = 10.0 + std::sin(j * 0.7) * 1e-3;
  t.position_deg = std::fmod(355.0 + j * 5.0, 360.0);
  t.mode = "rate";
  t.interlock = "closed";
  return t;
}

void expect_same(const TableSample& got, const TableSample& want, int j) {
  EXPECT_EQ(got.t_s, want.t_s) << j;
  EXPECT_EQ(got.demand_mode, want.demand_mode) << j;
  EXPECT_EQ(got.demand_rate_dps, want.demand_rate_dps) << j;
  EXPECT_EQ(got.demand_position_deg, want.demand_position_deg) << j;
  EXPECT_EQ(got.rate_dps, want.rate_dps) << j;
  EXPECT_EQ(got.position_deg, want.position_deg) << j;
  EXPECT_EQ(got.mode, want.mode) << j;
  EXPECT_EQ(got.interlock, want.interlock) << j;
}

RunRecord table_run() {
  RunRecord r;
  r.schedule_name = "sf";
  r.state = "acquiring";
  r.started_utc = "2026-11-27T08:00:00.000Z";
  r.orientation = "up";
  return r;
}

// A database written by schema 6 (runs, segments with windows, samples,
// rollup, Table I rows) opens at schema 7 with all of it, and the segments
// read the new columns' defaults: no table demand, no rate point.
TEST(TableStorage, MigratesASchema6DatabaseWithItsData) {
  TempDir dir;
  const std::string path = dir.file("v6.db");
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    std::string sql = "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);";
    for (const auto& m : internal::migrations()) {
      if (m.version <= 6) sql += m.sql;
    }
    sql +=
        "INSERT INTO meta VALUES('schema_version', '6');"
        "INSERT INTO runs(id, schedule_name, state, started_utc, config_json) VALUES(1, 'old', "
        "'completed', '2026-01-02T03:04:05.000Z', '{\"station\":{\"name\":\"lab-1\"}}');"
        "INSERT INTO segments(id, run_id, idx, kind, label, setpoint_c, ramp_rate_c_per_min, "
        "t_start_s, t_settled_s, t_acquire_start_s, t_acquire_end_s, t_end_s, paused_s, state) "
        "VALUES(7, 1, 0, 'soak', 'soak 20', 20.0, NULL, 0.0, 100.0, 100.0, 400.0, 400.0, 0.0, "
        "'completed');"
        "INSERT INTO acquisition_windows VALUES(7, 1, 100.0, 250.0), (7, 1, 260.0, 400.0);"
        "INSERT INTO gyro_samples VALUES(1, 100.0, 3, 12.5, 119, 21), (1, 100.1, 4, 12.75, 119, "
        "21);"
        "INSERT INTO gyro_rollup VALUES(1, 0, 1000, 1, 100.0, 1, 12.5, 12.5, 12.5);"
        "INSERT INTO temperature_samples VALUES(1, 100.0, 20.0, 19.9, 20.1, 20.05);"
        "INSERT INTO segment_stats(segment_id, run_id, segment_index, setpoint_c, n, "
        "computed_utc) VALUES(7, 1, 0, 20.0, 2, '2026-01-02T05:00:00.000Z');";
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(raw);
    sqlite3_close(raw);
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  EXPECT_TRUE(integrity_ok(db));

  auto runs = db.runs();
  ASSERT_TRUE(runs.ok()) << runs.error().message;
  ASSERT_EQ(runs->size(), 1u);
  EXPECT_EQ((*runs)[0].config_json, R"({"station":{"name":"lab-1"}})");

  auto segs = db.segments(1);
  ASSERT_TRUE(segs.ok()) << segs.error().message;
  ASSERT_EQ(segs->size(), 1u);
  const SegmentRecord& s = (*segs)[0];
  EXPECT_EQ(s.id, 7);
  EXPECT_EQ(s.kind, "soak");
  EXPECT_EQ(s.setpoint_c, 20.0);
  EXPECT_EQ(s.t_acquire_end_s, 400.0);
  EXPECT_EQ(s.state, "completed");
  ASSERT_EQ(s.windows.size(), 2u);
  EXPECT_EQ(s.windows[1], std::make_pair(260.0, 400.0));
  EXPECT_EQ(s.table_mode, "none");
  EXPECT_FALSE(s.table_rate_dps.has_value());
  EXPECT_FALSE(s.table_position_deg.has_value());
  EXPECT_FALSE(s.table_mean_rate_dps.has_value());
  EXPECT_FALSE(s.table_mean_position_deg.has_value());
  EXPECT_EQ(s.turns, 0);
  EXPECT_EQ(s.dwell_s, 0.0);
  EXPECT_EQ(s.sf_sequence, 0);
  EXPECT_EQ(s.sf_repetition, 0);

  auto gyro = db.gyro_samples(1, 0, 1e9);
  ASSERT_TRUE(gyro.ok());
  ASSERT_EQ(gyro->size(), 2u);
  EXPECT_EQ((*gyro)[1].rate_dph, 12.75);
  EXPECT_EQ(db.temperature_samples(1, 0, 1e9)->size(), 1u);
  // v9 moved the samples into chunks, their rollup into channel_rollup.
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM channel_rollup WHERE level = 1"), 3);
  auto stats = db.segment_stats(1);
  ASSERT_TRUE(stats.ok());
  ASSERT_EQ(stats->size(), 1u);
  EXPECT_EQ((*stats)[0].computed_utc, "2026-01-02T05:00:00.000Z");

  for (const char* table : {"table_samples", "scale_factor_points", "scale_factor_fits",
                            "scale_factor_temperature_fits"}) {
    EXPECT_EQ(query_int(db.handle(), fmt::format("SELECT count(*) FROM {}", table)), 0) << table;
  }
  EXPECT_EQ(*db.last_sample_t_s(1), 100.1);
  // The demand is one of three words.
  auto bad = db.exec("UPDATE segments SET table_mode = 'spinning' WHERE id = 7");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("CHECK constraint failed"), std::string::npos)
      << bad.error().message;
}

TEST(TableStorage, SegmentTableFieldsRoundTrip) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run_id = *db.create_run(table_run());
  SegmentRecord s;
  s.run_id = run_id;
  s.index = 3;
  s.kind = "rate";
  s.label = "rate -100 °/s (sequence 1, repetition 2)";
  s.setpoint_c = 40.0;
  s.state = "running";
  s.table_mode = "rate";
  s.table_rate_dps = -100.0;
  s.turns = 10;
  s.dwell_s = 36.0;
  s.sf_sequence = 1;
  s.sf_repetition = 2;
  auto id = db.create_segment(s);
  ASSERT_TRUE(id.ok()) << id.error().message;
  auto read = *db.segments(run_id);
  ASSERT_EQ(read.size(), 1u);
  EXPECT_EQ(read[0].table_mode, "rate");
  EXPECT_EQ(read[0].table_rate_dps, -100.0);
  EXPECT_FALSE(read[0].table_position_deg.has_value());
  EXPECT_FALSE(read[0].table_mean_rate_dps.has_value());
  EXPECT_EQ(read[0].turns, 10);
  EXPECT_EQ(read[0].dwell_s, 36.0);
  EXPECT_EQ(read[0].sf_sequence, 1);
  EXPECT_EQ(read[0].sf_repetition, 2);

  s.id = *id;
  s.state = "completed";
  s.windows = {{100.0, 136.0}};
  s.table_mean_rate_dps = -99.9987;
  s.table_mean_position_deg = 359.25;
  ASSERT_TRUE(db.update_segment(s).ok());
  read = *db.segments(run_id);
  EXPECT_EQ(read[0].table_mean_rate_dps, -99.9987);
  EXPECT_EQ(read[0].table_mean_position_deg, 359.25);
  EXPECT_EQ(read[0].windows.size(), 1u);

  SegmentRecord soak;
  soak.run_id = run_id;
  soak.index = 4;
  soak.kind = "soak";
  soak.state = "running";
  soak.table_mode = "static";
  soak.table_rate_dps = 0.0;
  soak.table_position_deg = 90.0;
  ASSERT_TRUE(db.create_segment(soak).ok());
  read = *db.segments(run_id);
  ASSERT_EQ(read.size(), 2u);
  EXPECT_EQ(read[1].table_mode, "static");
  EXPECT_EQ(read[1].table_position_deg, 90.0);
  EXPECT_EQ(read[1].sf_sequence, 0);

  soak.table_mode = "";  // not one of none, static, rate
  auto refused = db.create_segment(soak);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("segment 4 of run"), std::string::npos)
      << refused.error().message;
}

TEST(TableStorage, WriterCommitsTableSamplesAndIgnoresDuplicateTimes) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 1h});
  constexpr int kN = 200;
  for (int j = 0; j < kN; ++j) writer->push_table(1, table_sample(j));
  TableSample held;  // a static demand at a position, with a failed reading
  held.t_s = 1000.0;
  held.demand_mode = "static";
  held.demand_position_deg = 90.0;
  held.rate_dps = kNaN;
  held.position_deg = kNaN;
  held.mode = "unknown";
  held.interlock = "fault";
  writer->push_table(1, held);
  TableSample no_time = table_sample(0);
  no_time.t_s = kNaN;
  writer->push_table(1, no_time);  // refused
  ASSERT_TRUE(writer->flush().ok());

  // The same time again (another reading): the first one stays.
  TableSample again = table_sample(5);
  again.rate_dps = -1.0;
  writer->push_table(1, again);
  writer->push_table(2, again);  // another run: kept
  ASSERT_TRUE(writer->flush().ok());

  const SampleWriterStats stats = writer->stats();
  EXPECT_EQ(stats.table_rows, static_cast<uint64_t>(kN + 3));
  EXPECT_EQ(stats.duplicates, 1u);
  EXPECT_EQ(stats.rejected, 1u);
  EXPECT_EQ(stats.pending, 0u);
  EXPECT_EQ(stats.gyro_rows, 0u);

  auto db = Database::open_read_only(path);
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto rows = db->table_samples(1, 0, 1e9);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->size(), static_cast<std::size_t>(kN + 1));
  for (int j = 0; j < kN; ++j) expect_same((*rows)[j], table_sample(j), j);
  const TableSample& h = rows->back();
  EXPECT_EQ(h.demand_mode, "static");
  EXPECT_EQ(h.demand_position_deg, 90.0);
  EXPECT_TRUE(std::isnan(h.rate_dps));
  EXPECT_TRUE(std::isnan(h.position_deg));
  EXPECT_EQ(h.interlock, "fault");
  EXPECT_EQ(query_int(db->handle(),
                      "SELECT count(*) FROM table_samples WHERE demand_position_deg IS NULL"),
            kN + 1);  // the rate demands have none (and run 2's one)
  // Half-open windows, as for the other samples.
  EXPECT_EQ(db->table_samples(1, 10.0, 20.0)->size(), 20u);
  EXPECT_EQ(db->table_samples(2, 0, 1e9)->size(), 1u);
  EXPECT_EQ(*db->last_sample_t_s(1), 1000.0);
}

TEST(TableStorage, WriterDropsTableSamplesAfterGyroBeforeTemperatures) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 1h, .max_pending = 10});
  writer->push_temperature(
      1, {.t_s = 0.0, .setpoint_c = 20, .chamber_c = 20, .top_c = 20, .side_c = 20});
  for (int j = 0; j < 6; ++j) writer->push_table(1, table_sample(j));
  std::vector<GyroSample> gyro(3);
  for (int i = 0; i < 3; ++i) gyro[i].t_s = i * 0.001;
  writer->push_gyro(1, gyro);  // 10 pending: nothing dropped
  EXPECT_EQ(writer->stats().dropped, 0u);
  for (int j = 6; j < 11; ++j) writer->push_table(1, table_sample(j));  // 5 more
  // 15 pending: the 3 gyro samples go, then the 2 oldest table samples.
  EXPECT_EQ(writer->stats().dropped, 5u);
  ASSERT_TRUE(writer->flush().ok());
  auto db = Database::open_read_only(path);
  ASSERT_TRUE(db.ok());
  auto rows = *db->table_samples(1, 0, 1e9);
  ASSERT_EQ(rows.size(), 9u);
  EXPECT_EQ(rows.front().t_s, table_sample(2).t_s);
  EXPECT_EQ(db->temperature_samples(1, 0, 1e9)->size(), 1u);
  EXPECT_EQ(*db->count_gyro_samples(1), 0);
}

// A writer process that dies without stop(): what flush() returned Ok for
// is there after reopening, and the file is consistent.
TEST(TableStorage, FlushedTableSamplesSurviveAKilledWriter) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  constexpr int kFlushed = 3000;
  const pid_t pid = fork();
  ASSERT_NE(pid, -1);
  if (pid == 0) {
    auto w = SampleWriter::start(path, {.commit_interval = 20ms});
    if (!w) _exit(2);
    for (int j = 0; j < kFlushed; ++j) (*w)->push_table(1, table_sample(j));
    if (!(*w)->flush().ok()) _exit(3);
    for (int j = kFlushed; j < kFlushed + 20'000; ++j) (*w)->push_table(1, table_sample(j));
    _exit(0);  // no stop(), no destructors: the writer thread dies mid-flight
  }
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0);

  Database db = open_ok(path);
  EXPECT_TRUE(integrity_ok(db));
  auto rows = db.table_samples(1, 0, table_sample(kFlushed).t_s);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->size(), static_cast<std::size_t>(kFlushed));
  for (int j = 0; j < kFlushed; j += 499) expect_same((*rows)[j], table_sample(j), j);
  expect_same(rows->back(), table_sample(kFlushed - 1), kFlushed - 1);
  const long long all = query_int(db.handle(), "SELECT count(*) FROM table_samples");
  EXPECT_GE(all, kFlushed);
  EXPECT_LE(all, kFlushed + 20'000);
}

// Reference: numpy, degrees(arctan2(sum(sin(p)), sum(cos(p)))) % 360 of the
// positions inside the windows (/usr/bin/python3, numpy 1.24), to 1e-9 °.
TEST(TableStorage, CircularMeanOfPositionsAcrossZero) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 1h});
  auto push = [&](double t_s, double rate_dps, double position_deg) {
    TableSample s;
    s.t_s = t_s;
    s.demand_mode = "static";
    s.rate_dps = rate_dps;
    s.position_deg = position_deg;
    s.mode = "position";
    s.interlock = "closed";
    writer->push_table(1, s);
  };
  // Window 1 [10, 13): 358, 359; window 2 [20, 23): 1, 4. Outside: 180.
  push(9.0, 5.0, 180.0);
  push(10.0, 0.001, 358.0);
  push(11.0, -0.002, 359.0);
  push(13.0, 5.0, 180.0);  // a window's end is excluded
  push(20.0, 0.0, 1.0);
  push(22.0, 0.003, 4.0);
  // Window 3 [30, 33): 350, 352.5, 1, 7.25, 359.5.
  push(30.0, 0.0, 350.0);
  push(30.5, 0.0, 352.5);
  push(31.0, 0.0, 1.0);
  push(31.5, 0.0, 7.25);
  push(32.0, 0.0, 359.5);
  // Whole turns at rate: positions evenly round the circle.
  for (int k = 0; k < 36; ++k) push(100.0 + k, 10.0, k * 10.0);
  ASSERT_TRUE(writer->flush().ok());
  Database db = open_ok(path);

  auto m = db.mean_table_over_windows(1, {{10.0, 13.0}, {20.0, 23.0}});
  ASSERT_TRUE(m.ok()) << m.error().message;
  EXPECT_EQ(m->n, 4);
  ASSERT_TRUE(m->rate_dps.has_value());
  EXPECT_NEAR(*m->rate_dps, (0.001 - 0.002 + 0.0 + 0.003) / 4, 1e-15);
  ASSERT_TRUE(m->position_deg.has_value());
  EXPECT_NEAR(*m->position_deg, 0.4996952201137823, 1e-9);  // not 180.5, the plain mean
  EXPECT_NEAR(m->position_resultant, 0.9992005670250003, 1e-12);

  m = db.mean_table_over_windows(1, {{30.0, 33.0}});
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(m->n, 5);
  ASSERT_TRUE(m->position_deg.has_value());
  EXPECT_NEAR(*m->position_deg, 358.0488317763171, 1e-9);
  EXPECT_GE(*m->position_deg, 0.0);
  EXPECT_LT(*m->position_deg, 360.0);

  m = db.mean_table_over_windows(1, {{100.0, 136.0}});
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(m->n, 36);
  EXPECT_EQ(m->rate_dps, 10.0);
  EXPECT_LT(m->position_resultant, 1e-12);
  EXPECT_FALSE(m->position_deg.has_value()) << *m->position_deg;

  m = db.mean_table_over_windows(1, {{500.0, 600.0}});  // no samples
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(m->n, 0);
  EXPECT_FALSE(m->rate_dps.has_value());
  EXPECT_FALSE(m->position_deg.has_value());
  m = db.mean_table_over_windows(1, {});
  ASSERT_TRUE(m.ok());
  EXPECT_EQ(m->n, 0);
}

// The decimated table series against a direct computation from the rows:
// buckets of width (to - from) / max_points from `from` (the last one takes
// the remainder), rate mean/min/max over the bucket's non-NULL rates, the
// rest from the bucket's last row.
TEST(TableStorage, DecimatedTableSeriesMatchesAHandComputation) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 1h});
  std::vector<TableSample> rows;
  for (int j = 0; j < 30; ++j) {
    TableSample s;
    s.t_s = j * 1.0;
    s.demand_mode = j < 12 ? "static" : "rate";
    s.demand_rate_dps = j < 12 ? 0.0 : 50.0;
    s.rate_dps = (j % 7 == 3)
                     ? kNaN
                     : 50.0 * (1 - std::exp(-0.3 * std::max(0, j - 12))) + 0.01 * std::cos(j);
    s.position_deg = std::fmod(j * 37.0, 360.0);
    s.mode = j < 12 ? "position" : "rate";
    s.interlock = j == 17 ? "fault" : "closed";
    rows.push_back(s);
    writer->push_table(1, s);
  }
  ASSERT_TRUE(writer->flush().ok());
  Database db = open_ok(path);

  for (const auto& [from_s, to_s, max_points] :
       std::vector<std::tuple<double, std::optional<double>, int>>{
           {0.0, std::nullopt, 4}, {3.0, 17.5, 3}, {0.0, 29.0, 1}}) {
    SCOPED_TRACE(fmt::format("[{}, {}] in {} points", from_s, to_s.value_or(-1), max_points));
    auto d = db.decimated_samples(1, from_s, to_s, max_points);
    ASSERT_TRUE(d.ok()) << d.error().message;
    EXPECT_TRUE(d->gyro.t_s.empty());
    const double end_s = to_s.value_or(29.0);  // the last sample
    EXPECT_EQ(d->to_s, end_s);
    const double width_s = (end_s - from_s) / max_points;

    struct Bucket {
      int n = 0, rate_n = 0;
      double t_sum = 0, rate_sum = 0;
      double lo = std::numeric_limits<double>::infinity();
      double hi = -std::numeric_limits<double>::infinity();
      const TableSample* last = nullptr;
    };
    std::vector<Bucket> want(max_points);
    for (const TableSample& s : rows) {
      if (s.t_s < from_s || s.t_s > end_s) continue;
      const int b = std::min(static_cast<int>((s.t_s - from_s) / width_s), max_points - 1);
      Bucket& k = want[b];
      ++k.n;
      k.t_sum += s.t_s;
      if (!std::isnan(s.rate_dps)) {
        ++k.rate_n;
        k.rate_sum += s.rate_dps;
        k.lo = std::min(k.lo, s.rate_dps);
        k.hi = std::max(k.hi, s.rate_dps);
      }
      k.last = &s;
    }
    std::erase_if(want, [](const Bucket& k) { return k.n == 0; });
    const auto& tb = d->table;
    ASSERT_EQ(tb.t_s.size(), want.size());
    for (std::size_t i = 0; i < want.size(); ++i) {
      const Bucket& k = want[i];
      EXPECT_EQ(tb.n[i], k.n) << i;
      EXPECT_NEAR(tb.t_s[i], k.t_sum / k.n, 1e-12) << i;
      EXPECT_NEAR(tb.mean_rate_dps[i], k.rate_sum / k.rate_n, 1e-12) << i;
      EXPECT_EQ(tb.min_rate_dps[i], k.lo) << i;
      EXPECT_EQ(tb.max_rate_dps[i], k.hi) << i;
      EXPECT_EQ(tb.position_deg[i], k.last->position_deg) << i;
      EXPECT_EQ(tb.demand_rate_dps[i], k.last->demand_rate_dps) << i;
      EXPECT_EQ(tb.demand_mode[i], k.last->demand_mode) << i;
      EXPECT_EQ(tb.mode[i], k.last->mode) << i;
      EXPECT_EQ(tb.interlock[i], k.last->interlock) << i;
    }
  }

  // A bucket whose only reading has no rate: NaN, not 0.
  auto d = db.decimated_samples(1, 3.0, 3.0, 5);
  ASSERT_TRUE(d.ok());
  ASSERT_EQ(d->table.n.size(), 1u);
  EXPECT_TRUE(std::isnan(d->table.mean_rate_dps[0]));
  EXPECT_TRUE(std::isnan(d->table.min_rate_dps[0]));
  // A run without a table has no table series.
  d = db.decimated_samples(2, 0.0, 10.0, 5);
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(d->table.t_s.empty());
}

ScaleFactorPointRecord point(int64_t segment_id, int repetition, double rate_dps, double k) {
  ScaleFactorPointRecord p;
  p.segment_id = segment_id;
  p.sf_sequence = 1;
  p.repetition = repetition;
  p.rate_dps = rate_dps;
  p.measured_rate_dps = rate_dps * (1 + 1e-6);
  p.output_dps = k * rate_dps + 0.002;
  p.n = 36'000;
  p.temperature_c = 40.0 + 0.01 * repetition;
  p.duration_s = 360.0 / std::abs(rate_dps) * 10;
  p.turns = 10;
  return p;
}

TEST(TableStorage, ScaleFactorRowsStoreReplaceAndRead) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  ManualWallClock wall(1'795'000'000.0);  // 2026-11-18T11:06:40Z
  auto opened = Database::open(path, wall);
  ASSERT_TRUE(opened.ok()) << opened.error().message;
  Database& db = *opened;
  const int64_t run_id = *db.create_run(table_run());
  const int64_t other_run = *db.create_run(table_run());
  SegmentRecord seg;
  seg.run_id = run_id;
  seg.kind = "rate";
  seg.state = "completed";
  const int64_t seg_id = *db.create_segment(seg);

  std::vector<ScaleFactorPointRecord> points = {point(seg_id, 1, 100.0, 1.000012),
                                                point(seg_id, 1, -100.0, 1.000012),
                                                point(0, 2, 100.0, 1.000015)};
  points[2].measured_rate_dps = kNaN;  // not known: stored as NULL
  ScaleFactorFitRecord fit;
  fit.sf_sequence = 1;
  fit.temperature_c = 40.01;
  fit.k = 1.0000135;
  fit.k_se = 2.1e-7;
  fit.bias_dps = 0.002;
  fit.nonlinearity_ppm = 12.5;
  fit.nonlinearity_fs_ppm = 3.25;
  fit.asymmetry_ppm = -4.0;
  fit.n_points = 3;
  ScaleFactorFitRecord fit2 = fit;
  fit2.sf_sequence = 2;
  fit2.temperature_c = -10.0;
  fit2.asymmetry_ppm.reset();
  fit2.repeatability_ppm = 1.75;
  fit2.created_utc = "2026-01-01T00:00:00.000Z";
  ScaleFactorTemperatureFitRecord tfit;
  tfit.order = 2;
  tfit.t_centre_c = 25.0;
  tfit.k_coeffs_json = "[1.0000125,2.5e-6,-1e-9]";
  tfit.bias_coeffs_json = "[0.002,1.5e-5,0]";
  tfit.k_ppm_per_c = 2.5;
  tfit.bias_dph_per_c = 0.054;

  Status s = db.store_scale_factor(run_id, points, {fit, fit2}, tfit);
  ASSERT_TRUE(s.ok()) << s.error().message;
  // Another run's rows are not touched by this run's replacement.
  ASSERT_TRUE(db.store_scale_factor(other_run, {point(0, 1, 5.0, 1.0)}, {}, std::nullopt).ok());

  auto got_points = db.scale_factor_points(run_id);
  ASSERT_TRUE(got_points.ok()) << got_points.error().message;
  ASSERT_EQ(got_points->size(), 3u);
  // By sequence, repetition, rate.
  const auto& p0 = (*got_points)[0];
  EXPECT_EQ(p0.run_id, run_id);
  EXPECT_EQ(p0.segment_id, seg_id);
  EXPECT_EQ(p0.repetition, 1);
  EXPECT_EQ(p0.rate_dps, -100.0);
  EXPECT_EQ(p0.output_dps, points[1].output_dps);
  EXPECT_EQ(p0.measured_rate_dps, points[1].measured_rate_dps);
  EXPECT_EQ(p0.n, 36'000);
  EXPECT_EQ(p0.temperature_c, points[1].temperature_c);
  EXPECT_EQ(p0.duration_s, 36.0);
  EXPECT_EQ(p0.turns, 10.0);
  EXPECT_EQ((*got_points)[1].rate_dps, 100.0);
  EXPECT_EQ((*got_points)[2].segment_id, 0);
  EXPECT_TRUE(std::isnan((*got_points)[2].measured_rate_dps));

  auto got_fits = db.scale_factor_fits(run_id);
  ASSERT_TRUE(got_fits.ok()) << got_fits.error().message;
  ASSERT_EQ(got_fits->size(), 2u);
  const auto& f1 = (*got_fits)[0];
  EXPECT_EQ(f1.sf_sequence, 1);
  EXPECT_EQ(f1.k, 1.0000135);
  EXPECT_EQ(f1.k_se, 2.1e-7);
  EXPECT_EQ(f1.nonlinearity_ppm, 12.5);
  EXPECT_EQ(f1.nonlinearity_fs_ppm, 3.25);
  EXPECT_EQ(f1.asymmetry_ppm, -4.0);
  EXPECT_FALSE(f1.repeatability_ppm.has_value());
  EXPECT_EQ(f1.n_points, 3);
  EXPECT_EQ(f1.created_utc, "2026-11-18T11:06:40.000Z");  // the injected wall clock
  EXPECT_FALSE((*got_fits)[1].asymmetry_ppm.has_value());
  EXPECT_EQ((*got_fits)[1].repeatability_ppm, 1.75);
  EXPECT_EQ((*got_fits)[1].created_utc, "2026-01-01T00:00:00.000Z");

  auto got_t = db.scale_factor_temperature_fit(run_id);
  ASSERT_TRUE(got_t.ok()) << got_t.error().message;
  ASSERT_TRUE(got_t->has_value());
  EXPECT_EQ((*got_t)->order, 2);
  EXPECT_EQ((*got_t)->t_centre_c, 25.0);
  EXPECT_EQ((*got_t)->k_coeffs_json, tfit.k_coeffs_json);
  EXPECT_EQ((*got_t)->bias_coeffs_json, tfit.bias_coeffs_json);
  EXPECT_EQ((*got_t)->k_ppm_per_c, 2.5);
  EXPECT_EQ((*got_t)->bias_dph_per_c, 0.054);
  EXPECT_EQ((*got_t)->created_utc, "2026-11-18T11:06:40.000Z");
  // sqlite3 users read the coefficients with its JSON functions.
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT json_extract(k_coeffs_json, '$[1]') FROM "
                       "scale_factor_temperature_fits WHERE run_id = " +
                           std::to_string(run_id)),
            "2.5e-06");

  // Re-analysis replaces every row of the run.
  wall.advance(3600);
  ScaleFactorFitRecord refit = fit;
  refit.k = 1.0000140;
  ASSERT_TRUE(db.store_scale_factor(run_id, {points[0]}, {refit}, std::nullopt).ok());
  EXPECT_EQ(db.scale_factor_points(run_id)->size(), 1u);
  got_fits = db.scale_factor_fits(run_id);
  ASSERT_EQ(got_fits->size(), 1u);
  EXPECT_EQ((*got_fits)[0].k, 1.0000140);
  EXPECT_EQ((*got_fits)[0].created_utc, "2026-11-18T12:06:40.000Z");
  EXPECT_FALSE(db.scale_factor_temperature_fit(run_id)->has_value());
  EXPECT_EQ(db.scale_factor_points(other_run)->size(), 1u);

  // A failure leaves the previous rows as they were (one transaction): two
  // fits of the same sequence break the key after the points were written.
  auto dup = db.store_scale_factor(run_id, points, {fit, fit}, tfit);
  ASSERT_FALSE(dup.ok());
  EXPECT_NE(dup.error().message.find("fit of sequence 1"), std::string::npos)
      << dup.error().message;
  EXPECT_EQ(db.scale_factor_points(run_id)->size(), 1u);
  EXPECT_EQ((*db.scale_factor_fits(run_id))[0].k, 1.0000140);
  EXPECT_FALSE(db.scale_factor_temperature_fit(run_id)->has_value());

  // Records of another run, and coefficients that are not a JSON array of
  // numbers, are refused with what is wrong.
  ScaleFactorPointRecord stray = points[0];
  stray.run_id = other_run;
  auto wrong = db.store_scale_factor(run_id, {stray}, {}, std::nullopt);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.error().message.find(fmt::format("belongs to run {}", other_run)),
            std::string::npos)
      << wrong.error().message;
  tfit.bias_coeffs_json = R"({"b0": 0.002})";
  auto bad_json = db.store_scale_factor(run_id, {}, {}, tfit);
  ASSERT_FALSE(bad_json.ok());
  EXPECT_NE(bad_json.error().message.find("bias_coeffs_json"), std::string::npos)
      << bad_json.error().message;
  EXPECT_EQ(db.scale_factor_points(run_id)->size(), 1u);

  // A point tied to a segment that does not exist is refused (foreign key).
  auto orphan = db.store_scale_factor(run_id, {point(seg_id + 100, 1, 1.0, 1.0)}, {}, std::nullopt);
  EXPECT_FALSE(orphan.ok());
  EXPECT_TRUE(integrity_ok(db));
}

// The sqlite3 statements of docs/storage.md that read the v7 tables, run
// against a database holding such rows: they parse, return rows, and the
// figures they compute agree with the stored records.
TEST(TableStorage, DocumentedQueriesRun) {
  const std::string doc =
      gyrotherm::testing::read_text(std::string(GYROTHERM_SOURCE_DIR) + "/docs/storage.md");
  std::vector<std::string> statements;
  for (std::size_t at = 0; (at = doc.find("```sql\n", at)) != std::string::npos;) {
    at += 7;
    const std::size_t end = doc.find("```", at);
    ASSERT_NE(end, std::string::npos);
    const std::string block = doc.substr(at, end - at);
    at = end + 3;
    if (block.find("scale_factor") == std::string::npos &&
        block.find("table_samples") == std::string::npos) {
      continue;
    }
    // The DUT history queries (v8) have their own test (records_v8_test),
    // the result-quality one (v11) too (quality_storage_test).
    if (block.find("'17-0042'") != std::string::npos) continue;
    if (block.find("quality_reasons_json") != std::string::npos) continue;
    for (std::size_t from = 0, semi; (semi = block.find(';', from)) != std::string::npos;
         from = semi + 1) {
      statements.push_back(block.substr(from, semi + 1 - from));
    }
  }
  ASSERT_EQ(statements.size(), 4u) << "the documented v7 queries changed: update this test";

  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  int64_t run_id = 0;
  for (int i = 0; i < 3; ++i) run_id = *db.create_run(table_run());  // run 3, the last
  int64_t seg_id = 0;
  for (int idx = 0; idx <= 12; ++idx) {
    SegmentRecord seg;
    seg.run_id = run_id;
    seg.index = idx;
    seg.kind = idx == 12 ? "rate" : "soak";
    seg.state = "completed";
    seg.t_start_s = idx * 100.0;
    seg.t_end_s = idx * 100.0 + 100.0;
    seg_id = *db.create_segment(seg);
  }
  auto writer = start_ok(db.path(), {.commit_interval = 1h});
  for (int j = 0; j < 40; ++j) {
    TableSample t = table_sample(j);
    t.t_s = 1200.0 + j * 0.5;
    writer->push_table(run_id, t);
  }
  ASSERT_TRUE(writer->flush().ok());
  std::vector<ScaleFactorPointRecord> points;
  for (int rep = 1; rep <= 2; ++rep) {
    for (double rate : {-100.0, 100.0}) {
      ScaleFactorPointRecord p = point(seg_id, rep, rate, 1.000012);
      p.sf_sequence = 2;
      p.output_dps += 1e-5 * rate / 100.0;  // an asymmetry
      points.push_back(p);
    }
  }
  ScaleFactorFitRecord cold;
  cold.sf_sequence = 1;
  cold.temperature_c = -20.0;
  cold.k = 1.0000100;
  cold.asymmetry_ppm = 1.5;
  cold.n_points = 4;
  ScaleFactorFitRecord warm = cold;
  warm.sf_sequence = 2;
  warm.temperature_c = 40.0;
  warm.k = 1.0000121;
  warm.bias_dps = 0.002;
  warm.asymmetry_ppm.reset();
  ScaleFactorTemperatureFitRecord tfit;
  tfit.order = 1;
  tfit.t_centre_c = 10.0;
  tfit.k_coeffs_json = "[1.00001105,3.5e-8]";
  tfit.bias_coeffs_json = "[0.001,1.6e-5]";
  tfit.k_ppm_per_c = 0.035;
  tfit.bias_dph_per_c = 0.0576;
  ASSERT_TRUE(db.store_scale_factor(run_id, points, {cold, warm}, tfit).ok());

  std::vector<std::vector<std::vector<std::string>>> results;
  for (const std::string& sql : statements) {
    SCOPED_TRACE(sql);
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(db.handle(), sql.c_str(), -1, &st, nullptr), SQLITE_OK)
        << sqlite3_errmsg(db.handle());
    std::vector<std::vector<std::string>> rows;
    int rc;
    while ((rc = sqlite3_step(st)) == SQLITE_ROW) {
      std::vector<std::string> row;
      for (int c = 0; c < sqlite3_column_count(st); ++c) {
        const unsigned char* p = sqlite3_column_text(st, c);
        row.push_back(p != nullptr ? reinterpret_cast<const char*>(p) : "NULL");
      }
      rows.push_back(std::move(row));
    }
    EXPECT_EQ(rc, SQLITE_DONE) << sqlite3_errmsg(db.handle());
    sqlite3_finalize(st);
    EXPECT_FALSE(rows.empty());
    results.push_back(std::move(rows));
  }
  ASSERT_EQ(results.size(), 4u);
  // Scale factor over temperature: coldest first, K relative to it.
  ASSERT_EQ(results[0].size(), 2u);
  EXPECT_EQ(results[0][0][0], "1");
  EXPECT_EQ(results[0][1][2], "1.000012100");
  EXPECT_EQ(std::stod(results[0][1].back()), std::round((warm.k / cold.k - 1) * 1e7) / 10);
  EXPECT_EQ(results[0][1][6], "NULL");  // no asymmetry stored for the warm sequence
  ASSERT_EQ(results[1].size(), 1u);
  EXPECT_EQ(results[1][0][2], tfit.k_coeffs_json);
  // The points of sequence 2 with their residual from the line, in ppm.
  ASSERT_EQ(results[2].size(), 4u);
  for (std::size_t i = 0; i < 4; ++i) {
    const auto& p = points[i];  // stored order: repetition, then rate
    const double want =
        (p.output_dps - (warm.k * p.rate_dps + warm.bias_dps)) / (warm.k * p.rate_dps) * 1e6;
    EXPECT_NEAR(std::stod(results[2][i].back()), want, 0.05 + 1e-9) << i;
  }
  // The table during step 12: 40 readings at 2 a second.
  EXPECT_EQ(results[3].size(), 20u);
  EXPECT_EQ(results[3][0].back(), "closed");
}

}  // namespace
}  // namespace gyrotherm::storage
