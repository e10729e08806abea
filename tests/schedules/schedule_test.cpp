#include "gyrotherm/schedules/schedule.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "gyrotherm/schedules/sequencer.h"

namespace gyrotherm::schedules {
namespace {

using ::testing::HasSubstr;

const StationLimits kLimits{-20.0, 60.0, 2.0, StationLimits::Table{1000.0, 1000.0}};

Result<Plan> load_shipped(const std::string& name) {
  return load_schedule(std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/" + name, kLimits);
}

std::vector<StepKind> kinds_of(const Plan& plan) {
  std::vector<StepKind> kinds;
  for (const auto& s : plan.steps) kinds.push_back(s.kind);
  return kinds;
}

TEST(Schedule, ShippedDemoAndRampSchedules) {
  auto demo = load_shipped("demo.toml");
  ASSERT_TRUE(demo.ok()) << demo.error().message;
  EXPECT_EQ(demo->name, "demo");
  EXPECT_THAT(kinds_of(*demo),
              ::testing::ElementsAre(StepKind::kSoak, StepKind::kRamp, StepKind::kSoak));
  EXPECT_DOUBLE_EQ(demo->steps[1].setpoint_c, 40.0);
  EXPECT_DOUBLE_EQ(demo->steps[1].rate_c_per_min, 1.0);
  // The second soak is adaptive: the plan counts its cap (30 min).
  ASSERT_TRUE(demo->steps[2].adaptive);
  EXPECT_DOUBLE_EQ(demo->steps[2].adaptive->target_u95_dph, 0.15);
  EXPECT_DOUBLE_EQ(demo->nominal_duration_s(), (20 + 30) * 60.0);

  auto ramp = load_shipped("paper-ramp.toml");
  ASSERT_TRUE(ramp.ok()) << ramp.error().message;
  EXPECT_EQ(ramp->name, "paper-ramp");
  EXPECT_THAT(kinds_of(*ramp), ::testing::ElementsAre(StepKind::kSoak, StepKind::kRamp));
  EXPECT_DOUBLE_EQ(ramp->steps[0].setpoint_c, -20.0);
  EXPECT_DOUBLE_EQ(ramp->steps[1].setpoint_c, 60.0);
  EXPECT_DOUBLE_EQ(ramp->steps[1].rate_c_per_min, 0.5);
}

TEST(Schedule, PaperTable1HasEightTemperaturesFourTimes) {
  auto plan = load_shipped("paper-table1.toml");
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  ASSERT_EQ(plan->steps.size(), 32u);
  const double kSetpointsC[] = {-14.6, 2.7, 22.9, 40.0, 47.3, 50.8, 56.4, 60.0};
  for (std::size_t i = 0; i < plan->steps.size(); ++i) {
    EXPECT_EQ(plan->steps[i].kind, StepKind::kSoak) << i;
    EXPECT_DOUBLE_EQ(plan->steps[i].setpoint_c, kSetpointsC[i % 8]) << i;
  }
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

TEST(Schedule, AnAdaptiveSoakCarriesItsTargetAndIsPlannedAtItsCap) {
  auto plan = parse_schedule(R"(
[[step]]
type = "soak"
setpoint_c = 20
acquire = { target_u95_dph = 0.05, min_min = 15, max_min = 90 }
[[step]]
type = "soak"
setpoint_c = 40
acquire = { target_u95_dph = 0.1, min_min = 0, max_min = 30 }
)",
                             "a.toml", kLimits);
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  ASSERT_EQ(plan->steps.size(), 2u);
  const PlanStep& a = plan->steps[0];
  ASSERT_TRUE(a.adaptive);
  EXPECT_DOUBLE_EQ(a.adaptive->target_u95_dph, 0.05);
  EXPECT_DOUBLE_EQ(a.adaptive->min_s, 900.0);
  EXPECT_DOUBLE_EQ(a.adaptive->max_s, 5400.0);
  EXPECT_DOUBLE_EQ(a.acquire_s, 5400.0) << "the cap is what a plan counts";
  ASSERT_TRUE(plan->steps[1].adaptive);
  EXPECT_DOUBLE_EQ(plan->steps[1].adaptive->min_s, 0.0) << "min_min may be 0";
  EXPECT_DOUBLE_EQ(plan->nominal_duration_s(), 5400.0 + 1800.0);
  EXPECT_EQ(acquiring_for(a),
            "acquiring until the bias is known to ± 0.05 °/h (U95; 15 to 90 min)");
}

// Bad schedules are tested by the corpus in tests/schedules/bad/
// (bad_schedules_test.cpp); these are the edges that must still be accepted.

TEST(Schedule, BoundariesAreAccepted) {
  auto plan = parse_schedule(R"(
[[step]]
type = "ramp"            # a first ramp starts wherever the chamber is
target_c = -20
rate_c_per_min = 2       # the station's max
table_rate_dps = -1000
[[step]]
type = "soak"
setpoint_c = -20
acquire_min = 43200      # 30 days
tolerance_c = 0.01
stability_c_per_min = 10
stability_window_min = 1440   # 24 h
settle_timeout_min = 10080    # 7 days
[[step]]
type = "hold"
setpoint_c = 60
duration_min = 43200
table_rate_dps = 1000
)",
                             "edges.toml", kLimits);
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  ASSERT_EQ(plan->steps.size(), 3u);
  EXPECT_EQ(plan->steps[0].table.mode, TableDemandMode::kRate);
  EXPECT_DOUBLE_EQ(plan->steps[0].table.rate_dps, -1000.0);
  EXPECT_DOUBLE_EQ(plan->steps[1].stability_window_s, 1440 * 60.0);
  EXPECT_DOUBLE_EQ(plan->steps[1].settle_timeout_s, 10080 * 60.0);
  EXPECT_DOUBLE_EQ(plan->steps[2].hold_s, 43200 * 60.0);
  EXPECT_DOUBLE_EQ(plan->nominal_duration_s(), 2 * 43200 * 60.0);
}

TEST(Schedule, StabilityWindowIsCheckedAgainstItsOwnUpperBound) {
  auto plan = parse_schedule(
      "[[step]]\ntype = \"soak\"\nsetpoint_c = 20\nacquire_min = 1\n"
      "stability_window_min = 1441\nsettle_timeout_min = 2000\n",
      "w.toml", kLimits);
  ASSERT_FALSE(plan.ok());
  EXPECT_EQ(plan.error().message,
            "w.toml:5: step[0].stability_window_min: 1441 min is out of range: must be >= 1 and "
            "<= 1440 min (24 h)\n");
}

TEST(Schedule, RepeatsExpandInOrderWithLabels) {
  auto plan = parse_schedule(R"(
[[step]]
type = "soak"
setpoint_c = 20
acquire_min = 5
[[step]]
type = "repeat"
count = 2
  [[step.steps]]
  type = "ramp"
  target_c = 30
  rate_c_per_min = 1
  [[step.steps]]
  type = "repeat"
  count = 2
    [[step.steps.steps]]
    type = "hold"
    setpoint_c = 25
    duration_min = 1
  [[step.steps]]
  type = "ramp"
  target_c = 20
  rate_c_per_min = 0.5
)",
                             "r.toml", kLimits);
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  std::vector<std::string> labels;
  std::vector<int> lines;
  for (const auto& s : plan->steps) {
    labels.push_back(s.label);
    lines.push_back(s.source_line);
  }
  EXPECT_THAT(labels, ::testing::ElementsAre("step 1: soak 20 °C",
                                             "step 2: ramp to 30 °C at 1 °C/min (repeat 1/2)",
                                             "step 3: hold 25 °C (repeat 1/2) (repeat 1/2)",
                                             "step 4: hold 25 °C (repeat 2/2) (repeat 1/2)",
                                             "step 5: ramp to 20 °C at 0.5 °C/min (repeat 1/2)",
                                             "step 6: ramp to 30 °C at 1 °C/min (repeat 2/2)",
                                             "step 7: hold 25 °C (repeat 1/2) (repeat 2/2)",
                                             "step 8: hold 25 °C (repeat 2/2) (repeat 2/2)",
                                             "step 9: ramp to 20 °C at 0.5 °C/min (repeat 2/2)"));
  EXPECT_THAT(lines, ::testing::ElementsAre(2, 9, 16, 16, 20, 9, 16, 16, 20));
}

TEST(Schedule, PlanOfExactlyTheStepLimitIsAccepted) {
  std::string text = "[[step]]\ntype = \"repeat\"\ncount = 1000\n";
  for (int i = 0; i < 10; ++i) {
    text += fmt::format("[[step.steps]]\ntype = \"hold\"\nsetpoint_c = {}\nduration_min = 1\n", i);
  }
  auto plan = parse_schedule(text, "many.toml", kLimits);
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  EXPECT_EQ(plan->steps.size(), kMaxPlanSteps);
}

TEST(Schedule, TooManyStepsWithoutRepeatsIsRefused) {
  std::string text;
  for (std::size_t i = 0; i <= kMaxPlanSteps; ++i) {
    text += "[[step]]\ntype = \"hold\"\nsetpoint_c = 20\nduration_min = 1\n";
  }
  auto plan = parse_schedule(text, "long.toml", kLimits);
  ASSERT_FALSE(plan.ok());
  EXPECT_EQ(plan.error().message,
            "long.toml:1: step: the plan has 10001 steps; the limit is 10000\n");
}

}  // namespace
}  // namespace gyrotherm::schedules
