#include "gyrotherm/schedules/sequencer.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace gyrotherm::schedules {

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

bool is_terminal(RunState state) {
  return state == RunState::kCompleted || state == RunState::kFailed ||
         state == RunState::kInterrupted;
}

Sequencer::Sequencer(Plan plan, SequencerOptions options, SequencerObserver& observer)
    : plan_(std::move(plan)),
      options_(options),
      observer_(observer),
      setpoint_c_(options.safe_setpoint_c) {}

void Sequencer::set_state(RunState to, double t_s, const std::string& reason) {
  if (to == state_) return;
  const RunState from = state_;
  state_ = to;
  observer_.on_state(from, to, t_s, reason);
}

void Sequencer::start(double t_s, double start_setpoint_c) {
  if (state_ != RunState::kQueued) return;
  setpoint_c_ = start_setpoint_c;
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
  const PlanStep& step = plan_.steps[index];
  ramp_from_c_ = setpoint_c_;
  observer_.on_step_started(index, step, t_s);
  switch (step.kind) {
    case StepKind::kSoak:
      setpoint_c_ = step.setpoint_c;
      shell_window_ = analysis::StabilityWindow(step.stability_window_s);
      chamber_window_ = analysis::StabilityWindow(step.stability_window_s);
      set_state(RunState::kSettling, t_s,
                fmt::format("{}: waiting for the shell to settle at {:g} ± {:g} °C", step.label,
                            step.setpoint_c, step.tolerance_c));
      break;
    case StepKind::kRamp:
      times_.acquire_start_s = t_s;
      observer_.on_acquisition_started(index, times_);
      set_state(RunState::kRamping, t_s,
                fmt::format("{} from {:.2f} °C", step.label, ramp_from_c_));
      break;
    case StepKind::kHold:
      setpoint_c_ = step.setpoint_c;
      set_state(RunState::kSettling, t_s,
                fmt::format("{} for {:g} min", step.label, step.hold_s / 60.0));
      break;
  }
}

void Sequencer::finish_step(double t_s, bool completed) {
  times_.end_s = t_s;
  observer_.on_step_finished(index_, plan_.steps[index_], times_, completed);
}

void Sequencer::finish_run(RunState final_state, double t_s, const std::string& reason) {
  setpoint_c_ = options_.safe_setpoint_c;
  index_ = plan_.steps.size();
  set_state(final_state, t_s, reason);
}

void Sequencer::tick(double t_s, const Readings& readings) {
  if (finished() || state_ == RunState::kQueued) return;
  const PlanStep& step = plan_.steps[index_];
  bool step_done = false;
  switch (step.kind) {
    case StepKind::kSoak:
      tick_soak(t_s, readings);
      return;  // tick_soak advances by itself
    case StepKind::kRamp: {
      const double elapsed_min = (t_s - times_.start_s) / 60.0;
      const double span = step.setpoint_c - ramp_from_c_;
      const double moved = std::min(std::abs(span), step.rate_c_per_min * elapsed_min);
      setpoint_c_ = ramp_from_c_ + std::copysign(moved, span);
      if (moved >= std::abs(span)) {
        setpoint_c_ = step.setpoint_c;
        times_.acquire_end_s = t_s;
        step_done = true;
      }
      break;
    }
    case StepKind::kHold:
      step_done = t_s - times_.start_s >= step.hold_s;
      break;
  }
  if (step_done) advance(t_s);
}

void Sequencer::advance(double t_s) {
  finish_step(t_s, true);
  if (index_ + 1 < plan_.steps.size()) {
    begin_step(index_ + 1, t_s);
  } else {
    finish_run(RunState::kCompleted, t_s, "schedule completed");
  }
}

void Sequencer::tick_soak(double t_s, const Readings& readings) {
  const PlanStep& step = plan_.steps[index_];
  if (state_ == RunState::kSettling) {
    if (readings.top_c && readings.side_c) {
      last_shell_c_ = (*readings.top_c + *readings.side_c) / 2.0;
      shell_window_.push(t_s, *last_shell_c_);
    }
    if (readings.chamber_c) chamber_window_.push(t_s, *readings.chamber_c);
    const bool gate = shell_window_.full() && chamber_window_.full() &&
                      std::abs(shell_window_.slope_per_s() * 60.0) < step.stability_c_per_min &&
                      std::abs(shell_window_.mean() - step.setpoint_c) <= step.tolerance_c &&
                      std::abs(chamber_window_.mean() - step.setpoint_c) <= step.tolerance_c;
    if (gate) {
      times_.settled_s = t_s;
      times_.acquire_start_s = t_s;
      observer_.on_acquisition_started(index_, times_);
      set_state(RunState::kAcquiring, t_s,
                fmt::format("{}: stable (shell {:.3f} °C, {:+.4f} °C/min over {:g} min); acquiring "
                            "for {:g} min",
                            step.label, shell_window_.mean(), shell_window_.slope_per_s() * 60.0,
                            step.stability_window_s / 60.0, step.acquire_s / 60.0));
    } else if (t_s - times_.start_s > step.settle_timeout_s) {
      const std::string shell =
          last_shell_c_ ? fmt::format("{:.2f} °C", *last_shell_c_) : std::string("unknown");
      finish_step(t_s, false);
      finish_run(
          RunState::kFailed, t_s,
          fmt::format("{}: not stable within {:g} min (shell at {}); chamber to the safe "
                      "set point {:g} °C",
                      step.label, step.settle_timeout_s / 60.0, shell, options_.safe_setpoint_c));
    }
    return;
  }
  if (state_ == RunState::kAcquiring && t_s - *times_.acquire_start_s >= step.acquire_s) {
    times_.acquire_end_s = *times_.acquire_start_s + step.acquire_s;
    advance(t_s);
  }
}

void Sequencer::abort(double t_s, const std::string& reason) {
  if (finished()) return;
  if (state_ != RunState::kQueued) finish_step(t_s, false);
  set_state(RunState::kAborting, t_s, reason);
  finish_run(
      RunState::kFailed, t_s,
      fmt::format("aborted; chamber to the safe set point {:g} °C", options_.safe_setpoint_c));
}

void Sequencer::interrupt(double t_s, const std::string& reason) {
  if (finished()) return;
  if (state_ != RunState::kQueued) finish_step(t_s, false);
  finish_run(RunState::kInterrupted, t_s, reason);
}

}  // namespace gyrotherm::schedules
