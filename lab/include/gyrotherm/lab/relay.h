// The relay (docs/lab.md "Relay"): gyrothermd's thread that moves the
// station's outbox to the lab database.
//
// It reads pending outbox rows in seq order on its own SQLite connection,
// writes them to PostgreSQL in one transaction per batch (push_batch:
// idempotent upserts), and only then acknowledges them locally: a crash
// between the two replays the batch, which the lab recognises
// (redelivered), so delivery is at least once and the lab holds each
// record exactly once. Connection loss or a down server: exponential
// backoff (retry_min_s doubling to retry_max_s, wall time), then resume
// where the outbox stands. Memory is bounded by one batch (batch_records,
// batch_bytes). A refusal stops sending (state "refused") and is retried
// at retry_max_s in case the lab's registration is fixed; the registration
// is checked at each connection, before anything is sent. Every
// PostgreSQL call is bounded (statement_timeout_s, lock_timeout_s) and
// stop() cancels the one in progress.
#pragma once

#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/lab/relay_status.h"

namespace gyrotherm::lab {

class PgInterrupt;

struct RelayOptions {
  std::string station_id;
  std::string db_path;   // the station's SQLite file (bound to station_id before start)
  std::string conninfo;  // libpq conninfo/URI, may hold a password (never logged)
                         // "" = disabled ([lab] relay = false): the thread never connects, it
                         // only reads the outbox's figures every poll_s (state "disabled")
  int batch_records = 500;
  int64_t batch_bytes = 4 << 20;
  double poll_s = 1.0;         // wall s between outbox polls when idle (nudge() wakes it early)
  double retry_min_s = 1.0;    // backoff after a failure, doubling...
  double retry_max_s = 300.0;  // ...up to this
  double connect_timeout_s = 10.0;
  // The session's statement_timeout and lock_timeout (wall s, > 0): a batch
  // that waits longer (a lock held by an administrator's session, a server
  // that stalls) is cancelled by the server and retried after a backoff.
  double statement_timeout_s = 60.0;
  double lock_timeout_s = 10.0;
  // State changes worth an event (connected, lost, refused, resumed):
  // (kind "lab", message). Called from the relay thread.
  std::function<void(const std::string& message)> on_event;

  // False with a message naming the field when a value is out of range: a
  // station_id that is no lab station id, no db_path, batch_records or
  // batch_bytes below 1, a poll, backoff or timeout not positive (or not
  // finite), retry_max_s below retry_min_s, a conninfo libpq cannot parse
  // (the message names the bad keyword, never a value).
  bool is_valid(std::string* why) const;
};

class Relay {
 public:
  // Checks the options (RelayOptions::is_valid; not the server: an
  // unreachable lab is a backoff, not a start-up failure). The database must
  // be bound (lab_bind) to options.station_id.
  static Result<std::unique_ptr<Relay>> create(RelayOptions options);
  ~Relay();  // stop()
  void start();
  // Stops now. A call waiting for the lab database is cancelled (PQcancel,
  // sent from a thread of its own so that a silent host cannot hold stop()
  // up) and given up kCancelGrace_s later at most: the batch in flight is
  // committed or rolled back centrally, acknowledged locally only when
  // committed, and an event says which. Returns within kCancelGrace_s plus
  // a little, or within connect_timeout_s during a connection attempt.
  void stop();
  // Wakes the thread now (a result was committed).
  void nudge();
  RelayStatus status() const;

 private:
  class Loop;  // run()'s state and its steps (relay.cpp)

  explicit Relay(RelayOptions options);
  void run();

  RelayOptions options_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  bool stop_requested_ = false;
  bool nudged_ = false;
  RelayStatus status_;
  std::thread thread_;
  std::shared_ptr<PgInterrupt> interrupt_;  // stop() wakes the call in progress
};

}  // namespace gyrotherm::lab
