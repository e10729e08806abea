// Internal helpers over the SQLite C API: an owning statement handle with
// typed binds/columns (NaN <-> NULL), and error values that name the file.
#pragma once

#include <sqlite3.h>

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::storage::internal {

// The file a read-write connection opened, as SQLite resolved its name
// (absolute), with its identity then. Installed as the connection's commit
// hook (install_file_guard): a transaction commits only while the name still
// names that file.
struct FileGuard {
  std::string file;
  FileIdentity id;
};

// The identity of the file `file` names now; nullopt when it cannot be had
// (errno says why).
std::optional<FileIdentity> identity_of(const std::string& file);
// What happened to the file `guard` opened, "" while its name still names
// it: "deleted", or "replaced by another file (device 8:1, inode 5678)". A
// stat that fails otherwise than for a missing file (permissions, I/O) does
// not tell: "".
std::string file_change(const FileGuard& guard);
// Makes `db` roll back every write transaction once file_change(*guard) is
// not "" (the commit fails with SQLITE_CONSTRAINT_COMMITHOOK, which
// sqlite_error describes). `guard` outlives the connection.
void install_file_guard(sqlite3* db, FileGuard* guard);

// "storage: <path>: <what>: <sqlite3_errmsg>". Busy/locked/full/I/O errors are
// transient (another writer, a full or stalled disk); everything else permanent.
// A commit the file guard refused says that the file was deleted or replaced.
Error sqlite_error(sqlite3* db, const std::string& path, std::string_view what);
Error sqlite_error(int rc, const std::string& path, std::string_view what);

// An owning prepared statement. Bind indexes are 1-based, column indexes
// 0-based (as in the C API).
class Stmt {
 public:
  Stmt() = default;
  Stmt(Stmt&& other) noexcept : stmt_(other.stmt_) { other.stmt_ = nullptr; }
  Stmt& operator=(Stmt&& other) noexcept;
  Stmt(const Stmt&) = delete;
  Stmt& operator=(const Stmt&) = delete;
  ~Stmt() { sqlite3_finalize(stmt_); }

  // `persistent` hints SQLite that the statement is reused many times.
  static Result<Stmt> prepare(sqlite3* db, const std::string& path, std::string_view sql,
                              bool persistent = false);

  void bind(int i, double v);  // NaN binds NULL
  void bind(int i, int64_t v) { sqlite3_bind_int64(stmt_, i, v); }
  void bind(int i, int v) { sqlite3_bind_int(stmt_, i, v); }
  void bind(int i, std::string_view v);
  void bind_null(int i) { sqlite3_bind_null(stmt_, i); }
  void bind(int i, const std::optional<double>& v);
  void bind(int i, const std::optional<int64_t>& v);
  // Empty text binds NULL (for columns where "not set" reads better as NULL).
  void bind_text_or_null(int i, std::string_view v);

  // sqlite3_step; SQLITE_ROW / SQLITE_DONE / error code.
  int step() { return sqlite3_step(stmt_); }
  void reset() { sqlite3_reset(stmt_); }

  double column_double(int c) const;  // NULL reads NaN
  std::optional<double> column_optional_double(int c) const;
  int64_t column_int64(int c) const { return sqlite3_column_int64(stmt_, c); }
  std::optional<int64_t> column_optional_int64(int c) const;
  std::string column_text(int c) const;  // NULL reads ""

  sqlite3_stmt* get() { return stmt_; }

 private:
  explicit Stmt(sqlite3_stmt* s) : stmt_(s) {}
  sqlite3_stmt* stmt_ = nullptr;
};

// Runs one or more statements without results.
Status exec(sqlite3* db, const std::string& path, std::string_view sql);

// Rolls back unless commit() succeeded. Inside a transaction already open
// on the connection (Database::atomically) it is a savepoint of it: its
// changes commit, or roll back, with the outer one.
class Transaction {
 public:
  Transaction(sqlite3* db, const std::string& path) : db_(db), path_(path) {}
  ~Transaction() {
    if (!open_) return;
    (void)internal::exec(
        db_, path_, nested_ ? "ROLLBACK TO SAVEPOINT inner; RELEASE SAVEPOINT inner" : "ROLLBACK");
  }
  Status begin_immediate() {
    nested_ = sqlite3_get_autocommit(db_) == 0;
    Status s = internal::exec(db_, path_, nested_ ? "SAVEPOINT inner" : "BEGIN IMMEDIATE");
    open_ = s.ok();
    return s;
  }
  // A read transaction: the reads until commit() see one committed state.
  Status begin_deferred() {
    nested_ = sqlite3_get_autocommit(db_) == 0;
    Status s = internal::exec(db_, path_, nested_ ? "SAVEPOINT inner" : "BEGIN");
    open_ = s.ok();
    return s;
  }
  Status commit() {
    Status s = internal::exec(db_, path_, nested_ ? "RELEASE SAVEPOINT inner" : "COMMIT");
    if (s.ok()) open_ = false;
    return s;
  }

 private:
  sqlite3* db_;
  const std::string& path_;
  bool open_ = false;
  bool nested_ = false;
};

Status expect_done(Stmt& st, sqlite3* db, const std::string& path, std::string_view what);

}  // namespace gyrotherm::storage::internal
