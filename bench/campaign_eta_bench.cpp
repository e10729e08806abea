// How right the station's campaign ETA is (issue 27, item 6): the paper's
// campaign (config/schedules/paper-table1.toml, 32 soaks) run by the real
// Sequencer against seeded simulated chambers, the ETA taken at 25, 50 and
// 75 % of each campaign's true length as the daemon forms it, and compared
// with when the campaign really ended. Prints tables; not a pass/fail test.
// See bench/README.md, "The campaign ETA against the truth (issue 27)".
//
// Per seed, one chamber (sim::ThermalPlant): air lag log-uniform in
// [60, 300] s, case lag log-uniform in [600, 2400] s, control noise uniform
// in [0.1, 0.5] °C (as tests/analysis/settle_calibration_test.cpp draws
// them), from 23 °C. Ticked at 1 s; the Sequencer gets the chamber's air as
// the chamber reports it (to 0.1 °C) and the probes' readings.
//
// The ETA, as the daemon's status forms it (schedules::run_progress): the
// plan's fixed time left, the current settle from the settle forecast
// (analysis::predict_settle on the soak's 2 s means of shell and air since
// it began settling, as the daemon's settle watch keeps them; verdicts other
// than "predicted" leave it to the prior) and each later settle from the
// chamber's prior (schedules::settle_prior of its last 50 settles). Two
// campaigns per chamber, back to back: the first has only its own settles
// so far for a prior, the second the chamber's last 50 (its first campaign's
// included), as a station keeps them in its database.
//
// Usage: gyrotherm_bench_eta [--seeds N (50)] [--first-seed S (1)]
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <map>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/analysis/settle_prediction.h"
#include "gyrotherm/schedules/progress.h"
#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/schedules/sequencer.h"
#include "gyrotherm/sim/thermal_plant.h"

namespace {

namespace ga = gyrotherm::analysis;
namespace gs = gyrotherm::schedules;
namespace sim = gyrotherm::sim;

constexpr double kFractions[] = {0.25, 0.5, 0.75};
constexpr double kPackS = 2.0;          // the settle watch's means
constexpr double kMaxS = 30 * 86400.0;  // a campaign that has not ended by then is a failure

[[noreturn]] void die(const std::string& why) {
  fmt::print(stderr, "gyrotherm_bench_eta: {}\n", why);
  std::exit(1);
}

class Observer : public gs::SequencerObserver {
 public:
  explicit Observer(std::vector<double>& settles) : settles_(settles) {}
  void on_state(gs::RunState, gs::RunState, double, const std::string&) override {}
  void on_step_started(std::size_t, const gs::PlanStep&, double) override {}
  void on_step_changed(std::size_t, const gs::PlanStep&, const gs::StepTimes&) override {}
  void on_interlock(gs::InterlockKind, bool, double, const std::string&) override {}
  void on_step_finished(std::size_t, const gs::PlanStep& step, const gs::StepTimes& times,
                        bool) override {
    if (step.kind == gs::StepKind::kSoak && times.settled_s) {
      settles_.push_back(*times.settled_s - times.start_s);
    }
  }

 private:
  std::vector<double>& settles_;
};

sim::ThermalParams draw_chamber(int seed) {
  std::mt19937_64 rng(static_cast<uint64_t>(seed) * 7919 + 13);
  auto log_uniform = [&](double lo, double hi) {
    return std::exp(std::uniform_real_distribution<double>(std::log(lo), std::log(hi))(rng));
  };
  sim::ThermalParams p;
  p.air_tau_s = log_uniform(60, 300);
  p.case_tau_s = log_uniform(600, 2400);
  p.control_noise_c = std::uniform_real_distribution<double>(0.1, 0.5)(rng);
  return p;
}

// The current soak's settle so far: 2 s means since it began settling.
struct SettleSeries {
  std::optional<std::size_t> step;
  std::vector<double> t_s, shell_c, air_c;
  double pack_start_s = 0, t_sum = 0, shell_sum = 0, air_sum = 0;
  int n = 0;

  void add(std::optional<std::size_t> settling, double t, double shell, double air) {
    if (settling != step) {
      *this = SettleSeries{};
      step = settling;
    }
    if (!step) return;
    if (n > 0 && t - pack_start_s >= kPackS) {
      t_s.push_back(t_sum / n);
      shell_c.push_back(shell_sum / n);
      air_c.push_back(air_sum / n);
      n = 0;
      t_sum = shell_sum = air_sum = 0;
    }
    if (n == 0) pack_start_s = t;
    t_sum += t;
    shell_sum += shell;
    air_sum += air;
    ++n;
  }
};

struct Eta {
  std::optional<double> p10_s, p50_s, p90_s;  // from now
  // The band if the later settles were independent draws from the prior
  // (their spread adding in quadrature: sqrt(n) x, not n x): a diagnostic.
  std::optional<double> indep_p10_s, indep_p90_s;
  std::string basis;
  std::string why_none;  // without an ETA: the phase and the forecast's verdict
};

// The ETA at t as the daemon's status forms it.
Eta eta_now(const gs::Plan& plan, const gs::Sequencer& seq, double t,
            const std::vector<double>& settles, const SettleSeries& series) {
  const gs::SequencerSnapshot snap = seq.snapshot(t);
  const std::optional<gs::GateProgress> gate = seq.gate_progress(t);
  std::optional<gs::SettleForecast> forecast;
  if (series.step && series.t_s.size() >= 2) {
    const gs::PlanStep& step = plan.steps[*series.step];
    const ga::SettleGate g{.setpoint_c = step.setpoint_c,
                           .tolerance_c = step.tolerance_c,
                           .stability_c_per_min = step.stability_c_per_min,
                           .window_s = step.stability_window_s};
    if (auto pred = ga::predict_settle(series.t_s, series.shell_c, g, {}, series.air_c)) {
      gs::SettleForecast f;
      f.verdict = std::string(ga::to_string(pred->verdict));
      const auto from_now = [t](std::optional<double> at) -> std::optional<double> {
        if (!at) return std::nullopt;
        return std::max(0.0, *at - t);
      };
      f.p10_s = from_now(pred->p10_s);
      f.p50_s = from_now(pred->p50_s);
      f.p90_s = from_now(pred->p90_s);
      forecast = f;
    }
  }
  std::vector<double> recent = settles;
  if (recent.size() > static_cast<std::size_t>(gs::kMaxPriorSettles)) {
    recent.erase(recent.begin(), recent.end() - static_cast<std::ptrdiff_t>(gs::kMaxPriorSettles));
  }
  const gs::RunProgress p = gs::run_progress(plan, snap, gate, gs::PlannedDuration{}, forecast,
                                             gs::settle_prior(recent), std::nullopt);
  std::optional<double> indep_p10, indep_p90;
  const auto prior = gs::settle_prior(recent);
  const bool settling = p.settle.has_value() || p.phase == "settling";
  const int later = p.run_settles_remaining - (settling ? 1 : 0);
  if (p.run_eta_p10_s && prior && later > 0) {
    const double n = later;
    indep_p10 = *p.run_eta_p10_s - n * prior->p10_s + n * prior->p50_s -
                std::sqrt(n) * (prior->p50_s - prior->p10_s);
    if (p.run_eta_p90_s) {
      indep_p90 = *p.run_eta_p90_s - n * prior->p90_s + n * prior->p50_s +
                  std::sqrt(n) * (prior->p90_s - prior->p50_s);
    }
  }
  std::string why;
  if (!p.run_eta_s) {
    why = fmt::format("{}, forecast {}, prior {}", p.phase,
                      forecast ? forecast->verdict : std::string("none"),
                      p.prior_settles > 0 || gs::settle_prior(recent) ? "yes" : "no");
  }
  return {p.run_eta_p10_s, p.run_eta_s, p.run_eta_p90_s, indep_p10, indep_p90,
          p.run_eta_basis, why};
}

// One campaign on `plant` from its state now: its length (station s), or
// nullopt. `probe` (when given) is called at each of at_s (since the
// campaign's start, ascending). `settles` gains the campaign's settles.
using Probe = std::function<void(double t, const gs::Sequencer&, const SettleSeries&)>;
std::optional<double> play(const gs::Plan& plan, sim::ThermalPlant& plant,
                           std::vector<double>& settles, const std::vector<double>& at_s,
                           const Probe& probe) {
  Observer obs(settles);
  gs::Sequencer seq(plan, {}, obs);
  seq.start(0.0, plant.truth().air_c);
  SettleSeries series;
  std::size_t next = 0;
  for (double t = 1.0; t < kMaxS; t += 1.0) {
    plant.step(1.0, seq.setpoint_c());
    const double air = std::round(plant.truth().air_c * 10) / 10;
    const double top = plant.readings().top_c, side = plant.readings().side_c;
    seq.tick(t, gs::Readings{air, top, side});
    const gs::SequencerSnapshot snap = seq.snapshot(t);
    std::optional<std::size_t> settling;
    if (!seq.finished() && snap.step_index < plan.steps.size() &&
        plan.steps[snap.step_index].kind == gs::StepKind::kSoak &&
        snap.activity == gs::RunState::kSettling) {
      settling = snap.step_index;
    }
    series.add(settling, t, (top + side) / 2, air);
    while (probe && next < at_s.size() && t >= at_s[next]) probe(t, seq, series), ++next;
    if (seq.finished()) return t;
  }
  return std::nullopt;
}

struct Tally {
  int made = 0, inside = 0, early = 0, late = 0, none = 0;
  int indep_inside = 0;
  std::map<std::string, int> why_none;
  std::vector<double> error_frac;  // (P50 - truth) / truth, of the time left
  std::vector<double> error_h;     // |P50 - truth|
};

double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = 50, first = 1;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--seeds" && i + 1 < argc) {
      seeds = std::atoi(argv[++i]);
    } else if (a == "--first-seed" && i + 1 < argc) {
      first = std::atoi(argv[++i]);
    } else if (a.starts_with("--benchmark")) {
      // scripts/bench passes Google Benchmark's options to every binary
    } else {
      die("usage: gyrotherm_bench_eta [--seeds N] [--first-seed S]");
    }
  }
  const std::string path =
      std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml";
  auto plan = gs::load_schedule(path, gs::StationLimits{});
  if (!plan) die(plan.error().message);

  Tally tally[2][3];
  std::vector<double> lengths_h;
  for (int seed = first; seed < first + seeds; ++seed) {
    const sim::ThermalParams params = draw_chamber(seed);
    // Pass 1: the truth. Pass 2: the same chamber (same seed, so the same
    // noise), with the ETA taken at the fractions of each campaign's length.
    sim::ThermalPlant truth_plant(params, static_cast<uint64_t>(seed) + 1);
    std::vector<double> truth_settles;
    std::optional<double> length_s[2];
    for (int c = 0; c < 2; ++c) {
      length_s[c] = play(*plan, truth_plant, truth_settles, {}, nullptr);
      if (!length_s[c])
        die(fmt::format("seed {}: campaign {} did not end in 30 days", seed, c + 1));
      lengths_h.push_back(*length_s[c] / 3600.0);
    }
    sim::ThermalPlant plant(params, static_cast<uint64_t>(seed) + 1);
    std::vector<double> settles;
    for (int c = 0; c < 2; ++c) {
      std::vector<double> at_s;
      for (const double f : kFractions) at_s.push_back(std::ceil(f * *length_s[c]));
      int k = 0;
      const Probe probe = [&](double t, const gs::Sequencer& seq, const SettleSeries& series) {
        const Eta eta = eta_now(*plan, seq, t, settles, series);
        Tally& tl = tally[c][k++];
        const double truth = *length_s[c] - t;
        if (!eta.p50_s || !eta.p10_s) {
          ++tl.none;
          ++tl.why_none[eta.why_none.empty() ? "no band" : eta.why_none];
          return;
        }
        ++tl.made;
        const double hi = eta.p90_s.value_or(INFINITY);
        if (truth < *eta.p10_s) {
          ++tl.early;
        } else if (truth > hi) {
          ++tl.late;
        } else {
          ++tl.inside;
        }
        if (eta.indep_p10_s && truth >= *eta.indep_p10_s &&
            truth <= eta.indep_p90_s.value_or(INFINITY)) {
          ++tl.indep_inside;
        }
        tl.error_frac.push_back((*eta.p50_s - truth) / truth);
        tl.error_h.push_back(std::fabs(*eta.p50_s - truth) / 3600.0);
      };
      const auto length = play(*plan, plant, settles, at_s, probe);
      if (!length || *length != *length_s[c]) {
        die(fmt::format("seed {}: campaign {} was not reproduced", seed, c + 1));
      }
    }
  }
  fmt::print(
      "Paper campaign (32 soaks), {} seeded chambers, two campaigns each; campaign length "
      "median {:.1f} h (range {:.1f} ... {:.1f})\n\n",
      seeds, median(lengths_h), *std::min_element(lengths_h.begin(), lengths_h.end()),
      *std::max_element(lengths_h.begin(), lengths_h.end()));
  fmt::print(
      "| campaign | at | ETAs made | truth inside P10-P90 | before P10 | after P90 | median "
      "P50 error (of the time left) | median abs. P50 error | inside, later settles independent "
      "|\n");
  fmt::print("|---|---|---|---|---|---|---|---|---|\n");
  int made = 0, inside = 0;
  for (int c = 0; c < 2; ++c) {
    for (int k = 0; k < 3; ++k) {
      const Tally& t = tally[c][k];
      made += t.made;
      inside += t.inside;
      fmt::print(
          "| {} | {:.0f} % | {} of {} | {:.0f} % | {} | {} | {:+.1f} % | {:.2f} h | {:.0f} % |\n",
          c == 0 ? "first (own settles)" : "second (chamber's last 50)", 100 * kFractions[k],
          t.made, t.made + t.none, t.made ? 100.0 * t.inside / t.made : 0.0, t.early, t.late,
          100 * median(t.error_frac), median(t.error_h),
          t.made ? 100.0 * t.indep_inside / t.made : 0.0);
    }
  }
  std::map<std::string, int> why;
  for (const auto& row : tally) {
    for (const Tally& t : row) {
      for (const auto& [k, v] : t.why_none) why[k] += v;
    }
  }
  fmt::print("\nwithout an ETA:\n");
  for (const auto& [k, v] : why) fmt::print("  {:3d}  {}\n", v, k);
  fmt::print("\nsummary: {} of {} ETAs hold the true end inside P10-P90 ({:.1f} %)\n", inside, made,
             made ? 100.0 * inside / made : 0.0);
  return 0;
}
