// The relay (lab/relay.h, docs/lab.md "Relay") between a real SQLite file
// and a private PostgreSQL cluster (tests/support/pg_cluster.h): the
// history and new results arrive, once each; an outage backs off, says so
// once and catches up; a station the lab refuses says why; a batch the lab
// committed but the station never acknowledged (a crash in between) is
// replayed and counted redelivered, not duplicated; memory stays one batch;
// stop() is prompt in a backoff, in a lock wait (the batch cancelled) and
// bounded in a hung connect; lock and statement timeouts are backoffs; the
// station id is checked at connect; records the lab holds newer versions
// of are counted and said.
#include "gyrotherm/lab/relay.h"

#include <arpa/inet.h>
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sqlite3.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <future>
#include <limits>
#include <mutex>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "gyrotherm/lab/central.h"
#include "gyrotherm/lab/pg.h"
#include "gyrotherm/storage/database.h"
#include "support/pg_cluster.h"
#include "test_time.h"

namespace gyrotherm::lab {
namespace {

using namespace std::chrono_literals;
using ::testing::AnyOf;
using ::testing::Eq;
using ::testing::HasSubstr;
using testing::PgClusterTest;
using testing::scaled;
using testing::wait_for_condition;

// The relayed tables (docs/lab.md): a local row of any of them is one lab record.
constexpr const char* kRelayedTables[] = {"runs",
                                          "segments",
                                          "events",
                                          "segment_stats",
                                          "allan",
                                          "fits",
                                          "fit_runs",
                                          "exports",
                                          "export_runs",
                                          "scale_factor_points",
                                          "scale_factor_fits",
                                          "scale_factor_temperature_fits",
                                          "duts",
                                          "run_duts",
                                          "channels"};

class RelayTest : public PgClusterTest {
 protected:
  void SetUp() override {
    PgClusterTest::SetUp();
    if (IsSkipped() || HasFatalFailure()) return;
    dir_ = std::filesystem::temp_directory_path() /
           fmt::format("gyrotherm-relay-{}-{}", ::getpid(), dbname_);
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
    db_path_ = (dir_ / "station.db").string();
    auto admin = PgConnection::connect(conninfo());
    ASSERT_TRUE(admin.ok()) << admin.error().message;
    admin_.emplace(std::move(*admin));
    auto migrated = migrate_central(*admin_);
    ASSERT_TRUE(migrated.ok()) << migrated.error().message;
  }
  void TearDown() override {
    relay_.reset();
    admin_.reset();
    std::error_code ec;
    if (!dir_.empty()) std::filesystem::remove_all(dir_, ec);
  }

  storage::Database open_db() {
    auto db = storage::Database::open(db_path_);
    EXPECT_TRUE(db.ok()) << db.error().message;
    if (!db) std::abort();
    return std::move(*db);
  }

  // A run with `events` events, as the station writes them.
  static int64_t add_run(storage::Database& db, int events) {
    storage::RunRecord run;
    run.schedule_name = "soak";
    run.state = "acquiring";
    run.config_json = "{}";
    auto id = db.create_run(run);
    EXPECT_TRUE(id.ok()) << id.error().message;
    for (int i = 0; i < events; ++i) add_event(db, *id, fmt::format("event {}", i));
    return *id;
  }
  static void add_event(storage::Database& db, std::optional<int64_t> run_id,
                        const std::string& message) {
    storage::EventRecord ev;
    ev.run_id = run_id;
    ev.kind = "info";
    ev.message = message;
    auto r = db.add_event(ev);
    EXPECT_TRUE(r.ok()) << r.error().message;
  }

  // Runs `sql` on the station's file (raw SQLite: bulk inserts, counts).
  int64_t local_sql(const std::string& sql) {
    sqlite3* db = nullptr;
    EXPECT_EQ(sqlite3_open(db_path_.c_str(), &db), SQLITE_OK);
    sqlite3_busy_timeout(db, 10000);
    sqlite3_stmt* st = nullptr;
    int64_t value = 0;
    char* err = nullptr;
    if (sql.rfind("SELECT", 0) == 0) {
      EXPECT_EQ(sqlite3_prepare_v2(db, sql.c_str(), -1, &st, nullptr), SQLITE_OK)
          << sqlite3_errmsg(db);
      if (sqlite3_step(st) == SQLITE_ROW) value = sqlite3_column_int64(st, 0);
      sqlite3_finalize(st);
    } else {
      EXPECT_EQ(sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &err), SQLITE_OK)
          << (err ? err : "");
      sqlite3_free(err);
    }
    sqlite3_close(db);
    return value;
  }
  // Every relayed row of the station's file: what the lab should hold.
  int64_t local_rows() {
    std::string sql = "SELECT 0";
    for (const char* t : kRelayedTables) sql += fmt::format(" + (SELECT count(*) FROM {})", t);
    return local_sql(sql);
  }

  // A query of the lab as its administrator, on a new connection (the
  // outage tests restart the server under the fixture's).
  int64_t central(const std::string& sql, const std::string& station_id) {
    auto admin = PgConnection::connect(conninfo());
    EXPECT_TRUE(admin.ok()) << admin.error().message;
    if (!admin) return -1;
    auto rows = admin->exec_params(sql, {station_id});
    EXPECT_TRUE(rows.ok()) << rows.error().message;
    if (!rows || rows->rows.empty() || !rows->rows[0][0]) return -1;
    return std::stoll(*rows->rows[0][0]);
  }
  int64_t central_rows(const std::string& station_id) {
    return central("SELECT count(*) FROM lab.records WHERE station_id = $1", station_id);
  }
  int64_t central_redeliveries(const std::string& station_id) {
    return central("SELECT coalesce(sum(redeliveries), 0) FROM lab.records WHERE station_id = $1",
                   station_id);
  }

  // Holds an ACCESS EXCLUSIVE lock on `table` in an open transaction, as
  // an administrator's session might, until release() or the end of the
  // test (before TearDown stops the relay).
  class TableLock {
   public:
    TableLock(PgConnection pg, const std::string& table) : pg_(std::move(pg)) {
      auto locked = pg_->exec("BEGIN; LOCK TABLE " + table + " IN ACCESS EXCLUSIVE MODE");
      EXPECT_TRUE(locked.ok()) << locked.error().message;
    }
    TableLock(const TableLock&) = delete;
    TableLock& operator=(const TableLock&) = delete;
    ~TableLock() { release(); }
    void release() {
      if (pg_) (void)pg_->exec("ROLLBACK");
      pg_.reset();
    }

   private:
    std::optional<PgConnection> pg_;
  };
  std::unique_ptr<TableLock> lock_table(const std::string& table) {
    auto admin = PgConnection::connect(conninfo());
    EXPECT_TRUE(admin.ok()) << admin.error().message;
    if (!admin) std::abort();
    return std::make_unique<TableLock>(std::move(*admin), table);
  }
  // Backends of `role` in pg_stat_activity matching `condition`.
  int64_t backends(const std::string& role, const std::string& condition) {
    return central("SELECT count(*) FROM pg_stat_activity WHERE usename = $1 AND " + condition,
                   role);
  }

  void register_station(const std::string& station_id, const std::string& role) {
    auto st = add_station(*admin_, station_id, role, "test station");
    ASSERT_TRUE(st.ok()) << st.error().message;
  }

  RelayOptions options(const std::string& station_id, const std::string& role) {
    RelayOptions o;
    o.station_id = station_id;
    o.db_path = db_path_;
    o.conninfo = conninfo(role);
    o.poll_s = 0.05;
    o.retry_min_s = 0.05;
    o.retry_max_s = 0.2;
    o.connect_timeout_s = 5;
    o.on_event = [this](const std::string& m) {
      std::lock_guard lock(events_mu_);
      events_.push_back(m);
    };
    return o;
  }
  void start(RelayOptions o) {
    auto r = Relay::create(std::move(o));
    ASSERT_TRUE(r.ok()) << r.error().message;
    relay_ = std::move(*r);
    relay_->start();
  }
  std::vector<std::string> events() {
    std::lock_guard lock(events_mu_);
    return events_;
  }
  int events_with(const std::string& text) {
    int n = 0;
    for (const auto& e : events()) n += e.find(text) != std::string::npos ? 1 : 0;
    return n;
  }
  // Waits until the relay has sent everything the file holds.
  bool caught_up(std::chrono::milliseconds timeout = 60s) {
    return wait_for_condition(
        [&] {
          const RelayStatus s = relay_->status();
          return s.state == "connected" && s.pending == 0 && s.oldest_pending_age_s == std::nullopt;
        },
        timeout, 5ms);
  }
  std::string describe() {
    const RelayStatus s = relay_->status();
    std::string out = fmt::format("state {}, pending {}, sent {}, errors {}, last error: {}",
                                  s.state, s.pending, s.sent_total, s.errors_total, s.last_error);
    for (const auto& e : events()) out += "\n  event: " + e;
    return out;
  }

  std::filesystem::path dir_;
  std::string db_path_;
  std::optional<PgConnection> admin_;
  std::unique_ptr<Relay> relay_;
  std::mutex events_mu_;
  std::vector<std::string> events_;
};

TEST_F(RelayTest, SendsTheHistoryThenNewResultsOnceEach) {
  register_station("st-a", "relay_st_a");
  int64_t run1 = 0;
  {
    storage::Database db = open_db();
    run1 = add_run(db, 20);
    add_run(db, 5);
    add_event(db, std::nullopt, "outside a run");
    ASSERT_TRUE(db.lab_bind("st-a").ok());
    auto stats = db.outbox_stats();
    ASSERT_TRUE(stats.ok()) << stats.error().message;
    EXPECT_EQ(stats->pending, local_rows()) << "the binding queues the whole history";
  }
  const int64_t history = local_rows();
  ASSERT_GE(history, 28);
  start(options("st-a", "relay_st_a"));
  ASSERT_TRUE(caught_up()) << describe();
  EXPECT_EQ(central_rows("st-a"), history);
  RelayStatus s = relay_->status();
  EXPECT_EQ(s.sent_total, static_cast<uint64_t>(history));
  EXPECT_GE(s.batches_total, 1u);
  EXPECT_EQ(s.redelivered_total, 0u);
  EXPECT_EQ(s.errors_total, 0u);
  ASSERT_TRUE(s.last_lag_s.has_value());
  EXPECT_GE(*s.last_lag_s, 0.0);
  ASSERT_TRUE(s.max_lag_s.has_value());
  EXPECT_GE(*s.max_lag_s, *s.last_lag_s);
  EXPECT_FALSE(s.last_sent_utc.empty());
  EXPECT_EQ(s.station_id, "st-a");
  EXPECT_THAT(s.server, HasSubstr("as relay_st_a"));
  EXPECT_EQ(s.last_error, "");
  EXPECT_EQ(events_with("lab: connected to"), 1) << describe();

  // New results and a change of an old one: sent at once (nudge), the
  // change an update of the same record.
  {
    storage::Database db = open_db();
    for (int i = 0; i < 7; ++i) add_event(db, run1, fmt::format("new {}", i));
    ASSERT_TRUE(db.set_run_state(run1, "completed", true).ok());
  }
  relay_->nudge();
  ASSERT_TRUE(wait_for_condition([&] { return central_rows("st-a") == history + 7; }, 30s, 20ms))
      << describe();
  ASSERT_TRUE(caught_up()) << describe();
  EXPECT_EQ(central_rows("st-a"), local_rows());
  EXPECT_EQ(central(fmt::format("SELECT count(*) FROM lab.records WHERE station_id = $1 AND "
                                "kind = 'run' AND payload->>'state' = 'completed' AND "
                                "local_id = '{}'",
                                run1),
                    "st-a"),
            1);
  s = relay_->status();
  EXPECT_EQ(s.sent_total, static_cast<uint64_t>(history + 8)) << "7 events and the run's update";
  EXPECT_EQ(s.redelivered_total, 0u);
  EXPECT_EQ(central_redeliveries("st-a"), 0);
  EXPECT_EQ(events_with("lab: "), 1) << "no event while nothing changes: " << describe();
  relay_->stop();
  EXPECT_EQ(relay_->status().state, "stopped");
}

TEST_F(RelayTest, AnOutageBacksOffSaysSoOnceAndCatchesUp) {
  register_station("st-a", "relay_st_a");
  {
    storage::Database db = open_db();
    add_run(db, 10);
    ASSERT_TRUE(db.lab_bind("st-a").ok());
  }
  start(options("st-a", "relay_st_a"));
  ASSERT_TRUE(caught_up()) << describe();
  const uint64_t errors_before = relay_->status().errors_total;

  ASSERT_TRUE(cluster().stop());
  // Idle, the relay still notices (the server said goodbye on the socket).
  // What the status says then depends on which came first, the idle check
  // ("connection lost while idle") or a retry ("cannot connect"): the test
  // holds to the state, the count and the one event.
  ASSERT_TRUE(
      wait_for_condition([&] { return relay_->status().errors_total > errors_before; }, 10s))
      << describe();
  EXPECT_THAT(relay_->status().state, AnyOf(Eq("backoff"), Eq("connecting")));
  EXPECT_NE(relay_->status().last_error, "");
  EXPECT_EQ(events_with("lab: connection to the lab database lost"), 1) << describe();
  {
    storage::Database db = open_db();
    const int64_t run = add_run(db, 50);
    for (int i = 0; i < 150; ++i) add_event(db, run, fmt::format("during the outage {}", i));
  }
  relay_->nudge();
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().state == "backoff"; }, 30s))
      << describe();
  // Several retries, each failing: still one event.
  ASSERT_TRUE(
      wait_for_condition([&] { return relay_->status().errors_total >= errors_before + 4; }, 30s))
      << describe();
  // The outbox's figures stay current during the backoff (read each second).
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().pending > 200; }, 10s))
      << describe();
  RelayStatus s = relay_->status();
  EXPECT_THAT(s.state, AnyOf(Eq("backoff"), Eq("connecting")));  // between two retries, or in one
  EXPECT_NE(s.last_error, "");
  EXPECT_TRUE(s.oldest_pending_age_s.has_value());
  EXPECT_EQ(events_with("lab: connection to"), 1) << describe();
  EXPECT_EQ(events_with("lost"), 1) << describe();

  ASSERT_TRUE(cluster().start()) << cluster().log();
  ASSERT_TRUE(caught_up()) << describe();
  EXPECT_EQ(central_rows("st-a"), local_rows()) << "nothing lost";
  // Nothing twice: every local event id is one lab record.
  EXPECT_EQ(central("SELECT count(DISTINCT local_id) FROM lab.records WHERE station_id = $1 AND "
                    "kind = 'event'",
                    "st-a"),
            local_sql("SELECT count(*) FROM events"));
  EXPECT_EQ(events_with("again after"), 1) << describe();
  s = relay_->status();
  EXPECT_EQ(s.last_error, "");
  EXPECT_EQ(s.retry_in_s, std::nullopt);
  // The outage came between batches: every outbox row was sent once.
  EXPECT_EQ(s.sent_total, static_cast<uint64_t>(local_rows()));
  EXPECT_EQ(s.redelivered_total, 0u);
}

// The station's id registered to another role: row-level security refuses
// it (42501). An id nobody registered likewise, until it is registered:
// then the relay goes on by itself at the next retry.
TEST_F(RelayTest, ALabThatRefusesTheStationSaysWhyOnceAndIsRetried) {
  register_station("st-a", "relay_st_a");
  register_station("st-b", "relay_st_b");
  {
    storage::Database db = open_db();
    add_run(db, 3);
    ASSERT_TRUE(db.lab_bind("st-b").ok());
  }
  // st-b's database, relayed with st-a's role.
  start(options("st-b", "relay_st_a"));
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().state == "refused"; }, 30s))
      << describe();
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().errors_total >= 3; }, 30s))
      << describe();
  RelayStatus s = relay_->status();
  EXPECT_EQ(s.state, "refused");
  EXPECT_THAT(s.last_error, HasSubstr("registered to role 'relay_st_b'"));
  EXPECT_EQ(s.sent_total, 0u);
  EXPECT_GT(s.pending, 0);
  EXPECT_EQ(events_with("refused"), 1) << describe();
  EXPECT_EQ(central_rows("st-b"), 0);
  relay_.reset();

  // Not registered at all: refused until an administrator registers it.
  ASSERT_EQ(cluster().admin_exec("CREATE ROLE relay_st_c LOGIN", dbname_), "");
  ASSERT_EQ(cluster().admin_exec("GRANT gyrotherm_station TO relay_st_c", dbname_), "");
  db_path_ = (dir_ / "station-c.db").string();
  {
    storage::Database db = open_db();
    add_run(db, 2);
    ASSERT_TRUE(db.lab_bind("st-c").ok());
  }
  start(options("st-c", "relay_st_c"));
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().state == "refused"; }, 30s))
      << describe();
  register_station("st-c", "relay_st_c");
  ASSERT_TRUE(caught_up()) << describe();
  EXPECT_EQ(central_rows("st-c"), local_rows());
  EXPECT_EQ(events_with("again after"), 1) << describe();
}

// A relay killed after the lab's commit and before the local ack: the
// batch is still pending locally; the next relay sends it again, the lab
// counts the redelivery and keeps one record per key.
TEST_F(RelayTest, ABatchCommittedButNotAcknowledgedIsReplayedNotDuplicated) {
  register_station("st-a", "relay_st_a");
  {
    storage::Database db = open_db();
    add_run(db, 30);
    ASSERT_TRUE(db.lab_bind("st-a").ok());
    // What a relay does up to the central commit, then "dies".
    auto batch = db.outbox_batch(0, 20);
    ASSERT_TRUE(batch.ok()) << batch.error().message;
    ASSERT_EQ(batch->size(), 20u);
    auto pg = PgConnection::connect(conninfo("relay_st_a"));
    ASSERT_TRUE(pg.ok()) << pg.error().message;
    auto pushed = push_batch(*pg, "st-a", *batch);
    ASSERT_TRUE(pushed.ok()) << pushed.error().message;
    EXPECT_EQ(pushed->upserted, 20);
  }
  EXPECT_EQ(central_rows("st-a"), 20);
  const int64_t total = local_rows();
  start(options("st-a", "relay_st_a"));
  ASSERT_TRUE(caught_up()) << describe();
  EXPECT_EQ(central_rows("st-a"), total);
  const RelayStatus s = relay_->status();
  EXPECT_EQ(s.redelivered_total, 20u);
  EXPECT_EQ(s.sent_total, static_cast<uint64_t>(total));
  EXPECT_EQ(central_redeliveries("st-a"), 20);
}

// 100 000 records in batches of 500: at least 200 batches (memory is one
// batch), every record once.
TEST_F(RelayTest, ALargeBacklogGoesInBoundedBatches) {
  register_station("st-a", "relay_st_a");
  constexpr int kRecords = 20000;  // 40 batches of 500; bench/ measures throughput
  {
    storage::Database db = open_db();
    ASSERT_TRUE(db.lab_bind("st-a").ok());
  }
  local_sql(fmt::format(
      "BEGIN; WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < {}) "
      "INSERT INTO events(run_id, t_s, wall_utc, kind, message) SELECT NULL, 0, "
      "'2026-11-27T00:00:00.000Z', 'info', 'backlog event ' || i || ' with some text to weigh' "
      "FROM n; COMMIT;",
      kRecords));
  ASSERT_EQ(local_rows(), kRecords);
  RelayOptions o = options("st-a", "relay_st_a");
  o.batch_records = 500;
  const auto t0 = std::chrono::steady_clock::now();
  start(o);
  ASSERT_TRUE(caught_up(300s)) << describe();
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const RelayStatus s = relay_->status();
  EXPECT_GE(s.batches_total, static_cast<uint64_t>(kRecords / 500));
  EXPECT_EQ(s.sent_total, static_cast<uint64_t>(kRecords));
  EXPECT_EQ(central_rows("st-a"), kRecords);
  EXPECT_EQ(local_sql("SELECT count(*) FROM outbox"), 0);
  std::printf("relayed %d records in %llu batches in %.2f s (%.0f records/s)\n", kRecords,
              static_cast<unsigned long long>(s.batches_total), wall_s, kRecords / wall_s);
}

TEST_F(RelayTest, StopDuringABackoffReturnsWithinOneSecond) {
  register_station("st-a", "relay_st_a");
  {
    storage::Database db = open_db();
    add_run(db, 1);
    ASSERT_TRUE(db.lab_bind("st-a").ok());
  }
  ASSERT_TRUE(cluster().stop());
  RelayOptions o = options("st-a", "relay_st_a");
  o.retry_min_s = 60;
  o.retry_max_s = 600;
  start(o);
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().state == "backoff"; }, 30s))
      << describe();
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().retry_in_s.has_value(); }, 5s));
  EXPECT_GT(*relay_->status().retry_in_s, 30.0);
  // The event is said before the state it announces is shown.
  ASSERT_FALSE(events().empty()) << describe();
  EXPECT_THAT(events().at(0), HasSubstr("lab: cannot reach")) << describe();
  const auto t0 = std::chrono::steady_clock::now();
  relay_->stop();
  EXPECT_LT(std::chrono::steady_clock::now() - t0, scaled(1s));
  EXPECT_EQ(relay_->status().state, "stopped");
  ASSERT_TRUE(cluster().start()) << cluster().log();
}

// A server that takes the TCP connection and never answers: the attempt
// is bounded by connect_timeout_s, and so is stop().
TEST_F(RelayTest, StopDuringAHungConnectIsBoundedByTheConnectTimeout) {
  {
    storage::Database db = open_db();
    add_run(db, 1);
    ASSERT_TRUE(db.lab_bind("st-a").ok());
  }
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  ASSERT_GE(fd, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof addr;
  ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  ASSERT_EQ(::listen(fd, 8), 0);  // never accepted: the kernel completes the handshake
  ASSERT_EQ(::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len), 0);
  RelayOptions o = options("st-a", "relay_st_a");
  o.conninfo = fmt::format("host=127.0.0.1 port={} dbname=lab user=nobody", ntohs(addr.sin_port));
  o.connect_timeout_s = 1;
  start(o);
  // The relay is in its connection attempt once the socket holds it.
  pollfd pending{fd, POLLIN, 0};
  ASSERT_TRUE(wait_for_condition([&] { return ::poll(&pending, 1, 0) == 1; }, 5s));
  EXPECT_EQ(relay_->status().state, "connecting");
  const auto t0 = std::chrono::steady_clock::now();
  relay_->stop();
  EXPECT_LT(std::chrono::steady_clock::now() - t0, scaled(2500ms));
  ::close(fd);
}

// An administrator's session holds a lock the batch needs, and no limit
// applies: stop() has the server cancel the batch (the backend stops
// waiting, the lock still held), returns at once, and the relay says what
// became of the batch. Before, stop() waited as long as the lock was held.
TEST_F(RelayTest, StopDuringALockWaitCancelsTheBatchAndSaysSo) {
  register_station("st-a", "relay_st_a");
  {
    storage::Database db = open_db();
    add_run(db, 5);
    ASSERT_TRUE(db.lab_bind("st-a").ok());
  }
  auto lock = lock_table("lab.relay_progress");
  RelayOptions o = options("st-a", "relay_st_a");
  o.statement_timeout_s = 600;
  o.lock_timeout_s = 600;
  start(o);
  ASSERT_TRUE(wait_for_condition(
      [&] { return backends("relay_st_a", "wait_event_type = 'Lock'") == 1; }, 30s, 10ms))
      << describe();
  const auto t0 = std::chrono::steady_clock::now();
  auto stopped = std::async(std::launch::async, [&] { relay_->stop(); });
  const bool prompt = stopped.wait_for(scaled(3s)) == std::future_status::ready;
  const double stop_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!prompt) lock->release();  // an unbounded stop() returns then: the test ends
  stopped.wait();
  ASSERT_TRUE(prompt) << "stop() waited for the lock: " << describe();
  std::printf("stop() during a lock wait returned in %.3f s\n", stop_s);
  // Cancelled by the server, not merely abandoned: the lock is still held,
  // and the relay's backend waits no more.
  EXPECT_TRUE(wait_for_condition([&] { return backends("relay_st_a", "state = 'active'") == 0; },
                                 5s, 10ms));
  const RelayStatus s = relay_->status();
  EXPECT_EQ(s.state, "stopped");
  EXPECT_THAT(s.last_error, HasSubstr("canceling statement due to user request"));
  EXPECT_EQ(events_with("lab: relay stopped during a batch of"), 1) << describe();
  EXPECT_EQ(events_with("the lab rolled it back, it is sent again at the next start"), 1)
      << describe();
  lock->release();
  EXPECT_EQ(central_rows("st-a"), 0);
  EXPECT_EQ(local_sql("SELECT count(*) FROM outbox"), local_rows()) << "nothing acknowledged";
}

// lock_timeout: a lock held longer fails the batch (55P03), a backoff said
// once; once the lock is gone the batch goes through.
TEST_F(RelayTest, ALockHeldPastLockTimeoutIsABackoffThenTheBatchGoesThrough) {
  register_station("st-a", "relay_st_a");
  {
    storage::Database db = open_db();
    add_run(db, 5);
    ASSERT_TRUE(db.lab_bind("st-a").ok());
  }
  auto lock = lock_table("lab.relay_progress");
  RelayOptions o = options("st-a", "relay_st_a");
  o.statement_timeout_s = 600;
  o.lock_timeout_s = 0.2;
  start(o);
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().errors_total >= 2; }, 10s))
      << describe();
  const RelayStatus s = relay_->status();
  EXPECT_THAT(s.last_error, HasSubstr("lock timeout"));
  EXPECT_THAT(s.last_error, HasSubstr("55P03"));
  EXPECT_EQ(s.sent_total, 0u);
  EXPECT_EQ(events_with("lab: the lab database did not take a batch of"), 1) << describe();
  lock->release();
  ASSERT_TRUE(caught_up()) << describe();
  EXPECT_EQ(central_rows("st-a"), local_rows());
}

// statement_timeout: a batch that takes longer (here: waiting for a lock
// with no lock_timeout to speak of) is cancelled by the server (57014).
TEST_F(RelayTest, ABatchPastStatementTimeoutIsCancelledByTheServerAndRetried) {
  register_station("st-a", "relay_st_a");
  {
    storage::Database db = open_db();
    add_run(db, 5);
    ASSERT_TRUE(db.lab_bind("st-a").ok());
  }
  auto lock = lock_table("lab.relay_progress");
  RelayOptions o = options("st-a", "relay_st_a");
  o.statement_timeout_s = 0.3;
  o.lock_timeout_s = 600;
  start(o);
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().errors_total >= 2; }, 10s))
      << describe();
  EXPECT_THAT(relay_->status().last_error, HasSubstr("statement timeout"));
  EXPECT_THAT(relay_->status().last_error, HasSubstr("57014"));
  EXPECT_EQ(central_rows("st-a"), 0);
  lock->release();
  ASSERT_TRUE(caught_up()) << describe();
  EXPECT_EQ(central_rows("st-a"), local_rows());
}

// The station id is checked at connect: with nothing to send, a wrong id
// and an unregistered one are refused all the same, never "connected"
// until a first batch; a registration fixed is taken at the next retry.
TEST_F(RelayTest, AWrongOrUnregisteredIdIsRefusedAtConnectWithNothingToSend) {
  register_station("st-a", "relay_st_a");
  register_station("st-b", "relay_st_b");
  {
    storage::Database db = open_db();
    ASSERT_TRUE(db.lab_bind("st-b").ok());
  }
  std::set<std::string> seen;
  const auto reaches = [&](const std::string& state) {
    return wait_for_condition(
        [&] {
          seen.insert(relay_->status().state);
          return relay_->status().state == state;
        },
        10s, 1ms);
  };
  start(options("st-b", "relay_st_a"));
  ASSERT_TRUE(reaches("refused")) << describe();
  EXPECT_EQ(seen.count("connected"), 0u) << describe();
  EXPECT_THAT(relay_->status().last_error,
              HasSubstr("station id 'st-b' for role 'relay_st_a': the id is registered to role "
                        "'relay_st_b'"));
  EXPECT_EQ(events_with("lab: connected"), 0) << describe();
  EXPECT_EQ(events_with("refused"), 1) << describe();
  relay_.reset();

  ASSERT_EQ(cluster().admin_exec("CREATE ROLE relay_st_d LOGIN", dbname_), "");
  ASSERT_EQ(cluster().admin_exec("GRANT gyrotherm_station TO relay_st_d", dbname_), "");
  db_path_ = (dir_ / "station-d.db").string();
  {
    storage::Database db = open_db();
    ASSERT_TRUE(db.lab_bind("st-d").ok());
  }
  seen.clear();
  start(options("st-d", "relay_st_d"));
  ASSERT_TRUE(reaches("refused")) << describe();
  EXPECT_EQ(seen.count("connected"), 0u) << describe();
  EXPECT_THAT(relay_->status().last_error, HasSubstr("is not registered in lab.stations"));
  register_station("st-d", "relay_st_d");
  ASSERT_TRUE(reaches("connected")) << describe();
  EXPECT_EQ(relay_->status().last_error, "");
}

// A station database re-created (or restored) numbers its outbox from 1
// again: records of keys the lab already holds at a higher seq are
// ignored by the lab. The relay counts them and says so, once for a run
// of such batches.
TEST_F(RelayTest, RecordsTheLabHoldsNewerVersionsOfAreCountedAndSaidOnce) {
  register_station("st-a", "relay_st_a");
  {
    storage::Database db = open_db();
    for (int i = 0; i < 5; ++i) add_event(db, std::nullopt, fmt::format("first life {}", i));
    ASSERT_TRUE(db.lab_bind("st-a").ok());
  }
  local_sql("UPDATE events SET message = message || ' (edited)'");  // outbox seq 6 to 10
  start(options("st-a", "relay_st_a"));
  ASSERT_TRUE(caught_up()) << describe();
  EXPECT_EQ(relay_->status().stale_total, 0u);
  relay_.reset();

  db_path_ = (dir_ / "recreated.db").string();
  {
    storage::Database db = open_db();
    for (int i = 0; i < 5; ++i) add_event(db, std::nullopt, fmt::format("second life {}", i));
    ASSERT_TRUE(db.lab_bind("st-a").ok());  // outbox seq 1 to 5, the same event ids
  }
  RelayOptions o = options("st-a", "relay_st_a");
  o.batch_records = 2;  // three stale batches in a row
  start(o);
  ASSERT_TRUE(caught_up()) << describe();
  const RelayStatus s = relay_->status();
  EXPECT_EQ(s.stale_total, 5u);
  EXPECT_GE(s.batches_total, 3u);
  EXPECT_EQ(events_with("lab: the lab database holds newer versions of"), 1) << describe();
  EXPECT_EQ(events_with("re-created or restored"), 1) << describe();
  EXPECT_EQ(central("SELECT count(*) FROM lab.records WHERE station_id = $1 AND kind = 'event' "
                    "AND payload->>'message' LIKE '%(edited)'",
                    "st-a"),
            5)
      << "the lab kept its newer versions";
}

// relay = false: nothing is sent; the status still counts the outbox.
TEST_F(RelayTest, DisabledCountsTheOutboxAndNeverConnects) {
  {
    storage::Database db = open_db();
    add_run(db, 4);
    ASSERT_TRUE(db.lab_bind("st-a").ok());
  }
  RelayOptions o = options("st-a", "relay_st_a");
  o.conninfo.clear();
  start(o);
  RelayStatus s = relay_->status();
  EXPECT_EQ(s.state, "disabled");
  EXPECT_EQ(s.server, "");
  EXPECT_EQ(s.pending, local_rows());
  EXPECT_GT(s.pending_bytes, 0);
  {
    storage::Database db = open_db();
    add_event(db, std::nullopt, "one more");
  }
  ASSERT_TRUE(wait_for_condition([&] { return relay_->status().pending == local_rows(); }, 10s))
      << describe();
  s = relay_->status();
  EXPECT_EQ(s.state, "disabled");
  EXPECT_EQ(s.sent_total, 0u);
  EXPECT_EQ(s.errors_total, 0u);
  EXPECT_TRUE(events().empty()) << describe();
  EXPECT_EQ(central_rows("st-a"), 0);
}

TEST_F(RelayTest, CreateChecksTheOptionsAndTheBinding) {
  RelayOptions o = options("st-a", "relay_st_a");
  {
    storage::Database db = open_db();
    add_run(db, 1);
  }
  auto r = Relay::create(o);
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(r.error().message, HasSubstr("is not bound to a lab station"));
  {
    storage::Database db = open_db();
    ASSERT_TRUE(db.lab_bind("st-z").ok());
  }
  r = Relay::create(o);
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(r.error().message, HasSubstr("belongs to lab station \"st-z\", not \"st-a\""));
  EXPECT_THAT(r.error().message, HasSubstr(db_path_));
  o.station_id = "no spaces";
  EXPECT_FALSE(Relay::create(o).ok());
  o = options("st-z", "relay_st_a");
  o.retry_max_s = 0.01;
  EXPECT_THAT(Relay::create(o).error().message, HasSubstr("retry_max_s"));
  o = options("st-z", "relay_st_a");
  o.lock_timeout_s = 0;
  EXPECT_THAT(Relay::create(o).error().message, HasSubstr("lock_timeout_s"));
  o = options("st-z", "relay_st_a");
  o.statement_timeout_s = -1;
  EXPECT_THAT(Relay::create(o).error().message, HasSubstr("statement_timeout_s"));
  // A connection string libpq cannot parse stops the start, naming the
  // unknown option (a keyword) and never a value.
  o = options("st-z", "relay_st_a");
  o.conninfo += " sslmod=verify-full password=pw-secret-1";
  auto malformed = Relay::create(o);
  ASSERT_FALSE(malformed.ok());
  EXPECT_THAT(malformed.error().message, HasSubstr("invalid connection option \"sslmod\""));
  EXPECT_EQ(malformed.error().message.find("pw-secret-1"), std::string::npos);
  o = options("st-z", "relay_st_a");
  EXPECT_TRUE(Relay::create(o).ok());
}

// No server needed: the options alone.
TEST(RelayOptions, Validity) {
  RelayOptions o;
  std::string why;
  EXPECT_FALSE(o.is_valid(&why)) << "a station id and a database are required";
  EXPECT_THAT(why, HasSubstr("station_id"));
  o.station_id = "st-a";
  EXPECT_FALSE(o.is_valid(&why));
  EXPECT_THAT(why, HasSubstr("db_path"));
  o.db_path = "station.db";
  EXPECT_TRUE(o.is_valid(&why)) << "the other defaults are valid: " << why;
  const RelayOptions good = o;
  const std::vector<std::pair<std::function<void(RelayOptions&)>, std::string>> bad = {
      {[](RelayOptions& r) { r.station_id = "no spaces"; }, "station_id"},
      {[](RelayOptions& r) { r.batch_records = 0; }, "batch_records = 0 must be >= 1"},
      {[](RelayOptions& r) { r.batch_bytes = 0; }, "batch_bytes"},
      {[](RelayOptions& r) { r.poll_s = 0; }, "poll_s"},
      {[](RelayOptions& r) { r.retry_min_s = -1; }, "retry_min_s"},
      {[](RelayOptions& r) { r.retry_max_s = r.retry_min_s / 2; }, "retry_max_s"},
      {[](RelayOptions& r) { r.connect_timeout_s = std::nan(""); }, "connect_timeout_s"},
      {[](RelayOptions& r) { r.statement_timeout_s = -1; }, "statement_timeout_s"},
      {[](RelayOptions& r) { r.lock_timeout_s = std::numeric_limits<double>::infinity(); },
       "lock_timeout_s"},
      {[](RelayOptions& r) { r.conninfo = "host=lab sslmod=x password=pw-secret-2"; }, "conninfo"},
  };
  for (const auto& [spoil, field] : bad) {
    o = good;
    spoil(o);
    why.clear();
    EXPECT_FALSE(o.is_valid(&why)) << field;
    EXPECT_THAT(why, HasSubstr(field));
    EXPECT_EQ(why.find("pw-secret-2"), std::string::npos) << why;
    EXPECT_FALSE(o.is_valid(nullptr)) << field;
  }
}

}  // namespace
}  // namespace gyrotherm::lab
