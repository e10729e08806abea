// The sequencer on rate points (StepKind::kRate) in station time, with table
// readings fed by a fake table that follows the sequencer's demand within an
// acceleration: the spin-up gate, the dwell of exactly dwell_s of unheld
// time, holds that discard a partial dwell, the spin-up timeout, restarts,
// and the table demand along a plan.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gyrotherm/schedules/sequencer.h"

namespace gyrotherm::schedules {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

struct Observer : SequencerObserver {
  struct Transition {
    RunState to;
    double t_s;
    std::string reason;
  };
  struct Finished {
    std::size_t index;
    StepTimes times;
    bool completed;
  };
  void on_state(RunState, RunState to, double t_s, const std::string& reason) override {
    transitions.push_back({to, t_s, reason});
  }
  void on_step_started(std::size_t index, const PlanStep& step, double t_s) override {
    started.push_back(index);
    started_demands.push_back(step.table);
    started_at_s.push_back(t_s);
  }
  void on_step_changed(std::size_t, const PlanStep&, const StepTimes& times) override {
    for (const auto& w : times.windows) stored_window_lengths_s.push_back(w.to_s - w.from_s);
  }
  void on_step_finished(std::size_t index, const PlanStep&, const StepTimes& times,
                        bool completed) override {
    finished.push_back({index, times, completed});
  }
  void on_interlock(InterlockKind, bool, double, const std::string&) override {}

  std::vector<RunState> states() const {
    std::vector<RunState> out;
    for (const auto& t : transitions) out.push_back(t.to);
    return out;
  }
  std::vector<Transition> transitions;
  std::vector<std::size_t> started;
  std::vector<TableDemand> started_demands;
  std::vector<double> started_at_s;
  std::vector<double> stored_window_lengths_s;  // every window ever reported
  std::vector<Finished> finished;
};

// A table that follows the demanded rate at a constant acceleration (a
// static or absent demand: towards 0), integrating its position.
struct FakeTable {
  double rate_dps = 0;
  double position_deg = 0;
  double accel_dps2 = 5;
  bool stuck = false;  // the drive gives no more than stuck_at_dps
  double stuck_at_dps = 0;
  void step(double dt_s, const TableDemand& demand) {
    double target = demand.mode == TableDemandMode::kRate ? demand.rate_dps : 0.0;
    if (stuck) target = std::clamp(target, -stuck_at_dps, stuck_at_dps);
    const double dv = std::clamp(target - rate_dps, -accel_dps2 * dt_s, accel_dps2 * dt_s);
    position_deg = std::fmod(position_deg + (rate_dps + dv / 2) * dt_s, 360.0);
    rate_dps += dv;
  }
};

// Chamber and shell at `c`, the gyro heard, the table as given.
Readings at(double c, const FakeTable& table) {
  Readings r{c, c + 0.05, c - 0.05};
  r.table_present = true;
  r.table_rate_dps = table.rate_dps;
  r.table_position_deg = table.position_deg;
  return r;
}

PlanStep rate_point(double rate_dps, int turns, double setpoint_c = 30.0) {
  PlanStep s;
  s.kind = StepKind::kRate;
  s.setpoint_c = setpoint_c;
  s.table.mode = TableDemandMode::kRate;
  s.table.rate_dps = rate_dps;
  s.turns = turns;
  s.dwell_s = turns * 360.0 / std::abs(rate_dps);
  s.sf_sequence = 1;
  s.sf_repetition = 1;
  s.label = fmt::format("SF {:+g} °/s", rate_dps);
  return s;
}

Plan make_rate_plan(std::vector<PlanStep> steps) {
  Plan p;
  p.name = "rate";
  p.steps = std::move(steps);
  return p;
}

// A run on the fake table, ticked every dt_s of station time.
struct Rig {
  Observer obs;
  Sequencer seq;
  FakeTable table;
  double t_s = 0;
  double dt_s = 1.0;
  explicit Rig(Plan plan, SequencerOptions options = {}) : seq(std::move(plan), options, obs) {}
  void start() { seq.start(t_s, 30.0); }
  // Ticks until `until_s` or the run's end; `edit` changes the readings.
  template <typename Edit>
  void run_until(double until_s, Edit edit) {
    while (t_s + dt_s <= until_s + 1e-9 && !seq.finished()) {
      t_s += dt_s;
      table.step(dt_s, seq.table_demand());
      Readings r = at(seq.setpoint_c(), table);
      edit(r);
      seq.tick(t_s, r);
    }
  }
  void run_until(double until_s) {
    run_until(until_s, [](Readings&) {});
  }
};

TEST(RateSequencer, SpinsUpThenDwellsExactlyItsWholeTurns) {
  for (double dt_s : {1.0, 0.7, 0.25}) {
    SCOPED_TRACE(fmt::format("ticks every {} s", dt_s));
    Rig rig(make_rate_plan({rate_point(10, 1)}));  // 1 turn at 10 °/s: 36 s
    rig.dt_s = dt_s;
    rig.start();
    EXPECT_EQ(rig.seq.state(), RunState::kSettling);
    EXPECT_THAT(rig.obs.transitions.back().reason, HasSubstr("spinning up to +10 °/s"));
    EXPECT_DOUBLE_EQ(rig.seq.setpoint_c(), 30.0) << "the set point is held";
    rig.run_until(1000);
    ASSERT_EQ(rig.seq.state(), RunState::kCompleted);
    EXPECT_THAT(rig.obs.states(),
                ElementsAre(RunState::kSettling, RunState::kAcquiring, RunState::kCompleted));
    ASSERT_EQ(rig.obs.finished.size(), 1u);
    const StepTimes& t = rig.obs.finished[0].times;
    EXPECT_TRUE(rig.obs.finished[0].completed);
    ASSERT_EQ(t.windows.size(), 1u);
    EXPECT_DOUBLE_EQ(t.windows[0].to_s - t.windows[0].from_s, 36.0);
    // The table reaches 10 °/s at 2 s (5 °/s²); the window opens the first
    // tick after it has been there for at_rate_hold_s (1 s).
    EXPECT_GE(t.windows[0].from_s, 3.0 - 1e-9);
    EXPECT_LT(t.windows[0].from_s, 3.0 + dt_s + 1e-9);
    EXPECT_DOUBLE_EQ(*t.settled_s, t.windows[0].from_s);
  }
}

TEST(RateSequencer, GateNeedsTheRateWithinToleranceForTheHoldTime) {
  SequencerOptions options;
  options.at_rate_tolerance_dps = 0.05;
  options.at_rate_hold_s = 5;
  Rig rig(make_rate_plan({rate_point(-20, 2)}), options);
  rig.start();
  // The table sits 0.06 °/s off the demand: never at rate.
  rig.run_until(30, [](Readings& r) { *r.table_rate_dps += 0.06; });
  EXPECT_EQ(rig.seq.state(), RunState::kSettling);
  // Within tolerance, but a missing reading at 33 s restarts the hold.
  rig.run_until(32, [](Readings& r) { *r.table_rate_dps += 0.04; });
  rig.run_until(33, [](Readings& r) { r.table_rate_dps.reset(); });
  rig.run_until(37.5);
  EXPECT_EQ(rig.seq.state(), RunState::kSettling) << "only 3 s at rate since 34 s";
  rig.run_until(39);
  EXPECT_EQ(rig.seq.state(), RunState::kAcquiring);
  EXPECT_DOUBLE_EQ(*rig.seq.step_times().acquire_start_s, 39.0);
  EXPECT_THAT(rig.obs.transitions.back().reason, HasSubstr("acquiring 2 turns over 36 s"));
}

TEST(RateSequencer, PauseMidDwellDiscardsThePartialWindowAndDwellsInFullAgain) {
  Rig rig(make_rate_plan({rate_point(10, 2)}));  // 72 s
  rig.start();
  rig.run_until(40);
  ASSERT_EQ(rig.seq.state(), RunState::kAcquiring);
  const double first_open_s = *rig.seq.step_times().acquire_start_s;
  ASSERT_TRUE(rig.seq.pause(40.5, "door").ok());
  EXPECT_EQ(rig.seq.state(), RunState::kPaused);
  EXPECT_THAT(rig.obs.transitions.back().reason, HasSubstr("partial dwell is discarded"));
  EXPECT_TRUE(rig.seq.step_times().windows.empty()) << "the partial window is not stored";
  EXPECT_FALSE(rig.seq.step_times().acquire_start_s.has_value());
  rig.run_until(100);
  ASSERT_TRUE(rig.seq.resume(100, "closed").ok());
  EXPECT_THAT(rig.obs.transitions.back().reason, HasSubstr("the dwell starts over"));
  rig.run_until(101);
  EXPECT_EQ(rig.seq.state(), RunState::kSettling) << "spins up (gates) again";
  rig.run_until(1000);
  ASSERT_EQ(rig.seq.state(), RunState::kCompleted);
  const StepTimes& t = rig.obs.finished.at(0).times;
  ASSERT_EQ(t.windows.size(), 1u);
  EXPECT_GE(t.windows[0].from_s, 101.0);
  EXPECT_DOUBLE_EQ(t.windows[0].to_s - t.windows[0].from_s, 72.0);
  EXPECT_LT(first_open_s, 40.0);
  // No window other than the whole one was ever reported.
  for (double len_s : rig.obs.stored_window_lengths_s) EXPECT_DOUBLE_EQ(len_s, 72.0);
  EXPECT_GE(t.held_s, 59.0);
}

TEST(RateSequencer, InterlockMidDwellDiscardsThePartialWindowAndDwellsInFullAgain) {
  Rig rig(make_rate_plan({rate_point(10, 2)}));
  rig.start();
  rig.run_until(40);
  ASSERT_EQ(rig.seq.state(), RunState::kAcquiring);
  // The table controller goes silent for a while (no reading, then the
  // timeout): the interlock trips, the dwell is lost.
  double silent_s = 0;
  rig.run_until(55, [&](Readings& r) {
    r.table_rate_dps.reset();
    r.table_silent_s = (silent_s += 1.0);
  });
  EXPECT_EQ(rig.seq.state(), RunState::kSuspended);
  EXPECT_TRUE(rig.seq.step_times().windows.empty());
  rig.run_until(1000);
  ASSERT_EQ(rig.seq.state(), RunState::kCompleted);
  const StepTimes& t = rig.obs.finished.at(0).times;
  ASSERT_EQ(t.windows.size(), 1u);
  EXPECT_GE(t.windows[0].from_s, 56.0);
  EXPECT_DOUBLE_EQ(t.windows[0].to_s - t.windows[0].from_s, 72.0);
  for (double len_s : rig.obs.stored_window_lengths_s) EXPECT_DOUBLE_EQ(len_s, 72.0);
}

TEST(RateSequencer, AbortMidDwellStoresNoWindow) {
  Rig rig(make_rate_plan({rate_point(10, 2)}));
  rig.start();
  rig.run_until(40);
  rig.seq.abort(40, "operator");
  ASSERT_EQ(rig.obs.finished.size(), 1u);
  EXPECT_FALSE(rig.obs.finished[0].completed);
  EXPECT_TRUE(rig.obs.finished[0].times.windows.empty());
  EXPECT_EQ(rig.seq.table_demand().mode, TableDemandMode::kNone) << "the table is stopped";
}

TEST(RateSequencer, NotAtRateWithinTheSpinUpTimeoutFailsTheRun) {
  SequencerOptions options;
  options.spin_up_timeout_s = 120;
  Rig rig(make_rate_plan({rate_point(10, 1)}), options);
  rig.table.stuck = true;
  rig.table.stuck_at_dps = 3;
  rig.start();
  // A pause does not count against the spin-up.
  rig.run_until(50);
  ASSERT_TRUE(rig.seq.pause(50, "x").ok());
  rig.run_until(150);
  ASSERT_TRUE(rig.seq.resume(150, "x").ok());
  rig.run_until(200);
  EXPECT_EQ(rig.seq.state(), RunState::kSettling) << "a pause restarts the spin-up";
  rig.run_until(1000);
  ASSERT_EQ(rig.seq.state(), RunState::kAborting);
  const auto& last = rig.obs.transitions.back();
  // More than 120 s of unheld spin-up after the resume; the interval up to
  // the first tick after it (150 … 151 s) counts as held.
  EXPECT_NEAR(last.t_s, 151 + 121, 1e-9);
  EXPECT_THAT(last.reason, HasSubstr("did not reach +10 °/s"));
  EXPECT_THAT(last.reason, HasSubstr("within 120 s; last measured +3.0000 °/s"));
  rig.seq.safe_state_reached(last.t_s);
  EXPECT_EQ(rig.seq.state(), RunState::kFailed);
  EXPECT_FALSE(rig.obs.finished.at(0).completed);
}

TEST(RateSequencer, TableDemandAlongAPlan) {
  PlanStep soak;
  soak.kind = StepKind::kSoak;
  soak.setpoint_c = 30;
  soak.acquire_s = 20;
  soak.stability_window_s = 10;
  soak.label = "soak";
  soak.table.mode = TableDemandMode::kStatic;
  soak.table.position_deg = 90.0;
  PlanStep hold;
  hold.kind = StepKind::kHold;
  hold.setpoint_c = 30;
  hold.hold_s = 10;
  hold.label = "hold";
  Rig rig(make_rate_plan({soak, rate_point(50, 5), rate_point(-50, 5), hold}));
  EXPECT_EQ(rig.seq.table_demand().mode, TableDemandMode::kNone) << "before the start";
  std::vector<std::pair<TableDemandMode, double>> seen;
  auto record = [&] {
    const TableDemand& d = rig.seq.table_demand();
    const std::pair<TableDemandMode, double> v{d.mode, d.rate_dps};
    if (seen.empty() || seen.back() != v) seen.push_back(v);
  };
  rig.start();
  record();
  ASSERT_TRUE(rig.seq.table_demand().position_deg.has_value());
  EXPECT_DOUBLE_EQ(*rig.seq.table_demand().position_deg, 90.0);
  while (!rig.seq.finished() && rig.t_s < 2000) {
    rig.run_until(rig.t_s + 1);
    record();
  }
  ASSERT_EQ(rig.seq.state(), RunState::kCompleted);
  using M = TableDemandMode;
  EXPECT_THAT(seen, ElementsAre(std::pair{M::kStatic, 0.0}, std::pair{M::kRate, 50.0},
                                std::pair{M::kRate, -50.0}, std::pair{M::kNone, 0.0}));
  // The station commands the table when a step starts: on_step_started
  // carries each step's demand.
  EXPECT_THAT(rig.obs.started, ElementsAre(0u, 1u, 2u, 3u));
  EXPECT_EQ(rig.obs.started_demands[1].mode, M::kRate);
  EXPECT_DOUBLE_EQ(rig.obs.started_demands[2].rate_dps, -50.0);
  EXPECT_EQ(rig.obs.started_demands[3].mode, M::kNone);
  // -50 from +50 at 5 °/s²: 20 s of spin-up before the second dwell.
  const StepTimes& second = rig.obs.finished.at(2).times;
  EXPECT_GE(*second.acquire_start_s - second.start_s, 20.0 + 1.0 - 1e-9);
  EXPECT_DOUBLE_EQ(second.windows.at(0).to_s - second.windows.at(0).from_s, 36.0);
}

TEST(RateSequencer, RestoreRestartsARatePointInProgressWithItsFullDwell) {
  Rig rig(make_rate_plan({rate_point(10, 1), rate_point(-10, 2)}));
  rig.start();
  rig.run_until(60);  // the first point done (3 + 36 s), the second dwelling
  ASSERT_EQ(rig.seq.step_index(), 1u);
  ASSERT_EQ(rig.seq.state(), RunState::kAcquiring);
  auto snapshot = snapshot_from_json(nlohmann::json::parse(to_json(rig.seq.snapshot(60)).dump()));
  ASSERT_TRUE(snapshot.ok()) << snapshot.error().message;
  ASSERT_TRUE(snapshot->window_open_s.has_value());

  // The daemon comes back 30 s later; the table kept turning.
  Observer obs;
  Sequencer seq(make_rate_plan({rate_point(10, 1), rate_point(-10, 2)}), {}, obs);
  seq.restore(*snapshot, 90, 59.5, "daemon restarted");
  EXPECT_EQ(seq.state(), RunState::kSuspended);
  EXPECT_EQ(seq.step_index(), 1u) << "the completed point stays completed";
  EXPECT_TRUE(seq.step_times().windows.empty()) << "no partial dwell is credited";
  EXPECT_DOUBLE_EQ(seq.table_demand().rate_dps, -10.0);
  FakeTable table = rig.table;
  double t = 90;
  while (!seq.finished() && t < 1000) {
    t += 1;
    table.step(1, seq.table_demand());
    seq.tick(t, at(30, table));
  }
  ASSERT_EQ(seq.state(), RunState::kCompleted);
  EXPECT_TRUE(obs.started.empty()) << "no step started over from its beginning";
  ASSERT_EQ(obs.finished.size(), 1u);
  EXPECT_EQ(obs.finished[0].index, 1u);
  const StepTimes& times = obs.finished[0].times;
  ASSERT_EQ(times.windows.size(), 1u);
  // Held until the first tick with readings (91 s), then at rate for 1 s.
  EXPECT_DOUBLE_EQ(times.windows[0].from_s, 92.0);
  EXPECT_DOUBLE_EQ(times.windows[0].to_s - times.windows[0].from_s, 72.0);
}

// A soak turning the table (not a rate point) does not wait for the table
// when it starts, but after a hold (the station stops the table while the
// run is held) and after the controller took the table off its demand, its
// acquisition waits until the table has been at rate for at_rate_hold_s.
TEST(RateSequencer, ASpinningSoakWaitsForTheTableAtRateAfterAHoldOrAnInterruption) {
  PlanStep soak;
  soak.kind = StepKind::kSoak;
  soak.setpoint_c = 30.0;
  soak.stability_window_s = 60;
  soak.settle_timeout_s = 1800;
  soak.acquire_s = 300;
  soak.table.mode = TableDemandMode::kRate;
  soak.table.rate_dps = 10;
  soak.label = "soak 30 °C";
  Rig rig(make_rate_plan({soak}));
  rig.start();
  // The station's rule: the table is brought to rest while the run is held.
  auto run_until = [&](double until_s) {
    while (rig.t_s + 1 <= until_s + 1e-9 && !rig.seq.finished()) {
      rig.t_s += 1;
      const bool held = rig.seq.paused() || !rig.seq.tripped().empty();
      rig.table.step(1, held ? TableDemand{} : rig.seq.table_demand());
      rig.seq.tick(rig.t_s, at(30.0, rig.table));
    }
  };
  run_until(100);
  ASSERT_EQ(rig.seq.state(), RunState::kAcquiring);
  ASSERT_TRUE(rig.seq.pause(100.5, "door").ok());
  run_until(150);
  EXPECT_LT(std::abs(rig.table.rate_dps), 1e-9);
  ASSERT_TRUE(rig.seq.resume(150, "closed").ok());
  run_until(151);
  EXPECT_EQ(rig.seq.state(), RunState::kSettling);
  EXPECT_THAT(rig.obs.transitions.back().reason,
              HasSubstr("spinning the table up to +10 °/s again; acquisition waits"));
  ASSERT_TRUE(rig.seq.gate_progress(151).has_value());
  // 5 °/s²: at 10 °/s from 152 s; the window reopens 1 s (at_rate_hold_s) later.
  run_until(152);
  EXPECT_FALSE(rig.seq.step_times().windows.empty());
  EXPECT_EQ(rig.seq.state(), RunState::kSettling);
  run_until(153);
  EXPECT_EQ(rig.seq.state(), RunState::kAcquiring);

  run_until(170);
  rig.seq.table_interrupted(170.5, "the controller faulted the axis");
  rig.table.rate_dps = 0;  // the axis coasted to rest
  EXPECT_EQ(rig.seq.state(), RunState::kSettling);
  EXPECT_THAT(rig.obs.transitions.back().reason,
              HasSubstr("the controller faulted the axis; acquisition waits for the table at "
                        "+10 °/s again"));
  run_until(2000);
  ASSERT_EQ(rig.seq.state(), RunState::kCompleted);
  const StepTimes& t = rig.obs.finished.at(0).times;
  ASSERT_EQ(t.windows.size(), 3u);
  EXPECT_DOUBLE_EQ(t.windows[0].to_s, 100.5);
  EXPECT_DOUBLE_EQ(t.windows[1].from_s, 153.0);
  EXPECT_DOUBLE_EQ(t.windows[1].to_s, 170.5);
  EXPECT_DOUBLE_EQ(t.windows[2].from_s, 173.0);
  EXPECT_DOUBLE_EQ(t.acquired_s(), 300.0);
}

// The wait has the rate points' spin-up timeout.
TEST(RateSequencer, ASpinningSoakWhoseTableDoesNotComeBackFailsTheRun) {
  PlanStep hold;
  hold.kind = StepKind::kHold;
  hold.setpoint_c = 30.0;
  hold.hold_s = 600;
  hold.table.mode = TableDemandMode::kRate;
  hold.table.rate_dps = 10;
  hold.label = "hold 30 °C";
  SequencerOptions options;
  options.spin_up_timeout_s = 20;
  Rig rig(make_rate_plan({hold}), options);
  rig.start();
  rig.run_until(50);
  rig.seq.table_interrupted(50.5, "the table left rate +10 °/s");
  rig.run_until(100, [](Readings& r) { r.table_rate_dps = 0.0; });
  EXPECT_EQ(rig.seq.state(), RunState::kAborting);
  EXPECT_THAT(rig.obs.transitions.back().reason,
              HasSubstr("the table did not get back to +10 °/s"));
}

}  // namespace
}  // namespace gyrotherm::schedules
