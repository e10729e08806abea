// The lab outbox's cost (issue 19): results committed per second, one row
// per transaction as the station writes them, in three set-ups of the same
// schema-10 database:
//
//   no_triggers  the lab_outbox_* triggers dropped: what schema 9 paid
//   not_bound    the triggers installed, the database not bound: a lone
//                station (each trigger's WHEN finds no 'lab_station_id')
//   bound        bound to a lab station: every result also writes its
//                outbox row (payload JSON) in the same transaction
//
// for add_event (a short row of text) and put_segment_stats (a Table I
// row: 16 REAL columns, each formatted exactly into the payload). The
// relay's side: outbox_batch + outbox_ack of 500 rows at a time, and
// outbox_stats over a large backlog. Prints figures; not a pass/fail test.
// See bench/README.md.
#include <benchmark/benchmark.h>
#include <fmt/format.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

#include "gyrotherm/storage/database.h"

namespace {

namespace fs = std::filesystem;
using gyrotherm::storage::Database;
using gyrotherm::storage::EventRecord;
using gyrotherm::storage::RunRecord;
using gyrotherm::storage::SegmentRecord;
using gyrotherm::storage::SegmentStatsRecord;

enum Mode { kNoTriggers = 0, kNotBound = 1, kBound = 2 };
const char* mode_name(int64_t m) {
  return m == kNoTriggers ? "no_triggers" : m == kNotBound ? "not_bound" : "bound";
}

class ScratchDir {
 public:
  ScratchDir() {
    std::string tmpl = (fs::temp_directory_path() / "gyrotherm-bench-outbox-XXXXXX").string();
    if (mkdtemp(tmpl.data()) == nullptr) std::abort();
    path_ = tmpl;
  }
  ~ScratchDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  std::string file(const char* name) const { return (path_ / name).string(); }

 private:
  fs::path path_;
};

template <typename T>
T ok(gyrotherm::Result<T> r) {
  if (!r) {
    std::fprintf(stderr, "outbox bench: %s\n", r.error().message.c_str());
    std::abort();
  }
  return std::move(*r);
}
void ok(const gyrotherm::Status& s) {
  if (!s) {
    std::fprintf(stderr, "outbox bench: %s\n", s.error().message.c_str());
    std::abort();
  }
}

Database open_in(const std::string& path, int64_t mode) {
  Database db = ok(Database::open(path));
  if (mode == kNoTriggers) {
    for (const char* t :
         {"runs", "segments", "events", "segment_stats", "allan", "fits", "fit_runs", "exports",
          "export_runs", "scale_factor_points", "scale_factor_fits",
          "scale_factor_temperature_fits", "duts", "run_duts", "channels"}) {
      for (const char* op : {"insert", "update", "delete"}) {
        ok(db.exec(fmt::format("DROP TRIGGER lab_outbox_{}_{}", t, op)));
      }
    }
  }
  if (mode == kBound) ok(db.lab_bind("bench-1"));
  return db;
}

int64_t a_run(Database& db) {
  RunRecord r;
  r.schedule_name = "bench";
  r.state = "acquiring";
  r.orientation = "up";
  r.config_json = R"({"station":{"name":"bench"}})";
  return ok(db.create_run(r));
}

void BM_AddEvent(benchmark::State& state) {
  ScratchDir dir;
  Database db = open_in(dir.file("station.db"), state.range(0));
  const int64_t run = a_run(db);
  EventRecord e;
  e.run_id = run;
  e.t_s = 1234.5;
  e.wall_utc = "2026-11-21T05:38:43.120Z";
  e.kind = "state";
  e.from_state = "settling";
  e.to_state = "acquiring";
  e.message = "settling -> acquiring: stable for 600 s";
  for (auto _ : state) {
    ok(db.add_event(e));  // one transaction (autocommit)
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel(mode_name(state.range(0)));
  state.counters["outbox_rows"] = static_cast<double>(ok(db.outbox_stats()).pending);
}
BENCHMARK(BM_AddEvent)
    ->ArgName("mode")
    ->Arg(kNoTriggers)
    ->Arg(kNotBound)
    ->Arg(kBound)
    ->MinTime(2.0)
    ->UseRealTime();

void BM_PutSegmentStats(benchmark::State& state) {
  ScratchDir dir;
  Database db = open_in(dir.file("station.db"), state.range(0));
  const int64_t run = a_run(db);
  constexpr int kSegments = 1000;
  std::vector<int64_t> segments;
  for (int i = 0; i < kSegments; ++i) {
    SegmentRecord s;
    s.run_id = run;
    s.index = i;
    s.kind = "soak";
    s.state = "completed";
    segments.push_back(ok(db.create_segment(s)));
  }
  SegmentStatsRecord st;
  st.run_id = run;
  st.axis = "z";
  st.setpoint_c = 20;
  st.n = 7200;
  st.duration_s = 7200;
  st.temp_mean_c = 20.013;
  st.bias_mean_dph = 0.30000000000000004;
  st.bias_std_dph = 1.0 / 3.0;
  st.bias_std_ma_dph = 0.0012345678901234567;
  st.bias_mean_earth_removed_dph = -11.2;
  st.earth_rate_dph = 11.5;
  st.t_from_s = 600.123456789;
  st.t_to_s = 7800.987654321;
  st.computed_utc = "2026-11-21T07:00:00.000Z";
  int64_t i = 0;
  for (auto _ : state) {
    st.segment_id = segments[static_cast<std::size_t>(i % kSegments)];
    st.segment_index = static_cast<int>(i % kSegments);
    st.bias_mean_dph += 1e-9;
    ok(db.put_segment_stats(st));  // one transaction (BEGIN IMMEDIATE .. COMMIT)
    ++i;
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel(mode_name(state.range(0)));
}
BENCHMARK(BM_PutSegmentStats)
    ->ArgName("mode")
    ->Arg(kNoTriggers)
    ->Arg(kNotBound)
    ->Arg(kBound)
    ->MinTime(2.0)
    ->UseRealTime();

// The control loop's checkpoint (about once a wall second): runs' update
// trigger is OF the relayed columns only, so it is not even compiled in.
void BM_Checkpoint(benchmark::State& state) {
  ScratchDir dir;
  Database db = open_in(dir.file("station.db"), state.range(0));
  const int64_t run = a_run(db);
  const std::string resume = R"({"step":3,"windows":[[600.5,1800.25]],"setpoint_c":20.0})";
  double wall = 1.7e9;
  for (auto _ : state) ok(db.set_run_checkpoint(run, resume, wall += 1.0));
  state.SetItemsProcessed(state.iterations());
  state.SetLabel(mode_name(state.range(0)));
  state.counters["outbox_rows"] = static_cast<double>(ok(db.outbox_stats()).pending);
}
BENCHMARK(BM_Checkpoint)
    ->ArgName("mode")
    ->Arg(kNoTriggers)
    ->Arg(kNotBound)
    ->Arg(kBound)
    ->MinTime(2.0)
    ->UseRealTime();

// A backlog of `n` events (a relay down for a while) queued in one
// transaction, then drained as the relay does: batch of 500, ack.
Database backlog(const std::string& path, int64_t n) {
  Database db = open_in(path, kBound);
  const int64_t run = a_run(db);
  ok(db.exec("BEGIN"));
  EventRecord e;
  e.run_id = run;
  e.kind = "info";
  e.message = "a result of typical size: a Table I row is about 600 bytes of JSON";
  for (int64_t i = 0; i < n; ++i) ok(db.add_event(e));
  ok(db.exec("COMMIT"));
  return db;
}

void BM_RelayDrain(benchmark::State& state) {
  constexpr int64_t kRows = 100'000;
  int64_t drained = 0, bytes = 0;
  for (auto _ : state) {
    ScratchDir dir;
    Database db = backlog(dir.file("station.db"), kRows);  // not timed
    const auto t0 = std::chrono::steady_clock::now();
    int64_t last = 0;
    for (;;) {
      auto batch = ok(db.outbox_batch(last, 500));
      if (batch.empty()) break;
      for (const auto& r : batch) bytes += static_cast<int64_t>(r.payload_json.size());
      last = batch.back().seq;
      drained += static_cast<int64_t>(batch.size());
      ok(db.outbox_ack(last));
    }
    state.SetIterationTime(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  state.SetItemsProcessed(drained);
  state.SetBytesProcessed(bytes);
}
BENCHMARK(BM_RelayDrain)->Iterations(2)->Unit(benchmark::kMillisecond)->UseManualTime();

void BM_OutboxStats(benchmark::State& state) {
  ScratchDir dir;
  Database db = backlog(dir.file("station.db"), state.range(0));
  int64_t pending = 0;
  for (auto _ : state) pending = ok(db.outbox_stats()).pending;
  state.counters["pending"] = static_cast<double>(pending);
}
BENCHMARK(BM_OutboxStats)
    ->ArgName("pending")
    ->Arg(1000)
    ->Arg(100'000)
    ->Arg(1'000'000)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
