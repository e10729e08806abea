// The gyrotherm CLI as a user runs it: a real binary, files and a simulator.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <vector>

#include "gyrotherm/drivers/kvh1750.h"
#include "gyrotherm/storage/database.h"
#include "process.h"
#include "temp_dir_test.h"
#include "test_files.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using testing::ChildProcess;
using ::testing::HasSubstr;

class CliTest : public testing::TempDirTest {
 protected:
  CliTest() : TempDirTest("gyrotherm-cli") {}
  // Runs the CLI to completion; returns {exit code, stdout, stderr}.
  struct Run {
    int code;
    std::string out, err;
  };
  // `limit_s` > 0: killed after that many seconds (exit code 137).
  Run cli(std::vector<std::string> args, int limit_s = 0) {
    const std::string out = (dir_ / "out.txt").string(), err = (dir_ / "err.txt").string();
    std::string cmd = limit_s > 0 ? fmt::format("timeout -s KILL {} ", limit_s) : std::string();
    cmd += std::string(GYROTHERM_BIN_DIR) + "/gyrotherm";
    for (const auto& a : args) cmd += " '" + a + "'";
    cmd += " >" + out + " 2>" + err;
    const int st = std::system(cmd.c_str());
    return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, testing::read_text(out), testing::read_text(err)};
  }
};

drivers::GyroFrame frame(uint8_t seq) {
  drivers::GyroFrame f;
  f.gyro = {1.5e-5f * seq, -2.25e-6f, 3.9e-5f + 1e-7f * seq};
  f.accel = {0.001f, -0.002f, 1.0f};
  f.status = 0x77;
  f.seq = seq;
  f.temp_c = static_cast<int16_t>(20 + seq % 3);
  return f;
}

TEST_F(CliTest, DecodeWritesValidFramesAndSummarisesTheRest) {
  // 10 frames: garbage in front, frame 3 corrupted, frame 6 missing.
  std::vector<uint8_t> bytes = {0x00, 0xFE, 0x81, 0x12};
  for (uint8_t seq = 0; seq < 10; ++seq) {
    if (seq == 6) continue;
    auto b = drivers::encode_kvh1750(frame(seq));
    if (seq == 3) b[10] ^= 0x40;
    bytes.insert(bytes.end(), b.begin(), b.end());
  }
  const std::string path = (dir_ / "capture.bin").string();
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
  const Run r = cli({"decode", "--protocol", "kvh1750", path});
  ASSERT_EQ(r.code, 0) << r.err;
  std::istringstream lines(r.out);
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line, "seq,status,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z,temp_c");
  std::vector<int> seqs;
  while (std::getline(lines, line)) {
    int seq = 0, status = 0;
    float gx = 0, gy = 0, gz = 0;
    ASSERT_EQ(std::sscanf(line.c_str(), "%d,%d,%g,%g,%g", &seq, &status, &gx, &gy, &gz), 5) << line;
    const auto want = frame(static_cast<uint8_t>(seq));
    EXPECT_EQ(status, 0x77);
    // %.9g round-trips a float exactly.
    EXPECT_EQ(gx, want.gyro[0]) << line;
    EXPECT_EQ(gz, want.gyro[2]) << line;
    seqs.push_back(seq);
  }
  EXPECT_THAT(seqs, ::testing::ElementsAre(0, 1, 2, 4, 5, 7, 8, 9));
  EXPECT_THAT(r.err, HasSubstr("8 valid frames"));
  EXPECT_THAT(r.err, HasSubstr("1 CRC failures"));
  EXPECT_THAT(r.err, HasSubstr("40 bytes skipped"));  // 4 garbage + the corrupted frame's 36
  EXPECT_THAT(r.err, HasSubstr("2 sequence gaps"));

  const Run j = cli({"decode", "--protocol", "kvh1750", "--json", path});
  ASSERT_EQ(j.code, 0) << j.err;
  EXPECT_EQ(j.out, r.out) << "frames stay CSV";
  const auto summary = nlohmann::json::parse(j.err);
  EXPECT_EQ(summary["frames_ok"], 8);
  EXPECT_EQ(summary["crc_failures"], 1);
  EXPECT_EQ(summary["bytes_skipped"], 40);
  EXPECT_EQ(summary["sequence_gaps"], 2);
}

TEST_F(CliTest, DecodeMissingFileAndUnknownProtocol) {
  const Run missing = cli({"decode", "--protocol", "kvh1750", (dir_ / "nope.bin").string()});
  EXPECT_NE(missing.code, 0);
  EXPECT_THAT(missing.err, HasSubstr("nope.bin: cannot open"));
  const Run proto = cli({"decode", "--protocol", "nmea", (dir_ / "nope.bin").string()});
  EXPECT_NE(proto.code, 0);
  EXPECT_THAT(proto.err, HasSubstr("nmea"));
}

TEST_F(CliTest, StatsPrintsTableOneRowsAsTextAndJson) {
  const std::string db_path = (dir_ / "s.db").string();
  {
    auto db = storage::Database::open(db_path);
    ASSERT_TRUE(db.ok()) << db.error().message;
    storage::RunRecord run;
    run.schedule_name = "demo";
    run.state = "completed";
    auto run_id = db->create_run(run);
    ASSERT_TRUE(run_id.ok());
    storage::SegmentRecord seg;
    seg.run_id = *run_id;
    seg.index = 0;
    seg.kind = "soak";
    seg.setpoint_c = 20;
    auto seg_id = db->create_segment(seg);
    ASSERT_TRUE(seg_id.ok());
    storage::SegmentStatsRecord st;
    st.segment_id = *seg_id;
    st.run_id = *run_id;
    st.segment_index = 0;
    st.setpoint_c = 20;
    st.n = 1200;
    st.duration_s = 1200;
    st.temp_mean_c = 20.01;
    st.bias_mean_dph = 8.0771;
    st.bias_std_dph = 1.0352;
    st.bias_std_ma_dph = 0.0479;
    st.bias_mean_earth_removed_dph = 0.1291;
    st.earth_rate_dph = 7.948;
    ASSERT_TRUE(db->put_segment_stats(st).ok());
  }
  const Run text = cli({"stats", "--db", db_path, "--stored"});
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_THAT(text.out, HasSubstr("8.0771"));
  EXPECT_THAT(text.out, HasSubstr("0.0479"));
  const Run json = cli({"stats", "--db", db_path, "--stored", "--json"});
  ASSERT_EQ(json.code, 0) << json.err;
  const auto j = nlohmann::json::parse(json.out);
  ASSERT_EQ(j.size(), 1u);
  for (const char* key :
       {"run_id", "segment", "setpoint_c", "n", "duration_s", "temp_mean_c", "bias_mean_dph",
        "bias_std_dph", "bias_std_ma101_dph", "bias_mean_earth_removed_dph"}) {
    EXPECT_TRUE(j[0].contains(key)) << key;
  }
  EXPECT_EQ(j[0]["n"], 1200);
  EXPECT_DOUBLE_EQ(j[0]["bias_std_ma101_dph"].get<double>(), 0.0479);

  const Run none = cli({"stats", "--db", (dir_ / "missing.db").string()});
  EXPECT_NE(none.code, 0);
  EXPECT_THAT(none.err, HasSubstr("missing.db"));

  // --config names the database ([storage] db) as well as --db does.
  std::string cfg = testing::read_text(std::string(GYROTHERM_SOURCE_DIR) + "/config/station.toml");
  const std::string from = "\"/var/lib/gyrotherm/station.db\"";
  ASSERT_NE(cfg.find(from), std::string::npos);
  cfg.replace(cfg.find(from), from.size(), "\"" + db_path + "\"");
  const std::string cfg_path = (dir_ / "station.toml").string();
  std::ofstream(cfg_path) << cfg;
  const Run by_config = cli({"stats", "--config", cfg_path, "--stored"});
  ASSERT_EQ(by_config.code, 0) << by_config.err;
  EXPECT_EQ(by_config.out, text.out);
  EXPECT_EQ(cli({"stats", "--config", cfg_path, "--db", db_path, "--stored"}).code, 2);
}

TEST_F(CliTest, DevicesAndChamberSetpointAgainstTheSimulator) {
  std::string cfg = testing::read_text(std::string(GYROTHERM_SOURCE_DIR) + "/config/demo.toml");
  auto replace = [&](const std::string& from, const std::string& to) {
    const auto pos = cfg.find(from);
    ASSERT_NE(pos, std::string::npos) << from;
    cfg.replace(pos, from.size(), to);
  };
  replace("\"demo/sim-endpoints.toml\"", "\"" + (dir_ / "ep.toml").string() + "\"");
  replace("\"demo/sim-truth.json\"", "\"" + (dir_ / "truth.json").string() + "\"");
  replace("\"demo/gyro-pty\"", "\"" + (dir_ / "gyro-pty").string() + "\"");
  replace("\"demo/sim.sock\"", "\"" + (dir_ / "sim.sock").string() + "\"");
  // A quiet gyro, so one sample tells Earth rate from nothing: 0.1 °/h for a
  // 1 s average is 0.32 °/h for one 10 Hz sample.
  replace("white_noise_dph = 1.0", "white_noise_dph = 0.1");
  const std::string cfg_path = (dir_ / "station.toml").string();
  std::ofstream(cfg_path) << cfg;

  ChildProcess sim({std::string(GYROTHERM_BIN_DIR) + "/gyrotherm-sim", "--config", cfg_path,
                    "--time-scale", "10"},
                   (dir_ / "sim.log").string());
  ASSERT_TRUE(
      testing::wait_until([&] { return fs::exists(dir_ / "ep.toml"); }, std::chrono::seconds(20)))
      << sim.log();

  const Run set = cli({"chamber", "set-point", "31.5", "--config", cfg_path});
  ASSERT_EQ(set.code, 0) << set.err;
  EXPECT_THAT(set.out, HasSubstr("31.50"));
  const Run refused = cli({"chamber", "set-point", "95", "--config", cfg_path});
  EXPECT_EQ(refused.code, 2);
  EXPECT_THAT(refused.err, HasSubstr("outside the station's limits"));

  const Run dev = cli({"--json", "devices", "--config", cfg_path});
  ASSERT_EQ(dev.code, 0) << dev.out << dev.err;
  const auto j = nlohmann::json::parse(dev.out);
  EXPECT_DOUBLE_EQ(j["chamber"]["setpoint_c"].get<double>(), 31.5);
  EXPECT_NEAR(j["chamber"]["process_value_c"].get<double>(), 23.0, 3.0);
  EXPECT_NEAR(j["probes"]["top_c"].get<double>(), 23.0, 3.0);
  EXPECT_NEAR(j["probes"]["side_c"].get<double>(), 23.0, 3.0);
  // Earth rate on the up axis at 31.9° (7.95 °/h) plus the truth's bias at
  // about 23 °C (0.05 + 0.004 T − 8e-5 T² + 0.5 · 0.05 °C of gradient ≈
  // 0.12 °/h): 8.07 °/h, within 1.5 °/h (4.7 σ of one sample; the chamber's
  // move to 31.5 °C adds under 0.1 °/h of rate term meanwhile). 0, −8 or the
  // bias without Earth rate are far outside.
  EXPECT_NEAR(j["gyro"]["rate_dph"].get<double>(), 8.07, 1.5);
  EXPECT_EQ(j["gyro"]["crc_failures"], 0);

  // Issue 15 item 17: every refusal of a set point exits 2, "nan" too.
  const Run nan = cli({"chamber", "set-point", "nan", "--config", cfg_path});
  EXPECT_EQ(nan.code, 2) << nan.err;
  EXPECT_THAT(nan.err, HasSubstr("not a temperature"));

  // A gyro that gives no valid frame is a failed reading: exit 1.
  ChildProcess ctl({std::string(GYROTHERM_BIN_DIR) + "/gyrotherm-sim", "ctl", "--socket",
                    (dir_ / "sim.sock").string(), "frames", "corrupt", "1"},
                   (dir_ / "ctl.log").string());
  ASSERT_EQ(ctl.wait(std::chrono::seconds(10)), std::optional<int>(0)) << ctl.log();
  const Run silent = cli({"devices", "--config", cfg_path});
  EXPECT_EQ(silent.code, 1) << silent.out << silent.err;
  EXPECT_THAT(silent.out, HasSubstr("no valid frame"));
}

TEST_F(CliTest, ScheduleCheckListsEveryError) {
  const std::string bad = (dir_ / "bad.toml").string();
  std::ofstream(bad) << "[[step]]\ntype = \"soak\"\nsetpoint_c = 75\nacquire_min = 10\n"
                        "[[step]]\ntype = \"ramp\"\ntarget_c = 0\nrate_c_per_min = 9\n";
  const std::string station = std::string(GYROTHERM_SOURCE_DIR) + "/config/station.toml";
  const Run r = cli({"schedule", "check", bad, "--config", station});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("bad.toml:3: step[0].setpoint_c: 75 °C is outside"));
  EXPECT_THAT(r.err, HasSubstr("bad.toml:8: step[1].rate_c_per_min: 9 °C/min exceeds"));
  const Run ok = cli({"schedule", "check",
                      std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml",
                      "--config", station});
  EXPECT_EQ(ok.code, 0) << ok.err;
  EXPECT_THAT(ok.out, HasSubstr("32 steps"));
  // 4 × 1012 min of acquisition = 2 d 19 h 28 min; 32 soaks settle.
  EXPECT_THAT(ok.out, HasSubstr("planned duration: 2 d 19 h (+ 32 settles of unknown length)\n"));
  // Without --config: the default limits; --json gives the figures.
  const Run json = cli({"--json", "schedule", "check",
                        std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml"});
  ASSERT_EQ(json.code, 0) << json.err;
  const auto j = nlohmann::json::parse(json.out);
  EXPECT_DOUBLE_EQ(j["planned"]["fixed_s"].get<double>(), 4048 * 60.0);
  EXPECT_EQ(j["planned"]["settles"], 32);
}

// What is not a schedule file ends at once with an error naming it:
// /dev/zero used to be read until memory ran out, a directory was reported
// as a schedule without [[step]].
TEST_F(CliTest, ScheduleCheckRefusesWhatIsNotAFile) {
  const std::string station = std::string(GYROTHERM_SOURCE_DIR) + "/config/station.toml";
  const Run zero = cli({"schedule", "check", "/dev/zero", "--config", station}, 60);
  EXPECT_EQ(zero.code, 1) << zero.err;
  EXPECT_THAT(zero.err, HasSubstr("/dev/zero: is a character device, not a regular file"));
  const Run dir = cli({"schedule", "check", dir_.string(), "--config", station}, 60);
  EXPECT_EQ(dir.code, 1) << dir.err;
  EXPECT_THAT(dir.err, HasSubstr(dir_.string() + ": is a directory, not a file"));
  const Run config = cli({"schedule", "check",
                          std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml",
                          "--config", "/dev/zero"},
                         60);
  EXPECT_EQ(config.code, 2) << config.err;
  EXPECT_THAT(config.err, HasSubstr("/dev/zero: is a character device"));
}

// Thousands of errors: the first 50 in file order and a count of the rest.
TEST_F(CliTest, ScheduleCheckCapsTheErrorReport) {
  const std::string bad = (dir_ / "many.toml").string();
  {
    std::ofstream out(bad);
    for (int i = 0; i < 3000; ++i) out << "[[step]]\ntype = \"hold\"\nsetpoint_c = 99\n";
  }
  const std::string station = std::string(GYROTHERM_SOURCE_DIR) + "/config/station.toml";
  const Run r = cli({"schedule", "check", bad, "--config", station}, 60);
  EXPECT_EQ(r.code, 1);
  // 2 errors a step (set point out of limits, duration_min missing).
  EXPECT_THAT(r.err, HasSubstr("\n... and 5950 more errors\n"));
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 52) << r.err.substr(0, 3000);
  const Run j = cli({"schedule", "check", bad, "--config", station, "--json"}, 60);
  EXPECT_EQ(j.code, 1);
  const auto answer = nlohmann::json::parse(j.out);
  EXPECT_EQ(answer["errors"].size(), 50u);
  EXPECT_EQ(answer["more_errors"], 5950);
}

// A name with control characters is refused with its line; nothing from
// the file reaches the terminal raw.
// --db: the station's past settles (600, 900, 1200, 1500 s; a paused soak
// and one that never settled are left out) stand for the 32 soaks of the
// paper's campaign: numpy.percentile gives 690, 1050, 1410 s, so 4048 min
// of fixed time + 32 of them: 276 480 s (264 960 – 288 000). Two settles
// are too few, and it says so.
TEST_F(CliTest, ScheduleCheckEstimatesTheSettlesFromTheStationsPastSoaks) {
  const auto make_db = [&](const std::string& name, const std::vector<double>& settles_s) {
    const std::string path = (dir_ / name).string();
    auto db = storage::Database::open(path);
    EXPECT_TRUE(db.ok()) << db.error().message;
    storage::RunRecord run;
    run.schedule_name = "past";
    run.state = "completed";
    auto run_id = db->create_run(run);
    EXPECT_TRUE(run_id.ok());
    int index = 0;
    const auto add = [&](std::optional<double> settled_s, double paused_s) {
      storage::SegmentRecord seg;
      seg.run_id = *run_id;
      seg.index = index++;
      seg.kind = "soak";
      seg.setpoint_c = 20;
      seg.t_start_s = 100.0 * index;
      if (settled_s) seg.t_settled_s = seg.t_start_s + *settled_s;
      seg.paused_s = paused_s;
      seg.state = "completed";
      EXPECT_TRUE(db->create_segment(seg).ok());
    };
    for (double s : settles_s) add(s, 0);
    add(50, 30);           // paused: its settle cannot be told from its hold
    add(std::nullopt, 0);  // never settled
    return path;
  };
  const std::string paper =
      std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml";
  const std::string db = make_db("past.db", {1200, 600, 1500, 900});
  const Run text = cli({"schedule", "check", paper, "--db", db});
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_THAT(text.out, HasSubstr("planned duration: 2 d 19 h (+ 32 settles of unknown length)\n"
                                  "with the station's last 4 settles: ~3 d 5 h (P10 3 d 2 h – "
                                  "P90 3 d 8 h)\n"));
  const Run json = cli({"--json", "schedule", "check", paper, "--db", db});
  ASSERT_EQ(json.code, 0) << json.err;
  const auto j = nlohmann::json::parse(json.out)["planned"]["with_past_settles"];
  EXPECT_EQ(j["prior_settles"], 4);
  EXPECT_DOUBLE_EQ(j["eta_s"].get<double>(), 4048 * 60.0 + 32 * 1050.0);
  EXPECT_DOUBLE_EQ(j["eta_p10_s"].get<double>(), 4048 * 60.0 + 32 * 690.0);
  EXPECT_DOUBLE_EQ(j["eta_p90_s"].get<double>(), 4048 * 60.0 + 32 * 1410.0);

  const Run few = cli({"schedule", "check", paper, "--db", make_db("few.db", {600, 900})});
  ASSERT_EQ(few.code, 0) << few.err;
  EXPECT_THAT(few.out,
              HasSubstr("the database holds 2 settles without a pause; 3 are needed to estimate "
                        "them\n"));
  const Run missing = cli({"schedule", "check", paper, "--db", (dir_ / "none.db").string()});
  EXPECT_EQ(missing.code, 2);
  EXPECT_THAT(missing.err, HasSubstr("none.db"));
}

TEST_F(CliTest, ScheduleCheckRefusesControlCharactersInTheName) {
  const std::string bad = (dir_ / "ctl.toml").string();
  std::ofstream(bad) << "name = \"\\u001b[2Jx\"\n[[step]]\ntype = \"hold\"\nsetpoint_c = 20\n"
                        "duration_min = 5\n";
  const std::string station = std::string(GYROTHERM_SOURCE_DIR) + "/config/station.toml";
  const Run r = cli({"schedule", "check", bad, "--config", station}, 60);
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_THAT(r.err, HasSubstr("ctl.toml:1: name: \"\\x1B[2Jx\" holds control characters"));
  EXPECT_EQ(r.out.find('\x1b'), std::string::npos);
  EXPECT_EQ(r.err.find('\x1b'), std::string::npos);
}

// One step is "1 step", not "1 steps".
TEST_F(CliTest, ScheduleCheckCountsOneStep) {
  const std::string one = (dir_ / "one.toml").string();
  std::ofstream(one) << "name = \"one\"\n[[step]]\ntype = \"hold\"\nsetpoint_c = 20\n"
                        "duration_min = 5\n";
  const std::string station = std::string(GYROTHERM_SOURCE_DIR) + "/config/station.toml";
  const Run r = cli({"schedule", "check", one, "--config", station});
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out, "one: ok, 1 step\n  step 1: hold 20 °C\nplanned duration: 5 min\n");
}

// gyrothermd's usage errors exit 2, as a bad config does (a bad option
// exited 105-109, CLI11's own codes).
TEST_F(CliTest, DaemonUsageErrorsExitTwo) {
  const std::string daemon = std::string(GYROTHERM_BIN_DIR) + "/gyrothermd";
  const std::string station = std::string(GYROTHERM_SOURCE_DIR) + "/config/station.toml";
  auto run = [&](const std::string& args) {
    const std::string log = (dir_ / "daemon.log").string();
    const int st =
        std::system(fmt::format("timeout -s KILL 30 {} {} >{} 2>&1", daemon, args, log).c_str());
    return std::pair{WIFEXITED(st) ? WEXITSTATUS(st) : -1, testing::read_text(log)};
  };
  for (const std::string& args : std::vector<std::string>{
           "--bogus", "--config", "--config " + station + " --time-scale 0",
           "--config " + station + " --log-level loud", "--config " + station + " extra"}) {
    const auto [code, log] = run(args);
    EXPECT_EQ(code, 2) << args << "\n" << log;
  }
  const auto [bad_config, log] = run("--config /dev/zero");
  EXPECT_EQ(bad_config, 2) << log;
  EXPECT_THAT(log, HasSubstr("/dev/zero: is a character device"));
  EXPECT_EQ(run("--help").first, 0);
}

}  // namespace
}  // namespace gyrotherm
