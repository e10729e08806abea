#include "gyrotherm/schedules/sequencer.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <utility>
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
  void on_step_changed(std::size_t index, const PlanStep&, const StepTimes& times) override {
    changes.push_back({index, times, true});
  }
  void on_interlock(InterlockKind kind, bool tripped, double t_s,
                    const std::string& message) override {
    interlocks.push_back({kind, tripped, t_s, message});
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
  struct Interlock {
    InterlockKind kind;
    bool tripped;
    double t_s;
    std::string message;
  };
  std::vector<FinishedStep> changes;
  std::vector<Interlock> interlocks;
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
  Sequencer seq(make_plan({soak(20, 20), ramp(40, 1.0), soak(40, 20)}), {}, obs);
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

PlanStep adaptive_soak(double sp, double target_u95_dph, double min_min, double max_min) {
  PlanStep s = soak(sp, max_min);
  s.adaptive = analysis::AcquisitionTarget{
      .target_u95_dph = target_u95_dph, .min_s = min_min * 60.0, .max_s = max_min * 60.0};
  return s;
}

TEST(Sequencer, AnAdaptiveSoakEndsOnTheStationsVerdictAfterItsMinimum) {
  // The station says "done" from the first acquiring tick on: the soak still
  // acquires its minimum (10 min), then ends at once with the verdict stored.
  RecordingObserver obs;
  Sequencer seq(make_plan({adaptive_soak(30, 0.05, 10, 60), soak(30, 5)}), {}, obs);
  FakePlant plant;
  seq.start(0.0, 23.0);
  double t = 0;
  while (obs.finished.empty() && t < 6 * 3600) {
    t += 1.0;
    plant.step(1.0, seq.setpoint_c());
    Readings r = plant.readings();
    if (seq.state() == RunState::kAcquiring) r.acquisition_done = "target reached: U95 0.04 °/h";
    seq.tick(t, r);
  }
  ASSERT_EQ(obs.finished.size(), 1u);
  const StepTimes& a = obs.finished[0].times;
  EXPECT_TRUE(obs.finished[0].completed);
  EXPECT_NEAR(a.acquired_s(), 600.0, 1.0) << "the minimum is acquired first";
  EXPECT_EQ(a.acquire_stop, "target reached: U95 0.04 °/h");
  EXPECT_THAT(obs.transitions.at(1).reason, HasSubstr("acquiring until the bias is known to ± "
                                                      "0.05 °/h (U95; 10 to 60 min)"));

  // A fixed soak ignores a verdict: it acquires its 5 min.
  run(seq, plant, t + 6 * 3600.0, t);
  ASSERT_EQ(obs.finished.size(), 2u);
  EXPECT_DOUBLE_EQ(obs.finished[1].times.acquired_s(), 300.0);
  EXPECT_EQ(obs.finished[1].times.acquire_stop, "");
}

TEST(Sequencer, AnAdaptiveSoakWithoutAVerdictStopsAtItsCapAndSaysSo) {
  RecordingObserver obs;
  Sequencer seq(make_plan({adaptive_soak(30, 0.05, 5, 20)}), {}, obs);
  FakePlant plant;
  seq.start(0.0, 23.0);
  run(seq, plant, 8 * 3600.0);
  ASSERT_TRUE(seq.finished());
  ASSERT_EQ(obs.finished.size(), 1u);
  const StepTimes& a = obs.finished[0].times;
  EXPECT_DOUBLE_EQ(a.acquired_s(), 1200.0);
  EXPECT_EQ(a.acquire_stop, "cap: max_min 20 min acquired before the target 0.05 °/h was reached");
  // The reason survives a checkpoint.
  SequencerSnapshot snap;
  snap.times = a;
  auto back = snapshot_from_json(to_json(snap));
  ASSERT_TRUE(back) << back.error().message;
  EXPECT_EQ(back->times.acquire_stop, a.acquire_stop);
}

TEST(Sequencer, AcquisitionStartsOnlyWhenShellIsStable) {
  RecordingObserver obs;
  Sequencer seq(make_plan({soak(40, 10)}), {}, obs);
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

TEST(Sequencer, SettleTimeoutSuspendsThenAbortsAfterItsGrace) {
  RecordingObserver obs;
  PlanStep s = soak(40, 10);
  s.settle_timeout_s = 1800;  // far too short for a 900 s case lag
  SequencerOptions opt;
  opt.interlocks.grace_s[static_cast<int>(InterlockKind::kSettleTimeout)] = 600;
  Sequencer seq(make_plan({s, soak(20, 10)}), opt, obs);
  FakePlant plant;
  seq.start(0.0, 23.0);
  run(seq, plant, 4 * 3600.0);
  EXPECT_EQ(seq.state(), RunState::kAborting) << "aborting until the safe set point is written";
  EXPECT_DOUBLE_EQ(seq.setpoint_c(), 23.0);
  seq.safe_state_reached(2500.0);
  EXPECT_EQ(seq.state(), RunState::kFailed);
  EXPECT_THAT(obs.states(), ElementsAre(RunState::kSettling, RunState::kSuspended,
                                        RunState::kAborting, RunState::kFailed));
  // Suspended when the settle timeout passed, aborted 10 min later.
  EXPECT_NEAR(obs.transitions[1].t_s, 1801.0, 1.0);
  EXPECT_THAT(obs.transitions[1].reason, HasSubstr("not stable at 40 ± 0.5 °C within 30 min"));
  EXPECT_NEAR(obs.transitions[2].t_s, 2401.0, 1.0);
  EXPECT_THAT(obs.transitions[2].reason, HasSubstr("settle_timeout still tripped after 10 min"));
  ASSERT_EQ(obs.finished.size(), 1u);
  EXPECT_FALSE(obs.finished[0].completed);
  EXPECT_THAT(obs.started, ElementsAre(0u)) << "the second step never starts";
}

TEST(Sequencer, SettleTimeoutClearsWhenTheGateHoldsWithinTheGrace) {
  RecordingObserver obs;
  PlanStep s = soak(40, 10);
  s.settle_timeout_s = 1800;
  Sequencer seq(make_plan({s}), {}, obs);  // default grace 60 min
  FakePlant plant;
  seq.start(0.0, 23.0);
  run(seq, plant, 12 * 3600.0);
  EXPECT_EQ(seq.state(), RunState::kCompleted);
  EXPECT_THAT(obs.states(), ElementsAre(RunState::kSettling, RunState::kSuspended,
                                        RunState::kAcquiring, RunState::kCompleted));
  ASSERT_EQ(obs.interlocks.size(), 2u);
  EXPECT_TRUE(obs.interlocks[0].tripped);
  EXPECT_FALSE(obs.interlocks[1].tripped);
}

TEST(Sequencer, RampMovesTheSetpointLinearlyFromWhereItWas) {
  RecordingObserver obs;
  Sequencer seq(make_plan({ramp(30, 0.5)}), {}, obs);
  seq.start(0.0, 20.0);
  seq.tick(600.0, {});
  EXPECT_DOUBLE_EQ(seq.setpoint_c(), 25.0);  // 20 + 0.5 °C/min x 10 min
  seq.tick(1199.0, {});
  EXPECT_NEAR(seq.setpoint_c(), 29.99167, 1e-4);
  seq.tick(1200.0, {});
  EXPECT_EQ(seq.state(), RunState::kCompleted);
}

TEST(Sequencer, RampWindowEndsWhereTheSetPointReachedItsTargetNotAtTheLateTick) {
  // 3 °C at 2 °C/min is 90 s; ticks every 7 s and one 15 s late tick (a busy
  // control thread at a high time scale) must not lengthen the window.
  for (const std::vector<double>& ticks :
       {std::vector<double>{7, 14, 21, 28, 35, 42, 49, 56, 63, 70, 77, 84, 91},
        std::vector<double>{30, 60, 80, 105}}) {
    RecordingObserver obs;
    Sequencer seq(make_plan({ramp(26, 2.0), ramp(23, 2.0)}), {}, obs);
    seq.start(0.0, 23.0);
    for (double t : ticks) seq.tick(t, {});
    ASSERT_EQ(obs.finished.size(), 1u);
    const StepTimes& times = obs.finished[0].times;
    ASSERT_TRUE(times.acquire_start_s && times.acquire_end_s);
    EXPECT_DOUBLE_EQ(*times.acquire_start_s, 0.0);
    EXPECT_NEAR(*times.acquire_end_s, 90.0, 1e-9);
    EXPECT_NEAR(times.acquired_s(), 90.0, 1e-9);
    EXPECT_DOUBLE_EQ(*times.end_s, ticks.back()) << "the step ends when the sequencer acts";
    EXPECT_DOUBLE_EQ(seq.setpoint_c(), 26.0);
  }
}

TEST(Sequencer, DownwardRamp) {
  RecordingObserver obs;
  Sequencer seq(make_plan({ramp(-20, 2.0)}), {}, obs);
  seq.start(0.0, 20.0);
  seq.tick(300.0, {});
  EXPECT_DOUBLE_EQ(seq.setpoint_c(), 10.0);
}

TEST(Sequencer, AbortClosesTheStepAndGoesSafe) {
  RecordingObserver obs;
  Sequencer seq(make_plan({soak(50, 60)}), {}, obs);
  seq.start(0.0, 23.0);
  seq.tick(10.0, {});
  seq.abort(11.0, "operator abort");
  EXPECT_EQ(seq.state(), RunState::kAborting);
  seq.tick(12.0, {});
  EXPECT_EQ(seq.state(), RunState::kAborting) << "ticks do not end an abort";
  seq.safe_state_reached(13.0);
  EXPECT_EQ(seq.state(), RunState::kFailed);
  EXPECT_DOUBLE_EQ(seq.setpoint_c(), 23.0);
  EXPECT_THAT(obs.states(),
              ElementsAre(RunState::kSettling, RunState::kAborting, RunState::kFailed));
  ASSERT_EQ(obs.finished.size(), 1u);
  EXPECT_FALSE(obs.finished[0].completed);
}

TEST(Sequencer, InterruptMarksTheRun) {
  RecordingObserver obs;
  Sequencer seq(make_plan({soak(50, 60)}), {}, obs);
  seq.start(0.0, 23.0);
  seq.interrupt(5.0, "daemon stopped: SIGTERM");
  EXPECT_EQ(seq.state(), RunState::kInterrupted);
  EXPECT_TRUE(seq.finished());
  EXPECT_EQ(obs.transitions.back().reason, "daemon stopped: SIGTERM");
  EXPECT_TRUE(obs.finished.empty()) << "the step stays open for a resume";
}

TEST(Sequencer, MissingProbeReadingsNeverOpenTheGate) {
  RecordingObserver obs;
  Sequencer seq(make_plan({soak(23, 10)}), {}, obs);
  seq.start(0.0, 23.0);
  for (int t = 1; t < 3600; ++t) seq.tick(t, Readings{23.0, std::nullopt, std::nullopt});
  EXPECT_EQ(seq.state(), RunState::kSettling);
}

// The paper's whole Table I campaign (32 soaks, ~80 h of station time) in
// virtual time. How fast it runs is measured by bench/sequencer_bench.cpp.
TEST(Sequencer, PaperTable1CampaignInVirtualTime) {
  auto plan =
      load_schedule(std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml",
                    {-20.0, 60.0, 2.0});
  ASSERT_TRUE(plan.ok()) << plan.error().message;
  RecordingObserver obs;
  Sequencer seq(std::move(*plan), {}, obs);
  FakePlant plant;
  seq.start(0.0, 23.0);
  const double t_end = run(seq, plant, 30 * 24 * 3600.0);
  EXPECT_EQ(seq.state(), RunState::kCompleted);
  ASSERT_EQ(obs.finished.size(), 32u);
  double acquired_s = 0;
  for (const auto& f : obs.finished) {
    EXPECT_TRUE(f.completed);
    acquired_s += *f.times.acquire_end_s - *f.times.acquire_start_s;
  }
  EXPECT_DOUBLE_EQ(acquired_s, 4 * 60.0 * (103 + 143 + 136 + 68 + 141 + 153 + 135 + 133));
  EXPECT_GT(t_end, acquired_s);
}

// ------------------------------------------------------------- holds and interlocks

// Readings of a chamber sitting exactly at `c`, its rate table at rest.
Readings at(double c) {
  Readings r{c, c + 0.05, c - 0.05};
  r.table_present = true;
  r.table_rate_dps = 0.0;
  r.table_position_deg = 0.0;
  return r;
}

PlanStep quick_soak(double sp, double acquire_s) {
  PlanStep s = soak(sp, 0);
  s.acquire_s = acquire_s;
  s.stability_window_s = 60;
  return s;
}

// Ticks once a second from t0 to t1 (inclusive) with constant readings.
void tick_range(Sequencer& seq, double t0, double t1, const Readings& r) {
  for (double t = t0; t <= t1 && !seq.finished(); t += 1.0) seq.tick(t, r);
}

// A sequencer whose soak at 30 °C is acquiring from t = 60 s.
struct AcquiringSoak {
  RecordingObserver obs;
  Sequencer seq;
  explicit AcquiringSoak(SequencerOptions opt = {}, double acquire_s = 600)
      : seq(make_plan({quick_soak(30, acquire_s)}), opt, obs) {
    seq.start(0.0, 30.0);
    tick_range(seq, 1, 60, at(30));
  }
};

TEST(Sequencer, PauseStopsTheAcquisitionClockAndExcludesPausedTime) {
  AcquiringSoak f;
  ASSERT_EQ(f.seq.state(), RunState::kAcquiring);
  const double start = *f.seq.step_times().acquire_start_s;
  tick_range(f.seq, 61, 200, at(30));
  ASSERT_TRUE(f.seq.pause(200.5, "operator").ok());
  EXPECT_EQ(f.seq.state(), RunState::kPaused);
  EXPECT_FALSE(f.seq.pause(201, "again").ok()) << "already paused";
  tick_range(f.seq, 201, 500, at(30));
  EXPECT_EQ(f.seq.state(), RunState::kPaused) << "a pause never ends by itself";
  EXPECT_DOUBLE_EQ(f.seq.setpoint_c(), 30.0);
  ASSERT_TRUE(f.seq.resume(500.5, "operator").ok());
  EXPECT_FALSE(f.seq.resume(500.6, "again").ok());
  tick_range(f.seq, 501, 2000, at(30));
  ASSERT_EQ(f.seq.state(), RunState::kCompleted);
  ASSERT_EQ(f.obs.finished.size(), 1u);
  const StepTimes& t = f.obs.finished[0].times;
  ASSERT_EQ(t.windows.size(), 2u);
  EXPECT_DOUBLE_EQ(t.windows[0].from_s, start);
  EXPECT_DOUBLE_EQ(t.windows[0].to_s, 200.5);
  EXPECT_DOUBLE_EQ(t.windows[1].from_s, 501.0);
  EXPECT_DOUBLE_EQ(t.acquired_s(), 600.0)
      << "the acquisition time is the schedule's, pause excluded";
  EXPECT_DOUBLE_EQ(t.windows[1].to_s, 501.0 + 600.0 - (200.5 - start));
  EXPECT_NEAR(t.held_s, 300.0, 1.0);
  EXPECT_THAT(f.obs.states(),
              ElementsAre(RunState::kSettling, RunState::kAcquiring, RunState::kPaused,
                          RunState::kAcquiring, RunState::kCompleted));
}

TEST(Sequencer, PauseDuringSettlingStopsTheSettleTimeout) {
  RecordingObserver obs;
  PlanStep s = quick_soak(30, 60);
  s.settle_timeout_s = 100;
  Sequencer seq(make_plan({s}), {}, obs);
  seq.start(0, 23);
  tick_range(seq, 1, 50, at(23));  // far from 30 °C: never stable
  ASSERT_TRUE(seq.pause(50.5, "lunch").ok());
  tick_range(seq, 51, 1000, at(23));
  EXPECT_EQ(seq.state(), RunState::kPaused) << "paused time does not count toward the timeout";
  ASSERT_TRUE(seq.resume(1000.5, "back").ok());
  tick_range(seq, 1001, 1040, at(23));
  EXPECT_EQ(seq.state(), RunState::kSettling);
  tick_range(seq, 1041, 1060, at(23));
  EXPECT_EQ(seq.state(), RunState::kSuspended) << "100 s of unpaused settling passed";
}

TEST(Sequencer, PausedRampHoldsItsSetPoint) {
  RecordingObserver obs;
  Sequencer seq(make_plan({ramp(30, 1.0)}), {}, obs);
  seq.start(0, 20);
  tick_range(seq, 1, 60, {});
  EXPECT_NEAR(seq.setpoint_c(), 21.0, 1e-9);
  ASSERT_TRUE(seq.pause(60, "x").ok());
  tick_range(seq, 61, 600, {});
  EXPECT_NEAR(seq.setpoint_c(), 21.0, 1e-9);
  ASSERT_TRUE(seq.resume(600, "x").ok());
  tick_range(seq, 601, 660, {});
  // Holds are accounted per tick: the first tick after the resume ends the hold.
  EXPECT_NEAR(seq.setpoint_c(), 21.0 + 59.0 / 60.0, 1e-9);
  tick_range(seq, 661, 2000, {});
  ASSERT_EQ(obs.finished.size(), 1u);
  EXPECT_NEAR(obs.finished[0].times.acquired_s(), 600.0, 1.0) << "10 °C at 1 °C/min";
  EXPECT_EQ(obs.finished[0].times.windows.size(), 2u);
}

// One row per interlock: the readings that trip it during an acquiring soak
// at 30 °C, and what the technician reads.
struct InterlockCase {
  InterlockKind kind;
  Readings bad;
  const char* message;
};

class InterlockTrips : public ::testing::TestWithParam<InterlockCase> {};

TEST_P(InterlockTrips, SuspendsThenResumesWhenCleared) {
  const InterlockCase& c = GetParam();
  AcquiringSoak f;
  ASSERT_EQ(f.seq.state(), RunState::kAcquiring);
  tick_range(f.seq, 61, 100, at(30));
  f.seq.tick(101, c.bad);
  EXPECT_EQ(f.seq.state(), RunState::kSuspended);
  ASSERT_EQ(f.seq.tripped().size(), 1u);
  EXPECT_EQ(f.seq.tripped()[0].kind, c.kind);
  ASSERT_FALSE(f.obs.interlocks.empty());
  EXPECT_TRUE(f.obs.interlocks.back().tripped);
  EXPECT_THAT(f.obs.interlocks.back().message, HasSubstr(c.message));
  EXPECT_THAT(f.obs.transitions.back().reason, HasSubstr(std::string(to_string(c.kind))));
  for (double t = 102; t <= 200; ++t) f.seq.tick(t, c.bad);
  EXPECT_EQ(f.seq.state(), RunState::kSuspended);
  EXPECT_DOUBLE_EQ(f.seq.setpoint_c(), 30.0) << "suspended holds the set point";
  tick_range(f.seq, 201, 2000, at(30));
  EXPECT_EQ(f.seq.state(), RunState::kCompleted);
  EXPECT_FALSE(f.obs.interlocks.back().tripped);
  const StepTimes& t = f.obs.finished.at(0).times;
  ASSERT_EQ(t.windows.size(), 2u) << "the suspension is cut out of the window";
  EXPECT_DOUBLE_EQ(t.windows[0].to_s, 101);
  EXPECT_DOUBLE_EQ(t.windows[1].from_s, 201);
  EXPECT_DOUBLE_EQ(t.acquired_s(), 600);
}

Readings with(Readings r, void (*edit)(Readings&)) {
  edit(r);
  return r;
}

INSTANTIATE_TEST_SUITE_P(
    EachKind, InterlockTrips,
    ::testing::Values(InterlockCase{InterlockKind::kProbeDisagreement, Readings{30.0, 31.5, 28.5},
                                    "probes disagree by 3.00 °C (limit 2 °C)"},
                      InterlockCase{InterlockKind::kChamberSilent,
                                    with(at(30), [](Readings& r) { r.chamber_silent_s = 11; }),
                                    "chamber controller silent for 11 s (timeout 10 s)"},
                      InterlockCase{InterlockKind::kProbesSilent,
                                    with(at(30), [](Readings& r) { r.probes_silent_s = 12; }),
                                    "probe module silent for 12 s"},
                      InterlockCase{InterlockKind::kGyroLost,
                                    with(at(30), [](Readings& r) { r.gyro_silent_s = 6; }),
                                    "gyro stream silent for 6 s (timeout 5 s)"},
                      InterlockCase{InterlockKind::kChamberAlarm,
                                    with(at(30), [](Readings& r) { r.chamber_alarm = true; }),
                                    "reports an alarm"},
                      InterlockCase{InterlockKind::kStorageFailing,
                                    with(at(30),
                                         [](Readings& r) {
                                           r.storage_failing_s = 12;
                                           r.storage_error =
                                               "database or disk "
                                               "is full";
                                           r.storage_pending = 240;
                                         }),
                                    "storage failing for 12 s (timeout 10 s): database or disk is "
                                    "full; acquisition suspended, 240 samples held in memory"},
                      InterlockCase{InterlockKind::kTableFault,
                                    with(at(30),
                                         [](Readings& r) {
                                           r.table_fault = true;
                                           r.table_fault_text = "axis 1 over-speed";
                                         }),
                                    "the rate table's interlock is in fault: axis 1 over-speed"},
                      InterlockCase{InterlockKind::kTableSilent,
                                    with(at(30),
                                         [](Readings& r) {
                                           r.table_rate_dps.reset();
                                           r.table_position_deg.reset();
                                           r.table_silent_s = 11;
                                         }),
                                    "rate table controller silent for 11 s (timeout 10 s)"}),
    [](const auto& info) { return std::string(to_string(info.param.kind)); });

TEST(Sequencer, OutOfLimitsAbortsAfterItsGraceAndASoakDisturbedStartsOver) {
  // Cleared in time: the air went out of tolerance, so the soak settles again.
  {
    AcquiringSoak f;
    tick_range(f.seq, 61, 100, at(30));
    tick_range(f.seq, 101, 120, Readings{63.0, 30.0, 30.0});
    EXPECT_EQ(f.seq.state(), RunState::kSuspended);
    EXPECT_THAT(f.obs.interlocks.at(0).message,
                HasSubstr("chamber air 63.00 °C outside the station limits -20 … 60 °C"));
    f.seq.tick(121, Readings{35.0, 30.5, 30.4});
    EXPECT_EQ(f.seq.state(), RunState::kSettling);
    EXPECT_THAT(f.obs.transitions.back().reason, HasSubstr("restarts its acquisition"));
    EXPECT_TRUE(f.seq.step_times().windows.empty());
    tick_range(f.seq, 122, 2000, at(30));
    ASSERT_EQ(f.seq.state(), RunState::kCompleted);
    EXPECT_GE(f.obs.finished.at(0).times.windows.at(0).from_s, 180.0);
  }
  // Not cleared: abort after the grace (300 s by default).
  {
    AcquiringSoak f;
    tick_range(f.seq, 61, 700, Readings{63.0, 30.0, 30.0});
    EXPECT_EQ(f.seq.state(), RunState::kAborting);
    EXPECT_NEAR(f.obs.transitions.back().t_s, 361, 1e-9);
    EXPECT_THAT(f.obs.transitions.back().reason,
                HasSubstr("out_of_limits still tripped after 5 min"));
    EXPECT_DOUBLE_EQ(f.seq.setpoint_c(), 23.0);
  }
}

TEST(Interlocks, ConditionsAndHysteresis) {
  InterlockOptions o;
  bool none[kInterlockKindCount] = {};
  bool all[kInterlockKindCount];
  std::fill(std::begin(all), std::end(all), true);
  EXPECT_TRUE(evaluate_interlocks(at(30), o, none).empty());
  EXPECT_TRUE(evaluate_interlocks(Readings{}, o, none).empty()) << "no reading, no verdict";
  // Limits: -20 … 60 °C with a 2 °C margin.
  EXPECT_TRUE(evaluate_interlocks(Readings{61.9, 30.0, 30.0}, o, none).empty());
  EXPECT_EQ(evaluate_interlocks(Readings{62.1, 30.0, 30.0}, o, none).size(), 1u);
  EXPECT_EQ(evaluate_interlocks(Readings{30.0, -22.5, -22.0}, o, none).size(), 1u);
  // Once tripped, 61.9 °C is not yet clear (0.2 °C hysteresis); 61.7 is.
  EXPECT_EQ(evaluate_interlocks(Readings{61.9, 30.0, 30.0}, o, all).size(), 1u);
  EXPECT_TRUE(evaluate_interlocks(Readings{61.7, 30.0, 30.0}, o, all).empty());
  // Probes: 2 °C limit.
  EXPECT_TRUE(evaluate_interlocks(Readings{30.0, 31.0, 29.1}, o, none).empty());
  EXPECT_EQ(evaluate_interlocks(Readings{30.0, 31.0, 28.9}, o, none).at(0).kind,
            InterlockKind::kProbeDisagreement);
  EXPECT_EQ(evaluate_interlocks(Readings{30.0, 31.0, 29.1}, o, all).size(), 1u);
  // NaN from a device is out of limits, never silently fine.
  EXPECT_EQ(evaluate_interlocks(Readings{std::nan(""), 30.0, 30.0}, o, none).size(), 1u);
}

// ------------------------------------------------------------- restore (crash resume)

TEST(Sequencer, SnapshotSurvivesJson) {
  AcquiringSoak f;
  tick_range(f.seq, 61, 120, at(30));
  ASSERT_TRUE(f.seq.pause(120.5, "x").ok());
  const SequencerSnapshot s = f.seq.snapshot(130);
  auto back = snapshot_from_json(nlohmann::json::parse(to_json(s).dump()));
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(to_json(*back), to_json(s));
  EXPECT_TRUE(back->paused);
  EXPECT_EQ(back->times.windows.size(), 1u);
  EXPECT_FALSE(snapshot_from_json(nlohmann::json{{"t_s", 1}}).ok());
}

TEST(Sequencer, RestoredSoakKeepsItsAcquisitionWhenStillInTolerance) {
  AcquiringSoak f;
  tick_range(f.seq, 61, 300, at(30));  // 240 s acquired
  const SequencerSnapshot s = f.seq.snapshot(300);
  RecordingObserver obs;
  Sequencer seq(make_plan({quick_soak(30, 600)}), {}, obs);
  seq.restore(s, 400, 300, "daemon restarted");
  EXPECT_EQ(seq.state(), RunState::kSuspended) << "held until the first readings";
  seq.tick(401, Readings{});
  EXPECT_EQ(seq.state(), RunState::kSuspended);
  tick_range(seq, 402, 2000, at(30));
  ASSERT_EQ(seq.state(), RunState::kCompleted);
  const StepTimes& t = obs.finished.at(0).times;
  ASSERT_EQ(t.windows.size(), 2u);
  EXPECT_DOUBLE_EQ(t.windows[0].to_s, 300) << "the window before the crash ends at the snapshot";
  EXPECT_DOUBLE_EQ(t.windows[1].from_s, 402);
  EXPECT_DOUBLE_EQ(t.acquired_s(), 600);
  EXPECT_THAT(obs.transitions.at(1).reason, HasSubstr("acquisition goes on (4.0 of 10 min done)"));
}

TEST(Sequencer, RestoredSoakStartsOverWhenTemperatureLeftTolerance) {
  AcquiringSoak f;
  tick_range(f.seq, 61, 300, at(30));
  RecordingObserver obs;
  Sequencer seq(make_plan({quick_soak(30, 600)}), {}, obs);
  seq.restore(f.seq.snapshot(300), 400, 300, "daemon restarted");
  seq.tick(401, at(31));
  EXPECT_EQ(seq.state(), RunState::kSettling);
  EXPECT_TRUE(seq.step_times().windows.empty());
  tick_range(seq, 402, 3000, at(30));
  ASSERT_EQ(seq.state(), RunState::kCompleted);
  const StepTimes& t = obs.finished.at(0).times;
  ASSERT_EQ(t.windows.size(), 1u);
  EXPECT_GE(t.windows[0].from_s, 460);
}

TEST(Sequencer, RestoredRampGoesOnFromItsSetPoint) {
  RecordingObserver obs0;
  Sequencer first(make_plan({ramp(30, 1.0)}), {}, obs0);
  first.start(0, 20);
  tick_range(first, 1, 120, at(21));
  first.interrupt(120.5, "SIGTERM");
  EXPECT_EQ(first.state(), RunState::kInterrupted);
  RecordingObserver obs;
  Sequencer seq(make_plan({ramp(30, 1.0)}), {}, obs);
  seq.restore(first.snapshot(120.5), 1000, 120.5, "restart");
  EXPECT_NEAR(seq.setpoint_c(), 22.0, 1e-9);
  seq.tick(1001, at(22));
  tick_range(seq, 1002, 1060, at(22));
  EXPECT_NEAR(seq.setpoint_c(), 22.0 + 59.0 / 60.0, 1e-9);
  tick_range(seq, 1061, 2000, at(22));
  ASSERT_EQ(seq.state(), RunState::kCompleted);
  EXPECT_EQ(obs.finished.at(0).times.windows.size(), 2u);
  EXPECT_NEAR(obs.finished.at(0).times.acquired_s(), 600, 1.5);
}

TEST(Sequencer, RestoredPausedRunStaysPaused) {
  AcquiringSoak f;
  ASSERT_TRUE(f.seq.pause(100, "x").ok());
  RecordingObserver obs;
  Sequencer seq(make_plan({quick_soak(30, 600)}), {}, obs);
  seq.restore(f.seq.snapshot(100), 200, 100, "restart");
  tick_range(seq, 201, 300, at(30));
  EXPECT_EQ(seq.state(), RunState::kPaused);
  ASSERT_TRUE(seq.resume(300.5, "x").ok());
  tick_range(seq, 301, 2000, at(30));
  EXPECT_EQ(seq.state(), RunState::kCompleted);
}

// A kill -9 loses the samples not yet committed, and the time down holds no
// samples either: the resumed soak is credited only the acquisition time up
// to the last committed gyro sample, and acquires until the covered time
// reaches its acquire time (issue 15, item 7).
TEST(Sequencer, RestoreCreditsAcquisitionOnlyUpToTheLastCommittedSample) {
  AcquiringSoak f;
  const double start_s = *f.seq.step_times().acquire_start_s;
  tick_range(f.seq, 61, start_s + 400, at(30));
  const SequencerSnapshot s = f.seq.snapshot(start_s + 400);
  ASSERT_TRUE(s.window_open_s.has_value());
  ASSERT_DOUBLE_EQ(s.times.acquired_s() + (s.t_s - *s.window_open_s), 400.0)
      << "the checkpoint says 400 s acquired";
  RecordingObserver obs;
  Sequencer seq(make_plan({quick_soak(30, 600)}), {}, obs);
  const double resume_s = start_s + 500;
  seq.restore(s, resume_s, /*data_until_s=*/start_s + 380, "daemon restarted");
  tick_range(seq, resume_s + 1, resume_s + 2000, at(30));
  ASSERT_EQ(seq.state(), RunState::kCompleted);
  const StepTimes& t = obs.finished.at(0).times;
  ASSERT_EQ(t.windows.size(), 2u);
  EXPECT_DOUBLE_EQ(t.windows[0].from_s, start_s);
  EXPECT_DOUBLE_EQ(t.windows[0].to_s, start_s + 380) << "cut at the last committed sample";
  EXPECT_DOUBLE_EQ(t.windows[1].from_s, resume_s + 1);
  EXPECT_DOUBLE_EQ(t.windows[1].to_s - t.windows[1].from_s, 220.0)
      << "the resumed acquisition goes on for 220 s more";
  EXPECT_DOUBLE_EQ(t.acquired_s(), 600.0);
  EXPECT_THAT(obs.transitions.at(1).reason, HasSubstr("acquisition goes on (6.3 of 10 min done)"));
}

// After a restart the acquisition waits for the gyro stream too: a window
// opened before the first sample would credit time without data.
TEST(Sequencer, RestoredSoakWaitsForTheGyroBeforeItAcquires) {
  AcquiringSoak f;
  tick_range(f.seq, 61, 300, at(30));
  RecordingObserver obs;
  Sequencer seq(make_plan({quick_soak(30, 600)}), {}, obs);
  seq.restore(f.seq.snapshot(300), 400, 300, "daemon restarted");
  const Readings no_gyro = with(at(30), [](Readings& r) { r.gyro_heard = false; });
  tick_range(seq, 401, 410, no_gyro);
  EXPECT_EQ(seq.state(), RunState::kSuspended) << "no gyro sample since the restart";
  EXPECT_EQ(seq.step_times().windows.size(), 1u);
  tick_range(seq, 411, 2000, at(30));
  ASSERT_EQ(seq.state(), RunState::kCompleted);
  const StepTimes& t = obs.finished.at(0).times;
  ASSERT_EQ(t.windows.size(), 2u);
  EXPECT_DOUBLE_EQ(t.windows[1].from_s, 411);
}

// Windows closed before the checkpoint are cut too, and without any
// committed sample nothing is credited.
TEST(Sequencer, RestoreCutsClosedWindowsAndCreditsNothingWithoutSamples) {
  {
    AcquiringSoak f;
    const double start_s = *f.seq.step_times().acquire_start_s;
    tick_range(f.seq, 61, start_s + 300, at(30));
    ASSERT_TRUE(f.seq.pause(start_s + 300.5, "x").ok());  // window closed at +300.5
    RecordingObserver obs;
    Sequencer seq(make_plan({quick_soak(30, 600)}), {}, obs);
    seq.restore(f.seq.snapshot(start_s + 350), start_s + 400, start_s + 290, "restart");
    ASSERT_EQ(seq.step_times().windows.size(), 1u);
    EXPECT_DOUBLE_EQ(seq.step_times().windows[0].to_s, start_s + 290);
    ASSERT_TRUE(seq.resume(start_s + 400.5, "x").ok());
    tick_range(seq, start_s + 401, start_s + 2000, at(30));
    ASSERT_EQ(seq.state(), RunState::kCompleted);
    EXPECT_DOUBLE_EQ(obs.finished.at(0).times.acquired_s(), 600.0);
    EXPECT_DOUBLE_EQ(obs.finished.at(0).times.windows.back().to_s, start_s + 401 + 310);
  }
  {
    AcquiringSoak f;
    tick_range(f.seq, 61, 300, at(30));
    RecordingObserver obs;
    Sequencer seq(make_plan({quick_soak(30, 600)}), {}, obs);
    seq.restore(f.seq.snapshot(300), 400, -std::numeric_limits<double>::infinity(), "restart");
    EXPECT_TRUE(seq.step_times().windows.empty()) << "no committed sample: no time credited";
    tick_range(seq, 401, 2000, at(30));
    ASSERT_EQ(seq.state(), RunState::kCompleted);
    const StepTimes& t = obs.finished.at(0).times;
    ASSERT_EQ(t.windows.size(), 1u);
    EXPECT_DOUBLE_EQ(t.windows[0].from_s, 401);
    EXPECT_DOUBLE_EQ(t.acquired_s(), 600.0);
  }
}

// A daemon restart must not start an interlock's grace over: the trip and its
// start time are in the checkpoint (issue 15, item 12). Chamber alarm grace
// 2 min, alarm at 161 s, kill 1.4 min later, restart at 260 s: the abort
// comes at 161 + 120 s, not 260 + 120 s.
TEST(Sequencer, RestoredInterlockKeepsItsGraceFromItsTripTime) {
  SequencerOptions opt;
  opt.interlocks.grace_s[static_cast<int>(InterlockKind::kChamberAlarm)] = 120;
  const Readings alarm = with(at(30), [](Readings& r) { r.chamber_alarm = true; });
  AcquiringSoak f(opt);
  tick_range(f.seq, 61, 160, at(30));
  tick_range(f.seq, 161, 245, alarm);
  ASSERT_EQ(f.seq.state(), RunState::kSuspended);
  auto back = snapshot_from_json(nlohmann::json::parse(to_json(f.seq.snapshot(245.5)).dump()));
  ASSERT_TRUE(back.ok()) << back.error().message;
  ASSERT_EQ(back->trips.size(), 1u);
  EXPECT_EQ(back->trips[0].kind, InterlockKind::kChamberAlarm);
  EXPECT_DOUBLE_EQ(back->trips[0].since_s, 161);

  RecordingObserver obs;
  Sequencer seq(make_plan({quick_soak(30, 600)}), opt, obs);
  seq.restore(*back, 260, 245, "daemon restarted");
  ASSERT_EQ(seq.tripped().size(), 1u);
  EXPECT_EQ(seq.tripped()[0].kind, InterlockKind::kChamberAlarm);
  EXPECT_EQ(seq.state(), RunState::kSuspended);
  // The first tick after a restart may come without a chamber reading: that
  // cannot tell the alarm is gone, so the trip (and its grace) stays.
  seq.tick(261, Readings{});
  ASSERT_EQ(seq.tripped().size(), 1u) << "no chamber reading, no verdict on the alarm";
  tick_range(seq, 262, 600, alarm);
  ASSERT_EQ(seq.state(), RunState::kAborting);
  EXPECT_DOUBLE_EQ(obs.transitions.back().t_s, 281) << "alarm start + grace, not restart + grace";
  EXPECT_THAT(obs.transitions.back().reason, HasSubstr("chamber_alarm still tripped after 2 min"));
  EXPECT_TRUE(obs.interlocks.empty()) << "the restored trip is not reported again";
}

// A restored trip whose condition is gone clears at the first tick that can
// tell, and the soak goes on.
TEST(Sequencer, RestoredInterlockClearsWhenItsConditionIsGone) {
  AcquiringSoak f;
  tick_range(f.seq, 61, 100, at(30));
  f.seq.tick(101, with(at(30), [](Readings& r) { r.chamber_alarm = true; }));
  RecordingObserver obs;
  Sequencer seq(make_plan({quick_soak(30, 600)}), {}, obs);
  seq.restore(f.seq.snapshot(101.5), 150, 101, "daemon restarted");
  tick_range(seq, 151, 2000, at(30));
  ASSERT_EQ(seq.state(), RunState::kCompleted);
  ASSERT_EQ(obs.interlocks.size(), 1u);
  EXPECT_FALSE(obs.interlocks[0].tripped);
  EXPECT_THAT(obs.interlocks[0].message, HasSubstr("chamber_alarm cleared after 50 s"));
  EXPECT_DOUBLE_EQ(obs.finished.at(0).times.acquired_s(), 600.0);
}

// A checkpoint written before trips were checkpointed has no "trips": none.
TEST(Sequencer, CheckpointWithoutTripsLoads) {
  AcquiringSoak f;
  tick_range(f.seq, 61, 100, at(30));
  nlohmann::json j = to_json(f.seq.snapshot(100));
  ASSERT_TRUE(j.contains("trips"));
  j.erase("trips");
  auto back = snapshot_from_json(j);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_TRUE(back->trips.empty());
  j["trips"] = nlohmann::json::array({{{"kind", "meteor"}, {"since_s", 1}, {"message", "x"}}});
  auto bad = snapshot_from_json(j);
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.error().message, HasSubstr("unknown interlock 'meteor'"));
}

// Tripped interlocks are not cleared by a tick that lacks the readings their
// condition depends on (a silent device, a daemon that just restarted): the
// grace of a persistent fault runs on.
TEST(Sequencer, MissingReadingsDoNotClearATrippedInterlock) {
  struct Case {
    InterlockKind kind;
    Readings bad, unknown;
  };
  const Case cases[] = {
      {InterlockKind::kOutOfLimits, Readings{63.0, 30.0, 30.0}, Readings{std::nullopt, 30.0, 30.0}},
      {InterlockKind::kProbeDisagreement, Readings{30.0, 31.5, 28.5},
       Readings{30.0, 31.5, std::nullopt}},
      {InterlockKind::kChamberAlarm, with(at(30), [](Readings& r) { r.chamber_alarm = true; }),
       Readings{std::nullopt, 30.05, 29.95}},
      {InterlockKind::kChamberSilent, with(at(30), [](Readings& r) { r.chamber_silent_s = 11; }),
       Readings{std::nullopt, 30.05, 29.95}},
      {InterlockKind::kProbesSilent, with(at(30), [](Readings& r) { r.probes_silent_s = 11; }),
       Readings{30.0, std::nullopt, std::nullopt}},
      {InterlockKind::kGyroLost, with(at(30), [](Readings& r) { r.gyro_silent_s = 6; }),
       with(at(30), [](Readings& r) { r.gyro_heard = false; })},
      {InterlockKind::kStorageFailing, with(at(30), [](Readings& r) { r.storage_failing_s = 11; }),
       with(at(30), [](Readings& r) { r.storage_committed = false; })},
      // The table answered nothing this tick: its fault (latched) and its
      // silence stay tripped.
      {InterlockKind::kTableFault, with(at(30), [](Readings& r) { r.table_fault = true; }),
       with(at(30), [](Readings& r) { r.table_rate_dps.reset(); })},
      {InterlockKind::kTableSilent,
       with(at(30),
            [](Readings& r) {
              r.table_rate_dps.reset();
              r.table_silent_s = 11;
            }),
       with(at(30), [](Readings& r) { r.table_rate_dps.reset(); })},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(std::string(to_string(c.kind)));
    AcquiringSoak f;
    tick_range(f.seq, 61, 100, at(30));
    f.seq.tick(101, c.bad);
    ASSERT_EQ(f.seq.tripped().size(), 1u);
    tick_range(f.seq, 102, 150, c.unknown);
    bool still = false;
    for (const auto& t : f.seq.tripped()) still = still || t.kind == c.kind;
    EXPECT_TRUE(still) << "cleared without the readings to tell";
    tick_range(f.seq, 151, 2000, at(30));
    EXPECT_EQ(f.seq.state(), RunState::kCompleted);
  }
}

// Sibling timers across a restart: the settle timeout counts the soak's
// time before the crash (and the time down), not only the time since.
TEST(Sequencer, RestoredSettleTimeoutCountsTheTimeBeforeTheRestart) {
  RecordingObserver obs0;
  PlanStep step = quick_soak(30, 60);
  step.settle_timeout_s = 100;
  Sequencer first(make_plan({step}), {}, obs0);
  first.start(0, 23);
  tick_range(first, 1, 80, at(23));  // far from 30 °C: never stable
  RecordingObserver obs;
  Sequencer seq(make_plan({step}), {}, obs);
  seq.restore(first.snapshot(80), 90, 80, "restart");
  tick_range(seq, 91, 200, at(23));
  ASSERT_FALSE(obs.interlocks.empty());
  EXPECT_EQ(obs.interlocks[0].kind, InterlockKind::kSettleTimeout);
  // 100 s of the soak's time: 80 before the crash, 10 down, then ticks; the
  // first tick after the restart is held (it waits for readings).
  EXPECT_DOUBLE_EQ(obs.interlocks[0].t_s, 102) << "not 90 + 100 s: the timeout did not start over";
}

// ------------------------------------------------------------- transition table

// Every operator command and event from every live state: the state after it,
// and whether a command was refused. One row per (state, input).
enum class Input { kPause, kResume, kAbort, kSafe, kInterrupt, kTrip, kClear };

struct TransitionRow {
  RunState from;
  Input input;
  RunState to;
  bool refused;  // commands only (pause, resume)
};

// A sequencer brought into `state` with a single soak at 30 °C (or a ramp for
// kRamping), ticked once a second from t = 0.
struct InState {
  RecordingObserver obs;
  Sequencer seq;
  double t = 0;
  explicit InState(RunState state)
      : seq(make_plan({state == RunState::kRamping ? ramp(40, 0.1) : quick_soak(30, 6000)}), {},
            obs) {
    seq.start(0, 30);
    if (state == RunState::kRamping || state == RunState::kSettling) {
      tick(1, at(30));
    } else {
      tick(60, at(30));  // acquiring
    }
    if (state == RunState::kPaused) {
      EXPECT_TRUE(seq.pause(t, "x").ok());
    }
    if (state == RunState::kSuspended) tick(1, Readings{30.0, 32.0, 29.0});  // probes disagree
    if (state == RunState::kAborting) seq.abort(t, "x");
    if (state == RunState::kFailed) {
      seq.abort(t, "x");
      seq.safe_state_reached(t);
    }
    if (state == RunState::kInterrupted) seq.interrupt(t, "x");
    EXPECT_EQ(seq.state(), state);
  }
  void tick(int n, const Readings& r) {
    for (int i = 0; i < n; ++i) seq.tick(t += 1.0, r);
  }
  bool apply(Input input) {
    switch (input) {
      case Input::kPause:
        return seq.pause(t, "x").ok();
      case Input::kResume:
        return seq.resume(t, "x").ok();
      case Input::kAbort:
        seq.abort(t, "x");
        return true;
      case Input::kSafe:
        seq.safe_state_reached(t);
        return true;
      case Input::kInterrupt:
        seq.interrupt(t, "x");
        return true;
      case Input::kTrip:
        tick(1, Readings{30.0, 32.0, 29.0});
        return true;
      case Input::kClear:
        tick(1, at(30));
        return true;
    }
    return false;
  }
};

TEST(SequencerTransitions, Table) {
  using S = RunState;
  using I = Input;
  const TransitionRow rows[] = {
      {S::kSettling, I::kPause, S::kPaused, false},
      {S::kSettling, I::kResume, S::kSettling, true},
      {S::kSettling, I::kAbort, S::kAborting, false},
      {S::kSettling, I::kInterrupt, S::kInterrupted, false},
      {S::kSettling, I::kTrip, S::kSuspended, false},
      {S::kSettling, I::kSafe, S::kSettling, false},
      {S::kAcquiring, I::kPause, S::kPaused, false},
      {S::kAcquiring, I::kResume, S::kAcquiring, true},
      {S::kAcquiring, I::kAbort, S::kAborting, false},
      {S::kAcquiring, I::kInterrupt, S::kInterrupted, false},
      {S::kAcquiring, I::kTrip, S::kSuspended, false},
      {S::kAcquiring, I::kClear, S::kAcquiring, false},
      {S::kRamping, I::kPause, S::kPaused, false},
      {S::kRamping, I::kAbort, S::kAborting, false},
      {S::kRamping, I::kTrip, S::kSuspended, false},
      {S::kRamping, I::kInterrupt, S::kInterrupted, false},
      {S::kPaused, I::kPause, S::kPaused, true},
      {S::kPaused, I::kResume, S::kAcquiring, false},
      {S::kPaused, I::kClear, S::kPaused, false},
      {S::kPaused, I::kTrip, S::kSuspended, false},
      {S::kPaused, I::kAbort, S::kAborting, false},
      {S::kPaused, I::kInterrupt, S::kInterrupted, false},
      {S::kSuspended, I::kClear, S::kAcquiring, false},
      {S::kSuspended, I::kTrip, S::kSuspended, false},
      {S::kSuspended, I::kPause, S::kSuspended, false},
      {S::kSuspended, I::kResume, S::kSuspended, true},
      {S::kSuspended, I::kAbort, S::kAborting, false},
      {S::kSuspended, I::kInterrupt, S::kInterrupted, false},
      {S::kAborting, I::kSafe, S::kFailed, false},
      {S::kAborting, I::kPause, S::kAborting, true},
      {S::kAborting, I::kResume, S::kAborting, true},
      {S::kAborting, I::kTrip, S::kAborting, false},
      {S::kAborting, I::kInterrupt, S::kFailed, false},
      {S::kFailed, I::kPause, S::kFailed, true},
      {S::kFailed, I::kResume, S::kFailed, true},
      {S::kFailed, I::kAbort, S::kFailed, false},
      {S::kFailed, I::kTrip, S::kFailed, false},
      {S::kInterrupted, I::kPause, S::kInterrupted, true},
      {S::kInterrupted, I::kAbort, S::kInterrupted, false},
      {S::kInterrupted, I::kClear, S::kInterrupted, false},
  };
  for (const auto& row : rows) {
    SCOPED_TRACE(fmt::format("{} + input {}", to_string(row.from), static_cast<int>(row.input)));
    InState s(row.from);
    const bool accepted = s.apply(row.input);
    EXPECT_EQ(s.seq.state(), row.to);
    if (row.input == Input::kPause || row.input == Input::kResume) {
      EXPECT_EQ(!accepted, row.refused);
    }
    // Every transition was reported, in order, ending in the state shown.
    if (!s.obs.transitions.empty()) {
      EXPECT_EQ(s.obs.transitions.back().to, s.seq.state());
    }
    for (std::size_t i = 1; i < s.obs.transitions.size(); ++i) {
      EXPECT_EQ(s.obs.transitions[i].from, s.obs.transitions[i - 1].to);
    }
  }
}

TEST(SequencerOptions, Validity) {
  std::string why;
  EXPECT_TRUE(SequencerOptions{}.is_valid(&why)) << why;
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  const std::vector<std::pair<std::function<void(SequencerOptions&)>, std::string>> bad = {
      {[](SequencerOptions& o) { o.safe_setpoint_c = kNaN; }, "safe_setpoint_c"},
      {[](SequencerOptions& o) { o.safe_setpoint_c = o.interlocks.max_temp_c + 1; },
       "safe_setpoint_c"},
      {[](SequencerOptions& o) { o.at_rate_tolerance_dps = 0; }, "at_rate_tolerance_dps"},
      {[](SequencerOptions& o) { o.at_rate_tolerance_ppm = -1; }, "at_rate_tolerance_ppm"},
      {[](SequencerOptions& o) { o.at_rate_hold_s = -1; }, "at_rate_hold_s = -1 must be"},
      {[](SequencerOptions& o) { o.spin_up_timeout_s = 0; }, "spin_up_timeout_s"},
      {[](SequencerOptions& o) { o.spin_up_timeout_s = o.at_rate_hold_s; }, "spin_up_timeout_s"},
      // The interlocks are checked too, their fields named with the prefix.
      {[](SequencerOptions& o) { o.interlocks.gyro_timeout_s = 0; }, "interlocks.gyro_timeout_s"},
      {[](SequencerOptions& o) { o.interlocks.max_temp_c = -30; }, "interlocks.max_temp_c"},
  };
  for (const auto& [spoil, field] : bad) {
    SequencerOptions o;
    spoil(o);
    why.clear();
    EXPECT_FALSE(o.is_valid(&why)) << field;
    EXPECT_EQ(why.rfind(field, 0), 0u) << "the message starts with " << field << ": " << why;
    EXPECT_FALSE(o.is_valid(nullptr)) << field;
  }
}

}  // namespace
}  // namespace gyrotherm::schedules
