// Decimated reads (Database::decimated_samples), the gyro_rollup table they
// read (kept by SampleWriter, backfilled by migration 3) and stored fits,
// checked against brute-force recomputations from the raw rows.
//
// Sample times are kept at least 0.1 ms off every multiple of 0.1 s, so the
// block (and rollup bucket) of each sample does not hang on the last bit of
// a division: the brute force may then assign samples by time intervals.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <tuple>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "migrations.h"
#include "numbers.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using namespace std::chrono_literals;
using testing::open_ok;
using testing::query_int;
using testing::TempDir;

using gyrotherm::testing::kNaN;
// Relative tolerance on sums and means, relative to the sum of magnitudes
// (rates straddle zero, so relative to the mean itself would be meaningless).
constexpr double kRelTol = 1e-12;

// Commits only when flushed: each flush() below is one transaction.
std::unique_ptr<SampleWriter> start_flushing(const std::string& path) {
  return testing::start_ok(path, {.commit_interval = 600s});
}

GyroSample gyro(double t_s, double rate_dph) {
  GyroSample g;
  g.t_s = t_s;
  g.rate_dph = rate_dph;
  g.seq = 3;
  g.status = 0x77;
  g.temp_c = 21;
  return g;
}

// Pushes `samples` in chunks of the given sizes (cycled), one commit each.
void write_in_commits(SampleWriter& w, int64_t run_id, std::span<const GyroSample> samples,
                      std::vector<std::size_t> chunks) {
  std::size_t c = 0;
  for (std::size_t off = 0; off < samples.size(); c = (c + 1) % chunks.size()) {
    const std::size_t k = std::min(chunks[c], samples.size() - off);
    w.push_gyro(run_id, samples.subspan(off, k));
    const Status s = w.flush();
    ASSERT_TRUE(s.ok()) << s.error().message;
    off += k;
  }
}

// ---------------------------------------------------------------------------
// Raw rows and the brute-force rollup.

struct RawGyro {
  int64_t run_id;
  double t_s;
  double rate_dph;  // NaN: NULL
};

double column_or_nan(sqlite3_stmt* st, int c) {
  return sqlite3_column_type(st, c) == SQLITE_NULL ? kNaN : sqlite3_column_double(st, c);
}

// Every run's primary-axis samples, read back from their chunks.
std::vector<RawGyro> read_raw_gyro(sqlite3* db) {
  std::vector<RawGyro> out;
  auto reader = Database::open_read_only(sqlite3_db_filename(db, "main"));
  EXPECT_TRUE(reader.ok()) << reader.error().message;
  if (!reader) return out;
  sqlite3_stmt* st = nullptr;
  EXPECT_EQ(
      sqlite3_prepare_v2(db, "SELECT DISTINCT run_id FROM run_duts ORDER BY 1", -1, &st, nullptr),
      SQLITE_OK);
  while (sqlite3_step(st) == SQLITE_ROW) {
    const int64_t run_id = sqlite3_column_int64(st, 0);
    auto samples = reader->gyro_samples(run_id, -1e300, 1e300);
    EXPECT_TRUE(samples.ok()) << samples.error().message;
    if (!samples) continue;
    for (const GyroSample& g : *samples) out.push_back({run_id, g.t_s, g.rate_dph});
  }
  sqlite3_finalize(st);
  return out;
}

std::vector<RawGyro> of_run(const std::vector<RawGyro>& rows, int64_t run_id) {
  std::vector<RawGyro> out;
  for (const RawGyro& r : rows) {
    if (r.run_id == run_id) out.push_back(r);
  }
  return out;
}

struct RawTemp {
  double t_s;
  double setpoint_c, chamber_c, top_c, side_c;  // NaN: NULL
};

std::vector<RawTemp> read_raw_temps(sqlite3* db, int64_t run_id) {
  std::vector<RawTemp> out;
  sqlite3_stmt* st = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(db,
                               "SELECT t_s, setpoint_c, chamber_c, top_c, side_c FROM "
                               "temperature_samples WHERE run_id = ? ORDER BY t_s",
                               -1, &st, nullptr),
            SQLITE_OK);
  sqlite3_bind_int64(st, 1, run_id);
  while (sqlite3_step(st) == SQLITE_ROW) {
    out.push_back({sqlite3_column_double(st, 0), column_or_nan(st, 1), column_or_nan(st, 2),
                   column_or_nan(st, 3), column_or_nan(st, 4)});
  }
  sqlite3_finalize(st);
  return out;
}

using BlockKey = std::tuple<int64_t, int, int64_t>;  // run, level, block

struct Block {
  int64_t n = 0, rate_n = 0;
  double t_sum_s = 0, rate_sum_dph = 0;
  double rate_min_dph = kNaN, rate_max_dph = kNaN;  // NaN: NULL
  // Brute force only: sums of magnitudes, the scale of the tolerance.
  double t_abs_sum_s = 0, rate_abs_sum_dph = 0;
};

std::map<BlockKey, Block> read_rollup(sqlite3* db) {
  std::map<BlockKey, Block> out;
  sqlite3_stmt* st = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(db,
                               "SELECT c.run_id, level, block, n, t_sum_s, v_n, v_sum, v_min, "
                               "v_max FROM channel_rollup r JOIN channels c ON c.id = r.channel_id "
                               "WHERE c.kind = 'rate'",
                               -1, &st, nullptr),
            SQLITE_OK);
  while (sqlite3_step(st) == SQLITE_ROW) {
    Block b;
    b.n = sqlite3_column_int64(st, 3);
    b.t_sum_s = sqlite3_column_double(st, 4);
    b.rate_n = sqlite3_column_int64(st, 5);
    b.rate_sum_dph = column_or_nan(st, 6);
    b.rate_min_dph = column_or_nan(st, 7);
    b.rate_max_dph = column_or_nan(st, 8);
    out[{sqlite3_column_int64(st, 0), sqlite3_column_int(st, 1), sqlite3_column_int64(st, 2)}] = b;
  }
  sqlite3_finalize(st);
  return out;
}

std::map<BlockKey, Block> brute_rollup(const std::vector<RawGyro>& rows) {
  std::map<BlockKey, Block> out;
  for (const RawGyro& r : rows) {
    // channel_rollup keeps levels 1..4 (1 ... 1000 s).
    for (int level = 1; level < kRollupLevels; ++level) {
      const auto block = static_cast<int64_t>(std::floor(r.t_s / kRollupBlockS[level]));
      Block& b = out[{r.run_id, level, block}];
      ++b.n;
      b.t_sum_s += r.t_s;
      b.t_abs_sum_s += std::fabs(r.t_s);
      if (std::isnan(r.rate_dph)) continue;
      b.rate_sum_dph = b.rate_n == 0 ? r.rate_dph : b.rate_sum_dph + r.rate_dph;
      b.rate_abs_sum_dph += std::fabs(r.rate_dph);
      b.rate_min_dph = b.rate_n == 0 ? r.rate_dph : std::min(b.rate_min_dph, r.rate_dph);
      b.rate_max_dph = b.rate_n == 0 ? r.rate_dph : std::max(b.rate_max_dph, r.rate_dph);
      ++b.rate_n;
    }
  }
  return out;
}

std::string key_str(const BlockKey& k) {
  return "run " + std::to_string(std::get<0>(k)) + " level " + std::to_string(std::get<1>(k)) +
         " block " + std::to_string(std::get<2>(k));
}

// One block's difference from the brute force, "" if none.
std::string block_mismatch(const Block& got, const Block& want) {
  std::string out;
  auto note = [&](const char* what, double g, double w) {
    out +=
        std::string(" ") + what + " " + std::to_string(g) + " (expected " + std::to_string(w) + ")";
  };
  if (got.n != want.n) note("n", got.n, want.n);
  if (got.rate_n != want.rate_n) note("rate_n", got.rate_n, want.rate_n);
  if (!(std::fabs(got.t_sum_s - want.t_sum_s) <= kRelTol * want.t_abs_sum_s)) {
    note("t_sum_s", got.t_sum_s, want.t_sum_s);
  }
  if (want.rate_n == 0) {
    // No rate: the columns are NULL, not 0.
    if (!std::isnan(got.rate_sum_dph)) note("rate_sum_dph", got.rate_sum_dph, kNaN);
    if (!std::isnan(got.rate_min_dph)) note("rate_min_dph", got.rate_min_dph, kNaN);
    if (!std::isnan(got.rate_max_dph)) note("rate_max_dph", got.rate_max_dph, kNaN);
  } else {
    if (!(std::fabs(got.rate_sum_dph - want.rate_sum_dph) <= kRelTol * want.rate_abs_sum_dph)) {
      note("rate_sum_dph", got.rate_sum_dph, want.rate_sum_dph);
    }
    if (got.rate_min_dph != want.rate_min_dph) {
      note("rate_min_dph", got.rate_min_dph, want.rate_min_dph);
    }
    if (got.rate_max_dph != want.rate_max_dph) {
      note("rate_max_dph", got.rate_max_dph, want.rate_max_dph);
    }
  }
  return out;
}

// channel_rollup == the brute force over the stored samples, block by block.
void expect_rollup_matches_samples(sqlite3* db) {
  const auto stored = read_rollup(db);
  const auto expected = brute_rollup(read_raw_gyro(db));
  ASSERT_FALSE(expected.empty());
  EXPECT_EQ(stored.size(), expected.size());
  int reported = 0;
  for (const auto& [key, want] : expected) {
    const auto it = stored.find(key);
    const std::string diff =
        it == stored.end() ? std::string(" missing") : block_mismatch(it->second, want);
    if (!diff.empty() && ++reported <= 10) ADD_FAILURE() << key_str(key) << ":" << diff;
  }
  for (const auto& [key, got] : stored) {
    if (!expected.contains(key) && ++reported <= 10) {
      ADD_FAILURE() << key_str(key) << ": a rollup row without samples";
    }
  }
  EXPECT_EQ(reported, 0) << "rollup rows differing from the brute force";
}

// 1 kHz-ish: sample i at t0 + i ms + 0.4 ms.
double t_at(double t0_s, int i, double step_s = 0.001) { return t0_s + i * step_s + 0.0004; }

// ---------------------------------------------------------------------------
// The rollup kept by SampleWriter.

TEST(Rollup, WriterKeepsItEqualToTheSamples) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_flushing(path);
  std::mt19937_64 rng(7);
  std::normal_distribution<double> noise(0.0, 2.0);

  // Run 1: -3 ... 25 s at 1 kHz; every 37th rate missing, and none at all in
  // [5, 7) s (whole 0.1 s and 1 s blocks without a rate).
  std::vector<GyroSample> run1;
  for (int i = 0; i < 28'000; ++i) {
    const double t = t_at(-3.0, i);
    const bool missing = i % 37 == 0 || (t >= 5.0 && t < 7.0);
    run1.push_back(gyro(t, missing ? kNaN : 0.8 + 3.0 * std::sin(i * 0.01) + noise(rng)));
  }
  // Run 2: a sample every 0.7 s over 5600 s (every level-4 block 0 ... 5).
  std::vector<GyroSample> run2;
  for (int j = 0; j < 8000; ++j) {
    run2.push_back(gyro(0.05 + j * 0.7, j % 3 == 0 ? kNaN : -5.0 + noise(rng)));
  }
  // Run 3: a few far apart, negative blocks included.
  const std::vector<GyroSample> run3 = {gyro(-1500.55, 1.0), gyro(-0.05, kNaN), gyro(0.0004, 2.5),
                                        gyro(99'999.95, -7.25)};

  // Irregular commits, runs interleaved, blocks straddling commits.
  write_in_commits(*writer, 1, std::span(run1).first(10'000), {1234, 777, 3001});
  write_in_commits(*writer, 2, std::span(run2).first(3000), {997});
  writer->push_gyro(3, run3);
  write_in_commits(*writer, 1, std::span(run1).subspan(10'000), {4999, 13, 2500});
  write_in_commits(*writer, 2, std::span(run2).subspan(3000), {1500});

  // Duplicates with other rates, across commits and within one batch: the
  // stored rows keep their first rates and the rollup must not count these.
  std::vector<GyroSample> dups;
  for (int i = 100; i < 28'000; i += 997) {
    GyroSample g = run1[static_cast<std::size_t>(i)];
    g.rate_dph = 1e6;  // would show as a max
    dups.push_back(g);
  }
  const std::vector<GyroSample> fresh = {gyro(25.5004, 3.0), gyro(25.5004, -1e6),
                                         gyro(25.5014, kNaN), gyro(25.5014, 1e6)};
  writer->push_gyro(1, dups);
  writer->push_gyro(1, fresh);
  ASSERT_TRUE(writer->flush().ok());
  writer->stop();
  EXPECT_EQ(writer->stats().duplicates, dups.size() + 2);
  EXPECT_EQ(writer->stats().dropped, 0u);

  Database db = open_ok(path);
  EXPECT_EQ(*db.count_gyro_samples(1) + *db.count_gyro_samples(2) + *db.count_gyro_samples(3),
            static_cast<long long>(run1.size() + run2.size() + run3.size() + 2));
  EXPECT_EQ(query_int(db.handle(), "SELECT max(v_max) < 1e5 FROM channel_rollup"), 1);
  expect_rollup_matches_samples(db.handle());
  // The NaN-only stretch left NULL rate columns in the rollup.
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM channel_rollup r JOIN channels c ON c.id = "
                      "r.channel_id WHERE c.run_id = 1 AND c.name = 'rate' AND level = 1 AND "
                      "block IN (5, 6) AND v_n = 0 AND v_sum IS NULL AND "
                      "v_min IS NULL AND v_max IS NULL"),
            2);
}

// ---------------------------------------------------------------------------
// Migration 3 backfills the rollup of a schema-2 database.

TEST(Rollup, MigrationBackfillsASchema2Database) {
  TempDir dir;
  const std::string path = dir.file("v2.db");
  std::vector<RawGyro> rows;
  // Times on block edges (positive and negative, where SQL's CAST truncates
  // toward zero and the backfill must floor), NULL rates, two runs.
  for (double t : {-1000.0001, -1000.0, -100.0, -10.0, -1.0, -0.3, -0.2, -0.1, -0.05, 0.0, 0.1, 0.3,
                   0.7, 1.0, 10.0, 999.9999, 1e4, 12'345.678'9}) {
    rows.push_back({1, t, std::round(t * 7.0) / 3.0});
  }
  for (int i = 0; i < 5000; ++i) {
    rows.push_back({1, t_at(20.0, i), i % 11 == 0 ? kNaN : std::sin(i * 0.3) * 4.0});
  }
  for (int i = 0; i < 300; ++i) rows.push_back({2, t_at(-15.0, i, 0.01), kNaN});
  rows.push_back({2, 3.0004, 42.0});
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    const std::string sql =
        std::string("CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);") +
        internal::migrations()[0].sql + internal::migrations()[1].sql +
        "INSERT INTO meta VALUES('schema_version', '2');"
        "INSERT INTO runs(id, schedule_name, state, started_utc) VALUES"
        "(1, 'a', 'completed', '2026-01-01T00:00:00.000Z'), "
        "(2, 'b', 'completed', '2026-01-02T00:00:00.000Z');";
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(raw);
    ASSERT_EQ(sqlite3_exec(raw, "BEGIN", nullptr, nullptr, nullptr), SQLITE_OK);
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(raw,
                                 "INSERT INTO gyro_samples(run_id, t_s, seq, rate_dph, status, "
                                 "temp_c) VALUES(?, ?, 0, ?, 119, 20)",
                                 -1, &st, nullptr),
              SQLITE_OK);
    for (const RawGyro& r : rows) {
      sqlite3_bind_int64(st, 1, r.run_id);
      sqlite3_bind_double(st, 2, r.t_s);
      if (std::isnan(r.rate_dph)) {
        sqlite3_bind_null(st, 3);
      } else {
        sqlite3_bind_double(st, 3, r.rate_dph);
      }
      ASSERT_EQ(sqlite3_step(st), SQLITE_DONE) << sqlite3_errmsg(raw);
      sqlite3_reset(st);
    }
    sqlite3_finalize(st);
    ASSERT_EQ(sqlite3_exec(raw, "COMMIT", nullptr, nullptr, nullptr), SQLITE_OK);
    sqlite3_close(raw);
  }
  {
    Database db = open_ok(path);
    EXPECT_EQ(*db.schema_version(), kSchemaVersion);
    EXPECT_EQ(*db.count_gyro_samples(1) + *db.count_gyro_samples(2),
              static_cast<long long>(rows.size()));
    expect_rollup_matches_samples(db.handle());
    // Spot check of the floor on negative edges: [-1, 0) s is 1 s block -1.
    EXPECT_EQ(query_int(db.handle(),
                        "SELECT n FROM channel_rollup r JOIN channels c ON c.id = r.channel_id "
                        "WHERE c.run_id = 1 AND c.name = 'rate' AND level = 1 AND block = -1"),
              5);
  }
  // The writer then adds to the migrated blocks (and ignores duplicates: at
  // or before the last stored sample, 12 345.6789 s).
  auto writer = start_flushing(path);
  std::vector<GyroSample> more;
  more.push_back(gyro(12'345.678'9, 99.0));  // duplicate of a migrated row
  for (int i = 0; i < 1000; ++i) more.push_back(gyro(t_at(12'345.0, i), 1.5));  // 348 before it
  for (int i = 0; i < 1000; ++i) more.push_back(gyro(t_at(12'346.0, i), 1.5));
  write_in_commits(*writer, 1, more, {333});
  writer->stop();
  EXPECT_EQ(writer->stats().duplicates, 1u + 679u);
  Database db = open_ok(path);
  expect_rollup_matches_samples(db.handle());
}

// ---------------------------------------------------------------------------
// decimated_samples against a brute force over the raw rows.

enum class Path { kAsRecorded, kRawBuckets, kRollup };

const char* path_name(Path p) {
  switch (p) {
    case Path::kAsRecorded:
      return "as recorded";
    case Path::kRawBuckets:
      return "raw buckets";
    case Path::kRollup:
      return "rollup";
  }
  return "?";
}

Path path_of(const DecimatedSamples& d) {
  if (d.from_rollup) return Path::kRollup;
  return d.bucket_s == 0 ? Path::kAsRecorded : Path::kRawBuckets;
}

struct Acc {
  int64_t n = 0, rate_n = 0;
  double t_sum = 0, rate_sum = 0, rate_abs = 0;
  double lo = kNaN, hi = kNaN;
  void add(double t, double rate) {
    ++n;
    t_sum += t;
    if (std::isnan(rate)) return;
    rate_sum += rate;
    rate_abs += std::fabs(rate);
    lo = rate_n == 0 ? rate : std::min(lo, rate);
    hi = rate_n == 0 ? rate : std::max(hi, rate);
    ++rate_n;
  }
};

// Mean of the non-NaN values added; NaN if none.
struct Mean {
  int64_t n = 0;
  double sum = 0, abs_sum = 0;
  void add(double v) {
    if (std::isnan(v)) return;
    ++n;
    sum += v;
    abs_sum += std::fabs(v);
  }
};

void expect_mean(double got, const Mean& want, const std::string& what) {
  if (want.n == 0) {
    EXPECT_TRUE(std::isnan(got)) << what << ": " << got;
    return;
  }
  EXPECT_NEAR(got, want.sum / static_cast<double>(want.n),
              kRelTol * want.abs_sum / static_cast<double>(want.n) + 1e-300)
      << what;
}

// Checks `d` (= decimated_samples(run, from_s, to_s, max_points)) against
// the raw rows of the run. `to_s` is the resolved end (last sample if the
// call passed nullopt).
void check_decimated(const DecimatedSamples& d, const std::vector<RawGyro>& gyro_rows,
                     const std::vector<RawTemp>& temp_rows, double from_s, double to_s,
                     int max_points) {
  const auto& g = d.gyro;
  const std::size_t m = g.t_s.size();
  ASSERT_EQ(g.n.size(), m);
  ASSERT_EQ(g.mean_dph.size(), m);
  ASSERT_EQ(g.min_dph.size(), m);
  ASSERT_EQ(g.max_dph.size(), m);
  EXPECT_LE(m, static_cast<std::size_t>(max_points)) << path_name(path_of(d));
  for (std::size_t i = 1; i < m; ++i) ASSERT_LT(g.t_s[i - 1], g.t_s[i]) << "bucket " << i;

  // The covered range and each raw sample's bucket index k (-1: outside).
  const Path path = path_of(d);
  std::function<int64_t(double)> bucket_of;
  if (path == Path::kRollup) {
    EXPECT_LE(d.from_s, from_s);
    EXPECT_GE(d.to_s, to_s);
    EXPECT_GT(d.bucket_s, 0);
    // Buckets are whole blocks: from_s and bucket_s are multiples of a block.
    bool whole = false;
    for (double block_s : kRollupBlockS) {
      const double f = d.from_s / block_s, b = d.bucket_s / block_s;
      if (std::fabs(f - std::round(f)) < 1e-6 && std::fabs(b - std::round(b)) < 1e-6 &&
          std::round(b) >= 1 && d.from_s > from_s - block_s) {
        whole = true;
      }
    }
    EXPECT_TRUE(whole) << "from_s " << d.from_s << " bucket_s " << d.bucket_s;
    // The block or two beyond max_points buckets that widening to block
    // edges may add go into the last bucket.
    bucket_of = [&](double t) -> int64_t {
      if (t < d.from_s || t >= d.to_s) return -1;
      return std::min<int64_t>(static_cast<int64_t>(std::floor((t - d.from_s) / d.bucket_s)),
                               max_points - 1);
    };
  } else {
    EXPECT_EQ(d.from_s, from_s);
    EXPECT_EQ(d.to_s, to_s);
    if (path == Path::kRawBuckets) {
      EXPECT_DOUBLE_EQ(d.bucket_s, (to_s - from_s) / max_points);
      bucket_of = [&](double t) -> int64_t {
        if (t < from_s || t > to_s) return -1;
        return std::min<int64_t>(static_cast<int64_t>(std::floor((t - from_s) / d.bucket_s)),
                                 max_points - 1);  // t == to_s: the last bucket
      };
    }
  }

  if (path == Path::kAsRecorded) {
    std::vector<RawGyro> in;
    for (const RawGyro& r : gyro_rows) {
      if (r.t_s >= from_s && r.t_s <= to_s) in.push_back(r);
    }
    ASSERT_EQ(m, in.size());
    for (std::size_t i = 0; i < m; ++i) {
      EXPECT_EQ(g.t_s[i], in[i].t_s);
      EXPECT_EQ(g.n[i], 1);
      if (std::isnan(in[i].rate_dph)) {
        EXPECT_TRUE(std::isnan(g.mean_dph[i]) && std::isnan(g.min_dph[i]) &&
                    std::isnan(g.max_dph[i]))
            << "t " << in[i].t_s;
      } else {
        EXPECT_EQ(g.mean_dph[i], in[i].rate_dph);
        EXPECT_EQ(g.min_dph[i], in[i].rate_dph);
        EXPECT_EQ(g.max_dph[i], in[i].rate_dph);
      }
    }
  } else {
    std::map<int64_t, Acc> want;
    int64_t covered = 0;
    for (const RawGyro& r : gyro_rows) {
      const int64_t k = bucket_of(r.t_s);
      if (k < 0) continue;
      want[k].add(r.t_s, r.rate_dph);
      ++covered;
    }
    int64_t n_total = 0;
    for (int64_t n : g.n) n_total += n;
    EXPECT_EQ(n_total, covered);
    ASSERT_EQ(m, want.size()) << path_name(path);
    std::size_t i = 0;
    for (const auto& [k, a] : want) {
      const std::string what = std::string(path_name(path)) + " bucket " + std::to_string(k);
      EXPECT_EQ(g.n[i], a.n) << what;
      EXPECT_NEAR(g.t_s[i], a.t_sum / static_cast<double>(a.n),
                  kRelTol * std::fabs(a.t_sum / static_cast<double>(a.n)) + 1e-12)
          << what;
      EXPECT_EQ(bucket_of(g.t_s[i]), k) << what << ": mean time outside the bucket";
      expect_mean(g.mean_dph[i], Mean{a.rate_n, a.rate_sum, a.rate_abs}, what);
      if (a.rate_n == 0) {
        EXPECT_TRUE(std::isnan(g.min_dph[i]) && std::isnan(g.max_dph[i])) << what;
      } else {
        EXPECT_EQ(g.min_dph[i], a.lo) << what;
        EXPECT_EQ(g.max_dph[i], a.hi) << what;
      }
      ++i;
    }
    // The envelope a plot draws: every raw sample lies within its bucket's
    // [min, max], the bucket found from the returned times alone.
    std::map<int64_t, std::size_t> index_of;
    for (std::size_t j = 0; j < m; ++j) index_of[bucket_of(g.t_s[j])] = j;
    int outside = 0;
    for (const RawGyro& r : gyro_rows) {
      const int64_t k = bucket_of(r.t_s);
      if (k < 0 || std::isnan(r.rate_dph)) continue;
      const auto it = index_of.find(k);
      if (it == index_of.end() || !(g.min_dph[it->second] <= r.rate_dph) ||
          !(r.rate_dph <= g.max_dph[it->second])) {
        ++outside;
      }
    }
    EXPECT_EQ(outside, 0) << "raw samples outside their bucket's envelope";
  }

  // Temperatures: means per bucket of the same width (the asked-for width
  // when the gyro is as recorded) over the returned range.
  const auto& tp = d.temperature;
  const std::size_t mt = tp.t_s.size();
  ASSERT_EQ(tp.setpoint_c.size(), mt);
  ASSERT_EQ(tp.chamber_c.size(), mt);
  ASSERT_EQ(tp.top_c.size(), mt);
  ASSERT_EQ(tp.side_c.size(), mt);
  EXPECT_LE(mt, static_cast<std::size_t>(max_points));
  double width_s = d.bucket_s > 0 ? d.bucket_s : (to_s - from_s) / max_points;
  if (width_s == 0) width_s = 1.0;
  struct TempAcc {
    Mean t, sp, ch, top, side;
  };
  std::map<int64_t, TempAcc> want;
  for (const RawTemp& r : temp_rows) {
    if (r.t_s < d.from_s || r.t_s > d.to_s) continue;
    const int64_t k = std::min<int64_t>(
        static_cast<int64_t>(std::floor((r.t_s - d.from_s) / width_s)), max_points - 1);
    TempAcc& a = want[k];
    a.t.add(r.t_s);
    a.sp.add(r.setpoint_c);
    a.ch.add(r.chamber_c);
    a.top.add(r.top_c);
    a.side.add(r.side_c);
  }
  ASSERT_EQ(mt, want.size());
  std::size_t i = 0;
  for (const auto& [k, a] : want) {
    const std::string what = "temperature bucket " + std::to_string(k);
    expect_mean(tp.t_s[i], a.t, what + " t_s");
    expect_mean(tp.setpoint_c[i], a.sp, what + " setpoint");
    expect_mean(tp.chamber_c[i], a.ch, what + " chamber");
    expect_mean(tp.top_c[i], a.top, what + " top");
    expect_mean(tp.side_c[i], a.side, what + " side");
    if (i > 0) {
      EXPECT_LT(tp.t_s[i - 1], tp.t_s[i]);
    }
    ++i;
  }
}

// One database shared by the decimation tests (built once, read only).
//  run 1: 0 ... 130 s at 1 kHz (130 k samples, more than the raw-row
//         budget in one 1000 s block); every 101st rate missing and none in
//         [60, 62) s; temperatures at 1 Hz, top probe missing in [60, 62).
//  run 2: -50 ... 150 s at 20 Hz (4000 samples); temperatures at 1 Hz.
//  run 3: five samples; a temperature after the last one.
//  run 4: 0 ... 50 s at 100 Hz, no rate at all.
class Decimate : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir;
    path_ = new std::string(dir_->file("station.db"));
    auto writer = start_flushing(*path_);
    std::mt19937_64 rng(11);
    std::normal_distribution<double> noise(0.0, 1.0);
    std::vector<GyroSample> run1;
    for (int i = 0; i < 130'000; ++i) {
      const double t = t_at(0.0, i);
      const bool missing = i % 101 == 0 || (t >= 60.0 && t < 62.0);
      run1.push_back(gyro(t, missing ? kNaN : 0.8 + 3.0 * std::sin(i * 1.23e-4) + noise(rng)));
    }
    write_in_commits(*writer, 1, run1, {7919, 30'011});
    std::vector<GyroSample> run2;
    for (int j = 0; j < 4000; ++j) run2.push_back(gyro(t_at(-50.0, j, 0.05), -3.0 + noise(rng)));
    write_in_commits(*writer, 2, run2, {1001});
    std::vector<GyroSample> run3;
    for (double t : {0.5, 1.5, 2.5, 3.5, 4.5}) run3.push_back(gyro(t, t * 2.0));
    write_in_commits(*writer, 3, run3, {5});
    std::vector<GyroSample> run4;
    for (int i = 0; i < 5000; ++i) run4.push_back(gyro(t_at(0.0, i, 0.01), kNaN));
    write_in_commits(*writer, 4, run4, {5000});
    for (int j = 0; j < 130; ++j) {
      const bool gap = j >= 60 && j < 62;
      writer->push_temperature(1, {.t_s = j + 0.25,
                                   .setpoint_c = j < 65 ? 20.0 : 40.0,
                                   .chamber_c = 20.0 + j * 0.15,
                                   .top_c = gap ? kNaN : 20.5 + j * 0.1,
                                   .side_c = 20.25 + j * 0.1});
    }
    writer->push_temperature(
        3, {.t_s = 6.0, .setpoint_c = 1, .chamber_c = 2, .top_c = 3, .side_c = kNaN});
    for (int j = -50; j < 150; ++j) {
      writer->push_temperature(
          2, {.t_s = j + 0.5, .setpoint_c = 0, .chamber_c = -j * 0.01, .top_c = 1, .side_c = 2});
    }
    ASSERT_TRUE(writer->flush().ok());
    writer->stop();
    Database db = open_ok(*path_);
    rows_ = new std::vector<RawGyro>(read_raw_gyro(db.handle()));
    temps_ = new std::map<int64_t, std::vector<RawTemp>>;
    for (int64_t run : {1, 2, 3, 4}) (*temps_)[run] = read_raw_temps(db.handle(), run);
  }
  static void TearDownTestSuite() {
    delete rows_;
    delete temps_;
    delete path_;
    delete dir_;
  }

  // decimated_samples checked against the brute force; returns it.
  static DecimatedSamples check(int64_t run, double from_s, std::optional<double> to_s,
                                int max_points, Path expected) {
    Database db = open_ok(*path_);
    auto d = db.decimated_samples(run, from_s, to_s, max_points);
    EXPECT_TRUE(d.ok()) << d.error().message;
    if (!d) return {};
    double to = 0;
    if (to_s) {
      to = *to_s;
    } else {
      auto last = db.last_sample_t_s(run);
      EXPECT_TRUE(last.ok() && last->has_value());
      to = last->value_or(from_s);
    }
    SCOPED_TRACE(::testing::Message()
                 << "run " << run << " [" << from_s << ", " << to << "] max_points " << max_points);
    EXPECT_EQ(path_of(*d), expected)
        << "got " << path_name(path_of(*d)) << ", " << d->gyro.t_s.size() << " points";
    check_decimated(*d, of_run(*rows_, run), (*temps_)[run], from_s, to, max_points);
    return std::move(*d);
  }

  static TempDir* dir_;
  static std::string* path_;
  static std::vector<RawGyro>* rows_;
  static std::map<int64_t, std::vector<RawTemp>>* temps_;
};

TempDir* Decimate::dir_ = nullptr;
std::string* Decimate::path_ = nullptr;
std::vector<RawGyro>* Decimate::rows_ = nullptr;
std::map<int64_t, std::vector<RawTemp>>* Decimate::temps_ = nullptr;

TEST_F(Decimate, WholeRunFromTheRollup) {
  // 0.26 s asked for, finer than the finest block (1 s) over 130 k samples
  // (within the raw budget): exact buckets from the decoded chunks.
  auto d = check(1, 0, std::nullopt, 500, Path::kRawBuckets);
  EXPECT_GT(d.gyro.t_s.size(), 400u);
  // 3.25 s asked for: 1 s blocks, 4 a bucket.
  d = check(1, 0, std::nullopt, 40, Path::kRollup);
  EXPECT_DOUBLE_EQ(d.bucket_s, 4.0);
  check(1, 0, std::nullopt, 1, Path::kRollup);
  check(2, -50, std::nullopt, 300, Path::kRawBuckets);  // 0.67 s < the finest block
  check(2, -50, 150, 7, Path::kRollup);
}

TEST_F(Decimate, FinerThanTheFinestBlockOverManyRowsUsesTheFinestBlocks) {
  // 13 ms asked for over 130 k samples: within the raw budget (1 M samples
  // decoded), so exact buckets of 13 ms; beyond it the 1 s blocks.
  auto d = check(1, 0, 130, 10'000, Path::kRawBuckets);
  EXPECT_DOUBLE_EQ(d.bucket_s, 0.013);
  EXPECT_GT(d.gyro.t_s.size(), 9'000u);
}

TEST_F(Decimate, RangeNotOnBlockEdgesStaysWithinMaxPoints) {
  // 10 s over 10 points: 1 s blocks, but [0.5, 10.5] touches 11 of them.
  auto d = check(1, 0.5, 10.5, 10, Path::kRollup);
  EXPECT_EQ(d.gyro.t_s.size(), 10u);
  EXPECT_EQ(d.bucket_s, 1.0);
  EXPECT_EQ(d.gyro.n.back(), 2000);              // blocks 9 and 10: 9 ... 11 s
  check(1, 0.99, 10.01, 10, Path::kRawBuckets);  // 0.902 s < the finest block
  check(1, 0.05, 100.05, 100, Path::kRollup);
  check(1, 3.05, 123.95, 12, Path::kRollup);
  check(2, -49.95, 49.95, 99, Path::kRollup);
}

TEST_F(Decimate, ShortZoomsReadRawRows) {
  // Fewer rows than points: as recorded.
  check(1, 10.05, 10.25, 1000, Path::kAsRecorded);
  check(2, -49, -48.5, 100, Path::kAsRecorded);
  check(3, 0, std::nullopt, 100, Path::kAsRecorded);
  check(3, 1.5, 3.5, 3, Path::kAsRecorded);
  // More rows than points, buckets narrower than 0.1 s: raw buckets.
  auto d = check(1, 10.05, 10.95, 100, Path::kRawBuckets);
  EXPECT_EQ(d.gyro.t_s.size(), 100u);
  check(1, 20, 21, 333, Path::kRawBuckets);
  check(2, -20, 20, 600, Path::kRawBuckets);
}

TEST_F(Decimate, BucketsWithoutARateAreNaNNotZero) {
  // 1 s blocks from 50 s: two buckets in [60, 62) have no rate.
  auto d = check(1, 50, 70, 20, Path::kRollup);
  EXPECT_DOUBLE_EQ(d.bucket_s, 1.0);
  int nan_buckets = 0;
  for (std::size_t i = 0; i < d.gyro.t_s.size(); ++i) {
    if (d.gyro.t_s[i] >= 60 && d.gyro.t_s[i] < 62) {
      EXPECT_GT(d.gyro.n[i], 0);
      EXPECT_TRUE(std::isnan(d.gyro.mean_dph[i]));
      EXPECT_TRUE(std::isnan(d.gyro.min_dph[i]));
      EXPECT_TRUE(std::isnan(d.gyro.max_dph[i]));
      ++nan_buckets;
    }
  }
  EXPECT_EQ(nan_buckets, 2);
  check(1, 60.05, 60.95, 50, Path::kRawBuckets);
  check(1, 60.05, 60.15, 1000, Path::kAsRecorded);
  for (auto [mp, path] : {std::pair{10, Path::kRollup}, std::pair{100, Path::kRawBuckets},
                          std::pair{10'000, Path::kAsRecorded}}) {
    d = check(4, 0, std::nullopt, mp, path);
    ASSERT_FALSE(d.gyro.mean_dph.empty());
    for (double v : d.gyro.mean_dph) EXPECT_TRUE(std::isnan(v));
    for (double v : d.gyro.max_dph) EXPECT_TRUE(std::isnan(v));
  }
  d = check(4, 0, 2, 50, Path::kRawBuckets);
  ASSERT_EQ(d.gyro.t_s.size(), 50u);
  for (double v : d.gyro.min_dph) EXPECT_TRUE(std::isnan(v));
}

TEST_F(Decimate, DefaultsErrorsAndUnknownRuns) {
  Database db = open_ok(*path_);
  // to: the last sample of the run, here a temperature after the last gyro
  // sample.
  auto d = db.decimated_samples(3, 0, std::nullopt, 100);
  ASSERT_TRUE(d.ok()) << d.error().message;
  EXPECT_EQ(d->to_s, 6.0);
  EXPECT_EQ(d->gyro.t_s.size(), 5u);
  EXPECT_EQ(d->temperature.t_s.size(), 1u);
  d = db.decimated_samples(2, 0, std::nullopt, 1);
  ASSERT_TRUE(d.ok()) << d.error().message;
  EXPECT_GE(d->to_s, 149.9004);

  for (int bad : {0, -1}) {
    auto e = db.decimated_samples(1, 0, 10, bad);
    ASSERT_FALSE(e.ok());
    EXPECT_NE(e.error().message.find("max_points"), std::string::npos) << e.error().message;
  }
  auto e = db.decimated_samples(1, 10, 5, 100);
  ASSERT_FALSE(e.ok());
  EXPECT_NE(e.error().message.find("range"), std::string::npos) << e.error().message;
  EXPECT_FALSE(db.decimated_samples(1, kNaN, 5, 100).ok());
  EXPECT_FALSE(db.decimated_samples(1, 0, std::numeric_limits<double>::infinity(), 100).ok());

  for (std::optional<double> to : {std::optional<double>(), std::optional<double>(100.0)}) {
    auto u = db.decimated_samples(99, 0, to, 100);
    ASSERT_TRUE(u.ok()) << u.error().message;
    EXPECT_TRUE(u->gyro.t_s.empty());
    EXPECT_TRUE(u->gyro.mean_dph.empty());
    EXPECT_TRUE(u->temperature.t_s.empty());
  }
  // A range with no samples of a known run.
  auto empty = db.decimated_samples(1, 500, 600, 100);
  ASSERT_TRUE(empty.ok()) << empty.error().message;
  EXPECT_TRUE(empty->gyro.t_s.empty());
  // A zero-length range on a sample.
  check(3, 2.5, 2.5, 10, Path::kAsRecorded);
}

// ---------------------------------------------------------------------------
// Fits.

TEST(Fits, RoundTripAndRunLinks) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  FitRecord a;
  a.run_ids = {1};
  a.model = "T4+R1+G1";
  a.form = "paper";
  a.n = 12'345;
  a.coefficients_json = R"({"T1":0.01,"G1":0.3})";
  a.standard_errors_json = R"({"T1":0.001,"G1":0.02})";
  a.residual_std_dph = 0.0523;
  a.r_squared = 0.987654321;
  a.inputs_json = R"({"bin_s":1})";
  a.computed_utc = "2026-11-21T05:38:43.120Z";
  FitRecord b = a;
  b.run_ids = {2, 1};
  b.model = "T2";
  b.form = "centered";
  b.computed_utc = "";
  b.inputs_json = "";

  auto id_a = db.add_fit(a);
  ASSERT_TRUE(id_a.ok()) << id_a.error().message;
  auto id_b = db.add_fit(b);
  ASSERT_TRUE(id_b.ok()) << id_b.error().message;
  EXPECT_NE(*id_a, *id_b);

  auto got = db.fit(*id_a);
  ASSERT_TRUE(got.ok()) << got.error().message;
  ASSERT_TRUE(got->has_value());
  const FitRecord& f = **got;
  EXPECT_EQ(f.id, *id_a);
  EXPECT_EQ(f.run_ids, std::vector<int64_t>{1});
  EXPECT_EQ(f.model, a.model);
  EXPECT_EQ(f.form, a.form);
  EXPECT_EQ(f.n, a.n);
  EXPECT_EQ(f.coefficients_json, a.coefficients_json);
  EXPECT_EQ(f.standard_errors_json, a.standard_errors_json);
  EXPECT_EQ(f.residual_std_dph, a.residual_std_dph);
  EXPECT_EQ(f.r_squared, a.r_squared);
  EXPECT_EQ(f.inputs_json, a.inputs_json);
  EXPECT_EQ(f.computed_utc, a.computed_utc);

  auto fb = db.fit(*id_b);
  ASSERT_TRUE(fb.ok() && fb->has_value());
  EXPECT_EQ((*fb)->run_ids, (std::vector<int64_t>{1, 2}));
  EXPECT_EQ((*fb)->inputs_json, "{}");
  EXPECT_FALSE((*fb)->computed_utc.empty());

  // Run 1: both, newest first; run 2: the two-run fit; run 3: none.
  auto fits1 = db.fits(1);
  ASSERT_TRUE(fits1.ok()) << fits1.error().message;
  ASSERT_EQ(fits1->size(), 2u);
  EXPECT_EQ((*fits1)[0].id, *id_b);
  EXPECT_EQ((*fits1)[1].id, *id_a);
  EXPECT_EQ((*fits1)[0].run_ids, (std::vector<int64_t>{1, 2}));
  auto fits2 = db.fits(2);
  ASSERT_TRUE(fits2.ok());
  ASSERT_EQ(fits2->size(), 1u);
  EXPECT_EQ((*fits2)[0].id, *id_b);
  EXPECT_EQ((*fits2)[0].model, "T2");
  auto fits3 = db.fits(3);
  ASSERT_TRUE(fits3.ok());
  EXPECT_TRUE(fits3->empty());

  auto none = db.fit(*id_b + 100);
  ASSERT_TRUE(none.ok()) << none.error().message;
  EXPECT_FALSE(none->has_value());
}

}  // namespace
}  // namespace gyrotherm::storage
