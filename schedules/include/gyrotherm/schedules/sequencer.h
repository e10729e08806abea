// The run state machine (docs/architecture.md, "The run state machine";
// the soak stability gate and the step types: docs/schedules.md).
//
// A Sequencer executes one Plan. It owns no I/O and no clock: the daemon
// calls tick() with the station time (seconds since run start) and the
// latest readings; the Sequencer decides the set point to command, when
// acquisition windows open and close, and reports every transition to its
// observer (which writes event rows). Tests drive it with synthetic readings
// and run whole campaigns in virtual time without sleeping.
//
// The state a run shows is derived from three things kept apart:
//   - the step's activity: settling or acquiring (soak), ramping (ramp),
//     settling (hold);
//   - holds: an operator pause, tripped interlocks (interlocks.h), or a
//     restart that waits for its first readings. While held the set point
//     stays where it is and no step clock runs: a soak's acquisition clock
//     and settle timeout, a ramp's set point, a hold's duration all stop;
//   - the end: aborting (until the daemon has commanded the safe set point),
//     completed, failed, interrupted.
// State = end if any, else suspended if an interlock is tripped or a restart
// is pending, else paused if paused, else the activity.
//
// Soak: the stability gate holds when, over the step's stability window, the
// shell temperature ((top + side) / 2) changes slower than
// stability_c_per_min (least-squares slope) and the window means of both
// shell and chamber air are within tolerance of the set point. Only then
// does acquisition start. When the gate has not held within settle_timeout
// (not counting held time) the settle-timeout interlock trips; it clears
// when the gate holds. Acquisition is a list of windows: a hold closes the
// current one; when the hold ends with chamber and shell still within
// tolerance a new window opens and the soak keeps the time it had,
// otherwise the soak goes back to settling and its acquisition starts over.
// Ramp: the set point moves from where the previous step left it to the
// target at the step's rate; the whole ramp (minus holds) is acquisition.
// Hold: the set point is held for the step's duration, no acquisition.
// Rate point (kRate, from a scale_factor step): the set point is held and the
// step is settling ("spinning up") until the measured table rate has been
// within at_rate_tolerance_dps of the demand for at_rate_hold_s; then one
// acquisition window of exactly dwell_s (whole turns) of unheld time. A hold
// during the dwell discards the partial window (a window covers whole turns)
// and, once released, the point spins up and dwells in full again. Not at
// rate within spin_up_timeout_s of unheld time aborts the run. A restore
// restarts a rate point in progress the same way.
// Every step carries a table demand (table_demand()): the daemon commands the
// table from it when a step starts (on_step_started) and stops the table when
// the run ends. A soak, ramp or hold turning the table does not wait for it
// when the step starts, but after a hold (the daemon stops the table while
// the run is held) or when the controller took the table off its demand
// (table_interrupted()) it does: the step stays held, shown settling, until
// the table has been at rate for at_rate_hold_s (spin_up_timeout_s of
// unheld time at most, else the run aborts).
// After the last step, and on failure or abort, the safe set point is
// commanded.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/analysis/stability.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/schedules/interlocks.h"
#include "gyrotherm/schedules/schedule.h"

namespace gyrotherm::schedules {

enum class RunState {
  kQueued,
  kRamping,
  kSettling,
  kAcquiring,
  kPaused,
  kSuspended,
  kAborting,
  kCompleted,
  kFailed,
  kInterrupted,
};
std::string_view to_string(RunState state);
std::optional<RunState> parse_run_state(std::string_view name);
bool is_terminal(RunState state);  // completed, failed, interrupted

struct AcquisitionWindow {
  double from_s = 0;  // station s since run start
  double to_s = 0;
};

// Times of one step execution, station seconds since run start.
struct StepTimes {
  double start_s = 0;
  std::optional<double> settled_s;        // the gate held (first time this step)
  std::optional<double> acquire_start_s;  // first window's start
  std::optional<double> acquire_end_s;    // last window's end, once acquisition is over
  std::optional<double> end_s;
  std::vector<AcquisitionWindow> windows;  // closed acquisition windows
  // An adaptive soak's acquisition ended: why (the target reached, out of
  // reach with its floor, or the cap); empty for fixed soaks and until then.
  std::string acquire_stop;
  double held_s = 0;  // station s paused or suspended in this step

  double acquired_s() const;  // sum of the closed windows
};

// What the current step waits on before it acquires (docs/schedules.md,
// "Progress"). A soak's stability gate: held_s is how long chamber and shell
// have stayed within tolerance of the set point without a break, at most the
// stability window (needed_s); the gate also wants the shell's slope below
// its limit, so a soak may settle on with held_s == needed_s. A rate point's
// spin-up: held_s is how long the measured rate has been within tolerance,
// needed_s is at_rate_hold_s. waited_s: unheld station s spent waiting so far.
struct GateProgress {
  double held_s = 0;
  double needed_s = 0;
  double waited_s = 0;
};

// The acquisition a soak is told to make, for messages: "acquiring for 30
// min" or, adaptive, its target and bounds.
std::string acquiring_for(const PlanStep& step);

class SequencerObserver {
 public:
  virtual ~SequencerObserver() = default;
  virtual void on_state(RunState from, RunState to, double t_s, const std::string& reason) = 0;
  virtual void on_step_started(std::size_t index, const PlanStep& step, double t_s) = 0;
  // The step's times changed (settled, a window opened or closed, held time).
  virtual void on_step_changed(std::size_t index, const PlanStep& step, const StepTimes& times) = 0;
  // `completed` is false when the step ended by failure or abort.
  virtual void on_step_finished(std::size_t index, const PlanStep& step, const StepTimes& times,
                                bool completed) = 0;
  virtual void on_interlock(InterlockKind kind, bool tripped, double t_s,
                            const std::string& message) = 0;
};

struct SequencerOptions {
  double safe_setpoint_c = 23.0;
  InterlockOptions interlocks;
  // Rate points ([table]): the dwell starts once the measured rate has been
  // within at_rate_tolerance_dps of the demand for at_rate_hold_s; not so
  // within spin_up_timeout_s fails the step.
  // The tolerance is the larger of at_rate_tolerance_dps and
  // at_rate_tolerance_ppm of the demand (a table's rate noise is relative).
  double at_rate_tolerance_dps = 0.05;
  double at_rate_tolerance_ppm = 1000.0;
  double at_rate_hold_s = 1.0;
  double spin_up_timeout_s = 120.0;

  // False with a message when a value is out of range: the interlocks'
  // (InterlockOptions::is_valid, prefixed "interlocks."), safe_setpoint_c
  // outside the station limits, the rate tolerances, hold or spin-up timeout
  // out of range, or a spin-up timeout no longer than the hold it contains.
  // The message starts with the field it names (the config reader maps it to
  // its key).
  bool is_valid(std::string* why) const;
};

// A tripped interlock in a snapshot: a restart keeps its grace running from
// when it tripped, not from the restart.
struct InterlockTrip {
  InterlockKind kind = InterlockKind::kOutOfLimits;
  double since_s = 0;  // station s since run start when it tripped
  std::string message;
};

// What a restart needs to continue a run (stored as JSON with the run).
struct SequencerSnapshot {
  double t_s = 0;  // when taken
  RunState state = RunState::kQueued;
  RunState activity = RunState::kSettling;
  std::size_t step_index = 0;
  StepTimes times;
  std::optional<double> window_open_s;
  double step_active_s = 0;  // unheld station s in the step
  double setpoint_c = 0;
  double ramp_from_c = 0;
  bool paused = false;
  std::vector<InterlockTrip> trips;  // tripped interlocks (JSON "trips"; absent = none)
};
nlohmann::json to_json(const SequencerSnapshot& snapshot);
Result<SequencerSnapshot> snapshot_from_json(const nlohmann::json& j);

class Sequencer {
 public:
  // `options` must be valid (SequencerOptions::is_valid): the daemon checks
  // the station's in its config reader and in Station::create.
  Sequencer(Plan plan, SequencerOptions options, SequencerObserver& observer);

  // Starts the first step at t_s. `start_setpoint_c` is where a first ramp
  // starts from (the chamber's current set point or air temperature).
  void start(double t_s, double start_setpoint_c);
  // Continues a run from a snapshot at t_s (>= snapshot.t_s; the time
  // between counts as held for ramps and as elapsed for soaks and holds,
  // whose set point the controller kept). The run is held until the first
  // tick with chamber and shell readings and a gyro sample heard since the
  // restart, then goes on by the same rule as after any hold. `reason` goes into the state change
  // event. `data_until_s` is the station time (s since run start) of the run's last committed gyro
  // sample (-infinity when none is): acquisition windows are cut there, since the time after it
  // holds no data, so a soak acquires until the covered time reaches its acquire time. Tripped
  // interlocks come back with their trip times: their grace runs on across the restart.
  void restore(const SequencerSnapshot& snapshot, double t_s, double data_until_s,
               const std::string& reason);
  void tick(double t_s, const Readings& readings);
  // After restore(): the step of the snapshot had already been recorded
  // finished (the daemon died between its end and the checkpoint that said
  // so). Goes on with the next step (or completes the run) without
  // finishing that step again.
  void continue_after_finished_step(double t_s);

  // Operator commands. Permanent error, nothing changed, when they do not
  // apply (not running, already paused, ...).
  Status pause(double t_s, const std::string& reason);
  Status resume(double t_s, const std::string& reason);
  // Ends the run: the current step is closed, the safe set point commanded,
  // state aborting until safe_state_reached().
  void abort(double t_s, const std::string& reason);
  // The daemon has commanded the safe set point: aborting -> failed.
  void safe_state_reached(double t_s);
  // Marks the run interrupted (daemon shutting down mid-run); the open
  // window is closed, the step stays open for restore().
  void interrupt(double t_s, const std::string& reason);
  // The controller took the table off the step's rate (`reason`: a fault, a
  // reset): the open window closes (a rate point's partial dwell is
  // discarded) and acquisition waits for the table at rate again. Nothing
  // for a step that does not turn the table.
  void table_interrupted(double t_s, const std::string& reason);

  SequencerSnapshot snapshot(double t_s) const;

  RunState state() const { return state_; }
  bool finished() const { return is_terminal(state_); }
  bool paused() const { return paused_; }
  double setpoint_c() const { return setpoint_c_; }
  // The table demand of the current step; kNone before start() and once the
  // run has ended (aborting, completed, failed, interrupted): the daemon
  // stops the table then.
  const TableDemand& table_demand() const;
  // Index of the current step (== steps().size() once finished).
  std::size_t step_index() const { return index_; }
  const Plan& plan() const { return plan_; }
  const StepTimes& step_times() const { return times_; }
  // Tripped interlocks with their messages.
  std::vector<InterlockCondition> tripped() const;
  // The gate the current step waits on at t_s; nullopt when it waits on none
  // (ramps, holds, acquiring, no run).
  std::optional<GateProgress> gate_progress(double t_s) const;

 private:
  // A pause, a tripped interlock or a pending restore holds the run; held()
  // also counts the wait for the table after one (table_spin_up_pending_).
  bool hold_active() const;
  bool held() const;
  // The wait for the table back at the step's rate; false when it ran out
  // (the run was aborted).
  bool tick_table_gate(double t_s, double dt_s, const Readings& readings);
  double at_rate_tolerance_dps(double demand_dps) const {
    return std::max(options_.at_rate_tolerance_dps,
                    options_.at_rate_tolerance_ppm * 1e-6 * std::abs(demand_dps));
  }
  RunState derived_state() const;
  // Emits on_state when the derived state differs from state_.
  void update_state(double t_s, const std::string& reason);
  void begin_step(std::size_t index, double t_s);
  void finish_step(double t_s, bool completed);
  void advance(double t_s);
  void finish_run(RunState final_state, double t_s, const std::string& reason);
  void evaluate(double t_s, const Readings& readings);
  void trip(InterlockKind kind, double t_s, const std::string& message);
  void clear(InterlockKind kind, double t_s);
  void open_window(double t_s);
  void close_window(double t_s);
  void on_unheld(double t_s, const Readings& readings);
  void tick_soak(double t_s, const Readings& readings);
  void tick_rate(double t_s, double active_dt_s, const Readings& readings);
  // A rate point starts its spin-up (again): no window, the gate unheld.
  void restart_spin_up();

  Plan plan_;
  SequencerOptions options_;
  SequencerObserver& observer_;
  RunState state_ = RunState::kQueued;
  RunState activity_ = RunState::kSettling;
  std::optional<RunState> end_;  // aborting or terminal
  std::size_t index_ = 0;
  StepTimes times_;
  std::optional<double> window_open_s_;
  double step_active_s_ = 0;
  double last_tick_s_ = 0;
  double setpoint_c_ = 0;
  double ramp_from_c_ = 0;
  bool paused_ = false;
  bool restore_pending_ = false;
  bool was_held_ = false;
  bool tripped_[kInterlockKindCount] = {};
  double trip_since_s_[kInterlockKindCount] = {};
  std::string trip_message_[kInterlockKindCount];
  analysis::StabilityWindow shell_window_{600.0};
  analysis::StabilityWindow chamber_window_{600.0};
  std::optional<double> last_shell_c_;
  // Soak settling: since when chamber and shell have been within tolerance
  // (the gate's progress; reset with the stability windows).
  std::optional<double> in_tolerance_since_s_;
  // Rate point: unheld station s of the current spin-up, since when the
  // measured rate has been within tolerance, the last measured rate.
  double spin_up_s_ = 0;
  std::optional<double> at_rate_since_s_;
  std::optional<double> last_table_rate_dps_;
  // A soak, ramp or hold turning the table waits for it at rate again (the
  // spin-up fields above time it).
  bool table_spin_up_pending_ = false;
};

}  // namespace gyrotherm::schedules
