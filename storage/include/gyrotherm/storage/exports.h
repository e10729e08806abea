// The record of calibration exports in the station database (database.h;
// schema v5, tables `exports` and `export_runs`).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"

struct sqlite3;

namespace gyrotherm::storage {

class Database;

// One calibration export (docs/reports.md; schema v5, tables `exports` and
// `export_runs`): the reports of some runs written into one directory.
// Nightly exports carry the slot they ran for; at most one export per slot
// (a unique index), and a completed run is in at most one nightly export
// that is writing or done, so nothing is exported twice. Manual exports
// (`gyrotherm export`) are recorded too but never take runs from the nightly
// selection.
struct ExportRecord {
  int64_t id = 0;
  std::string kind;                   // nightly, manual
  std::optional<double> slot_unix_s;  // nightly: the scheduled slot (Unix seconds)
  std::string slot_local;          // nightly: the slot as local time, e.g. "2026-03-29 02:00 CET"
  std::string state;               // writing, done, failed
  std::string directory;           // where the files are
  std::vector<int64_t> run_ids;    // ascending
  std::vector<std::string> files;  // relative to directory (set by finish_export)
  std::string started_utc;         // ISO-8601 UTC; "" = now (begin_export)
  std::string finished_utc;        // "" until finished
  std::string message;             // failed: why; done: a summary (may be "")
};

// Part of Database (database.h): call these on a Database. Defined in
// storage/src/exports.cpp.
class ExportStore {
 public:
  // Exports. begin_export inserts the record in state "writing" with its
  // runs (one transaction) and returns its id; errors: a nightly export
  // without slot, a second export of the same nightly slot (names the slot),
  // a run in another nightly export that is writing or done (names it), an
  // unknown run. finish_export sets state "done" or "failed", the files and
  // the message, and stamps finished_utc.
  Result<int64_t> begin_export(const ExportRecord& record);
  Status finish_export(int64_t export_id, std::string_view state,
                       const std::vector<std::string>& files, std::string_view message);
  // Every export, newest (highest id) first, with runs and files.
  Result<std::vector<ExportRecord>> exports();
  Result<std::optional<ExportRecord>> export_record(int64_t export_id);
  // The latest slot of any nightly export (whatever its state); nullopt when
  // there is none.
  Result<std::optional<double>> last_nightly_slot_unix_s();
  // Completed runs (state 'completed') in no nightly export that is writing
  // or done, ascending.
  Result<std::vector<int64_t>> runs_not_exported();

 private:
  friend class Database;
  ExportStore() = default;
  ~ExportStore() = default;
  ExportStore(const ExportStore&) = delete;
  ExportStore& operator=(const ExportStore&) = delete;
  // The Database this store is part of, its connection and its path
  // (exports.cpp).
  Database& self();
  sqlite3* db();
  const std::string& path();
};

}  // namespace gyrotherm::storage
