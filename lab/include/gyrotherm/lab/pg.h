// A PostgreSQL connection (libpq), owned, with the few calls the lab needs.
//
// Errors come back as values: a lost server or a refused connection is
// transient (the relay retries), a statement the server refuses for what it
// is (a policy, a constraint, bad SQL) is permanent; the server's SQLSTATE
// is kept so callers can tell a row-level-security refusal (42501) from a
// foreign key (23503) through last_sqlstate(). Connection strings may hold a password: they are
// never put in messages (only host, port, database and user are).
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"

struct pg_conn;

namespace gyrotherm::lab {

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
  pg_conn* conn_ = nullptr;
  std::string last_sqlstate_;
};

// `conninfo` with any password removed (for messages and status).
std::string redact_conninfo(std::string_view conninfo);

}  // namespace gyrotherm::lab
