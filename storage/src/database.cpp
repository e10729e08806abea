#include "gyrotherm/storage/database.h"

#include <fmt/format.h>
#include <sqlite3.h>
#include <sys/sysmacros.h>
#include <sys/types.h>

#include <boost/uuid/uuid.hpp>
#include <boost/uuid/uuid_generators.hpp>
#include <boost/uuid/uuid_io.hpp>
#include <charconv>
#include <chrono>
#include <cmath>
#include <nlohmann/json.hpp>
#include <thread>
#include <utility>

#include "duts_internal.h"
#include "gyrotherm/core/clock.h"
#include "migrations.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;
using internal::Transaction;

namespace {

constexpr int kBusyTimeoutMs = 5000;

// 0 for an empty file (no tables at all). Refuses an SQLite file that has
// tables but no meta table: it belongs to something else.
Result<int> read_schema_version(sqlite3* db, const std::string& path) {
  // One statement, so one snapshot: another connection may create the
  // schema between two separate reads.
  bool has_meta = false, empty = false;
  {
    auto probe = Stmt::prepare(db, path,
                               "SELECT (SELECT count(*) FROM sqlite_master WHERE type='table' AND "
                               "name='meta'), (SELECT count(*) FROM sqlite_master)");
    if (!probe) return probe.error();
    if (probe->step() != SQLITE_ROW) return sqlite_error(db, path, "reading the schema");
    has_meta = probe->column_int64(0) != 0;
    empty = probe->column_int64(1) == 0;
  }
  if (!has_meta) {
    if (!empty) {
      return Error::Permanent(fmt::format(
          "storage: {}: not a gyrotherm database (it has tables but no meta table)", path));
    }
    return 0;
  }
  auto st = Stmt::prepare(db, path, "SELECT value FROM meta WHERE key='schema_version'");
  if (!st) return st.error();
  const int rc = st->step();
  if (rc == SQLITE_DONE) {
    return Error::Permanent(
        fmt::format("storage: {}: meta table has no 'schema_version' row", path));
  }
  if (rc != SQLITE_ROW) return sqlite_error(db, path, "reading the schema version");
  const std::string text = st->column_text(0);
  int version = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), version);
  if (ec != std::errc() || end != text.data() + text.size() || version < 0) {
    return Error::Permanent(fmt::format(
        "storage: {}: meta 'schema_version' is not a version number: '{}'", path, text));
  }
  return version;
}

Error newer_schema_error(const std::string& path, int version) {
  return Error::Permanent(
      fmt::format("storage: {}: database has schema version {}, newer than this build's {}; "
                  "use a newer gyrotherm (databases are never downgraded)",
                  path, version, kSchemaVersion));
}

Status migrate(sqlite3* db, const std::string& path, const WallClock& wall) {
  auto current = read_schema_version(db, path);
  if (!current) return current.error();
  if (*current > kSchemaVersion) return newer_schema_error(path, *current);
  if (*current == kSchemaVersion) return Status::Ok();

  for (const internal::Migration& m : internal::migrations()) {
    Transaction txn(db, path);
    if (Status s = txn.begin_immediate(); !s) return s;
    // Read again under the write lock: another connection may have migrated.
    auto version = read_schema_version(db, path);
    if (!version) return version.error();
    if (*version > kSchemaVersion) return newer_schema_error(path, *version);
    if (*version >= m.version) continue;  // rolls back the empty transaction
    if (*version != m.version - 1) {
      return Error::Permanent(
          fmt::format("storage: {}: schema version {} cannot be migrated by step {} ({})", path,
                      *version, m.version, m.name));
    }
    const std::string what = fmt::format("migrating to schema version {} ({})", m.version, m.name);
    if (*version == 0) {
      if (Status s = internal::exec(db, path,
                                    "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL)");
          !s) {
        return Error{fmt::format("{} [{}]", s.error().message, what), s.error().transient};
      }
    }
    if (Status s = internal::exec(db, path, m.sql); !s) {
      return Error{fmt::format("{} [{}]", s.error().message, what), s.error().transient};
    }
    if (m.data_step) {
      if (Status s = m.data_step(db, path, utc_iso(wall)); !s) {
        return Error{fmt::format("{} [{}]", s.error().message, what), s.error().transient};
      }
    }
    auto st = Stmt::prepare(db, path,
                            "INSERT INTO meta(key, value) VALUES('schema_version', ?) "
                            "ON CONFLICT(key) DO UPDATE SET value = excluded.value");
    if (!st) return st.error();
    st->bind(1, std::string_view(std::to_string(m.version)));
    if (st->step() != SQLITE_DONE) return sqlite_error(db, path, what);
    auto created =
        Stmt::prepare(db, path, "INSERT OR IGNORE INTO meta(key, value) VALUES('created_utc', ?)");
    if (!created) return created.error();
    created->bind(1, std::string_view(utc_iso(wall)));
    if (created->step() != SQLITE_DONE) return sqlite_error(db, path, what);
    if (Status s = txn.commit(); !s) return s;
  }
  return Status::Ok();
}

constexpr const char* kRunColumns =
    "id, schedule_name, state, started_utc, ended_utc, time_scale, latitude_deg, orientation, "
    "config_json, queue_id, schedule_id, resume_json, checkpoint_wall_unix_s, config_toml, "
    "operator, comment, tags_json, dut_serials_json, uuid";

Result<RunRecord> read_run(const Stmt& st, const std::string& path) {
  RunRecord r;
  r.id = st.column_int64(0);
  r.schedule_name = st.column_text(1);
  r.state = st.column_text(2);
  r.started_utc = st.column_text(3);
  r.ended_utc = st.column_text(4);
  r.time_scale = st.column_double(5);
  r.latitude_deg = st.column_double(6);
  r.orientation = st.column_text(7);
  r.config_json = st.column_text(8);
  r.queue_id = st.column_optional_int64(9);
  r.schedule_id = st.column_optional_int64(10);
  r.resume_json = st.column_text(11);
  r.checkpoint_wall_unix_s = st.column_optional_double(12);
  r.config_toml = st.column_text(13);
  auto metadata = internal::read_metadata(st, 14, fmt::format("storage: {}: run {}", path, r.id));
  if (!metadata) return metadata.error();
  r.metadata = std::move(*metadata);
  r.uuid = st.column_text(18);
  return r;
}

// A random (version 4) UUID in the RFC 4122 text form, lower case.
Result<std::string> random_uuid(const std::string& path) {
  try {
    boost::uuids::random_generator generate;  // the kernel's entropy (getrandom)
    return boost::uuids::to_string(generate());
  } catch (const std::exception& e) {
    return Error::Transient(fmt::format("storage: {}: making a run uuid: {}", path, e.what()));
  }
}

// xxxxxxxx-xxxx-xxxx-xxxx-xxxxxxxxxxxx, lower-case hex digits.
bool is_uuid_text(std::string_view s) {
  if (s.size() != 36) return false;
  for (std::size_t i = 0; i < s.size(); ++i) {
    const char c = s[i];
    if (i == 8 || i == 13 || i == 18 || i == 23) {
      if (c != '-') return false;
    } else if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) {
      return false;
    }
  }
  return true;
}

constexpr const char* kSegmentColumns =
    "id, run_id, idx, kind, label, setpoint_c, ramp_rate_c_per_min, t_start_s, t_settled_s, "
    "t_acquire_start_s, t_acquire_end_s, t_end_s, paused_s, state, table_mode, table_rate_dps, "
    "table_position_deg, table_mean_rate_dps, table_mean_position_deg, turns, dwell_s, "
    "sf_sequence, sf_repetition";

SegmentRecord read_segment(const Stmt& st) {
  SegmentRecord s;
  s.id = st.column_int64(0);
  s.run_id = st.column_int64(1);
  s.index = static_cast<int>(st.column_int64(2));
  s.kind = st.column_text(3);
  s.label = st.column_text(4);
  s.setpoint_c = st.column_double(5);
  s.ramp_rate_c_per_min = st.column_double(6);
  s.t_start_s = st.column_double(7);
  s.t_settled_s = st.column_optional_double(8);
  s.t_acquire_start_s = st.column_optional_double(9);
  s.t_acquire_end_s = st.column_optional_double(10);
  s.t_end_s = st.column_optional_double(11);
  s.paused_s = st.column_double(12);
  s.state = st.column_text(13);
  s.table_mode = st.column_text(14);
  s.table_rate_dps = st.column_optional_double(15);
  s.table_position_deg = st.column_optional_double(16);
  s.table_mean_rate_dps = st.column_optional_double(17);
  s.table_mean_position_deg = st.column_optional_double(18);
  s.turns = static_cast<int>(st.column_int64(19));
  s.dwell_s = st.column_double(20);
  s.sf_sequence = static_cast<int>(st.column_int64(21));
  s.sf_repetition = static_cast<int>(st.column_int64(22));
  return s;
}

// Binds the segment's fields from parameter `first` on, in kSegmentColumns
// order without id.
void bind_segment(Stmt& st, const SegmentRecord& s, int first) {
  int i = first;
  st.bind(i++, s.run_id);
  st.bind(i++, s.index);
  st.bind(i++, std::string_view(s.kind));
  st.bind(i++, std::string_view(s.label));
  st.bind(i++, s.setpoint_c);
  st.bind(i++, s.ramp_rate_c_per_min);
  st.bind(i++, s.t_start_s);
  st.bind(i++, s.t_settled_s);
  st.bind(i++, s.t_acquire_start_s);
  st.bind(i++, s.t_acquire_end_s);
  st.bind(i++, s.t_end_s);
  st.bind(i++, s.paused_s);
  st.bind(i++, std::string_view(s.state));
  st.bind(i++, std::string_view(s.table_mode));
  st.bind(i++, s.table_rate_dps);
  st.bind(i++, s.table_position_deg);
  st.bind(i++, s.table_mean_rate_dps);
  st.bind(i++, s.table_mean_position_deg);
  st.bind(i++, s.turns);
  st.bind(i++, s.dwell_s);
  st.bind(i++, s.sf_sequence);
  st.bind(i++, s.sf_repetition);
}
constexpr int kSegmentBoundColumns = 22;  // bind_segment's parameters

constexpr const char* kStatsColumns =
    "segment_id, run_id, segment_index, setpoint_c, n, duration_s, temp_mean_c, bias_mean_dph, "
    "bias_std_dph, bias_std_ma_dph, bias_mean_earth_removed_dph, bin_s, ma_window, "
    "earth_rate_dph, t_from_s, t_to_s, computed_utc, dut_serial, axis, coverage_samples, "
    "coverage_expected, coverage, longest_gap_s, quality, quality_reasons_json";

}  // namespace

Database::Database(sqlite3* db, std::string path, const WallClock& wall)
    : db_(db), path_(std::move(path)), wall_(&wall) {
  const char* file = db_ != nullptr ? sqlite3_db_filename(db_, "main") : nullptr;
  if (file == nullptr || *file == '\0') return;  // in memory, temporary
  if (auto id = internal::identity_of(file)) {
    guard_ = std::make_unique<internal::FileGuard>(internal::FileGuard{file, *id});
  }
}

Result<Database> Database::open(const std::string& path, const WallClock& wall, OpenCheck check) {
  sqlite3* raw = nullptr;
  const int rc =
      sqlite3_open_v2(path.c_str(), &raw, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr);
  Database db(raw, path, wall);  // owns the handle even when opening failed
  if (rc != SQLITE_OK) return sqlite_error(raw, path, "cannot open");
  sqlite3_extended_result_codes(raw, 1);
  sqlite3_busy_timeout(raw, kBusyTimeoutMs);
  if (db.guard_) internal::install_file_guard(raw, db.guard_.get());
  // A new file gets 2 KiB pages (SQLite's default is 4 KiB): a packed
  // chunk's row keeps at most a page of it in its leaf, and rows of 0.2 …
  // 2 KiB pack into the leaves with less left over than rows of 0.5 … 4 KiB
  // (docs/storage.md "Encodings": 2.0 % of the chunk table unused against
  // 8.9 %). An existing file keeps its page size (this is a no-op there).
  if (Status s = internal::exec(raw, path, "PRAGMA page_size=2048"); !s) return s.error();

  {
    // Switching a new file to WAL takes an exclusive lock and may answer
    // SQLITE_BUSY without consulting the busy handler when another
    // connection opens the same new file at that moment: retry, bounded.
    std::string mode;
    const auto deadline =
        std::chrono::steady_clock::now() + std::chrono::milliseconds(kBusyTimeoutMs);
    for (;;) {
      auto st = Stmt::prepare(raw, path, "PRAGMA journal_mode=WAL");
      if (!st) return st.error();
      const int step_rc = st->step();
      if (step_rc == SQLITE_ROW) {
        mode = st->column_text(0);
        break;
      }
      if ((step_rc & 0xff) != SQLITE_BUSY || std::chrono::steady_clock::now() >= deadline) {
        return sqlite_error(raw, path, "enabling WAL");
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    if (mode != "wal" && mode != "memory") {
      return Error::Permanent(fmt::format(
          "storage: {}: cannot enable WAL journal mode (got '{}'); is the file on a network "
          "filesystem?",
          path, mode));
    }
  }
  if (Status s = internal::exec(raw, path, "PRAGMA synchronous=NORMAL; PRAGMA foreign_keys=ON");
      !s) {
    return s.error();
  }
  if (check == OpenCheck::kQuick) {
    if (Status s = db.verify_quick(); !s) return s.error();
  }
  if (Status s = migrate(raw, path, wall); !s) return s.error();
  return db;
}

Result<Database> Database::open_read_only(const std::string& path) {
  sqlite3* raw = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &raw, SQLITE_OPEN_READONLY, nullptr);
  Database db(raw, path, system_wall_clock());  // stamps nothing
  if (rc != SQLITE_OK) return sqlite_error(raw, path, "cannot open read-only");
  sqlite3_extended_result_codes(raw, 1);
  sqlite3_busy_timeout(raw, kBusyTimeoutMs);
  auto version = read_schema_version(raw, path);
  if (!version) return version.error();
  if (*version == 0) {
    return Error::Permanent(fmt::format("storage: {}: not a gyrotherm database (empty)", path));
  }
  if (*version > kSchemaVersion) return newer_schema_error(path, *version);
  if (*version < kSchemaVersion) {
    return Error::Permanent(fmt::format(
        "storage: {}: database has schema version {}, older than this build's {}; open it "
        "once read-write (gyrothermd, or gyrotherm on the file) to migrate it",
        path, *version, kSchemaVersion));
  }
  return db;
}

Database::Database(Database&& other) noexcept
    : db_(std::exchange(other.db_, nullptr)),
      path_(std::move(other.path_)),
      wall_(other.wall_),
      guard_(std::move(other.guard_)) {}

Database& Database::operator=(Database&& other) noexcept {
  if (this != &other) {
    sqlite3_close_v2(db_);
    db_ = std::exchange(other.db_, nullptr);
    path_ = std::move(other.path_);
    wall_ = other.wall_;
    guard_ = std::move(other.guard_);
  }
  return *this;
}

Database::~Database() { sqlite3_close_v2(db_); }

std::string Database::utc_now() const { return utc_iso(*wall_); }

Result<int> Database::schema_version() { return read_schema_version(db_, path_); }

Result<int64_t> Database::create_run(const RunRecord& run) {
  if (Status s = internal::check_metadata(run.metadata, path_, "creating a run"); !s) {
    return s.error();
  }
  std::string uuid = run.uuid;
  if (uuid.empty()) {
    auto made = random_uuid(path_);
    if (!made) return made.error();
    uuid = std::move(*made);
  } else if (!is_uuid_text(uuid)) {
    return Error::Permanent(
        fmt::format("storage: {}: creating a run: uuid '{}' is not a UUID in lower-case text "
                    "form (xxxxxxxx-xxxx-xxxx-xxxx-xxxxxxxxxxxx)",
                    path_, uuid));
  }
  auto st = Stmt::prepare(db_, path_,
                          "INSERT INTO runs(schedule_name, state, started_utc, ended_utc, "
                          "time_scale, latitude_deg, orientation, config_json, queue_id, "
                          "schedule_id, config_toml, operator, comment, tags_json, "
                          "dut_serials_json, uuid) VALUES(?, ?, ?, NULL, ?, ?, ?, ?, ?, ?, ?, ?, "
                          "?, ?, ?, ?)");
  if (!st) return st.error();
  st->bind(1, std::string_view(run.schedule_name));
  st->bind(2, std::string_view(run.state));
  st->bind(3, std::string_view(utc_or_now(run.started_utc)));
  st->bind(4, run.time_scale);
  st->bind(5, run.latitude_deg);
  st->bind(6, std::string_view(run.orientation));
  st->bind_text_or_null(7, run.config_json);
  st->bind(8, run.queue_id);
  st->bind(9, run.schedule_id);
  st->bind_text_or_null(10, run.config_toml);
  internal::bind_metadata(*st, 11, run.metadata);
  st->bind(15, std::string_view(uuid));
  if (Status s = expect_done(*st, db_, path_, "creating a run"); !s) return s.error();
  return static_cast<int64_t>(sqlite3_last_insert_rowid(db_));
}

Status Database::set_run_state(int64_t run_id, std::string_view state, bool ended) {
  auto st = Stmt::prepare(db_, path_, "UPDATE runs SET state = ?, ended_utc = ? WHERE id = ?");
  if (!st) return st.error();
  st->bind(1, state);
  if (ended) {
    st->bind(2, std::string_view(utc_now()));
  } else {
    st->bind_null(2);
  }
  st->bind(3, run_id);
  const std::string what = fmt::format("setting run {} state to '{}'", run_id, state);
  if (Status s = expect_done(*st, db_, path_, what); !s) return s;
  if (sqlite3_changes(db_) == 0) {
    return Error::Permanent(fmt::format("storage: {}: {}: no such run", path_, what));
  }
  return Status::Ok();
}

Result<std::vector<RunRecord>> Database::runs() {
  auto st = Stmt::prepare(db_, path_, fmt::format("SELECT {} FROM runs ORDER BY id", kRunColumns));
  if (!st) return st.error();
  std::vector<RunRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    auto run = read_run(*st, path_);
    if (!run) return run.error();
    out.push_back(std::move(*run));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db_, path_, "reading runs");
  return out;
}

Result<RunRecord> Database::run(int64_t run_id) {
  auto st = Stmt::prepare(db_, path_, fmt::format("SELECT {} FROM runs WHERE id = ?", kRunColumns));
  if (!st) return st.error();
  st->bind(1, run_id);
  const int rc = st->step();
  if (rc == SQLITE_ROW) return read_run(*st, path_);
  if (rc == SQLITE_DONE) {
    return Error::Permanent(fmt::format("storage: {}: no run with id {}", path_, run_id));
  }
  return sqlite_error(db_, path_, fmt::format("reading run {}", run_id));
}

Result<int64_t> Database::create_segment(const SegmentRecord& segment) {
  auto st = Stmt::prepare(db_, path_,
                          "INSERT INTO segments(run_id, idx, kind, label, setpoint_c, "
                          "ramp_rate_c_per_min, t_start_s, t_settled_s, t_acquire_start_s, "
                          "t_acquire_end_s, t_end_s, paused_s, state, table_mode, "
                          "table_rate_dps, table_position_deg, table_mean_rate_dps, "
                          "table_mean_position_deg, turns, dwell_s, sf_sequence, sf_repetition) "
                          "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
                          "?)");
  if (!st) return st.error();
  bind_segment(*st, segment, 1);
  if (Status s =
          expect_done(*st, db_, path_,
                      fmt::format("creating segment {} of run {}", segment.index, segment.run_id));
      !s) {
    return s.error();
  }
  return static_cast<int64_t>(sqlite3_last_insert_rowid(db_));
}

Status Database::update_segment(const SegmentRecord& segment) {
  Transaction tx(db_, path_);
  if (Status s = tx.begin_immediate(); !s) return s;
  auto st = Stmt::prepare(db_, path_,
                          "UPDATE segments SET run_id = ?, idx = ?, kind = ?, label = ?, "
                          "setpoint_c = ?, ramp_rate_c_per_min = ?, t_start_s = ?, "
                          "t_settled_s = ?, t_acquire_start_s = ?, t_acquire_end_s = ?, "
                          "t_end_s = ?, paused_s = ?, state = ?, table_mode = ?, "
                          "table_rate_dps = ?, table_position_deg = ?, table_mean_rate_dps = ?, "
                          "table_mean_position_deg = ?, turns = ?, dwell_s = ?, sf_sequence = ?, "
                          "sf_repetition = ? WHERE id = ?");
  if (!st) return st.error();
  bind_segment(*st, segment, 1);
  st->bind(kSegmentBoundColumns + 1, segment.id);
  const std::string what = fmt::format("updating segment {}", segment.id);
  if (Status s = expect_done(*st, db_, path_, what); !s) return s;
  if (sqlite3_changes(db_) == 0) {
    return Error::Permanent(fmt::format("storage: {}: {}: no such segment", path_, what));
  }
  auto del = Stmt::prepare(db_, path_, "DELETE FROM acquisition_windows WHERE segment_id = ?");
  if (!del) return del.error();
  del->bind(1, segment.id);
  if (Status s = expect_done(*del, db_, path_, what); !s) return s;
  auto ins = Stmt::prepare(db_, path_,
                           "INSERT OR REPLACE INTO acquisition_windows(segment_id, run_id, "
                           "t_from_s, t_to_s) VALUES(?, ?, ?, ?)");
  if (!ins) return ins.error();
  for (const auto& [from_s, to_s] : segment.windows) {
    ins->reset();
    ins->bind(1, segment.id);
    ins->bind(2, segment.run_id);
    ins->bind(3, from_s);
    ins->bind(4, to_s);
    if (Status s = expect_done(*ins, db_, path_, what); !s) return s;
  }
  return tx.commit();
}

Result<std::vector<SegmentRecord>> Database::segments(int64_t run_id) {
  auto st = Stmt::prepare(
      db_, path_,
      fmt::format("SELECT {} FROM segments WHERE run_id = ? ORDER BY idx, id", kSegmentColumns));
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<SegmentRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) out.push_back(read_segment(*st));
  if (rc != SQLITE_DONE) {
    return sqlite_error(db_, path_, fmt::format("reading segments of run {}", run_id));
  }
  auto win = Stmt::prepare(db_, path_,
                           "SELECT t_from_s, t_to_s FROM acquisition_windows WHERE segment_id = ? "
                           "ORDER BY t_from_s");
  if (!win) return win.error();
  for (auto& seg : out) {
    win->reset();
    win->bind(1, seg.id);
    while ((rc = win->step()) == SQLITE_ROW) {
      seg.windows.emplace_back(win->column_double(0), win->column_double(1));
    }
    if (rc != SQLITE_DONE) {
      return sqlite_error(db_, path_, fmt::format("reading windows of segment {}", seg.id));
    }
  }
  return out;
}

Result<int64_t> Database::add_event(const EventRecord& event) {
  auto st = Stmt::prepare(db_, path_,
                          "INSERT INTO events(run_id, t_s, wall_utc, kind, from_state, to_state, "
                          "message) VALUES(?, ?, ?, ?, ?, ?, ?)");
  if (!st) return st.error();
  st->bind(1, event.run_id);
  st->bind(2, event.t_s);
  st->bind(3, std::string_view(utc_or_now(event.wall_utc)));
  st->bind(4, std::string_view(event.kind));
  st->bind_text_or_null(5, event.from_state);
  st->bind_text_or_null(6, event.to_state);
  st->bind(7, std::string_view(event.message));
  if (Status s = expect_done(*st, db_, path_, fmt::format("adding a '{}' event", event.kind)); !s) {
    return s.error();
  }
  return static_cast<int64_t>(sqlite3_last_insert_rowid(db_));
}

Result<std::vector<EventRecord>> Database::events(int64_t run_id) {
  auto st = Stmt::prepare(db_, path_,
                          "SELECT id, run_id, t_s, wall_utc, kind, from_state, to_state, message "
                          "FROM events WHERE run_id = ? ORDER BY id");
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<EventRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    EventRecord e;
    e.id = st->column_int64(0);
    e.run_id = st->column_optional_int64(1);
    e.t_s = st->column_double(2);
    e.wall_utc = st->column_text(3);
    e.kind = st->column_text(4);
    e.from_state = st->column_text(5);
    e.to_state = st->column_text(6);
    e.message = st->column_text(7);
    out.push_back(std::move(e));
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db_, path_, fmt::format("reading events of run {}", run_id));
  }
  return out;
}

Status Database::put_segment_stats(const SegmentStatsRecord& s) {
  const std::string what = fmt::format("storing statistics of segment {}", s.segment_id);
  auto key = internal::result_key(db_, path_, s.run_id, s.dut_serial, s.axis, what);
  if (!key) return key.error();
  auto st =
      Stmt::prepare(db_, path_,
                    fmt::format("INSERT OR REPLACE INTO segment_stats({}) "
                                "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
                                "?, ?, ?, ?, ?, ?)",
                                kStatsColumns));
  if (!st) return st.error();
  int i = 1;
  st->bind(i++, s.segment_id);
  st->bind(i++, s.run_id);
  st->bind(i++, s.segment_index);
  st->bind(i++, s.setpoint_c);
  st->bind(i++, s.n);
  st->bind(i++, s.duration_s);
  st->bind(i++, s.temp_mean_c);
  st->bind(i++, s.bias_mean_dph);
  st->bind(i++, s.bias_std_dph);
  st->bind(i++, s.bias_std_ma_dph);
  st->bind(i++, s.bias_mean_earth_removed_dph);
  st->bind(i++, s.bin_s);
  st->bind(i++, s.ma_window);
  st->bind(i++, s.earth_rate_dph);
  st->bind(i++, s.t_from_s);
  st->bind(i++, s.t_to_s);
  st->bind(i++, std::string_view(utc_or_now(s.computed_utc)));
  st->bind(i++, std::string_view(key->serial));
  st->bind(i++, std::string_view(key->axis));
  internal::bind_quality(*st, i, s.quality);
  internal::WriteScope tx(db_, path_, "put_segment_stats");
  if (Status s = tx.begin(); !s) return s;
  if (Status s = expect_done(*st, db_, path_, what); !s) return s;
  if (key->primary && !key->axis.empty()) {
    // The row stored before v8 for this DUT (axis '' = its primary axis)
    // is this series: the new row replaces it.
    auto legacy = Stmt::prepare(db_, path_,
                                "DELETE FROM segment_stats WHERE segment_id = ? AND "
                                "dut_serial = ? AND axis = ''");
    if (!legacy) return legacy.error();
    legacy->bind(1, s.segment_id);
    legacy->bind(2, std::string_view(key->serial));
    if (Status e = expect_done(*legacy, db_, path_, what); !e) return e;
  }
  return tx.commit();
}

Result<std::vector<SegmentStatsRecord>> Database::segment_stats(std::optional<int64_t> run_id) {
  const std::string columns = internal::qualified(kStatsColumns, "s");
  auto st = Stmt::prepare(
      db_, path_,
      fmt::format("SELECT {} FROM segment_stats s {} WHERE ?1 IS NULL OR s.run_id = ?1 "
                  "ORDER BY s.run_id, s.segment_index, s.segment_id, {}, s.dut_serial, s.axis",
                  columns, internal::dut_position_join("s"), internal::kDutPositionOrder));
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<SegmentStatsRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    SegmentStatsRecord r;
    int c = 0;
    r.segment_id = st->column_int64(c++);
    r.run_id = st->column_int64(c++);
    r.segment_index = static_cast<int>(st->column_int64(c++));
    r.setpoint_c = st->column_double(c++);
    r.n = st->column_int64(c++);
    r.duration_s = st->column_double(c++);
    r.temp_mean_c = st->column_double(c++);
    r.bias_mean_dph = st->column_double(c++);
    r.bias_std_dph = st->column_double(c++);
    r.bias_std_ma_dph = st->column_double(c++);
    r.bias_mean_earth_removed_dph = st->column_double(c++);
    r.bin_s = st->column_double(c++);
    r.ma_window = static_cast<int>(st->column_int64(c++));
    r.earth_rate_dph = st->column_double(c++);
    r.t_from_s = st->column_double(c++);
    r.t_to_s = st->column_double(c++);
    r.computed_utc = st->column_text(c++);
    r.dut_serial = st->column_text(c++);
    r.axis = st->column_text(c++);
    r.quality = internal::read_quality(*st, c);
    out.push_back(std::move(r));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db_, path_, "reading segment statistics");
  return out;
}

Result<std::vector<TemperatureSample>> Database::temperature_samples(int64_t run_id,
                                                                     double t_from_s,
                                                                     double t_to_s) {
  auto st = Stmt::prepare(db_, path_,
                          "SELECT t_s, setpoint_c, chamber_c, top_c, side_c FROM "
                          "temperature_samples WHERE run_id = ? AND t_s >= ? AND t_s < ? "
                          "ORDER BY t_s");
  if (!st) return st.error();
  st->bind(1, run_id);
  st->bind(2, t_from_s);
  st->bind(3, t_to_s);
  std::vector<TemperatureSample> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    TemperatureSample t;
    t.t_s = st->column_double(0);
    t.setpoint_c = st->column_double(1);
    t.chamber_c = st->column_double(2);
    t.top_c = st->column_double(3);
    t.side_c = st->column_double(4);
    out.push_back(t);
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db_, path_, fmt::format("reading temperature samples of run {}", run_id));
  }
  return out;
}

namespace {

constexpr const char* kAllanColumns =
    "id, run_id, segment_id, segment_index, t_from_s, t_to_s, taus, tau0_s, n_samples, "
    "curve_json, angle_random_walk_dprh, bias_instability_dph, bias_instability_tau_s, "
    "rate_random_walk_dphprh, bias_instability_method, inputs_json, computed_utc, dut_serial, "
    "axis, coverage_samples, coverage_expected, coverage, longest_gap_s, quality, "
    "quality_reasons_json";

// The curve's arrays, in the order of curve_json.
struct AllanCurveField {
  const char* name;
  std::vector<double> AllanRecord::*values;
};
constexpr AllanCurveField kAllanCurve[] = {{"tau_s", &AllanRecord::tau_s},
                                           {"adev_dph", &AllanRecord::adev_dph},
                                           {"adev_lo_dph", &AllanRecord::adev_lo_dph},
                                           {"adev_hi_dph", &AllanRecord::adev_hi_dph}};

std::string allan_label(const AllanRecord& a) {
  if (a.dut_serial.empty() && a.axis.empty()) {
    return fmt::format("Allan deviation of run {} step {} (taus '{}')", a.run_id, a.segment_index,
                       a.taus);
  }
  return fmt::format("Allan deviation of run {} step {} DUT '{}' axis '{}' (taus '{}')", a.run_id,
                     a.segment_index, a.dut_serial, a.axis, a.taus);
}

// The curve as JSON, or an error naming the field (and index) that cannot be
// stored: JSON has no NaN or infinity, and the arrays must line up.
Result<std::string> allan_curve_json(const AllanRecord& a, const std::string& path) {
  const auto bad = [&](const std::string& why) {
    return Error::Permanent(fmt::format("storage: {}: storing {}: {}", path, allan_label(a), why));
  };
  const std::size_t n = a.tau_s.size();
  nlohmann::ordered_json curve = nlohmann::ordered_json::object();  // keys in documented order
  for (const AllanCurveField& f : kAllanCurve) {
    const std::vector<double>& values = a.*f.values;
    if (values.size() != n) {
      return bad(
          fmt::format("{} has {} values but tau_s has {} (the arrays must have the same "
                      "length)",
                      f.name, values.size(), n));
    }
    for (std::size_t i = 0; i < values.size(); ++i) {
      if (!std::isfinite(values[i])) {
        return bad(
            fmt::format("{}[{}] is {} (only finite numbers can be stored)", f.name, i, values[i]));
      }
    }
    curve[f.name] = values;
  }
  return curve.dump();
}

Status check_allan_scalars(const AllanRecord& a, const std::string& path) {
  const auto bad = [&](const char* field, double v) {
    return Error::Permanent(
        fmt::format("storage: {}: storing {}: {} is {} (only finite numbers "
                    "can be stored; leave a noise term unset instead)",
                    path, allan_label(a), field, v));
  };
  const std::pair<const char*, double> required[] = {
      {"t_from_s", a.t_from_s}, {"t_to_s", a.t_to_s}, {"tau0_s", a.tau0_s}};
  for (const auto& [field, v] : required) {
    if (!std::isfinite(v)) return bad(field, v);
  }
  const std::pair<const char*, const std::optional<double>*> optional[] = {
      {"angle_random_walk_dprh", &a.angle_random_walk_dprh},
      {"bias_instability_dph", &a.bias_instability_dph},
      {"bias_instability_tau_s", &a.bias_instability_tau_s},
      {"rate_random_walk_dphprh", &a.rate_random_walk_dphprh}};
  for (const auto& [field, v] : optional) {
    if (v->has_value() && !std::isfinite(**v)) return bad(field, **v);
  }
  if (a.taus.empty()) {
    return Error::Permanent(
        fmt::format("storage: {}: storing {}: taus is empty", path, allan_label(a)));
  }
  return Status::Ok();
}

Status read_allan_curve(AllanRecord& r, const std::string& text, const std::string& path) {
  const auto bad = [&](const std::string& why) {
    return Error::Permanent(fmt::format("storage: {}: allan row {} (run {} step {}): curve_json {}",
                                        path, r.id, r.run_id, r.segment_index, why));
  };
  const nlohmann::json curve = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (curve.is_discarded()) return bad("is not valid JSON");
  if (!curve.is_object()) return bad("is not a JSON object");
  for (const AllanCurveField& f : kAllanCurve) {
    const auto it = curve.find(f.name);
    if (it == curve.end() || !it->is_array()) {
      return bad(fmt::format("has no array '{}'", f.name));
    }
    std::vector<double>& values = r.*f.values;
    values.reserve(it->size());
    for (const nlohmann::json& v : *it) {
      if (!v.is_number()) {
        return bad(fmt::format("'{}'[{}] is not a number", f.name, values.size()));
      }
      values.push_back(v.get<double>());
    }
    if (values.size() != r.tau_s.size()) {
      return bad(fmt::format("'{}' has {} values but 'tau_s' has {}", f.name, values.size(),
                             r.tau_s.size()));
    }
  }
  return Status::Ok();
}

}  // namespace

Result<int64_t> Database::put_allan(const AllanRecord& a) {
  if (Status s = check_allan_scalars(a, path_); !s) return s.error();
  auto curve = allan_curve_json(a, path_);
  if (!curve) return curve.error();
  const std::string inputs = a.inputs_json.empty() ? "{}" : a.inputs_json;
  if (!nlohmann::json::accept(inputs)) {
    return Error::Permanent(fmt::format("storage: {}: storing {}: inputs_json is not valid JSON",
                                        path_, allan_label(a)));
  }
  auto key = internal::result_key(db_, path_, a.run_id, a.dut_serial, a.axis,
                                  fmt::format("storing {}", allan_label(a)));
  if (!key) return key.error();
  // An upsert keeps the row's id when a recomputation replaces it.
  auto st = Stmt::prepare(
      db_, path_,
      "INSERT INTO allan(run_id, segment_id, segment_index, t_from_s, t_to_s, taus, tau0_s, "
      "n_samples, curve_json, angle_random_walk_dprh, bias_instability_dph, "
      "bias_instability_tau_s, rate_random_walk_dphprh, bias_instability_method, inputs_json, "
      "computed_utc, dut_serial, axis, coverage_samples, coverage_expected, coverage, "
      "longest_gap_s, quality, quality_reasons_json) VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
      "?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
      "ON CONFLICT(run_id, segment_index, taus, dut_serial, axis) DO UPDATE SET segment_id = "
      "excluded.segment_id, "
      "t_from_s = excluded.t_from_s, t_to_s = excluded.t_to_s, tau0_s = excluded.tau0_s, "
      "n_samples = excluded.n_samples, curve_json = excluded.curve_json, "
      "angle_random_walk_dprh = excluded.angle_random_walk_dprh, "
      "bias_instability_dph = excluded.bias_instability_dph, "
      "bias_instability_tau_s = excluded.bias_instability_tau_s, "
      "rate_random_walk_dphprh = excluded.rate_random_walk_dphprh, "
      "bias_instability_method = excluded.bias_instability_method, "
      "inputs_json = excluded.inputs_json, computed_utc = excluded.computed_utc, "
      "coverage_samples = excluded.coverage_samples, coverage_expected = "
      "excluded.coverage_expected, coverage = excluded.coverage, longest_gap_s = "
      "excluded.longest_gap_s, quality = excluded.quality, quality_reasons_json = "
      "excluded.quality_reasons_json "
      "RETURNING id");
  if (!st) return st.error();
  int i = 1;
  st->bind(i++, a.run_id);
  if (a.segment_id == 0) {
    st->bind_null(i++);
  } else {
    st->bind(i++, a.segment_id);
  }
  st->bind(i++, a.segment_index);
  st->bind(i++, a.t_from_s);
  st->bind(i++, a.t_to_s);
  st->bind(i++, std::string_view(a.taus));
  st->bind(i++, a.tau0_s);
  st->bind(i++, a.n_samples);
  st->bind(i++, std::string_view(*curve));
  st->bind(i++, a.angle_random_walk_dprh);
  st->bind(i++, a.bias_instability_dph);
  st->bind(i++, a.bias_instability_tau_s);
  st->bind(i++, a.rate_random_walk_dphprh);
  st->bind(i++, std::string_view(a.bias_instability_method));
  st->bind(i++, std::string_view(inputs));
  st->bind(i++, std::string_view(utc_or_now(a.computed_utc)));
  st->bind(i++, std::string_view(key->serial));
  st->bind(i++, std::string_view(key->axis));
  internal::bind_quality(*st, i, a.quality);
  const std::string what = fmt::format("storing {}", allan_label(a));
  internal::WriteScope tx(db_, path_, "put_allan");
  if (Status s = tx.begin(); !s) return s.error();
  if (st->step() != SQLITE_ROW) return sqlite_error(db_, path_, what);
  const int64_t id = st->column_int64(0);
  if (Status s = expect_done(*st, db_, path_, what); !s) return s.error();
  if (key->primary && !key->axis.empty()) {
    // The row stored before v8 for this DUT (axis '' = its primary axis)
    // is this series: the new row replaces it.
    auto legacy = Stmt::prepare(db_, path_,
                                "DELETE FROM allan WHERE run_id = ? AND segment_index = ? AND "
                                "taus = ? AND dut_serial = ? AND axis = ''");
    if (!legacy) return legacy.error();
    legacy->bind(1, a.run_id);
    legacy->bind(2, a.segment_index);
    legacy->bind(3, std::string_view(a.taus));
    legacy->bind(4, std::string_view(key->serial));
    if (Status s = expect_done(*legacy, db_, path_, what); !s) return s.error();
  }
  if (Status s = tx.commit(); !s) return s.error();
  return id;
}

Result<std::vector<AllanRecord>> Database::allan(int64_t run_id) {
  auto st =
      Stmt::prepare(db_, path_,
                    fmt::format("SELECT {} FROM allan a {} WHERE a.run_id = ? "
                                "ORDER BY a.segment_index, {}, a.dut_serial, a.axis, a.taus",
                                internal::qualified(kAllanColumns, "a"),
                                internal::dut_position_join("a"), internal::kDutPositionOrder));
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<AllanRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    AllanRecord r;
    int c = 0;
    r.id = st->column_int64(c++);
    r.run_id = st->column_int64(c++);
    r.segment_id = st->column_optional_int64(c++).value_or(0);
    r.segment_index = static_cast<int>(st->column_int64(c++));
    r.t_from_s = st->column_double(c++);
    r.t_to_s = st->column_double(c++);
    r.taus = st->column_text(c++);
    r.tau0_s = st->column_double(c++);
    r.n_samples = st->column_int64(c++);
    const std::string curve = st->column_text(c++);
    r.angle_random_walk_dprh = st->column_optional_double(c++);
    r.bias_instability_dph = st->column_optional_double(c++);
    r.bias_instability_tau_s = st->column_optional_double(c++);
    r.rate_random_walk_dphprh = st->column_optional_double(c++);
    r.bias_instability_method = st->column_text(c++);
    r.inputs_json = st->column_text(c++);
    r.computed_utc = st->column_text(c++);
    r.dut_serial = st->column_text(c++);
    r.axis = st->column_text(c++);
    r.quality = internal::read_quality(*st, c);
    if (Status s = read_allan_curve(r, curve, path_); !s) return s.error();
    out.push_back(std::move(r));
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db_, path_, fmt::format("reading Allan deviations of run {}", run_id));
  }
  return out;
}

Status Database::exec(std::string_view sql) { return internal::exec(db_, path_, sql); }

Status Database::verify_quick() {
  auto st = Stmt::prepare(db_, path_, "PRAGMA quick_check");
  if (!st) return st.error();
  // A row may hold several problems, one per line, after a heading naming
  // the schema ("*** in database main ***").
  std::vector<std::string> rows;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    const std::string text = st->column_text(0);
    for (std::size_t from = 0; from <= text.size();) {
      std::size_t to = text.find('\n', from);
      if (to == std::string::npos) to = text.size();
      const std::string line = text.substr(from, to - from);
      if (!line.empty() && !line.starts_with("*** in database")) rows.push_back(line);
      from = to + 1;
    }
  }
  // The check may stop on a page too damaged to go on, after the problems
  // it found so far; other failures (busy, I/O) are no verdict on the file.
  std::string stopped;
  if (rc != SQLITE_DONE) {
    if ((rc & 0xff) != SQLITE_CORRUPT && (rc & 0xff) != SQLITE_NOTADB) {
      return sqlite_error(db_, path_, "PRAGMA quick_check");
    }
    stopped = sqlite3_errmsg(db_);
  }
  if (stopped.empty() && rows == std::vector<std::string>{"ok"}) return Status::Ok();
  std::erase(rows, "ok");
  constexpr std::size_t kShown = 5;
  std::string found;
  for (std::size_t i = 0; i < rows.size() && i < kShown; ++i) {
    found += fmt::format("{}{}", i ? "; " : "", rows[i]);
  }
  std::string what;
  if (!rows.empty()) {
    // quick_check stops at 100 rows.
    what = fmt::format("found {}{} problem(s){}: {}", rows.size(),
                       rows.size() >= 100 ? " or more" : "",
                       rows.size() > kShown ? fmt::format(", the first {}", kShown) : "", found);
  }
  if (!stopped.empty()) {
    what += fmt::format("{}stopped: {}", what.empty() ? "" : "; then it ", stopped);
  }
  return Error::Permanent(fmt::format(
      "storage: {}: the database is damaged: PRAGMA quick_check {}; nothing was written to it. "
      "Restore it from a backup (docs/operations.md \"Restore\")",
      path_, what));
}

std::optional<FileIdentity> Database::file_identity() const {
  if (!guard_) return std::nullopt;
  return guard_->id;
}

Status Database::check_file() const {
  if (!guard_) return Status::Ok();
  const std::string change = internal::file_change(*guard_);
  if (change.empty()) return Status::Ok();
  const FileIdentity& id = guard_->id;
  return Error::Permanent(fmt::format(
      "storage: {}: the database file was {} while open (the open one is device {}:{}, inode {}); "
      "nothing is written to it any more",
      path_, change, major(static_cast<dev_t>(id.dev)), minor(static_cast<dev_t>(id.dev)), id.ino));
}

Status Database::release_wal() {
  // Not the 5 s busy timeout: another connection reading holds it off, and
  // the caller tries again later.
  sqlite3_busy_timeout(db_, 0);
  const int rc =
      sqlite3_wal_checkpoint_v2(db_, "main", SQLITE_CHECKPOINT_TRUNCATE, nullptr, nullptr);
  sqlite3_busy_timeout(db_, kBusyTimeoutMs);
  if (rc != SQLITE_OK) return sqlite_error(db_, path_, "emptying the write-ahead log");
  return Status::Ok();
}

Result<std::vector<std::string>> Database::integrity_check(bool quick) {
  const char* pragma = quick ? "PRAGMA quick_check" : "PRAGMA integrity_check";
  auto st = Stmt::prepare(db_, path_, pragma);
  if (!st) return st.error();
  std::vector<std::string> rows;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) rows.push_back(st->column_text(0));
  if (rc != SQLITE_DONE) return sqlite_error(db_, path_, pragma);
  return rows;
}

}  // namespace gyrotherm::storage
