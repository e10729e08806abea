// PgConnection against a private PostgreSQL cluster: rows as text, NULLs,
// parameters, errors classified transient (server gone) or permanent
// (server refuses), SQLSTATEs kept, and no password in any message.
#include "gyrotherm/lab/pg.h"

#include <gtest/gtest.h>

#include <string>

#include "support/pg_cluster.h"

namespace gyrotherm::lab {
namespace {

using testing::PgCluster;
using testing::PgClusterTest;

class PgTest : public PgClusterTest {};

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
