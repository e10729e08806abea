// Chunked sample storage (issue 18) beside today's row-per-sample layout,
// in one run. Prints a table; not a pass/fail test. See bench/README.md.
//
//   1. bytes per channel-sample: one hour of a KVH 1750 at 1 kHz (8
//      channels) written through SampleWriter::push_frames; the old layout
//      (gyro_samples WITHOUT ROWID + gyro_rollup, their DDL and insert kept
//      below) with the same hour of its one axis.
//   2. ingest: channel-samples per second end to end through SampleWriter
//      (push in 100-frame spans as a reader does, a flush() every 1 M frames
//      so nothing is dropped, until the last commit) for that hour.
//   3. a whole-run decimated query (2000 points) on a 10 M-sample run
//      (push_gyro, as the old bench), against the old layout's rollup query
//      on the same samples.
//   4. peak RSS of streaming one channel of an H-hour 1 kHz run through
//      Database::for_each_channel_block into 1-s bins, in a fresh process
//      (wait4's ru_maxrss).
//
// Usage: gyrotherm_bench_chunks [--hours H] [--dir D]   (H default 80)
#include <fmt/format.h>
#include <sqlite3.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/core/samples.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace {

namespace fs = std::filesystem;
using namespace gyrotherm;
using storage::Database;
using storage::SampleWriter;
using BenchClock = std::chrono::steady_clock;

double seconds_since(BenchClock::time_point t0) {
  return std::chrono::duration<double>(BenchClock::now() - t0).count();
}

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "chunks_bench: %s\n", what.c_str());
  std::exit(1);
}

template <class T>
T ok(Result<T> r, const char* what) {
  if (!r) die(fmt::format("{}: {}", what, r.error().message));
  return std::move(*r);
}
void ok(Status s, const char* what) {
  if (!s) die(fmt::format("{}: {}", what, s.error().message));
}

// Bytes the file's pages hold (after a WAL checkpoint), free pages excluded.
double used_bytes(const std::string& path) {
  sqlite3* db = nullptr;
  sqlite3_open(path.c_str(), &db);
  sqlite3_exec(db, "PRAGMA wal_checkpoint(TRUNCATE)", nullptr, nullptr, nullptr);
  auto q = [&](const char* sql) {
    sqlite3_stmt* st = nullptr;
    sqlite3_prepare_v2(db, sql, -1, &st, nullptr);
    sqlite3_step(st);
    const double v = sqlite3_column_double(st, 0);
    sqlite3_finalize(st);
    return v;
  };
  const double bytes =
      (q("PRAGMA page_count") - q("PRAGMA freelist_count")) * q("PRAGMA page_size");
  sqlite3_close(db);
  return bytes;
}

// ------------------------------------------------------------ the old layout
// Schema v1's gyro_samples and v3's gyro_rollup, and the old writer's
// inserts, kept here to compare against (the station no longer has them).
constexpr const char* kOldDdl = R"sql(
CREATE TABLE gyro_samples(run_id INTEGER NOT NULL, t_s REAL NOT NULL, seq INTEGER NOT NULL,
  rate_dph REAL, status INTEGER NOT NULL, temp_c INTEGER, PRIMARY KEY(run_id, t_s)) WITHOUT ROWID;
CREATE TABLE gyro_rollup(run_id INTEGER NOT NULL, level INTEGER NOT NULL, block INTEGER NOT NULL,
  n INTEGER NOT NULL, t_sum_s REAL NOT NULL, rate_n INTEGER NOT NULL, rate_sum_dph REAL,
  rate_min_dph REAL, rate_max_dph REAL, PRIMARY KEY(run_id, level, block)) WITHOUT ROWID;
)sql";
constexpr const char* kOldInsert =
    "INSERT OR IGNORE INTO gyro_samples(run_id, t_s, seq, rate_dph, status, temp_c) "
    "VALUES(?, ?, ?, ?, ?, ?)";
constexpr const char* kOldRollupUpsert =
    "INSERT INTO gyro_rollup(run_id, level, block, n, t_sum_s, rate_n, rate_sum_dph, "
    "rate_min_dph, rate_max_dph) VALUES(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9) "
    "ON CONFLICT(run_id, level, block) DO UPDATE SET n = n + ?4, t_sum_s = t_sum_s + ?5, "
    "rate_n = rate_n + ?6, rate_sum_dph = rate_sum_dph + ?7, "
    "rate_min_dph = min(rate_min_dph, ?8), rate_max_dph = max(rate_max_dph, ?9)";
constexpr double kOldBlockS[] = {0.1, 1.0, 10.0, 100.0, 1000.0};

// Writes samples into the old layout in 500-ms-of-data transactions as the
// old writer did (rows, then the batch's rollup upserts).
void write_old(const std::string& path, const std::vector<GyroSample>& samples) {
  sqlite3* db = nullptr;
  sqlite3_open(path.c_str(), &db);
  sqlite3_exec(db, "PRAGMA journal_mode=WAL; PRAGMA synchronous=NORMAL", nullptr, nullptr, nullptr);
  if (sqlite3_exec(db, kOldDdl, nullptr, nullptr, nullptr) != SQLITE_OK) die(sqlite3_errmsg(db));
  sqlite3_stmt *ins = nullptr, *up = nullptr;
  sqlite3_prepare_v2(db, kOldInsert, -1, &ins, nullptr);
  sqlite3_prepare_v2(db, kOldRollupUpsert, -1, &up, nullptr);
  struct Acc {
    int64_t n = 0;
    double t = 0, s = 0, mn = INFINITY, mx = -INFINITY;
  };
  constexpr std::size_t kBatch = 100'000;
  for (std::size_t b = 0; b < samples.size(); b += kBatch) {
    sqlite3_exec(db, "BEGIN", nullptr, nullptr, nullptr);
    std::map<std::pair<int, int64_t>, Acc> roll;
    for (std::size_t i = b; i < std::min(samples.size(), b + kBatch); ++i) {
      const GyroSample& g = samples[i];
      sqlite3_bind_int64(ins, 1, 1);
      sqlite3_bind_double(ins, 2, g.t_s);
      sqlite3_bind_int(ins, 3, g.seq);
      sqlite3_bind_double(ins, 4, g.rate_dph);
      sqlite3_bind_int(ins, 5, g.status);
      sqlite3_bind_int(ins, 6, g.temp_c);
      sqlite3_step(ins);
      sqlite3_reset(ins);
      for (int l = 0; l < 5; ++l) {
        Acc& a = roll[{l, static_cast<int64_t>(std::floor(g.t_s / kOldBlockS[l]))}];
        ++a.n;
        a.t += g.t_s;
        a.s += g.rate_dph;
        a.mn = std::min(a.mn, g.rate_dph);
        a.mx = std::max(a.mx, g.rate_dph);
      }
    }
    for (const auto& [k, a] : roll) {
      sqlite3_bind_int64(up, 1, 1);
      sqlite3_bind_int(up, 2, k.first);
      sqlite3_bind_int64(up, 3, k.second);
      sqlite3_bind_int64(up, 4, a.n);
      sqlite3_bind_double(up, 5, a.t);
      sqlite3_bind_int64(up, 6, a.n);
      sqlite3_bind_double(up, 7, a.s);
      sqlite3_bind_double(up, 8, a.mn);
      sqlite3_bind_double(up, 9, a.mx);
      sqlite3_step(up);
      sqlite3_reset(up);
    }
    sqlite3_exec(db, "COMMIT", nullptr, nullptr, nullptr);
  }
  sqlite3_finalize(ins);
  sqlite3_finalize(up);
  sqlite3_close(db);
}

// The old decimated_samples' gyro reads for a whole run, 2000 points: the
// count over 1000-s blocks, then 1-s blocks 5 a bucket.
double old_whole_run_query_ms(const std::string& path, double run_s) {
  sqlite3* db = nullptr;
  sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr);
  const auto t0 = BenchClock::now();
  sqlite3_stmt* st = nullptr;
  sqlite3_prepare_v2(db,
                     "SELECT coalesce(sum(n), 0) FROM gyro_rollup WHERE run_id = 1 AND level = 4 "
                     "AND block BETWEEN 0 AND ?",
                     -1, &st, nullptr);
  sqlite3_bind_int64(st, 1, static_cast<int64_t>(run_s / 1000));
  sqlite3_step(st);
  sqlite3_finalize(st);
  sqlite3_prepare_v2(
      db,
      "SELECT min((block - 0) / 5, 1999) AS b, sum(n), sum(t_sum_s), sum(rate_n), "
      "sum(rate_sum_dph), min(rate_min_dph), max(rate_max_dph) FROM gyro_rollup "
      "WHERE run_id = 1 AND level = 1 AND block BETWEEN 0 AND ? GROUP BY b ORDER BY b",
      -1, &st, nullptr);
  sqlite3_bind_int64(st, 1, static_cast<int64_t>(run_s));
  int points = 0;
  while (sqlite3_step(st) == SQLITE_ROW) ++points;
  sqlite3_finalize(st);
  const double ms = seconds_since(t0) * 1e3;
  sqlite3_close(db);
  if (points < 1900) die(fmt::format("old query: {} points", points));
  return ms;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// A KVH 1750 as the drivers describe it (dut_channels): 3 rates in rad/s as
// float32 scaled to deg/h, 3 accelerations (g), status, temperature.
storage::RunDutRecord kvh_dut(int64_t run_id, const std::string& serial, int n_channels) {
  storage::RunDutRecord d;
  d.run_id = run_id;
  d.dut.serial = serial;
  d.dut.model = "KVH 1750";
  d.primary_axis = "z";
  d.axes = {"x", "y", "z"};
  d.rate_hz = 1000;
  d.seq_modulo = 128;
  const double rad_to_dph = 180.0 / M_PI * 3600.0;
  const ChannelSpec all[] = {{"gyro_z", "deg/h", ChannelKind::kRate, "z", rad_to_dph},
                             {"gyro_x", "deg/h", ChannelKind::kRate, "x", rad_to_dph},
                             {"gyro_y", "deg/h", ChannelKind::kRate, "y", rad_to_dph},
                             {"accel_x", "g", ChannelKind::kAccel, "x", 1},
                             {"accel_y", "g", ChannelKind::kAccel, "y", 1},
                             {"accel_z", "g", ChannelKind::kAccel, "z", 1},
                             {"status", "", ChannelKind::kStatus, "", 1},
                             {"temp_c", "degC", ChannelKind::kTemperature, "", 1}};
  for (int i = 0; i < n_channels; ++i) d.channels.push_back({0, run_id, 0, i, all[i]});
  return d;
}

// Frame i of the simulated KVH: float32 rates (noise + Earth rate) and
// accelerations, status 0x77, a slowly rising whole-degree temperature.
struct KvhSource {
  std::mt19937_64 rng{18};
  std::normal_distribution<float> noise{0.0f, 1.0f};
  DutFrame frame(int64_t i) {
    DutFrame f;
    f.t_s = static_cast<double>(i) * 0.001;
    f.seq = static_cast<uint32_t>(i % 128);
    for (int c = 0; c < 3; ++c) f.raw[c] = static_cast<float>(3.5e-5 + 2e-6 * noise(rng));
    for (int c = 3; c < 6; ++c)
      f.raw[c] = static_cast<float>((c == 5 ? 1.0 : 0.0) + 1e-4 * noise(rng));
    f.raw[6] = 0x77;
    f.raw[7] = 20 + static_cast<double>(i / 600'000);
    return f;
  }
};

// Writes `frames` frames through a SampleWriter; returns wall seconds.
double ingest(const std::string& path, const storage::RunDutRecord& dut, int64_t frames) {
  auto writer = ok(SampleWriter::start(path), "starting the writer");
  KvhSource src;
  std::vector<DutFrame> span(100);
  const auto t0 = BenchClock::now();
  for (int64_t i = 0; i < frames; i += 100) {
    for (int64_t k = 0; k < 100; ++k) span[static_cast<std::size_t>(k)] = src.frame(i + k);
    writer->push_frames(dut, span);
    if ((i + 100) % 1'000'000 == 0) ok(writer->flush(), "flush");
  }
  ok(writer->flush(), "flush");
  const double s = seconds_since(t0);
  writer->stop();
  const auto st = writer->stats();
  if (st.dropped != 0 || st.gyro_rows != static_cast<uint64_t>(frames)) {
    die(fmt::format("writer dropped {} / stored {} frames", st.dropped, st.gyro_rows));
  }
  return s;
}

storage::RunDutRecord new_run_with_dut(const std::string& path, int n_channels) {
  auto db = ok(Database::open(path), "opening");
  storage::RunRecord run;
  run.schedule_name = "bench";
  run.state = "completed";
  const int64_t run_id = ok(db.create_run(run), "creating the run");
  return ok(db.add_run_dut(run_id, kvh_dut(run_id, "BENCH-1", n_channels)), "add_run_dut");
}

// Child mode: stream channel `channel_id` into 1-s bins; prints the bins.
int stream_mode(const std::string& path, int64_t channel_id) {
  auto db = ok(Database::open_read_only(path), "opening read-only");
  int64_t bins = 0, n = 0, bin = INT64_MIN;
  double sum = 0, checksum = 0;
  ok(db.for_each_channel_block(
         channel_id, -1e300, 1e300,
         [&](std::span<const double> t, std::span<const double> v, std::span<const uint32_t>) {
           for (std::size_t i = 0; i < t.size(); ++i) {
             const auto b = static_cast<int64_t>(std::floor(t[i]));
             if (b != bin) {
               if (n > 0) checksum += sum / static_cast<double>(n);
               bin = b;
               ++bins;
               n = 0;
               sum = 0;
             }
             ++n;
             sum += v[i];
           }
           return true;
         }),
     "streaming");
  // This process's peak RSS (VmHWM: since exec, so the parent's memory does
  // not count).
  long hwm_kib = -1;
  if (FILE* f = std::fopen("/proc/self/status", "r")) {
    char line[256];
    while (std::fgets(line, sizeof line, f)) {
      if (std::strncmp(line, "VmHWM:", 6) == 0) hwm_kib = std::atol(line + 6);
    }
    std::fclose(f);
  }
  std::printf("%lld %.17g %ld\n", static_cast<long long>(bins), checksum, hwm_kib);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  double hours = 80;
  std::string dir = fs::temp_directory_path().string();
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--stream" && i + 2 < argc) return stream_mode(argv[i + 1], std::atoll(argv[i + 2]));
    if (a == "--hours" && i + 1 < argc) {
      hours = std::atof(argv[++i]);
    } else if (a == "--dir" && i + 1 < argc) {
      dir = argv[++i];
    } else {
      die(fmt::format("unknown argument '{}' (usage: [--hours H] [--dir D])", a));
    }
  }
  const fs::path d = fs::path(dir) / fmt::format("gyrotherm-bench-chunks-{}", getpid());
  fs::create_directories(d);
  std::printf("chunks_bench in %s\n\n", d.c_str());

  // 1 + 2: one hour of a KVH 1750, 8 channels.
  constexpr int64_t kHourFrames = 3'600'000;
  const std::string kvh_path = (d / "kvh-1h.db").string();
  const auto kvh = new_run_with_dut(kvh_path, 8);
  const double ingest_s = ingest(kvh_path, kvh, kHourFrames);
  const double kvh_samples = static_cast<double>(kHourFrames) * 8;
  const double kvh_bytes = used_bytes(kvh_path);

  // The old layout with the same hour of the primary axis (one sample per
  // frame: what it stored).
  std::vector<GyroSample> old_hour;
  {
    KvhSource src;
    old_hour.reserve(kHourFrames);
    for (int64_t i = 0; i < kHourFrames; ++i) {
      const DutFrame f = src.frame(i);
      old_hour.push_back({f.t_s, f.raw[0] * kvh.channels[0].spec.scale, static_cast<uint8_t>(f.seq),
                          0x77, static_cast<int16_t>(f.raw[7])});
    }
  }
  const std::string old_hour_path = (d / "old-1h.db").string();
  const auto old_t0 = BenchClock::now();
  write_old(old_hour_path, old_hour);
  const double old_ingest_s = seconds_since(old_t0);
  const double old_bytes = used_bytes(old_hour_path);
  old_hour = {};

  // 3: 10 M samples through push_gyro (the old API; rate, status, temp_c)
  // and the same in the old layout.
  constexpr int64_t k10M = 10'000'000;
  const std::string new10_path = (d / "new-10M.db").string();
  std::vector<GyroSample> ten_m;
  ten_m.reserve(k10M);
  {
    std::mt19937_64 rng(4);
    std::normal_distribution<double> noise(0, 31.6);
    for (int64_t i = 0; i < k10M; ++i) {
      const double t = static_cast<double>(i) * 0.001;
      ten_m.push_back({t, 10.4 + 2 * std::sin(t / 7200 * 2 * M_PI) + noise(rng),
                       static_cast<uint8_t>(i % 128), 0x77, 21});
    }
    auto writer = ok(SampleWriter::start(new10_path), "starting the writer");
    for (int64_t i = 0; i < k10M; i += 1000) {
      writer->push_gyro(1, std::span(ten_m).subspan(static_cast<std::size_t>(i), 1000));
      if ((i + 1000) % 1'000'000 == 0) ok(writer->flush(), "flush");
    }
    ok(writer->flush(), "flush");
  }
  const std::string old10_path = (d / "old-10M.db").string();
  write_old(old10_path, ten_m);
  ten_m = {};
  std::vector<double> new_ms, old_ms;
  for (int rep = 0; rep < 7; ++rep) {
    auto db = ok(Database::open_read_only(new10_path), "opening");
    const auto t0 = BenchClock::now();
    auto dec = ok(db.decimated_samples(1, 0, std::nullopt, 2000), "decimated_samples");
    new_ms.push_back(seconds_since(t0) * 1e3);
    if (dec.gyro.t_s.size() < 1900) die(fmt::format("{} points", dec.gyro.t_s.size()));
    old_ms.push_back(old_whole_run_query_ms(old10_path, 10'000));
  }
  const double new10_bytes = used_bytes(new10_path);
  const double old10_bytes = used_bytes(old10_path);
  fs::remove(old10_path);
  fs::remove(old_hour_path);

  // 4: an H-hour run of one channel (the primary axis), streamed in 1-s
  // bins by a fresh process.
  const auto long_frames = static_cast<int64_t>(hours * 3600 * 1000);
  const std::string long_path = (d / "long.db").string();
  const auto axis = new_run_with_dut(long_path, 1);
  const double long_ingest_s = ingest(long_path, axis, long_frames);
  const double long_bytes = used_bytes(long_path);
  const std::string self = fs::read_symlink("/proc/self/exe").string();
  const std::string cmd =
      fmt::format("'{}' --stream '{}' {}", self, long_path, axis.channels[0].id);
  const auto stream_t0 = BenchClock::now();
  FILE* child = popen(cmd.c_str(), "r");
  if (!child) die("cannot start the streaming child");
  long long bins = 0;
  double checksum = 0;
  long hwm_kib = -1;
  const int got = std::fscanf(child, "%lld %lf %ld", &bins, &checksum, &hwm_kib);
  if (pclose(child) != 0 || got != 3) die("the streaming child failed");
  const double stream_s = seconds_since(stream_t0);
  if (bins < static_cast<long long>(hours * 3600) - 1) die(fmt::format("{} bins", bins));

  std::printf("| Figure | chunks (v9) | rows (old layout) | goal |\n|---|---|---|---|\n");
  std::printf(
      "| bytes per channel-sample, KVH 1750 1 kHz, 1 h (8 channels) | **%.2f** (%.0f MB/h) "
      "| %.1f per sample, one axis (%.0f MB/h) | <= 5 |\n",
      kvh_bytes / kvh_samples, kvh_bytes / 1e6, old_bytes / kHourFrames, old_bytes / 1e6);
  std::printf(
      "| ingest, channel-samples/s end to end (SampleWriter) | **%.2f M** (%.1f s for %.1f M) "
      "| %.2f M rows/s (SQLite inserts alone) | >= 5 M |\n",
      kvh_samples / ingest_s / 1e6, ingest_s, kvh_samples / 1e6, kHourFrames / old_ingest_s / 1e6);
  std::printf(
      "| whole-run decimated query, 10 M samples, 2000 points, ms (median of 7) | **%.1f** "
      "| %.1f (the old rollup query) | no slower than 17 |\n",
      median(new_ms), median(old_ms));
  std::printf(
      "| 10 M push_gyro samples (rate f64 + status + temp_c): file bytes per sample | %.2f "
      "| %.1f | |\n",
      new10_bytes / k10M, old10_bytes / k10M);
  std::printf(
      "| %.1f-h 1 kHz run, one channel: file size | %.2f GB (%.2f B/sample), written in "
      "%.0f s | | |\n",
      hours, long_bytes / 1e9, long_bytes / static_cast<double>(long_frames), long_ingest_s);
  std::printf(
      "| streaming it in 1-s bins (for_each_channel_block), fresh process | peak RSS "
      "**%.1f MiB** (VmHWM), %.1f s (%.0f M samples/s), %lld bins | | bounded |\n",
      hwm_kib / 1024.0, stream_s, long_frames / stream_s / 1e6, bins);
  fs::remove_all(d);
  return 0;
}
