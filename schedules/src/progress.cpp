#include "gyrotherm/schedules/progress.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <set>

namespace gyrotherm::schedules {

double step_table_rate_dps(const PlanStep& step) {
  return step.table.mode == TableDemandMode::kRate ? step.table.rate_dps : 0.0;
}

namespace {

double ramp_s(const PlanStep& step, double from_setpoint_c) {
  if (!(step.rate_c_per_min > 0)) return 0;
  return std::abs(step.setpoint_c - from_setpoint_c) / step.rate_c_per_min * 60.0;
}

double spin_up_s(const PlanStep& step, double from_rate_dps, double table_accel_dps2) {
  if (!(table_accel_dps2 > 0)) return 0;
  return std::abs(step_table_rate_dps(step) - from_rate_dps) / table_accel_dps2;
}

double clamp01(double x) { return std::clamp(x, 0.0, 1.0); }

}  // namespace

double step_fixed_s(const PlanStep& step, double from_setpoint_c, double from_rate_dps,
                    double table_accel_dps2) {
  switch (step.kind) {
    case StepKind::kSoak:
      return step.acquire_s;
    case StepKind::kRamp:
      return ramp_s(step, from_setpoint_c);
    case StepKind::kHold:
      return step.hold_s;
    case StepKind::kRate:
      return spin_up_s(step, from_rate_dps, table_accel_dps2) + step.dwell_s;
  }
  return 0;
}

bool step_settles(const PlanStep& step) { return step.kind == StepKind::kSoak; }

namespace {

// Steps [first, end) entered with the set point and table rate given.
PlannedDuration planned_range(const Plan& plan, std::size_t first, double setpoint_c,
                              double rate_dps) {
  PlannedDuration d;
  for (std::size_t i = first; i < plan.steps.size(); ++i) {
    const PlanStep& s = plan.steps[i];
    d.fixed_s += step_fixed_s(s, setpoint_c, rate_dps, plan.table_accel_dps2);
    if (step_settles(s)) ++d.settles;
    setpoint_c = s.setpoint_c;
    rate_dps = step_table_rate_dps(s);
  }
  return d;
}

}  // namespace

PlannedDuration planned_duration(const Plan& plan, double start_setpoint_c) {
  return planned_range(plan, 0, start_setpoint_c, 0.0);
}

PlannedDuration planned_duration_after(const Plan& plan, std::size_t index) {
  if (index >= plan.steps.size()) return {};
  const PlanStep& s = plan.steps[index];
  return planned_range(plan, index + 1, s.setpoint_c, step_table_rate_dps(s));
}

std::string format_duration(double s) {
  if (!std::isfinite(s) || s < 0) s = 0;
  constexpr double kMin = 60, kHour = 3600, kDay = 86400;
  if (s >= kDay) {
    const auto hours = static_cast<int64_t>(std::llround(s / kHour));
    const int64_t d = hours / 24, h = hours % 24;
    return h ? fmt::format("{} d {} h", d, h) : fmt::format("{} d", d);
  }
  if (s >= kHour) {
    const auto mins = static_cast<int64_t>(std::llround(s / kMin));
    const int64_t h = mins / 60, m = mins % 60;
    if (h >= 24) return "1 d";
    return m ? fmt::format("{} h {} min", h, m) : fmt::format("{} h", h);
  }
  if (s >= kMin) {
    const auto secs = static_cast<int64_t>(std::llround(s));
    const int64_t m = secs / 60, sec = secs % 60;
    if (m >= 60) return "1 h";
    return sec ? fmt::format("{} min {} s", m, sec) : fmt::format("{} min", m);
  }
  const auto secs = static_cast<int64_t>(std::llround(s));
  return secs >= 60 ? "1 min" : fmt::format("{} s", secs);
}

std::string format_planned(const PlannedDuration& d) {
  if (d.settles == 0) return format_duration(d.fixed_s);
  return fmt::format("{} (+ {} settle{} of unknown length)", format_duration(d.fixed_s), d.settles,
                     d.settles == 1 ? "" : "s");
}

std::optional<SettlePrior> settle_prior(std::vector<double> settles_s) {
  std::erase_if(settles_s, [](double s) { return !std::isfinite(s) || s < 0; });
  if (settles_s.size() < static_cast<std::size_t>(kMinPriorSettles)) return std::nullopt;
  std::sort(settles_s.begin(), settles_s.end());
  const auto quantile = [&](double q) {
    const double pos = q * static_cast<double>(settles_s.size() - 1);
    const auto lo = static_cast<std::size_t>(std::floor(pos));
    const std::size_t hi = std::min(lo + 1, settles_s.size() - 1);
    return settles_s[lo] + (pos - static_cast<double>(lo)) * (settles_s[hi] - settles_s[lo]);
  };
  return SettlePrior{static_cast<int>(settles_s.size()), quantile(0.1), quantile(0.5),
                     quantile(0.9)};
}

namespace {

// The settles' part of an ETA, station s: P10, P50 and P90 (nullopt: beyond
// the forecast's horizon).
struct SettleBand {
  double p10_s = 0, p50_s = 0;
  std::optional<double> p90_s = 0.0;

  void add(double p10, double p50, std::optional<double> p90) {
    p10_s += p10;
    p50_s += p50;
    p90_s = p90_s && p90 ? std::optional<double>(*p90_s + *p90) : std::nullopt;
  }
};

void set_queue_eta(RunProgress& p, const PlannedDuration& queue,
                   const std::optional<SettlePrior>& prior) {
  p.queue_fixed_s = queue.fixed_s;
  p.queue_settles = queue.settles;
  if (queue.settles == 0) {
    p.queue_eta_s = p.queue_eta_p10_s = p.queue_eta_p90_s = queue.fixed_s;
  } else if (prior) {
    p.queue_eta_s = queue.fixed_s + queue.settles * prior->p50_s;
    p.queue_eta_p10_s = queue.fixed_s + queue.settles * prior->p10_s;
    p.queue_eta_p90_s = queue.fixed_s + queue.settles * prior->p90_s;
  }
}

// The run's ETA from its fixed time, the current settle's part (`current`:
// nullopt when unknown; none when no soak settles) and `later` settles
// from the prior.
void set_run_eta(RunProgress& p, bool settling, const std::optional<SettleBand>& current,
                 bool current_forecast, int later, const std::optional<SettlePrior>& prior) {
  if (settling && !current) return;
  if (later > 0 && !prior) return;
  SettleBand band;
  if (settling) band.add(current->p10_s, current->p50_s, current->p90_s);
  if (later > 0) band.add(later * prior->p10_s, later * prior->p50_s, later * prior->p90_s);
  const bool uses_prior = later > 0 || (settling && !current_forecast);
  const double fixed = p.run_remaining_fixed_s;
  p.run_eta_s = fixed + band.p50_s;
  if (settling || later > 0) {
    p.run_eta_p10_s = fixed + band.p10_s;
    if (band.p90_s) p.run_eta_p90_s = fixed + *band.p90_s;
  }
  p.run_eta_basis = !settling && later == 0        ? "fixed"
                    : current_forecast && settling ? (uses_prior ? "forecast+prior" : "forecast")
                                                   : "prior";
  if (uses_prior) p.prior_settles = prior->settles;
}

}  // namespace

RunProgress queue_progress(const PlannedDuration& queue, const std::optional<SettlePrior>& prior) {
  RunProgress p;
  set_queue_eta(p, queue, prior);
  return p;
}

RunProgress run_progress(const Plan& plan, const SequencerSnapshot& snap,
                         const std::optional<GateProgress>& gate, const PlannedDuration& queue,
                         const std::optional<SettleForecast>& settle,
                         const std::optional<SettlePrior>& prior,
                         const std::optional<AcquireForecast>& acquire) {
  RunProgress p;
  set_queue_eta(p, queue, prior);
  const std::size_t index = snap.step_index;
  if (snap.state == RunState::kQueued) {
    // Not started: the whole plan lies ahead (from where the set point is).
    const PlannedDuration all = planned_duration(plan, snap.setpoint_c);
    p.phase = "queued";
    p.run_remaining_fixed_s = all.fixed_s;
    p.run_settles_remaining = all.settles;
    set_run_eta(p, false, std::nullopt, false, all.settles, prior);
    return p;
  }
  if (index >= plan.steps.size() || snap.state == RunState::kAborting || is_terminal(snap.state)) {
    p.phase = std::string(to_string(snap.state));
    p.run_eta_s = 0;
    p.run_eta_basis = "fixed";
    return p;
  }

  const PlanStep& step = plan.steps[index];
  const double rate_before_dps = index > 0 ? step_table_rate_dps(plan.steps[index - 1]) : 0.0;
  const double acquired_s =
      snap.times.acquired_s() + (snap.window_open_s ? snap.t_s - *snap.window_open_s : 0.0);
  bool settling = false;   // a settle of unknown length is under way
  double step_left_s = 0;  // the current step's remaining fixed time
  switch (step.kind) {
    case StepKind::kSoak: {
      p.step_planned_s = step.acquire_s;
      if (snap.activity == RunState::kSettling) {
        settling = true;
        p.phase = "settling";
        p.step_elapsed_s = snap.step_active_s;
        step_left_s = step.acquire_s;
      } else {
        p.phase = "acquiring";
        // An adaptive soak: its projected length once its axes are judged
        // (the cap until then, and when an axis has no projection).
        double planned_s = step.acquire_s;
        if (step.adaptive && acquire) {
          p.acquire = acquire;
          if (acquire->planned_s) {
            planned_s = std::clamp(*acquire->planned_s, step.adaptive->min_s, step.acquire_s);
            planned_s = std::max(planned_s, std::min(acquired_s, step.acquire_s));
          }
          p.step_planned_s = planned_s;
        }
        p.step_elapsed_s = std::min(acquired_s, planned_s);
        p.step_fraction = planned_s > 0 ? clamp01(acquired_s / planned_s) : 1.0;
        step_left_s = std::max(0.0, planned_s - acquired_s);
      }
      break;
    }
    case StepKind::kRamp: {
      p.phase = "ramping";
      const double span_c = std::abs(step.setpoint_c - snap.ramp_from_c);
      const double moved_c = std::min(span_c, std::abs(snap.setpoint_c - snap.ramp_from_c));
      const double planned_s = ramp_s(step, snap.ramp_from_c);
      const double fraction = span_c > 0 ? clamp01(moved_c / span_c) : 1.0;
      p.step_planned_s = planned_s;
      p.step_elapsed_s = planned_s * fraction;
      p.step_fraction = fraction;
      step_left_s = planned_s - planned_s * fraction;
      break;
    }
    case StepKind::kHold: {
      p.phase = "holding";
      p.step_planned_s = step.hold_s;
      p.step_elapsed_s = std::min(snap.step_active_s, step.hold_s);
      p.step_fraction = step.hold_s > 0 ? clamp01(snap.step_active_s / step.hold_s) : 1.0;
      step_left_s = std::max(0.0, step.hold_s - snap.step_active_s);
      break;
    }
    case StepKind::kRate: {
      // The spin-up is estimated from the table's acceleration: it counts as
      // fixed time, and its gate (at rate for at_rate_hold_s) is shown too.
      const double spin_s = spin_up_s(step, rate_before_dps, plan.table_accel_dps2);
      const double planned_s = spin_s + step.dwell_s;
      p.step_planned_s = planned_s;
      double elapsed_s = 0;
      if (snap.activity == RunState::kSettling) {
        p.phase = "spinning_up";
        elapsed_s = std::min(gate ? gate->waited_s : 0.0, spin_s);
      } else {
        p.phase = "acquiring";
        elapsed_s = spin_s + std::min(acquired_s, step.dwell_s);
      }
      p.step_elapsed_s = elapsed_s;
      p.step_fraction = planned_s > 0 ? clamp01(elapsed_s / planned_s) : 1.0;
      step_left_s = std::max(0.0, planned_s - elapsed_s);
      break;
    }
  }
  if (gate) {
    p.gate_held_s = gate->held_s;
    p.gate_needed_s = gate->needed_s;
  }
  const PlannedDuration after = planned_duration_after(plan, index);
  p.run_remaining_fixed_s = step_left_s + after.fixed_s;
  p.run_settles_remaining = after.settles + (settling ? 1 : 0);
  // The current settle: its forecast when it has a P50; else the prior less
  // what it has settled: before the first forecast, early in the rise, and
  // when the forecast has no P50 (beyond its horizon, or a final value it
  // puts outside the tolerance: on 50 seeded chambers running the paper's
  // campaign, bench/campaign_eta_bench.cpp, such forecasts came before
  // settles that all ended, and left the station without an ETA for half
  // the first campaign). The forecast's own verdict stays in `settle`.
  std::optional<SettleBand> current;
  bool current_forecast = false;
  if (settling) {
    if (settle) p.settle = settle;
    if (settle && settle->p50_s) {
      current = SettleBand{settle->p10_s.value_or(*settle->p50_s), *settle->p50_s, settle->p90_s};
      current_forecast = true;
    } else if (prior) {
      const double done_s = snap.step_active_s;
      current =
          SettleBand{std::max(0.0, prior->p10_s - done_s), std::max(0.0, prior->p50_s - done_s),
                     std::max(0.0, prior->p90_s - done_s)};
    }
  }
  set_run_eta(p, settling, current, current_forecast, after.settles, prior);
  return p;
}

PlannedDuration QueueDurations::update(const std::vector<Entry>& entries,
                                       const StationLimits& limits, double start_setpoint_c) {
  PlannedDuration total;
  std::set<int64_t> seen;
  for (const Entry& e : entries) {
    seen.insert(e.id);
    auto it = cache_.find(e.id);
    if (it == cache_.end()) {
      ++parses_;
      auto plan = parse_schedule(e.toml_text, std::string(e.source), limits);
      it =
          cache_.emplace(e.id, plan ? planned_duration(*plan, start_setpoint_c) : PlannedDuration{})
              .first;
    }
    total += it->second;
  }
  std::erase_if(cache_, [&](const auto& kv) { return !seen.count(kv.first); });
  return total;
}

}  // namespace gyrotherm::schedules
