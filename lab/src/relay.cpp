// The relay's thread (relay.h; docs/lab.md "Relay").
//
// One round: read the next batch of the outbox (after the last seq this
// thread acknowledged), push it to the lab in one transaction, and only
// once the lab committed it acknowledge it locally. Nothing else is held in
// memory: the batch in flight and a few counters.
//
// States and events. The status shows the state of the moment; events (the
// station's event log, kind "lab") are said only when the state worth
// telling changes: connected, lost (or never reached) with the reason,
// refused with the reason, back after N s. A retry that fails the same way
// says nothing more (a lab down for a weekend is one event, not thousands).
//
// The outbox's figures (pending, bytes, oldest age) are read by this
// thread about once a second (less often when the read is slow), and
// between reads adjusted by what it acknowledged: status() only copies
// them, so the HTTP thread never reads the outbox.
//
// Disabled mode (RelayOptions::conninfo empty, [lab] relay = false): the
// thread never connects; it only keeps the outbox's figures current, so
// the status and metrics show how much is queued.
//
// Each connection is first limited (statement_timeout, lock_timeout) and
// checked (the station id registered to its role) before anything is
// sent: a wrong id is "refused" at once, not "connected" until the first
// batch. stop() interrupts the call in progress (PgInterrupt).
#include "gyrotherm/lab/relay.h"

#include <fmt/format.h>
#include <libpq-fe.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <future>
#include <optional>
#include <string_view>
#include <utility>
#include <vector>

#include "gyrotherm/lab/central.h"
#include "gyrotherm/lab/pg.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::lab {
namespace {

using namespace std::chrono_literals;
using steady = std::chrono::steady_clock;

double unix_now_s() { return system_wall_clock().unix_now_s(); }

std::chrono::steady_clock::duration seconds(double s) {
  return std::chrono::duration_cast<steady::duration>(std::chrono::duration<double>(s));
}

// "host:port/db as user" from a conninfo or URI, before any connection
// (PgConnection::server() says it once connected). Never the password.
std::string server_of(const std::string& conninfo) {
  char* error = nullptr;
  PQconninfoOption* options = PQconninfoParse(conninfo.c_str(), &error);
  if (error) PQfreemem(error);
  if (!options) return "(unparsable connection string)";
  std::string host, hostaddr, port, db, user;
  for (PQconninfoOption* o = options; o->keyword; ++o) {
    if (!o->val) continue;
    const std::string_view key = o->keyword;
    if (key == "host") host = o->val;
    if (key == "hostaddr") hostaddr = o->val;
    if (key == "port") port = o->val;
    if (key == "dbname") db = o->val;
    if (key == "user") user = o->val;
  }
  PQconninfoFree(options);
  if (host.empty()) host = hostaddr.empty() ? "localhost" : hostaddr;
  if (port.empty()) port = "5432";
  std::string out = fmt::format("{}:{}/{}", host, port, db.empty() ? user : db);
  if (!user.empty()) out += " as " + user;
  return out;
}

// libpq's multi-line messages as one line.
std::string one_line(std::string_view s) {
  std::string out;
  for (const char c : s) {
    if (c == '\n' || c == '\r' || c == '\t' || c == ' ') {
      if (!out.empty() && out.back() != ' ') out += ' ';
    } else {
      out += c;
    }
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

// "1 record", "12 records".
std::string records(int64_t n) { return fmt::format("{} record{}", n, n == 1 ? "" : "s"); }

// A message inside a sentence: without its final full stop.
std::string clause(std::string s) {
  while (!s.empty() && (s.back() == '.' || s.back() == ' ')) s.pop_back();
  return s;
}

std::string describe_s(double s) {
  if (s < 10) return fmt::format("{:.2g} s", s);
  if (s < 120) return fmt::format("{:.0f} s", s);
  if (s < 7200) return fmt::format("{:.0f} min", s / 60);
  return fmt::format("{:.1f} h", s / 3600);
}

}  // namespace

Relay::Relay(RelayOptions options)
    : options_(std::move(options)), interrupt_(std::make_shared<PgInterrupt>()) {}

bool RelayOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  if (!valid_station_id(station_id)) {
    return fail(
        fmt::format("station_id = \"{}\" is not [A-Za-z0-9][A-Za-z0-9._-]{{0,63}}", station_id));
  }
  if (db_path.empty()) return fail("db_path is empty (the station's database is needed)");
  if (batch_records < 1) return fail(fmt::format("batch_records = {} must be >= 1", batch_records));
  if (batch_bytes < 1) return fail(fmt::format("batch_bytes = {} must be >= 1", batch_bytes));
  // Wall seconds the relay waits for: 0 would spin, infinity never wake.
  for (const auto& [name, value] :
       {std::pair{"poll_s", poll_s}, std::pair{"retry_min_s", retry_min_s},
        std::pair{"connect_timeout_s", connect_timeout_s},
        std::pair{"statement_timeout_s", statement_timeout_s},
        std::pair{"lock_timeout_s", lock_timeout_s}}) {
    if (!(value > 0) || !std::isfinite(value)) {
      return fail(fmt::format("{} = {} must be finite and > 0", name, value));
    }
  }
  if (!(retry_max_s >= retry_min_s) || !std::isfinite(retry_max_s)) {
    return fail(fmt::format("retry_max_s = {} must be finite and >= retry_min_s = {}", retry_max_s,
                            retry_min_s));
  }
  if (!conninfo.empty()) {
    if (auto malformed = conninfo_error(conninfo)) return fail("conninfo: " + *malformed);
  }
  return true;
}

Result<std::unique_ptr<Relay>> Relay::create(RelayOptions options) {
  const auto bad = [](const std::string& what) { return Error::Permanent("lab relay: " + what); };
  if (std::string why; !options.is_valid(&why)) return bad(why);

  // The binding is checked here, once: the thread trusts it.
  auto db = storage::Database::open(options.db_path);
  if (!db) return db.error();
  auto bound = db->lab_station_id();
  if (!bound) return bound.error();
  if (!*bound) {
    return bad(
        fmt::format("database {} is not bound to a lab station (lab_bind first)", options.db_path));
  }
  if (**bound != options.station_id) {
    return bad(fmt::format("database {} belongs to lab station \"{}\", not \"{}\"", options.db_path,
                           **bound, options.station_id));
  }
  auto stats = db->outbox_stats();
  if (!stats) return stats.error();

  std::unique_ptr<Relay> relay(new Relay(std::move(options)));
  RelayStatus& s = relay->status_;
  s.station_id = relay->options_.station_id;
  const bool disabled = relay->options_.conninfo.empty();
  s.server = disabled ? "" : server_of(relay->options_.conninfo);
  s.state = disabled ? "disabled" : "connecting";
  s.pending = stats->pending;
  s.pending_bytes = stats->pending_bytes;
  if (stats->oldest_unix_s)
    s.oldest_pending_age_s = std::max(0.0, unix_now_s() - *stats->oldest_unix_s);
  return relay;
}

Relay::~Relay() { stop(); }

void Relay::start() {
  std::lock_guard lock(mutex_);
  if (thread_.joinable() || stop_requested_) return;
  thread_ = std::thread([this] { run(); });
}

void Relay::stop() {
  {
    std::lock_guard lock(mutex_);
    stop_requested_ = true;
  }
  wake_.notify_all();
  // The call in progress wakes now and waits kCancelGrace_s at most for the
  // server's answer to the cancel request. PQcancel opens a connection of
  // its own without a time limit (to a host gone silent: minutes), so it is
  // sent from a thread of its own, left to finish alone when it takes long.
  interrupt_->trigger();
  std::thread canceller;
  std::future<std::string> cancelled;
  if (interrupt_->busy()) {
    std::packaged_task<std::string()> task([i = interrupt_] { return i->cancel_running(); });
    cancelled = task.get_future();
    canceller = std::thread(std::move(task));
  }
  if (thread_.joinable()) thread_.join();
  if (canceller.joinable()) {
    if (cancelled.wait_for(100ms) == std::future_status::ready) {
      canceller.join();
    } else {
      canceller.detach();
    }
  }
  std::lock_guard lock(mutex_);
  status_.state = "stopped";
  status_.retry_in_s.reset();
}

void Relay::nudge() {
  {
    std::lock_guard lock(mutex_);
    nudged_ = true;
  }
  wake_.notify_all();
}

RelayStatus Relay::status() const {
  std::lock_guard lock(mutex_);
  return status_;
}

// run()'s state and its steps. A round is open_station_db,
// refresh_stats_when_due, connect, check and send_batch in order; each step
// either lets the round go on (Next::kStep) or ends it: a failure or an idle
// poll waited out (Next::kRound), or stop() (Next::kStop).
class Relay::Loop {
 public:
  explicit Loop(Relay& relay)
      : relay_(relay),
        options_(relay.options_),
        disabled_(options_.conninfo.empty()),
        delay_s_(options_.retry_min_s) {}

  // One round; false when stopping.
  bool round();

 private:
  // What a step leaves the loop to do.
  enum class Next {
    kStep,   // the round's next step
    kRound,  // the next round
    kStop,   // stopping
  };

  // The steps of a round.
  Next open_station_db();
  Next refresh_stats_when_due();
  Next connect();
  Next check();
  Next send_batch();
  // send_batch's parts.
  Next idle();
  void note_stale(const std::vector<storage::OutboxRecord>& batch, int64_t stale);
  // What acknowledge needs of a committed batch once its records are freed.
  struct Sent {
    int64_t last_seq = 0;
    int64_t count = 0;  // records
    int64_t bytes = 0;  // their payloads
  };
  Sent record_sent(const std::vector<storage::OutboxRecord>& batch, const PushResult& pushed);
  Next acknowledge(const Sent& sent, int64_t waiting);
  // Shared by the steps.
  template <typename Fn>
  void update(Fn&& fn);
  void event(const std::string& message);
  bool refresh_stats();
  Next read_stats();
  Next wait(double wait_s, bool nudgeable, bool backoff);
  Next fail(const Error& e, bool local);
  void report_interrupted_batch(const Error& e);
  void announce_failure(const Error& e, bool local, bool refused);
  void succeeded(int64_t waiting);

  Relay& relay_;
  const RelayOptions& options_;
  const bool disabled_;
  std::optional<storage::Database> db_;
  std::optional<PgConnection> pg_;
  int64_t after_seq_ = -1;  // the last seq acknowledged (-1: read it from the outbox first)
  double delay_s_;
  // What the events last said: "" (nothing yet), "connected", "backoff",
  // "refused"; and since when (steady) the relay has not been sending.
  std::string announced_;
  std::optional<steady::time_point> outage_since_;
  steady::time_point stats_due_{};
  bool checked_ = false;             // this connection is limited and its station id registered
  bool stale_said_ = false;          // the stale records of this run of batches have an event
  bool refused_at_connect_ = false;  // the last refusal was the check's, not a batch's
  std::string in_flight_;            // "a batch of N records (outbox seq A to B)" while pushed
};

void Relay::run() {
  Loop loop(*this);
  for (;;) {
    {
      std::lock_guard lock(mutex_);
      if (stop_requested_) break;
    }
    if (!loop.round()) break;
  }
  std::lock_guard lock(mutex_);
  status_.state = "stopped";
  status_.retry_in_s.reset();
}

bool Relay::Loop::round() {
  Next next = open_station_db();
  if (next == Next::kStep) next = refresh_stats_when_due();
  // Disabled: the outbox's figures only, every poll_s.
  if (next == Next::kStep && disabled_) next = wait(options_.poll_s, true, false);
  if (next == Next::kStep) next = connect();
  if (next == Next::kStep) next = check();
  if (next == Next::kStep) next = send_batch();
  return next != Next::kStop;
}

// --- The steps of a round ---------------------------------------------------

// The station's database, opened again after a local failure (fail() drops
// it); the seq to read after is then taken from the outbox again.
Relay::Loop::Next Relay::Loop::open_station_db() {
  if (db_) return Next::kStep;
  auto d = storage::Database::open(options_.db_path);
  if (!d) return fail(d.error(), true);
  db_.emplace(std::move(*d));
  after_seq_ = -1;
  return Next::kStep;
}

Relay::Loop::Next Relay::Loop::refresh_stats_when_due() {
  if (after_seq_ < 0 || steady::now() >= stats_due_) return read_stats();
  return Next::kStep;
}

// A connection to the lab database when there is none (the first round, or
// after fail() dropped it).
Relay::Loop::Next Relay::Loop::connect() {
  if (pg_) return Next::kStep;
  if (announced_ != "refused") update([](RelayStatus& s) { s.state = "connecting"; });
  auto c = PgConnection::connect(options_.conninfo, options_.connect_timeout_s);
  if (!c) return fail(c.error(), false);
  pg_.emplace(std::move(*c));
  pg_->set_interrupt(relay_.interrupt_);
  update([&](RelayStatus& s) { s.server = pg_->server(); });
  checked_ = false;
  return Next::kStep;
}

// Each connection limited (statement_timeout, lock_timeout) and its station
// id checked before anything is sent.
Relay::Loop::Next Relay::Loop::check() {
  if (checked_) return Next::kStep;
  Status ready = pg_->limit(options_.statement_timeout_s, options_.lock_timeout_s);
  if (ready.ok()) ready = check_station(*pg_, options_.station_id);
  if (!ready.ok()) {
    refused_at_connect_ = true;
    return fail(ready.error(), false);
  }
  checked_ = true;
  return Next::kStep;
}

// The next batch of the outbox pushed to the lab in one transaction and,
// once committed there, acknowledged locally; no batch: idle.
Relay::Loop::Next Relay::Loop::send_batch() {
  auto batch = db_->outbox_batch(after_seq_, options_.batch_records, options_.batch_bytes);
  if (!batch) return fail(batch.error(), true);
  if (batch->empty()) return idle();
  const double oldest_unix_s = batch->front().committed_unix_s;
  int64_t waiting = 0;
  update([&](RelayStatus& s) {
    s.oldest_pending_age_s = std::max(0.0, unix_now_s() - oldest_unix_s);
    s.pending = std::max<int64_t>(s.pending, static_cast<int64_t>(batch->size()));
    waiting = s.pending;
  });
  in_flight_ = fmt::format("a batch of {} (outbox seq {} to {})",
                           records(static_cast<int64_t>(batch->size())), batch->front().seq,
                           batch->back().seq);
  auto pushed = push_batch(*pg_, options_.station_id, *batch);
  if (!pushed) {
    refused_at_connect_ = false;
    const Next next = fail(pushed.error(), false);
    in_flight_.clear();
    return next;
  }
  in_flight_.clear();
  note_stale(*batch, pushed->stale);
  const Sent sent = record_sent(*batch, *pushed);
  batch->clear();
  batch->shrink_to_fit();
  return acknowledge(sent, waiting);
}

// Nothing to send: the outbox's figures read again, the connection watched,
// and a wait of poll_s (nudge() ends it early).
Relay::Loop::Next Relay::Loop::idle() {
  if (const Next next = read_stats(); next != Next::kStep) return next;
  // Idle: a server that shut down or restarted has said so on the
  // socket (read without a round trip), so the status and the events
  // follow an outage even when nothing is to be sent. A link that died
  // silently shows at the next batch (or the keepalives). A batch's
  // refusal stays a refusal until a batch goes through; the check's
  // ends when the check passes.
  if (PQconsumeInput(pg_->handle()) == 0 || !pg_->ok()) {
    return fail(
        Error::Transient(fmt::format("lab database {}: connection lost while idle: {}",
                                     pg_->server(), one_line(PQerrorMessage(pg_->handle())))),
        false);
  }
  if (announced_ != "refused" || refused_at_connect_) succeeded(0);
  return wait(options_.poll_s, true, false);
}

// The lab kept newer versions of some records: said once per run of
// such batches, counted always.
void Relay::Loop::note_stale(const std::vector<storage::OutboxRecord>& batch, int64_t stale) {
  if (stale > 0) {
    if (!stale_said_) {
      event(fmt::format(
          "lab: the lab database holds newer versions of {} of the batch of {} (outbox seq {} "
          "to {}) and kept its own: the station's versions of them are not in the lab. The "
          "station's database was re-created or restored from a backup (its outbox numbers "
          "started again); see docs/lab.md \"Records the lab ignores as stale\"",
          records(stale), records(static_cast<int64_t>(batch.size())), batch.front().seq,
          batch.back().seq));
      stale_said_ = true;
    }
    update([&](RelayStatus& s) { s.stale_total += static_cast<uint64_t>(stale); });
  } else {
    stale_said_ = false;
  }
}

// Committed centrally: the lag is measured now, then acknowledged.
Relay::Loop::Sent Relay::Loop::record_sent(const std::vector<storage::OutboxRecord>& batch,
                                           const PushResult& pushed) {
  const double now_unix = unix_now_s();
  double newest_unix_s = batch.front().committed_unix_s;
  int64_t bytes = 0;
  for (const auto& r : batch) {
    newest_unix_s = std::max(newest_unix_s, r.committed_unix_s);
    bytes += static_cast<int64_t>(r.payload_json.size());
  }
  const double lag_s = std::max(0.0, now_unix - newest_unix_s);
  const Sent sent{batch.back().seq, static_cast<int64_t>(batch.size()), bytes};
  update([&](RelayStatus& s) {
    ++s.batches_total;
    s.sent_total += static_cast<uint64_t>(sent.count);
    s.redelivered_total += static_cast<uint64_t>(pushed.redelivered);
    s.last_lag_s = lag_s;
    s.max_lag_s = std::max(lag_s, s.max_lag_s.value_or(0.0));
    s.last_sent_utc = utc_iso(now_unix);
  });
  return sent;
}

// `waiting`: the records pending when the round began.
Relay::Loop::Next Relay::Loop::acknowledge(const Sent& sent, int64_t waiting) {
  if (auto acked = db_->outbox_ack(sent.last_seq); !acked) {
    // The lab has the batch; it is sent again (counted redelivered).
    return fail(acked.error(), true);
  }
  after_seq_ = sent.last_seq;
  update([&](RelayStatus& s) {
    s.pending = std::max<int64_t>(0, s.pending - sent.count);
    s.pending_bytes = std::max<int64_t>(0, s.pending_bytes - sent.bytes);
  });
  succeeded(waiting);
  return Next::kRound;
}

// --- Shared by the steps ----------------------------------------------------

template <typename Fn>
void Relay::Loop::update(Fn&& fn) {
  std::lock_guard lock(relay_.mutex_);
  fn(relay_.status_);
}

void Relay::Loop::event(const std::string& message) {
  if (options_.on_event) options_.on_event(message);
}

// The outbox's figures (pending, bytes, oldest age), read again at most
// once a wall second, and less often when reading them takes long (a
// large outbox, e.g. a station that queues without relaying): the reads
// take at most 2 % of the time.
bool Relay::Loop::refresh_stats() {
  const auto started = steady::now();
  auto stats = db_->outbox_stats();
  stats_due_ = steady::now() + std::max<steady::duration>(1s, 50 * (steady::now() - started));
  if (!stats) return false;
  if (after_seq_ < 0) after_seq_ = stats->last_acked_seq;
  const double now = unix_now_s();
  update([&](RelayStatus& s) {
    s.pending = stats->pending;
    s.pending_bytes = stats->pending_bytes;
    s.oldest_pending_age_s.reset();
    if (stats->oldest_unix_s) s.oldest_pending_age_s = std::max(0.0, now - *stats->oldest_unix_s);
  });
  return true;
}

// refresh_stats, or the backoff of its failure.
Relay::Loop::Next Relay::Loop::read_stats() {
  if (refresh_stats()) return Next::kStep;
  return fail(Error::Transient("reading the outbox's figures failed"), true);
}

// Waits `wait_s` wall seconds, or less when stop() (or, `nudgeable`, nudge())
// is called; Next::kStop when stopping, else Next::kRound. Meanwhile
// retry_in_s counts down and the outbox's figures stay current (a lab down
// for hours is when the pending count matters).
Relay::Loop::Next Relay::Loop::wait(double wait_s, bool nudgeable, bool backoff) {
  Relay& r = relay_;
  const auto until = steady::now() + seconds(wait_s);
  for (;;) {
    {
      std::unique_lock lock(r.mutex_);
      const auto done = [&] {
        return r.stop_requested_ || (nudgeable && r.nudged_) || steady::now() >= until;
      };
      if (!done()) {
        if (backoff) {
          r.status_.retry_in_s = std::chrono::duration<double>(until - steady::now()).count();
        }
        const auto now = steady::now();
        r.wake_.wait_until(lock,
                           std::min(until, db_ ? std::max(stats_due_, now + 10ms) : now + 1s));
      }
      if (done()) {
        r.nudged_ = false;
        r.status_.retry_in_s.reset();
        return r.stop_requested_ ? Next::kStop : Next::kRound;
      }
    }
    if (db_ && steady::now() >= stats_due_) refresh_stats();
  }
}

// A failed attempt: backoff (transient: retry_min_s doubling up to
// retry_max_s) or refused (permanent: retry_max_s), one event per change.
Relay::Loop::Next Relay::Loop::fail(const Error& e, bool local) {
  // Stopping: the call was interrupted. A batch says what became of it;
  // anything else has nothing to tell.
  if (relay_.interrupt_->triggered()) {
    if (!in_flight_.empty()) report_interrupted_batch(e);
    return Next::kStop;
  }
  const bool refused = !e.transient && !local;
  const std::string state = refused ? "refused" : disabled_ ? "disabled" : "backoff";
  const double wait_s = refused ? options_.retry_max_s : delay_s_;
  if (!refused) delay_s_ = std::min(options_.retry_max_s, delay_s_ * 2);
  if (!outage_since_) outage_since_ = steady::now();
  // The event before the status that follows from it (as on success): a
  // reader who sees the new state or count finds its event already said.
  if (announced_ != state) {
    announce_failure(e, local, refused);
    announced_ = state;
  }
  update([&](RelayStatus& s) {
    ++s.errors_total;
    s.last_error = e.message;
    s.state = state;
    s.retry_in_s = wait_s;
  });
  // A lost connection is reopened; a refusal's is kept when still usable
  // (and checked again at the next attempt).
  if (pg_ && (!refused || !pg_->ok())) pg_.reset();
  checked_ = false;
  if (local) db_.reset();
  return wait(wait_s, false, true);
}

// stop() interrupted the batch in flight: what became of it.
void Relay::Loop::report_interrupted_batch(const Error& e) {
  const bool cancelled = pg_ && pg_->last_sqlstate() == "57014";
  const std::string message = fmt::format(
      "lab: relay stopped during {}: {}; {}", in_flight_, clause(e.message),
      cancelled ? "the lab rolled it back, it is sent again at the next start"
                : "the lab commits it or rolls it back, and the station sends it again at "
                  "the next start either way (counted redelivered if it was committed)");
  event(message);
  update([&](RelayStatus& s) { s.last_error = message.substr(5); });
}

// fail()'s event when the state changes (announced_ is still the old one).
void Relay::Loop::announce_failure(const Error& e, bool local, bool refused) {
  const std::string retrying =
      fmt::format("retrying {} to {} apart", describe_s(options_.retry_min_s),
                  describe_s(options_.retry_max_s));
  if (refused) {
    event(fmt::format("lab: the lab database refused station {}'s records: {}; retried every {}",
                      options_.station_id, clause(e.message), describe_s(options_.retry_max_s)));
  } else if (local) {
    event(fmt::format("lab: relay stalled on the station database: {}; {}", clause(e.message),
                      retrying));
  } else if (pg_ && pg_->ok()) {
    // The server answered and is still there: a lock or statement
    // timeout, a conflict.
    event(fmt::format("lab: the lab database did not take {}: {}; {}",
                      in_flight_.empty() ? "the relay's request" : in_flight_, clause(e.message),
                      retrying));
  } else if (announced_ == "connected") {
    event(fmt::format("lab: connection to the lab database lost: {}; {}", clause(e.message),
                      retrying));
  } else {
    event(fmt::format("lab: cannot reach the lab database: {}; {}", clause(e.message), retrying));
  }
}

// A round that reached the lab (a batch committed, or nothing to send).
// `waiting`: the records pending when the round began.
void Relay::Loop::succeeded(int64_t waiting) {
  delay_s_ = options_.retry_min_s;
  if (announced_ != "connected") {
    const std::string server = pg_ ? pg_->server() : server_of(options_.conninfo);
    if (outage_since_) {
      event(fmt::format(
          "lab: relaying to {} again after {}; {} waiting", server,
          describe_s(std::chrono::duration<double>(steady::now() - *outage_since_).count()),
          records(waiting)));
    } else {
      event(fmt::format("lab: connected to {} (station {}); {} to send", server,
                        options_.station_id, records(waiting)));
    }
    announced_ = "connected";
  }
  outage_since_.reset();
  update([&](RelayStatus& s) {
    s.state = "connected";
    s.last_error.clear();
    s.retry_in_s.reset();
  });
}

}  // namespace gyrotherm::lab
