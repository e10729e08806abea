#include "gyrotherm/storage/sample_writer.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <exception>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <system_error>
#include <tuple>

#include "chunks.h"
#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::sqlite_error;
using internal::Stmt;

namespace {

// A frame waiting for its commit: of `dut` (as push_frames was given it),
// or, when dut is nullptr, a push_gyro sample of the run's first DUT (raw:
// rate_dph, status, temp_c).
struct FrameRow {
  int64_t run_id;
  const RunDutRecord* dut;
  DutFrame f;
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

// Closed channel-chunks a commit packs at least (docs/storage.md
// "Writing"); a quarter of those waiting when more wait.
constexpr std::size_t kPackPerCommit = 4;

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
  Stmt begin, commit, rollback, insert_temp, insert_table;
  Pending<FrameRow> batch_gyro;
  Pending<TempRow> batch_temps;
  Pending<TableRow> batch_table;

  mutable std::mutex mu;
  std::condition_variable wake;  // to the writer: flush or stop requested
  std::condition_variable done;  // to flushers: a batch finished
  // Guarded by mu.
  Pending<FrameRow> gyro;
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
  std::set<int64_t> closing;  // close_run()'s runs whose state is still held

  std::mutex join_mu;
  std::thread thread;

  Status prepare();
  void run() noexcept;
  void loop();
  void trim_locked();
  struct Outcome {
    Status status;
    uint64_t duplicates = 0;
    uint64_t channel_samples = 0;
    uint64_t chunks = 0;
    bool wrote = false;  // rows, or chunks packed
  };
  // Commits the batch. The open chunks of the runs in `finishing` (closed
  // runs with nothing more pending), or of every run when `finish_all`
  // (stopping), are closed and written whole.
  Outcome commit_batch(bool finish_all, const std::set<int64_t>& finishing);

  // The chunks of each DUT of each run written to (writer thread); dropped
  // after a failed commit (the next commit starts new chunks after what is
  // stored).
  struct Stream {
    std::unique_ptr<internal::ChunkBuilder> builder;
    // push_gyro into this DUT: where rate, status and temp_c go (-1: none).
    int rate_idx = -1, status_idx = -1, temp_idx = -1;
    double rate_scale = 1;
    bool touched = false;
  };
  // By (run, DUT id, first channel id): a DUT's frames, and apart the
  // channels it pushes at another rate (its own probes), are two streams.
  std::map<std::tuple<int64_t, int64_t, int64_t>, Stream> streams;
  std::map<int64_t, int64_t> first_dut;  // run -> its first DUT's id
  // Pieces in the file no stream owns may be left (a killed writer's, or
  // the streams a failed commit dropped): packed by the next commits.
  bool left_pieces = true;
  // The DUT records push_frames was given (guarded by mu; FrameRow points
  // at them: erased only when no pending row is of their run).
  // By (run, DUT id, first channel id), as streams.
  std::map<std::tuple<int64_t, int64_t, int64_t>, std::unique_ptr<RunDutRecord>> known_duts;
  Result<Stream*> stream_for(const FrameRow& r);
  Result<int64_t> first_dut_of(int64_t run_id);
  Outcome fail_batch(std::string_view what);
  // Writer thread, mu held, after a successful round: forgets the closing
  // runs nothing of which waits, and counts the runs still held.
  void release_closed_runs_locked();
};

void SampleWriter::Impl::release_closed_runs_locked() {
  const auto waits = [&](int64_t run_id) {
    const auto of_run = [run_id](const auto& r) { return r.run_id == run_id; };
    const auto in = [&](const auto& p) {
      return std::any_of(p.rows.begin() + static_cast<std::ptrdiff_t>(p.head), p.rows.end(),
                         of_run);
    };
    return in(gyro) || in(temps) || in(table);
  };
  for (auto it = closing.begin(); it != closing.end();) {
    const int64_t run_id = *it;
    // A stream with an open chunk is kept until a commit wrote the chunk
    // whole (the loop's next round: close_run asked for one).
    const bool open_chunk = std::any_of(streams.begin(), streams.end(), [&](const auto& kv) {
      return std::get<0>(kv.first) == run_id &&
             (kv.second.builder->has_open_chunk() || kv.second.builder->unpacked() > 0);
    });
    if (waits(run_id) || open_chunk) {
      ++it;
      continue;
    }
    std::erase_if(streams, [&](const auto& kv) { return std::get<0>(kv.first) == run_id; });
    std::erase_if(known_duts, [&](const auto& kv) { return std::get<0>(kv.first) == run_id; });
    first_dut.erase(run_id);
    it = closing.erase(it);
  }
  std::set<int64_t> held;
  for (const auto& kv : streams) held.insert(std::get<0>(kv.first));
  for (const auto& kv : known_duts) held.insert(std::get<0>(kv.first));
  for (const auto& kv : first_dut) held.insert(kv.first);
  stats.runs_held = held.size();
}

Status SampleWriter::Impl::prepare() {
  sqlite3* h = db.handle();
  struct {
    Stmt* stmt;
    const char* sql;
  } const statements[] = {
      {&begin, "BEGIN IMMEDIATE"},
      {&commit, "COMMIT"},
      {&rollback, "ROLLBACK"},
      {&insert_temp,
       "INSERT OR IGNORE INTO temperature_samples(run_id, t_s, setpoint_c, chamber_c, top_c, "
       "side_c) VALUES(?, ?, ?, ?, ?, ?)"},
      {&insert_table,
       "INSERT OR IGNORE INTO table_samples(run_id, t_s, demand_mode, demand_rate_dps, "
       "demand_position_deg, rate_dps, position_deg, mode, interlock) "
       "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?)"},
  };
  for (const auto& s : statements) {
    auto st = Stmt::prepare(h, path, s.sql, /*persistent=*/true);
    if (!st) return st.error();
    *s.stmt = std::move(*st);
  }
  return Status::Ok();
}

Result<int64_t> SampleWriter::Impl::first_dut_of(int64_t run_id) {
  if (auto it = first_dut.find(run_id); it != first_dut.end()) return it->second;
  sqlite3* h = db.handle();
  auto st = Stmt::prepare(h, path,
                          "SELECT dut_id FROM run_duts WHERE run_id = ? ORDER BY position LIMIT 1");
  if (!st) return st.error();
  st->bind(1, run_id);
  const int rc = st->step();
  int64_t dut_id = 0;
  if (rc == SQLITE_ROW) {
    dut_id = st->column_int64(0);
  } else if (rc == SQLITE_DONE) {
    // A run without DUT (older callers): the unnamed gyro, as the v9
    // migration registers it, on the run's configured axis.
    auto axis = Stmt::prepare(
        h, path,
        "SELECT CASE WHEN json_valid(config_json) AND json_extract(config_json, '$.gyro.axis') "
        "IN ('x', 'y', 'z') THEN json_extract(config_json, '$.gyro.axis') ELSE 'z' END "
        "FROM runs WHERE id = ?");
    if (!axis) return axis.error();
    axis->bind(1, run_id);
    const std::string a = axis->step() == SQLITE_ROW ? axis->column_text(0) : "z";
    auto id = internal::register_unnamed_gyro(h, path, run_id, a, db.utc_now());
    if (!id) return id.error();
    dut_id = *id;
  } else {
    return sqlite_error(h, path, fmt::format("reading the DUTs of run {}", run_id));
  }
  first_dut[run_id] = dut_id;
  return dut_id;
}

Result<SampleWriter::Impl::Stream*> SampleWriter::Impl::stream_for(const FrameRow& r) {
  int64_t dut_id = 0;
  if (r.dut) {
    dut_id = r.dut->dut.id;
  } else {
    auto id = first_dut_of(r.run_id);
    if (!id) return id.error();
    dut_id = *id;
  }
  const int64_t first_channel = r.dut && !r.dut->channels.empty() ? r.dut->channels[0].id : 0;
  auto [it, inserted] = streams.try_emplace({r.run_id, dut_id, first_channel});
  Stream& s = it->second;
  if (!inserted) return &s;
  sqlite3* h = db.handle();
  std::vector<internal::ChannelInfo> channels;
  double rate_hz = 0;
  uint32_t seq_modulo = 0;
  std::string primary_axis;
  if (r.dut) {
    for (const ChannelRecord& c : r.dut->channels) {
      channels.push_back({.id = c.id,
                          .index = c.index,
                          .name = c.spec.name,
                          .unit = c.spec.unit,
                          .axis = c.spec.axis,
                          .kind = c.spec.kind,
                          .scale = c.spec.scale});
    }
    rate_hz = r.dut->rate_hz;
    seq_modulo = r.dut->seq_modulo;
    primary_axis = r.dut->primary_axis;
  } else {
    auto chans = internal::read_channels(h, path, r.run_id, dut_id);
    if (!chans) return chans.error();
    channels = std::move(*chans);
    auto st = Stmt::prepare(h, path,
                            "SELECT coalesce(rate_hz, 0), seq_modulo, primary_axis FROM run_duts "
                            "WHERE run_id = ? AND dut_id = ?");
    if (!st) return st.error();
    st->bind(1, r.run_id);
    st->bind(2, dut_id);
    if (st->step() != SQLITE_ROW) {
      return sqlite_error(h, path, fmt::format("reading DUT {} of run {}", dut_id, r.run_id));
    }
    rate_hz = st->column_double(0);
    seq_modulo = static_cast<uint32_t>(st->column_int64(1));
    primary_axis = st->column_text(2);
  }
  for (const internal::ChannelInfo& c : channels) {
    if (c.kind == ChannelKind::kRate && s.rate_idx < 0 &&
        (c.axis == primary_axis || primary_axis.empty())) {
      s.rate_idx = c.index;
      s.rate_scale = c.scale != 0 ? c.scale : 1;
    }
    if (c.kind == ChannelKind::kStatus && s.status_idx < 0) s.status_idx = c.index;
    if (c.kind == ChannelKind::kTemperature && s.temp_idx < 0) s.temp_idx = c.index;
  }
  // Where the stored samples end: the last chunk of each of the stream's
  // channels.
  std::string ids;
  for (const internal::ChannelInfo& c : channels) {
    ids += fmt::format("{}{}", ids.empty() ? "" : ",", c.id);
  }
  auto last = Stmt::prepare(h, path,
                            "SELECT max((SELECT t0_s + (n - 1) * period_s FROM sample_chunks k "
                            "WHERE k.channel_id = c.id ORDER BY t0_s DESC LIMIT 1)) "
                            "FROM channels c WHERE c.run_id = ? AND c.dut_id = ? AND c.id IN (" +
                                ids + ")");
  if (!last) return last.error();
  last->bind(1, r.run_id);
  last->bind(2, dut_id);
  if (last->step() != SQLITE_ROW) {
    return sqlite_error(h, path, fmt::format("reading the last samples of run {}", r.run_id));
  }
  s.builder = std::make_unique<internal::ChunkBuilder>(std::move(channels), rate_hz, seq_modulo);
  s.builder->set_last_stored_t_s(last->column_optional_double(0));
  return &s;
}

SampleWriter::Impl::Outcome SampleWriter::Impl::fail_batch(std::string_view what) {
  Error e = sqlite_error(db.handle(), path, what);
  begin.reset();
  insert_temp.reset();
  insert_table.reset();
  streams.clear();
  first_dut.clear();
  left_pieces = true;  // the dropped streams' pieces
  commit.reset();
  if (!sqlite3_get_autocommit(db.handle())) {
    rollback.step();
    rollback.reset();
  }
  return {Status(std::move(e)), 0};
}

SampleWriter::Impl::Outcome SampleWriter::Impl::commit_batch(bool finish_all,
                                                             const std::set<int64_t>& finishing) {
  const std::size_t n_gyro = batch_gyro.size();
  const std::size_t n_temps = batch_temps.size();
  const std::size_t n_table = batch_table.size();
  const auto finishes = [&](const auto& key) {
    return finish_all || finishing.contains(std::get<0>(key));
  };
  if (n_gyro + n_temps + n_table == 0 && !left_pieces &&
      std::none_of(streams.begin(), streams.end(), [&](const auto& kv) {
        return (kv.second.builder->has_open_chunk() && finishes(kv.first)) ||
               kv.second.builder->unpacked() > 0;
      })) {
    return {};
  }
  const std::string what = fmt::format("committing {} gyro, {} temperature and {} table samples",
                                       n_gyro, n_temps, n_table);
  sqlite3* h = db.handle();
  if (begin.step() != SQLITE_DONE) return fail_batch(what);
  begin.reset();
  uint64_t duplicates = 0;
  uint64_t channel_samples = 0;
  // Frames go into their DUT's chunks in time order. Producers push each
  // DUT's frames in order; should two producers interleave one DUT, the
  // batch is sorted (stable) per DUT first.
  {
    auto& rows = batch_gyro.rows;
    const auto first = rows.begin() + static_cast<std::ptrdiff_t>(batch_gyro.head);
    auto key = [](const FrameRow& r) {
      return std::pair{r.run_id, r.dut ? r.dut->dut.id : int64_t{-1}};
    };
    std::vector<std::pair<std::pair<int64_t, int64_t>, double>> last;  // few DUTs
    bool sorted = true;
    for (auto it = first; it != rows.end() && sorted; ++it) {
      const auto k = key(*it);
      auto l = std::find_if(last.begin(), last.end(), [&](const auto& e) { return e.first == k; });
      if (l == last.end()) {
        last.emplace_back(k, it->f.t_s);
      } else if (it->f.t_s < l->second) {
        sorted = false;
      } else {
        l->second = it->f.t_s;
      }
    }
    if (!sorted) {
      std::stable_sort(first, rows.end(), [&](const FrameRow& a, const FrameRow& b) {
        return std::pair{key(a), a.f.t_s} < std::pair{key(b), b.f.t_s};
      });
    }
  }
  Stream* stream = nullptr;
  std::pair<int64_t, const RunDutRecord*> stream_key{0, nullptr};
  std::array<double, kMaxChannels> raw{};
  for (std::size_t i = batch_gyro.head; i < batch_gyro.rows.size(); ++i) {
    const FrameRow& r = batch_gyro.rows[i];
    if (!stream || stream_key != std::pair{r.run_id, r.dut}) {
      auto s = stream_for(r);
      if (!s) {
        Outcome out = fail_batch(what);
        out.status = Status(s.error());
        return out;
      }
      stream = *s;
      stream_key = {r.run_id, r.dut};
      stream->touched = true;
    }
    const double* values = r.f.raw.data();
    if (!r.dut) {
      raw.fill(std::numeric_limits<double>::quiet_NaN());
      if (stream->rate_idx >= 0) raw[stream->rate_idx] = r.f.raw[0] / stream->rate_scale;
      if (stream->status_idx >= 0) raw[stream->status_idx] = r.f.raw[1];
      if (stream->temp_idx >= 0) raw[stream->temp_idx] = r.f.raw[2];
      values = raw.data();
    }
    if (stream->builder->add(r.f.t_s, r.f.seq, values)) {
      channel_samples += stream->builder->channels().size();
    } else {
      ++duplicates;
    }
  }
  // The open chunks that close now, with this batch's samples.
  for (auto& [key, st] : streams) {
    if (st.builder->has_open_chunk() && finishes(key)) {
      st.builder->finish();
      st.touched = true;
    }
  }
  // Packing closed chunks is most of a commit's work, and every channel's
  // chunk of a DUT closes at the same frame: a commit packs a few
  // (kPackPerCommit, more when many wait) and leaves the rest as pieces for
  // the next ones; stopping packs every one.
  std::size_t backlog = 0;
  for (const auto& kv : streams) backlog += kv.second.builder->unpacked();
  std::size_t budget = std::max(kPackPerCommit, (backlog + 3) / 4);
  std::size_t* const pack_budget = finish_all ? nullptr : &budget;
  uint64_t chunks = 0;
  for (auto& [key, st] : streams) {
    if (!st.touched && st.builder->unpacked() == 0) continue;
    const uint64_t before = st.builder->chunks_written();
    if (Status s = st.builder->flush(h, path, pack_budget); !s) {
      Outcome out = fail_batch(what);
      out.status = s;
      return out;
    }
    chunks += st.builder->chunks_written() - before;
    st.touched = false;
  }
  if (left_pieces && (finish_all || budget > 0)) {
    std::vector<int64_t> owned;
    for (const auto& kv : streams) kv.second.builder->add_piece_ids(owned);
    std::sort(owned.begin(), owned.end());
    bool more = false;
    auto packed = internal::pack_left_pieces(h, path, owned, finish_all ? 0 : budget, &more);
    if (!packed) {
      Outcome out = fail_batch(what);
      out.status = Status(packed.error());
      return out;
    }
    chunks += *packed;
    left_pieces = more;
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
  return {Status::Ok(), duplicates, channel_samples, chunks, chunks > 0};
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
    // Closed runs whose rows are all in this batch: their chunks close.
    std::set<int64_t> finishing;
    for (int64_t run_id : closing) {
      const auto of_run = [run_id](const auto& r) { return r.run_id == run_id; };
      const auto in = [&](const auto& p) {
        return std::any_of(p.rows.begin() + static_cast<std::ptrdiff_t>(p.head), p.rows.end(),
                           of_run);
      };
      if (!in(gyro) && !in(temps) && !in(table)) finishing.insert(run_id);
    }
    const auto t0 = Clock::now();
    next_commit = t0 + options.commit_interval;
    lk.unlock();

    Outcome out = commit_batch(stopping, finishing);
    const double elapsed_ms = ms_since(t0);
    // A round that only packed chunks is a commit too (its time counts).
    const bool wrote = n_rows > 0 || out.wrote;
    if (out.status.ok() && wrote && on_commit) {
      on_commit(elapsed_ms / 1000.0);
    }

    lk.lock();
    inflight = 0;
    if (out.status.ok()) {
      committed_through = batch;
      stats.consecutive_failures = 0;
      if (wrote) {
        stats.gyro_rows += n_gyro;
        stats.temperature_rows += n_temps;
        stats.table_rows += n_table;
        stats.duplicates += out.duplicates;
        stats.channel_samples += out.channel_samples;
        stats.chunks += out.chunks;
        ++stats.commits;
        stats.last_commit_ms = elapsed_ms;
        stats.max_commit_ms = std::max(stats.max_commit_ms, elapsed_ms);
      }
      batch_gyro.clear();
      batch_temps.clear();
      batch_table.clear();
      release_closed_runs_locked();
      // A closed run is released once its chunks are packed, a few per
      // commit: the next round comes at once while some wait.
      for (const auto& kv : streams) {
        if (closing.contains(std::get<0>(kv.first)) && kv.second.builder->unpacked() > 0) {
          flush_requested = true;
        }
      }
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
    const std::string msg = fmt::format(
        "storage: {}: sample writer stopped: {}; nothing more is committed until the daemon is "
        "restarted",
        path, what);
    stats.last_error = msg;
    stats.thread_failed = true;
    ++stats.commit_failures;
    ++stats.consecutive_failures;
    last_failure = Error::Permanent(msg);
    failed_through = next_batch;
    accepting = false;
    thread_done = true;
    done.notify_all();
  }
}

bool SampleWriterOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  // 0 would commit in a busy loop; a queue of 0 drops every sample.
  if (commit_interval <= std::chrono::milliseconds::zero()) {
    return fail(fmt::format("commit_interval = {} ms must be > 0", commit_interval.count()));
  }
  if (max_pending == 0) return fail("max_pending = 0 must be >= 1");
  return true;
}

Result<std::unique_ptr<SampleWriter>> SampleWriter::start(
    const std::string& db_path, SampleWriterOptions options,
    std::function<void(double seconds)> on_commit) {
  if (std::string why; !options.is_valid(&why)) {
    return Error::Permanent(fmt::format("storage: {}: sample writer options: {}", db_path, why));
  }
  auto db = Database::open(db_path);
  if (!db) return db.error();
  // Samples are not tied to their run by a foreign key (insert speed, and
  // samples pushed for a run id without row stay as before); the unnamed
  // gyro's registration follows suit.
  if (Status s = db->exec("PRAGMA foreign_keys=OFF"); !s) return s.error();
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
    FrameRow& r = m.gyro.rows.emplace_back(FrameRow{run_id, nullptr, {}});
    r.f.t_s = s.t_s;
    r.f.seq = s.seq;
    r.f.raw[0] = s.rate_dph;
    r.f.raw[1] = s.status;
    r.f.raw[2] = s.temp_c;
  }
  m.trim_locked();
}

void SampleWriter::push_frames(const RunDutRecord& dut, std::span<const DutFrame> frames) {
  Impl& m = *impl_;
  std::lock_guard lk(m.mu);
  // Only a DUT registered in its run (add_run_dut: ids set) has chunks to go to.
  const bool registered =
      dut.dut.id > 0 && !dut.channels.empty() && dut.channels.size() <= kMaxChannels &&
      std::all_of(dut.channels.begin(), dut.channels.end(), [](const ChannelRecord& c) {
        return c.id > 0 && c.index >= 0 && c.index < static_cast<int>(kMaxChannels);
      });
  if (!m.accepting || !registered) {
    m.stats.rejected += frames.size();
    return;
  }
  auto& known = m.known_duts[{dut.run_id, dut.dut.id, dut.channels.front().id}];
  if (!known) known = std::make_unique<RunDutRecord>(dut);
  for (const DutFrame& f : frames) {
    if (!std::isfinite(f.t_s)) {
      ++m.stats.rejected;
      continue;
    }
    m.gyro.rows.push_back(FrameRow{dut.run_id, known.get(), f});
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
  if (m.stats.thread_failed && m.last_failure) return *m.last_failure;
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

void SampleWriter::close_run(int64_t run_id) {
  Impl& m = *impl_;
  {
    std::lock_guard lk(m.mu);
    m.closing.insert(run_id);
    m.flush_requested = true;
  }
  m.wake.notify_one();
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
