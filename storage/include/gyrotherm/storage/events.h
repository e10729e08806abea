// Events in the station database (database.h): state changes, interlocks,
// device messages, metadata edits; what a technician reads.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/core/result.h"

struct sqlite3;

namespace gyrotherm::storage {

class Database;

struct EventRecord {
  int64_t id = 0;
  std::optional<int64_t> run_id;
  double t_s = 0;        // station seconds since run start (0 without run)
  std::string wall_utc;  // ISO-8601 UTC; "" = now (add_event)
  std::string kind;      // state, interlock, device, info, error
  std::string from_state;
  std::string to_state;
  std::string message;  // what a technician reads
};

// Part of Database (database.h): call these on a Database. Defined in
// storage/src/events.cpp.
class EventStore {
 public:
  // Events.
  Result<int64_t> add_event(const EventRecord& event);
  Result<std::vector<EventRecord>> events(int64_t run_id);

 private:
  friend class Database;
  EventStore() = default;
  ~EventStore() = default;
  EventStore(const EventStore&) = delete;
  EventStore& operator=(const EventStore&) = delete;
  // The Database this store is part of, its connection and its path
  // (events.cpp).
  Database& self();
  sqlite3* db();
  const std::string& path();
};

}  // namespace gyrotherm::storage
