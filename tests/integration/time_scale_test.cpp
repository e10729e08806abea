// The daemon's and the simulator's clocks must run at the same time scale,
// within the range that works (issue 15 item 19).
#include "gyrotherm/core/time_scale.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "gyrotherm/config/sim_endpoints.h"
#include "station_fixture.h"

namespace gyrotherm::testing {
namespace {

using ::testing::HasSubstr;

class TimeScaleTest : public StationTest {};

TEST_F(TimeScaleTest, DaemonRefusesASimulatorAtAnotherScale) {
  ASSERT_NO_FATAL_FAILURE(start_sim());  // at kTimeScale (200)
  const auto ep = config::read_sim_endpoints((dir_ / "endpoints.toml").string());
  ASSERT_TRUE(ep.ok()) << ep.error().message;
  EXPECT_DOUBLE_EQ(ep->time_scale, kTimeScale) << "the simulator publishes its time scale";

  time_scale_ = 100;
  start_daemon();
  const auto code = daemon_->wait(std::chrono::seconds(20));
  ASSERT_TRUE(code.has_value()) << "the daemon runs against a simulator at another time scale\n"
                                << daemon_->log();
  EXPECT_EQ(*code, 2) << daemon_->log();
  EXPECT_THAT(daemon_->log(), HasSubstr("the simulator runs at time scale 200"));
  EXPECT_THAT(daemon_->log(), HasSubstr("the daemon was asked for 100"));
}

TEST_F(TimeScaleTest, ScalesOutsideTheWorkingRangeAreRefused) {
  const std::string too_fast = fmt::format("{:g}", 2 * kMaxTimeScale);
  ChildProcess sim({bin("gyrotherm-sim"), "--config", (dir_ / "station.toml").string(),
                    "--time-scale", too_fast},
                   (dir_ / "sim.log").string());
  const auto sim_code = sim.wait(std::chrono::seconds(20));
  ASSERT_TRUE(sim_code.has_value()) << "the simulator runs at " << too_fast;
  EXPECT_EQ(*sim_code, 2) << sim.log();
  EXPECT_THAT(sim.log(), HasSubstr("time scale"));

  ChildProcess daemon(
      {bin("gyrothermd"), "--config", (dir_ / "station.toml").string(), "--time-scale", too_fast},
      (dir_ / "daemon.log").string());
  const auto daemon_code = daemon.wait(std::chrono::seconds(20));
  ASSERT_TRUE(daemon_code.has_value()) << "the daemon runs at " << too_fast;
  EXPECT_NE(*daemon_code, 0) << daemon.log();
  EXPECT_THAT(daemon.log(), HasSubstr("--time-scale"));
}

}  // namespace
}  // namespace gyrotherm::testing
