// Helpers for the storage tests: a fresh temporary directory per test,
// opening a database or a sample writer that must succeed, and one-value SQL
// queries on a raw connection.
#pragma once

#include <gtest/gtest.h>
#include <sqlite3.h>
#include <stdlib.h>

#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace gyrotherm::storage::testing {

class TempDir {
 public:
  TempDir() {
    std::string tmpl =
        (std::filesystem::temp_directory_path() / "gyrotherm-storage-XXXXXX").string();
    if (mkdtemp(tmpl.data()) == nullptr) ADD_FAILURE() << "mkdtemp failed";
    path_ = tmpl;
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;

  std::string file(const std::string& name) const { return (path_ / name).string(); }

 private:
  std::filesystem::path path_;
};

// The test cannot go on without these: a failure is reported and aborts.
inline Database open_ok(const std::string& path) {
  auto db = Database::open(path);
  if (!db) {
    ADD_FAILURE() << db.error().message;
    std::abort();
  }
  return std::move(*db);
}

// The file passes PRAGMA integrity_check: its rows are exactly {"ok"}. A
// failure lists the rows (or why the check could not run).
inline ::testing::AssertionResult integrity_ok(Database& db) {
  auto rows = db.integrity_check();
  if (!rows) {
    return ::testing::AssertionFailure() << "integrity_check did not run: " << rows.error().message;
  }
  if (*rows == std::vector<std::string>{"ok"}) return ::testing::AssertionSuccess();
  auto failure = ::testing::AssertionFailure() << "integrity_check: " << rows->size() << " row(s)";
  for (const auto& row : *rows) failure << "\n  " << row;
  return failure;
}

inline std::unique_ptr<SampleWriter> start_ok(const std::string& path,
                                              SampleWriterOptions options) {
  auto w = SampleWriter::start(path, options);
  if (!w) {
    ADD_FAILURE() << w.error().message;
    std::abort();
  }
  return std::move(*w);
}

// First column of the first row as text ("" for no row or NULL).
inline std::string query_text(sqlite3* db, const std::string& sql) {
  sqlite3_stmt* st = nullptr;
  if (sqlite3_prepare_v2(db, sql.c_str(), -1, &st, nullptr) != SQLITE_OK) {
    ADD_FAILURE() << sql << ": " << sqlite3_errmsg(db);
    return {};
  }
  std::string out;
  if (sqlite3_step(st) == SQLITE_ROW && sqlite3_column_text(st, 0) != nullptr) {
    out = reinterpret_cast<const char*>(sqlite3_column_text(st, 0));
  }
  sqlite3_finalize(st);
  return out;
}

inline long long query_int(sqlite3* db, const std::string& sql) {
  sqlite3_stmt* st = nullptr;
  if (sqlite3_prepare_v2(db, sql.c_str(), -1, &st, nullptr) != SQLITE_OK) {
    ADD_FAILURE() << sql << ": " << sqlite3_errmsg(db);
    return -1;
  }
  long long out = -1;
  if (sqlite3_step(st) == SQLITE_ROW) out = sqlite3_column_int64(st, 0);
  sqlite3_finalize(st);
  return out;
}

}  // namespace gyrotherm::storage::testing
