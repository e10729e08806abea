#include "gyrotherm/lab/pg.h"

#include <fmt/format.h>
#include <libpq-fe.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <climits>
#include <cmath>
#include <memory>
#include <optional>
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
// where its password is, so every quoted piece goes, except the name of an
// unknown option (a keyword, never a value: "invalid connection option
// "sslmod"" is what the technician must see).
std::string without_quoted(std::string_view message) {
  static const std::regex quoted("\"[^\"]*\"");
  static const std::regex keyword("[A-Za-z_][A-Za-z0-9_]{0,63}");
  const std::string text(message);
  std::string out;
  size_t done = 0;
  for (auto it = std::sregex_iterator(text.begin(), text.end(), quoted);
       it != std::sregex_iterator(); ++it) {
    const auto at = static_cast<size_t>(it->position());
    const std::string_view before = std::string_view(text).substr(0, at);
    const std::string inner = it->str().substr(1, it->str().size() - 2);
    const bool option_name = (before.ends_with("invalid connection option ") ||
                              before.ends_with("invalid URI query parameter: ")) &&
                             std::regex_match(inner, keyword);
    out += text.substr(done, at - done);
    out += option_name ? it->str() : "\"...\"";
    done = at + static_cast<size_t>(it->length());
  }
  out += text.substr(done);
  return out;
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

PgInterrupt::PgInterrupt() : fd_(::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK)) {}

PgInterrupt::~PgInterrupt() {
  if (fd_ >= 0) ::close(fd_);
}

void PgInterrupt::trigger() {
  triggered_ = true;
  if (fd_ >= 0) {
    const uint64_t one = 1;
    [[maybe_unused]] const auto n = ::write(fd_, &one, sizeof one);
  }
}

std::string PgInterrupt::cancel_running() {
  if (!busy_) return "";
  std::shared_ptr<pg_cancel> cancel;
  {
    std::lock_guard lock(mu_);
    cancel = cancel_;
  }
  if (!cancel) return "no connection to cancel";
  char why[256] = "";
  if (PQcancel(cancel.get(), why, sizeof why) == 1) return "";
  return trim(why);
}

void PgInterrupt::attach(pg_conn* conn) {
  std::shared_ptr<pg_cancel> cancel(PQgetCancel(conn), [](pg_cancel* c) { PQfreeCancel(c); });
  std::lock_guard lock(mu_);
  attached_ = conn;
  cancel_ = std::move(cancel);
}

void PgInterrupt::detach(pg_conn* conn) {
  std::lock_guard lock(mu_);
  if (attached_ != conn) return;
  attached_ = nullptr;
  cancel_.reset();
}

std::optional<std::string> conninfo_error(std::string_view conninfo) {
  char* parse_error = nullptr;
  OptionsPtr options(PQconninfoParse(std::string(conninfo).c_str(), &parse_error));
  if (options) return std::nullopt;
  std::string why = parse_error ? trim(parse_error) : "out of memory";
  if (parse_error) PQfreemem(parse_error);
  return fmt::format("the lab database's connection string is malformed: {}", without_quoted(why));
}

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
  if (auto malformed = conninfo_error(conninfo)) return Error::Permanent(*malformed);
  char* parse_error = nullptr;
  OptionsPtr options(PQconninfoParse(conninfo.c_str(), &parse_error));
  if (parse_error) PQfreemem(parse_error);
  if (!options) return Error::Permanent("the lab database's connection string is malformed");
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
  // Calls send and wait themselves (call()): sending never blocks either.
  PQsetnonblocking(conn, 1);
  PgConnection out(conn);
  out.where_ = out.server();
  return out;
}

PgConnection::PgConnection(PgConnection&& other) noexcept
    : conn_(std::exchange(other.conn_, nullptr)),
      last_sqlstate_(std::move(other.last_sqlstate_)),
      where_(std::move(other.where_)),
      answer_timeout_s_(other.answer_timeout_s_),
      answer_grace_s_(other.answer_grace_s_),
      interrupt_(std::move(other.interrupt_)) {}

PgConnection& PgConnection::operator=(PgConnection&& other) noexcept {
  if (this != &other) {
    abandon();
    conn_ = std::exchange(other.conn_, nullptr);
    last_sqlstate_ = std::move(other.last_sqlstate_);
    where_ = std::move(other.where_);
    answer_timeout_s_ = other.answer_timeout_s_;
    answer_grace_s_ = other.answer_grace_s_;
    interrupt_ = std::move(other.interrupt_);
  }
  return *this;
}

PgConnection::~PgConnection() { abandon(); }

void PgConnection::abandon() {
  if (!conn_) return;
  if (interrupt_) interrupt_->detach(conn_);
  PQfinish(conn_);
  conn_ = nullptr;
}

void PgConnection::set_interrupt(std::shared_ptr<PgInterrupt> interrupt) {
  if (interrupt_ && conn_) interrupt_->detach(conn_);
  interrupt_ = std::move(interrupt);
  if (interrupt_ && conn_) interrupt_->attach(conn_);
}

Status PgConnection::limit(double statement_timeout_s, double lock_timeout_s,
                           double answer_grace_s) {
  const auto ms = [](double s) {
    if (!std::isfinite(s) || s <= 0) return int64_t{0};
    return std::clamp<int64_t>(std::llround(s * 1000), 1, INT_MAX);
  };
  answer_grace_s_ = std::max(0.0, answer_grace_s);
  answer_timeout_s_ = ms(statement_timeout_s) > 0 ? statement_timeout_s + answer_grace_s_ : 0;
  auto set = exec(fmt::format("SET statement_timeout = {}; SET lock_timeout = {}",
                              ms(statement_timeout_s), ms(lock_timeout_s)));
  if (!set) return set.error();
  return {};
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

// Sends, then waits for the results on the socket and on the interrupt's
// eventfd at once: until the answer, the client's deadline
// (answer_timeout_s_), or an interrupt and kCancelGrace_s after it. Past a
// deadline the connection is given up (closed: the server rolls back what
// it did not commit). Of several results (statements), the first error or
// else the last, as PQexec.
template <class Send>
Result<PgRows> PgConnection::call(Send&& send) {
  if (!conn_) {
    last_sqlstate_.clear();
    return Error::Transient(where_.empty() ? std::string("lab database: not connected")
                                           : fmt::format("lab database {}: not connected", where_));
  }
  const std::string where = server();
  // busy before the check: a trigger() then either stops the call here or
  // finds it busy (and cancels it).
  struct Busy {
    PgInterrupt* interrupt;
    explicit Busy(PgInterrupt* i) : interrupt(i) {
      if (interrupt) interrupt->busy_ = true;
    }
    ~Busy() {
      if (interrupt) interrupt->busy_ = false;
    }
  } busy(interrupt_.get());
  if (interrupt_ && interrupt_->triggered()) {
    last_sqlstate_.clear();
    return Error::Transient(fmt::format("lab database {}: not sent: stopping", where));
  }
  if (!send(conn_)) return finish(conn_, nullptr, last_sqlstate_, where);

  using clock = std::chrono::steady_clock;
  const auto after = [](double s) {
    return clock::now() +
           std::chrono::duration_cast<clock::duration>(std::chrono::duration<double>(s));
  };
  std::optional<clock::time_point> deadline;
  if (answer_timeout_s_ > 0) deadline = after(answer_timeout_s_);
  std::optional<clock::time_point> interrupted_until;
  // Waits until a result can be read without blocking; the reason when
  // the wait was given up.
  const auto wait = [&]() -> std::optional<std::string> {
    for (;;) {
      const int flushed = PQflush(conn_);  // 0: all sent, 1: more to send, -1: failed
      if (flushed < 0 || (flushed == 0 && !PQisBusy(conn_))) return std::nullopt;
      if (!interrupted_until && interrupt_ && interrupt_->triggered()) {
        interrupted_until = after(kCancelGrace_s);
      }
      std::optional<clock::time_point> until = deadline;
      if (interrupted_until && (!until || *interrupted_until < *until)) until = interrupted_until;
      int timeout_ms = -1;
      if (until) {
        const auto left = std::chrono::ceil<std::chrono::milliseconds>(*until - clock::now());
        if (left.count() <= 0) {
          return interrupted_until && *until == *interrupted_until
                     ? fmt::format("no answer within {:g} s of the stop's cancel request",
                                   kCancelGrace_s)
                     : fmt::format("no answer within {:g} s (statement_timeout + {:g} s)",
                                   answer_timeout_s_, answer_grace_s_);
        }
        timeout_ms = static_cast<int>(std::min<int64_t>(left.count(), INT_MAX));
      }
      // An interrupt without an eventfd is seen within 100 ms.
      const bool watch_interrupt = interrupt_ && !interrupted_until;
      if (watch_interrupt && interrupt_->fd_ < 0 && (timeout_ms < 0 || timeout_ms > 100)) {
        timeout_ms = 100;
      }
      pollfd fds[2] = {
          {PQsocket(conn_), static_cast<short>(POLLIN | (flushed == 1 ? POLLOUT : 0)), 0},
          {watch_interrupt ? interrupt_->fd_ : -1, POLLIN, 0}};
      const int n = ::poll(fds, 2, timeout_ms);
      if (n < 0 && errno != EINTR) return std::nullopt;  // PQgetResult reports the state
      if (n > 0 && (fds[0].revents & (POLLIN | POLLERR | POLLHUP)) != 0 &&
          PQconsumeInput(conn_) == 0) {
        return std::nullopt;  // the connection failed: PQgetResult says how
      }
    }
  };
  PGresult* kept = nullptr;
  for (;;) {
    if (auto gave_up = wait()) {
      PQclear(kept);
      abandon();
      last_sqlstate_.clear();
      return Error::Transient(
          fmt::format("lab database {}: {}; connection closed", where, *gave_up));
    }
    PGresult* res = PQgetResult(conn_);
    if (!res) break;
    const auto status = PQresultStatus(res);
    if (kept && PQresultStatus(kept) == PGRES_FATAL_ERROR) {
      PQclear(res);
    } else {
      PQclear(kept);
      kept = res;
    }
    if (status == PGRES_COPY_IN || status == PGRES_COPY_OUT || status == PGRES_COPY_BOTH ||
        PQstatus(conn_) == CONNECTION_BAD) {
      break;
    }
  }
  return finish(conn_, kept, last_sqlstate_, where);
}

Result<PgRows> PgConnection::exec(std::string_view sql) {
  const std::string text(sql);
  return call([&](pg_conn* conn) { return PQsendQuery(conn, text.c_str()) == 1; });
}

Result<PgRows> PgConnection::exec_params(std::string_view sql,
                                         const std::vector<std::optional<std::string>>& params) {
  const std::string text(sql);
  std::vector<const char*> values;
  values.reserve(params.size());
  for (const auto& p : params) values.push_back(p ? p->c_str() : nullptr);
  return call([&](pg_conn* conn) {
    return PQsendQueryParams(conn, text.c_str(), static_cast<int>(values.size()),
                             /*paramTypes=*/nullptr, values.data(), /*paramLengths=*/nullptr,
                             /*paramFormats=*/nullptr, /*resultFormat=*/0) == 1;
  });
}

}  // namespace gyrotherm::lab
