// Table demands and scale_factor steps (schedule.h): how they read, how a
// scale_factor step expands into rate points over whole turns, and what the
// plan's nominal duration counts. The refusals, each with its file:line:key,
// are in the bad-schedule corpus (tests/schedules/bad/table-demand,
// scale-factor, scale-factor-too-many, no-table-demands).
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "gyrotherm/schedules/schedule.h"
#include "station_limits.h"

namespace gyrotherm::schedules {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

Result<Plan> parse(const std::string& text, const StationLimits& limits = kTable) {
  return parse_schedule(text, "t.toml", limits);
}

std::string hold_with(const std::string& table_line) {
  return "[[step]]\ntype = \"hold\"\nsetpoint_c = 20\nduration_min = 1\n" + table_line + "\n";
}

std::vector<double> rates_of(const Plan& plan) {
  std::vector<double> out;
  for (const auto& s : plan.steps) out.push_back(s.table.rate_dps);
  return out;
}

TEST(TableDemand, InlineTableAndItsShortForm) {
  struct Case {
    std::string line;
    TableDemandMode mode;
    std::optional<double> position_deg;
    double rate_dps;
  };
  const Case cases[] = {
      {"", TableDemandMode::kNone, std::nullopt, 0},
      {"table = { mode = \"static\" }", TableDemandMode::kStatic, std::nullopt, 0},
      {"table = { mode = \"static\", position_deg = 90.0 }", TableDemandMode::kStatic, 90.0, 0},
      // Positions are any finite angle, normalised to [0, 360).
      {"table = { mode = \"static\", position_deg = 450 }", TableDemandMode::kStatic, 90.0, 0},
      {"table = { mode = \"static\", position_deg = -90 }", TableDemandMode::kStatic, 270.0, 0},
      {"table = { mode = \"static\", position_deg = 360 }", TableDemandMode::kStatic, 0.0, 0},
      {"table = { mode = \"static\", position_deg = -720.5 }", TableDemandMode::kStatic, 359.5, 0},
      {"table = { mode = \"rate\", rate_dps = 10.0 }", TableDemandMode::kRate, std::nullopt, 10},
      {"table = { mode = \"rate\", rate_dps = -500 }", TableDemandMode::kRate, std::nullopt, -500},
      {"table_rate_dps = -2.5", TableDemandMode::kRate, std::nullopt, -2.5},
      {"table_rate_dps = 0", TableDemandMode::kStatic, std::nullopt, 0},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.line);
    auto plan = parse(hold_with(c.line));
    ASSERT_TRUE(plan.ok()) << plan.error().message;
    const TableDemand& d = plan->steps.at(0).table;
    EXPECT_EQ(d.mode, c.mode);
    EXPECT_EQ(d.position_deg.has_value(), c.position_deg.has_value());
    if (d.position_deg && c.position_deg) {
      EXPECT_DOUBLE_EQ(*d.position_deg, *c.position_deg);
    }
    EXPECT_DOUBLE_EQ(d.rate_dps, c.rate_dps);
    EXPECT_EQ(plan->steps[0].kind, StepKind::kHold) << "a demand does not change the step";
  }
  // Soaks and ramps take it too.
  auto plan = parse(
      "[[step]]\ntype = \"soak\"\nsetpoint_c = 20\nacquire_min = 1\n"
      "table = { mode = \"static\", position_deg = 45 }\n"
      "[[step]]\ntype = \"ramp\"\ntarget_c = 30\nrate_c_per_min = 1\n"
      "table = { mode = \"rate\", rate_dps = 1 }\n");
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  EXPECT_EQ(plan->steps[0].table.mode, TableDemandMode::kStatic);
  EXPECT_EQ(plan->steps[1].table.mode, TableDemandMode::kRate);
}

TEST(TableDemand, MaxRateIsTheStationsAndBothEndsAreAllowed) {
  EXPECT_TRUE(parse(hold_with("table_rate_dps = 500")).ok());
  EXPECT_TRUE(parse(hold_with("table = { mode = \"rate\", rate_dps = -500 }")).ok());
  auto over = parse(hold_with("table = { mode = \"rate\", rate_dps = 500.5 }"));
  ASSERT_FALSE(over.ok());
  EXPECT_EQ(over.error().message,
            "t.toml:5: step[0].table.rate_dps: 500.5 °/s is faster than the station's max table "
            "rate 500 °/s ([table] max_rate_dps)\n");
}

TEST(TableDemand, StationWithoutATableRefusesEveryDemandButAcceptsNone) {
  EXPECT_TRUE(parse(hold_with(""), kNoTable).ok());
  for (const char* line :
       {"table_rate_dps = 0", "table_rate_dps = 1", "table = { mode = \"static\" }",
        "table = { mode = \"rate\", "
        "rate_dps = 1 }"}) {
    SCOPED_TRACE(line);
    auto plan = parse(hold_with(line), kNoTable);
    ASSERT_FALSE(plan.ok());
    EXPECT_THAT(plan.error().message, HasSubstr("t.toml:5: step[0].table"));
    EXPECT_THAT(plan.error().message, HasSubstr("the station has no [table]"));
  }
}

// An AERO station (StationLimits::Table::whole_numbers, from [table]
// profile = "aero"): its driver sends JOG and MOV as whole numbers, so a
// rate or position that is not one is refused when the schedule is read,
// not hours later at the table.
TEST(TableDemand, AStationWhoseTableTakesWholeNumbersRefusesOthersEarly) {
  const StationLimits aero{-20.0, 60.0, 2.0, StationLimits::Table{500.0, 100.0, true}};
  for (const char* line : {"table_rate_dps = -100", "table = { mode = \"rate\", rate_dps = 7 }",
                           "table = { mode = \"static\", position_deg = -90 }"}) {
    SCOPED_TRACE(line);
    EXPECT_TRUE(parse(hold_with(line), aero).ok());
  }
  auto rate = parse(hold_with("table_rate_dps = 7.5"), aero);
  ASSERT_FALSE(rate.ok());
  EXPECT_EQ(rate.error().message,
            "t.toml:5: step[0].table_rate_dps: 7.5 °/s is not a whole number, and the station's "
            "table takes whole °/s only ([table] profile \"aero\": JOG and MOV send whole "
            "numbers, docs/table.md)\n");
  auto position = parse(hold_with("table = { mode = \"static\", position_deg = 90.25 }"), aero);
  ASSERT_FALSE(position.ok());
  EXPECT_THAT(position.error().message,
              HasSubstr("step[0].table.position_deg: 90.25 ° is not a whole number"));
  auto sweep =
      parse("[[step]]\ntype = \"scale_factor\"\nsetpoint_c = 20\nrates_dps = [1, 2.5]\n", aero);
  ASSERT_FALSE(sweep.ok());
  EXPECT_THAT(sweep.error().message, HasSubstr("rates_dps[1]: 2.5 °/s is not a whole number"));
  // Any other station takes them.
  EXPECT_TRUE(parse(hold_with("table_rate_dps = 7.5")).ok());
}

// A scale_factor step with `extra` keys at 20 °C.
std::string sf(const std::string& extra) {
  return "[[step]]\ntype = \"scale_factor\"\nsetpoint_c = 20\n" + extra + "\n";
}

TEST(ScaleFactor, ExpandsAscendingPlusThenMinusWithWholeTurns) {
  // Listed out of order: the points go by |rate| ascending.
  auto plan = parse(sf("rates_dps = [10, 1, 5.0]\nmin_dwell_s = 100"));
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  EXPECT_THAT(rates_of(*plan), ElementsAre(1, -1, 5, -5, 10, -10));
  for (const PlanStep& s : plan->steps) {
    SCOPED_TRACE(s.label);
    const double rate = std::abs(s.table.rate_dps);
    EXPECT_EQ(s.kind, StepKind::kRate);
    EXPECT_EQ(s.table.mode, TableDemandMode::kRate);
    EXPECT_DOUBLE_EQ(s.setpoint_c, 20.0);
    EXPECT_EQ(s.source_line, 1);
    EXPECT_EQ(s.sf_sequence, 1);
    EXPECT_EQ(s.sf_repetition, 1);
    // The dwell is a whole number of turns, at least min_dwell_s and one
    // turn, and the fewest turns that make it so.
    EXPECT_NEAR(s.dwell_s * rate, 360.0 * s.turns, 1e-9);
    EXPECT_GE(s.turns, 1);
    EXPECT_GE(s.dwell_s, 100.0 - 1e-9);
    if (s.turns > 1) {
      EXPECT_LT((s.turns - 1) * 360.0 / rate, 100.0);
    }
    EXPECT_DOUBLE_EQ(s.acquire_s, 0);
    EXPECT_DOUBLE_EQ(s.hold_s, 0);
  }
  // By hand: 1 °/s 1 turn in 360 s; 5 °/s 2 turns (500° > 360) in 144 s;
  // 10 °/s 3 turns (1000° > 720) in 108 s.
  EXPECT_EQ(plan->steps[0].turns, 1);
  EXPECT_DOUBLE_EQ(plan->steps[0].dwell_s, 360.0);
  EXPECT_EQ(plan->steps[3].turns, 2);
  EXPECT_DOUBLE_EQ(plan->steps[3].dwell_s, 144.0);
  EXPECT_EQ(plan->steps[4].turns, 3);
  EXPECT_DOUBLE_EQ(plan->steps[4].dwell_s, 108.0);
  EXPECT_EQ(plan->steps[4].label, "step 5: SF +10 °/s, rep 1 (3 turns)");
  EXPECT_EQ(plan->steps[1].label, "step 2: SF -1 °/s, rep 1 (1 turn)");
}

TEST(ScaleFactor, TurnsAndMinDwellPickTheLongerAndAnExactQuotientIsNotRoundedUp) {
  // 10 s at 36 °/s is exactly one turn.
  auto exact = parse(sf("rates_dps = [36]\ndirections = \"positive\""));
  ASSERT_TRUE(exact.ok()) << exact.error().message;
  ASSERT_EQ(exact->steps.size(), 1u);
  EXPECT_EQ(exact->steps[0].turns, 1);
  EXPECT_DOUBLE_EQ(exact->steps[0].dwell_s, 10.0);
  // turns = 4 is longer than min_dwell_s at 36 °/s; shorter at 360 °/s.
  auto both =
      parse(sf("rates_dps = [36, 360]\nturns = 4\nmin_dwell_s = 10\n"
               "directions = \"negative\""));
  ASSERT_TRUE(both.ok()) << both.error().message;
  EXPECT_THAT(rates_of(*both), ElementsAre(-36, -360));
  EXPECT_EQ(both->steps[0].turns, 4);
  EXPECT_DOUBLE_EQ(both->steps[0].dwell_s, 40.0);
  EXPECT_EQ(both->steps[1].turns, 10);
  EXPECT_DOUBLE_EQ(both->steps[1].dwell_s, 10.0);
}

TEST(ScaleFactor, RepetitionsAndDescendingOrder) {
  auto plan = parse(sf("rates_dps = [5, 50]\nrepetitions = 3\norder = \"descending\""));
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  EXPECT_THAT(rates_of(*plan), ElementsAre(50, -50, 5, -5, 50, -50, 5, -5, 50, -50, 5, -5));
  std::vector<int> reps;
  for (const auto& s : plan->steps) {
    reps.push_back(s.sf_repetition);
    EXPECT_EQ(s.sf_sequence, 1);
  }
  EXPECT_THAT(reps, ElementsAre(1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3));
  EXPECT_EQ(plan->steps[8].label, "step 9: SF +50 °/s, rep 3 (2 turns)");
}

TEST(ScaleFactor, SequencesAreNumberedInPlanOrderAlsoInsideRepeats) {
  auto plan = parse(R"(
[[step]]
type = "soak"
setpoint_c = 20
acquire_min = 1
table = { mode = "static", position_deg = 0 }
[[step]]
type = "repeat"
count = 2
  [[step.steps]]
  type = "scale_factor"
  setpoint_c = 20
  rates_dps = [10]
  [[step.steps]]
  type = "hold"
  setpoint_c = 30
  duration_min = 1
[[step]]
type = "scale_factor"
setpoint_c = 30
rates_dps = [10]
directions = "positive"
repetitions = 2
[[step]]
type = "ramp"
target_c = 40
rate_c_per_min = 1
)");
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  std::vector<std::string> labels;
  std::vector<int> sequences, repetitions;
  for (const auto& s : plan->steps) {
    labels.push_back(s.label);
    sequences.push_back(s.sf_sequence);
    repetitions.push_back(s.sf_repetition);
  }
  EXPECT_THAT(
      labels,
      ElementsAre("step 1: soak 20 °C", "step 2: SF +10 °/s, rep 1 (1 turn) (repeat 1/2)",
                  "step 3: SF -10 °/s, rep 1 (1 turn) (repeat 1/2)",
                  "step 4: hold 30 °C (repeat 1/2)",
                  "step 5: SF +10 °/s, rep 1 (1 turn) (repeat 2/2)",
                  "step 6: SF -10 °/s, rep 1 (1 turn) (repeat 2/2)",
                  "step 7: hold 30 °C (repeat 2/2)", "step 8: SF +10 °/s, rep 1 (1 turn)",
                  "step 9: SF +10 °/s, rep 2 (1 turn)", "step 10: ramp to 40 °C at 1 °C/min"));
  EXPECT_THAT(sequences, ElementsAre(0, 1, 1, 0, 2, 2, 0, 3, 3, 0));
  EXPECT_THAT(repetitions, ElementsAre(0, 1, 1, 0, 1, 1, 0, 1, 2, 0));
  // A ramp after rate points starts from their set point (30 °C), so it is
  // not empty: the ramp check sees through the expansion.
  auto empty = parse(sf("rates_dps = [10]") +
                     "[[step]]\ntype = \"ramp\"\ntarget_c = 20\nrate_c_per_min = 1\n");
  ASSERT_FALSE(empty.ok());
  EXPECT_THAT(empty.error().message, HasSubstr("the ramp would be empty"));
}

TEST(ScaleFactor, ExpandedPointsCountAgainstThePlanLimit) {
  // 50 rates x 2 directions x 100 repetitions = 10000: exactly the limit.
  std::string rates = "1";
  for (int r = 2; r <= 50; ++r) rates += fmt::format(", {}", r);
  auto at_limit = parse(sf("rates_dps = [" + rates + "]\nrepetitions = 100"));
  ASSERT_TRUE(at_limit.ok()) << at_limit.error().message;
  EXPECT_EQ(at_limit->steps.size(), kMaxPlanSteps);
  auto over = parse(sf("rates_dps = [" + rates + "]\nrepetitions = 100") +
                    "[[step]]\ntype = \"hold\"\nsetpoint_c = 20\nduration_min = 1\n");
  ASSERT_FALSE(over.ok());
  EXPECT_THAT(over.error().message, HasSubstr("the plan has 10001 steps; the limit is 10000"));
}

// Each rate point counts its dwell and its spin-up from the previous step's
// rate at the station's acceleration; soaks count their acquisition.
TEST(ScaleFactor, NominalDurationCountsDwellAndSpinUp) {
  auto plan = parse(
      "[[step]]\ntype = \"soak\"\nsetpoint_c = 20\nacquire_min = 5\n"
      "table = { mode = \"static\" }\n" +
      sf("rates_dps = [10, 100]\nmin_dwell_s = 1"));
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  EXPECT_DOUBLE_EQ(plan->table_accel_dps2, 100.0);
  // 300 s of soak; dwells 36 + 36 + 3.6 + 3.6 s; spin-ups at 100 °/s²:
  // 0 -> +10: 0.1 s, +10 -> -10: 0.2 s, -10 -> +100: 1.1 s, +100 -> -100: 2 s.
  EXPECT_NEAR(plan->nominal_duration_s(), 300 + 79.2 + 3.4, 1e-9);
}

// The shipped scale-factor schedules are valid for a 500 °/s, 100 °/s²
// table. Nominal durations: numpy over the points (rates, ceil turns,
// dwells, |Δrate| / 100), 14613 s and 811.2 s.
TEST(ScaleFactor, ShippedSchedulesParse) {
  auto full = load_schedule(
      std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/scale-factor.toml", kTable);
  ASSERT_TRUE(full.ok()) << full.error().message;
  ASSERT_EQ(full->steps.size(), 3u * (1 + 7 * 2 * 2));
  for (std::size_t temp = 0; temp < 3; ++temp) {
    const PlanStep& soak = full->steps[temp * 29];
    EXPECT_EQ(soak.kind, StepKind::kSoak);
    EXPECT_EQ(soak.table.mode, TableDemandMode::kStatic);
    ASSERT_TRUE(soak.table.position_deg.has_value());
    for (std::size_t k = 1; k < 29; ++k) {
      const PlanStep& p = full->steps[temp * 29 + k];
      EXPECT_EQ(p.kind, StepKind::kRate);
      EXPECT_EQ(p.sf_sequence, static_cast<int>(temp + 1));
      EXPECT_DOUBLE_EQ(p.setpoint_c, soak.setpoint_c);
      EXPECT_GE(p.dwell_s, 60.0);
    }
  }
  const auto full_rates = rates_of(*full);
  EXPECT_THAT(std::vector<double>(full_rates.begin() + 1, full_rates.begin() + 15),
              ElementsAre(1, -1, 5, -5, 10, -10, 50, -50, 100, -100, 200, -200, 500, -500));
  EXPECT_NEAR(full->nominal_duration_s(), 14613.0, 1e-6);

  auto demo = load_schedule(
      std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/demo-scale-factor.toml", kTable);
  ASSERT_TRUE(demo.ok()) << demo.error().message;
  ASSERT_EQ(demo->steps.size(), 14u);
  EXPECT_DOUBLE_EQ(demo->steps[0].setpoint_c, 15.0);
  EXPECT_DOUBLE_EQ(demo->steps[7].setpoint_c, 35.0);
  const auto demo_rates = rates_of(*demo);
  EXPECT_THAT(std::vector<double>(demo_rates.begin() + 1, demo_rates.begin() + 7),
              ElementsAre(10, -10, 50, -50, 200, -200));
  EXPECT_NEAR(demo->nominal_duration_s(), 811.2, 1e-6);

  // Neither runs on a station without a table.
  EXPECT_FALSE(
      load_schedule(std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/scale-factor.toml",
                    kNoTable)
          .ok());
}

}  // namespace
}  // namespace gyrotherm::schedules
