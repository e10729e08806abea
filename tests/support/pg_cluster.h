// A private PostgreSQL cluster for tests of the lab database.
//
// PgCluster runs Debian's postgresql-15 binaries (initdb, pg_ctl; the
// directory is /usr/lib/postgresql/15/bin, or GYROTHERM_PG_BINDIR) on a
// fresh data directory under a temp directory: listening on 127.0.0.1 and
// a free port, its unix socket in the temp directory, trust authentication,
// superuser gyrotherm_admin, durability off (a test cluster dies with the
// test). PostgreSQL refuses to run as root: when the test runs as root the
// temp directory is given to `nobody` and every server command runs through
// `runuser -u nobody --`. pg_ctl's -w waits (with a deadline) until the
// server accepts connections; nothing sleeps and hopes. The destructor
// stops the server (`-m immediate`) and removes the directory.
//
// When the binaries are missing, tests skip with the reason, unless
// GYROTHERM_REQUIRE_POSTGRES=1 (CI sets it): then they fail. Any other
// start-up failure fails the test with the server's log.
//
// PgClusterTest is the usual fixture: one cluster per test suite (started
// in SetUpTestSuite), a fresh database per test (CREATE DATABASE, named
// after the test), conninfo(user) for it.
#pragma once

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <libpq-fe.h>
#include <netinet/in.h>
#include <pwd.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cctype>
#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "test_time.h"

namespace gyrotherm::testing {

// GYROTHERM_REQUIRE_POSTGRES=1: a missing PostgreSQL fails instead of skipping.
inline bool postgres_required() {
  const char* v = std::getenv("GYROTHERM_REQUIRE_POSTGRES");
  return v && std::string(v) == "1";
}

inline std::filesystem::path postgres_bindir() {
  const char* v = std::getenv("GYROTHERM_PG_BINDIR");
  return v && *v ? std::filesystem::path(v) : std::filesystem::path("/usr/lib/postgresql/15/bin");
}

// Skips (or, with GYROTHERM_REQUIRE_POSTGRES=1, fails) the current test
// with `why`; for SetUp and test bodies.
#define GYROTHERM_PG_SKIP_OR_FAIL(why)                                           \
  do {                                                                           \
    if (::gyrotherm::testing::postgres_required()) {                             \
      FAIL() << (why) << " (GYROTHERM_REQUIRE_POSTGRES=1: PostgreSQL required)"; \
    } else {                                                                     \
      GTEST_SKIP() << (why);                                                     \
    }                                                                            \
  } while (0)

class PgCluster {
 public:
  static constexpr const char* kAdmin = "gyrotherm_admin";

  // Creates and starts a cluster. nullptr on failure, with *why (and
  // *missing = true when the binaries are not installed).
  static std::unique_ptr<PgCluster> create(std::string* why, bool* missing) {
    *missing = false;
    const auto bin = postgres_bindir();
    for (const char* tool : {"initdb", "pg_ctl", "postgres"}) {
      if (::access((bin / tool).c_str(), X_OK) != 0) {
        *missing = true;
        *why = "PostgreSQL server binaries not found: " + (bin / tool).string() +
               " (apt-get install postgresql-15, or set GYROTHERM_PG_BINDIR)";
        return nullptr;
      }
    }
    std::unique_ptr<PgCluster> cluster(new PgCluster(bin));
    if (!cluster->init(why)) return nullptr;
    return cluster;
  }

  PgCluster(const PgCluster&) = delete;
  PgCluster& operator=(const PgCluster&) = delete;

  ~PgCluster() {
    if (running_) {
      run_as_server(
          {(bin_ / "pg_ctl").string(), "-D", data_.string(), "-m", "immediate", "-w", "stop"});
    }
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }

  // pg_ctl stop -m fast: clients are disconnected (57P01), the server is
  // gone when it returns. For outage tests.
  bool stop() {
    const bool ok = run_as_server({(bin_ / "pg_ctl").string(), "-D", data_.string(), "-m", "fast",
                                   "-w", "stop"}) == 0;
    if (ok) running_ = false;
    return ok;
  }
  // Starts it again on the same port; returns when it accepts connections.
  bool start() {
    const bool ok =
        run_as_server({(bin_ / "pg_ctl").string(), "-D", data_.string(), "-l",
                       (dir_ / "server.log").string(), "-w", "-t",
                       std::to_string(static_cast<int>(60 * time_factor())), "start"}) == 0;
    if (ok) running_ = true;
    return ok;
  }
  bool running() const { return running_; }

  int port() const { return port_; }
  const std::filesystem::path& dir() const { return dir_; }
  std::filesystem::path socket_dir() const { return dir_; }

  // A libpq conninfo for `user` on `dbname` over TCP (no password: trust).
  std::string conninfo(const std::string& user = kAdmin,
                       const std::string& dbname = "postgres") const {
    return "host=127.0.0.1 port=" + std::to_string(port_) + " dbname=" + dbname + " user=" + user +
           " connect_timeout=10";
  }

  // Runs `sql` as the superuser on `dbname`; "" when it worked, else the
  // error.
  std::string admin_exec(const std::string& sql, const std::string& dbname = "postgres") const {
    PGconn* conn = PQconnectdb(conninfo(kAdmin, dbname).c_str());
    std::string error;
    if (PQstatus(conn) != CONNECTION_OK) {
      error = PQerrorMessage(conn);
    } else {
      PGresult* res = PQexec(conn, sql.c_str());
      const auto st = PQresultStatus(res);
      if (st != PGRES_COMMAND_OK && st != PGRES_TUPLES_OK) error = PQresultErrorMessage(res);
      PQclear(res);
    }
    PQfinish(conn);
    return error.empty() ? "" : error + " (" + sql + ")";
  }

  // CREATE DATABASE `name` (a plain identifier); "" or the error.
  std::string create_database(const std::string& name) const {
    return admin_exec("CREATE DATABASE \"" + name + "\"");
  }

  // The server's log (for failure messages).
  std::string log() const {
    std::ifstream in(dir_ / "server.log");
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }

 private:
  explicit PgCluster(std::filesystem::path bin) : bin_(std::move(bin)) {}

  static bool as_root() { return ::geteuid() == 0; }

  static std::string shell_quote(const std::string& s) {
    std::string out = "'";
    for (char c : s) {
      if (c == '\'') {
        out += "'\\''";
      } else {
        out += c;
      }
    }
    return out + "'";
  }

  // Runs argv (as `nobody` when root), its output appended to
  // commands.log; the exit status.
  int run_as_server(const std::vector<std::string>& argv) const {
    std::string cmd;
    if (as_root()) cmd = "runuser -u nobody -- ";
    for (const auto& a : argv) cmd += shell_quote(a) + " ";
    cmd += ">> " + shell_quote((dir_ / "commands.log").string()) + " 2>&1 </dev/null";
    const int rc = std::system(cmd.c_str());
    return rc == -1 ? -1 : WEXITSTATUS(rc);
  }

  static int free_port() {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0) return 0;
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    addr.sin_port = 0;
    socklen_t len = sizeof addr;
    int port = 0;
    if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0 &&
        ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len) == 0) {
      port = ntohs(addr.sin_port);
    }
    ::close(fd);
    return port;
  }

  std::string file_text(const std::filesystem::path& p) const {
    std::ifstream in(p);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }

  // Clusters of test processes that died without their destructor (a
  // timeout's kill, a crash) would run on: stopped and removed here. A
  // directory without owner.pid is still being set up by a live process.
  void reap_orphans(const std::filesystem::path& base) const {
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator(base, ec)) {
      const std::string name = entry.path().filename().string();
      if (name.rfind("gyrotherm-pg-", 0) != 0 || entry.path() == dir_) continue;
      std::ifstream in(entry.path() / "owner.pid");
      long pid = 0;
      if (!(in >> pid) || pid <= 0) continue;
      if (::kill(static_cast<pid_t>(pid), 0) == 0 || errno != ESRCH) continue;
      std::string cmd = as_root() ? "runuser -u nobody -- " : "";
      cmd += shell_quote((bin_ / "pg_ctl").string()) + " -D " +
             shell_quote((entry.path() / "data").string()) +
             " -m immediate -w stop >/dev/null 2>&1 </dev/null";
      if (std::system(cmd.c_str()) == -1) continue;
      std::filesystem::remove_all(entry.path(), ec);
    }
  }

  bool init(std::string* why) {
    // As root, TMPDIR may be a directory `nobody` cannot enter: /tmp is.
    const auto base =
        as_root() ? std::filesystem::path("/tmp") : std::filesystem::temp_directory_path();
    std::string templ = (base / "gyrotherm-pg-XXXXXX").string();
    if (!::mkdtemp(templ.data())) {
      *why = "cannot create a temp directory under " + base.string();
      return false;
    }
    dir_ = templ;
    data_ = dir_ / "data";
    std::ofstream(dir_ / "owner.pid") << ::getpid() << "\n";
    reap_orphans(base);
    if (as_root()) {
      const passwd* nobody = ::getpwnam("nobody");
      if (!nobody || ::chown(dir_.c_str(), nobody->pw_uid, nobody->pw_gid) != 0) {
        *why = "running as root, and cannot give " + dir_.string() + " to user nobody";
        return false;
      }
    }
    if (run_as_server({(bin_ / "initdb").string(), "-D", data_.string(), "-U", kAdmin,
                       "--auth=trust", "-E", "UTF8", "--locale=C", "--no-sync"}) != 0) {
      *why = "initdb failed: " + file_text(dir_ / "commands.log");
      return false;
    }
    // A free port can be taken between the probe and the server's bind:
    // try a few.
    for (int attempt = 0; attempt < 5; ++attempt) {
      port_ = free_port();
      {
        std::ofstream conf(data_ / "postgresql.conf", std::ios::app);
        conf << "\n# gyrotherm test cluster\n"
             << "listen_addresses = '127.0.0.1'\n"
             << "port = " << port_ << "\n"
             << "unix_socket_directories = '" << dir_.string() << "'\n"
             << "fsync = off\nsynchronous_commit = off\nfull_page_writes = off\n"
             << "shared_buffers = 16MB\nmax_connections = 40\n";
        if (!conf) {
          *why = "cannot write " + (data_ / "postgresql.conf").string();
          return false;
        }
      }
      if (start()) return true;
    }
    *why = "pg_ctl start failed on 127.0.0.1: " + file_text(dir_ / "commands.log") +
           "\nserver log:\n" + log();
    return false;
  }

  std::filesystem::path bin_;
  std::filesystem::path dir_;
  std::filesystem::path data_;
  int port_ = 0;
  bool running_ = false;
};

// One cluster per test suite, one fresh database per test.
class PgClusterTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    bool missing = false;
    std::string why;
    shared_cluster() = PgCluster::create(&why, &missing);
    shared_why() = why;
    shared_missing() = missing;
  }
  static void TearDownTestSuite() { shared_cluster().reset(); }

  void SetUp() override {
    if (!shared_cluster()) {
      if (shared_missing()) GYROTHERM_PG_SKIP_OR_FAIL(shared_why());
      FAIL() << "cannot start a PostgreSQL test cluster: " << shared_why();
    }
    // A test that stopped the server leaves it stopped: start it again.
    if (!cluster().running()) {
      ASSERT_TRUE(cluster().start()) << cluster().log();
    }
    static std::atomic<int> counter{0};
    std::string name = "t";
    for (char c : std::string(::testing::UnitTest::GetInstance()->current_test_info()->name())) {
      name += std::isalnum(static_cast<unsigned char>(c))
                  ? static_cast<char>(std::tolower(static_cast<unsigned char>(c)))
                  : '_';
    }
    dbname_ = name.substr(0, 50) + "_" + std::to_string(counter++);
    const std::string error = cluster().create_database(dbname_);
    ASSERT_EQ(error, "");
  }

  PgCluster& cluster() { return *shared_cluster(); }
  // conninfo for `user` on this test's database.
  std::string conninfo(const std::string& user = PgCluster::kAdmin) const {
    return shared_cluster()->conninfo(user, dbname_);
  }

  std::string dbname_;

 private:
  static std::unique_ptr<PgCluster>& shared_cluster() {
    static std::unique_ptr<PgCluster> c;
    return c;
  }
  static std::string& shared_why() {
    static std::string why;
    return why;
  }
  static bool& shared_missing() {
    static bool missing = false;
    return missing;
  }
};

}  // namespace gyrotherm::testing
