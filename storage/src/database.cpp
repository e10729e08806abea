#include "gyrotherm/storage/database.h"

#include <fmt/format.h>
#include <sqlite3.h>
#include <sys/sysmacros.h>
#include <sys/types.h>

#include <charconv>
#include <chrono>
#include <thread>
#include <type_traits>
#include <utility>

#include "gyrotherm/core/clock.h"
#include "migrations.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;
using internal::Transaction;

// The stores are parts of Database: no data of their own (what a Database
// owns moves with it), never made, copied or moved apart from one.
template <class Store>
constexpr bool kIsPart =
    std::is_empty_v<Store> && !std::is_default_constructible_v<Store> &&
    !std::is_copy_constructible_v<Store> && !std::is_move_constructible_v<Store>;
static_assert(kIsPart<RunStore> && kIsPart<DutStore> && kIsPart<QueueStore> &&
              kIsPart<EventStore> && kIsPart<ResultStore> && kIsPart<SampleStore> &&
              kIsPart<ExportStore> && kIsPart<OutboxStore>);
static_assert(std::is_nothrow_move_constructible_v<Database> &&
              std::is_nothrow_move_assignable_v<Database> &&
              !std::is_copy_constructible_v<Database>);

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

Status Database::atomically(const std::function<Status()>& body) {
  Transaction tx(db_, path_);
  if (Status s = tx.begin_immediate(); !s) return s;
  if (Status s = body(); !s) return s;  // rolled back
  return tx.commit();
}

Status Database::read_consistently(const std::function<Status()>& body) {
  Transaction tx(db_, path_);
  if (Status s = tx.begin_deferred(); !s) return s;
  if (Status s = body(); !s) return s;  // ended by the rollback
  return tx.commit();
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
