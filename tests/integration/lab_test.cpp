// End-to-end lab: three simulated stations (gyrotherm-sim + gyrothermd as
// processes, each with its own SQLite file) relay their campaigns to one
// real PostgreSQL (a private cluster, tests/support/pg_cluster.h). The lab
// database is stopped mid-campaign and one station is killed with SIGKILL
// while its relay is inside a batch; afterwards every record each station
// holds is in the lab exactly once and equal to the station's own. A
// station claiming another station's id is refused by the lab.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sqlite3.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "../support/pg_cluster.h"
#include "gyrotherm/cli/http_client.h"
#include "gyrotherm/lab/central.h"
#include "gyrotherm/lab/pg.h"
#include "gyrotherm/storage/database.h"
#include "process.h"
#include "station_fixture.h"
#include "temp_dir_test.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using testing::ChildProcess;
using ::testing::HasSubstr;
using testing::wait_until;

std::string bin(const char* name) { return std::string(GYROTHERM_BIN_DIR) + "/" + name; }

// The relayed tables and the kind their rows have in the lab (docs/lab.md).
const std::map<std::string, std::string> kKindOfTable = {
    {"runs", "run"},
    {"segments", "segment"},
    {"events", "event"},
    {"segment_stats", "table1"},
    {"allan", "allan"},
    {"fits", "fit"},
    {"fit_runs", "fit_run"},
    {"exports", "export"},
    {"export_runs", "export_run"},
    {"scale_factor_points", "sf_point"},
    {"scale_factor_fits", "sf_fit"},
    {"scale_factor_temperature_fits", "sf_temperature_fit"},
    {"duts", "dut"},
    {"run_duts", "run_dut"},
    {"channels", "channel"},
};

// A campaign of three soaks: about 1700 station s, 9 s of wall time at the
// fixture's time scale of 200.
constexpr const char* kCampaign = R"(
name = "lab-campaign"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 2
acquire_min = 6
[[step]]
type = "soak"
setpoint_c = 26.0
stability_window_min = 2
acquire_min = 6
[[step]]
type = "soak"
setpoint_c = 29.0
stability_window_min = 2
acquire_min = 6
)";

// One station: its folder, config with [lab], simulator and daemon.
struct LabStation {
  std::string id;
  fs::path dir;
  int api_port = 0;
  std::unique_ptr<ChildProcess> sim;
  std::unique_ptr<ChildProcess> daemon;

  LabStation(std::string station_id, fs::path folder, const std::string& lab_conninfo,
             const std::string& claimed_id)
      : id(std::move(station_id)), dir(std::move(folder)) {
    fs::create_directories(dir);
    api_port = testing::free_tcp_port();
    std::ofstream(dir / "lab-url") << lab_conninfo << "\n";
    std::ofstream(dir / "station.toml") << testing::station_config(dir, api_port)
                                        << fmt::format(R"(
[lab]
station_id = "{}"
relay = true
url_file = "lab-url"
poll_s = 0.05
retry_min_s = 0.1
retry_max_s = 0.5
connect_timeout_s = 5
)",
                                                       claimed_id);
    std::ofstream(dir / "campaign.toml") << kCampaign;
  }

  void start_sim() {
    sim = std::make_unique<ChildProcess>(
        std::vector<std::string>{bin("gyrotherm-sim"), "--config", (dir / "station.toml").string(),
                                 "--time-scale", fmt::format("{}", testing::kTimeScale)},
        (dir / "sim.log").string());
  }
  bool sim_ready() const { return fs::exists(dir / "endpoints.toml"); }
  void start_daemon(bool with_campaign) {
    std::vector<std::string> argv{bin("gyrothermd"), "--config", (dir / "station.toml").string(),
                                  "--time-scale", fmt::format("{}", testing::kTimeScale)};
    if (with_campaign) {
      argv.push_back("--schedule");
      argv.push_back((dir / "campaign.toml").string());
    }
    daemon = std::make_unique<ChildProcess>(argv, (dir / "daemon.log").string());
  }
  std::optional<nlohmann::json> status() const {
    auto r = cli::http_request("GET", fmt::format("http://127.0.0.1:{}/api/v1/status", api_port),
                               "", "", std::chrono::milliseconds(500));
    if (!r || r->status != 200) return std::nullopt;
    auto j = nlohmann::json::parse(r->body, nullptr, false);
    if (j.is_discarded()) return std::nullopt;
    return j;
  }
  // The relay's figure `key` from the status; -1 when not readable.
  double lab(const std::string& key) const {
    auto s = status();
    if (!s || !s->contains("lab") || !(*s)["lab"].is_object()) return -1;
    const auto& v = (*s)["lab"][key];
    return v.is_number() ? v.get<double>() : -1;
  }
  std::string lab_state() const {
    auto s = status();
    if (!s || !s->contains("lab") || !(*s)["lab"].is_object()) return "";
    return (*s)["lab"].value("state", "");
  }
  std::string logs() const {
    return fmt::format("--- {} daemon\n{}\n", id, daemon ? daemon->log() : "(none)");
  }
  std::string db_path() const { return (dir / "station.db").string(); }
};

// Rows of `table` (that satisfy `where`) in a station's SQLite file; -1
// when it cannot be read.
int64_t local_count(const std::string& db_path, const std::string& table,
                    const std::string& where = "1") {
  sqlite3* db = nullptr;
  int64_t n = -1;
  if (sqlite3_open_v2(db_path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) == SQLITE_OK) {
    sqlite3_stmt* st = nullptr;
    const std::string sql = "SELECT count(*) FROM " + table + " WHERE " + where;
    if (sqlite3_prepare_v2(db, sql.c_str(), -1, &st, nullptr) == SQLITE_OK &&
        sqlite3_step(st) == SQLITE_ROW) {
      n = sqlite3_column_int64(st, 0);
    }
    sqlite3_finalize(st);
  }
  sqlite3_close(db);
  return n;
}

class LabTest : public testing::TempDirTest {
 protected:
  LabTest() : TempDirTest("gyrotherm-lab") {}

  void SetUp() override {
    TempDirTest::SetUp();
    std::string why;
    bool missing = false;
    cluster_ = testing::PgCluster::create(&why, &missing);
    if (!cluster_) {
      if (missing) GYROTHERM_PG_SKIP_OR_FAIL(why);
      FAIL() << why;
    }
    ASSERT_EQ(cluster_->create_database("lab"), "");
    auto admin = lab::PgConnection::connect(cluster_->conninfo(testing::PgCluster::kAdmin, "lab"));
    ASSERT_TRUE(admin.ok()) << admin.error().message;
    admin_.emplace(std::move(*admin));
    auto version = lab::migrate_central(*admin_);
    ASSERT_TRUE(version.ok()) << version.error().message;
    ASSERT_EQ(*version, lab::kCentralSchemaVersion);
  }
  void TearDown() override {
    stations_.clear();  // daemons and simulators killed before the cluster goes
    admin_.reset();
    cluster_.reset();
    TempDirTest::TearDown();
  }

  // Registers `id` for role gyrotherm_<id>.
  void register_station(const std::string& id) {
    ASSERT_TRUE(lab::add_station(*admin_, id, "gyrotherm_" + id, "test station " + id).ok());
  }
  // A station relaying as role gyrotherm_<role_of> and claiming `claimed_id`.
  LabStation& add_station(const std::string& id, const std::string& role_of,
                          const std::string& claimed_id) {
    stations_.push_back(std::make_unique<LabStation>(
        id, dir_ / id, cluster_->conninfo("gyrotherm_" + role_of, "lab"), claimed_id));
    return *stations_.back();
  }

  // A query's single number (as the administrator).
  int64_t central_int(const std::string& sql, const std::vector<std::optional<std::string>>& p) {
    auto rows = admin_->exec_params(sql, p);
    if (!rows.ok() || rows->rows.empty() || !rows->rows[0][0]) return -1;
    return std::stoll(*rows->rows[0][0]);
  }

  std::unique_ptr<testing::PgCluster> cluster_;
  std::optional<lab::PgConnection> admin_;
  std::vector<std::unique_ptr<LabStation>> stations_;
};

TEST_F(LabTest, ThreeStationsThroughAnOutageAndAKillArriveExactlyOnce) {
  for (const char* id : {"st01", "st02", "st03"}) register_station(id);
  for (const char* id : {"st01", "st02", "st03"}) add_station(id, id, id);
  for (auto& s : stations_) s->start_sim();
  for (auto& s : stations_) {
    ASSERT_TRUE(wait_until([&] { return s->sim_ready(); }, std::chrono::seconds(20)))
        << s->sim->log();
  }
  for (auto& s : stations_) s->start_daemon(true);
  const auto logs = [&] {
    std::string text;
    for (auto& s : stations_) text += s->logs();
    return text + "--- lab server\n" + cluster_->log();
  };

  // Every relay connected and sending.
  for (auto& s : stations_) {
    ASSERT_TRUE(wait_until([&] { return s->lab("sent_total") > 0; }, std::chrono::seconds(60)))
        << logs();
  }

  // The lab database goes down mid-campaign: the relays back off, the
  // stations run on and their outboxes grow.
  std::map<std::string, double> pending_at_stop;
  ASSERT_TRUE(cluster_->stop()) << cluster_->log();
  admin_.reset();
  for (auto& s : stations_) {
    ASSERT_TRUE(wait_until([&] { return s->lab_state() == "backoff"; }, std::chrono::seconds(30)))
        << s->id << " state " << s->lab_state() << "\n"
        << logs();
    pending_at_stop[s->id] = s->lab("pending");
  }
  for (auto& s : stations_) {
    ASSERT_TRUE(wait_until([&] { return s->lab("pending") > pending_at_stop[s->id] + 2; },
                           std::chrono::seconds(60)))
        << s->id << ": nothing queued while the lab was down\n"
        << logs();
    EXPECT_TRUE(s->daemon->running()) << logs();
  }
  ASSERT_TRUE(cluster_->start()) << cluster_->log();
  auto admin = lab::PgConnection::connect(cluster_->conninfo(testing::PgCluster::kAdmin, "lab"));
  ASSERT_TRUE(admin.ok()) << admin.error().message;
  admin_.emplace(std::move(*admin));
  for (auto& s : stations_) {
    ASSERT_TRUE(wait_until([&] { return s->lab_state() == "connected"; }, std::chrono::seconds(60)))
        << s->id << " state " << s->lab_state() << "\n"
        << logs();
  }

  // Station st02 is killed inside a relay batch: the lab's records table is
  // locked, so its batch waits in the middle of its transaction; SIGKILL
  // then, and the lock let go.
  LabStation& victim = *stations_[1];
  ASSERT_TRUE(victim.daemon->running());
  ASSERT_TRUE(admin_->exec("BEGIN; LOCK TABLE lab.records IN EXCLUSIVE MODE").ok());
  ASSERT_TRUE(wait_until(
      [&] {
        return central_int(
                   "SELECT count(*) FROM pg_stat_activity WHERE usename = $1 AND "
                   "wait_event_type = 'Lock'",
                   {std::string("gyrotherm_st02")}) > 0;
      },
      std::chrono::seconds(60)))
      << "st02's relay never started a batch while the lab was locked\n"
      << logs();
  victim.daemon->signal(SIGKILL);
  ASSERT_TRUE(victim.daemon->wait(std::chrono::seconds(10)).has_value());
  ASSERT_TRUE(admin_->exec("ROLLBACK").ok());
  victim.start_daemon(false);  // its queue and interrupted run are in its database

  // Every campaign ends, and every relay catches up.
  for (auto& s : stations_) {
    ASSERT_TRUE(wait_until(
        [&] {
          auto st = s->status();
          return st && st->value("state", "") == "idle" && st->value("queue_length", -1) == 0;
        },
        std::chrono::seconds(240)))
        << s->id << "\n"
        << logs();
  }
  // The analysis after each run stores its fits; then nothing is pending.
  for (auto& s : stations_) {
    ASSERT_TRUE(wait_until(
        [&] {
          // (the status's pending figure is refreshed about once a second:
          // the outbox itself says when everything was acknowledged)
          return local_count(s->db_path(), "fits") > 0 &&
                 local_count(s->db_path(), "outbox") == 0 && s->lab_state() == "connected";
        },
        std::chrono::seconds(120)))
        << s->id << " outbox " << local_count(s->db_path(), "outbox") << "\n"
        << logs();
  }

  // Each station's records are in the lab exactly once, equal to its own.
  int64_t total_local = 0;
  std::map<std::string, int64_t> local_rows;
  for (auto& s : stations_) {
    for (const auto& [table, kind] : kKindOfTable) {
      const int64_t here = local_count(s->db_path(), table);
      ASSERT_GE(here, 0) << table;
      const int64_t there = central_int(
          "SELECT count(*) FROM lab.records WHERE station_id = $1 AND kind = $2 AND NOT deleted",
          {s->id, kind});
      EXPECT_EQ(there, here) << s->id << " " << table << " (" << kind << ")";
      total_local += here;
      local_rows[s->id] += here;
    }
    EXPECT_GT(local_count(s->db_path(), "segment_stats"), 0) << s->id;
    EXPECT_EQ(local_count(s->db_path(), "outbox"), 0) << s->id;

    // Table I rows: the lab's numbers are the station's, exactly.
    auto db = storage::Database::open_read_only(s->db_path());
    ASSERT_TRUE(db.ok()) << db.error().message;
    auto runs = db->runs();
    ASSERT_TRUE(runs.ok());
    for (const auto& run : *runs) {
      EXPECT_EQ(central_int("SELECT count(*) FROM lab.runs WHERE station_id = $1 AND run_uuid = $2 "
                            "AND local_run_id = $3 AND state = $4",
                            {s->id, run.uuid, std::to_string(run.id), run.state}),
                1)
          << s->id << " run " << run.id << " " << run.uuid;
      auto stats = db->segment_stats(run.id);
      ASSERT_TRUE(stats.ok());
      for (const auto& row : *stats) {
        auto there = admin_->exec_params(
            "SELECT bias_mean_dph, bias_std_dph, bias_std_ma_dph, temp_mean_c, bias_u_dph, "
            "bias_u_expanded_dph FROM lab.table1 "
            "WHERE station_id = $1 AND run_uuid = $2 AND segment_id = $3 AND dut_serial = $4 AND "
            "axis = $5",
            {s->id, run.uuid, std::to_string(row.segment_id), row.dut_serial, row.axis});
        ASSERT_TRUE(there.ok()) << there.error().message;
        ASSERT_EQ(there->rows.size(), 1u) << s->id << " segment " << row.segment_id;
        const auto& r = there->rows[0];
        EXPECT_EQ(std::stod(r[0].value_or("nan")), row.bias_mean_dph) << "exact, 17 digits";
        EXPECT_EQ(std::stod(r[1].value_or("nan")), row.bias_std_dph);
        EXPECT_EQ(std::stod(r[2].value_or("nan")), row.bias_std_ma_dph);
        EXPECT_EQ(std::stod(r[3].value_or("nan")), row.temp_mean_c);
        // The bias mean's uncertainty arrives with the row (schema v13).
        ASSERT_TRUE(row.bias_u) << row.bias_u_note;
        EXPECT_EQ(std::stod(r[4].value_or("nan")), row.bias_u->u_dph);
        EXPECT_EQ(std::stod(r[5].value_or("nan")), row.bias_u->expanded_dph);
      }
    }
  }
  // Nothing else arrived: no duplicate under another key, no stray station.
  EXPECT_EQ(central_int("SELECT count(*) FROM lab.records WHERE NOT deleted", {}), total_local);
  EXPECT_EQ(central_int("SELECT count(DISTINCT station_id) FROM lab.records", {}), 3);

  // The figures for the record (docs/lab.md "Outages").
  for (auto& s : stations_) {
    std::printf(
        "lab: %s local %lld rows, lab %lld rows (+%lld tombstones), %lld redelivered; relay sent "
        "%.0f outbox rows since its last start\n",
        s->id.c_str(), static_cast<long long>(local_rows[s->id]),
        static_cast<long long>(central_int(
            "SELECT count(*) FROM lab.records WHERE station_id = $1 AND NOT deleted", {s->id})),
        static_cast<long long>(central_int(
            "SELECT count(*) FROM lab.records WHERE station_id = $1 AND deleted", {s->id})),
        static_cast<long long>(central_int(
            "SELECT coalesce(sum(redeliveries), 0) FROM lab.records WHERE station_id = $1",
            {s->id})),
        s->lab("sent_total"));
  }
}

TEST_F(LabTest, AStationClaimingAnotherStationsIdIsRefused) {
  register_station("st01");
  register_station("st02");
  // Credentials of st01, configured as st02.
  LabStation& s = add_station("impostor", "st01", "st02");
  s.start_sim();
  ASSERT_TRUE(wait_until([&] { return s.sim_ready(); }, std::chrono::seconds(20)));
  s.start_daemon(true);
  ASSERT_TRUE(wait_until([&] { return s.lab_state() == "refused"; }, std::chrono::seconds(60)))
      << s.lab_state() << "\n"
      << s.logs();
  auto st = s.status();
  ASSERT_TRUE(st);
  EXPECT_THAT((*st)["lab"].value("last_error", ""), HasSubstr("st02"));
  EXPECT_EQ(central_int("SELECT count(*) FROM lab.records", {}), 0);

  // The refusal is an event of the station, and the metric says so.
  ASSERT_TRUE(wait_until(
      [&] {
        return local_count(s.db_path(), "events", "kind = 'lab' AND message LIKE '%refused%'") > 0;
      },
      std::chrono::seconds(30)))
      << s.logs();
  auto metrics = cli::http_request("GET", fmt::format("http://127.0.0.1:{}/metrics", s.api_port),
                                   "", "", std::chrono::seconds(5));
  ASSERT_TRUE(metrics && metrics->status == 200);
  EXPECT_THAT(metrics->body, HasSubstr("gyrotherm_lab_relay_state{state=\"refused\"} 1"));
  // The station itself runs on: the campaign is not stopped by the lab.
  EXPECT_TRUE(s.daemon->running());
}

}  // namespace
}  // namespace gyrotherm
