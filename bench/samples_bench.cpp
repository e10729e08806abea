// Decimated-samples benchmark (issue 4): Database::decimated_samples, what
// the REST route GET /api/v1/runs/{id}/samples answers with, on a run of
// 10 M gyro samples, beside a brute-force GROUP BY over the raw rows and a
// plain load of the whole run. Prints figures; it is not a pass/fail test.
// See bench/README.md.
//
// The database (one run: 10 M samples at 1 kHz = 10 000 s, written through
// SampleWriter so the rollups exist as in production, plus 1 Hz
// temperatures) is built once in a child process and kept at
// $TMPDIR/gyrotherm-bench-samples-10M.db (default /tmp); later runs reuse
// it. Building it in a child keeps the parent's peak RSS (getrusage) clean,
// so the `peak_rss_growth_kib` counter shows what each query holds at most.
#include <benchmark/benchmark.h>
#include <sqlite3.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <numbers>
#include <optional>
#include <random>
#include <string>
#include <system_error>
#include <vector>

#include "gyrotherm/core/samples.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace {

namespace fs = std::filesystem;
using gyrotherm::GyroSample;
using gyrotherm::TemperatureSample;
using gyrotherm::storage::Database;
using gyrotherm::storage::DecimatedSamples;
using gyrotherm::storage::SampleWriter;
using SteadyClock = std::chrono::steady_clock;

constexpr int64_t kSamples = 10'000'000;
constexpr double kRateHz = 1000.0;
constexpr double kRunS = kSamples / kRateHz;  // 10 000 s
constexpr const char* kCompleteKey = "bench_samples_complete";

double seconds_since(SteadyClock::time_point t0) {
  return std::chrono::duration<double>(SteadyClock::now() - t0).count();
}

std::string db_path() {
  return (fs::temp_directory_path() / "gyrotherm-bench-samples-10M.db").string();
}

void remove_db(const std::string& path) {
  std::error_code ec;
  for (const char* suffix : {"", "-wal", "-shm", "-journal"}) fs::remove(path + suffix, ec);
}

bool db_complete(const std::string& path) {
  if (!fs::exists(path)) return false;
  auto db = Database::open_read_only(path);
  if (!db) return false;
  auto v = db->meta(kCompleteKey);
  return v && v->has_value() && **v == std::to_string(kSamples);
}

// Writes the run through SampleWriter. Returns 0 on success.
int build_db(const std::string& path) {
  remove_db(path);
  const auto t0 = SteadyClock::now();
  int64_t run_id = 0;
  {
    auto db = Database::open(path);
    if (!db) {
      std::fprintf(stderr, "samples bench: %s\n", db.error().message.c_str());
      return 1;
    }
    gyrotherm::storage::RunRecord run;
    run.schedule_name = "bench-10M";
    run.state = "completed";
    run.orientation = "up";
    auto id = db->create_run(run);
    if (!id) {
      std::fprintf(stderr, "samples bench: %s\n", id.error().message.c_str());
      return 1;
    }
    run_id = *id;
  }
  auto writer = SampleWriter::start(path);
  if (!writer) {
    std::fprintf(stderr, "samples bench: %s\n", writer.error().message.c_str());
    return 1;
  }
  // Earth rate + 0.8 °/h bias + a 2 h thermal wander + white noise of
  // 1 °/h per 1 s (31.6 °/h per 1 ms sample).
  std::mt19937_64 rng(20261121);
  std::normal_distribution<double> noise(0.0, std::sqrt(kRateHz));
  std::vector<GyroSample> chunk;
  for (int64_t i = 0; i < kSamples; ++i) {
    GyroSample g;
    g.t_s = static_cast<double>(i) / kRateHz;
    g.rate_dph = 10.4 + 0.8 + 2.0 * std::sin(2 * std::numbers::pi * g.t_s / 7200.0) + noise(rng);
    g.seq = static_cast<uint8_t>(i % 128);
    g.status = 0x77;
    g.temp_c = static_cast<int16_t>(20 + i / 1'000'000);
    chunk.push_back(g);
    if (chunk.size() == 1000) {  // one second, as GyroReader's sink would get it
      (*writer)->push_gyro(run_id, chunk);
      chunk.clear();
      const int64_t s = (i + 1) / 1000;
      const double shell = 20.0 + 20.0 * std::sin(2 * std::numbers::pi * s / 7200.0);
      (*writer)->push_temperature(run_id, TemperatureSample{.t_s = static_cast<double>(s),
                                                            .setpoint_c = s < 5000 ? 20.0 : 40.0,
                                                            .chamber_c = shell + 0.5,
                                                            .top_c = shell + 0.1,
                                                            .side_c = shell - 0.1});
    }
    // Keep the writer's queue bounded (it drops beyond max_pending).
    if ((i + 1) % 1'000'000 == 0) {
      if (auto s = (*writer)->flush(); !s) {
        std::fprintf(stderr, "samples bench: %s\n", s.error().message.c_str());
        return 1;
      }
      std::fprintf(stderr, "\rsamples bench: building %s: %lld M samples", path.c_str(),
                   static_cast<long long>((i + 1) / 1'000'000));
    }
  }
  (*writer)->stop();
  const auto stats = (*writer)->stats();
  if (stats.gyro_rows != static_cast<uint64_t>(kSamples) || stats.dropped != 0) {
    std::fprintf(stderr, "\nsamples bench: only %llu samples committed, %llu dropped\n",
                 static_cast<unsigned long long>(stats.gyro_rows),
                 static_cast<unsigned long long>(stats.dropped));
    return 1;
  }
  writer->reset();
  auto db = Database::open(path);
  if (!db || !db->set_meta(kCompleteKey, std::to_string(kSamples)).ok() ||
      !db->exec("PRAGMA wal_checkpoint(TRUNCATE)").ok()) {
    std::fprintf(stderr, "\nsamples bench: cannot finish %s\n", path.c_str());
    return 1;
  }
  std::error_code ec;
  std::fprintf(stderr, "\nsamples bench: built in %.0f s, %.0f MB\n", seconds_since(t0),
               static_cast<double>(fs::file_size(path, ec)) / 1e6);
  return 0;
}

// Builds the database in a child process unless a complete one is there.
bool ensure_db(const std::string& path) {
  if (db_complete(path)) return true;
  std::fflush(nullptr);
  const pid_t pid = fork();
  if (pid < 0) return false;
  if (pid == 0) _exit(build_db(path));
  int status = 0;
  if (waitpid(pid, &status, 0) != pid) return false;
  return WIFEXITED(status) && WEXITSTATUS(status) == 0 && db_complete(path);
}

// --- memory ----------------------------------------------------------------

long rss_kib(const char* field) {  // VmRSS / VmHWM of /proc/self/status
  std::ifstream in("/proc/self/status");
  std::string line;
  const std::string prefix = std::string(field) + ":";
  while (std::getline(in, line)) {
    if (line.rfind(prefix, 0) == 0) return std::stol(line.substr(prefix.size()));
  }
  return -1;
}

long maxrss_kib() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss;
}

// Resets the peak RSS to the current RSS (Linux: "5" to clear_refs), so
// getrusage's ru_maxrss afterwards is the peak of what follows. False when
// the kernel refuses; the growth is then only a lower bound.
bool reset_peak_rss() {
  std::ofstream out("/proc/self/clear_refs");
  out << "5";
  out.flush();
  return out.good() && maxrss_kib() <= rss_kib("VmRSS") + 64;
}

// Peak RSS growth over a benchmark's iterations, from getrusage.
struct MemoryProbe {
  bool exact = reset_peak_rss();
  long rss_before = rss_kib("VmRSS");
  long peak_before = maxrss_kib();  // == rss_before when exact
  void report(benchmark::State& state) const {
    state.counters["rss_before_mib"] = static_cast<double>(rss_before) / 1024.0;
    state.counters["peak_rss_growth_kib"] =
        static_cast<double>(std::max(0L, maxrss_kib() - peak_before));
    if (!exact) state.counters["peak_growth_lower_bound"] = 1;
  }
};

// --- results ---------------------------------------------------------------

struct Figure {
  double ms = 0;
  double growth_kib = 0;
  std::size_t points = 0;
  const char* source = "";
};
std::map<std::string, Figure>& figures() {
  static std::map<std::string, Figure> f;
  return f;
}

const char* source_of(const DecimatedSamples& d) {
  if (d.from_rollup) return "rollup";
  return d.bucket_s == 0 ? "as recorded" : "raw buckets";
}

// --- benchmarks ------------------------------------------------------------

struct Query {
  const char* name;  // for the summary
  double from_s;
  std::optional<double> to_s;  // nullopt: last sample
  int max_points;
  int64_t expect_n;  // gyro samples the answer must cover, -1: not checked
};

void BM_Decimated(benchmark::State& state, Query q) {
  auto db = Database::open_read_only(db_path());
  if (!db) {
    state.SkipWithError(db.error().message.c_str());
    return;
  }
  const MemoryProbe mem;
  double total_s = 0;
  std::size_t points = 0;
  int64_t n_total = 0;
  const char* source = "";
  for (auto _ : state) {
    const auto t0 = SteadyClock::now();
    auto d = db->decimated_samples(1, q.from_s, q.to_s, q.max_points);
    const double s = seconds_since(t0);
    state.SetIterationTime(s);
    total_s += s;
    if (!d) {
      state.SkipWithError(d.error().message.c_str());
      return;
    }
    benchmark::DoNotOptimize(d->gyro.mean_dph.data());
    points = d->gyro.t_s.size();
    n_total = 0;
    for (int64_t n : d->gyro.n) n_total += n;
    source = source_of(*d);
    if (points > static_cast<std::size_t>(q.max_points) ||
        (q.expect_n >= 0 && n_total != q.expect_n)) {
      state.SkipWithError("wrong answer: too many points or samples missing");
      return;
    }
  }
  mem.report(state);
  state.counters["points"] = static_cast<double>(points);
  state.counters["samples_covered"] = static_cast<double>(n_total);
  state.SetLabel(source);
  Figure& f = figures()[q.name];
  f.ms = total_s / static_cast<double>(state.iterations()) * 1e3;
  f.growth_kib = state.counters["peak_rss_growth_kib"];
  f.points = points;
  f.source = source;
}

constexpr int64_t kAll = kSamples;
BENCHMARK_CAPTURE(BM_Decimated, whole_run_2000,
                  Query{"1 whole run, 2000 points", 0, std::nullopt, 2000, kAll})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(20)
    ->UseManualTime();
BENCHMARK_CAPTURE(BM_Decimated, whole_run_20000,
                  Query{"2 whole run, 20000 points", 0, std::nullopt, 20'000, kAll})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(10)
    ->UseManualTime();
BENCHMARK_CAPTURE(BM_Decimated, last_hour_1200,
                  Query{"3 last hour, 1200 points", kRunS - 3600.0, std::nullopt, 1200, 3'600'000})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(20)
    ->UseManualTime();
BENCHMARK_CAPTURE(BM_Decimated, zoom_10min_2000,
                  Query{"4 10-minute zoom, 2000 points", 5000.0, 5600.0, 2000, 600'100})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(20)
    ->UseManualTime();
BENCHMARK_CAPTURE(BM_Decimated, zoom_1s_2000,
                  Query{"5 1-second zoom, 2000 points", 5000.0, 5001.0, 2000, 1001})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(50)
    ->UseManualTime();

// The same reduction as whole_run_2000 (5 s buckets) straight from the raw
// rows: what the rollup saves.
void BM_GroupByRawRows(benchmark::State& state) {
  auto db = Database::open_read_only(db_path());
  if (!db) {
    state.SkipWithError(db.error().message.c_str());
    return;
  }
  sqlite3_stmt* st = nullptr;
  if (sqlite3_prepare_v2(db->handle(),
                         "SELECT CAST(t_s / 5.0 AS INTEGER) AS b, count(*), avg(t_s), "
                         "avg(rate_dph), min(rate_dph), max(rate_dph) FROM gyro_samples "
                         "WHERE run_id = 1 GROUP BY b ORDER BY b",
                         -1, &st, nullptr) != SQLITE_OK) {
    state.SkipWithError(sqlite3_errmsg(db->handle()));
    return;
  }
  const MemoryProbe mem;
  double total_s = 0;
  std::size_t points = 0;
  int64_t n_total = 0;
  for (auto _ : state) {
    const auto t0 = SteadyClock::now();
    std::vector<double> mean;
    n_total = 0;
    while (sqlite3_step(st) == SQLITE_ROW) {
      n_total += sqlite3_column_int64(st, 1);
      mean.push_back(sqlite3_column_double(st, 3));
    }
    sqlite3_reset(st);
    const double s = seconds_since(t0);
    state.SetIterationTime(s);
    total_s += s;
    benchmark::DoNotOptimize(mean.data());
    points = mean.size();
  }
  sqlite3_finalize(st);
  mem.report(state);
  if (n_total != kSamples) state.SkipWithError("GROUP BY did not see every sample");
  state.counters["points"] = static_cast<double>(points);
  Figure& f = figures()["7 GROUP BY raw rows, whole run, 5 s"];
  f.ms = total_s / static_cast<double>(state.iterations()) * 1e3;
  f.growth_kib = state.counters["peak_rss_growth_kib"];
  f.points = points;
  f.source = "raw rows";
}
BENCHMARK(BM_GroupByRawRows)->Unit(benchmark::kMillisecond)->Iterations(2)->UseManualTime();

// What "loading the run into memory" costs: Database::gyro_samples over the
// whole run (10 M GyroSample = 240 MB).
void BM_LoadWholeRun(benchmark::State& state) {
  auto db = Database::open_read_only(db_path());
  if (!db) {
    state.SkipWithError(db.error().message.c_str());
    return;
  }
  const MemoryProbe mem;
  double total_s = 0;
  std::size_t rows = 0;
  for (auto _ : state) {
    const auto t0 = SteadyClock::now();
    auto samples = db->gyro_samples(1, 0, kRunS + 1);
    const double s = seconds_since(t0);
    state.SetIterationTime(s);
    total_s += s;
    if (!samples) {
      state.SkipWithError(samples.error().message.c_str());
      return;
    }
    benchmark::DoNotOptimize(samples->data());
    rows = samples->size();
  }
  mem.report(state);
  state.counters["rows"] = static_cast<double>(rows);
  Figure& f = figures()["8 load the whole run (gyro_samples)"];
  f.ms = total_s / static_cast<double>(state.iterations()) * 1e3;
  f.growth_kib = state.counters["peak_rss_growth_kib"];
  f.points = rows;
  f.source = "all rows";
}
BENCHMARK(BM_LoadWholeRun)->Unit(benchmark::kMillisecond)->Iterations(1)->UseManualTime();

void print_summary() {
  for (const auto& [name, f] : figures()) {
    std::printf("summary: %-48s %9.2f ms  %6zu points  peak RSS +%.0f KiB  (%s)\n", name.c_str(),
                f.ms, f.points, f.growth_kib, f.source);
  }
}

}  // namespace

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  // Before any thread exists: the child that builds the database is forked.
  const std::string path = db_path();
  if (!ensure_db(path)) {
    std::fprintf(stderr, "samples bench: cannot build %s\n", path.c_str());
    return 1;
  }
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  print_summary();
  return 0;
}
