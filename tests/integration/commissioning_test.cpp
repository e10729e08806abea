// Commissioning commands (`gyrotherm devices`, `gyrotherm chamber set-point`)
// next to a running daemon: the daemon owns the station, so they refuse
// (exit 2, naming the daemon) instead of stealing gyro frames from it or
// moving the chamber under a run (issue 15 item 13).
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include "station_fixture.h"
#include "test_files.h"

namespace gyrotherm::testing {
namespace {

using ::testing::HasSubstr;
using json = nlohmann::json;

class CommissioningTest : public StationTest {
 protected:
  struct Run {
    int code;
    std::string out, err;
  };
  Run cli(const std::vector<std::string>& args) {
    const std::string out = (dir_ / "cli.out").string(), err = (dir_ / "cli.err").string();
    std::string cmd = bin("gyrotherm");
    for (const auto& a : args) cmd += " '" + a + "'";
    cmd += " >" + out + " 2>" + err;
    const int st = std::system(cmd.c_str());
    return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, read_text(out), read_text(err)};
  }
  // Waits for an acquiring soak with gyro frames flowing.
  void wait_acquiring() {
    ASSERT_TRUE(wait_until(
        [&] {
          last_ = status();
          return last_ && last_->value("state", "") == "acquiring" &&
                 (*last_)["devices"]["gyro"]["frames_ok"].get<uint64_t>() > 100;
        },
        std::chrono::seconds(60)))
        << (last_ ? last_->dump() : "no status") << "\n"
        << daemon_->log();
  }
  uint64_t gyro(const char* key) {
    auto s = status();
    return s ? (*s)["devices"]["gyro"][key].get<uint64_t>() : 0;
  }
  // The daemon's frame counters after it has read `more` further frames.
  void expect_no_frames_lost(uint64_t gaps_before, uint64_t missed_before) {
    const uint64_t frames = gyro("frames_ok");
    ASSERT_TRUE(
        wait_until([&] { return gyro("frames_ok") > frames + 200; }, std::chrono::seconds(30)));
    EXPECT_EQ(gyro("sequence_gaps"), gaps_before) << "the daemon lost gyro frames";
    EXPECT_EQ(gyro("frames_missed"), missed_before) << "the daemon lost gyro frames";
  }
  std::optional<json> last_;
};

TEST_F(CommissioningTest, RefusedWhileTheDaemonOwnsTheStation) {
  write(dir_ / "schedule.toml", soak_schedule("long soak", 23.0, 600));
  ASSERT_NO_FATAL_FAILURE(start_sim());
  start_daemon();
  ASSERT_NO_FATAL_FAILURE(wait_acquiring());
  const uint64_t gaps = gyro("sequence_gaps"), missed = gyro("frames_missed");
  const std::string cfg = (dir_ / "station.toml").string();

  const Run devices = cli({"devices", "--config", cfg});
  EXPECT_EQ(devices.code, 2) << devices.out << devices.err;
  EXPECT_THAT(devices.err, HasSubstr("gyrothermd"));
  EXPECT_THAT(devices.err, HasSubstr(fmt::format("pid {}", daemon_->pid())));

  const Run set = cli({"chamber", "set-point", "31.5", "--config", cfg});
  EXPECT_EQ(set.code, 2) << set.out << set.err;
  EXPECT_THAT(set.err, HasSubstr("gyrothermd"));
  auto s = status();
  ASSERT_TRUE(s);
  EXPECT_EQ(s->value("state", ""), "acquiring");
  EXPECT_DOUBLE_EQ((*s)["setpoint_c"].get<double>(), 23.0);

  expect_no_frames_lost(gaps, missed);
}

// A daemon started on another database (--db) holds no lock beside the
// config's database; the gyro line itself is held exclusively (flock), so
// `devices` still refuses rather than share the line.
TEST_F(CommissioningTest, TheGyroLineIsHeldExclusively) {
  write(dir_ / "schedule.toml", soak_schedule("long soak", 23.0, 600));
  ASSERT_NO_FATAL_FAILURE(start_sim());
  start_daemon({"--db", (dir_ / "elsewhere.db").string()});
  ASSERT_NO_FATAL_FAILURE(wait_acquiring());
  const uint64_t gaps = gyro("sequence_gaps"), missed = gyro("frames_missed");

  const Run devices = cli({"devices", "--config", (dir_ / "station.toml").string()});
  EXPECT_EQ(devices.code, 2) << devices.out << devices.err;
  EXPECT_THAT(devices.err, HasSubstr("in use by another process"));

  expect_no_frames_lost(gaps, missed);
}

}  // namespace
}  // namespace gyrotherm::testing
