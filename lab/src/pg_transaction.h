// Internal helpers over PgConnection: an explicit transaction that rolls
// back unless committed, and identifier quoting.
#pragma once

#include <libpq-fe.h>

#include <string>
#include <string_view>

#include "gyrotherm/lab/pg.h"

namespace gyrotherm::lab::internal {

// BEGIN on construction (begin() tells whether it worked), ROLLBACK in the
// destructor unless commit() succeeded. A rollback on a lost connection
// fails quietly: the server rolled back already.
class PgTransaction {
 public:
  explicit PgTransaction(PgConnection& pg) : pg_(pg) {}
  PgTransaction(const PgTransaction&) = delete;
  PgTransaction& operator=(const PgTransaction&) = delete;
  ~PgTransaction() {
    if (open_) rollback();
  }

  Status begin() {
    auto r = pg_.exec("BEGIN");
    if (!r.ok()) return r.error();
    open_ = true;
    return {};
  }
  Status commit() {
    auto r = pg_.exec("COMMIT");
    open_ = false;
    if (!r.ok()) return r.error();
    return {};
  }
  // Without touching the connection's last SQLSTATE (callers report the
  // statement that failed, not the rollback).
  void rollback() {
    open_ = false;
    if (pg_.handle() && PQstatus(pg_.handle()) == CONNECTION_OK) {
      PQclear(PQexec(pg_.handle(), "ROLLBACK"));
    }
  }

 private:
  PgConnection& pg_;
  bool open_ = false;
};

// `name` as a quoted SQL identifier ("" when the connection cannot quote).
inline std::string quote_ident(PgConnection& pg, std::string_view name) {
  if (!pg.handle()) return "";
  char* q = PQescapeIdentifier(pg.handle(), name.data(), name.size());
  if (!q) return "";
  std::string out(q);
  PQfreemem(q);
  return out;
}

}  // namespace gyrotherm::lab::internal
