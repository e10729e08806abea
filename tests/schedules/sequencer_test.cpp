#include "gyrotherm/schedules/sequencer.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <vector>

namespace gyrotherm::schedules {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

struct Transition {
  RunState from, to;
  double t_s;
  std::string reason;
};

struct FinishedStep {
  std::size_t index;
  StepTimes times;
  bool completed;
};

class RecordingObserver : public SequencerObserver {
 public:
  void on_state(RunState from, RunState to, double t_s, const std::string& reason) override {
    transitions.push_back({from, to, t_s, reason});
  }
  void on_step_started(std::size_t index, const PlanStep&, double) override {
    started.push_back(index);
  }
  void on_acquisition_started(std::size_t index, const StepTimes& times) override {
    acquisitions.push_back({index, times, true});
  }
  void on_step_finished(std::size_t index, const PlanStep&, const StepTimes& times,
                        bool completed) override {
    finished.push_back({index, times, completed});
  }
  std::vector<RunState> states() const {
    std::vector<RunState> out;
    for (const auto& t : transitions) out.push_back(t.to);
    return out;
  }

  std::vector<Transition> transitions;
  std::vector<std::size_t> started;
  std::vector<FinishedStep> acquisitions;
  std::vector<FinishedStep> finished;
};

// A deterministic stand-in for the chamber: air follows the set point with a
// 60 s lag, the shell follows the air with a 900 s lag; top/side straddle the
// shell by a gradient proportional to its rate.
struct FakePlant {
  double air_c = 23.0, shell_c = 23.0;
  void step(double dt_s, double setpoint_c) {
    air_c += (setpoint_c - air_c) * (1.0 - std::exp(-dt_s / 60.0));
    shell_c += (air_c - shell_c) * (1.0 - std::exp(-dt_s / 900.0));
  }
  Readings readings() const { return {air_c, shell_c + 0.05, shell_c - 0.05}; }
};

// Runs the sequencer against the fake plant with 1 s ticks until it finishes
// or `max_s` of station time passes. Returns the station time at the end.
double run(Sequencer& seq, FakePlant& plant, double max_s, double t0_s = 0.0) {
  double t = t0_s;
  while (!seq.finished() && t < max_s) {
    t += 1.0;
    plant.step(1.0, seq.setpoint_c());
    seq.tick(t, plant.readings());
  }
  return t;
}

Plan make_plan(std::vector<PlanStep> steps) {
  Plan p;
  p.name = "test";
  p.steps = std::move(steps);
  return p;
}

PlanStep soak(double sp, double acquire_min) {
  PlanStep s;
  s.kind = StepKind::kSoak;
  s.setpoint_c = sp;
  s.acquire_s = acquire_min * 60.0;
  s.label = fmt::format("soak {}", sp);
  return s;
}

PlanStep ramp(double target, double rate) {
  PlanStep s;
  s.kind = StepKind::kRamp;
  s.setpoint_c = target;
  s.rate_c_per_min = rate;
  s.label = fmt::format("ramp {}", target);
  return s;
}

TEST(Sequencer, DemoScheduleRunsThroughItsStates) {
  RecordingObserver obs;
  Sequencer seq(make_plan({soak(20, 20), ramp(40, 1.0), soak(40, 20)}), {23.0}, obs);
  FakePlant plant;
  seq.start(0.0, 23.0);
  run(seq, plant, 12 * 3600.0);
  ASSERT_TRUE(seq.finished());
  EXPECT_THAT(obs.states(),
              ElementsAre(RunState::kSettling, RunState::kAcquiring, RunState::kRamping,
                          RunState::kSettling, RunState::kAcquiring, RunState::kCompleted));
  EXPECT_EQ(seq.state(), RunState::kCompleted);
  EXPECT_DOUBLE_EQ(seq.setpoint_c(), 23.0) << "completed runs leave the chamber at the safe point";
  ASSERT_EQ(obs.finished.size(), 3u);
  for (const auto& f : obs.finished) EXPECT_TRUE(f.completed);
  // Soak windows are exactly the acquisition time and start only after a
  // full stability window.
  const StepTimes& s1 = obs.finished[0].times;
  EXPECT_DOUBLE_EQ(*s1.acquire_end_s - *s1.acquire_start_s, 1200.0);
  EXPECT_GE(*s1.settled_s - s1.start_s, 600.0);
  // The ramp acquires from its start until the target is reached: 20 °C at 1 °C/min.
  const StepTimes& r = obs.finished[1].times;
  EXPECT_NEAR(*r.acquire_end_s - *r.acquire_start_s, 1200.0, 1.0);
  EXPECT_DOUBLE_EQ(*r.acquire_start_s, obs.finished[0].times.end_s.value());
}

TEST(Sequencer, AcquisitionStartsOnlyWhenShellIsStable) {
  RecordingObserver obs;
  Sequencer seq(make_plan({soak(40, 10)}), {23.0}, obs);
  FakePlant plant;
  seq.start(0.0, 23.0);
  double t = 0;
  while (seq.state() == RunState::kSettling && t < 6 * 3600) {
    t += 1.0;
    plant.step(1.0, seq.setpoint_c());
    seq.tick(t, plant.readings());
  }
  ASSERT_EQ(seq.state(), RunState::kAcquiring);
  // Gate: |dT/dt| < 0.02 °C/min. The shell's rate is 17 °C / 900 s x e^(-t/900)
  // x 60 s/min, below 0.02 °C/min only after ~ 900 ln(56.7) ≈ 3600 s.
  EXPECT_GT(t, 3500.0);
  EXPECT_NEAR(plant.shell_c, 40.0, 0.5);
}

TEST(Sequencer, SettleTimeoutFailsToSafeSetpoint) {
  RecordingObserver obs;
  PlanStep s = soak(40, 10);
  s.settle_timeout_s = 1800;  // far too short for a 900 s case lag
  Sequencer seq(make_plan({s, soak(20, 10)}), {23.0}, obs);
  FakePlant plant;
  seq.start(0.0, 23.0);
  run(seq, plant, 4 * 3600.0);
  EXPECT_EQ(seq.state(), RunState::kFailed);
  EXPECT_DOUBLE_EQ(seq.setpoint_c(), 23.0);
  ASSERT_FALSE(obs.transitions.empty());
  EXPECT_THAT(obs.transitions.back().reason, HasSubstr("not stable within 30 min"));
  ASSERT_EQ(obs.finished.size(), 1u);
  EXPECT_FALSE(obs.finished[0].completed);
  EXPECT_THAT(obs.started, ElementsAre(0u)) << "the second step never starts";
}

TEST(Sequencer, RampMovesTheSetpointLinearlyFromWhereItWas) {
  RecordingObserver obs;
  Sequencer seq(make_plan({ramp(30, 0.5)}), {23.0}, obs);
  seq.start(0.0, 20.0);
  seq.tick(600.0, {});
  EXPECT_DOUBLE_EQ(seq.setpoint_c(), 25.0);  // 20 + 0.5 °C/min x 10 min
  seq.tick(1199.0, {});
  EXPECT_NEAR(seq.setpoint_c(), 29.99167, 1e-4);
  seq.tick(1200.0, {});
  EXPECT_EQ(seq.state(), RunState::kCompleted);
}

TEST(Sequencer, DownwardRamp) {
  RecordingObserver obs;
  Sequencer seq(make_plan({ramp(-20, 2.0)}), {23.0}, obs);
  seq.start(0.0, 20.0);
  seq.tick(300.0, {});
  EXPECT_DOUBLE_EQ(seq.setpoint_c(), 10.0);
}

TEST(Sequencer, AbortClosesTheStepAndGoesSafe) {
  RecordingObserver obs;
  Sequencer seq(make_plan({soak(50, 60)}), {23.0}, obs);
  seq.start(0.0, 23.0);
  seq.tick(10.0, {});
  seq.abort(11.0, "operator abort");
  EXPECT_EQ(seq.state(), RunState::kFailed);
  EXPECT_DOUBLE_EQ(seq.setpoint_c(), 23.0);
  EXPECT_THAT(obs.states(),
              ElementsAre(RunState::kSettling, RunState::kAborting, RunState::kFailed));
  ASSERT_EQ(obs.finished.size(), 1u);
  EXPECT_FALSE(obs.finished[0].completed);
}

TEST(Sequencer, InterruptMarksTheRun) {
  RecordingObserver obs;
  Sequencer seq(make_plan({soak(50, 60)}), {23.0}, obs);
  seq.start(0.0, 23.0);
  seq.interrupt(5.0, "daemon stopped: SIGTERM");
  EXPECT_EQ(seq.state(), RunState::kInterrupted);
  EXPECT_TRUE(seq.finished());
  EXPECT_EQ(obs.transitions.back().reason, "daemon stopped: SIGTERM");
}

TEST(Sequencer, MissingProbeReadingsNeverOpenTheGate) {
  RecordingObserver obs;
  Sequencer seq(make_plan({soak(23, 10)}), {23.0}, obs);
  seq.start(0.0, 23.0);
  for (int t = 1; t < 3600; ++t) seq.tick(t, Readings{23.0, std::nullopt, std::nullopt});
  EXPECT_EQ(seq.state(), RunState::kSettling);
}

// The paper's whole Table I campaign (32 soaks, ~80 h of station time) in
// virtual time, well under a second of wall time.
TEST(Sequencer, PaperTable1CampaignInVirtualTime) {
  auto plan =
      load_schedule(std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml",
                    {-20.0, 60.0, 2.0});
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  RecordingObserver obs;
  Sequencer seq(std::move(*plan), {23.0}, obs);
  FakePlant plant;
  const auto wall0 = std::chrono::steady_clock::now();
  seq.start(0.0, 23.0);
  const double t_end = run(seq, plant, 30 * 24 * 3600.0);
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  EXPECT_EQ(seq.state(), RunState::kCompleted);
  ASSERT_EQ(obs.finished.size(), 32u);
  double acquired_s = 0;
  for (const auto& f : obs.finished) {
    EXPECT_TRUE(f.completed);
    acquired_s += *f.times.acquire_end_s - *f.times.acquire_start_s;
  }
  EXPECT_DOUBLE_EQ(acquired_s, 4 * 60.0 * (103 + 143 + 136 + 68 + 141 + 153 + 135 + 133));
  EXPECT_GT(t_end, acquired_s);
  EXPECT_LT(wall_s, 1.0) << "station time " << t_end << " s";
}

}  // namespace
}  // namespace gyrotherm::schedules
