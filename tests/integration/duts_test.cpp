// Several devices under test through a real campaign: gyrotherm-sim serves
// three DUTs (two KVH 1750 on their own ptys, one ASCII test set), each with
// its own truth; gyrothermd records every channel of every DUT into chunked
// storage and analyses each DUT and axis. Checked against the simulator's
// truth file, through REST and the CLI, with the run's metadata.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include "station_fixture.h"
#include "three_duts.h"

namespace gyrotherm::testing {
namespace {

class DutsTest : public StationTest {
 protected:
  void SetUp() override {
    StationTest::SetUp();
    std::string text = station_config(dir_, api_port_);
    ASSERT_TRUE(with_three_duts(text));
    write(dir_ / "station.toml", text);
    write(dir_ / "schedule.toml", soak_schedule("two DUT soaks", 25.0, 6));
  }

  static double truth_bias_dph(const nlohmann::json& truth, const std::string& serial,
                               const std::string& axis, double temp_c) {
    return three_duts_truth_bias_dph(truth, serial, axis, temp_c);
  }

  std::string run_cli(const std::vector<std::string>& args, int* code = nullptr) {
    std::vector<std::string> argv{bin("gyrotherm")};
    argv.insert(argv.end(), args.begin(), args.end());
    const fs::path out = dir_ / "cli.out";
    ChildProcess cli(argv, out.string());
    const auto rc = cli.wait(std::chrono::seconds(30));
    if (code) *code = rc ? *rc : -1;
    std::ifstream in(out);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }
};

// `queue add --dut A --dut B` records A and B only: the third DUT has no
// place in the run, no sample and no Table I row, and the soak is credited
// for the named DUTs' data (the run ends though the third is never stored).
TEST_F(DutsTest, QueueAddDutRecordsTheDutsItNamesOnly) {
  write(dir_ / "short.toml", soak_schedule("two of three DUTs", 25.0, 2, 1));
  start_sim();
  start_daemon({}, /*with_schedule=*/false);
  ASSERT_TRUE(wait_until([&] { return status().has_value(); }, std::chrono::seconds(30)))
      << daemon_->log();
  int code = -1;
  const std::string out = run_cli({"queue", "add", (dir_ / "short.toml").string(), "--dut",
                                   "17-0042", "--dut", "TS-7", "--url", url(""), "--token", kToken},
                                  &code);
  ASSERT_EQ(code, 0) << out;

  ASSERT_TRUE(wait_until(
      [&] {
        auto events = get_json("/api/v1/runs/1/events");
        if (!events.is_array()) return false;
        return std::any_of(events.begin(), events.end(),
                           [](const auto& e) { return e.value("kind", "") == "analysis"; });
      },
      std::chrono::seconds(180)))
      << daemon_->log();

  auto db = storage::Database::open_read_only((dir_ / "station.db").string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto run_duts = db->run_duts(1);
  ASSERT_TRUE(run_duts.ok()) << run_duts.error().message;
  std::vector<std::string> serials;
  for (const auto& d : *run_duts) {
    serials.push_back(d.dut.serial);
    for (const auto& c : d.channels) {
      auto n = db->count_channel_samples(c.id);
      ASSERT_TRUE(n.ok()) << n.error().message;
      EXPECT_GT(*n, 0) << d.dut.serial << " " << c.spec.name;
    }
  }
  EXPECT_THAT(serials, ::testing::ElementsAre("17-0042", "TS-7"));
  auto stats = db->segment_stats(1);
  ASSERT_TRUE(stats.ok());
  ASSERT_FALSE(stats->empty());
  for (const auto& r : *stats) EXPECT_NE(r.dut_serial, "17-0043") << r.axis;
  auto run = get_json("/api/v1/runs/1");
  EXPECT_EQ(run["metadata"]["duts"], nlohmann::json::array({"17-0042", "TS-7"})) << run.dump(2);
}

TEST_F(DutsTest, ThreeDutsThroughACampaignEachRecoversItsOwnTruth) {
  start_sim();
  start_daemon({}, /*with_schedule=*/false);
  ASSERT_TRUE(wait_until([&] { return status().has_value(); }, std::chrono::seconds(30)))
      << daemon_->log();

  // Queued with its metadata over REST.
  const std::string schedule_text = [&] {
    std::ifstream in(dir_ / "schedule.toml");
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }();
  nlohmann::json add = {{"schedule_toml", schedule_text},
                        {"operator", "ana"},
                        {"comment", "three IMUs, first soak"},
                        {"tags", {"qualification", "lot-7"}}};
  auto added = call("POST", "/api/v1/queue", add.dump());
  ASSERT_TRUE(added.has_value());
  ASSERT_EQ(added->status, 201) << added->body;

  // Live: every DUT has a card's worth of status, rates per axis.
  std::optional<nlohmann::json> live;
  ASSERT_TRUE(wait_until(
      [&] {
        live = status();
        if (!live || live->value("state", "") != "acquiring") return false;
        const auto& duts = (*live)["duts"];
        if (!duts.is_array() || duts.size() != 3) return false;
        for (const auto& d : duts) {
          for (const auto& [axis, v] : d["rates_dph"].items()) {
            if (v.is_null()) return false;
          }
        }
        return true;
      },
      std::chrono::seconds(90)))
      << (live ? live->dump(2) : "no status") << daemon_->log();
  EXPECT_EQ((*live)["duts"][0]["serial"], "17-0042");
  EXPECT_EQ((*live)["duts"][2]["serial"], "TS-7");
  EXPECT_EQ((*live)["run_metadata"]["operator"], "ana");
  EXPECT_NEAR((*live)["duts"][0]["samples_per_s"].get<double>(), kRateHz, 1.0);

  // The run completes and is analysed.
  ASSERT_TRUE(wait_until(
      [&] {
        auto events = get_json("/api/v1/runs/1/events");
        if (!events.is_array()) return false;
        for (const auto& e : events) {
          if (e.value("kind", "") == "analysis") return true;
        }
        return false;
      },
      std::chrono::seconds(180)))
      << daemon_->log();

  std::ifstream truth_in(dir_ / "truth.json");
  const nlohmann::json truth = nlohmann::json::parse(truth_in);

  auto db = storage::Database::open_read_only((dir_ / "station.db").string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto run_duts = db->run_duts(1);
  ASSERT_TRUE(run_duts.ok()) << run_duts.error().message;
  ASSERT_EQ(run_duts->size(), 3u);
  EXPECT_EQ((*run_duts)[0].channels.size(), 8u) << "KVH 1750: 3 gyro, 3 accel, status, temp";

  // Every channel of every DUT was recorded at the DUT's rate.
  auto segments = db->segments(1);
  ASSERT_TRUE(segments.ok());
  const double run_s = *segments->back().t_end_s;
  // A DUT's own probes are read once a control tick, as the station's are:
  // as many readings as the station's temperature rows (at a time scale of
  // 200 a slow build ticks less often than once per station second).
  auto ticks = db->temperature_samples(1, 0, run_s + 1);
  ASSERT_TRUE(ticks.ok());
  for (const auto& d : *run_duts) {
    for (const auto& c : d.channels) {
      auto n = db->count_channel_samples(c.id);
      ASSERT_TRUE(n.ok()) << n.error().message;
      const double expected = c.spec.name.rfind("probe_", 0) == 0
                                  ? static_cast<double>(ticks->size())
                                  : run_s * kRateHz;
      EXPECT_GT(static_cast<double>(*n), 0.97 * expected) << d.dut.serial << " " << c.spec.name;
    }
  }

  // Table I per DUT and axis, each against its own truth (Earth rate
  // removed per the axis's orientation).
  auto stats = db->segment_stats(1);
  ASSERT_TRUE(stats.ok());
  const std::map<std::string, std::vector<std::string>> analysed = {
      {"17-0042", {"x", "y", "z"}}, {"17-0043", {"x", "z"}}, {"TS-7", {"x", "y"}}};
  std::size_t rows = 0;
  for (const auto& entry : analysed) {
    const std::string& serial = entry.first;  // (clang 14: no structured binding in a lambda)
    for (const auto& axis : entry.second) {
      SCOPED_TRACE(serial + " " + axis);
      const auto it = std::find_if(stats->begin(), stats->end(), [&](const auto& r) {
        return r.dut_serial == serial && r.axis == axis;
      });
      ASSERT_NE(it, stats->end()) << db->events(1)->back().message;
      ++rows;
      // 360 one-second bins, one either way (a data-credited window need
      // not end on the bin grid).
      EXPECT_GE(it->n, 359);
      EXPECT_LE(it->n, 361);
      // 360 one-second means of 1 °/h noise: σ ≈ 0.053 °/h.
      EXPECT_NEAR(it->bias_mean_earth_removed_dph,
                  truth_bias_dph(truth, serial, axis, it->temp_mean_c), 0.25);
    }
  }
  EXPECT_EQ(stats->size(), rows) << "one row per soak, DUT and analysed axis";

  // 17-0043's own probes (the simulator's read its shell + 0.1 °C) give its
  // rows their temperature; the others use the station's probes.
  auto temp_of = [&](const std::string& serial) {
    const auto it = std::find_if(stats->begin(), stats->end(),
                                 [&](const auto& r) { return r.dut_serial == serial; });
    return it == stats->end() ? NAN : it->temp_mean_c;
  };
  EXPECT_NEAR(temp_of("17-0043") - temp_of("17-0042"), 0.1, 0.05);
  // (averaged over each DUT's own 1-s bins: a few mK apart)
  EXPECT_NEAR(temp_of("TS-7"), temp_of("17-0042"), 0.01);

  // The raw samples out, exactly: a rate channel of the ASCII DUT as CSV.
  int code = 0;
  // Ten seconds from the middle of the run (a slow build opens the ASCII
  // line a few station seconds late).
  const double from_s = std::floor(run_s / 2);
  const std::string csv =
      run_cli({"samples", "--db", (dir_ / "station.db").string(), "--run", "1", "--dut", "TS-7",
               "--channel", "rate_y", "--from", fmt::format("{}", from_s), "--to",
               fmt::format("{}", from_s + 10)},
              &code);
  ASSERT_EQ(code, 0) << csv;
  EXPECT_THAT(csv, ::testing::StartsWith("t_s,rate_y (deg/h)")) << csv.substr(0, 200);
  EXPECT_NEAR(std::count(csv.begin(), csv.end(), '\n'), 1 + 10 * kRateHz, 2);

  // Metadata edited afterwards leaves an audit event; the DUT's history has the run.
  auto patched = call("PATCH", "/api/v1/runs/1", R"({"comment": "three IMUs, reviewed"})");
  ASSERT_TRUE(patched.has_value());
  EXPECT_EQ(patched->status, 200) << patched->body;
  auto run = get_json("/api/v1/runs/1");
  EXPECT_EQ(run["metadata"]["comment"], "three IMUs, reviewed");
  EXPECT_EQ(run["metadata"]["operator"], "ana");
  auto events = get_json("/api/v1/runs/1/events");
  EXPECT_TRUE(std::any_of(events.begin(), events.end(), [](const auto& e) {
    return e.value("kind", "") == "metadata" &&
           e.value("message", "").find("reviewed") != std::string::npos;
  })) << events.dump(2);
  auto history = get_json("/api/v1/duts/17-0043");
  ASSERT_TRUE(history.is_object()) << history.dump();
  EXPECT_EQ(history["runs"].size(), 1u) << history.dump(2).substr(0, 2000);
}

}  // namespace
}  // namespace gyrotherm::testing
