// Planned durations and progress (progress.h) against hand-computed figures:
// the plan's fixed-length time and its settles, the progress of each kind of
// step from a sequencer snapshot, a real sequencer's gate while a soak
// settles, and the queue's cache.
#include "gyrotherm/schedules/progress.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "station_limits.h"

namespace gyrotherm::schedules {
namespace {

// Fixed parts, by hand: soak 20 °C acquires 60 min (3600 s); ramp 20 -> 40
// at 0.5 °C/min: 40 min (2400 s); soak 40 °C acquires 30 min (1800 s); hold
// 20 min (1200 s); ramp 40 -> 10 at 1 °C/min: 30 min (1800 s); soak 10 °C
// acquires 45 min (2700 s). Sum 13500 s = 3 h 45 min; three soaks settle.
constexpr const char* kCampaign = R"(
name = "campaign"
[[step]]
type = "soak"
setpoint_c = 20
acquire_min = 60
[[step]]
type = "ramp"
target_c = 40
rate_c_per_min = 0.5
[[step]]
type = "soak"
setpoint_c = 40
acquire_min = 30
[[step]]
type = "hold"
setpoint_c = 40
duration_min = 20
[[step]]
type = "ramp"
target_c = 10
rate_c_per_min = 1
[[step]]
type = "soak"
setpoint_c = 10
acquire_min = 45
)";

Plan parse_plan(const std::string& text, const StationLimits& limits = kNoTable) {
  auto plan = parse_schedule(text, "t.toml", limits);
  if (!plan) {
    ADD_FAILURE() << plan.error().message;
    return {};
  }
  return *plan;
}

TEST(PlannedDuration, CountsRampsAcquisitionsHoldsAndSettles) {
  const Plan plan = parse_plan(kCampaign);
  const PlannedDuration d = planned_duration(plan, 23.0);
  EXPECT_DOUBLE_EQ(d.fixed_s, 13500.0);
  EXPECT_EQ(d.settles, 3);
  EXPECT_EQ(format_planned(d), "3 h 45 min (+ 3 settles of unknown length)");
}

// A first ramp starts where the chamber is: 23 -> 35 °C at 1.5 °C/min is
// 8 min; from 11 °C, 16 min. A repeat counts each pass.
TEST(PlannedDuration, FirstRampFromTheStartAndRepeats) {
  const Plan plan = parse_plan(R"(
[[step]]
type = "ramp"
target_c = 35
rate_c_per_min = 1.5
[[step]]
type = "repeat"
count = 3
[[step.steps]]
type = "hold"
setpoint_c = 35
duration_min = 10
[[step.steps]]
type = "soak"
setpoint_c = 35
acquire_min = 5
)");
  EXPECT_DOUBLE_EQ(planned_duration(plan, 23.0).fixed_s, 480.0 + 3 * (600.0 + 300.0));
  EXPECT_DOUBLE_EQ(planned_duration(plan, 11.0).fixed_s, 960.0 + 3 * (600.0 + 300.0));
  EXPECT_EQ(planned_duration(plan, 23.0).settles, 3);
  // Without settles: the time alone.
  const Plan holds = parse_plan("[[step]]\ntype = \"hold\"\nsetpoint_c = 30\nduration_min = 90\n");
  EXPECT_EQ(format_planned(planned_duration(holds, 23.0)), "1 h 30 min");
}

// Rate points: dwell plus spin-up at 100 °/s² (table_schedule_test.cpp's
// figures): dwells 36 + 36 + 3.6 + 3.6 s, spin-ups 0.1 + 0.2 + 1.1 + 2 s,
// and the soak's 300 s: 382.6 s, one settle.
TEST(PlannedDuration, RatePointsSpinUpAndDwell) {
  const Plan plan = parse_plan(
      "[[step]]\ntype = \"soak\"\nsetpoint_c = 20\nacquire_min = 5\n"
      "table = { mode = \"static\" }\n"
      "[[step]]\ntype = \"scale_factor\"\nsetpoint_c = 20\nrates_dps = [10, 100]\n"
      "min_dwell_s = 1\n",
      kTable);
  ASSERT_EQ(plan.steps.size(), 5u);
  const PlannedDuration d = planned_duration(plan, 20.0);
  EXPECT_NEAR(d.fixed_s, 382.6, 1e-9);
  EXPECT_EQ(d.settles, 1);
  // The plan's older figure (no ramps) agrees where there are none.
  EXPECT_NEAR(d.fixed_s, plan.nominal_duration_s(), 1e-9);
}

TEST(PlannedDuration, FormatsTheTwoLargestUnits) {
  EXPECT_EQ(format_duration(0), "0 s");
  EXPECT_EQ(format_duration(45.4), "45 s");
  EXPECT_EQ(format_duration(59.6), "1 min");
  EXPECT_EQ(format_duration(750), "12 min 30 s");
  EXPECT_EQ(format_duration(3599.7), "1 h");
  EXPECT_EQ(format_duration(5 * 3600 + 20 * 60), "5 h 20 min");
  EXPECT_EQ(format_duration(51 * 3600 + 1000), "2 d 3 h");
  EXPECT_EQ(format_duration(2 * 86400), "2 d");
  EXPECT_EQ(format_duration(-5), "0 s");
  EXPECT_EQ(format_planned({19200, 4}), "5 h 20 min (+ 4 settles of unknown length)");
  EXPECT_EQ(format_planned({600, 1}), "10 min (+ 1 settle of unknown length)");
}

SequencerSnapshot at_step(std::size_t index, RunState activity, double t_s) {
  SequencerSnapshot s;
  s.t_s = t_s;
  s.state = activity;
  s.activity = activity;
  s.step_index = index;
  return s;
}

// Ramp 20 -> 40 at 0.5 °C/min with the set point at 25: a quarter done,
// 600 of 2400 s; 1800 s left in it plus 7500 s after (1800 + 1200 + 1800 +
// 2700); two soaks still to settle: no ETA.
TEST(RunProgress, RampFromTheSetPointsTrajectory) {
  const Plan plan = parse_plan(kCampaign);
  SequencerSnapshot s = at_step(1, RunState::kRamping, 5000);
  s.ramp_from_c = 20;
  s.setpoint_c = 25;
  const RunProgress p = run_progress(plan, s, std::nullopt, {3600, 2});
  EXPECT_EQ(p.phase, "ramping");
  EXPECT_DOUBLE_EQ(*p.step_planned_s, 2400);
  EXPECT_DOUBLE_EQ(*p.step_elapsed_s, 600);
  EXPECT_DOUBLE_EQ(*p.step_fraction, 0.25);
  EXPECT_DOUBLE_EQ(p.run_remaining_fixed_s, 1800 + 7500);
  EXPECT_EQ(p.run_settles_remaining, 2);
  EXPECT_FALSE(p.run_eta_s);
  EXPECT_FALSE(p.gate_held_s);
  EXPECT_DOUBLE_EQ(p.queue_fixed_s, 3600);
  EXPECT_EQ(p.queue_settles, 2);
}

// Hold of 20 min, 300 s of unheld time in it: 900 s left, then the ramp
// (1800 s) and the last soak (2700 s) with its settle.
TEST(RunProgress, HoldCountsUnheldTime) {
  const Plan plan = parse_plan(kCampaign);
  SequencerSnapshot s = at_step(3, RunState::kSettling, 9000);
  s.step_active_s = 300;
  s.times.held_s = 120;  // paused for a while: not counted
  const RunProgress p = run_progress(plan, s, std::nullopt, {});
  EXPECT_EQ(p.phase, "holding");
  EXPECT_DOUBLE_EQ(*p.step_fraction, 0.25);
  EXPECT_DOUBLE_EQ(p.run_remaining_fixed_s, 900 + 1800 + 2700);
  EXPECT_EQ(p.run_settles_remaining, 1);
  EXPECT_FALSE(p.run_eta_s);
}

// The last soak (45 min): while it settles there is no fraction and no ETA,
// the gate's progress instead; once acquiring (a closed window of 600 s and
// an open one of 500 s) 1100 of 2700 s are done and the ETA is the 1600 s
// left.
TEST(RunProgress, SoakSettlingShowsTheGateThenAcquiringHasAnEta) {
  const Plan plan = parse_plan(kCampaign);
  SequencerSnapshot settling = at_step(5, RunState::kSettling, 20000);
  settling.step_active_s = 420;
  const RunProgress a = run_progress(plan, settling, GateProgress{240, 600, 420}, {});
  EXPECT_EQ(a.phase, "settling");
  EXPECT_FALSE(a.step_fraction);
  EXPECT_DOUBLE_EQ(*a.step_elapsed_s, 420);
  EXPECT_DOUBLE_EQ(*a.step_planned_s, 2700);
  EXPECT_DOUBLE_EQ(*a.gate_held_s, 240);
  EXPECT_DOUBLE_EQ(*a.gate_needed_s, 600);
  EXPECT_DOUBLE_EQ(a.run_remaining_fixed_s, 2700);
  EXPECT_EQ(a.run_settles_remaining, 1);
  EXPECT_FALSE(a.run_eta_s);

  SequencerSnapshot acquiring = at_step(5, RunState::kAcquiring, 2500);
  acquiring.times.windows = {{1000, 1600}};
  acquiring.window_open_s = 2000;
  const RunProgress b = run_progress(plan, acquiring, std::nullopt, {});
  EXPECT_EQ(b.phase, "acquiring");
  EXPECT_DOUBLE_EQ(*b.step_elapsed_s, 1100);
  EXPECT_DOUBLE_EQ(*b.step_fraction, 1100.0 / 2700.0);
  EXPECT_DOUBLE_EQ(b.run_remaining_fixed_s, 1600);
  EXPECT_EQ(b.run_settles_remaining, 0);
  ASSERT_TRUE(b.run_eta_s);
  EXPECT_DOUBLE_EQ(*b.run_eta_s, 1600);
}

// The last soak settling with a forecast of its gate in 900 s (P10 600,
// P90 1500): it is the only settle left, so the run ends after it and the
// soak's 2700 s of acquisition: 3600 s (3300 - 4200). A soak earlier in the
// plan (step 2; the last soak still settles later) shows its forecast but
// gives no ETA; a P90 beyond the horizon leaves the band open; acquiring,
// the forecast is dropped.
TEST(RunProgress, TheCurrentSettlesForecastCompletesTheEtaWhenItIsTheLastSettle) {
  const Plan plan = parse_plan(kCampaign);
  const SettleForecast forecast{"predicted", "fitted", 600.0, 900.0, 1500.0};
  SequencerSnapshot last = at_step(5, RunState::kSettling, 20000);
  const RunProgress a = run_progress(plan, last, GateProgress{0, 600, 300}, {}, forecast);
  ASSERT_TRUE(a.settle);
  EXPECT_EQ(a.settle->verdict, "predicted");
  EXPECT_DOUBLE_EQ(*a.settle->p50_s, 900);
  ASSERT_TRUE(a.run_eta_s);
  EXPECT_DOUBLE_EQ(*a.run_eta_s, 900 + 2700);
  EXPECT_DOUBLE_EQ(*a.run_eta_p10_s, 600 + 2700);
  EXPECT_DOUBLE_EQ(*a.run_eta_p90_s, 1500 + 2700);

  SettleForecast open = forecast;
  open.p90_s.reset();
  const RunProgress b = run_progress(plan, last, std::nullopt, {}, open);
  EXPECT_DOUBLE_EQ(*b.run_eta_s, 3600);
  EXPECT_FALSE(b.run_eta_p90_s);

  SequencerSnapshot earlier = at_step(2, RunState::kSettling, 6000);
  const RunProgress c = run_progress(plan, earlier, std::nullopt, {}, forecast);
  ASSERT_TRUE(c.settle);
  EXPECT_EQ(c.run_settles_remaining, 2);
  EXPECT_FALSE(c.run_eta_s);
  EXPECT_FALSE(c.run_eta_p10_s);

  const SettleForecast early{"not_enough_curvature", "too early", {}, {}, {}};
  const RunProgress d = run_progress(plan, last, std::nullopt, {}, early);
  ASSERT_TRUE(d.settle);
  EXPECT_FALSE(d.run_eta_s);

  SequencerSnapshot acquiring = at_step(5, RunState::kAcquiring, 25000);
  acquiring.window_open_s = 24000;
  const RunProgress e = run_progress(plan, acquiring, std::nullopt, {}, forecast);
  EXPECT_FALSE(e.settle);
  EXPECT_DOUBLE_EQ(*e.run_eta_s, 1700);
  EXPECT_FALSE(e.run_eta_p10_s);
}

// The chamber's prior: numpy.percentile's default (linear) of the past
// settles, the unusable ones dropped, none under three.
TEST(SettlePrior, QuantilesOfThePastSettles) {
  const auto prior = settle_prior({1000, 300, 100, 400, 200, std::nan(""), -5});
  ASSERT_TRUE(prior);
  EXPECT_EQ(prior->settles, 5);
  EXPECT_DOUBLE_EQ(prior->p10_s, 140);  // 100 + 0.4 (200 - 100)
  EXPECT_DOUBLE_EQ(prior->p50_s, 300);
  EXPECT_DOUBLE_EQ(prior->p90_s, 760);  // 400 + 0.6 (1000 - 400)
  EXPECT_FALSE(settle_prior({100, 200}));
  EXPECT_FALSE(settle_prior({100, 200, std::nan("")}));
  const auto one_value = settle_prior({50, 50, 50});
  ASSERT_TRUE(one_value);
  EXPECT_DOUBLE_EQ(one_value->p10_s, 50);
  EXPECT_DOUBLE_EQ(one_value->p90_s, 50);
}

// The prior (P10 140, P50 300, P90 760 s from 5 settles) fills in the
// settles not forecast. Soak 40 °C settling with its forecast (600/900/1500
// s): 1800 s of its acquisition + 5700 s after (hold 1200, ramp 1800, soak
// 2700) and one later settle: 7500 + 900 + 300 = 8700 s (P10 7500 + 600 +
// 140, P90 7500 + 1500 + 760). Without a forecast, 200 s settled: the prior
// less 200 s (0, 100, 560), and the same with a forecast that has no P50.
// Queued (from 23 °C): 13500 s + 3 settles. The
// queue: 3600 s + 2 settles.
TEST(RunProgress, TheChambersPriorCompletesTheEtaForSettlesNotForecast) {
  const Plan plan = parse_plan(kCampaign);
  const SettlePrior prior{5, 140, 300, 760};
  const SettleForecast forecast{"predicted", "fitted", 600.0, 900.0, 1500.0};
  SequencerSnapshot soak = at_step(2, RunState::kSettling, 6000);
  soak.step_active_s = 200;
  const RunProgress a = run_progress(plan, soak, std::nullopt, {}, forecast, prior);
  EXPECT_DOUBLE_EQ(a.run_remaining_fixed_s, 7500);
  ASSERT_TRUE(a.run_eta_s && a.run_eta_p10_s && a.run_eta_p90_s);
  EXPECT_DOUBLE_EQ(*a.run_eta_s, 8700);
  EXPECT_DOUBLE_EQ(*a.run_eta_p10_s, 8240);
  EXPECT_DOUBLE_EQ(*a.run_eta_p90_s, 9760);
  EXPECT_EQ(a.run_eta_basis, "forecast+prior");
  EXPECT_EQ(a.prior_settles, 5);

  const RunProgress b = run_progress(plan, soak, std::nullopt, {}, std::nullopt, prior);
  EXPECT_DOUBLE_EQ(*b.run_eta_s, 7500 + 100 + 300);
  EXPECT_DOUBLE_EQ(*b.run_eta_p10_s, 7500 + 0 + 140);
  EXPECT_DOUBLE_EQ(*b.run_eta_p90_s, 7500 + 560 + 760);
  EXPECT_EQ(b.run_eta_basis, "prior");

  // A forecast without a P50 (a final value outside the tolerance, or
  // beyond its horizon) leaves the current settle to the prior, as before a
  // forecast; the forecast's verdict is still shown.
  const SettleForecast outside{"never_within_tolerance", "final 41.2 °C", {}, {}, {}};
  const RunProgress c = run_progress(plan, soak, std::nullopt, {}, outside, prior);
  ASSERT_TRUE(c.run_eta_s);
  EXPECT_DOUBLE_EQ(*c.run_eta_s, *b.run_eta_s);
  EXPECT_DOUBLE_EQ(*c.run_eta_p90_s, *b.run_eta_p90_s);
  EXPECT_EQ(c.run_eta_basis, "prior");
  EXPECT_EQ(c.prior_settles, 5);
  ASSERT_TRUE(c.settle);
  EXPECT_EQ(c.settle->verdict, "never_within_tolerance");
  const SettleForecast far{"predicted", "beyond 48 h", 600.0, {}, {}};
  const RunProgress far_eta = run_progress(plan, soak, std::nullopt, {}, far, prior);
  ASSERT_TRUE(far_eta.run_eta_s);
  EXPECT_DOUBLE_EQ(*far_eta.run_eta_s, *b.run_eta_s);
  EXPECT_EQ(far_eta.run_eta_basis, "prior");
  // Without a prior, such a settle leaves the run without an ETA.
  EXPECT_FALSE(run_progress(plan, soak, std::nullopt, {}, outside).run_eta_s);

  SequencerSnapshot queued = at_step(0, RunState::kQueued, 0);
  queued.setpoint_c = 23;
  const RunProgress d = run_progress(plan, queued, std::nullopt, {3600, 2}, std::nullopt, prior);
  EXPECT_DOUBLE_EQ(*d.run_eta_s, 13500 + 3 * 300);
  EXPECT_DOUBLE_EQ(*d.run_eta_p10_s, 13500 + 3 * 140);
  EXPECT_DOUBLE_EQ(*d.run_eta_p90_s, 13500 + 3 * 760);
  EXPECT_EQ(d.run_eta_basis, "prior");
  EXPECT_DOUBLE_EQ(*d.queue_eta_s, 3600 + 2 * 300);
  EXPECT_DOUBLE_EQ(*d.queue_eta_p10_s, 3600 + 2 * 140);
  EXPECT_DOUBLE_EQ(*d.queue_eta_p90_s, 3600 + 2 * 760);

  EXPECT_FALSE(queue_progress({3600, 2}, std::nullopt).queue_eta_s);
  EXPECT_DOUBLE_EQ(*queue_progress({3600, 0}, std::nullopt).queue_eta_s, 3600);
  EXPECT_FALSE(run_progress(plan, queued, std::nullopt, {}).run_eta_s);
}

// Rate point -10 °/s after +10 °/s: spin-up 0.2 s + dwell 36 s. Dwelling
// for 10 s: 10.2 of 36.2 s; left 26 s, then +100 (1.1 + 3.6 s) and -100
// (2 + 3.6 s): 36.3 s, no settle, so that is the ETA. Spinning up for 0.1 s
// with the at-rate gate half held.
TEST(RunProgress, RatePointSpinUpAndDwell) {
  const Plan plan = parse_plan(
      "[[step]]\ntype = \"soak\"\nsetpoint_c = 20\nacquire_min = 5\n"
      "table = { mode = \"static\" }\n"
      "[[step]]\ntype = \"scale_factor\"\nsetpoint_c = 20\nrates_dps = [10, 100]\n"
      "min_dwell_s = 1\n",
      kTable);
  ASSERT_EQ(plan.steps.size(), 5u);
  ASSERT_DOUBLE_EQ(plan.steps[2].table.rate_dps, -10);
  SequencerSnapshot dwell = at_step(2, RunState::kAcquiring, 500);
  dwell.window_open_s = 490;
  const RunProgress a = run_progress(plan, dwell, std::nullopt, {});
  EXPECT_EQ(a.phase, "acquiring");
  EXPECT_NEAR(*a.step_planned_s, 36.2, 1e-9);
  EXPECT_NEAR(*a.step_elapsed_s, 10.2, 1e-9);
  EXPECT_NEAR(*a.step_fraction, 10.2 / 36.2, 1e-12);
  EXPECT_NEAR(a.run_remaining_fixed_s, 26 + 4.7 + 5.6, 1e-9);
  ASSERT_TRUE(a.run_eta_s);
  EXPECT_NEAR(*a.run_eta_s, 36.3, 1e-9);

  SequencerSnapshot spin = at_step(2, RunState::kSettling, 480);
  const RunProgress b = run_progress(plan, spin, GateProgress{0.5, 1.0, 0.1}, {});
  EXPECT_EQ(b.phase, "spinning_up");
  EXPECT_NEAR(*b.step_elapsed_s, 0.1, 1e-12);
  EXPECT_DOUBLE_EQ(*b.gate_held_s, 0.5);
  EXPECT_DOUBLE_EQ(*b.gate_needed_s, 1.0);
  EXPECT_NEAR(b.run_remaining_fixed_s, 36.1 + 4.7 + 5.6, 1e-9);
  EXPECT_EQ(b.run_settles_remaining, 0);
}

TEST(RunProgress, EndedRunHasNothingLeft) {
  const Plan plan = parse_plan(kCampaign);
  SequencerSnapshot s = at_step(plan.steps.size(), RunState::kCompleted, 30000);
  const RunProgress p = run_progress(plan, s, std::nullopt, {100, 1});
  EXPECT_EQ(p.phase, "completed");
  EXPECT_DOUBLE_EQ(p.run_remaining_fixed_s, 0);
  EXPECT_EQ(p.run_settles_remaining, 0);
  EXPECT_DOUBLE_EQ(p.queue_fixed_s, 100);
}

class NullObserver : public SequencerObserver {
 public:
  void on_state(RunState, RunState, double, const std::string&) override {}
  void on_step_started(std::size_t, const PlanStep&, double) override {}
  void on_step_changed(std::size_t, const PlanStep&, const StepTimes&) override {}
  void on_step_finished(std::size_t, const PlanStep&, const StepTimes&, bool) override {}
  void on_interlock(InterlockKind, bool, double, const std::string&) override {}
};

// A real sequencer: soak at 30 °C with a 10 min window. Chamber and shell
// out of tolerance until t = 100 s, then at the set point: the gate's held
// time counts from the first tick within tolerance (110 s), a tick out of
// tolerance starts it over, it never exceeds the window, and once the gate
// holds the soak acquires and the progress has a fraction.
TEST(RunProgress, RealSequencerGateWhileSettling) {
  const Plan plan = parse_plan(R"(
[[step]]
type = "soak"
setpoint_c = 30
stability_window_min = 10
acquire_min = 20
)");
  NullObserver observer;
  Sequencer seq(plan, SequencerOptions{}, observer);
  seq.start(0, 30);
  auto readings = [](double c) { return Readings{c, c + 0.01, c - 0.01}; };
  double t = 0;
  for (; t <= 100; t += 10) seq.tick(t, readings(25));
  EXPECT_DOUBLE_EQ(seq.gate_progress(t - 10)->held_s, 0);
  for (; t <= 300; t += 10) seq.tick(t, readings(30));
  auto gate = seq.gate_progress(300);
  ASSERT_TRUE(gate);
  EXPECT_DOUBLE_EQ(gate->held_s, 190);
  EXPECT_DOUBLE_EQ(gate->needed_s, 600);
  RunProgress p = run_progress(seq.plan(), seq.snapshot(300), gate, {});
  EXPECT_EQ(p.phase, "settling");
  EXPECT_FALSE(p.step_fraction);
  EXPECT_DOUBLE_EQ(*p.gate_held_s, 190);
  EXPECT_EQ(p.run_settles_remaining, 1);
  EXPECT_FALSE(p.run_eta_s);

  // One tick out of tolerance: the gate starts over.
  seq.tick(310, readings(31));
  EXPECT_DOUBLE_EQ(seq.gate_progress(310)->held_s, 0);
  // Only steady readings from here: held time grows to the window, then the
  // gate holds (the window is full of flat readings) and acquisition starts.
  for (t = 320; seq.state() == RunState::kSettling && t < 3600; t += 10) {
    seq.tick(t, readings(30));
    if (auto g = seq.gate_progress(t)) {
      EXPECT_LE(g->held_s, 600);
    }
  }
  ASSERT_EQ(seq.state(), RunState::kAcquiring) << "t = " << t;
  EXPECT_FALSE(seq.gate_progress(t));
  for (const double end = t + 600; t < end; t += 10) seq.tick(t, readings(30));
  p = run_progress(seq.plan(), seq.snapshot(t - 10), seq.gate_progress(t - 10), {});
  EXPECT_EQ(p.phase, "acquiring");
  ASSERT_TRUE(p.step_fraction);
  EXPECT_NEAR(*p.step_fraction, 0.5, 10.0 / 1200);  // 600 of 1200 s, within a tick
  ASSERT_TRUE(p.run_eta_s);
  EXPECT_NEAR(*p.run_eta_s, 600, 10);
  EXPECT_FALSE(p.gate_held_s);
}

// Each entry's text is parsed once; entries gone are forgotten; a text that
// no longer parses counts nothing.
TEST(QueueDurations, ParsesEachEntryOnce) {
  const std::string hold = "[[step]]\ntype = \"hold\"\nsetpoint_c = 23\nduration_min = 10\n";
  QueueDurations q;
  std::vector<QueueDurations::Entry> entries = {{1, kCampaign, "a.toml"}, {2, hold, "b.toml"}};
  PlannedDuration d = q.update(entries, kNoTable, 23.0);
  EXPECT_DOUBLE_EQ(d.fixed_s, 13500 + 600);
  EXPECT_EQ(d.settles, 3);
  d = q.update(entries, kNoTable, 23.0);
  EXPECT_DOUBLE_EQ(d.fixed_s, 13500 + 600);
  EXPECT_EQ(q.parsed(), 2u);
  entries.erase(entries.begin());
  d = q.update(entries, kNoTable, 23.0);
  EXPECT_DOUBLE_EQ(d.fixed_s, 600);
  EXPECT_EQ(d.settles, 0);
  entries.push_back({3, "[[step]]\ntype = \"soak\"\nsetpoint_c = 500\n", "bad.toml"});
  d = q.update(entries, kNoTable, 23.0);
  EXPECT_DOUBLE_EQ(d.fixed_s, 600);
  EXPECT_EQ(q.parsed(), 3u);
}

}  // namespace
}  // namespace gyrotherm::schedules
