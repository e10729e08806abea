// The fault campaign (issue 7): the simulated station (real gyrotherm-sim
// and gyrothermd, Modbus TCP, a pty, a SQLite file, HTTP) under kill -9 at
// random moments, a dropped Modbus link, a hung-up gyro line, corrupted
// frames and a full disk. Each test checks the database file afterwards —
// integrity, committed samples kept, every run ended or resumed — and prints
// one "fault-campaign:" line per fault with its figures. scripts/fault-campaign
// runs the same tests at a larger scale (GYROTHERM_FAULT_KILLS).
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/mount.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>

#include "gyrotherm/core/shared_clock.h"
#include "gyrotherm/storage/database.h"
#include "station_fixture.h"

namespace gyrotherm {
namespace {

using ::testing::HasSubstr;
using testing::StationTest;
using testing::wait_until;
using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

constexpr double kCommitIntervalS = 0.2;  // [storage] commit_interval_s of the fixture

int env_int(const char* name, int fallback) {
  const char* v = std::getenv(name);
  return v && *v ? std::atoi(v) : fallback;
}

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

std::string replace_once(std::string text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

// PRAGMA integrity_check's answer ("ok" when the file is sound).
// The file itself (plain SQLite, whatever its schema version: a kill
// between two migrations at start-up leaves an older one). Opened
// read-write, as the next daemon opens it: a kill in the middle of a write
// (at start-up, a hot rollback journal before the switch to WAL; later, a
// write-ahead log index left half written) leaves what only a writer may
// recover, and a read-only connection gets "attempt to write a readonly
// database" (SQLITE_READONLY_ROLLBACK / _RECOVERY). The daemon is dead, so
// nothing else writes.
std::string integrity_check(const std::filesystem::path& db_path) {
  sqlite3* raw = nullptr;
  if (sqlite3_open_v2(db_path.c_str(), &raw, SQLITE_OPEN_READWRITE, nullptr) != SQLITE_OK) {
    const std::string why = raw ? sqlite3_errmsg(raw) : "out of memory";
    sqlite3_close(raw);
    return "cannot open: " + why;
  }
  std::unique_ptr<sqlite3, decltype(&sqlite3_close)> handle(raw, &sqlite3_close);
  sqlite3_busy_timeout(raw, 5000);
  sqlite3_stmt* st = nullptr;
  if (sqlite3_prepare_v2(raw, "PRAGMA integrity_check", -1, &st, nullptr) != SQLITE_OK) {
    return std::string("cannot prepare: ") + sqlite3_errmsg(raw);
  }
  std::string out;
  while (sqlite3_step(st) == SQLITE_ROW) {
    if (!out.empty()) out += "; ";
    out += reinterpret_cast<const char*>(sqlite3_column_text(st, 0));
  }
  sqlite3_finalize(st);
  return out;
}

int64_t count_between(storage::Database& db, int64_t run_id, double from_s, double to_s) {
  auto rows = db.gyro_samples(run_id, from_s, to_s);
  return rows ? static_cast<int64_t>(rows->size()) : -1;
}

std::string events_text(storage::Database& db, int64_t run_id) {
  std::string all;
  auto rows = db.events(run_id);
  if (!rows) return "events: " + rows.error().message;
  for (const auto& e : *rows) all += fmt::format("[{}] {}\n", e.kind, e.message);
  return all;
}

// The run's "resume" events: one per start-up that resumed it.
int resumes_of(storage::Database& db, int64_t run_id) {
  auto rows = db.events(run_id);
  if (!rows) return -1;
  return static_cast<int>(
      std::count_if(rows->begin(), rows->end(), [](const auto& e) { return e.kind == "resume"; }));
}

class FaultCampaignTest : public StationTest {
 protected:
  void TearDown() override {
    daemon_.reset();
    sim_.reset();
    in_process_sim_.reset();
    if (!tmpfs_.empty()) ::umount2(tmpfs_.c_str(), MNT_DETACH);
    StationTest::TearDown();
  }

  std::filesystem::path db_path() const {
    return db_path_.empty() ? dir_ / "station.db" : db_path_;
  }
  json daemon_status() {
    auto s = status();
    return s ? *s : json();
  }
  bool wait_status(const std::function<bool(const json&)>& pred, std::chrono::seconds timeout) {
    return wait_until(
        [&] {
          last_ = daemon_status();
          return !last_.is_null() && pred(last_);
        },
        timeout);
  }
  // Waits until the first run has completed.
  bool wait_run_completed() {
    return wait_until(
        [&] {
          auto runs = get_json("/api/v1/runs");
          return runs.is_array() && !runs.empty() && runs[0]["state"] == "completed";
        },
        std::chrono::seconds(120));
  }
  std::string diag() {
    return "\nlast status: " + last_.dump() + "\ndaemon log:\n" + daemon_->log();
  }
  // Waits until the in-process simulator's station clock reaches t_s.
  bool wait_sim_time(double t_s) {
    return wait_until([&] { return in_process_sim_->status().t_s >= t_s; },
                      std::chrono::seconds(60));
  }
  // The fixture's config with edits for this test.
  void write_config(const std::vector<std::pair<std::string, std::string>>& edits,
                    const std::string& extra = "") {
    std::string text = testing::station_config(dir_, api_port_);
    for (const auto& [from, to] : edits) text = replace_once(text, from, to);
    write(dir_ / "station.toml", text + extra);
  }

  json last_;
  std::filesystem::path db_path_;  // "": the fixture's <dir>/station.db
  std::string tmpfs_;              // mounted by the disk-full test
};

// `soaks` soaks of 4 min of acquisition, alternately at 23 and 26 °C, with
// 2 °C/min ramps between them: settling, acquiring and ramping each take a
// good share of the campaign.
std::string soaks_and_ramps(int soaks) {
  std::string text = "name = \"fault campaign\"\n";
  for (int i = 0; i < soaks; ++i) {
    const double setpoint_c = i % 2 == 0 ? 23.0 : 26.0;
    if (i > 0) {
      text += fmt::format("[[step]]\ntype = \"ramp\"\ntarget_c = {}\nrate_c_per_min = 2.0\n",
                          setpoint_c);
    }
    text += fmt::format(
        "[[step]]\ntype = \"soak\"\nsetpoint_c = {}\nstability_window_min = 2\n"
        "acquire_min = 4\n",
        setpoint_c);
  }
  return text;
}

// kill -9 at random moments (start-up, ramp, settling, acquisition, a commit
// in flight): after every kill the file passes integrity_check and holds
// every sample the daemon had before the last commit interval; each restart
// resumes the run (or marks it); the campaign completes with its analysis.
TEST_F(FaultCampaignTest, KillNineAtRandomMoments) {
  const int kills = std::max(1, env_int("GYROTHERM_FAULT_KILLS", 5));
  const unsigned seed = static_cast<unsigned>(
      env_int("GYROTHERM_FAULT_SEED", static_cast<int>(std::random_device{}() & 0x7fffffff)));
  std::printf("fault-campaign: kill -9 x%d, seed %u (GYROTHERM_FAULT_SEED to repeat)\n", kills,
              seed);
  std::mt19937 rng(seed);
  // A quarter of the moments fall in the start-up (database opening, run
  // resume), the rest anywhere in the campaign.
  std::bernoulli_distribution in_start_up(0.25);
  std::uniform_real_distribution<double> start_up_s(0.02, 0.4), running_s(0.4, 2.5);
  // Half of the others right after a step ends (the status shows the next
  // step): a soak's tail, and the step change with its checkpoint.
  std::bernoulli_distribution at_step_end(0.5);
  // About 350 station seconds go by per kill (time scale 200), 500 per
  // soak and ramp: the kills spread over the whole campaign.
  const int soaks = std::max(2, kills * 2 / 3);
  write(dir_ / "schedule.toml", soaks_and_ramps(soaks));
  start_sim();
  start_daemon();
  // The one station clock (the simulator's, which the daemon follows),
  // read with the wall time while the test polls: how long ago, in wall
  // seconds, the clock passed a given station time. Station time is not
  // wall time × 200 on a busy machine.
  auto clock_map = SharedClockMap::open((dir_ / "endpoints.toml.clock").string());
  ASSERT_TRUE(clock_map.ok()) << clock_map.error().message;
  std::deque<std::pair<Clock::time_point, double>> clock_seen;  // (wall, station s)
  auto see_clock = [&] {
    const auto now = Clock::now();
    clock_seen.emplace_back(now, read_shared_clock(**clock_map).t_s);
    while (!clock_seen.empty() && now - clock_seen.front().first > std::chrono::seconds(30)) {
      clock_seen.pop_front();
    }
  };

  // Per kill: the run and what the file held right after it.
  struct Committed {
    int64_t run_id;
    double last_t_s;
    int64_t count;
  };
  std::vector<Committed> committed;
  std::vector<double> lost_wall_s;
  std::map<std::string, int> states_at_kill;
  int resumes_checked = 0;
  int64_t open_run = 0;  // a run the previous kill left open (0: none)
  int resumes_before = 0;
  const double allowance_s = 0.25 * testing::time_factor();

  for (int k = 0; k < kills; ++k) {
    // Poll the status until the random moment; the last answer tells what
    // the daemon had acquired just before the kill.
    const auto started = Clock::now();
    // This daemon's life only: what it lost, it had after it started.
    clock_seen.clear();
    const bool start_up = in_start_up(rng);
    const double moment_s = start_up ? start_up_s(rng) : running_s(rng);
    const bool step_end = !start_up && at_step_end(rng);
    json before;
    std::optional<int64_t> first_step;
    while (seconds_since(started) < moment_s ||
           (step_end && seconds_since(started) < 30 * testing::time_factor())) {
      see_clock();
      if (json s = daemon_status(); !s.is_null()) {
        before = s;
        if (step_end && s["step"]["index"].is_number()) {
          const int64_t index = s["step"]["index"].get<int64_t>();
          if (!first_step) first_step = index;
          if (index != *first_step) break;  // the step changed: kill now
        }
      }
    }
    if (step_end) ++states_at_kill["step end"];
    see_clock();
    const auto killed_at = Clock::now();
    daemon_->signal(SIGKILL);
    ASSERT_TRUE(daemon_->wait(std::chrono::seconds(10)).has_value());
    const std::string state =
        before.is_null() || moment_s < 0.4 ? "start-up" : before["state"].get<std::string>();
    ++states_at_kill[state];

    if (!std::filesystem::exists(db_path())) {
      // Killed in its start-up before it created the database: nothing was
      // recorded, so nothing can be lost. Started again with the schedule.
      ++states_at_kill["before the database"];
      open_run = 0;
      start_daemon();
      continue;
    }
    ASSERT_EQ(integrity_check(db_path()), "ok") << "after kill " << k + 1;
    auto db = storage::Database::open_read_only(db_path().string());
    const bool created_only =
        !db.ok() &&
        db.error().message.find("not a gyrotherm database (empty)") != std::string::npos;
    if (!db.ok() &&
        (created_only || db.error().message.find("older than this build") != std::string::npos)) {
      // Killed between creating the file and its first schema migration, or
      // between two migrations (each is its own transaction): the next start
      // finishes them. Nothing was recorded; nothing else to check.
      ++states_at_kill[created_only ? "before the schema" : "migration"];
      open_run = 0;
      start_daemon();  // it died before it could queue the schedule
      continue;
    }
    ASSERT_TRUE(db.ok()) << db.error().message;
    auto runs = db->runs();
    ASSERT_TRUE(runs.ok());
    auto queued = db->queue_entries();
    ASSERT_TRUE(queued.ok());
    // Killed in its start-up before it queued the schedule: queue it again.
    const bool queue_again = runs->empty() && queued->empty();

    // The previous kill left a run open: this start (it answered, so its
    // start-up was done) resumed it or marked it.
    if (open_run != 0 && !before.is_null()) {
      auto run = db->run(open_run);
      ASSERT_TRUE(run.ok());
      const int resumes = resumes_of(*db, open_run);
      EXPECT_TRUE(resumes == resumes_before + 1 || run->state == "interrupted")
          << "kill " << k + 1 << ": run " << open_run << " is " << run->state << " after "
          << resumes << " resumes (" << resumes_before << " before)";
      ++resumes_checked;
    }
    open_run = 0;
    for (const auto& r : *runs) {
      if (r.state != "completed" && r.state != "failed" && r.state != "interrupted") {
        open_run = r.id;
        resumes_before = resumes_of(*db, r.id);
      }
    }

    if (!before.is_null() && !before["run_id"].is_null() && before["state"] != "queued") {
      const int64_t run_id = before["run_id"].get<int64_t>();
      const double run_t0_s = before["t_station_s"].get<double>() - before["t_run_s"].get<double>();
      auto last = db->last_sample_t_s(run_id);
      ASSERT_TRUE(last.ok());
      if (*last) {
        // The wall seconds between the clock passing the last stored sample
        // and the kill: what the kill lost (0 when the clock never passed it
        // while the test watched, i.e. nothing after it was due; at most this
        // daemon's life, when the clock had passed it before this start).
        const double last_station_s = run_t0_s + **last;
        double lost_s = 0;
        for (const auto& [wall, t_s] : clock_seen) {
          if (t_s > last_station_s) {
            lost_s = std::max(0.0, std::chrono::duration<double>(killed_at - wall).count());
            break;
          }
        }
        lost_wall_s.push_back(lost_s);
        EXPECT_LE(lost_s, kCommitIntervalS + allowance_s)
            << "kill " << k + 1 << " in state " << state << ": the clock passed the file's last "
            << "sample (run t = " << **last << " s) " << lost_s << " wall s before the kill";
        committed.push_back({run_id, **last, count_between(*db, run_id, -1e12, **last + 1e-9)});
      }
    }
    start_daemon({}, queue_again);
  }

  // The rest of the campaign, undisturbed. The daemon stopped here may not
  // have queued the schedule yet (it was just started): then it is queued
  // with the restart.
  daemon_->signal(SIGKILL);
  ASSERT_TRUE(daemon_->wait(std::chrono::seconds(10)).has_value());
  bool queued = false;
  if (std::filesystem::exists(db_path())) {
    auto db = storage::Database::open_read_only(db_path().string());
    if (db.ok()) {
      auto runs = db->runs();
      auto entries = db->queue_entries();
      queued = runs.ok() && entries.ok() && !(runs->empty() && entries->empty());
    }
  }
  start_daemon({"--exit-when-done"}, !queued);
  const auto code =
      daemon_->wait(std::chrono::seconds(static_cast<int>(240 * testing::time_factor())));
  ASSERT_EQ(code, std::optional<int>(0)) << daemon_->log();

  ASSERT_EQ(integrity_check(db_path()), "ok");
  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok());
  auto runs = db->runs();
  ASSERT_TRUE(runs.ok());
  ASSERT_FALSE(runs->empty());
  int completed_runs = 0;
  for (const auto& r : *runs) {
    EXPECT_TRUE(r.state == "completed" || r.state == "interrupted")
        << "run " << r.id << " left " << r.state;
    completed_runs += r.state == "completed";
  }
  EXPECT_EQ(completed_runs, 1) << "the campaign completed once";
  for (const auto& c : committed) {
    EXPECT_EQ(count_between(*db, c.run_id, -1e12, c.last_t_s + 1e-9), c.count)
        << "samples committed before a kill are all still there (run " << c.run_id
        << ", up to t = " << c.last_t_s << " s)";
  }
  const auto& run = runs->back();
  auto stats = db->segment_stats(run.id);
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(stats->size(), static_cast<std::size_t>(soaks)) << "a Table I row per soak\n"
                                                            << events_text(*db, run.id);
  // Each soak's Table I row has the data its schedule asked for: 4 min of
  // 1 s bins, but for a partial bin at the end of each window and a few
  // seconds where the gyro stream restarts after each resume (6 allowed per
  // restart; observed 2-3). A restart credits no time without samples
  // (issue 15, item 7): before, a whole commit interval could be missing.
  // NOTE: the loss at the stream's restart is the gyro reader's, left open.
  auto segs = db->segments(run.id);
  ASSERT_TRUE(segs.ok());
  for (const auto& row : *stats) {
    const auto seg = std::find_if(segs->begin(), segs->end(),
                                  [&](const auto& s) { return s.id == row.segment_id; });
    ASSERT_NE(seg, segs->end());
    const auto windows = static_cast<int64_t>(seg->windows.size());
    EXPECT_GE(row.n, 240 - windows - 6 * (windows - 1))
        << "soak " << row.segment_index + 1 << " of run " << run.id << "\n"
        << testing::window_coverage(*db, run.id, seg->windows) << events_text(*db, run.id);
  }
  // Timestamps stay strictly increasing across every restart.
  auto samples = db->gyro_samples(run.id, -1e12, 1e12);
  ASSERT_TRUE(samples.ok());
  for (std::size_t i = 1; i < samples->size(); ++i) {
    ASSERT_GT((*samples)[i].t_s, (*samples)[i - 1].t_s) << i;
  }

  const double max_lost =
      lost_wall_s.empty() ? 0.0 : *std::max_element(lost_wall_s.begin(), lost_wall_s.end());
  std::string where;
  for (const auto& [s, n] : states_at_kill) where += fmt::format(" {} {}", s, n);
  std::printf(
      "fault-campaign: kill -9: %d kills (at:%s), integrity_check ok after each, %zu during "
      "a run measured: samples lost at most %.3f s wall (commit interval %.1f s), committed "
      "samples lost 0, %d restarts checked resumed or marked, runs %zu, completed %d\n",
      kills, where.c_str(), lost_wall_s.size(), max_lost, kCommitIntervalS, resumes_checked,
      runs->size(), completed_runs);
}

// The chamber's Modbus link down for 30 s of station time, the gyro line hung
// up and reopened, 1 % of the frames corrupted — all during one run, which
// completes with its Table I row.
TEST_F(FaultCampaignTest, DeviceFaultsDuringARun) {
  time_scale_ = 20;
  write_config(
      {{"silent_timeout_s = 60.0\n[chamber.alarm]", "silent_timeout_s = 10.0\n[chamber.alarm]"},
       {"rate_hz = 10", "rate_hz = 100"}},
      "[control]\nmin_silent_wall_s = 0.2\n");
  write(dir_ / "schedule.toml", testing::soak_schedule("device faults", 23.0, 6, 1));
  ASSERT_NO_FATAL_FAILURE(start_sim_in_process());
  start_daemon();
  ASSERT_TRUE(wait_status([](const json& s) { return s["state"] == "acquiring"; },
                          std::chrono::seconds(120)))
      << diag();
  sim::Simulator& sim = *in_process_sim_;
  auto gyro = [&](const char* key) { return daemon_status()["devices"]["gyro"][key]; };

  // 1. The chamber's Modbus link, down for 30 s of station time.
  const auto reconnects_before = last_["devices"]["chamber"]["reconnects"].get<uint64_t>();
  const double setpoint_before_c = sim.status().setpoint_c;
  const double down_at_s = sim.status().t_s;
  sim.set_modbus_down(true);
  ASSERT_TRUE(wait_sim_time(down_at_s + 30.0));
  sim.set_modbus_down(false);
  const double up_at_s = sim.status().t_s;
  EXPECT_EQ(sim.status().setpoint_c, setpoint_before_c) << "the controller kept its set point";
  ASSERT_TRUE(wait_status(
      [&](const json& s) {
        return s["devices"]["chamber"]["connected"].get<bool>() && s["interlocks"].empty() &&
               s["state"] == "acquiring" &&
               s["devices"]["chamber"]["reconnects"].get<uint64_t>() > reconnects_before;
      },
      std::chrono::seconds(60)))
      << diag();
  EXPECT_EQ(sim.status().setpoint_c, setpoint_before_c);

  // 2. The gyro line hung up for 10 s of station time, then a new pty.
  const uint64_t samples_before = gyro("samples").get<uint64_t>();
  const uint64_t reopens_before = gyro("reopens").get<uint64_t>();
  const double closed_at_s = sim.status().t_s;
  sim.close_pty();
  ASSERT_TRUE(wait_until([&] { return !gyro("connected").get<bool>(); }, std::chrono::seconds(30)))
      << diag();
  ASSERT_TRUE(wait_sim_time(closed_at_s + 10.0));
  ASSERT_TRUE(sim.reopen_pty().ok());
  ASSERT_TRUE(wait_until(
      [&] {
        return gyro("connected").get<bool>() &&
               gyro("samples").get<uint64_t>() > samples_before + 2000;
      },
      std::chrono::seconds(60)))
      << diag();
  const uint64_t reopens = gyro("reopens").get<uint64_t>() - reopens_before;
  EXPECT_GE(reopens, 1u);

  // 3. 1 % of the frames corrupted: every one rejected by its CRC, counted,
  //    and missing from the samples.
  const uint64_t crc_before = gyro("crc_failures").get<uint64_t>();
  const uint64_t missed_before = gyro("frames_missed").get<uint64_t>();
  const uint64_t corrupted_before = sim.status().frames_fault_corrupted;
  const uint64_t generated_before = sim.status().frames_generated;
  sim.set_frame_corruption_rate(0.01);
  ASSERT_TRUE(
      wait_until([&] { return sim.status().frames_fault_corrupted >= corrupted_before + 100; },
                 std::chrono::seconds(60)));
  sim.set_frame_corruption_rate(0.0);
  const uint64_t corrupted = sim.status().frames_fault_corrupted - corrupted_before;
  const uint64_t generated = sim.status().frames_generated - generated_before;
  ASSERT_TRUE(wait_until(
      [&] {
        return gyro("crc_failures").get<uint64_t>() - crc_before >= corrupted &&
               gyro("frames_missed").get<uint64_t>() - missed_before >= corrupted;
      },
      std::chrono::seconds(30)))
      << diag();
  const uint64_t rejected = gyro("crc_failures").get<uint64_t>() - crc_before;
  EXPECT_EQ(rejected, corrupted);
  EXPECT_EQ(gyro("frames_missed").get<uint64_t>() - missed_before, corrupted)
      << "each corrupted frame is a missing sample";

  ASSERT_TRUE(wait_run_completed()) << diag();
  daemon_->signal(SIGTERM);
  ASSERT_EQ(daemon_->wait(std::chrono::seconds(30)), std::optional<int>(0)) << daemon_->log();

  ASSERT_EQ(integrity_check(db_path()), "ok");
  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok());
  const std::string events = events_text(*db, 1);
  EXPECT_THAT(events, HasSubstr("chamber: no answer"));
  EXPECT_THAT(events, HasSubstr("answers again after"));
  EXPECT_THAT(events, HasSubstr("chamber controller silent"));
  EXPECT_THAT(events, HasSubstr("interlock chamber_silent cleared"));
  // The gap, as recorded: temperature rows without a chamber reading.
  auto temps = db->temperature_samples(1, -1e12, 1e12);
  ASSERT_TRUE(temps.ok());
  double gap_s = 0, gap_from_s = 0;
  bool in_gap = false;
  for (const auto& t : *temps) {
    if (std::isnan(t.chamber_c)) {
      if (!in_gap) gap_from_s = t.t_s;
      in_gap = true;
      gap_s = std::max(gap_s, t.t_s - gap_from_s);
    } else {
      in_gap = false;
    }
  }
  EXPECT_GE(gap_s, 20.0) << "the chamber gap is in the temperature rows";
  EXPECT_LE(gap_s, 45.0);
  auto samples = db->gyro_samples(1, -1e12, 1e12);
  ASSERT_TRUE(samples.ok());
  for (std::size_t i = 1; i < samples->size(); ++i) {
    ASSERT_GT((*samples)[i].t_s, (*samples)[i - 1].t_s) << i;
  }
  auto stats = db->segment_stats(1);
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(stats->size(), 1u) << events;

  std::printf(
      "fault-campaign: Modbus link down %.1f s station time: reconnected, gap of %.1f s recorded "
      "(temperature rows, device and interlock events), set point held at %.1f °C\n",
      up_at_s - down_at_s, gap_s, setpoint_before_c);
  std::printf(
      "fault-campaign: gyro pty closed 10 s station time and reopened: stream resumed (%llu "
      "reopen(s)), timestamps strictly increasing\n",
      static_cast<unsigned long long>(reopens));
  std::printf(
      "fault-campaign: 1 %% corrupted frames: %llu of %llu frames corrupted, %llu rejected by CRC "
      "and counted, %llu accepted\n",
      static_cast<unsigned long long>(corrupted), static_cast<unsigned long long>(generated),
      static_cast<unsigned long long>(rejected),
      static_cast<unsigned long long>(rejected >= corrupted ? 0 : corrupted - rejected));
}

// The disk fills up under the daemon (a 1 MB tmpfs holding the database):
// commits fail, the storage_failing interlock suspends the run with a clear
// event, the samples wait in memory; when the tmpfs grows, the held samples
// are committed, the run goes on and completes — the file intact, the gyro
// series without a hole.
TEST_F(FaultCampaignTest, DiskFullSuspendsAcquisitionAndResumes) {
  const std::filesystem::path disk = dir_ / "disk";
  std::filesystem::create_directories(disk);
  if (::mount("tmpfs", disk.c_str(), "tmpfs", 0, "size=1m,mode=0755") != 0) {
    GTEST_SKIP() << "mounting a tmpfs needs root (CAP_SYS_ADMIN): " << std::strerror(errno);
  }
  tmpfs_ = disk.string();
  db_path_ = disk / "station.db";
  time_scale_ = 20;
  write_config({{fmt::format("db = \"{}/station.db\"", dir_.string()),
                 fmt::format("db = \"{}\"", db_path_.string())},
                {"rate_hz = 10", "rate_hz = 100"}});
  write(dir_ / "schedule.toml", testing::soak_schedule("disk full", 23.0, 10, 1));
  ASSERT_NO_FATAL_FAILURE(start_sim_in_process());
  start_daemon();

  // The database grows until the tmpfs is full.
  ASSERT_TRUE(wait_status(
      [](const json& s) {
        for (const auto& i : s["interlocks"]) {
          if (i["kind"] == "storage_failing") return true;
        }
        return false;
      },
      std::chrono::seconds(120)))
      << diag();
  EXPECT_EQ(last_["state"], "suspended") << diag();
  EXPECT_GT(last_["storage"]["consecutive_failures"].get<uint64_t>(), 0u);
  EXPECT_THAT(last_["storage"]["last_error"].get<std::string>(), HasSubstr("full"));
  std::string message;
  for (const auto& i : last_["interlocks"]) message += i["message"].get<std::string>();
  EXPECT_THAT(message, HasSubstr("acquisition suspended"));
  EXPECT_EQ(in_process_sim_->status().setpoint_c, 23.0) << "the set point is held";
  // Acquisition goes on into memory meanwhile.
  const auto pending_at_trip = last_["storage"]["pending"].get<uint64_t>();
  ASSERT_TRUE(wait_status(
      [&](const json& s) {
        return s["storage"]["pending"].get<uint64_t>() > pending_at_trip + 2000;
      },
      std::chrono::seconds(30)))
      << diag();
  const auto held = last_["storage"]["pending"].get<uint64_t>();
  EXPECT_EQ(last_["state"], "suspended");

  // Space returns.
  ASSERT_EQ(::mount("tmpfs", disk.c_str(), "tmpfs", MS_REMOUNT, "size=256m,mode=0755"), 0)
      << std::strerror(errno);
  ASSERT_TRUE(wait_status(
      [](const json& s) {
        return s["interlocks"].empty() && s["storage"]["consecutive_failures"] == 0 &&
               s["state"] != "suspended";
      },
      std::chrono::seconds(60)))
      << diag();
  ASSERT_TRUE(wait_run_completed()) << diag();
  const json final_status = daemon_status();
  EXPECT_EQ(final_status["storage"]["dropped"], 0) << "no sample was dropped";
  daemon_->signal(SIGTERM);
  ASSERT_EQ(daemon_->wait(std::chrono::seconds(30)), std::optional<int>(0)) << daemon_->log();

  ASSERT_EQ(integrity_check(db_path()), "ok");
  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok());
  const std::string events = events_text(*db, 1);
  EXPECT_THAT(events, HasSubstr("storage failing for"))
      << "the event of the suspension was written once the disk took writes again";
  EXPECT_THAT(events, HasSubstr("interlock storage_failing cleared"));
  auto rows = db->events(1);
  ASSERT_TRUE(rows.ok());
  EXPECT_TRUE(std::any_of(rows->begin(), rows->end(), [](const storage::EventRecord& e) {
    return e.kind == "state" && e.to_state == "suspended";
  })) << events;
  auto samples = db->gyro_samples(1, -1e12, 1e12);
  ASSERT_TRUE(samples.ok());
  ASSERT_GT(samples->size(), 1000u);
  double max_step_s = 0;
  for (std::size_t i = 1; i < samples->size(); ++i) {
    ASSERT_GT((*samples)[i].t_s, (*samples)[i - 1].t_s) << i;
    max_step_s = std::max(max_step_s, (*samples)[i].t_s - (*samples)[i - 1].t_s);
  }
  // 100 Hz: a hole would show as a step well beyond 10 ms.
  EXPECT_LT(max_step_s, 0.5) << "the gyro series has no hole across the full disk";
  auto stats = db->segment_stats(1);
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(stats->size(), 1u) << events;
  std::printf(
      "fault-campaign: disk full (1 MB tmpfs): storage_failing tripped, run suspended, %llu "
      "samples held in memory, resumed after the tmpfs grew; %zu gyro samples, largest step "
      "%.3f s, dropped 0, integrity_check ok\n",
      static_cast<unsigned long long>(held), samples->size(), max_step_s);
}

}  // namespace
}  // namespace gyrotherm
