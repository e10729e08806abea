// Ingest-path benchmark (issue 2): KVH 1750 frames -> Kvh1750Parser ->
// GyroSample -> SampleWriter -> SQLite, beside raw SQLite inserts into a table
// of the same shape on the same file system. Prints figures; it is not a
// pass/fail test. See bench/README.md.
//
// The stream is 1 M frames of a gyro at 1000 Hz (rad/s, Z axis; Earth rate +
// bias + white noise of about 1 °/h per 1 s sample), encoded once before any
// timing. Database files live in a fresh directory under $TMPDIR (/tmp).
#include <benchmark/benchmark.h>
#include <sqlite3.h>
#include <stdlib.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <map>
#include <numbers>
#include <random>
#include <span>
#include <string>
#include <system_error>
#include <vector>

#include "gyrotherm/core/samples.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/drivers/kvh1750.h"
#include "gyrotherm/storage/sample_writer.h"

namespace {

namespace fs = std::filesystem;
using gyrotherm::GyroSample;
using gyrotherm::drivers::AngleUnit;
using gyrotherm::drivers::GyroFormat;
using gyrotherm::drivers::GyroFrame;
using gyrotherm::drivers::Kvh1750Parser;
using gyrotherm::drivers::OutputKind;
using gyrotherm::storage::SampleWriter;
using SteadyClock = std::chrono::steady_clock;

constexpr int64_t kSamples = 1'000'000;
constexpr std::size_t kChunkBytes = 4096;  // GyroReader's read buffer
constexpr int64_t kRowsPerTxn = 50'000;    // SQLite baseline
constexpr int64_t kRunId = 1;
const GyroFormat kFormat{AngleUnit::kRad, OutputKind::kRate, /*axis=*/2, /*rate_hz=*/1000.0};

double seconds_since(SteadyClock::time_point t0) {
  return std::chrono::duration<double>(SteadyClock::now() - t0).count();
}

// items/s of each benchmark's last run, for the summary printed after all runs.
std::map<std::string, double>& rates() {
  static std::map<std::string, double> r;
  return r;
}

float dph_to_rad_s(double rate_dph) {
  return static_cast<float>(rate_dph / 3600.0 * std::numbers::pi / 180.0);
}

const std::vector<uint8_t>& encoded_stream() {
  static const std::vector<uint8_t> bytes = [] {
    std::mt19937_64 rng(20240601);
    const double white_dph = 1.0 * std::sqrt(kFormat.rate_hz);  // 1 °/h per 1 s sample
    std::normal_distribution<double> gyro_noise(0.0, white_dph);
    std::normal_distribution<double> accel_noise(0.0, 1e-4);
    const double earth_z_dph = 15.041 * std::sin(55.75 * std::numbers::pi / 180.0);
    const double bias_dph = 0.8;
    std::vector<uint8_t> out;
    out.reserve(static_cast<std::size_t>(kSamples) * gyrotherm::drivers::kKvh1750FrameSize);
    for (int64_t n = 0; n < kSamples; ++n) {
      GyroFrame f;
      f.gyro = {dph_to_rad_s(gyro_noise(rng)), dph_to_rad_s(gyro_noise(rng)),
                dph_to_rad_s(earth_z_dph + bias_dph + gyro_noise(rng))};
      f.accel = {static_cast<float>(0.002 + accel_noise(rng)),
                 static_cast<float>(-0.001 + accel_noise(rng)),
                 static_cast<float>(1.0 + accel_noise(rng))};
      f.status = 0x77;
      f.seq = static_cast<uint8_t>(n % gyrotherm::drivers::kKvh1750SeqModulo);
      f.temp_c = static_cast<int16_t>(20 + n / 100'000);  // slow warm-up
      const auto frame = gyrotherm::drivers::encode_kvh1750(f);
      out.insert(out.end(), frame.begin(), frame.end());
    }
    return out;
  }();
  return bytes;
}

// Frames -> samples as GyroReader does: t_s from the frame count and the
// device rate, the axis value in °/h, frames with the axis flagged invalid
// skipped. `n` counts frames across calls.
void frames_to_samples(const std::vector<GyroFrame>& frames, uint64_t& n,
                       std::vector<GyroSample>& out) {
  const auto axis = static_cast<std::size_t>(kFormat.axis);
  for (const GyroFrame& f : frames) {
    const double t_s = static_cast<double>(n++) / kFormat.rate_hz;
    if ((f.status & (1u << axis)) == 0) continue;
    GyroSample s;
    s.t_s = t_s;
    s.rate_dph = gyrotherm::drivers::to_rate_dph(f.gyro[axis], kFormat);
    s.seq = f.seq;
    s.status = f.status;
    s.temp_c = f.temp_c;
    out.push_back(s);
  }
}

// The whole stream as samples, for the SQLite baseline's bound values.
const std::vector<GyroSample>& decoded_samples() {
  static const std::vector<GyroSample> samples = [] {
    Kvh1750Parser parser;
    std::vector<GyroFrame> frames;
    parser.feed(encoded_stream(), frames);
    std::vector<GyroSample> out;
    uint64_t n = 0;
    frames_to_samples(frames, n, out);
    return out;
  }();
  return samples;
}

// A fresh directory under the temp directory, removed with everything in it.
class TempDir {
 public:
  TempDir() {
    std::string tmpl = (fs::temp_directory_path() / "gyrotherm-bench-XXXXXX").string();
    if (mkdtemp(tmpl.data()) != nullptr) path_ = tmpl;
  }
  ~TempDir() {
    std::error_code ec;
    if (!path_.empty()) fs::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;

  bool ok() const { return !path_.empty(); }
  std::string file(const std::string& name) const { return (path_ / name).string(); }

 private:
  fs::path path_;
};

void remove_db(const std::string& path) {
  std::error_code ec;
  for (const char* suffix : {"", "-wal", "-shm", "-journal"}) fs::remove(path + suffix, ec);
}

// ---------------------------------------------------------------------------
// 1. Parser alone: 4 KiB chunks in, frames out.

void BM_Parse(benchmark::State& state) {
  const std::vector<uint8_t>& stream = encoded_stream();
  const std::span<const uint8_t> all(stream);
  std::vector<GyroFrame> frames;
  frames.reserve(kChunkBytes / gyrotherm::drivers::kKvh1750FrameSize + 1);
  int64_t total_frames = 0;
  double total_s = 0;
  for (auto _ : state) {
    Kvh1750Parser parser;
    const auto t0 = SteadyClock::now();
    for (std::size_t off = 0; off < all.size(); off += kChunkBytes) {
      frames.clear();
      parser.feed(all.subspan(off, std::min(kChunkBytes, all.size() - off)), frames);
      benchmark::DoNotOptimize(frames.data());
    }
    total_s += seconds_since(t0);
    if (parser.counters().frames_ok != static_cast<uint64_t>(kSamples)) {
      state.SkipWithError("parser did not emit every frame");
      return;
    }
    total_frames += static_cast<int64_t>(parser.counters().frames_ok);
  }
  state.SetItemsProcessed(total_frames);
  state.SetBytesProcessed(state.iterations() * static_cast<int64_t>(stream.size()));
  rates()["parse"] = static_cast<double>(total_frames) / total_s;
}
BENCHMARK(BM_Parse)->Unit(benchmark::kMillisecond)->Iterations(3)->UseRealTime();

// ---------------------------------------------------------------------------
// 2. SQLite alone: a prepared INSERT, one transaction per 50 k rows, same
// journal settings as the station database (WAL, synchronous=NORMAL).
// `gyro_samples`: the station's table shape (WITHOUT ROWID, primary key
// (run_id, t_s)), the anchor for the end-to-end figure. `rowid_table`: the
// same columns in a plain rowid table without a key, the cheapest insert
// SQLite offers. Creating the file is not timed.

enum class TableShape { kGyroSamples, kRowidTable };

bool sql_ok(benchmark::State& state, sqlite3* db, int rc, int expected) {
  if (rc == expected) return true;
  const std::string msg = std::string("sqlite: ") + sqlite3_errmsg(db);
  state.SkipWithError(msg.c_str());
  return false;
}

void BM_SqliteBaseline(benchmark::State& state, TableShape shape) {
  const std::vector<GyroSample>& samples = decoded_samples();
  TempDir dir;
  if (!dir.ok()) {
    state.SkipWithError("cannot create a temp directory");
    return;
  }
  int64_t total_rows = 0;
  double total_s = 0;
  int iteration = 0;
  for (auto _ : state) {
    const std::string path = dir.file("baseline-" + std::to_string(iteration++) + ".db");
    sqlite3* db = nullptr;
    sqlite3_stmt* insert = nullptr;
    const bool ok = [&] {
      if (!sql_ok(state, db, sqlite3_open(path.c_str(), &db), SQLITE_OK)) return false;
      const char* schema =
          shape == TableShape::kGyroSamples
              ? "PRAGMA journal_mode=WAL; PRAGMA synchronous=NORMAL;"
                "CREATE TABLE gyro_samples(run_id INTEGER NOT NULL, t_s REAL NOT NULL,"
                " seq INTEGER NOT NULL, rate_dph REAL, status INTEGER NOT NULL, temp_c INTEGER,"
                " PRIMARY KEY(run_id, t_s)) WITHOUT ROWID;"
              : "PRAGMA journal_mode=WAL; PRAGMA synchronous=NORMAL;"
                "CREATE TABLE gyro_samples(run_id INTEGER NOT NULL, t_s REAL NOT NULL,"
                " seq INTEGER NOT NULL, rate_dph REAL, status INTEGER NOT NULL,"
                " temp_c INTEGER);";
      if (!sql_ok(state, db, sqlite3_exec(db, schema, nullptr, nullptr, nullptr), SQLITE_OK)) {
        return false;
      }
      const char* sql =
          "INSERT INTO gyro_samples(run_id, t_s, seq, rate_dph, status, temp_c) "
          "VALUES(?, ?, ?, ?, ?, ?)";
      if (!sql_ok(state, db, sqlite3_prepare_v2(db, sql, -1, &insert, nullptr), SQLITE_OK)) {
        return false;
      }
      const auto t0 = SteadyClock::now();
      for (std::size_t i = 0; i < samples.size(); ++i) {
        if (i % kRowsPerTxn == 0) {
          if (i > 0 && !sql_ok(state, db, sqlite3_exec(db, "COMMIT", nullptr, nullptr, nullptr),
                               SQLITE_OK)) {
            return false;
          }
          if (!sql_ok(state, db, sqlite3_exec(db, "BEGIN", nullptr, nullptr, nullptr), SQLITE_OK)) {
            return false;
          }
        }
        const GyroSample& s = samples[i];
        sqlite3_bind_int64(insert, 1, kRunId);
        sqlite3_bind_double(insert, 2, s.t_s);
        sqlite3_bind_int(insert, 3, s.seq);
        sqlite3_bind_double(insert, 4, s.rate_dph);
        sqlite3_bind_int(insert, 5, s.status);
        sqlite3_bind_int(insert, 6, s.temp_c);
        if (!sql_ok(state, db, sqlite3_step(insert), SQLITE_DONE)) return false;
        sqlite3_reset(insert);
      }
      if (!sql_ok(state, db, sqlite3_exec(db, "COMMIT", nullptr, nullptr, nullptr), SQLITE_OK)) {
        return false;
      }
      const double s = seconds_since(t0);
      state.SetIterationTime(s);
      total_s += s;
      total_rows += static_cast<int64_t>(samples.size());
      return true;
    }();
    sqlite3_finalize(insert);
    sqlite3_close(db);
    remove_db(path);
    if (!ok) return;
  }
  state.SetItemsProcessed(total_rows);
  state.counters["rows_per_txn"] = static_cast<double>(kRowsPerTxn);
  rates()[shape == TableShape::kGyroSamples ? "sqlite_gyro_samples" : "sqlite_rowid_table"] =
      static_cast<double>(total_rows) / total_s;
}
BENCHMARK_CAPTURE(BM_SqliteBaseline, gyro_samples, TableShape::kGyroSamples)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3)
    ->UseManualTime();
BENCHMARK_CAPTURE(BM_SqliteBaseline, rowid_table, TableShape::kRowidTable)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3)
    ->UseManualTime();

// ---------------------------------------------------------------------------
// 3. End to end: 4 KiB chunks -> parser -> samples -> SampleWriter::push_gyro
// (one push per chunk, as GyroReader's sink gets one batch per read) ->
// flush(). Timed from the first byte to flush() returning, with the writer's
// default options (commit every 500 ms). SampleWriter::start (creating the
// schema in a fresh file) and stop() are not timed.

void BM_IngestEndToEnd(benchmark::State& state) {
  const std::vector<uint8_t>& stream = encoded_stream();
  const std::span<const uint8_t> all(stream);
  TempDir dir;
  if (!dir.ok()) {
    state.SkipWithError("cannot create a temp directory");
    return;
  }
  std::vector<GyroFrame> frames;
  std::vector<GyroSample> batch;
  int64_t total_rows = 0;
  double total_s = 0;
  double produce_s = 0;
  uint64_t commits = 0;
  uint64_t dropped = 0;
  double max_commit_ms = 0;
  double db_bytes = 0;
  int iteration = 0;
  for (auto _ : state) {
    const std::string path = dir.file("ingest-" + std::to_string(iteration++) + ".db");
    auto writer = SampleWriter::start(path);
    if (!writer) {
      state.SkipWithError(writer.error().message.c_str());
      return;
    }
    Kvh1750Parser parser;
    uint64_t n = 0;
    const auto t0 = SteadyClock::now();
    for (std::size_t off = 0; off < all.size(); off += kChunkBytes) {
      frames.clear();
      parser.feed(all.subspan(off, std::min(kChunkBytes, all.size() - off)), frames);
      batch.clear();
      frames_to_samples(frames, n, batch);
      if (!batch.empty()) (*writer)->push_gyro(kRunId, batch);
    }
    const double pushed_s = seconds_since(t0);
    const gyrotherm::Status flushed = (*writer)->flush();
    const double s = seconds_since(t0);
    state.SetIterationTime(s);
    (*writer)->stop();
    const auto stats = (*writer)->stats();
    writer->reset();
    std::error_code ec;
    const auto size = fs::file_size(path, ec);
    if (!ec) db_bytes = static_cast<double>(size);
    remove_db(path);
    if (!flushed) {
      state.SkipWithError(flushed.error().message.c_str());
      return;
    }
    if (stats.gyro_rows != static_cast<uint64_t>(kSamples) || stats.duplicates != 0) {
      state.SkipWithError("not every sample was committed");
      return;
    }
    total_rows += static_cast<int64_t>(stats.gyro_rows);
    total_s += s;
    produce_s += pushed_s;
    commits += stats.commits;
    dropped += stats.dropped;
    max_commit_ms = std::max(max_commit_ms, stats.max_commit_ms);
  }
  const auto iters = static_cast<double>(state.iterations());
  state.SetItemsProcessed(total_rows);
  state.counters["commits"] = static_cast<double>(commits) / iters;
  state.counters["max_commit_ms"] = max_commit_ms;
  state.counters["dropped"] = static_cast<double>(dropped);
  state.counters["produce_ms"] = produce_s / iters * 1e3;  // parse + push, before flush()
  state.counters["db_bytes_per_sample"] = db_bytes / static_cast<double>(kSamples);
  rates()["ingest"] = static_cast<double>(total_rows) / total_s;
}
BENCHMARK(BM_IngestEndToEnd)->Unit(benchmark::kMillisecond)->Iterations(3)->UseManualTime();

void print_summary() {
  const auto& r = rates();
  const auto get = [&](const char* name) {
    const auto it = r.find(name);
    return it == r.end() ? 0.0 : it->second;
  };
  const double parse = get("parse");
  const double sqlite = get("sqlite_gyro_samples");
  const double sqlite_rowid = get("sqlite_rowid_table");
  const double ingest = get("ingest");
  if (parse > 0) std::printf("summary: parser alone                  %8.3g frames/s\n", parse);
  if (sqlite_rowid > 0) {
    std::printf("summary: SQLite alone, rowid table     %8.3g rows/s\n", sqlite_rowid);
  }
  if (sqlite > 0) std::printf("summary: SQLite alone, gyro_samples    %8.3g rows/s\n", sqlite);
  if (ingest > 0) {
    std::printf("summary: ingest end to end             %8.3g samples/s", ingest);
    if (sqlite > 0) {
      std::printf(" = %.0f %% of SQLite alone (gyro_samples)", 100.0 * ingest / sqlite);
    }
    std::printf(", %.0fx a 5000 Hz gyro\n", ingest / 5000.0);
  }
}

}  // namespace

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  print_summary();
  return 0;
}
