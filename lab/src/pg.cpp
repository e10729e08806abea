#include "gyrotherm/lab/pg.h"

#include <fmt/format.h>
#include <libpq-fe.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <regex>
#include <utility>

namespace gyrotherm::lab {
namespace {

struct ResultDeleter {
  void operator()(PGresult* r) const { PQclear(r); }
};
using ResultPtr = std::unique_ptr<PGresult, ResultDeleter>;

struct OptionsDeleter {
  void operator()(PQconninfoOption* o) const { PQconninfoFree(o); }
};
using OptionsPtr = std::unique_ptr<PQconninfoOption, OptionsDeleter>;

// Keywords whose values are secrets: never shown.
bool is_secret(std::string_view keyword) {
  return keyword == "password" || keyword == "sslpassword";
}

// A value as conninfo writes it: quoted when empty or holding spaces,
// quotes or backslashes.
std::string quote_value(std::string_view value) {
  const bool plain = !value.empty() && value.find_first_of(" \t\n'\\") == std::string_view::npos;
  if (plain) return std::string(value);
  std::string out = "'";
  for (char c : value) {
    if (c == '\'' || c == '\\') out += '\\';
    out += c;
  }
  out += '\'';
  return out;
}

// libpq's parse errors quote pieces of the connection string (a whole URI,
// an option's value); when the string could not be parsed we cannot know
// where its password is, so every quoted piece goes.
std::string without_quoted(std::string_view message) {
  static const std::regex quoted("\"[^\"]*\"");
  return std::regex_replace(std::string(message), quoted, "\"...\"");
}

// libpq's messages span lines ("FATAL: ...\nserver closed the connection
// unexpectedly\n\tThis probably means..."): one line for logs and events,
// runs of white space as one space.
std::string trim(std::string_view s) {
  std::string out;
  for (char c : s) {
    const bool space = c == '\n' || c == '\r' || c == '\t' || c == ' ';
    if (space) {
      if (!out.empty() && out.back() != ' ') out += ' ';
    } else {
      out += c;
    }
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

// Replaces every occurrence of each secret in `message` (a server or libpq
// message that might echo part of the connection string).
std::string scrub(std::string message, const std::vector<std::string>& secrets) {
  for (const auto& secret : secrets) {
    if (secret.empty()) continue;
    for (auto pos = message.find(secret); pos != std::string::npos;
         pos = message.find(secret, pos)) {
      message.replace(pos, secret.size(), "***");
      pos += 3;
    }
  }
  return message;
}

// "host:port/dbname as user" from parsed options (the defaults libpq would
// use where absent are left out: the message then says what was given).
std::string describe(const PQconninfoOption* options) {
  std::string host, port, dbname, user;
  for (const auto* o = options; o && o->keyword; ++o) {
    if (!o->val) continue;
    const std::string_view k = o->keyword;
    if (k == "host" || (k == "hostaddr" && host.empty())) host = o->val;
    if (k == "port") port = o->val;
    if (k == "dbname") dbname = o->val;
    if (k == "user") user = o->val;
  }
  std::string out = host.empty() ? "(default host)" : host;
  if (!port.empty()) out += ":" + port;
  if (!dbname.empty()) out += "/" + dbname;
  if (!user.empty()) out += " as " + user;
  return out;
}

// SQLSTATEs that say "the server or the way to it is gone for now", not
// "the server refuses this": connection exceptions (class 08), shutdowns
// and start-ups (57P01 admin shutdown, 57P02 crash shutdown, 57P03 cannot
// connect now, 57P05 idle session timeout), resources (class 53: disk
// full, out of memory, too many connections), and conflicts a retry
// resolves (40001 serialization failure, 40P01 deadlock, 55P03 lock not
// available, 57014 statement cancelled).
bool transient_sqlstate(std::string_view s) {
  if (s.size() != 5) return false;
  if (s.substr(0, 2) == "08" || s.substr(0, 2) == "53") return true;
  return s == "57P01" || s == "57P02" || s == "57P03" || s == "57P05" || s == "40001" ||
         s == "40P01" || s == "55P03" || s == "57014";
}

}  // namespace

std::string redact_conninfo(std::string_view conninfo) {
  char* err = nullptr;
  OptionsPtr options(PQconninfoParse(std::string(conninfo).c_str(), &err));
  if (!options) {
    if (err) PQfreemem(err);
    return "(malformed connection string)";
  }
  std::string out;
  for (const auto* o = options.get(); o->keyword; ++o) {
    if (!o->val || is_secret(o->keyword)) continue;
    if (!out.empty()) out += ' ';
    out += fmt::format("{}={}", o->keyword, quote_value(o->val));
  }
  return out;
}

Result<PgConnection> PgConnection::connect(const std::string& conninfo, double connect_timeout_s) {
  char* parse_error = nullptr;
  OptionsPtr options(PQconninfoParse(conninfo.c_str(), &parse_error));
  if (!options) {
    std::string why = parse_error ? trim(parse_error) : "out of memory";
    if (parse_error) PQfreemem(parse_error);
    return Error::Permanent(
        fmt::format("the lab database's connection string is malformed: {}", without_quoted(why)));
  }
  std::vector<std::string> secrets;
  for (const auto* o = options.get(); o->keyword; ++o) {
    if (o->val && is_secret(o->keyword)) secrets.emplace_back(o->val);
  }
  const std::string where = describe(options.get());

  // Order matters (libpq keeps the last value of a repeated keyword): the
  // keepalive defaults first, so the connection string may override them;
  // then the connection string (expanded from dbname); then the timeout,
  // which the caller's setting always bounds. Keepalives and the TCP user
  // timeout notice a server that vanished without closing (a cable pulled,
  // a VM frozen) in about a minute instead of the kernel's hours, so a
  // relay blocked in a statement gets its error and backs off.
  const int timeout_s = std::isfinite(connect_timeout_s)
                            ? std::max(1, static_cast<int>(std::ceil(connect_timeout_s)))
                            : 10;
  const std::string timeout = std::to_string(timeout_s);
  const char* keywords[] = {"keepalives",       "keepalives_idle",  "keepalives_interval",
                            "keepalives_count", "tcp_user_timeout", "fallback_application_name",
                            "dbname",           "connect_timeout",  nullptr};
  const char* values[] = {
      "1", "30", "10", "3", "60000", "gyrotherm", conninfo.c_str(), timeout.c_str(), nullptr};
  pg_conn* conn = PQconnectdbParams(keywords, values, /*expand_dbname=*/1);
  if (!conn)
    return Error::Transient(
        fmt::format("cannot connect to the lab database {}: out of memory", where));
  if (PQstatus(conn) != CONNECTION_OK) {
    std::string why = scrub(trim(PQerrorMessage(conn)), secrets);
    PQfinish(conn);
    return Error::Transient(fmt::format("cannot connect to the lab database {}: {}", where, why));
  }
  // The server's notices (a role already a member, a schema that exists)
  // would go to stderr, the daemon's journal: they say nothing to act on.
  PQsetNoticeProcessor(
      conn, [](void*, const char*) {}, nullptr);
  return PgConnection(conn);
}

PgConnection::PgConnection(PgConnection&& other) noexcept
    : conn_(std::exchange(other.conn_, nullptr)), last_sqlstate_(std::move(other.last_sqlstate_)) {}

PgConnection& PgConnection::operator=(PgConnection&& other) noexcept {
  if (this != &other) {
    if (conn_) PQfinish(conn_);
    conn_ = std::exchange(other.conn_, nullptr);
    last_sqlstate_ = std::move(other.last_sqlstate_);
  }
  return *this;
}

PgConnection::~PgConnection() {
  if (conn_) PQfinish(conn_);
}

bool PgConnection::ok() const { return conn_ && PQstatus(conn_) == CONNECTION_OK; }

std::string PgConnection::server() const {
  if (!conn_) return "(not connected)";
  const char* host = PQhost(conn_);
  const char* port = PQport(conn_);
  const char* db = PQdb(conn_);
  const char* user = PQuser(conn_);
  return fmt::format("{}:{}/{} as {}", host ? host : "", port ? port : "", db ? db : "",
                     user ? user : "");
}

namespace {

// The rows of a successful result, as text.
PgRows rows_of(const PGresult* res) {
  PgRows out;
  const int ncols = PQnfields(res);
  const int nrows = PQntuples(res);
  out.columns.reserve(static_cast<size_t>(ncols));
  for (int c = 0; c < ncols; ++c) out.columns.emplace_back(PQfname(res, c));
  out.rows.reserve(static_cast<size_t>(nrows));
  for (int r = 0; r < nrows; ++r) {
    auto& row = out.rows.emplace_back();
    row.reserve(static_cast<size_t>(ncols));
    for (int c = 0; c < ncols; ++c) {
      if (PQgetisnull(res, r, c)) {
        row.emplace_back(std::nullopt);
      } else {
        row.emplace_back(
            std::string(PQgetvalue(res, r, c), static_cast<size_t>(PQgetlength(res, r, c))));
      }
    }
  }
  return out;
}

// One place turns a libpq outcome into rows or an error, so exec and
// exec_params classify failures the same way.
Result<PgRows> finish(pg_conn* conn, PGresult* raw, std::string& sqlstate,
                      const std::string& where) {
  ResultPtr res(raw);
  const auto status = res ? PQresultStatus(res.get()) : PGRES_FATAL_ERROR;
  if (res &&
      (status == PGRES_COMMAND_OK || status == PGRES_TUPLES_OK || status == PGRES_EMPTY_QUERY)) {
    sqlstate.clear();
    return rows_of(res.get());
  }
  const char* state = res ? PQresultErrorField(res.get(), PG_DIAG_SQLSTATE) : nullptr;
  sqlstate = state ? state : "";
  std::string message;
  if (res && PQresultErrorField(res.get(), PG_DIAG_MESSAGE_PRIMARY)) {
    message = PQresultErrorField(res.get(), PG_DIAG_MESSAGE_PRIMARY);
    if (const char* detail = PQresultErrorField(res.get(), PG_DIAG_MESSAGE_DETAIL)) {
      message += fmt::format(" ({})", detail);
    }
    if (const char* hint = PQresultErrorField(res.get(), PG_DIAG_MESSAGE_HINT)) {
      message += fmt::format(" [hint: {}]", hint);
    }
  } else {
    message = trim(PQerrorMessage(conn));
    if (message.empty()) message = res ? PQresStatus(status) : "no result (out of memory?)";
  }
  const bool lost = PQstatus(conn) != CONNECTION_OK;
  const bool transient = lost || transient_sqlstate(sqlstate);
  std::string text = fmt::format("lab database {}: {}{}", where, trim(message),
                                 sqlstate.empty() ? "" : fmt::format(" (SQLSTATE {})", sqlstate));
  if (lost) text += " (connection lost)";
  return transient ? Error::Transient(std::move(text)) : Error::Permanent(std::move(text));
}

}  // namespace

Result<PgRows> PgConnection::exec(std::string_view sql) {
  if (!conn_) {
    last_sqlstate_.clear();
    return Error::Transient("lab database: not connected");
  }
  return finish(conn_, PQexec(conn_, std::string(sql).c_str()), last_sqlstate_, server());
}

Result<PgRows> PgConnection::exec_params(std::string_view sql,
                                         const std::vector<std::optional<std::string>>& params) {
  if (!conn_) {
    last_sqlstate_.clear();
    return Error::Transient("lab database: not connected");
  }
  std::vector<const char*> values;
  values.reserve(params.size());
  for (const auto& p : params) values.push_back(p ? p->c_str() : nullptr);
  PGresult* res = PQexecParams(conn_, std::string(sql).c_str(), static_cast<int>(values.size()),
                               /*paramTypes=*/nullptr, values.data(), /*paramLengths=*/nullptr,
                               /*paramFormats=*/nullptr, /*resultFormat=*/0);
  return finish(conn_, res, last_sqlstate_, server());
}

}  // namespace gyrotherm::lab
