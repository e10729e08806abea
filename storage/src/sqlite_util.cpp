#include "sqlite_util.h"

#include <fmt/format.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>

#include <cerrno>
#include <cmath>
#include <limits>

namespace gyrotherm::storage::internal {
namespace {

int guard_commit(void* arg) { return file_change(*static_cast<FileGuard*>(arg)).empty() ? 0 : 1; }

bool is_transient(int rc) {
  switch (rc & 0xff) {
    case SQLITE_BUSY:
    case SQLITE_LOCKED:
    case SQLITE_FULL:
    case SQLITE_IOERR:
      return true;
    default:
      return false;
  }
}

Error make_error(int rc, std::string message) {
  return is_transient(rc) ? Error::Transient(std::move(message))
                          : Error::Permanent(std::move(message));
}

}  // namespace

std::optional<FileIdentity> identity_of(const std::string& file) {
  struct stat st {};
  if (::stat(file.c_str(), &st) != 0) return std::nullopt;
  return FileIdentity{static_cast<uint64_t>(st.st_dev), static_cast<uint64_t>(st.st_ino)};
}

std::string file_change(const FileGuard& guard) {
  const auto now = identity_of(guard.file);
  if (!now) return errno == ENOENT || errno == ENOTDIR ? "deleted" : "";
  if (*now == guard.id) return "";
  return fmt::format("replaced by another file (device {}:{}, inode {})",
                     major(static_cast<dev_t>(now->dev)), minor(static_cast<dev_t>(now->dev)),
                     now->ino);
}

void install_file_guard(sqlite3* db, FileGuard* guard) {
  sqlite3_commit_hook(db, &guard_commit, guard);
}

Error sqlite_error(sqlite3* db, const std::string& path, std::string_view what) {
  const int rc = db != nullptr ? sqlite3_extended_errcode(db) : SQLITE_ERROR;
  if (rc == SQLITE_CONSTRAINT_COMMITHOOK) {
    // Only the file guard refuses commits.
    const char* file = sqlite3_db_filename(db, "main");
    struct stat st {};
    const bool deleted = file != nullptr && ::stat(file, &st) != 0 && errno == ENOENT;
    return Error::Permanent(fmt::format(
        "storage: {}: {}: not committed: the database file was {} after it was opened; nothing "
        "is written to it any more",
        path, what, deleted ? "deleted" : "replaced by another file"));
  }
  const char* msg = db != nullptr ? sqlite3_errmsg(db) : "no connection";
  return make_error(rc, fmt::format("storage: {}: {}: {}", path, what, msg));
}

Error sqlite_error(int rc, const std::string& path, std::string_view what) {
  return make_error(rc, fmt::format("storage: {}: {}: {}", path, what, sqlite3_errstr(rc)));
}

Stmt& Stmt::operator=(Stmt&& other) noexcept {
  if (this != &other) {
    sqlite3_finalize(stmt_);
    stmt_ = other.stmt_;
    other.stmt_ = nullptr;
  }
  return *this;
}

Result<Stmt> Stmt::prepare(sqlite3* db, const std::string& path, std::string_view sql,
                           bool persistent) {
  sqlite3_stmt* s = nullptr;
  const int rc = sqlite3_prepare_v3(db, sql.data(), static_cast<int>(sql.size()),
                                    persistent ? SQLITE_PREPARE_PERSISTENT : 0, &s, nullptr);
  if (rc != SQLITE_OK) {
    sqlite3_finalize(s);
    return sqlite_error(db, path, fmt::format("preparing \"{}\"", sql));
  }
  return Stmt(s);
}

void Stmt::bind(int i, double v) {
  if (std::isnan(v)) {
    sqlite3_bind_null(stmt_, i);
  } else {
    sqlite3_bind_double(stmt_, i, v);
  }
}

void Stmt::bind(int i, std::string_view v) {
  sqlite3_bind_text(stmt_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT);
}

void Stmt::bind(int i, const std::optional<double>& v) {
  if (v) {
    bind(i, *v);
  } else {
    sqlite3_bind_null(stmt_, i);
  }
}

void Stmt::bind(int i, const std::optional<int64_t>& v) {
  if (v) {
    bind(i, *v);
  } else {
    sqlite3_bind_null(stmt_, i);
  }
}

void Stmt::bind_text_or_null(int i, std::string_view v) {
  if (v.empty()) {
    sqlite3_bind_null(stmt_, i);
  } else {
    bind(i, v);
  }
}

double Stmt::column_double(int c) const {
  if (sqlite3_column_type(stmt_, c) == SQLITE_NULL) return std::numeric_limits<double>::quiet_NaN();
  return sqlite3_column_double(stmt_, c);
}

std::optional<double> Stmt::column_optional_double(int c) const {
  if (sqlite3_column_type(stmt_, c) == SQLITE_NULL) return std::nullopt;
  return sqlite3_column_double(stmt_, c);
}

std::optional<int64_t> Stmt::column_optional_int64(int c) const {
  if (sqlite3_column_type(stmt_, c) == SQLITE_NULL) return std::nullopt;
  return sqlite3_column_int64(stmt_, c);
}

std::string Stmt::column_text(int c) const {
  const auto* p = sqlite3_column_text(stmt_, c);
  if (p == nullptr) return {};
  return std::string(reinterpret_cast<const char*>(p),
                     static_cast<std::size_t>(sqlite3_column_bytes(stmt_, c)));
}

Status exec(sqlite3* db, const std::string& path, std::string_view sql) {
  const std::string text(sql);
  char* err = nullptr;
  const int rc = sqlite3_exec(db, text.c_str(), nullptr, nullptr, &err);
  if (rc != SQLITE_OK) {
    std::string msg = err != nullptr ? err : sqlite3_errstr(rc);
    sqlite3_free(err);
    return make_error(rc, fmt::format("storage: {}: executing \"{}\": {}", path,
                                      text.size() > 80 ? text.substr(0, 77) + "..." : text, msg));
  }
  return Status::Ok();
}

Status expect_done(Stmt& st, sqlite3* db, const std::string& path, std::string_view what) {
  if (st.step() != SQLITE_DONE) return sqlite_error(db, path, what);
  return Status::Ok();
}

}  // namespace gyrotherm::storage::internal
