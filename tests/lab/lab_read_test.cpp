// The lab's reads (central.h: lab_stations, lab_runs, lab_run_json,
// lab_dut_json, lab_summary_html) on a real PostgreSQL: two stations
// registered and relayed with push_batch as their own roles
// (lab_records.h), then read back through the views as a reader would.
#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <nlohmann/json.hpp>
#include <regex>
#include <string>

#include "gyrotherm/lab/central.h"
#include "gyrotherm/lab/pg.h"
#include "lab/lab_records.h"
#include "support/pg_cluster.h"

namespace gyrotherm::lab {
namespace {

using nlohmann::json;
using testing::kUuidA1;
using testing::kUuidA2;
using testing::kUuidB1;

class LabReadTest : public testing::PgClusterTest {
 protected:
  void SetUp() override {
    PgClusterTest::SetUp();
    if (IsSkipped() || HasFatalFailure()) return;
    testing::fill_two_station_lab(conninfo(),
                                  [this](const std::string& role) { return conninfo(role); });
    if (HasFatalFailure()) return;
    auto added = PgConnection::connect(conninfo());
    ASSERT_TRUE(added.ok()) << added.error().message;
    ASSERT_TRUE(add_reader(*added, "lab_reader").ok());
    // Reads as a reader: what `gyrotherm lab` does on a lab screen.
    auto pg = PgConnection::connect(conninfo("lab_reader"));
    ASSERT_TRUE(pg.ok()) << pg.error().message;
    reader_.emplace(std::move(*pg));
  }

  PgConnection& pg() { return *reader_; }

  // "station/local id" of each run, in the order given.
  static std::vector<std::string> refs(const std::vector<LabRun>& runs) {
    std::vector<std::string> out;
    for (const auto& r : runs) out.push_back(r.station_id + "/" + std::to_string(r.local_run_id));
    return out;
  }

  std::vector<std::string> runs_where(LabRunFilter filter) {
    auto runs = lab_runs(pg(), filter);
    EXPECT_TRUE(runs.ok()) << runs.error().message;
    return runs.ok() ? refs(*runs) : std::vector<std::string>{};
  }

  std::optional<PgConnection> reader_;
};

using Refs = std::vector<std::string>;

TEST_F(LabReadTest, StationsShowTheirRelayProgressAndRuns) {
  auto stations = lab_stations(pg());
  ASSERT_TRUE(stations.ok()) << stations.error().message;
  ASSERT_EQ(stations->size(), 2u);
  const LabStation& a = (*stations)[0];
  const LabStation& b = (*stations)[1];
  EXPECT_EQ(a.station_id, "lab-a");
  EXPECT_EQ(a.db_role, "lab_a_relay");
  EXPECT_EQ(a.description, "bench lab-a");
  EXPECT_EQ(a.runs, 2);
  EXPECT_EQ(a.last_seq, static_cast<int64_t>(testing::station_a_outbox().records.size()));
  EXPECT_EQ(a.records, a.last_seq);
  ASSERT_TRUE(a.last_batch_utc.has_value());
  EXPECT_TRUE(
      std::regex_match(*a.last_batch_utc, std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z)")))
      << *a.last_batch_utc;
  EXPECT_TRUE(
      std::regex_match(a.registered_utc, std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z)")))
      << a.registered_utc;
  EXPECT_EQ(b.station_id, "lab-b");
  EXPECT_EQ(b.runs, 1);
}

TEST_F(LabReadTest, AStationNeverRelayedIsListedWithoutABatch) {
  auto admin = PgConnection::connect(conninfo());
  ASSERT_TRUE(admin.ok());
  ASSERT_TRUE(add_station(*admin, "lab-c", "lab_c_relay").ok());
  auto stations = lab_stations(pg());
  ASSERT_TRUE(stations.ok()) << stations.error().message;
  ASSERT_EQ(stations->size(), 3u);
  EXPECT_EQ((*stations)[2].station_id, "lab-c");
  EXPECT_FALSE((*stations)[2].last_batch_utc.has_value());
  EXPECT_EQ((*stations)[2].runs, 0);
  EXPECT_EQ((*stations)[2].last_seq, 0);
}

TEST_F(LabReadTest, RunsNewestFirstWithTheirMetadataAndDuts) {
  auto runs = lab_runs(pg(), {});
  ASSERT_TRUE(runs.ok()) << runs.error().message;
  EXPECT_EQ(refs(*runs), (Refs{"lab-b/1", "lab-a/2", "lab-a/1"}));
  const LabRun& a1 = (*runs)[2];
  EXPECT_EQ(a1.run_uuid, kUuidA1);
  EXPECT_EQ(a1.schedule_name, "paper-table1");
  EXPECT_EQ(a1.state, "completed");
  EXPECT_EQ(a1.started_utc, "2026-11-20T05:00:00.000Z");
  EXPECT_EQ(a1.ended_utc, "2026-11-20T11:00:00.000Z");
  EXPECT_EQ(a1.operator_name, "Ana Müller");
  EXPECT_EQ(a1.comment, testing::kComment);
  EXPECT_EQ(a1.tags, (Refs{"campaign-7", "week-1"}));
  EXPECT_EQ(a1.dut_serials, (Refs{"17-0042", "TS-7"}));  // run_duts, by position
  const LabRun& a2 = (*runs)[1];
  EXPECT_EQ(a2.ended_utc, "");  // still running
  EXPECT_TRUE(a2.tags.empty());
  EXPECT_EQ(a2.dut_serials, (Refs{"TS-7"}));
}

TEST_F(LabReadTest, RunsFilterByStationDutSinceAndLimit) {
  LabRunFilter f;
  f.station_id = "lab-a";
  EXPECT_EQ(runs_where(f), (Refs{"lab-a/2", "lab-a/1"}));
  f = {};
  f.station_id = "lab-z";
  EXPECT_EQ(runs_where(f), Refs{});

  f = {};
  f.dut_serial = "17-0042";  // across both stations
  EXPECT_EQ(runs_where(f), (Refs{"lab-b/1", "lab-a/1"}));
  f.dut_serial = "TS-7";
  EXPECT_EQ(runs_where(f), (Refs{"lab-a/2", "lab-a/1"}));
  f.station_id = "lab-b";
  EXPECT_EQ(runs_where(f), Refs{});

  f = {};
  f.since_utc = "2026-11-21";  // midnight UTC
  EXPECT_EQ(runs_where(f), (Refs{"lab-b/1", "lab-a/2"}));
  f.since_utc = "2026-11-22T09:30:00Z";  // inclusive
  EXPECT_EQ(runs_where(f), (Refs{"lab-b/1", "lab-a/2"}));
  f.since_utc = "2026-11-22T11:30:00.001+02:00";  // an offset: 09:30:00.001 UTC
  EXPECT_EQ(runs_where(f), (Refs{"lab-b/1"}));

  f = {};
  f.limit = 1;
  EXPECT_EQ(runs_where(f), (Refs{"lab-b/1"}));
  f.limit = 0;  // no bound
  EXPECT_EQ(runs_where(f).size(), 3u);
}

TEST_F(LabReadTest, ABadSinceIsAnErrorNamingIt) {
  LabRunFilter f;
  f.since_utc = "yesterday";
  auto runs = lab_runs(pg(), f);
  ASSERT_FALSE(runs.ok());
  EXPECT_FALSE(runs.error().transient);
  EXPECT_NE(runs.error().message.find("yesterday"), std::string::npos) << runs.error().message;
}

TEST_F(LabReadTest, FilterValuesAreParametersNotSql) {
  LabRunFilter f;
  f.station_id = "lab-a' OR '1'='1";
  EXPECT_EQ(runs_where(f), Refs{});
  f = {};
  f.dut_serial = "x') OR true --";
  EXPECT_EQ(runs_where(f), Refs{});
  auto run = lab_run_json(pg(), "lab-a' OR '1'='1/1");
  ASSERT_FALSE(run.ok());
}

TEST_F(LabReadTest, ARunByUuidOrStationAndLocalIdWithEverythingRelayed) {
  auto by_uuid = lab_run_json(pg(), kUuidA1);
  ASSERT_TRUE(by_uuid.ok()) << by_uuid.error().message;
  auto by_ref = lab_run_json(pg(), "lab-a/1");
  ASSERT_TRUE(by_ref.ok()) << by_ref.error().message;
  EXPECT_EQ(*by_uuid, *by_ref);
  // Upper case is the same UUID.
  std::string upper = kUuidA1;
  std::transform(upper.begin(), upper.end(), upper.begin(),
                 [](unsigned char c) { return static_cast<char>(std::toupper(c)); });
  auto by_upper = lab_run_json(pg(), upper);
  ASSERT_TRUE(by_upper.ok()) << by_upper.error().message;
  EXPECT_EQ(*by_upper, *by_uuid);

  const json j = json::parse(*by_uuid);
  EXPECT_EQ(j["run"]["station_id"], "lab-a");
  EXPECT_EQ(j["run"]["run_uuid"], kUuidA1);
  EXPECT_EQ(j["run"]["local_run_id"], 1);
  EXPECT_EQ(j["run"]["comment"], testing::kComment);
  ASSERT_EQ(j["duts"].size(), 2u);
  EXPECT_EQ(j["duts"][0]["dut_serial"], "17-0042");
  EXPECT_EQ(j["duts"][0]["model"], "KVH 1750");
  EXPECT_EQ(j["duts"][1]["dut_serial"], "TS-7");
  ASSERT_EQ(j["segments"].size(), 3u);
  EXPECT_EQ(j["segments"][2]["idx"], 2);
  EXPECT_DOUBLE_EQ(j["segments"][2]["setpoint_c"].get<double>(), 40.0);
  ASSERT_EQ(j["table1"].size(), 3u);  // 17-0042 z at 20 and 40 °C, TS-7 x at 20 °C
  EXPECT_EQ(j["table1"][0]["dut_serial"], "17-0042");
  EXPECT_DOUBLE_EQ(j["table1"][0]["bias_mean_dph"].get<double>(), 1.2031);
  EXPECT_DOUBLE_EQ(j["table1"][1]["bias_mean_dph"].get<double>(), 1.4562);
  EXPECT_FALSE(j["table1"][0].contains("station_id")) << "rows drop the run's key";
  ASSERT_EQ(j["allan"].size(), 1u);
  EXPECT_DOUBLE_EQ(j["allan"][0]["bias_instability_dph"].get<double>(), 0.0456);
  EXPECT_TRUE(j["allan"][0]["curve"].is_object());
  ASSERT_EQ(j["fits"].size(), 1u);
  EXPECT_EQ(j["fits"][0]["model"], "T1+R1");
  EXPECT_DOUBLE_EQ(j["fits"][0]["coefficients"]["T1"].get<double>(), 0.0123);
  EXPECT_EQ(j["fits"][0]["run_ids"], json::array({1}));
  ASSERT_EQ(j["scale_factor_fits"].size(), 1u);
  EXPECT_DOUBLE_EQ(j["scale_factor_fits"][0]["k"].get<double>(), 1.00015);
  ASSERT_EQ(j["scale_factor_temperature_fits"].size(), 1u);
  EXPECT_EQ(j["scale_factor_temperature_fits"][0]["k_coeffs"].size(), 2u);
  // The run's events only, in order; the station event outside runs is not one.
  ASSERT_EQ(j["events"].size(), 2u);
  EXPECT_EQ(j["events"][0]["message"], "run started");
  EXPECT_EQ(j["events"][1]["to_state"], "completed");

  // The same local id at another station is another run.
  auto b = lab_run_json(pg(), "lab-b/1");
  ASSERT_TRUE(b.ok()) << b.error().message;
  const json jb = json::parse(*b);
  EXPECT_EQ(jb["run"]["run_uuid"], kUuidB1);
  EXPECT_EQ(jb["table1"].size(), 2u);
  EXPECT_EQ(jb["fits"].size(), 0u);
}

TEST_F(LabReadTest, AnUnknownRunIsAnErrorNamingIt) {
  for (const std::string& run :
       {std::string("lab-a/99"), std::string("lab-x/1"),
        std::string("11111111-2222-4333-8444-555555555555"), std::string("not-a-run"),
        std::string("lab-a/"), std::string("/1"), std::string("lab-a/1x")}) {
    auto r = lab_run_json(pg(), run);
    ASSERT_FALSE(r.ok()) << run;
    EXPECT_FALSE(r.error().transient) << run;
    EXPECT_NE(r.error().message.find(run), std::string::npos) << r.error().message;
  }
  auto unregistered = lab_run_json(pg(), "lab-x/1");
  EXPECT_NE(unregistered.error().message.find("no station \"lab-x\" is registered"),
            std::string::npos)
      << unregistered.error().message;
}

TEST_F(LabReadTest, ADutsHistoryAcrossStations) {
  auto history = lab_dut_json(pg(), "17-0042");
  ASSERT_TRUE(history.ok()) << history.error().message;
  const json h = json::parse(*history);
  EXPECT_EQ(h["serial"], "17-0042");
  EXPECT_EQ(h["model"], "KVH 1750");
  EXPECT_EQ(h["first_seen_utc"], "2026-11-20T05:00:00.000Z");
  EXPECT_EQ(h["stations"], json::array({"lab-a", "lab-b"}));
  ASSERT_EQ(h["runs"].size(), 2u);  // oldest first
  const json& a = h["runs"][0];
  const json& b = h["runs"][1];
  EXPECT_EQ(a["station_id"], "lab-a");
  EXPECT_EQ(a["run"]["run_uuid"], kUuidA1);
  EXPECT_EQ(a["dut"]["primary_axis"], "z");
  EXPECT_EQ(a["dut"]["position"], 0);
  EXPECT_EQ(a["segments"].size(), 3u);
  ASSERT_EQ(a["table1"].size(), 2u) << "only this DUT's rows (not TS-7's)";
  EXPECT_DOUBLE_EQ(a["table1"][0]["bias_mean_dph"].get<double>(), 1.2031);
  EXPECT_EQ(a["allan"].size(), 1u);
  EXPECT_EQ(a["fits"].size(), 1u);
  EXPECT_EQ(a["scale_factor_fits"].size(), 1u);
  EXPECT_EQ(a["scale_factor_temperature_fits"].size(), 1u);
  EXPECT_EQ(b["station_id"], "lab-b");
  EXPECT_EQ(b["run"]["run_uuid"], kUuidB1);
  ASSERT_EQ(b["table1"].size(), 2u);
  EXPECT_DOUBLE_EQ(b["table1"][0]["bias_mean_dph"].get<double>(), 0.9876);
  EXPECT_DOUBLE_EQ(b["table1"][1]["bias_mean_dph"].get<double>(), 1.2105);
  EXPECT_EQ(b["allan"].size(), 0u);
  ASSERT_EQ(h["fits"].size(), 1u);
  EXPECT_EQ(h["fits"][0]["station_id"], "lab-a");
  EXPECT_EQ(h["fits"][0]["run_ids"], json::array({1}));

  auto ts7 = lab_dut_json(pg(), "TS-7");
  ASSERT_TRUE(ts7.ok()) << ts7.error().message;
  const json t = json::parse(*ts7);
  EXPECT_EQ(t["runs"].size(), 2u);
  EXPECT_EQ(t["stations"], json::array({"lab-a"}));
  EXPECT_EQ(t["runs"][0]["table1"].size(), 1u);
}

TEST_F(LabReadTest, AnUnknownDutIsAnErrorNamingIt) {
  auto h = lab_dut_json(pg(), "99-9999");
  ASSERT_FALSE(h.ok());
  EXPECT_FALSE(h.error().transient);
  EXPECT_NE(h.error().message.find("\"99-9999\""), std::string::npos) << h.error().message;
}

TEST_F(LabReadTest, TheSummaryPageHasTheNumbersAndEscapesEveryText) {
  LabSummaryOptions options;
  options.generated_utc = "2026-11-26T02:00:00.000Z";
  auto page = lab_summary_html(pg(), options);
  ASSERT_TRUE(page.ok()) << page.error().message;
  const std::string& h = *page;
  auto has = [&](const std::string& s) { return h.find(s) != std::string::npos; };
  EXPECT_TRUE(has("<!DOCTYPE html>"));
  // Provenance: the server (no password), the time given.
  EXPECT_TRUE(has("127.0.0.1:" + std::to_string(cluster().port()))) << "server in provenance";
  EXPECT_TRUE(has("2026-11-26 02:00:00 UTC"));
  // Stations, runs.
  for (const char* s : {"lab-a", "lab-b", "lab_a_relay", kUuidA1, kUuidA2, kUuidB1, "rate-sweep",
                        "Ana Müller", "campaign-7, week-1", "17-0042, TS-7"}) {
    EXPECT_TRUE(has(s)) << s;
  }
  // Table I across runs and stations; fits, Allan, scale factor.
  for (const char* s :
       {"1.2031", "1.4562", "0.9876", "1.2105", "0.0117", "-3.2500", "T1 = 0.0123", "± 0.0004",
        "0.9870", "0.0456", "0.00123", "1.0001500", "7.560", "41.0", "1.500"}) {
    EXPECT_TRUE(has(s)) << s;
  }
  EXPECT_TRUE(has("<svg")) << "the bias against set point plot";
  // Why lab-b's adaptive soak ended, in its Table I row.
  EXPECT_TRUE(has("adaptive soak ended"));
  EXPECT_TRUE(has("target reached: U95 &lt;= 0.05 °/h on every gated axis")) << "the stop";
  // The comment escaped: no script, no request anywhere.
  EXPECT_TRUE(has("&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt; &amp; after")) << h;
  EXPECT_FALSE(has("<script"));
  EXPECT_FALSE(has("http://"));
  EXPECT_FALSE(has("https://"));
  EXPECT_FALSE(has("src="));
  EXPECT_FALSE(has("<link"));

  // Since: only lab-b's run and lab-a's second; lab-a/1's numbers are gone.
  options.since_utc = "2026-11-21";
  auto since = lab_summary_html(pg(), options);
  ASSERT_TRUE(since.ok()) << since.error().message;
  EXPECT_NE(since->find("1.2105"), std::string::npos);
  EXPECT_EQ(since->find("1.2031"), std::string::npos);
  EXPECT_EQ(since->find(kUuidA1), std::string::npos);
  EXPECT_NE(since->find("started since 2026-11-21 00:00:00 UTC"), std::string::npos);
}

TEST_F(LabReadTest, ReadsSeeRelayedUpdatesAndTombstones) {
  // lab-a's run 2 completes and its segment is deleted (a re-analysis):
  // newer outbox rows of the same keys.
  testing::StationOutbox update(static_cast<int64_t>(testing::station_a_outbox().records.size()));
  update.run(2, kUuidA2, "rate-sweep", "completed", "2026-11-22T09:30:00.000Z",
             "2026-11-22T15:00:00.000Z", "Bo Lind", "", json::array(), json::array({"TS-7"}));
  update.tombstone("segment", kUuidA2, "4");
  auto station = PgConnection::connect(conninfo("lab_a_relay"));
  ASSERT_TRUE(station.ok());
  auto pushed = push_batch(*station, "lab-a", update.records);
  ASSERT_TRUE(pushed.ok()) << pushed.error().message;

  auto run = lab_run_json(pg(), "lab-a/2");
  ASSERT_TRUE(run.ok()) << run.error().message;
  const json j = json::parse(*run);
  EXPECT_EQ(j["run"]["state"], "completed");
  EXPECT_EQ(j["segments"].size(), 0u);
}

TEST_F(LabReadTest, AStationRoleMayNotReadAndIsToldWhy) {
  auto station = PgConnection::connect(conninfo("lab_a_relay"));
  ASSERT_TRUE(station.ok());
  auto runs = lab_runs(*station, {});
  ASSERT_FALSE(runs.ok()) << "a station's role writes; it does not read the lab's views";
  EXPECT_NE(runs.error().message.find("add-reader"), std::string::npos) << runs.error().message;
}

TEST_F(LabReadTest, AnUnmigratedDatabaseSaysSo) {
  const std::string other = dbname_ + "_empty";
  ASSERT_EQ(cluster().create_database(other), "");
  auto pg = PgConnection::connect(cluster().conninfo(testing::PgCluster::kAdmin, other));
  ASSERT_TRUE(pg.ok());
  auto stations = lab_stations(*pg);
  ASSERT_FALSE(stations.ok());
  EXPECT_NE(stations.error().message.find("gyrotherm lab migrate"), std::string::npos)
      << stations.error().message;
  // The connection is usable afterwards (the snapshot was rolled back).
  auto rows = pg->exec("SELECT 1");
  EXPECT_TRUE(rows.ok()) << rows.error().message;
}

}  // namespace
}  // namespace gyrotherm::lab
