#include "gyrotherm/schedules/sequencer.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

namespace gyrotherm::schedules {

namespace {
constexpr RunState kAllStates[] = {
    RunState::kQueued, RunState::kRamping,     RunState::kSettling, RunState::kAcquiring,
    RunState::kPaused, RunState::kSuspended,   RunState::kAborting, RunState::kCompleted,
    RunState::kFailed, RunState::kInterrupted,
};
}  // namespace

std::string_view to_string(RunState state) {
  switch (state) {
    case RunState::kQueued:
      return "queued";
    case RunState::kRamping:
      return "ramping";
    case RunState::kSettling:
      return "settling";
    case RunState::kAcquiring:
      return "acquiring";
    case RunState::kPaused:
      return "paused";
    case RunState::kSuspended:
      return "suspended";
    case RunState::kAborting:
      return "aborting";
    case RunState::kCompleted:
      return "completed";
    case RunState::kFailed:
      return "failed";
    case RunState::kInterrupted:
      return "interrupted";
  }
  return "?";
}

std::optional<RunState> parse_run_state(std::string_view name) {
  for (RunState s : kAllStates) {
    if (to_string(s) == name) return s;
  }
  return std::nullopt;
}

bool is_terminal(RunState state) {
  return state == RunState::kCompleted || state == RunState::kFailed ||
         state == RunState::kInterrupted;
}

double StepTimes::acquired_s() const {
  double sum = 0;
  for (const auto& w : windows) sum += w.to_s - w.from_s;
  return sum;
}

bool SequencerOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  if (std::string sub_why; !interlocks.is_valid(&sub_why)) return fail("interlocks." + sub_why);
  // The safe state must not itself trip out_of_limits.
  if (!(safe_setpoint_c >= interlocks.min_temp_c && safe_setpoint_c <= interlocks.max_temp_c)) {
    return fail(fmt::format(
        "safe_setpoint_c = {} must lie within interlocks.min_temp_c = {} … max_temp_c = {}",
        safe_setpoint_c, interlocks.min_temp_c, interlocks.max_temp_c));
  }
  // The tolerance is the larger of the two: a positive dps keeps it above 0.
  if (!(at_rate_tolerance_dps > 0) || !std::isfinite(at_rate_tolerance_dps)) {
    return fail(
        fmt::format("at_rate_tolerance_dps = {} must be finite and > 0", at_rate_tolerance_dps));
  }
  if (!(at_rate_tolerance_ppm >= 0) || !std::isfinite(at_rate_tolerance_ppm)) {
    return fail(
        fmt::format("at_rate_tolerance_ppm = {} must be finite and >= 0", at_rate_tolerance_ppm));
  }
  if (!(at_rate_hold_s >= 0) || !std::isfinite(at_rate_hold_s)) {
    return fail(fmt::format("at_rate_hold_s = {} must be finite and >= 0", at_rate_hold_s));
  }
  // The hold is part of the spin-up: a timeout no longer than it fails
  // every rate step.
  if (!(spin_up_timeout_s > at_rate_hold_s) || !std::isfinite(spin_up_timeout_s)) {
    return fail(fmt::format("spin_up_timeout_s = {} must be finite and above at_rate_hold_s = {}",
                            spin_up_timeout_s, at_rate_hold_s));
  }
  return true;
}

Sequencer::Sequencer(Plan plan, SequencerOptions options, SequencerObserver& observer)
    : plan_(std::move(plan)),
      options_(options),
      observer_(observer),
      setpoint_c_(options.safe_setpoint_c) {}

bool Sequencer::hold_active() const {
  if (paused_ || restore_pending_) return true;
  return std::any_of(std::begin(tripped_), std::end(tripped_), [](bool t) { return t; });
}

bool Sequencer::held() const { return hold_active() || table_spin_up_pending_; }

RunState Sequencer::derived_state() const {
  if (end_) return *end_;
  if (restore_pending_ ||
      std::any_of(std::begin(tripped_), std::end(tripped_), [](bool t) { return t; })) {
    return RunState::kSuspended;
  }
  if (paused_) return RunState::kPaused;
  if (table_spin_up_pending_) return RunState::kSettling;
  return activity_;
}

void Sequencer::update_state(double t_s, const std::string& reason) {
  const RunState to = derived_state();
  if (to == state_) return;
  const RunState from = state_;
  state_ = to;
  observer_.on_state(from, to, t_s, reason);
}

std::optional<GateProgress> Sequencer::gate_progress(double t_s) const {
  if (end_ || state_ == RunState::kQueued || index_ >= plan_.steps.size() ||
      (activity_ != RunState::kSettling && !table_spin_up_pending_)) {
    return std::nullopt;
  }
  const PlanStep& step = plan_.steps[index_];
  if (step.kind == StepKind::kSoak && !table_spin_up_pending_) {
    const double held_s = in_tolerance_since_s_ ? std::max(0.0, t_s - *in_tolerance_since_s_) : 0.0;
    return GateProgress{std::min(held_s, step.stability_window_s), step.stability_window_s,
                        step_active_s_};
  }
  if (step.kind == StepKind::kRate || table_spin_up_pending_) {
    const double held_s = at_rate_since_s_ ? std::max(0.0, t_s - *at_rate_since_s_) : 0.0;
    return GateProgress{std::min(held_s, options_.at_rate_hold_s), options_.at_rate_hold_s,
                        spin_up_s_};
  }
  return std::nullopt;
}

std::vector<InterlockCondition> Sequencer::tripped() const {
  std::vector<InterlockCondition> out;
  for (int k = 0; k < kInterlockKindCount; ++k) {
    if (tripped_[k]) out.push_back({static_cast<InterlockKind>(k), trip_message_[k]});
  }
  return out;
}

void Sequencer::start(double t_s, double start_setpoint_c) {
  if (state_ != RunState::kQueued || end_) return;
  setpoint_c_ = start_setpoint_c;
  last_tick_s_ = t_s;
  if (plan_.steps.empty()) {
    finish_run(RunState::kCompleted, t_s, "schedule has no steps");
    return;
  }
  begin_step(0, t_s);
}

void Sequencer::begin_step(std::size_t index, double t_s) {
  index_ = index;
  times_ = StepTimes{};
  times_.start_s = t_s;
  window_open_s_.reset();
  step_active_s_ = 0;
  const PlanStep& step = plan_.steps[index];
  ramp_from_c_ = setpoint_c_;
  in_tolerance_since_s_.reset();
  table_spin_up_pending_ = false;
  observer_.on_step_started(index, step, t_s);
  switch (step.kind) {
    case StepKind::kSoak:
      setpoint_c_ = step.setpoint_c;
      shell_window_ = analysis::StabilityWindow(step.stability_window_s);
      chamber_window_ = analysis::StabilityWindow(step.stability_window_s);
      activity_ = RunState::kSettling;
      update_state(t_s, fmt::format("{}: waiting for the shell to settle at {:g} ± {:g} °C",
                                    step.label, step.setpoint_c, step.tolerance_c));
      break;
    case StepKind::kRamp:
      activity_ = RunState::kRamping;
      if (!held()) open_window(t_s);
      update_state(t_s, fmt::format("{} from {:.2f} °C", step.label, ramp_from_c_));
      break;
    case StepKind::kHold:
      setpoint_c_ = step.setpoint_c;
      activity_ = RunState::kSettling;
      update_state(t_s, fmt::format("{} for {:g} min", step.label, step.hold_s / 60.0));
      break;
    case StepKind::kRate:
      setpoint_c_ = step.setpoint_c;
      restart_spin_up();
      last_table_rate_dps_.reset();
      update_state(t_s,
                   fmt::format("{}: spinning up to {:+g} °/s", step.label, step.table.rate_dps));
      break;
  }
}

const TableDemand& Sequencer::table_demand() const {
  static const TableDemand kNoDemand{};
  if (end_ || state_ == RunState::kQueued || index_ >= plan_.steps.size()) return kNoDemand;
  return plan_.steps[index_].table;
}

void Sequencer::restart_spin_up() {
  activity_ = RunState::kSettling;
  spin_up_s_ = 0;
  at_rate_since_s_.reset();
}

void Sequencer::open_window(double t_s) {
  if (window_open_s_) return;
  window_open_s_ = t_s;
  if (!times_.acquire_start_s) times_.acquire_start_s = t_s;
  observer_.on_step_changed(index_, plan_.steps[index_], times_);
}

void Sequencer::close_window(double t_s) {
  if (!window_open_s_) return;
  if (index_ < plan_.steps.size() && plan_.steps[index_].kind == StepKind::kRate) {
    // A rate point's window covers whole turns or nothing: a window cut
    // short (a hold, an abort) is discarded, never stored, and the point
    // spins up and dwells in full again.
    window_open_s_.reset();
    if (times_.windows.empty()) times_.acquire_start_s.reset();
    restart_spin_up();
    observer_.on_step_changed(index_, plan_.steps[index_], times_);
    return;
  }
  times_.windows.push_back({*window_open_s_, std::max(t_s, *window_open_s_)});
  window_open_s_.reset();
  observer_.on_step_changed(index_, plan_.steps[index_], times_);
}

void Sequencer::finish_step(double t_s, bool completed) {
  close_window(t_s);
  if (!times_.windows.empty()) times_.acquire_end_s = times_.windows.back().to_s;
  times_.end_s = t_s;
  observer_.on_step_finished(index_, plan_.steps[index_], times_, completed);
}

void Sequencer::finish_run(RunState final_state, double t_s, const std::string& reason) {
  setpoint_c_ = options_.safe_setpoint_c;
  index_ = plan_.steps.size();
  window_open_s_.reset();
  end_ = final_state;
  update_state(t_s, reason);
}

void Sequencer::continue_after_finished_step(double t_s) {
  if (end_ || is_terminal(state_) || index_ >= plan_.steps.size()) return;
  window_open_s_.reset();
  times_.windows.clear();
  if (index_ + 1 < plan_.steps.size()) {
    begin_step(index_ + 1, t_s);
  } else {
    finish_run(RunState::kCompleted, t_s, "schedule completed");
  }
}

std::string acquiring_for(const PlanStep& step) {
  if (!step.adaptive) return fmt::format("acquiring for {:g} min", step.acquire_s / 60.0);
  return fmt::format("acquiring until the bias is known to ± {:g} °/h (U95; {:g} to {:g} min)",
                     step.adaptive->target_u95_dph, step.adaptive->min_s / 60.0,
                     step.acquire_s / 60.0);
}

void Sequencer::advance(double t_s) {
  finish_step(t_s, true);
  if (index_ + 1 < plan_.steps.size()) {
    begin_step(index_ + 1, t_s);
  } else {
    finish_run(RunState::kCompleted, t_s, "schedule completed");
  }
}

void Sequencer::trip(InterlockKind kind, double t_s, const std::string& message) {
  const int k = static_cast<int>(kind);
  trip_message_[k] = message;
  if (tripped_[k]) return;
  tripped_[k] = true;
  trip_since_s_[k] = t_s;
  const double grace_s = options_.interlocks.grace_for(kind);
  const std::string text =
      fmt::format("interlock {}: {}; holding {:.2f} °C, aborting after {:g} min", to_string(kind),
                  message, setpoint_c_, grace_s / 60.0);
  observer_.on_interlock(kind, true, t_s, text);
  close_window(t_s);
  update_state(t_s, text);
}

void Sequencer::clear(InterlockKind kind, double t_s) {
  const int k = static_cast<int>(kind);
  if (!tripped_[k]) return;
  tripped_[k] = false;
  observer_.on_interlock(
      kind, false, t_s,
      fmt::format("interlock {} cleared after {:.0f} s", to_string(kind), t_s - trip_since_s_[k]));
}

void Sequencer::evaluate(double t_s, const Readings& readings) {
  const auto conditions = evaluate_interlocks(readings, options_.interlocks, tripped_);
  bool present[kInterlockKindCount] = {};
  for (const auto& c : conditions) {
    present[static_cast<int>(c.kind)] = true;
    trip(c.kind, t_s, c.message);
  }
  for (int k = 0; k < kInterlockKindCount; ++k) {
    const auto kind = static_cast<InterlockKind>(k);
    if (tripped_[k] && !present[k] && readings_can_clear(kind, readings)) clear(kind, t_s);
  }
}

void Sequencer::on_unheld(double t_s, const Readings& readings) {
  const PlanStep& step = plan_.steps[index_];
  if (step.kind == StepKind::kRamp) {
    open_window(t_s);
    return;
  }
  if (step.kind != StepKind::kSoak || activity_ != RunState::kAcquiring) return;
  const bool have = readings.chamber_c && readings.top_c && readings.side_c;
  const double shell_c = have ? (*readings.top_c + *readings.side_c) / 2.0 : 0.0;
  const bool in_tolerance = have &&
                            std::abs(*readings.chamber_c - step.setpoint_c) <= step.tolerance_c &&
                            std::abs(shell_c - step.setpoint_c) <= step.tolerance_c;
  if (in_tolerance) {
    open_window(t_s);
    update_state(t_s, fmt::format("{}: chamber {:.2f} °C and shell {:.2f} °C within ± {:g} °C; "
                                  "acquisition goes on ({:.1f} of {:g} min done)",
                                  step.label, *readings.chamber_c, shell_c, step.tolerance_c,
                                  times_.acquired_s() / 60.0, step.acquire_s / 60.0));
    return;
  }
  // The soak was disturbed: its acquisition starts over once stable again.
  const std::string seen =
      have ? fmt::format("chamber {:.2f} °C, shell {:.2f} °C", *readings.chamber_c, shell_c)
           : std::string("no readings");
  times_.windows.clear();
  times_.settled_s.reset();
  times_.acquire_start_s.reset();
  step_active_s_ = 0;
  shell_window_.clear();
  chamber_window_.clear();
  in_tolerance_since_s_.reset();
  activity_ = RunState::kSettling;
  observer_.on_step_changed(index_, step, times_);
  update_state(t_s, fmt::format("{}: temperature out of ± {:g} °C ({}); the soak settles again and "
                                "restarts its acquisition",
                                step.label, step.tolerance_c, seen));
}

void Sequencer::tick(double t_s, const Readings& readings) {
  if (end_ || state_ == RunState::kQueued) return;
  const double dt_s = std::max(0.0, t_s - last_tick_s_);
  last_tick_s_ = t_s;
  // Time since the last tick counts for the step only if it was not held.
  const double active_dt_s = was_held_ ? 0.0 : dt_s;
  if (was_held_) {
    times_.held_s += dt_s;
  } else {
    step_active_s_ += dt_s;
  }
  // After a restart the run waits for chamber and shell readings and for the
  // gyro stream: a window opened before the first sample would hold no data.
  if (restore_pending_ && readings.chamber_c && readings.top_c && readings.side_c &&
      readings.gyro_heard) {
    restore_pending_ = false;
  }
  evaluate(t_s, readings);
  for (int k = 0; k < kInterlockKindCount; ++k) {
    if (tripped_[k] && t_s - trip_since_s_[k] >= options_.interlocks.grace_s[k]) {
      abort(t_s, fmt::format("interlock {} still tripped after {:g} min: {}",
                             to_string(static_cast<InterlockKind>(k)),
                             options_.interlocks.grace_s[k] / 60.0, trip_message_[k]));
      return;
    }
  }

  const PlanStep& step = plan_.steps[index_];
  if (step.kind != StepKind::kRate && step.table.mode == TableDemandMode::kRate) {
    if (hold_active()) {
      // The daemon stops the table while the run is held: the wait (and its
      // timeout) starts when the hold ends.
      table_spin_up_pending_ = true;
      spin_up_s_ = 0;
      at_rate_since_s_.reset();
    } else if (table_spin_up_pending_ && !tick_table_gate(t_s, dt_s, readings)) {
      return;
    }
  }
  if (step.kind == StepKind::kSoak) {
    tick_soak(t_s, readings);
    return;
  }
  if (step.kind == StepKind::kRate) {
    tick_rate(t_s, active_dt_s, readings);
    return;
  }
  if (held()) {
    if (!was_held_) close_window(t_s);
    was_held_ = true;
    update_state(t_s, "held");
    return;
  }
  if (was_held_) {
    was_held_ = false;
    on_unheld(t_s, readings);
  }
  bool done = false;
  if (step.kind == StepKind::kRamp) {
    const double span = step.setpoint_c - ramp_from_c_;
    const double moved = std::min(std::abs(span), std::abs(setpoint_c_ - ramp_from_c_) +
                                                      step.rate_c_per_min * active_dt_s / 60.0);
    const double wanted =
        std::abs(setpoint_c_ - ramp_from_c_) + step.rate_c_per_min * active_dt_s / 60.0;
    setpoint_c_ = ramp_from_c_ + std::copysign(moved, span);
    if (moved >= std::abs(span)) {
      setpoint_c_ = step.setpoint_c;
      done = true;
      // The set point's trajectory reached the target before this tick (a
      // late tick, or one tick period's quantum): the ramp's acquisition ends
      // there, so its window is span / rate of unheld time whatever the ticks.
      if (step.rate_c_per_min > 0 && window_open_s_) {
        const double late_s = (wanted - std::abs(span)) / step.rate_c_per_min * 60.0;
        close_window(std::max(*window_open_s_, t_s - late_s));
      }
    }
  } else {
    done = step_active_s_ >= step.hold_s;
  }
  update_state(t_s, fmt::format("{}: holds released, the step goes on", step.label));
  if (done) advance(t_s);
}

void Sequencer::tick_soak(double t_s, const Readings& readings) {
  const PlanStep& step = plan_.steps[index_];
  if (readings.top_c && readings.side_c) {
    last_shell_c_ = (*readings.top_c + *readings.side_c) / 2.0;
    shell_window_.push(t_s, *last_shell_c_);
  }
  if (readings.chamber_c) chamber_window_.push(t_s, *readings.chamber_c);

  if (activity_ == RunState::kSettling) {
    // The gate's progress: a tick without readings neither breaks nor extends it.
    if (readings.chamber_c && last_shell_c_ && readings.top_c && readings.side_c) {
      const bool within = std::abs(*readings.chamber_c - step.setpoint_c) <= step.tolerance_c &&
                          std::abs(*last_shell_c_ - step.setpoint_c) <= step.tolerance_c;
      if (!within) {
        in_tolerance_since_s_.reset();
      } else if (!in_tolerance_since_s_) {
        in_tolerance_since_s_ = t_s;
      }
    }
    const bool gate = shell_window_.full() && chamber_window_.full() &&
                      std::abs(shell_window_.slope_per_s() * 60.0) < step.stability_c_per_min &&
                      std::abs(shell_window_.mean() - step.setpoint_c) <= step.tolerance_c &&
                      std::abs(chamber_window_.mean() - step.setpoint_c) <= step.tolerance_c;
    if (gate) clear(InterlockKind::kSettleTimeout, t_s);
    if (gate && !held()) {
      was_held_ = false;
      if (!times_.settled_s) times_.settled_s = t_s;
      activity_ = RunState::kAcquiring;
      open_window(t_s);
      update_state(t_s,
                   fmt::format("{}: stable (shell {:.3f} °C, {:+.4f} °C/min over {:g} min); "
                               "{}",
                               step.label, shell_window_.mean(), shell_window_.slope_per_s() * 60.0,
                               step.stability_window_s / 60.0, acquiring_for(step)));
      return;
    }
    if (!gate && step_active_s_ > step.settle_timeout_s &&
        !tripped_[static_cast<int>(InterlockKind::kSettleTimeout)]) {
      const std::string shell =
          last_shell_c_ ? fmt::format("{:.2f} °C", *last_shell_c_) : std::string("unknown");
      trip(InterlockKind::kSettleTimeout, t_s,
           fmt::format("{}: not stable at {:g} ± {:g} °C within {:g} min (shell at {})", step.label,
                       step.setpoint_c, step.tolerance_c, step.settle_timeout_s / 60.0, shell));
    }
    was_held_ = held();
    update_state(t_s, fmt::format("{}: holds released; settling goes on", step.label));
    return;
  }

  // Acquiring.
  if (held()) {
    if (!was_held_) close_window(t_s);
    was_held_ = true;
    update_state(t_s, "held");
    return;
  }
  if (was_held_) {
    was_held_ = false;
    on_unheld(t_s, readings);
    if (activity_ != RunState::kAcquiring) return;
  }
  // Credited: the time the DUTs' samples cover when the daemon accounts for
  // data (a silent line, a stall, lost frames are not credited), else the
  // clock's.
  double closed_s = times_.acquired_s();
  double acquired_s = closed_s + (window_open_s_ ? t_s - *window_open_s_ : 0.0);
  if (readings.data_covered_s && readings.data_reached_at_s) {
    closed_s = 0;
    for (const auto& w : times_.windows) closed_s += readings.data_covered_s(w.from_s, w.to_s);
    acquired_s = closed_s + (window_open_s_ ? readings.data_covered_s(*window_open_s_, t_s) : 0.0);
  }
  if (step.adaptive && readings.acquisition_done && window_open_s_ &&
      acquired_s >= step.adaptive->min_s && acquired_s < step.acquire_s) {
    // An adaptive soak whose mean is known to its target (or cannot be):
    // the station's verdict on the data so far ends it here.
    times_.acquire_stop = *readings.acquisition_done;
    close_window(t_s);
    advance(t_s);
    return;
  }
  if (acquired_s >= step.acquire_s && window_open_s_) {
    if (step.adaptive) {
      times_.acquire_stop =
          fmt::format("cap: max_min {:g} min acquired before the target {:g} °/h was reached",
                      step.acquire_s / 60.0, step.adaptive->target_u95_dph);
    }
    // The window ends when the acquisition time is complete (ticks are coarse).
    double end_s = *window_open_s_ + (step.acquire_s - closed_s);
    if (readings.data_reached_at_s) {
      if (auto at = readings.data_reached_at_s(*window_open_s_, step.acquire_s - closed_s)) {
        end_s = std::min(*at, t_s);
      }
    }
    close_window(end_s);
    advance(t_s);
  }
}

void Sequencer::tick_rate(double t_s, double active_dt_s, const Readings& readings) {
  const PlanStep& step = plan_.steps[index_];
  const double demand_dps = step.table.rate_dps;
  if (readings.table_rate_dps) last_table_rate_dps_ = readings.table_rate_dps;
  if (held()) {
    if (!was_held_) close_window(t_s);  // discards a partial dwell
    restart_spin_up();
    was_held_ = true;
    update_state(t_s, "held");
    return;
  }
  if (was_held_) {
    was_held_ = false;
    update_state(t_s, fmt::format("{}: holds released; spinning up to {:+g} °/s again, the dwell "
                                  "starts over ({} turns, {:g} s)",
                                  step.label, demand_dps, step.turns, step.dwell_s));
  }

  if (activity_ == RunState::kSettling) {
    spin_up_s_ += active_dt_s;
    const double tolerance_dps = at_rate_tolerance_dps(demand_dps);
    const bool at_rate =
        readings.table_rate_dps && std::abs(*readings.table_rate_dps - demand_dps) <= tolerance_dps;
    if (!at_rate) {
      at_rate_since_s_.reset();
    } else if (!at_rate_since_s_) {
      at_rate_since_s_ = t_s;
    }
    if (at_rate && t_s - *at_rate_since_s_ >= options_.at_rate_hold_s) {
      if (!times_.settled_s) times_.settled_s = t_s;
      activity_ = RunState::kAcquiring;
      open_window(t_s);
      update_state(t_s, fmt::format("{}: at {:+g} °/s (measured {:+.4f} °/s for {:g} s); "
                                    "acquiring {} turn{} over {:g} s",
                                    step.label, demand_dps, *readings.table_rate_dps,
                                    options_.at_rate_hold_s, step.turns, step.turns == 1 ? "" : "s",
                                    step.dwell_s));
      return;
    }
    if (spin_up_s_ > options_.spin_up_timeout_s) {
      const std::string measured = last_table_rate_dps_
                                       ? fmt::format("{:+.4f} °/s", *last_table_rate_dps_)
                                       : std::string("no table reading");
      abort(t_s, fmt::format("{}: the table did not reach {:+g} °/s (± {:g} °/s for {:g} s) "
                             "within {:g} s; last measured {}",
                             step.label, demand_dps, tolerance_dps, options_.at_rate_hold_s,
                             options_.spin_up_timeout_s, measured));
      return;
    }
    update_state(t_s, fmt::format("{}: spinning up to {:+g} °/s", step.label, demand_dps));
    return;
  }

  // Acquiring: the window ends after exactly dwell_s (ticks are coarse).
  if (window_open_s_ && t_s - *window_open_s_ >= step.dwell_s) {
    times_.windows.push_back({*window_open_s_, *window_open_s_ + step.dwell_s});
    window_open_s_.reset();
    observer_.on_step_changed(index_, step, times_);
    advance(t_s);
  }
}

bool Sequencer::tick_table_gate(double t_s, double dt_s, const Readings& readings) {
  const PlanStep& step = plan_.steps[index_];
  const double demand_dps = step.table.rate_dps;
  if (readings.table_rate_dps) last_table_rate_dps_ = readings.table_rate_dps;
  spin_up_s_ += dt_s;
  const double tolerance_dps = at_rate_tolerance_dps(demand_dps);
  const bool at_rate =
      readings.table_rate_dps && std::abs(*readings.table_rate_dps - demand_dps) <= tolerance_dps;
  if (!at_rate) {
    at_rate_since_s_.reset();
  } else if (!at_rate_since_s_) {
    at_rate_since_s_ = t_s;
  }
  if (at_rate && t_s - *at_rate_since_s_ >= options_.at_rate_hold_s) {
    // The step goes on at this tick (its window reopens as after any hold).
    table_spin_up_pending_ = false;
    at_rate_since_s_.reset();
    return true;
  }
  if (spin_up_s_ > options_.spin_up_timeout_s) {
    const std::string measured = last_table_rate_dps_
                                     ? fmt::format("{:+.4f} °/s", *last_table_rate_dps_)
                                     : std::string("no table reading");
    abort(t_s, fmt::format("{}: the table did not get back to {:+g} °/s (± {:g} °/s for {:g} s) "
                           "within {:g} s; last measured {}",
                           step.label, demand_dps, tolerance_dps, options_.at_rate_hold_s,
                           options_.spin_up_timeout_s, measured));
    return false;
  }
  update_state(t_s, fmt::format("{}: spinning the table up to {:+g} °/s again; acquisition "
                                "waits for the rate",
                                step.label, demand_dps));
  return true;
}

void Sequencer::table_interrupted(double t_s, const std::string& reason) {
  if (end_ || state_ == RunState::kQueued || index_ >= plan_.steps.size()) return;
  const PlanStep& step = plan_.steps[index_];
  if (step.table.mode != TableDemandMode::kRate) return;
  if (step.kind == StepKind::kRate) {
    close_window(t_s);  // discards a partial dwell
    restart_spin_up();
    update_state(t_s, fmt::format("{}: {}; spinning up to {:+g} °/s again, the dwell starts over",
                                  step.label, reason, step.table.rate_dps));
    return;
  }
  close_window(t_s);
  was_held_ = true;  // the window reopens as after a hold
  if (!table_spin_up_pending_) {
    table_spin_up_pending_ = true;
    spin_up_s_ = 0;
    at_rate_since_s_.reset();
  }
  update_state(t_s, fmt::format("{}: {}; acquisition waits for the table at {:+g} °/s again",
                                step.label, reason, step.table.rate_dps));
}

Status Sequencer::pause(double t_s, const std::string& reason) {
  if (end_ || state_ == RunState::kQueued) return Error::Permanent("no run in progress to pause");
  if (paused_) return Error::Permanent("the run is already paused");
  paused_ = true;
  const bool rate_dwell = window_open_s_ && plan_.steps[index_].kind == StepKind::kRate;
  close_window(t_s);
  was_held_ = true;
  update_state(t_s, fmt::format("paused ({}); holding {:.2f} °C, acquisition clock stopped{}",
                                reason, setpoint_c_,
                                rate_dwell ? "; the rate point's partial dwell is discarded" : ""));
  return Status::Ok();
}

Status Sequencer::resume(double t_s, const std::string& reason) {
  if (end_ || state_ == RunState::kQueued) return Error::Permanent("no run in progress to resume");
  if (!paused_) return Error::Permanent("the run is not paused");
  paused_ = false;
  // The window reopens (or the soak restarts) at the next tick, with readings.
  const PlanStep& step = plan_.steps[index_];
  std::string what = fmt::format("resumed ({})", reason);
  if (step.kind == StepKind::kRate) {
    what += fmt::format("; {}: spinning up to {:+g} °/s, the dwell starts over", step.label,
                        step.table.rate_dps);
  } else if (table_spin_up_pending_ && !hold_active()) {
    what += fmt::format(
        "; {}: spinning the table up to {:+g} °/s again; acquisition waits for "
        "the rate",
        step.label, step.table.rate_dps);
  }
  update_state(t_s, what);
  return Status::Ok();
}

void Sequencer::abort(double t_s, const std::string& reason) {
  if (end_) return;
  if (state_ != RunState::kQueued) finish_step(t_s, false);
  setpoint_c_ = options_.safe_setpoint_c;
  index_ = plan_.steps.size();
  end_ = RunState::kAborting;
  update_state(t_s, fmt::format("{}; chamber to the safe set point {:g} °C", reason,
                                options_.safe_setpoint_c));
}

void Sequencer::safe_state_reached(double t_s) {
  if (end_ != RunState::kAborting) return;
  finish_run(RunState::kFailed, t_s,
             fmt::format("aborted; safe set point {:g} °C commanded", options_.safe_setpoint_c));
}

void Sequencer::interrupt(double t_s, const std::string& reason) {
  if (end_ && *end_ != RunState::kAborting) return;
  if (end_ == RunState::kAborting) {
    finish_run(RunState::kFailed, t_s, "aborted; " + reason);
    return;
  }
  if (state_ != RunState::kQueued && index_ < plan_.steps.size()) close_window(t_s);
  end_ = RunState::kInterrupted;
  update_state(t_s, reason);
}

SequencerSnapshot Sequencer::snapshot(double t_s) const {
  SequencerSnapshot s;
  s.t_s = t_s;
  s.state = state_;
  s.activity = activity_;
  s.step_index = index_;
  s.times = times_;
  s.window_open_s = window_open_s_;
  s.step_active_s = step_active_s_;
  s.setpoint_c = setpoint_c_;
  s.ramp_from_c = ramp_from_c_;
  s.paused = paused_;
  for (int k = 0; k < kInterlockKindCount; ++k) {
    if (tripped_[k]) {
      s.trips.push_back({static_cast<InterlockKind>(k), trip_since_s_[k], trip_message_[k]});
    }
  }
  return s;
}

void Sequencer::restore(const SequencerSnapshot& s, double t_s, double data_until_s,
                        const std::string& reason) {
  state_ = s.state;
  last_tick_s_ = t_s;
  if (s.state == RunState::kAborting) {
    // Died while going safe: finish going safe.
    setpoint_c_ = options_.safe_setpoint_c;
    index_ = plan_.steps.size();
    end_ = RunState::kAborting;
    return;
  }
  if (s.step_index >= plan_.steps.size()) {
    finish_run(RunState::kFailed, t_s,
               fmt::format("cannot resume: step {} is not in the schedule", s.step_index + 1));
    return;
  }
  index_ = s.step_index;
  times_ = s.times;
  activity_ = s.activity;
  setpoint_c_ = s.setpoint_c;
  ramp_from_c_ = s.ramp_from_c;
  paused_ = s.paused;
  step_active_s_ = s.step_active_s;
  end_.reset();
  const PlanStep& step = plan_.steps[index_];
  shell_window_ = analysis::StabilityWindow(step.stability_window_s);
  chamber_window_ = analysis::StabilityWindow(step.stability_window_s);
  in_tolerance_since_s_.reset();
  if (step.kind == StepKind::kRate) {
    // A rate point in progress starts over: it spins up again and dwells
    // its whole turns (a partial window is never stored).
    times_.windows.clear();
    times_.acquire_start_s.reset();
    restart_spin_up();
    last_table_rate_dps_.reset();
  } else if (s.window_open_s) {
    // The window that was open when the snapshot was taken ends there, and no
    // window reaches past the last committed sample: the samples after it died
    // with the daemon, so that time is not credited (the soak acquires it again).
    times_.windows.push_back({*s.window_open_s, std::max(s.t_s, *s.window_open_s)});
  }
  std::vector<AcquisitionWindow> covered;
  for (AcquisitionWindow w : times_.windows) {
    if (w.from_s >= data_until_s) continue;
    w.to_s = std::min(w.to_s, data_until_s);
    covered.push_back(w);
  }
  times_.windows = std::move(covered);
  if (times_.windows.empty()) times_.acquire_start_s.reset();
  // Tripped interlocks come back with their trip times (already reported).
  std::fill(std::begin(tripped_), std::end(tripped_), false);
  for (const InterlockTrip& trip : s.trips) {
    const int k = static_cast<int>(trip.kind);
    tripped_[k] = true;
    trip_since_s_[k] = trip.since_s;
    trip_message_[k] = trip.message;
  }
  const double down_s = std::max(0.0, t_s - s.t_s);
  if (step.kind == StepKind::kRamp || step.kind == StepKind::kRate || paused_) {
    times_.held_s += down_s;
  } else {
    step_active_s_ += down_s;
  }
  restore_pending_ = true;
  was_held_ = true;
  observer_.on_step_changed(index_, step, times_);
  update_state(t_s, reason);
}

// ---------------------------------------------------------------- snapshot JSON

nlohmann::json to_json(const SequencerSnapshot& s) {
  nlohmann::json windows = nlohmann::json::array();
  for (const auto& w : s.times.windows) windows.push_back({w.from_s, w.to_s});
  auto opt = [](const std::optional<double>& v) {
    return v ? nlohmann::json(*v) : nlohmann::json(nullptr);
  };
  nlohmann::json trips = nlohmann::json::array();
  for (const auto& t : s.trips) {
    trips.push_back({{"kind", to_string(t.kind)}, {"since_s", t.since_s}, {"message", t.message}});
  }
  return {{"t_s", s.t_s},
          {"state", to_string(s.state)},
          {"activity", to_string(s.activity)},
          {"step_index", s.step_index},
          {"start_s", s.times.start_s},
          {"settled_s", opt(s.times.settled_s)},
          {"acquire_start_s", opt(s.times.acquire_start_s)},
          {"acquire_stop", s.times.acquire_stop},
          {"held_s", s.times.held_s},
          {"windows", windows},
          {"window_open_s", opt(s.window_open_s)},
          {"step_active_s", s.step_active_s},
          {"setpoint_c", s.setpoint_c},
          {"ramp_from_c", s.ramp_from_c},
          {"paused", s.paused},
          {"trips", trips}};
}

Result<SequencerSnapshot> snapshot_from_json(const nlohmann::json& j) {
  try {
    SequencerSnapshot s;
    auto opt = [&](const char* key) -> std::optional<double> {
      const auto& v = j.at(key);
      if (v.is_null()) return std::nullopt;
      return v.get<double>();
    };
    s.t_s = j.at("t_s").get<double>();
    auto state = parse_run_state(j.at("state").get<std::string>());
    auto activity = parse_run_state(j.at("activity").get<std::string>());
    if (!state || !activity) return Error::Permanent("run snapshot: unknown state");
    s.state = *state;
    s.activity = *activity;
    s.step_index = j.at("step_index").get<std::size_t>();
    s.times.start_s = j.at("start_s").get<double>();
    s.times.settled_s = opt("settled_s");
    s.times.acquire_start_s = opt("acquire_start_s");
    // Checkpoints from before adaptive soaks have none.
    s.times.acquire_stop = j.value("acquire_stop", std::string{});
    s.times.held_s = j.at("held_s").get<double>();
    for (const auto& w : j.at("windows")) {
      s.times.windows.push_back({w.at(0).get<double>(), w.at(1).get<double>()});
    }
    s.window_open_s = opt("window_open_s");
    s.step_active_s = j.at("step_active_s").get<double>();
    s.setpoint_c = j.at("setpoint_c").get<double>();
    s.ramp_from_c = j.at("ramp_from_c").get<double>();
    s.paused = j.at("paused").get<bool>();
    // Checkpoints written before trips were kept have none.
    if (auto it = j.find("trips"); it != j.end()) {
      for (const auto& t : *it) {
        const auto name = t.at("kind").get<std::string>();
        const auto kind = parse_interlock_kind(name);
        if (!kind) {
          return Error::Permanent(fmt::format("run snapshot: unknown interlock '{}'", name));
        }
        s.trips.push_back(
            {*kind, t.at("since_s").get<double>(), t.at("message").get<std::string>()});
      }
    }
    return s;
  } catch (const nlohmann::json::exception& e) {
    return Error::Permanent(fmt::format("run snapshot: {}", e.what()));
  }
}

}  // namespace gyrotherm::schedules
