// The persistent run queue and the station-wide settings (the meta
// table) in the station database (database.h).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/runs.h"

struct sqlite3;

namespace gyrotherm::storage {

class Database;

// One entry of the persistent run queue, with its schedule.
struct QueueEntry {
  int64_t id = 0;
  RunMetadata metadata;  // schema v8: given to the run it starts
  int64_t schedule_id = 0;
  int position = 0;   // among queued entries, 0 = next; -1 once taken
  std::string state;  // queued, running, completed, failed, interrupted, removed
  std::string added_utc;
  bool ignore_failures = false;
  std::optional<int64_t> run_id;
  std::string schedule_name;
  std::string source_path;
  std::string toml_text;
};

// Part of Database (database.h): call these on a Database. Defined in
// storage/src/queue.cpp.
class QueueStore {
 public:
  // The queue. Positions of queued entries are kept 0..n-1 in run order.
  // add: stores the schedule text and appends the entry.
  Result<QueueEntry> queue_add(const std::string& schedule_name, const std::string& source_path,
                               const std::string& toml_text, bool ignore_failures,
                               const RunMetadata& metadata = {});
  // The running entry (if any) first, then queued entries by position.
  Result<std::vector<QueueEntry>> queue_entries();
  Result<std::optional<QueueEntry>> queue_entry(int64_t id);
  // Queued -> removed. False (nothing changed) when the entry is not queued.
  Result<bool> queue_remove(int64_t id);
  // Moves a queued entry to `position` (clamped). False when not queued.
  Result<bool> queue_move(int64_t id, int position);
  // Queued -> running with its run. False when the entry is no longer queued.
  Result<bool> queue_claim(int64_t id, int64_t run_id);
  // Starts the run of a queued entry in one transaction: the entry goes
  // queued -> running and a run row is created from `run` (its queue_id and
  // schedule_id are the entry's). nullopt, and no run row, when the entry is
  // no longer queued (removed or moved on by another connection meanwhile).
  Result<std::optional<int64_t>> queue_start_run(int64_t id, const RunRecord& run);
  // running -> a final state (completed, failed, interrupted).
  Status queue_finish(int64_t id, std::string_view state);
  // Running -> queued again at the head (a run that could not start).
  Status queue_requeue(int64_t id);

  // Station-wide settings (the meta table): queue hold, etc.
  Result<std::optional<std::string>> meta(std::string_view key);
  Status set_meta(std::string_view key, std::string_view value);
  Status delete_meta(std::string_view key);

 private:
  friend class Database;
  QueueStore() = default;
  ~QueueStore() = default;
  QueueStore(const QueueStore&) = delete;
  QueueStore& operator=(const QueueStore&) = delete;
  // The Database this store is part of, its connection and its path
  // (queue.cpp).
  Database& self();
  sqlite3* db();
  const std::string& path();
};

}  // namespace gyrotherm::storage
