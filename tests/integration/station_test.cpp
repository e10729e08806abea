// End-to-end: gyrotherm-sim + gyrothermd as real processes on loopback run a
// short accelerated schedule; the database must tell the truth of it.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>

#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/cli/http_client.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/config/run_config.h"
#include "gyrotherm/config/sim_endpoints.h"
#include "gyrotherm/drivers/modbus_device.h"
#include "gyrotherm/sim/simulator.h"
#include "gyrotherm/storage/database.h"
#include "process.h"
#include "station_fixture.h"
#include "test_files.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using testing::ChildProcess;
using ::testing::HasSubstr;
using testing::kLatitudeDeg;
using testing::kRateHz;
using testing::kTimeScale;
using testing::kWhiteNoiseDph;
using testing::StationTest;
using testing::wait_until;

TEST_F(StationTest, ShortScheduleEndToEnd) {
  start_sim();
  start_daemon({"--exit-when-done"});

  // Live status over HTTP while the run goes.
  std::optional<nlohmann::json> live;
  ASSERT_TRUE(wait_until(
      [&] {
        live = status();
        return live && live->value("state", "") == "acquiring" && !(*live)["top_c"].is_null() &&
               !(*live)["gyro_rate_dph"].is_null();
      },
      std::chrono::seconds(60)))
      << daemon_->log();
  EXPECT_EQ((*live)["run_id"], 1);
  EXPECT_TRUE((*live)["devices"]["chamber"]["connected"].get<bool>());
  EXPECT_TRUE((*live)["devices"]["gyro"]["connected"].get<bool>());
  EXPECT_NEAR((*live)["top_c"].get<double>(), 23.0, 1.0);

  const auto code = daemon_->wait(std::chrono::seconds(120));
  ASSERT_TRUE(code.has_value()) << "daemon did not finish the schedule\n" << daemon_->log();
  EXPECT_EQ(*code, 0) << daemon_->log();

  auto db = storage::Database::open_read_only((dir_ / "station.db").string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto run = db->run(1);
  ASSERT_TRUE(run.ok()) << run.error().message;
  EXPECT_EQ(run->state, "completed");
  EXPECT_FALSE(run->ended_utc.empty());

  auto segments = db->segments(1);
  ASSERT_TRUE(segments.ok());
  ASSERT_EQ(segments->size(), 3u);
  for (const auto& s : *segments) EXPECT_EQ(s.state, "completed") << s.label;
  EXPECT_EQ((*segments)[1].kind, "ramp");
  EXPECT_NEAR(*(*segments)[1].t_acquire_end_s - *(*segments)[1].t_acquire_start_s, 90.0, 2.0)
      << "3 °C at 2 °C/min";

  // Full-rate gyro samples over the whole run, stream without gaps.
  auto count = db->count_gyro_samples(1);
  ASSERT_TRUE(count.ok());
  const double run_s = *segments->back().t_end_s;
  EXPECT_GT(static_cast<double>(*count), 0.97 * run_s * kRateHz);
  EXPECT_LT(static_cast<double>(*count), 1.01 * run_s * kRateHz + 10);

  // Table I rows: one per soak, on 1 s bins of a 6 min window.
  auto stats = db->segment_stats(1);
  ASSERT_TRUE(stats.ok());
  ASSERT_EQ(stats->size(), 2u);
  const double earth_dph = 15.041067 * std::sin(kLatitudeDeg * M_PI / 180.0);
  for (const auto& r : *stats) {
    SCOPED_TRACE(fmt::format("segment {}", r.segment_index + 1));
    // 360 one-second bins, one either way: the window ends where the
    // samples cover the 6 min (soaks are credited for data), which need
    // not fall on a whole second of the bin grid.
    EXPECT_GE(r.n, 359);
    EXPECT_LE(r.n, 361);
    EXPECT_NEAR(r.duration_s, 360.0, 1.0);
    EXPECT_NEAR(r.temp_mean_c, r.setpoint_c, 0.5);
    // Truth: Earth + 0.05 + 0.004 T (+ small gradient terms when settled).
    const double truth_dph = earth_dph + 0.05 + 0.004 * r.temp_mean_c;
    // The mean of 360 one-second points with 1 °/h noise: σ ≈ 0.053 °/h.
    EXPECT_NEAR(r.bias_mean_dph, truth_dph, 0.25);
    EXPECT_NEAR(r.bias_std_dph, kWhiteNoiseDph, 0.15 * kWhiteNoiseDph);
    EXPECT_LT(r.bias_std_ma_dph, r.bias_std_dph / 4.0) << "101-point average shrinks white noise";
    EXPECT_NEAR(r.bias_mean_earth_removed_dph, r.bias_mean_dph - earth_dph, 1e-9);
    EXPECT_NEAR(r.earth_rate_dph, earth_dph, 1e-9);
    // The mean's uncertainty: white noise, so u is the standard error of
    // the 360 bins' mean (within the spread of one soak's noise model), and
    // the 95 % interval is about two of it.
    ASSERT_TRUE(r.bias_u) << r.bias_u_note;
    const double se_dph = r.bias_std_dph / std::sqrt(static_cast<double>(r.n));
    EXPECT_NEAR(r.bias_u->u_dph, se_dph, 0.3 * se_dph);
    EXPECT_NEAR(r.bias_u->expanded_dph / r.bias_u->u_dph, 1.96, 0.15);
    EXPECT_FALSE(r.bias_u->random_walk_dominated);
  }

  // Every state change is an event row with a reason.
  auto events = db->events(1);
  ASSERT_TRUE(events.ok());
  std::vector<std::string> to_states;
  for (const auto& e : *events) {
    if (e.kind == "state") to_states.push_back(e.to_state);
    EXPECT_FALSE(e.message.empty());
  }
  EXPECT_THAT(to_states, ::testing::ElementsAre("settling", "acquiring", "ramping", "settling",
                                                "acquiring", "completed"));

  // The run's analysis ran on the worker before the daemon exited: an
  // "analysis" event, the Allan deviation of each soak, and the configured
  // model fitted in both forms, each with its inputs.
  const auto analysis_event =
      std::find_if(events->begin(), events->end(),
                   [](const storage::EventRecord& e) { return e.kind == "analysis"; });
  ASSERT_NE(analysis_event, events->end()) << daemon_->log();
  EXPECT_NE(analysis_event->message.find("2 Allan deviation(s), 2 fit(s)"), std::string::npos)
      << analysis_event->message;
  auto allan = db->allan(1);
  ASSERT_TRUE(allan.ok()) << allan.error().message;
  ASSERT_EQ(allan->size(), 2u);
  for (const auto& a : *allan) {
    SCOPED_TRACE(fmt::format("segment {}", a.segment_index + 1));
    EXPECT_EQ(a.taus, "octave");
    EXPECT_NEAR(a.tau0_s, 1.0 / kRateHz, 1e-3);
    EXPECT_NEAR(a.t_to_s - a.t_from_s, 360.0, 1.0);
    ASSERT_FALSE(a.tau_s.empty());
    EXPECT_EQ(a.adev_dph.size(), a.tau_s.size());
    // White noise of 1 °/h per 1 s mean: sigma(1 s) = 1 °/h, ARW = 1/60 °/√h.
    ASSERT_TRUE(a.angle_random_walk_dprh.has_value());
    EXPECT_NEAR(*a.angle_random_walk_dprh, kWhiteNoiseDph / 60.0, 0.2 * kWhiteNoiseDph / 60.0);
    const auto inputs = nlohmann::json::parse(a.inputs_json);
    EXPECT_EQ(inputs["segment"], a.segment_index + 1);
  }
  auto fits = db->fits(1);
  ASSERT_TRUE(fits.ok()) << fits.error().message;
  ASSERT_EQ(fits->size(), 2u);
  std::vector<std::string> forms;
  for (const auto& f : *fits) {
    forms.push_back(f.form);
    EXPECT_EQ(f.model, "T1+R1+G1");
    EXPECT_EQ(f.run_ids, std::vector<int64_t>{1});
    EXPECT_GT(static_cast<double>(f.n), 0.95 * run_s);  // every second of the run, binned
    // Residual std ~ the white noise of 1 s means.
    EXPECT_NEAR(f.residual_std_dph, kWhiteNoiseDph, 0.15 * kWhiteNoiseDph);
    const auto c = nlohmann::json::parse(f.coefficients_json);
    for (const char* key : {"T1", "R1", "G1"}) EXPECT_TRUE(c.contains(key)) << key;
    const auto inputs = nlohmann::json::parse(f.inputs_json);
    EXPECT_EQ(inputs["model"], "T1+R1+G1");
    EXPECT_EQ(inputs["derivative_window_s"], 60.0);
  }
  std::sort(forms.begin(), forms.end());
  EXPECT_EQ(forms, (std::vector<std::string>{"centered", "paper"}));

  // A run that completed while its analysis never ran (the daemon stopped in
  // between) is analysed at the next start.
  {
    auto rw = storage::Database::open((dir_ / "station.db").string());
    ASSERT_TRUE(rw.ok()) << rw.error().message;
    ASSERT_TRUE(rw->exec("DELETE FROM allan; DELETE FROM fit_runs; DELETE FROM fits; "
                         "DELETE FROM events WHERE kind = 'analysis'")
                    .ok());
  }
  start_daemon({"--exit-when-done"}, /*with_schedule=*/false);
  const auto again = daemon_->wait(std::chrono::seconds(60));
  ASSERT_TRUE(again.has_value()) << daemon_->log();
  EXPECT_EQ(*again, 0) << daemon_->log();
  auto redone_allan = db->allan(1);
  ASSERT_TRUE(redone_allan.ok());
  EXPECT_EQ(redone_allan->size(), 2u) << daemon_->log();
  auto redone_fits = db->fits(1);
  ASSERT_TRUE(redone_fits.ok());
  ASSERT_EQ(redone_fits->size(), 2u) << daemon_->log();
  // The same data and settings give the same numbers.
  for (const auto& f : *redone_fits) {
    const auto before = std::find_if(fits->begin(), fits->end(),
                                     [&](const storage::FitRecord& b) { return b.form == f.form; });
    ASSERT_NE(before, fits->end());
    EXPECT_EQ(f.coefficients_json, before->coefficients_json) << f.form;
  }
}

// The configuration stored with a run is the one in force: the file edited
// on disk after the daemon started changes neither what is stored nor what
// the analysis uses; the CLI and reports read the same settings back.
// Two daemons must never share one database: the second would mark the
// first's run interrupted and write its chamber. The second refuses at
// start-up, naming the first's pid, also when its config reaches the file
// through a symlink, and the first's run goes on untouched.
TEST_F(StationTest, SecondDaemonOnTheSameDatabaseIsRefusedAndTheRunGoesOn) {
  // A soak long enough (2 h of station time, 36 s of wall time) to outlast
  // both refusals (each waits up to 5 s for the lock).
  write(dir_ / "schedule.toml", testing::soak_schedule("long", 23.0, 120));
  start_sim();
  start_daemon();
  std::optional<nlohmann::json> live;
  ASSERT_TRUE(wait_until(
      [&] {
        live = status();
        return live && live->value("state", "") == "acquiring";
      },
      std::chrono::seconds(60)))
      << daemon_->log();

  // The same config (same database), another API port; then a config
  // naming the database through a symlink in another directory.
  const fs::path link_dir = dir_ / "elsewhere";
  fs::create_directories(link_dir);
  fs::create_symlink(dir_ / "station.db", link_dir / "alias.db");
  std::string text;
  {
    std::ifstream in(dir_ / "station.toml");
    text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  const auto with = [&](const std::string& from, const std::string& to) {
    std::string t = text;
    t.replace(t.find(from), from.size(), to);
    return t;
  };
  const std::string port_line = fmt::format("port = {}", api_port_);
  const std::string other_port = fmt::format("port = {}", testing::free_tcp_port());
  write(dir_ / "second.toml", with(port_line, other_port));
  std::string aliased = with(port_line, other_port);
  const std::string db_line = fmt::format("db = \"{}/station.db\"", dir_.string());
  aliased.replace(aliased.find(db_line), db_line.size(),
                  fmt::format("db = \"{}\"", (link_dir / "alias.db").string()));
  write(dir_ / "aliased.toml", aliased);

  for (const char* config : {"second.toml", "aliased.toml"}) {
    ChildProcess second({bin("gyrothermd"), "--config", (dir_ / config).string(), "--time-scale",
                         fmt::format("{}", time_scale_)},
                        (dir_ / "second.log").string());
    const auto code = second.wait(std::chrono::seconds(30));
    ASSERT_TRUE(code.has_value()) << config << ": the second daemon kept running";
    EXPECT_EQ(*code, 1) << second.log();
    EXPECT_THAT(second.log(), HasSubstr("run by another gyrothermd"));
    EXPECT_THAT(second.log(), HasSubstr(fmt::format("pid {}", daemon_->pid())));
  }

  // The first daemon still runs its run, and the run was never interrupted.
  ASSERT_TRUE(daemon_->running()) << daemon_->log();
  const double t_before = status()->value("t_run_s", 0.0);
  ASSERT_TRUE(wait_until([&] { return status() && status()->value("t_run_s", 0.0) > t_before + 5; },
                         std::chrono::seconds(30)));
  auto now = status();
  ASSERT_TRUE(now);
  EXPECT_EQ((*now)["run_id"], 1);
  EXPECT_NE(now->value("state", ""), "interrupted");
  auto db = storage::Database::open_read_only((dir_ / "station.db").string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto events = db->events(1);
  ASSERT_TRUE(events.ok());
  for (const auto& e : *events) EXPECT_NE(e.to_state, "interrupted") << e.message;
}

TEST_F(StationTest, StoredConfigIsTheOneInForceNotTheFileOnDisk) {
  const fs::path config = dir_ / "station.toml";
  auto edit = [&](const std::string& from, const std::string& to) {
    std::string text = testing::read_text(config);
    const auto at = text.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    text.replace(at, from.size(), to);
    write(config, text);
  };
  edit("model = \"T1+R1+G1\"", "model = \"T1+R1+G1\"\nma_window = 51");
  start_sim();
  start_daemon({"--exit-when-done"}, /*with_schedule=*/false);
  ASSERT_TRUE(wait_until([&] { return status().has_value(); }, std::chrono::seconds(30)))
      << daemon_->log();
  // The daemon runs with ma_window 51; the file now says 11 and another name.
  edit("ma_window = 51", "ma_window = 11");
  edit("name = \"integration\"", "name = \"edited on disk\"");
  auto r = call("POST", "/api/v1/queue",
                nlohmann::json{{"schedule_toml", testing::soak_schedule("cfg", 23, 3)},
                               {"source", "cfg.toml"}}
                    .dump());
  ASSERT_TRUE(r && r->status == 201) << (r ? r->body : "no answer");
  const auto code = daemon_->wait(std::chrono::seconds(120));
  ASSERT_TRUE(code.has_value()) << daemon_->log();
  EXPECT_EQ(*code, 0) << daemon_->log();

  // Read-write: a file an older daemon wrote is migrated first.
  auto db = storage::Database::open((dir_ / "station.db").string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto run = db->run(1);
  ASSERT_TRUE(run.ok()) << run.error().message;
  EXPECT_EQ(run->state, "completed");
  EXPECT_EQ(run->config_toml, "");
  const auto stored = nlohmann::json::parse(run->config_json, nullptr, false);
  ASSERT_TRUE(stored.is_object()) << "runs.config_json is not JSON:\n" << run->config_json;
  EXPECT_EQ(stored["analysis"]["ma_window"], 51);
  EXPECT_EQ(stored["station"]["name"], "integration");
  EXPECT_EQ(stored["analysis"]["model"], "T1+R1+G1");
  EXPECT_EQ(run->config_json.find(kToken), std::string::npos) << "no token in the database";
  // The daemon's analysis used it.
  auto stats = db->segment_stats(1);
  ASSERT_TRUE(stats.ok());
  ASSERT_EQ(stats->size(), 1u) << daemon_->log();
  EXPECT_EQ((*stats)[0].ma_window, 51);
  // And so do the CLI and the reports, which read the stored config.
  const config::RunConfig back = calibration::read_run_config(*run);
  EXPECT_EQ(back.ma_window, 51);
  EXPECT_EQ(back.station_name, "integration");
  auto settings = calibration::analysis_settings_of_run(*run);
  ASSERT_TRUE(settings.ok()) << settings.error().message;
  EXPECT_EQ(settings->table1.ma_window, 51u);
}

TEST_F(StationTest, SigtermInterruptsTheRunAndLeavesTheChamberSafe) {
  start_sim();
  start_daemon();
  ASSERT_TRUE(wait_until(
      [&] {
        auto s = status();
        return s && s->value("state", "") == "acquiring";
      },
      std::chrono::seconds(60)))
      << daemon_->log();
  daemon_->signal(SIGTERM);
  const auto code = daemon_->wait(std::chrono::seconds(20));
  ASSERT_TRUE(code.has_value()) << daemon_->log();
  EXPECT_EQ(*code, 0) << daemon_->log();

  auto db = storage::Database::open_read_only((dir_ / "station.db").string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto run = db->run(1);
  ASSERT_TRUE(run.ok());
  EXPECT_EQ(run->state, "interrupted");
  auto events = db->events(1);
  ASSERT_TRUE(events.ok());
  ASSERT_FALSE(events->empty());
  EXPECT_THAT(events->back().message, HasSubstr("SIGTERM"));
  EXPECT_TRUE(testing::integrity_ok(*db));

  // The chamber was left at the safe set point (23 °C).
  auto cfg = config::load_station_config((dir_ / "station.toml").string());
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  auto ep = config::read_sim_endpoints(cfg->simulator.endpoints_file);
  ASSERT_TRUE(ep.ok());
  config::apply_sim_endpoints(*cfg, *ep);
  drivers::ModbusDevice chamber("chamber", cfg->chamber.endpoint);
  auto sp = chamber.read(cfg->chamber.map.setpoint);
  ASSERT_TRUE(sp.ok()) << sp.error().message;
  EXPECT_DOUBLE_EQ(*sp, 23.0);
}

// The gyro line goes away (USB adapter unplugged, pty closed) and comes back
// at the same path: the daemon keeps running, reports it, and resumes.
TEST_F(StationTest, GyroLineClosedAndReopenedStreamResumes) {
  ASSERT_NO_FATAL_FAILURE(start_sim_in_process());
  start_daemon();

  auto gyro = [&](const char* key) -> uint64_t {
    auto s = status();
    return s ? (*s)["devices"]["gyro"][key].get<uint64_t>() : 0;
  };
  auto connected = [&] {
    auto s = status();
    return s && (*s)["devices"]["gyro"]["connected"].get<bool>();
  };
  ASSERT_TRUE(wait_until([&] { return gyro("samples") > 500; }, std::chrono::seconds(30)))
      << daemon_->log();
  // The run's samples before the outage are stored (committed), so the
  // stored series can show the outage: the reader counts samples from its
  // start, which on a busy machine may all come before the run's.
  ASSERT_TRUE(wait_until(
      [&] {
        auto st = status();
        return st && (*st)["storage"]["gyro_rows"].get<uint64_t>() > 50;
      },
      std::chrono::seconds(30)))
      << daemon_->log();

  in_process_sim_->close_pty();
  ASSERT_TRUE(wait_until([&] { return !connected(); }, std::chrono::seconds(20))) << daemon_->log();
  auto s = status();
  ASSERT_TRUE(s.has_value());
  EXPECT_FALSE((*s)["devices"]["gyro"]["last_error"].get<std::string>().empty());
  const uint64_t before = gyro("samples");

  ASSERT_TRUE(in_process_sim_->reopen_pty().ok());
  ASSERT_TRUE(wait_until([&] { return connected() && gyro("samples") > before + 500; },
                         std::chrono::seconds(30)))
      << daemon_->log();
  EXPECT_GE(gyro("reopens"), 1u);
  EXPECT_EQ(gyro("crc_failures"), 0u);
  EXPECT_TRUE(daemon_->running());
  daemon_->signal(SIGTERM);
  EXPECT_EQ(daemon_->wait(std::chrono::seconds(20)), std::optional<int>(0)) << daemon_->log();
  in_process_sim_->stop();

  // Timestamps stay strictly increasing across the outage. The 500 samples
  // after the reopen all fall in the run; of those before the outage only
  // the ones after the run's start are stored (the status counts them all).
  auto db = storage::Database::open_read_only((dir_ / "station.db").string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto samples = db->gyro_samples(1, 0.0, 1e9);
  ASSERT_TRUE(samples.ok());
  ASSERT_GT(samples->size(), 500u);
  double max_gap_s = 0;
  for (std::size_t i = 1; i < samples->size(); ++i) {
    ASSERT_GT((*samples)[i].t_s, (*samples)[i - 1].t_s) << i;
    max_gap_s = std::max(max_gap_s, (*samples)[i].t_s - (*samples)[i - 1].t_s);
  }
  // Samples from both sides of the outage are stored: the series has its gap.
  EXPECT_GT(max_gap_s, 3.0 / kRateHz) << "no outage inside the stored samples\n" << daemon_->log();
}

// Garbage on the serial line: every corrupted frame is rejected and counted,
// and no sample comes from one (each shows as a missing frame).
TEST_F(StationTest, CorruptedFramesAreRejectedAndCounted) {
  ASSERT_NO_FATAL_FAILURE(start_sim_in_process());
  start_daemon();
  auto gyro = [&](const char* key) -> uint64_t {
    auto s = status();
    return s ? (*s)["devices"]["gyro"][key].get<uint64_t>() : 0;
  };
  ASSERT_TRUE(wait_until([&] { return gyro("samples") > 200; }, std::chrono::seconds(30)))
      << daemon_->log();
  in_process_sim_->set_frame_corruption_rate(0.02);
  ASSERT_TRUE(wait_until([&] { return in_process_sim_->status().frames_fault_corrupted >= 50; },
                         std::chrono::seconds(30)));
  in_process_sim_->set_frame_corruption_rate(0.0);
  const uint64_t corrupted = in_process_sim_->status().frames_fault_corrupted;
  // A corrupted frame counts as missed once the next good frame shows the gap.
  ASSERT_TRUE(wait_until(
      [&] { return gyro("crc_failures") >= corrupted && gyro("frames_missed") >= corrupted; },
      std::chrono::seconds(20)))
      << "daemon saw " << gyro("crc_failures") << " CRC failures, " << gyro("frames_missed")
      << " missed of " << corrupted;
  EXPECT_EQ(gyro("crc_failures"), corrupted);
  EXPECT_EQ(gyro("frames_missed"), corrupted) << "each corrupted frame is a missing sample";
  EXPECT_TRUE(daemon_->running());
}

TEST_F(StationTest, BadConfigFailsFastWithFileLineKey) {
  write(dir_ / "bad.toml", "[station]\nlatitude_deg = 95\n[chamber]\n[probes]\n[gyro]\n");
  ChildProcess d({bin("gyrothermd"), "--config", (dir_ / "bad.toml").string()},
                 (dir_ / "bad.log").string());
  const auto code = d.wait(std::chrono::seconds(10));
  ASSERT_TRUE(code.has_value());
  EXPECT_EQ(*code, 2);
  EXPECT_THAT(d.log(), HasSubstr("bad.toml:2: station.latitude_deg: 95 is out of range"));
}

TEST_F(StationTest, UnreachableDevicesDoNotKillTheDaemon) {
  // No simulator: endpoints point at a closed port and a missing pty.
  config::SimEndpoints ep{"127.0.0.1", testing::free_tcp_port(), (dir_ / "no-such-pty").string(), 0,
                          ""};
  ASSERT_TRUE(config::write_sim_endpoints((dir_ / "endpoints.toml").string(), ep).ok());
  start_daemon();
  std::optional<nlohmann::json> s;
  ASSERT_TRUE(wait_until(
      [&] {
        s = status();
        return s && (*s)["devices"]["chamber"]["errors"].get<uint64_t>() > 3 &&
               (*s)["devices"]["gyro"]["read_errors"].get<uint64_t>() +
                       !(*s)["devices"]["gyro"]["last_error"].get<std::string>().empty() >
                   0;
      },
      std::chrono::seconds(30)))
      << daemon_->log();
  EXPECT_FALSE((*s)["devices"]["chamber"]["connected"].get<bool>());
  EXPECT_THAT((*s)["devices"]["chamber"]["last_error"].get<std::string>(), HasSubstr("chamber"));
  ASSERT_TRUE(wait_until(
      [&] {
        s = status();
        return s && (*s)["state"] == "suspended" && (*s)["interlocks"].size() >= 2;
      },
      std::chrono::seconds(30)))
      << "the run is held by the silent-device interlocks: " << (s ? s->dump() : "")
      << daemon_->log();
  EXPECT_THAT((*s)["interlocks"].dump(), HasSubstr("chamber_silent"));
  EXPECT_THAT((*s)["interlocks"].dump(), HasSubstr("probes_silent"));
  EXPECT_TRUE(daemon_->running());
  daemon_->signal(SIGTERM);
  EXPECT_EQ(daemon_->wait(std::chrono::seconds(20)), std::optional<int>(0)) << daemon_->log();
}

}  // namespace
}  // namespace gyrotherm
