// `gyrotherm lab`: the real CLI binary against a private PostgreSQL cluster
// (tests/support/pg_cluster.h): the administrator's migrate, add-station
// and add-reader, then the reads (stations, runs, run, dut, summary) of a
// lab two stations relayed into (tests/lab/lab_records.h); the URL from
// --pg, @FILE or GYROTHERM_LAB_URL; errors that are clear and never show a
// password.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gyrotherm/lab/central.h"
#include "lab/lab_records.h"
#include "process.h"
#include "support/pg_cluster.h"
#include "test_files.h"

namespace gyrotherm {
namespace {

using nlohmann::json;
using ::testing::HasSubstr;
using ::testing::Not;

class LabCliTest : public testing::PgClusterTest {
 protected:
  void SetUp() override {
    PgClusterTest::SetUp();
    if (IsSkipped() || HasFatalFailure()) return;
    std::string templ =
        (std::filesystem::temp_directory_path() / "gyrotherm-lab-cli-XXXXXX").string();
    ASSERT_NE(::mkdtemp(templ.data()), nullptr);
    dir_ = templ;
  }
  void TearDown() override {
    std::error_code ec;
    if (!dir_.empty() && !HasFailure()) std::filesystem::remove_all(dir_, ec);
  }

  struct Run {
    int code;
    std::string out, err;
  };
  // Runs the CLI to completion (killed after 60 s). `env`: assignments put
  // before it ("" = GYROTHERM_LAB_URL unset).
  Run cli(const std::vector<std::string>& args, const std::string& env = "") {
    const std::string out = (dir_ / "out.txt").string(), err = (dir_ / "err.txt").string();
    std::string cmd = fmt::format("env -u GYROTHERM_LAB_URL {} timeout -s KILL 60 {}/gyrotherm",
                                  env, GYROTHERM_BIN_DIR);
    for (const auto& a : args) cmd += fmt::format(" {}", quote(a));
    cmd += fmt::format(" >{} 2>{} </dev/null", out, err);
    const int st = std::system(cmd.c_str());
    return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, testing::read_text(out), testing::read_text(err)};
  }
  Run lab(std::vector<std::string> args) {
    args.insert(args.begin(), "lab");
    args.push_back("--pg");
    args.push_back(conninfo());
    return cli(args);
  }

  static std::string quote(const std::string& s) {
    std::string out = "'";
    for (const char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return out + "'";
  }

  void fill() {
    testing::fill_two_station_lab(conninfo(),
                                  [this](const std::string& role) { return conninfo(role); });
  }

  std::filesystem::path dir_;
};

TEST_F(LabCliTest, MigrateThenRegisterStationsAndReaders) {
  Run r = lab({"migrate"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out,
            fmt::format("lab schema migrated from version 0 to {}\n", lab::kCentralSchemaVersion));
  r = lab({"migrate"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out,
            fmt::format("lab schema at version {} (nothing to do)\n", lab::kCentralSchemaVersion));

  r = lab({"add-station", "lab-c", "--role", "lab_c_relay", "--description", "bench c, room 2"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("station lab-c registered"));
  // Again: a no-op. The id for another role: refused, naming both.
  r = lab({"add-station", "lab-c", "--role", "lab_c_relay"});
  EXPECT_EQ(r.code, 0) << r.err;
  r = lab({"add-station", "lab-c", "--role", "somebody_else"});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("lab-c"));
  EXPECT_THAT(r.err, HasSubstr("somebody_else"));
  r = lab({"add-station", "no spaces please", "--role", "x_relay"});
  EXPECT_EQ(r.code, 1) << r.out;

  r = lab({"add-reader", "lab_screen"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("lab_screen may read the lab"));

  r = lab({"stations"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("station"));
  EXPECT_THAT(r.out, HasSubstr("lab-c"));
  EXPECT_THAT(r.out, HasSubstr("lab_c_relay"));
  EXPECT_THAT(r.out, HasSubstr("bench c, room 2"));
  EXPECT_THAT(r.out, HasSubstr("never"));
  r = lab({"stations", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = json::parse(r.out);
  ASSERT_EQ(j.size(), 1u);
  EXPECT_EQ(j[0]["station_id"], "lab-c");
  EXPECT_TRUE(j[0]["last_batch_utc"].is_null());

  // The reader reads (trust authentication: no password in this cluster).
  r = cli({"lab", "runs", "--pg", conninfo("lab_screen")});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out, "no runs\n");
}

TEST_F(LabCliTest, ReadsAcrossStations) {
  fill();
  if (HasFatalFailure()) return;

  Run r = lab({"stations"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("lab-a"));
  EXPECT_THAT(r.out, HasSubstr("lab-b"));

  r = lab({"runs"});
  ASSERT_EQ(r.code, 0) << r.err;
  const auto b1 = r.out.find(testing::kUuidB1), a2 = r.out.find(testing::kUuidA2),
             a1 = r.out.find(testing::kUuidA1);
  ASSERT_NE(a1, std::string::npos) << r.out;
  EXPECT_LT(b1, a2) << "newest first:\n" << r.out;
  EXPECT_LT(a2, a1) << r.out;
  EXPECT_THAT(r.out, HasSubstr("2026-11-20 05:00:00"));
  EXPECT_THAT(r.out, HasSubstr("Ana Müller"));
  EXPECT_THAT(r.out, HasSubstr("17-0042, TS-7"));
  EXPECT_THAT(r.out, HasSubstr("campaign-7, week-1"));

  r = lab({"runs", "--station", "lab-a"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, Not(HasSubstr(testing::kUuidB1)));
  EXPECT_THAT(r.out, HasSubstr(testing::kUuidA2));
  r = lab({"runs", "--dut", "17-0042", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  json runs = json::parse(r.out);
  ASSERT_EQ(runs.size(), 2u);
  EXPECT_EQ(runs[0]["station_id"], "lab-b");
  EXPECT_EQ(runs[1]["run_uuid"], testing::kUuidA1);
  EXPECT_EQ(runs[1]["tags"], json::array({"campaign-7", "week-1"}));
  r = lab({"runs", "--since", "2026-11-21", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(json::parse(r.out).size(), 2u);
  r = lab({"runs", "--limit", "2"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, Not(HasSubstr(testing::kUuidA1)));
  EXPECT_THAT(r.out, HasSubstr("(the newest 2: --limit N or --since DATE for others)"));
  r = lab({"runs", "--limit", "3"});  // all there are: not cut
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr(testing::kUuidA1));
  EXPECT_THAT(r.out, Not(HasSubstr("the newest")));
  r = lab({"runs", "--limit", "1", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(json::parse(r.out).size(), 1u);
  r = lab({"runs", "--since", "last tuesday"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("--since"));
  EXPECT_THAT(r.err, HasSubstr("last tuesday"));

  r = lab({"run", "lab-a/1"});
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* s : {"run lab-a/1  paper-table1  completed", testing::kUuidA1, "Ana Müller",
                        "17-0042  KVH 1750, axes x y z (primary z), 1000 Hz", "Table I", "1.2031",
                        "1.4562", "T1+R1", "1.0001500", "Allan noise terms", "run completed"}) {
    EXPECT_THAT(r.out, HasSubstr(s));
  }
  r = lab({"run", testing::kUuidB1, "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json run = json::parse(r.out);
  EXPECT_EQ(run["run"]["station_id"], "lab-b");
  EXPECT_EQ(run["table1"].size(), 2u);
  r = lab({"run", "lab-a/99"});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("no run lab-a/99"));
  r = lab({"run", "seven"});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("STATION/LOCAL_ID"));

  r = lab({"dut", "17-0042"});
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* s :
       {"DUT 17-0042  KVH 1750", "runs        2", "stations    lab-a, lab-b",
        "run lab-a/1  paper-table1  completed", "run lab-b/1  paper-table1", "1.2031", "0.9876",
        "1.2105", "drift fits", "lab-a/1", "scale factor", "Allan noise terms"}) {
    EXPECT_THAT(r.out, HasSubstr(s));
  }
  r = lab({"dut", "17-0042", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(json::parse(r.out)["runs"].size(), 2u);
  r = lab({"dut", "00-0000"});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("no DUT \"00-0000\""));

  r = lab({"summary"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out.rfind("<!DOCTYPE html>", 0), 0u);
  const std::string page = (dir_ / "summary.html").string();
  r = lab({"summary", "-o", page});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr(page));
  const std::string html = testing::read_text(page);
  EXPECT_THAT(html, HasSubstr("1.2031"));
  EXPECT_THAT(html, HasSubstr("0.9876"));
  EXPECT_THAT(html, HasSubstr("&lt;script&gt;"));
  EXPECT_THAT(html, Not(HasSubstr("<script")));
  r = lab({"summary", "--since", "2026-11-21", "-o", page});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(testing::read_text(page), Not(HasSubstr("1.2031")));
}

TEST_F(LabCliTest, TheUrlFromAFileOrTheEnvironment) {
  ASSERT_EQ(lab({"migrate"}).code, 0);
  const std::string file = (dir_ / "lab.url").string();
  std::ofstream(file) << "  " << conninfo() << "  \n# comment lines after the first are ignored\n";
  Run r = cli({"lab", "stations", "--pg", "@" + file});
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out, "no stations registered\n");
  r = cli({"lab", "stations"}, "GYROTHERM_LAB_URL=" + quote(conninfo()));
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out, "no stations registered\n");

  r = cli({"lab", "stations"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("GYROTHERM_LAB_URL"));
  EXPECT_THAT(r.err, HasSubstr("--pg"));
  r = cli({"lab", "stations", "--pg", "@" + (dir_ / "missing.url").string()});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("missing.url"));
}

TEST_F(LabCliTest, ABadUrlIsAClearErrorWithoutThePassword) {
  const std::string secret = "s3cret-Pw0rd";
  const int closed = testing::free_tcp_port();
  const std::string uri =
      fmt::format("postgresql://lab_screen:{}@127.0.0.1:{}/lab?connect_timeout=5", secret, closed);
  Run r = cli({"lab", "runs", "--pg", uri});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("cannot connect to the lab database"));
  EXPECT_THAT(r.err, HasSubstr(fmt::format("127.0.0.1:{}", closed)));
  EXPECT_THAT(r.err + r.out, Not(HasSubstr(secret)));

  const std::string conninfo_text =
      fmt::format("host=127.0.0.1 port={} dbname=lab user=lab_screen password={}", closed, secret);
  r = cli({"lab", "stations"}, "GYROTHERM_LAB_URL=" + quote(conninfo_text));
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("cannot connect"));
  EXPECT_THAT(r.err + r.out, Not(HasSubstr(secret)));

  // A wrong database on the right server: the server's refusal, no password.
  const std::string wrong_db = fmt::format("postgresql://{}:{}@127.0.0.1:{}/no_such_db",
                                           testing::PgCluster::kAdmin, secret, cluster().port());
  r = cli({"lab", "stations", "--pg", wrong_db});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("no_such_db"));
  EXPECT_THAT(r.err + r.out, Not(HasSubstr(secret)));

  // A connection string libpq cannot parse.
  r = cli({"lab", "stations", "--pg", "host=127.0.0.1 password='" + secret});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("malformed"));
  EXPECT_THAT(r.err + r.out, Not(HasSubstr(secret)));

  // A usage error echoes the arguments: not the password.
  r = cli({"lab", "stations", "--pg", uri, "--bogus"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err + r.out, Not(HasSubstr(secret)));
}

}  // namespace
}  // namespace gyrotherm
