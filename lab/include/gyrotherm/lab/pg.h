// A PostgreSQL connection (libpq), owned, with the few calls the lab needs.
//
// Errors come back as values: a lost server or a refused connection is
// transient (the relay retries), a statement the server refuses for what it
// is (a policy, a constraint, bad SQL) is permanent; the server's SQLSTATE
// is kept so callers can tell a row-level-security refusal (42501) from a
// foreign key (23503) through last_sqlstate(). Connection strings may hold a password: they are
// never put in messages (only host, port, database and user are).
//
// Every call is bounded (docs/lab.md "Time limits"): limit() sets the
// session's statement_timeout and lock_timeout, and the client waits for an
// answer at most that long plus kAnswerGrace_s (a server that stopped
// answering gives the connection up). A PgInterrupt, attached from another
// thread's point of view, wakes a call in progress at once (stop()).
#pragma once

#include <atomic>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"

struct pg_conn;
struct pg_cancel;

namespace gyrotherm::lab {

// Past statement_timeout, the client waits this long more for the server's
// answer before it gives the connection up.
inline constexpr double kAnswerGrace_s = 5.0;
// After an interrupt, the call in progress waits this long for the server's
// answer to the cancel request (the statement rolled back), then gives the
// connection up (the server rolls back what it did not commit).
inline constexpr double kCancelGrace_s = 2.0;

// Interrupts the calls of the connection it is attached to, from another
// thread (the relay's stop()). Thread-safe. One per relay, for every
// connection it opens in turn.
class PgInterrupt {
 public:
  PgInterrupt();
  ~PgInterrupt();
  PgInterrupt(const PgInterrupt&) = delete;
  PgInterrupt& operator=(const PgInterrupt&) = delete;

  // From now on: the call in progress wakes at once and waits at most
  // kCancelGrace_s for the server's answer (to cancel_running()), later
  // calls fail at once. For good (stop).
  void trigger();
  bool triggered() const { return triggered_.load(); }
  // A call is waiting for the server.
  bool busy() const { return busy_.load(); }
  // Asks the server to cancel the statement of the call in progress
  // (PQcancel). It opens a connection of its own without a time limit of
  // its own (to a host gone silent: minutes), so callers that must not
  // block run it on a thread of its own. "" when the server took the
  // request or nothing was running, else why not.
  std::string cancel_running();

 private:
  friend class PgConnection;
  void attach(pg_conn* conn);
  void detach(pg_conn* conn);

  int fd_ = -1;  // an eventfd, readable once triggered
  std::atomic<bool> triggered_{false};
  std::atomic<bool> busy_{false};
  std::mutex mu_;
  pg_conn* attached_ = nullptr;        // only compared, never used
  std::shared_ptr<pg_cancel> cancel_;  // the attached connection's
};

// Rows of a result, as text (NULL = nullopt), by column index.
struct PgRows {
  std::vector<std::string> columns;
  std::vector<std::vector<std::optional<std::string>>> rows;
};

class PgConnection {
 public:
  // Connects (libpq conninfo or URI). connect_timeout_s bounds the attempt.
  static Result<PgConnection> connect(const std::string& conninfo, double connect_timeout_s = 10);
  PgConnection(PgConnection&&) noexcept;
  PgConnection& operator=(PgConnection&&) noexcept;
  PgConnection(const PgConnection&) = delete;
  PgConnection& operator=(const PgConnection&) = delete;
  ~PgConnection();

  // Bounds every later call: the session's statement_timeout and
  // lock_timeout (0 = none), and the client's wait for an answer
  // (statement_timeout_s + answer_grace_s; none when statement_timeout_s
  // is 0). The server's errors: 57014 (statement timeout), 55P03 (lock
  // timeout), transient; no answer in time: transient, connection closed.
  Status limit(double statement_timeout_s, double lock_timeout_s,
               double answer_grace_s = kAnswerGrace_s);
  // Calls from now on can be interrupted by `interrupt` (nullptr: not).
  void set_interrupt(std::shared_ptr<PgInterrupt> interrupt);

  // Runs `sql` (one or more statements, no parameters); rows of the last.
  Result<PgRows> exec(std::string_view sql);
  // One statement with text parameters ($1, $2, ...; nullopt = NULL).
  Result<PgRows> exec_params(std::string_view sql,
                             const std::vector<std::optional<std::string>>& params);
  // The SQLSTATE of the last failed call ("" when it was not the server's).
  const std::string& last_sqlstate() const { return last_sqlstate_; }
  bool ok() const;             // the connection is usable
  std::string server() const;  // "host:port/dbname as user", no password
  pg_conn* handle() { return conn_; }

 private:
  explicit PgConnection(pg_conn* conn) : conn_(conn) {}
  // Sends with `send` and waits (bounded, interruptible) for the result.
  template <class Send>
  Result<PgRows> call(Send&& send);
  // Gives the connection up (closed; ok() is false from now on).
  void abandon();

  pg_conn* conn_ = nullptr;
  std::string last_sqlstate_;
  std::string where_;            // server(), kept for messages after abandon()
  double answer_timeout_s_ = 0;  // 0 = none
  double answer_grace_s_ = kAnswerGrace_s;
  std::shared_ptr<PgInterrupt> interrupt_;
};

// Why libpq cannot parse `conninfo` (an unknown option is named, values
// never are), or nullopt when it can.
std::optional<std::string> conninfo_error(std::string_view conninfo);

// `conninfo` with any password removed (for messages and status).
std::string redact_conninfo(std::string_view conninfo);

}  // namespace gyrotherm::lab
