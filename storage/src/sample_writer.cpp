#include "gyrotherm/storage/sample_writer.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <exception>
#include <limits>
#include <map>
#include <optional>
#include <system_error>

#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::sqlite_error;
using internal::Stmt;

namespace {

struct GyroRow {
  int64_t run_id;
  GyroSample s;
};

struct TempRow {
  int64_t run_id;
  TemperatureSample s;
};

struct TableRow {
  int64_t run_id;
  TableSample s;
};

// Rows in push order; dropping the oldest advances `head` (O(1)) and
// compacts once half the vector is dead, so a stalled disk under a full
// queue costs amortised O(1) per dropped row.
template <class Row>
struct Pending {
  std::vector<Row> rows;
  std::size_t head = 0;

  std::size_t size() const { return rows.size() - head; }
  void drop_oldest(std::size_t k) {
    head += k;
    if (head * 2 >= rows.size()) {
      rows.erase(rows.begin(), rows.begin() + static_cast<std::ptrdiff_t>(head));
      head = 0;
    }
  }
  void clear() {
    rows.clear();
    head = 0;
  }
  // Moves the rows out into `batch` (whose vector must be empty), leaving
  // this with the batch's old capacity.
  void take_into(Pending& batch) {
    std::swap(rows, batch.rows);
    batch.head = head;
    head = 0;
  }
  // Puts the rows of a failed batch back in front of the newer ones.
  void requeue_front(Pending& batch) {
    batch.rows.erase(batch.rows.begin(),
                     batch.rows.begin() + static_cast<std::ptrdiff_t>(batch.head));
    batch.rows.insert(batch.rows.end(), rows.begin() + static_cast<std::ptrdiff_t>(head),
                      rows.end());
    rows.clear();
    head = 0;
    std::swap(rows, batch.rows);
    batch.head = 0;
  }
};

double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

struct SampleWriter::Impl {
  Impl(Database database, SampleWriterOptions opts)
      : db(std::move(database)), path(db.path()), options(opts) {}

  // Writer-thread only.
  Database db;
  std::string path;
  SampleWriterOptions options;
  std::function<void(double)> on_commit;
  Stmt begin, commit, rollback, insert_gyro, insert_temp, insert_table, upsert_rollup;
  Pending<GyroRow> batch_gyro;
  Pending<TempRow> batch_temps;
  Pending<TableRow> batch_table;

  mutable std::mutex mu;
  std::condition_variable wake;  // to the writer: flush or stop requested
  std::condition_variable done;  // to flushers: a batch finished
  // Guarded by mu.
  Pending<GyroRow> gyro;
  Pending<TempRow> temps;
  Pending<TableRow> table;
  std::size_t inflight = 0;  // rows of the batch being committed
  uint64_t next_batch = 1;   // number the buffered rows get when taken
  uint64_t committed_through = 0;
  uint64_t failed_through = 0;
  std::optional<Error> last_failure;
  bool flush_requested = false;
  bool stop_requested = false;
  bool accepting = true;
  bool thread_done = false;
  SampleWriterStats stats;

  std::mutex join_mu;
  std::thread thread;

  Status prepare();
  void run() noexcept;
  void loop();
  void trim_locked();
  struct Outcome {
    Status status;
    uint64_t duplicates = 0;
  };
  Outcome commit_batch();

  // The batch's contribution to gyro_rollup, per (run, level, block).
  struct RollupKey {
    int64_t run_id;
    int level;
    int64_t block;
    auto operator<=>(const RollupKey&) const = default;
  };
  struct RollupBlock {
    int64_t n = 0, rate_n = 0;
    double t_sum_s = 0, rate_sum_dph = 0;
    double rate_min_dph = std::numeric_limits<double>::infinity();
    double rate_max_dph = -std::numeric_limits<double>::infinity();
  };
  std::map<RollupKey, RollupBlock> rollups;
  void add_to_rollups(const GyroRow& r);
  Outcome fail_batch(std::string_view what);
};

Status SampleWriter::Impl::prepare() {
  sqlite3* h = db.handle();
  struct {
    Stmt* stmt;
    const char* sql;
  } const statements[] = {
      {&begin, "BEGIN IMMEDIATE"},
      {&commit, "COMMIT"},
      {&rollback, "ROLLBACK"},
      {&insert_gyro,
       "INSERT OR IGNORE INTO gyro_samples(run_id, t_s, seq, rate_dph, status, temp_c) "
       "VALUES(?, ?, ?, ?, ?, ?)"},
      {&insert_temp,
       "INSERT OR IGNORE INTO temperature_samples(run_id, t_s, setpoint_c, chamber_c, top_c, "
       "side_c) VALUES(?, ?, ?, ?, ?, ?)"},
      {&insert_table,
       "INSERT OR IGNORE INTO table_samples(run_id, t_s, demand_mode, demand_rate_dps, "
       "demand_position_deg, rate_dps, position_deg, mode, interlock) "
       "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?)"},
      {&upsert_rollup,
       "INSERT INTO gyro_rollup(run_id, level, block, n, t_sum_s, rate_n, rate_sum_dph, "
       "rate_min_dph, rate_max_dph) VALUES(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9) "
       "ON CONFLICT(run_id, level, block) DO UPDATE SET n = n + ?4, t_sum_s = t_sum_s + ?5, "
       "rate_n = rate_n + ?6, rate_sum_dph = coalesce(rate_sum_dph + ?7, rate_sum_dph, ?7), "
       "rate_min_dph = coalesce(min(rate_min_dph, ?8), rate_min_dph, ?8), "
       "rate_max_dph = coalesce(max(rate_max_dph, ?9), rate_max_dph, ?9)"},
  };
  for (const auto& s : statements) {
    auto st = Stmt::prepare(h, path, s.sql, /*persistent=*/true);
    if (!st) return st.error();
    *s.stmt = std::move(*st);
  }
  return Status::Ok();
}

SampleWriter::Impl::Outcome SampleWriter::Impl::fail_batch(std::string_view what) {
  Error e = sqlite_error(db.handle(), path, what);
  begin.reset();
  insert_gyro.reset();
  insert_temp.reset();
  insert_table.reset();
  upsert_rollup.reset();
  commit.reset();
  if (!sqlite3_get_autocommit(db.handle())) {
    rollback.step();
    rollback.reset();
  }
  return {Status(std::move(e)), 0};
}

void SampleWriter::Impl::add_to_rollups(const GyroRow& r) {
  for (int level = 0; level < kRollupLevels; ++level) {
    const auto block = static_cast<int64_t>(std::floor(r.s.t_s / kRollupBlockS[level]));
    RollupBlock& b = rollups[RollupKey{r.run_id, level, block}];
    ++b.n;
    b.t_sum_s += r.s.t_s;
    if (std::isfinite(r.s.rate_dph)) {
      ++b.rate_n;
      b.rate_sum_dph += r.s.rate_dph;
      b.rate_min_dph = std::min(b.rate_min_dph, r.s.rate_dph);
      b.rate_max_dph = std::max(b.rate_max_dph, r.s.rate_dph);
    }
  }
}

SampleWriter::Impl::Outcome SampleWriter::Impl::commit_batch() {
  const std::size_t n_gyro = batch_gyro.size();
  const std::size_t n_temps = batch_temps.size();
  const std::size_t n_table = batch_table.size();
  if (n_gyro + n_temps + n_table == 0) return {};
  const std::string what = fmt::format("committing {} gyro, {} temperature and {} table samples",
                                       n_gyro, n_temps, n_table);
  sqlite3* h = db.handle();
  if (begin.step() != SQLITE_DONE) return fail_batch(what);
  begin.reset();
  uint64_t duplicates = 0;
  rollups.clear();
  for (std::size_t i = batch_gyro.head; i < batch_gyro.rows.size(); ++i) {
    const GyroRow& r = batch_gyro.rows[i];
    insert_gyro.bind(1, r.run_id);
    insert_gyro.bind(2, r.s.t_s);
    insert_gyro.bind(3, static_cast<int>(r.s.seq));
    insert_gyro.bind(4, r.s.rate_dph);
    insert_gyro.bind(5, static_cast<int>(r.s.status));
    insert_gyro.bind(6, static_cast<int>(r.s.temp_c));
    if (insert_gyro.step() != SQLITE_DONE) return fail_batch(what);
    insert_gyro.reset();
    if (sqlite3_changes(h) == 0) {
      ++duplicates;
    } else {
      add_to_rollups(r);
    }
  }
  for (const auto& [key, b] : rollups) {
    upsert_rollup.bind(1, key.run_id);
    upsert_rollup.bind(2, key.level);
    upsert_rollup.bind(3, key.block);
    upsert_rollup.bind(4, b.n);
    upsert_rollup.bind(5, b.t_sum_s);
    upsert_rollup.bind(6, b.rate_n);
    if (b.rate_n > 0) {
      upsert_rollup.bind(7, b.rate_sum_dph);
      upsert_rollup.bind(8, b.rate_min_dph);
      upsert_rollup.bind(9, b.rate_max_dph);
    } else {
      for (int c : {7, 8, 9}) upsert_rollup.bind_null(c);
    }
    if (upsert_rollup.step() != SQLITE_DONE) return fail_batch(what);
    upsert_rollup.reset();
  }
  for (std::size_t i = batch_temps.head; i < batch_temps.rows.size(); ++i) {
    const TempRow& r = batch_temps.rows[i];
    insert_temp.bind(1, r.run_id);
    insert_temp.bind(2, r.s.t_s);
    insert_temp.bind(3, r.s.setpoint_c);
    insert_temp.bind(4, r.s.chamber_c);
    insert_temp.bind(5, r.s.top_c);
    insert_temp.bind(6, r.s.side_c);
    if (insert_temp.step() != SQLITE_DONE) return fail_batch(what);
    insert_temp.reset();
    if (sqlite3_changes(h) == 0) ++duplicates;
  }
  for (std::size_t i = batch_table.head; i < batch_table.rows.size(); ++i) {
    const TableRow& r = batch_table.rows[i];
    int c = 1;
    insert_table.bind(c++, r.run_id);
    insert_table.bind(c++, r.s.t_s);
    insert_table.bind(c++, std::string_view(r.s.demand_mode));
    insert_table.bind(c++, r.s.demand_rate_dps);
    insert_table.bind(c++, r.s.demand_position_deg);
    insert_table.bind(c++, r.s.rate_dps);
    insert_table.bind(c++, r.s.position_deg);
    insert_table.bind_text_or_null(c++, r.s.mode);
    insert_table.bind_text_or_null(c++, r.s.interlock);
    if (insert_table.step() != SQLITE_DONE) return fail_batch(what);
    insert_table.reset();
    if (sqlite3_changes(h) == 0) ++duplicates;
  }
  if (commit.step() != SQLITE_DONE) return fail_batch(what);
  commit.reset();
  return {Status::Ok(), duplicates};
}

void SampleWriter::Impl::trim_locked() {
  const std::size_t total = gyro.size() + table.size() + temps.size() + inflight;
  if (total <= options.max_pending) return;
  std::size_t excess = total - options.max_pending;
  const std::size_t from_gyro = std::min(excess, gyro.size());
  gyro.drop_oldest(from_gyro);
  excess -= from_gyro;
  const std::size_t from_table = std::min(excess, table.size());
  table.drop_oldest(from_table);
  excess -= from_table;
  const std::size_t from_temps = std::min(excess, temps.size());
  temps.drop_oldest(from_temps);
  stats.dropped += from_gyro + from_table + from_temps;
}

void SampleWriter::Impl::loop() {
  using Clock = std::chrono::steady_clock;
  std::unique_lock lk(mu);
  auto next_commit = Clock::now() + options.commit_interval;
  for (;;) {
    wake.wait_until(lk, next_commit, [&] { return flush_requested || stop_requested; });
    const bool stopping = stop_requested;
    flush_requested = false;
    gyro.take_into(batch_gyro);
    temps.take_into(batch_temps);
    table.take_into(batch_table);
    const uint64_t batch = next_batch++;
    const std::size_t n_gyro = batch_gyro.size();
    const std::size_t n_temps = batch_temps.size();
    const std::size_t n_table = batch_table.size();
    const std::size_t n_rows = n_gyro + n_temps + n_table;
    inflight = n_rows;
    const auto t0 = Clock::now();
    next_commit = t0 + options.commit_interval;
    lk.unlock();

    Outcome out = commit_batch();
    const double elapsed_ms = ms_since(t0);
    if (out.status.ok() && n_rows > 0 && on_commit) {
      on_commit(elapsed_ms / 1000.0);
    }

    lk.lock();
    inflight = 0;
    if (out.status.ok()) {
      committed_through = batch;
      stats.consecutive_failures = 0;
      if (n_rows > 0) {
        stats.gyro_rows += n_gyro;
        stats.temperature_rows += n_temps;
        stats.table_rows += n_table;
        stats.duplicates += out.duplicates;
        ++stats.commits;
        stats.last_commit_ms = elapsed_ms;
        stats.max_commit_ms = std::max(stats.max_commit_ms, elapsed_ms);
      }
      batch_gyro.clear();
      batch_temps.clear();
      batch_table.clear();
    } else {
      failed_through = batch;
      last_failure = out.status.error();
      ++stats.commit_failures;
      ++stats.consecutive_failures;
      stats.last_error = out.status.error().message;
      gyro.requeue_front(batch_gyro);
      temps.requeue_front(batch_temps);
      table.requeue_front(batch_table);
      trim_locked();
    }
    done.notify_all();

    if (stopping) {
      const std::size_t left = gyro.size() + temps.size() + table.size();
      if (left == 0) break;
      if (!out.status.ok()) {
        stats.dropped += left;  // lost: the final commit failed
        gyro.clear();
        temps.clear();
        table.clear();
        break;
      }
      flush_requested = true;  // rows that raced stop(): one more round
    }
  }
  thread_done = true;
  done.notify_all();
}

void SampleWriter::Impl::run() noexcept {
  try {
    loop();
  } catch (...) {
    std::string what = "unknown exception";
    try {
      throw;
    } catch (const std::exception& e) {
      what = e.what();
    } catch (...) {
    }
    std::lock_guard lk(mu);  // loop() released it while unwinding
    const std::string msg = fmt::format("storage: {}: sample writer stopped: {}", path, what);
    stats.last_error = msg;
    last_failure = Error::Permanent(msg);
    failed_through = next_batch;
    accepting = false;
    thread_done = true;
    done.notify_all();
  }
}

Result<std::unique_ptr<SampleWriter>> SampleWriter::start(
    const std::string& db_path, SampleWriterOptions options,
    std::function<void(double seconds)> on_commit) {
  if (options.commit_interval <= std::chrono::milliseconds::zero() || options.max_pending == 0) {
    return Error::Permanent(fmt::format(
        "storage: {}: sample writer options: commit_interval and max_pending must be > 0",
        db_path));
  }
  auto db = Database::open(db_path);
  if (!db) return db.error();
  auto impl = std::make_unique<Impl>(std::move(*db), options);
  impl->on_commit = std::move(on_commit);
  if (Status s = impl->prepare(); !s) return s.error();
  std::unique_ptr<SampleWriter> writer(new SampleWriter());
  writer->impl_ = std::move(impl);
  Impl* p = writer->impl_.get();
  try {
    p->thread = std::thread([p] { p->run(); });
  } catch (const std::system_error& e) {
    p->thread_done = true;
    p->accepting = false;
    return Error::Transient(
        fmt::format("storage: {}: cannot start the sample writer thread: {}", db_path, e.what()));
  }
  return writer;
}

SampleWriter::~SampleWriter() {
  if (impl_) stop();
}

void SampleWriter::push_gyro(int64_t run_id, std::span<const GyroSample> samples) {
  Impl& m = *impl_;
  std::lock_guard lk(m.mu);
  if (!m.accepting) {
    m.stats.rejected += samples.size();
    return;
  }
  for (const GyroSample& s : samples) {
    if (!std::isfinite(s.t_s)) {
      ++m.stats.rejected;
      continue;
    }
    m.gyro.rows.push_back(GyroRow{run_id, s});
  }
  m.trim_locked();
}

void SampleWriter::push_temperature(int64_t run_id, const TemperatureSample& sample) {
  Impl& m = *impl_;
  std::lock_guard lk(m.mu);
  if (!m.accepting || !std::isfinite(sample.t_s)) {
    ++m.stats.rejected;
    return;
  }
  m.temps.rows.push_back(TempRow{run_id, sample});
  m.trim_locked();
}

void SampleWriter::push_table(int64_t run_id, const TableSample& sample) {
  Impl& m = *impl_;
  std::lock_guard lk(m.mu);
  if (!m.accepting || !std::isfinite(sample.t_s)) {
    ++m.stats.rejected;
    return;
  }
  m.table.rows.push_back(TableRow{run_id, sample});
  m.trim_locked();
}

Status SampleWriter::flush() {
  Impl& m = *impl_;
  std::unique_lock lk(m.mu);
  const std::size_t buffered = m.gyro.size() + m.temps.size() + m.table.size();
  if (buffered == 0 && m.inflight == 0) return Status::Ok();
  if (m.thread_done) {
    return Error::Permanent(fmt::format(
        "storage: {}: sample writer is stopped; {} samples not committed", m.path, buffered));
  }
  const uint64_t target = m.next_batch;
  m.flush_requested = true;
  m.wake.notify_one();
  m.done.wait(lk, [&] {
    return m.committed_through >= target || m.failed_through >= target || m.thread_done;
  });
  if (m.committed_through >= target) return Status::Ok();
  if (m.failed_through >= target && m.last_failure) return *m.last_failure;
  return Error::Permanent(
      fmt::format("storage: {}: sample writer stopped before committing", m.path));
}

void SampleWriter::stop() {
  Impl& m = *impl_;
  std::lock_guard join_lock(m.join_mu);
  {
    std::lock_guard lk(m.mu);
    m.stop_requested = true;
    m.accepting = false;
  }
  m.wake.notify_one();
  if (m.thread.joinable()) m.thread.join();
}

SampleWriterStats SampleWriter::stats() const {
  const Impl& m = *impl_;
  std::lock_guard lk(m.mu);
  SampleWriterStats s = m.stats;
  s.pending = m.gyro.size() + m.temps.size() + m.table.size() + m.inflight;
  return s;
}

}  // namespace gyrotherm::storage

namespace gyrotherm::storage {
// Contract placeholder, replaced by the chunked writer (schema v9).
void SampleWriter::push_frames(const RunDutRecord&, std::span<const DutFrame>) {}
}  // namespace gyrotherm::storage
