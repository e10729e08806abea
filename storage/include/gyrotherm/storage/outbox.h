// The lab outbox in the station database (database.h; schema v10,
// docs/storage.md "Lab outbox"): binding the database to a lab station,
// and what the relay reads and acknowledges.
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

// The lab outbox (schema v10, docs/lab.md "Outbox"). Once a station is
// bound to a lab (lab_bind), every insert, update and delete of a relayed
// table (runs, segments, events, segment_stats, allan, fits, fit_runs,
// exports, export_runs, scale_factor_points, scale_factor_fits,
// scale_factor_temperature_fits, duts, run_duts, channels) adds one outbox
// row, written by triggers in the same
// transaction as the change itself: a result committed is a result queued
// for the lab. Raw samples are not relayed.
struct OutboxRecord {
  int64_t seq = 0;   // outbox order (AUTOINCREMENT: never reused)
  std::string kind;  // the relayed table's record kind: run, segment, table1, allan, ...
  std::string
      run_uuid;  // the run's uuid; kNilUuid for station-level rows (duts, events outside runs)
  std::string local_id;         // the row's key in its table as text, e.g. "12" or "12/17-0042/x"
  bool deleted = false;         // a tombstone: the row was deleted (payload {})
  std::string payload_json;     // the row as a JSON object of its columns ({} for tombstones)
  double committed_unix_s = 0;  // wall time (system clock) the change was written, Unix s
};

inline constexpr std::string_view kNilUuid = "00000000-0000-0000-0000-000000000000";

struct OutboxStats {
  int64_t pending = 0;                  // rows not yet acknowledged
  int64_t pending_bytes = 0;            // sum of their payload sizes
  std::optional<double> oldest_unix_s;  // committed_unix_s of the oldest pending row
  int64_t last_acked_seq = 0;           // highest seq acknowledged so far (0: none)
};

// Part of Database (database.h): call these on a Database. Defined in
// storage/src/outbox.cpp.
class OutboxStore {
 public:
  // The lab (schema v10). lab_station_id: the station id the database is
  // bound to (meta 'lab_station_id'), nullopt when never bound. lab_bind
  // binds it (first time: in one transaction, sets the id and queues every
  // existing row of the relayed tables in the outbox, so the lab gets the
  // station's history) or checks it (same id: nothing changes; another id:
  // permanent error naming both: a database belongs to one station).
  Result<std::optional<std::string>> lab_station_id();
  Status lab_bind(std::string_view station_id);
  // Up to `limit` pending outbox rows with seq > after_seq, in seq order,
  // their payloads totalling at most about max_bytes (at least one row).
  Result<std::vector<OutboxRecord>> outbox_batch(int64_t after_seq, int limit,
                                                 int64_t max_bytes = 4 << 20);
  // Acknowledges (deletes) every pending row with seq <= up_to_seq; called
  // only after the lab database committed them.
  Status outbox_ack(int64_t up_to_seq);
  Result<OutboxStats> outbox_stats();

 private:
  friend class Database;
  OutboxStore() = default;
  ~OutboxStore() = default;
  OutboxStore(const OutboxStore&) = delete;
  OutboxStore& operator=(const OutboxStore&) = delete;
  // The Database this store is part of, its connection and its path
  // (outbox.cpp).
  Database& self();
  sqlite3* db();
  const std::string& path();
};

}  // namespace gyrotherm::storage
