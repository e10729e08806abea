// Sequencer speed in virtual time: the paper's whole Table I campaign
// (config/schedules/paper-table1.toml: 32 soaks, about 80 h of station time)
// ticked once per station second against a first-order chamber and shell,
// as the daemon's tests run hours of schedule in milliseconds. Prints the
// wall time per campaign and station seconds per wall second; it is not a
// pass/fail test (tests/schedules/sequencer_test.cpp checks what the run
// does, this measures how fast). See bench/README.md.
// BM_ScaleFactorCampaign: config/schedules/scale-factor.toml (3 soaks and 84
// rate points on a 500 °/s table) against the same plant and a table that
// follows the demand at 100 °/s², ticked every 0.1 station s.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <utility>

#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/schedules/sequencer.h"

namespace {

namespace gs = gyrotherm::schedules;

class NullObserver : public gs::SequencerObserver {
 public:
  void on_state(gs::RunState, gs::RunState, double, const std::string&) override {}
  void on_step_started(std::size_t, const gs::PlanStep&, double) override {}
  void on_step_changed(std::size_t, const gs::PlanStep&, const gs::StepTimes&) override {}
  void on_interlock(gs::InterlockKind, bool, double, const std::string&) override {}
  void on_step_finished(std::size_t, const gs::PlanStep&, const gs::StepTimes&, bool) override {
    ++steps_finished;
  }
  int steps_finished = 0;
};

// Air follows the set point with a 60 s lag, the shell the air with 900 s;
// the probes straddle the shell by ±0.05 °C.
struct Plant {
  double air_c = 23.0, shell_c = 23.0;
  void step(double dt_s, double setpoint_c) {
    air_c += (setpoint_c - air_c) * (1.0 - std::exp(-dt_s / 60.0));
    shell_c += (air_c - shell_c) * (1.0 - std::exp(-dt_s / 900.0));
  }
};

void BM_PaperTable1Campaign(benchmark::State& state) {
  const std::string path =
      std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml";
  auto plan = gs::load_schedule(path, {-20.0, 60.0, 2.0});
  if (!plan.ok()) {
    state.SkipWithError(plan.error().message.c_str());
    return;
  }
  double station_s = 0;
  for (auto _ : state) {
    NullObserver obs;
    gs::Sequencer seq(*plan, {}, obs);
    Plant plant;
    double t = 0;
    seq.start(0.0, 23.0);
    while (!seq.finished() && t < 30 * 24 * 3600.0) {
      t += 1.0;
      plant.step(1.0, seq.setpoint_c());
      seq.tick(t, gs::Readings{plant.air_c, plant.shell_c + 0.05, plant.shell_c - 0.05});
    }
    if (obs.steps_finished != 32) state.SkipWithError("the campaign did not finish 32 soaks");
    station_s = t;
    benchmark::DoNotOptimize(t);
  }
  state.counters["station_h"] = station_s / 3600.0;
  state.counters["station_s_per_wall_s"] = benchmark::Counter(
      station_s * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_PaperTable1Campaign)->Unit(benchmark::kMillisecond);

void BM_ScaleFactorCampaign(benchmark::State& state) {
  const std::string path =
      std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/scale-factor.toml";
  gs::StationLimits limits{-20.0, 60.0, 2.0};
  limits.table = gs::StationLimits::Table{500.0, 100.0};
  auto plan = gs::load_schedule(path, limits);
  if (!plan.ok()) {
    state.SkipWithError(plan.error().message.c_str());
    return;
  }
  const std::size_t steps = plan->steps.size();
  double station_s = 0;
  for (auto _ : state) {
    NullObserver obs;
    gs::Sequencer seq(*plan, {}, obs);
    Plant plant;
    double rate_dps = 0;
    constexpr double kDt = 0.1;
    double t = 0;
    seq.start(0.0, 23.0);
    while (!seq.finished() && t < 30 * 24 * 3600.0) {
      t += kDt;
      plant.step(kDt, seq.setpoint_c());
      const gs::TableDemand& d = seq.table_demand();
      const double target = d.mode == gs::TableDemandMode::kRate ? d.rate_dps : 0.0;
      rate_dps += std::clamp(target - rate_dps, -100.0 * kDt, 100.0 * kDt);
      gs::Readings r{plant.air_c, plant.shell_c + 0.05, plant.shell_c - 0.05};
      r.table_present = true;
      r.table_rate_dps = rate_dps;
      seq.tick(t, r);
    }
    if (obs.steps_finished != static_cast<int>(steps)) {
      state.SkipWithError("the campaign did not finish every step");
    }
    station_s = t;
    benchmark::DoNotOptimize(t);
  }
  state.counters["station_h"] = station_s / 3600.0;
  state.counters["station_s_per_wall_s"] = benchmark::Counter(
      station_s * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_ScaleFactorCampaign)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
