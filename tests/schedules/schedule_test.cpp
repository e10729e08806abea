#include "gyrotherm/schedules/schedule.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

namespace gyrotherm::schedules {
namespace {

using ::testing::HasSubstr;

const StationLimits kLimits{-20.0, 60.0, 2.0};

TEST(Schedule, ShippedSchedulesAreValid) {
  for (const char* name : {"demo.toml", "paper-table1.toml", "paper-ramp.toml"}) {
    auto plan =
        load_schedule(std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/" + name, kLimits);
    ASSERT_TRUE(plan.ok()) << name << ":\n" << plan.error().message;
    EXPECT_FALSE(plan->steps.empty()) << name;
  }
}

TEST(Schedule, PaperTable1HasEightTemperaturesFourTimes) {
  auto plan = load_schedule(
      std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml", kLimits);
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  ASSERT_EQ(plan->steps.size(), 32u);
  EXPECT_DOUBLE_EQ(plan->steps[0].setpoint_c, -14.6);
  EXPECT_DOUBLE_EQ(plan->steps[8].setpoint_c, -14.6);
  EXPECT_DOUBLE_EQ(plan->steps[31].setpoint_c, 60.0);
  EXPECT_THAT(plan->steps[8].label, HasSubstr("repeat 2/4"));
}

TEST(Schedule, DefaultsAndUnits) {
  auto plan = parse_schedule(R"(
[[step]]
type = "soak"
setpoint_c = 20
acquire_min = 20
[[step]]
type = "ramp"
target_c = 40
rate_c_per_min = 1.5
[[step]]
type = "hold"
setpoint_c = 23
duration_min = 5
)",
                             "s.toml", kLimits);
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  ASSERT_EQ(plan->steps.size(), 3u);
  const PlanStep& soak = plan->steps[0];
  EXPECT_EQ(soak.kind, StepKind::kSoak);
  EXPECT_DOUBLE_EQ(soak.acquire_s, 1200.0);
  EXPECT_DOUBLE_EQ(soak.tolerance_c, 0.5);
  EXPECT_DOUBLE_EQ(soak.stability_c_per_min, 0.02);
  EXPECT_DOUBLE_EQ(soak.stability_window_s, 600.0);
  EXPECT_DOUBLE_EQ(soak.settle_timeout_s, 3 * 3600.0);
  EXPECT_EQ(plan->steps[1].kind, StepKind::kRamp);
  EXPECT_DOUBLE_EQ(plan->steps[1].rate_c_per_min, 1.5);
  EXPECT_DOUBLE_EQ(plan->steps[2].hold_s, 300.0);
  EXPECT_EQ(plan->name, "s.toml");
}

// Each bad schedule and the message (file:line: key: ...) it must produce.
struct BadCase {
  const char* what;
  const char* toml;
  std::vector<const char*> expected;
};

class BadSchedule : public ::testing::TestWithParam<BadCase> {};

TEST_P(BadSchedule, IsRefusedWithEveryErrorNamed) {
  const BadCase& c = GetParam();
  auto plan = parse_schedule(c.toml, "bad.toml", kLimits);
  ASSERT_FALSE(plan.ok()) << c.what;
  for (const char* e : c.expected) EXPECT_THAT(plan.error().message, HasSubstr(e)) << c.what;
}

INSTANTIATE_TEST_SUITE_P(
    Corpus, BadSchedule,
    ::testing::Values(
        BadCase{"syntax", "[[step]\n", {"bad.toml:1: TOML syntax error"}},
        BadCase{"no steps", "name = \"x\"\n", {"bad.toml:1: step: missing"}},
        BadCase{"above limit",
                "[[step]]\ntype = \"soak\"\nsetpoint_c = 80\nacquire_min = 5\n",
                {"bad.toml:3: step[0].setpoint_c: 80 °C is outside the station's limits"}},
        BadCase{"ramp too fast",
                "[[step]]\ntype = \"ramp\"\ntarget_c = 40\nrate_c_per_min = 5\n",
                {"bad.toml:4: step[0].rate_c_per_min: 5 °C/min exceeds the station's max ramp "
                 "rate 2 °C/min"}},
        BadCase{"unknown key and wrong type, both reported",
                "[[step]]\ntype = \"soak\"\nsetpoint_c = \"twenty\"\nacquire_min = 5\n"
                "acqire_min = 3\n",
                {"bad.toml:3: step[0].setpoint_c: expected a number, got string",
                 "bad.toml:5: step[0].acqire_min: unknown key"}},
        BadCase{"negative duration",
                "[[step]]\ntype = \"soak\"\nsetpoint_c = 20\nacquire_min = -5\n",
                {"bad.toml:4: step[0].acquire_min: -5 min is out of range"}},
        BadCase{"missing acquisition",
                "[[step]]\ntype = \"soak\"\nsetpoint_c = 20\n",
                {"step[0].acquire_min: missing"}},
        BadCase{"unknown step type",
                "[[step]]\ntype = \"bake\"\n",
                {"bad.toml:2: step[0].type: \"bake\" is not one of: soak, ramp, hold, repeat"}},
        BadCase{"window longer than timeout",
                "[[step]]\ntype = \"soak\"\nsetpoint_c = 20\nacquire_min = 5\n"
                "stability_window_min = 60\nsettle_timeout_min = 30\n",
                {"stability_window_min: is longer than settle_timeout_min"}},
        BadCase{"repeat without count",
                "[[step]]\ntype = \"repeat\"\n[[step.steps]]\ntype = \"hold\"\nsetpoint_c = 20\n"
                "duration_min = 1\n",
                {"step[0].count: missing"}},
        BadCase{"tolerance zero",
                "[[step]]\ntype = \"soak\"\nsetpoint_c = 20\nacquire_min = 5\ntolerance_c = 0\n",
                {"bad.toml:5: step[0].tolerance_c: 0 is out of range"}}));

}  // namespace
}  // namespace gyrotherm::schedules
