// PgConnection against a private PostgreSQL cluster: rows as text, NULLs,
// parameters, errors classified transient (server gone) or permanent
// (server refuses), SQLSTATEs kept, no password in any message; every call
// bounded (statement and lock timeouts, a server that stops answering) and
// interruptible from another thread.
#include "gyrotherm/lab/pg.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>

#include <chrono>
#include <future>
#include <string>

#include "support/pg_cluster.h"
#include "test_time.h"

namespace gyrotherm::lab {
namespace {

using namespace std::chrono_literals;
using ::testing::HasSubstr;
using testing::PgCluster;
using testing::PgClusterTest;
using testing::scaled;
using testing::wait_for_condition;

class PgTest : public PgClusterTest {
 protected:
  static double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
};

TEST_F(PgTest, RowsComeBackAsTextWithNullsAsNullopt) {
  auto pg = PgConnection::connect(conninfo());
  ASSERT_TRUE(pg.ok()) << pg.error().message;
  EXPECT_TRUE(pg->ok());
  auto rows = pg->exec(
      "SELECT 1 AS one, NULL::text AS nothing, 'a b' AS text UNION ALL "
      "SELECT 2, 'x', ''");
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  EXPECT_EQ(rows->columns, (std::vector<std::string>{"one", "nothing", "text"}));
  ASSERT_EQ(rows->rows.size(), 2u);
  EXPECT_EQ(rows->rows[0][0], "1");
  EXPECT_EQ(rows->rows[0][1], std::nullopt);
  EXPECT_EQ(rows->rows[0][2], "a b");
  EXPECT_EQ(rows->rows[1][1], "x");
  EXPECT_EQ(rows->rows[1][2], "");
  EXPECT_EQ(pg->last_sqlstate(), "");
}

TEST_F(PgTest, ParametersAreTextAndNullopt) {
  auto pg = PgConnection::connect(conninfo());
  ASSERT_TRUE(pg.ok()) << pg.error().message;
  auto rows = pg->exec_params("SELECT $1::int + 1, $2::text IS NULL, $3::text",
                              {std::string("41"), std::nullopt, std::string("it's; DROP")});
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->rows.size(), 1u);
  EXPECT_EQ(rows->rows[0][0], "42");
  EXPECT_EQ(rows->rows[0][1], "t");
  EXPECT_EQ(rows->rows[0][2], "it's; DROP");
}

TEST_F(PgTest, ServerRefusalsArePermanentWithTheirSqlstate) {
  auto pg = PgConnection::connect(conninfo());
  ASSERT_TRUE(pg.ok()) << pg.error().message;
  auto bad = pg->exec("SELEC 1");
  ASSERT_FALSE(bad.ok());
  EXPECT_FALSE(bad.error().transient);
  EXPECT_EQ(pg->last_sqlstate(), "42601");
  EXPECT_NE(bad.error().message.find("syntax error"), std::string::npos) << bad.error().message;
  EXPECT_NE(bad.error().message.find(std::to_string(cluster().port())), std::string::npos)
      << "the message names the server: " << bad.error().message;

  auto fk = pg->exec(
      "CREATE TABLE p(id int PRIMARY KEY); CREATE TABLE c(p int REFERENCES p);"
      "INSERT INTO c VALUES (1)");
  ASSERT_FALSE(fk.ok());
  EXPECT_FALSE(fk.error().transient);
  EXPECT_EQ(pg->last_sqlstate(), "23503");

  // Still usable after an error; a success clears the SQLSTATE.
  ASSERT_TRUE(pg->exec("SELECT 1").ok());
  EXPECT_EQ(pg->last_sqlstate(), "");
}

TEST_F(PgTest, NoServerIsTransient) {
  // A port nobody listens on: the cluster is stopped.
  const std::string info = conninfo();
  ASSERT_TRUE(cluster().stop());
  auto pg = PgConnection::connect(info, 2);
  ASSERT_FALSE(pg.ok());
  EXPECT_TRUE(pg.error().transient);
  EXPECT_NE(pg.error().message.find("127.0.0.1:" + std::to_string(cluster().port())),
            std::string::npos)
      << pg.error().message;
  ASSERT_TRUE(cluster().start()) << cluster().log();
  EXPECT_TRUE(PgConnection::connect(info).ok());
}

TEST_F(PgTest, LostConnectionIsTransientAndANewOneWorksAfterRestart) {
  auto pg = PgConnection::connect(conninfo());
  ASSERT_TRUE(pg.ok()) << pg.error().message;
  ASSERT_TRUE(pg->exec("SELECT 1").ok());
  ASSERT_TRUE(cluster().stop());
  auto lost = pg->exec("SELECT 1");
  ASSERT_FALSE(lost.ok());
  EXPECT_TRUE(lost.error().transient) << lost.error().message;
  EXPECT_FALSE(pg->ok());
  auto again = pg->exec_params("SELECT $1::int", {std::string("1")});
  ASSERT_FALSE(again.ok());
  EXPECT_TRUE(again.error().transient) << again.error().message;

  ASSERT_TRUE(cluster().start()) << cluster().log();
  auto fresh = PgConnection::connect(conninfo());
  ASSERT_TRUE(fresh.ok()) << fresh.error().message;
  EXPECT_TRUE(fresh->exec("SELECT 1").ok());
}

TEST_F(PgTest, TerminatedBackendIsTransient) {
  auto pg = PgConnection::connect(conninfo());
  ASSERT_TRUE(pg.ok()) << pg.error().message;
  auto pid = pg->exec("SELECT pg_backend_pid()");
  ASSERT_TRUE(pid.ok());
  auto admin = PgConnection::connect(conninfo());
  ASSERT_TRUE(admin.ok());
  ASSERT_TRUE(admin->exec_params("SELECT pg_terminate_backend($1::int)", {*pid->rows[0][0]}).ok());
  auto lost = pg->exec("SELECT 1");
  ASSERT_FALSE(lost.ok());
  EXPECT_TRUE(lost.error().transient) << lost.error().message;
}

TEST_F(PgTest, PasswordNeverInMessages) {
  const std::string secret = "Sup3r-Secret-pw";
  // Accepted (trust ignores it), then errors of every kind.
  auto pg = PgConnection::connect(conninfo() + " password=" + secret);
  ASSERT_TRUE(pg.ok()) << pg.error().message;
  EXPECT_EQ(pg->server().find(secret), std::string::npos);
  EXPECT_NE(pg->server().find("127.0.0.1:" + std::to_string(cluster().port())), std::string::npos)
      << pg->server();
  EXPECT_NE(pg->server().find(dbname_), std::string::npos) << pg->server();
  EXPECT_NE(pg->server().find(PgCluster::kAdmin), std::string::npos) << pg->server();
  auto bad = pg->exec("SELECT nonsense");
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().message.find(secret), std::string::npos) << bad.error().message;

  const std::string port = std::to_string(cluster().port());
  const std::vector<std::string> failing = {
      // unknown database, unknown role
      "host=127.0.0.1 port=" + port + " dbname=nowhere user=gyrotherm_admin password=" + secret,
      "host=127.0.0.1 port=" + port + " dbname=postgres user=nobody_here password='" + secret + "'",
      "postgresql://gyrotherm_admin:" + secret + "@127.0.0.1:" + port + "/nowhere",
      // malformed: libpq's parse errors quote the string they choke on
      "postgresql://gyrotherm_admin:" + secret + "@[::1:" + port + "/x",
      "host=127.0.0.1 password=" + secret + " bogus_option=1",
      "host=127.0.0.1 password='" + secret,
      "postgresql://u:" + secret + "@127.0.0.1/db?sslmode=require&nonsense=" + secret,
  };
  for (const auto& info : failing) {
    auto c = PgConnection::connect(info, 2);
    ASSERT_FALSE(c.ok()) << info;
    EXPECT_EQ(c.error().message.find(secret), std::string::npos) << c.error().message;
    EXPECT_FALSE(c.error().message.empty());
    EXPECT_EQ(redact_conninfo(info).find(secret), std::string::npos) << redact_conninfo(info);
  }
  // The stopped server: a transient error, still without the password.
  ASSERT_TRUE(cluster().stop());
  auto down = PgConnection::connect(conninfo() + " password=" + secret, 2);
  ASSERT_FALSE(down.ok());
  EXPECT_TRUE(down.error().transient);
  EXPECT_EQ(down.error().message.find(secret), std::string::npos) << down.error().message;
}

TEST_F(PgTest, LimitBoundsStatementsAndLockWaits) {
  auto pg = PgConnection::connect(conninfo());
  ASSERT_TRUE(pg.ok()) << pg.error().message;
  ASSERT_TRUE(pg->limit(0.2, 0.1).ok());
  auto set =
      pg->exec("SELECT current_setting('statement_timeout'), current_setting('lock_timeout')");
  ASSERT_TRUE(set.ok()) << set.error().message;
  EXPECT_EQ(set->rows[0][0], "200ms");
  EXPECT_EQ(set->rows[0][1], "100ms");

  auto t0 = std::chrono::steady_clock::now();
  auto slow = pg->exec("SELECT pg_sleep(30)");
  ASSERT_FALSE(slow.ok());
  EXPECT_LT(seconds_since(t0), scaled(5s).count() / 1000.0);
  EXPECT_TRUE(slow.error().transient);
  EXPECT_EQ(pg->last_sqlstate(), "57014");
  EXPECT_THAT(slow.error().message, HasSubstr("statement timeout"));

  auto admin = PgConnection::connect(conninfo());
  ASSERT_TRUE(admin.ok()) << admin.error().message;
  ASSERT_TRUE(admin->exec("CREATE TABLE held(x int)").ok());
  ASSERT_TRUE(admin->exec("BEGIN; LOCK TABLE held").ok());
  auto waiting = pg->exec("SELECT * FROM held");
  ASSERT_FALSE(waiting.ok());
  EXPECT_TRUE(waiting.error().transient);
  EXPECT_EQ(pg->last_sqlstate(), "55P03");
  EXPECT_THAT(waiting.error().message, HasSubstr("lock timeout"));
  EXPECT_TRUE(pg->exec("SELECT 1").ok()) << "still usable";
}

// A server that takes the statement and never answers (its backend
// stopped: a VM frozen, a disk hung): the client gives the connection up
// after statement_timeout + the grace, since the server's own timeout
// cannot fire.
TEST_F(PgTest, AServerThatStopsAnsweringIsGivenUp) {
  auto pg = PgConnection::connect(conninfo());
  ASSERT_TRUE(pg.ok()) << pg.error().message;
  auto pid = pg->exec("SELECT pg_backend_pid()");
  ASSERT_TRUE(pid.ok()) << pid.error().message;
  const pid_t backend = std::stoi(*pid->rows[0][0]);
  ASSERT_TRUE(pg->limit(0.3, 0.3, 0.3).ok());
  ASSERT_EQ(::kill(backend, SIGSTOP), 0);
  const auto t0 = std::chrono::steady_clock::now();
  auto lost = pg->exec("SELECT 1");
  const double waited_s = seconds_since(t0);
  ::kill(backend, SIGCONT);
  ASSERT_FALSE(lost.ok());
  EXPECT_TRUE(lost.error().transient);
  EXPECT_THAT(lost.error().message, HasSubstr("no answer within 0.6 s"));
  EXPECT_GE(waited_s, 0.5);
  EXPECT_LT(waited_s, scaled(3s).count() / 1000.0);
  EXPECT_FALSE(pg->ok()) << "given up";
}

// Another thread interrupts a call in progress: it has the server cancel
// the statement (57014, "user request") and the call returns at once;
// later calls fail at once, unsent.
TEST_F(PgTest, AnInterruptCancelsTheCallInProgressFromAnotherThread) {
  auto pg = PgConnection::connect(conninfo());
  ASSERT_TRUE(pg.ok()) << pg.error().message;
  auto interrupt = std::make_shared<PgInterrupt>();
  pg->set_interrupt(interrupt);
  EXPECT_EQ(interrupt->cancel_running(), "") << "nothing running: nothing to do";
  auto call = std::async(std::launch::async, [&] { return pg->exec("SELECT pg_sleep(60)"); });
  ASSERT_TRUE(wait_for_condition([&] { return interrupt->busy(); }, 5s));
  // The statement is running on the server before it is cancelled.
  auto admin = PgConnection::connect(conninfo());
  ASSERT_TRUE(admin.ok()) << admin.error().message;
  ASSERT_TRUE(wait_for_condition(
      [&] {
        auto n = admin->exec(
            "SELECT count(*) FROM pg_stat_activity WHERE query = 'SELECT pg_sleep(60)' AND "
            "state = 'active'");
        return n.ok() && n->rows[0][0] == "1";
      },
      5s, 5ms));
  const auto t0 = std::chrono::steady_clock::now();
  interrupt->trigger();
  EXPECT_EQ(interrupt->cancel_running(), "");
  ASSERT_EQ(call.wait_for(scaled(3s)), std::future_status::ready);
  EXPECT_LT(seconds_since(t0), scaled(3s).count() / 1000.0);
  auto cancelled = call.get();
  ASSERT_FALSE(cancelled.ok());
  EXPECT_THAT(cancelled.error().message, HasSubstr("canceling statement due to user request"));
  EXPECT_EQ(pg->last_sqlstate(), "57014");
  auto later = pg->exec("SELECT 1");
  ASSERT_FALSE(later.ok());
  EXPECT_THAT(later.error().message, HasSubstr("not sent: stopping"));
}

// libpq's parse errors quote what they choke on; an unknown option's name
// is shown (it is a keyword, and the fix), values never are.
TEST_F(PgTest, AnUnknownOptionIsNamedAndValuesAreNot) {
  const std::string secret = "Sup3r-Secret-pw";
  auto c = PgConnection::connect("host=127.0.0.1 password=" + secret + " sslmod=verify-full", 2);
  ASSERT_FALSE(c.ok());
  EXPECT_FALSE(c.error().transient);
  EXPECT_THAT(c.error().message, HasSubstr("invalid connection option \"sslmod\""));
  EXPECT_EQ(c.error().message.find(secret), std::string::npos) << c.error().message;
  c = PgConnection::connect("postgresql://u:" + secret + "@127.0.0.1/db?sslmod=require", 2);
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.error().message, HasSubstr("invalid URI query parameter: \"sslmod\""));
  EXPECT_EQ(c.error().message.find(secret), std::string::npos) << c.error().message;
  EXPECT_EQ(conninfo_error("host=x port=1"), std::nullopt);
  // A value is never shown, even where an option's name would be.
  auto v = conninfo_error("host=x " + secret);
  ASSERT_TRUE(v.has_value());
  EXPECT_EQ(v->find(secret), std::string::npos) << *v;
}

TEST(RedactConninfo, DropsPasswordsKeepsTheRest) {
  EXPECT_EQ(redact_conninfo("host=db.lab port=5433 dbname=lab user=st01 password=s3cret "
                            "sslmode=verify-full"),
            "user=st01 dbname=lab host=db.lab port=5433 sslmode=verify-full");
  EXPECT_EQ(redact_conninfo("postgresql://st01:s3cret@db.lab:5433/lab?sslmode=require"),
            "user=st01 dbname=lab host=db.lab port=5433 sslmode=require");
  const auto quoted = redact_conninfo("host=db password='with space' sslpassword=k3y user=a");
  EXPECT_EQ(quoted, "user=a host=db");
  EXPECT_EQ(redact_conninfo("host='/run/my dir' dbname=lab"), "dbname=lab host='/run/my dir'");
  EXPECT_EQ(redact_conninfo("password='unterminated"), "(malformed connection string)");
}

}  // namespace
}  // namespace gyrotherm::lab
