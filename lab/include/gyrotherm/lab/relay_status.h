// The relay's state as status and metrics show it (no libpq here).
#pragma once

#include <cstdint>
#include <optional>
#include <string>

namespace gyrotherm::lab {

struct RelayStatus {
  std::string station_id;
  std::string server;  // "host:port/db as user" (never a password)
  // disabled: [lab] relay off (records still queue in the outbox);
  // connecting; connected (the station id checked, caught up or sending);
  // backoff (lost or cannot connect: retrying in retry_in_s); refused (the
  // lab refused the station for good, at connect or for a record, e.g. the
  // station id is not registered or belongs to another role: retried at the
  // longest backoff, an event says why); stopped.
  std::string state = "disabled";
  int64_t pending = 0;                         // outbox rows not yet acknowledged
  int64_t pending_bytes = 0;                   // their payload bytes
  std::optional<double> oldest_pending_age_s;  // wall s since the oldest pending row was committed
  uint64_t sent_total = 0;                     // records acknowledged by the lab
  uint64_t batches_total = 0;                  // batches committed centrally
  uint64_t redelivered_total = 0;  // records the lab already had (replays after a crash or loss)
  uint64_t errors_total = 0;       // failed attempts (connect or batch)
  // Records the lab ignored because it holds a newer version (a higher
  // outbox seq) of them: a re-created or restored station database (an
  // event says so).
  uint64_t stale_total = 0;
  // For the last batch: wall s from the local commit to the central commit
  // of its newest record.
  std::optional<double> last_lag_s;
  std::optional<double> max_lag_s;   // largest since start
  std::string last_error;            // "" when the last attempt succeeded
  std::optional<double> retry_in_s;  // backoff and refused: wall s to the next attempt
  std::string last_sent_utc;         // "" = nothing sent since start
};

}  // namespace gyrotherm::lab
