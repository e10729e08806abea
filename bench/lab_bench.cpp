// The lab relay (issue 19) with ten simulated stations on this machine, in
// one run. Prints a table; not a pass/fail test. See bench/README.md.
//
// A private PostgreSQL 15 cluster (tests/support/pg_cluster.h) with fsync
// and synchronous_commit on, as a lab would run it. Each station is a
// SQLite file bound to its station id and a lab::Relay as gyrothermd runs
// it (its own thread, its own connections, role gyrotherm_<id>). Results
// are what a station commits after each step: a segment and its Table I
// row, each in its own transaction (two outbox records).
//
//   1. local commit rate: results committed per second on one station's
//      file, unbound (no outbox) and bound (the outbox triggers), no relay.
//   2. relay throughput: every station's outbox preloaded with R records,
//      then all ten relays started at once; records per second until every
//      outbox is empty (aggregate and per station).
//   3. lag: the ten stations commit results at a steady rate while fresh
//      relays run, first woken after each commit (as gyrothermd wakes its
//      relay on every event it publishes), then on their poll (poll_s)
//      alone; per record, wall time from its local commit (outbox
//      committed_unix_s) to the central transaction that stored it
//      (lab.records.central_committed_at, the transaction's start),
//      quantiles; and the relays' own largest figure (measured after the
//      central commit). Every record written must be in the lab.
//
// Usage: gyrotherm_bench_lab [--stations N] [--preload R] [--rate PER_S]
//                            [--seconds S] [--poll S] [--dir D]
#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "../tests/support/pg_cluster.h"
#include "gyrotherm/lab/central.h"
#include "gyrotherm/lab/pg.h"
#include "gyrotherm/lab/relay.h"
#include "gyrotherm/storage/database.h"

namespace {

namespace fs = std::filesystem;
using namespace gyrotherm;
using BenchClock = std::chrono::steady_clock;

double seconds_since(BenchClock::time_point t0) {
  return std::chrono::duration<double>(BenchClock::now() - t0).count();
}

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "lab_bench: %s\n", what.c_str());
  std::exit(1);
}

template <class T>
T ok(Result<T> r, const char* what) {
  if (!r) die(fmt::format("{}: {}", what, r.error().message));
  return std::move(*r);
}
void ok(const Status& s, const char* what) {
  if (!s.ok()) die(fmt::format("{}: {}", what, s.error().message));
}

// One station's file with a run to hang results on.
struct StationFile {
  std::string id;
  std::string path;
  int64_t run_id = 0;
  int next_index = 0;
};

StationFile make_station(const fs::path& dir, const std::string& id, bool bind) {
  StationFile s{id, (dir / (id + ".db")).string()};
  fs::remove(s.path);
  auto db = ok(storage::Database::open(s.path), "open");
  if (bind) ok(db.lab_bind(id), "lab_bind");
  storage::RunRecord run;
  run.schedule_name = "bench";
  run.state = "acquiring";
  s.run_id = ok(db.create_run(run), "create_run");
  return s;
}

// One result as a station commits it after a step: the segment, then its
// Table I row (two transactions, two outbox records when bound).
void commit_result(storage::Database& db, StationFile& s) {
  storage::SegmentRecord seg;
  seg.run_id = s.run_id;
  seg.index = s.next_index++;
  seg.kind = "soak";
  seg.label = fmt::format("soak {}", seg.index);
  seg.setpoint_c = -20.0 + (seg.index % 9) * 10.0;
  seg.t_start_s = seg.index * 3600.0;
  seg.state = "completed";
  const int64_t segment_id = ok(db.create_segment(seg), "create_segment");
  storage::SegmentStatsRecord st;
  st.segment_id = segment_id;
  st.run_id = s.run_id;
  st.segment_index = seg.index;
  st.setpoint_c = seg.setpoint_c;
  st.n = 3600;
  st.duration_s = 3600;
  st.temp_mean_c = seg.setpoint_c + 0.123456789;
  st.bias_mean_dph = 0.1 + 1e-3 * seg.index;
  st.bias_std_dph = 0.0123456789;
  st.bias_std_ma_dph = 0.00123456789;
  st.bias_mean_earth_removed_dph = st.bias_mean_dph - 9.87;
  st.bin_s = 1;
  st.ma_window = 101;
  st.earth_rate_dph = 9.87;
  st.t_from_s = seg.index * 3600.0;
  st.t_to_s = st.t_from_s + 3600;
  ok(db.put_segment_stats(st), "put_segment_stats");
}

double local_rate(const fs::path& dir, bool bind, int results) {
  StationFile s = make_station(dir, bind ? "local-bound" : "local-unbound", bind);
  auto db = ok(storage::Database::open(s.path), "open");
  const auto t0 = BenchClock::now();
  for (int i = 0; i < results; ++i) commit_result(db, s);
  return 2.0 * results / seconds_since(t0);  // rows (transactions) per second
}

int arg_int(int argc, char** argv, const char* name, int fallback) {
  for (int i = 1; i + 1 < argc; ++i) {
    if (std::string(argv[i]) == name) return std::stoi(argv[i + 1]);
  }
  return fallback;
}
double arg_double(int argc, char** argv, const char* name, double fallback) {
  for (int i = 1; i + 1 < argc; ++i) {
    if (std::string(argv[i]) == name) return std::stod(argv[i + 1]);
  }
  return fallback;
}
std::string arg_string(int argc, char** argv, const char* name, std::string fallback) {
  for (int i = 1; i + 1 < argc; ++i) {
    if (std::string(argv[i]) == name) return argv[i + 1];
  }
  return fallback;
}

std::unique_ptr<lab::Relay> make_relay(const gyrotherm::testing::PgCluster& pg,
                                       const StationFile& s, double poll_s) {
  lab::RelayOptions o;
  o.station_id = s.id;
  o.db_path = s.path;
  o.conninfo = pg.conninfo("gyrotherm_" + s.id, "lab");
  o.poll_s = poll_s;
  o.retry_min_s = 0.1;
  o.retry_max_s = 1.0;
  return ok(lab::Relay::create(o), "relay");
}

struct Steady {
  int64_t records = 0;
  double p50_s = 0, p95_s = 0, p99_s = 0, max_s = 0;
  double relay_max_lag_s = 0;
  uint64_t redelivered = 0;
};

// The stations commit `rate` results per second each for `run_s`, their
// relays running (woken after each commit when `nudge`); the lag of every
// record of the phase from the lab's rows.
Steady steady(lab::PgConnection& admin, const gyrotherm::testing::PgCluster& pg,
              std::vector<StationFile>& files, double rate, double run_s, double poll_s, bool nudge,
              const std::string& phase) {
  ok(admin.exec("DROP TABLE IF EXISTS bench_mark; CREATE TABLE bench_mark AS SELECT station_id, "
                "coalesce(max(outbox_seq), 0) AS seq FROM lab.records GROUP BY station_id"),
     "mark");
  std::vector<std::unique_ptr<lab::Relay>> relays;
  for (auto& f : files) relays.push_back(make_relay(pg, f, poll_s));
  for (auto& r : relays) r->start();
  std::atomic<bool> stop{false};
  std::atomic<int64_t> written{0};
  std::vector<std::thread> writers;
  for (std::size_t i = 0; i < files.size(); ++i) {
    lab::Relay* relay = nudge ? relays[i].get() : nullptr;
    StationFile* f = &files[i];
    writers.emplace_back([f, relay, &stop, &written, rate] {
      auto db = ok(storage::Database::open(f->path), "open");
      const auto period = std::chrono::duration<double>(1.0 / rate);
      auto next = BenchClock::now();
      while (!stop.load()) {
        commit_result(db, *f);
        if (relay) relay->nudge();
        written += 2;
        next += std::chrono::duration_cast<BenchClock::duration>(period);
        std::this_thread::sleep_until(next);
      }
    });
  }
  std::this_thread::sleep_for(std::chrono::duration<double>(run_s));
  stop = true;
  for (auto& w : writers) w.join();
  // Drained when every station's outbox is empty (the relays' own pending
  // figure is refreshed about once a second: not a drain signal).
  const auto t_drain = BenchClock::now();
  std::vector<storage::Database> dbs;
  for (auto& f : files) dbs.push_back(ok(storage::Database::open(f.path), "open"));
  for (bool all = false; !all;) {
    all = true;
    for (auto& db : dbs) all = all && ok(db.outbox_stats(), "stats").pending == 0;
    if (seconds_since(t_drain) > 120) die(phase + ": relays did not catch up in 120 s");
    if (!all) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  Steady out;
  for (auto& r : relays) {
    const auto st = r->status();
    out.relay_max_lag_s = std::max(out.relay_max_lag_s, st.max_lag_s.value_or(0));
    out.redelivered += st.redelivered_total;
    r->stop();
  }
  auto lag = ok(admin.exec("SELECT count(*), "
                           "percentile_cont(0.5) WITHIN GROUP (ORDER BY lag_s), "
                           "percentile_cont(0.95) WITHIN GROUP (ORDER BY lag_s), "
                           "percentile_cont(0.99) WITHIN GROUP (ORDER BY lag_s), max(lag_s) "
                           "FROM (SELECT extract(epoch FROM r.central_committed_at - "
                           "r.station_committed_at) AS lag_s FROM lab.records r JOIN bench_mark m "
                           "USING (station_id) WHERE r.outbox_seq > m.seq) x"),
                "lag");
  const auto cell = [&](int c) { return std::stod(lag.rows.at(0).at(c).value_or("nan")); };
  out.records = static_cast<int64_t>(cell(0));
  out.p50_s = cell(1);
  out.p95_s = cell(2);
  out.p99_s = cell(3);
  out.max_s = cell(4);
  if (out.records != written.load()) {
    die(fmt::format("{}: {} records written, {} in the lab", phase, written.load(), out.records));
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  const int stations = arg_int(argc, argv, "--stations", 10);
  const int preload = arg_int(argc, argv, "--preload", 20000);
  const double rate = arg_double(argc, argv, "--rate", 5.0);
  const double run_s = arg_double(argc, argv, "--seconds", 20.0);
  const double poll_s = arg_double(argc, argv, "--poll", 1.0);
  const fs::path dir =
      arg_string(argc, argv, "--dir", (fs::temp_directory_path() / "gyrotherm-lab-bench").string());
  fs::create_directories(dir);

  std::string why;
  bool missing = false;
  auto pg = gyrotherm::testing::PgCluster::create(&why, &missing, /*durable=*/true);
  if (!pg) die("PostgreSQL: " + why);
  if (const auto e = pg->create_database("lab"); !e.empty()) die(e);
  auto admin =
      ok(lab::PgConnection::connect(pg->conninfo(gyrotherm::testing::PgCluster::kAdmin, "lab")),
         "connect");
  ok(lab::migrate_central(admin), "migrate");

  // 1. Local commit rate.
  const int local_results = 2000;
  const double unbound_rows_s = local_rate(dir, false, local_results);
  const double bound_rows_s = local_rate(dir, true, local_results);

  // 2. Throughput: preloaded outboxes, ten relays at once.
  std::vector<StationFile> files;
  for (int i = 0; i < stations; ++i) {
    const std::string id = fmt::format("st{:02}", i + 1);
    ok(lab::add_station(admin, id, "gyrotherm_" + id), "add_station");
    files.push_back(make_station(dir, id, true));
    auto db = ok(storage::Database::open(files.back().path), "open");
    ok(db.exec("BEGIN"), "begin");
    for (int r = 0; r < preload / 2; ++r) commit_result(db, files.back());
    ok(db.exec("COMMIT"), "commit");
  }
  int64_t preloaded = 0;
  for (auto& f : files) {
    auto db = ok(storage::Database::open(f.path), "open");
    preloaded += ok(db.outbox_stats(), "stats").pending;
  }
  std::vector<std::unique_ptr<lab::Relay>> relays;
  for (auto& f : files) relays.push_back(make_relay(*pg, f, poll_s));
  const auto t_send = BenchClock::now();
  for (auto& r : relays) r->start();
  std::vector<double> done_s(files.size(), 0);
  for (bool all = false; !all;) {
    all = true;
    for (std::size_t i = 0; i < relays.size(); ++i) {
      if (done_s[i] > 0) continue;
      if (relays[i]->status().sent_total >= static_cast<uint64_t>(preloaded / stations)) {
        done_s[i] = seconds_since(t_send);
      } else {
        all = false;
      }
    }
    if (seconds_since(t_send) > 600) die("relays did not empty their outboxes in 600 s");
    if (!all) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  const double send_s = *std::max_element(done_s.begin(), done_s.end());
  const double throughput = static_cast<double>(preloaded) / send_s;

  for (auto& r : relays) r->stop();
  relays.clear();

  // 3. Lag under a steady load: fresh relays (their largest lag is this
  // phase's), first woken by each commit as gyrothermd wakes its relay on
  // every event it publishes, then on their poll alone.
  const Steady nudged = steady(admin, *pg, files, rate, run_s, poll_s, true, "nudged");
  const Steady polled = steady(admin, *pg, files, rate, run_s, poll_s, false, "polled");

  std::printf("gyrotherm lab relay bench: %d stations, PostgreSQL 15 (fsync on), this machine\n",
              stations);
  std::printf("| figure | value |\n|---|---|\n");
  std::printf("| local commits, one station, no outbox (rows/s) | %.0f |\n", unbound_rows_s);
  std::printf("| local commits, one station, bound (outbox triggers) (rows/s) | %.0f |\n",
              bound_rows_s);
  std::printf(
      "| relay throughput, %d stations at once, %lld preloaded records | %.0f records/s (%.1f "
      "s) |\n",
      stations, static_cast<long long>(preloaded), throughput, send_s);
  std::printf("| per station (slowest) | %.0f records/s |\n",
              static_cast<double>(preloaded / stations) / send_s);
  for (const Steady* st : {&nudged, &polled}) {
    std::printf(
        "| steady load, relays %s: %d stations x %.1f results/s (%.0f records/s) for %.0f s, "
        "poll_s %.2f | %lld records |\n",
        st == &nudged ? "woken by each commit (as gyrothermd)" : "on their poll alone", stations,
        rate, 2 * rate * stations, run_s, poll_s, static_cast<long long>(st->records));
    std::printf(
        "| lag local commit -> central transaction, p50 / p95 / p99 / max (s) | %.3f / %.3f / "
        "%.3f / %.3f |\n",
        st->p50_s, st->p95_s, st->p99_s, st->max_s);
    std::printf("| lag local commit -> central commit, largest the relays saw (s) | %.3f |\n",
                st->relay_max_lag_s);
    std::printf("| records redelivered | %llu |\n",
                static_cast<unsigned long long>(st->redelivered));
  }
  return 0;
}
