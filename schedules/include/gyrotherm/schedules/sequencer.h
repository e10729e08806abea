// The run state machine.
//
// A Sequencer executes one Plan. It owns no I/O and no clock: the daemon
// calls tick() with the station time (seconds since run start) and the
// latest readings; the Sequencer decides the set point to command, when
// acquisition windows open and close, and reports every transition to its
// observer (which writes event rows). Tests drive it with synthetic readings
// and run whole campaigns in virtual time without sleeping.
//
// Soak: the set point is commanded; the stability gate holds when, over the
// step's stability window, the shell temperature ((top + side) / 2) changes
// slower than stability_c_per_min (least-squares slope) and the window means
// of both the shell and the chamber air are within tolerance of the set
// point. Only then does the acquisition clock start. If the gate has not
// held within settle_timeout the run fails (to the safe state).
// Ramp: the set point moves linearly from where the previous step left it to
// the target at the step's rate; the whole ramp is the acquisition window.
// Hold: the set point is held for the step's duration, no acquisition.
// After the last step, or on failure or abort, the safe set point is
// commanded.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>

#include "gyrotherm/analysis/stability.h"
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
bool is_terminal(RunState state);  // completed, failed, interrupted

// One control-loop reading; nullopt where the device gave no value this tick.
struct Readings {
  std::optional<double> chamber_c;
  std::optional<double> top_c;
  std::optional<double> side_c;
};

// Times of one step execution, station seconds since run start.
struct StepTimes {
  double start_s = 0;
  std::optional<double> settled_s;
  std::optional<double> acquire_start_s;
  std::optional<double> acquire_end_s;
  std::optional<double> end_s;
};

class SequencerObserver {
 public:
  virtual ~SequencerObserver() = default;
  virtual void on_state(RunState from, RunState to, double t_s, const std::string& reason) = 0;
  virtual void on_step_started(std::size_t index, const PlanStep& step, double t_s) = 0;
  virtual void on_acquisition_started(std::size_t index, const StepTimes& times) = 0;
  // `completed` is false when the step ended by failure or abort.
  virtual void on_step_finished(std::size_t index, const PlanStep& step, const StepTimes& times,
                                bool completed) = 0;
};

struct SequencerOptions {
  double safe_setpoint_c = 23.0;
};

class Sequencer {
 public:
  Sequencer(Plan plan, SequencerOptions options, SequencerObserver& observer);

  // Starts the first step at t_s. `start_setpoint_c` is where a first ramp
  // starts from (the chamber's current set point or air temperature).
  void start(double t_s, double start_setpoint_c);
  void tick(double t_s, const Readings& readings);
  // Ends the run: the current step is closed, the safe set point commanded.
  void abort(double t_s, const std::string& reason);
  // Marks the run interrupted (daemon shutting down mid-run).
  void interrupt(double t_s, const std::string& reason);

  RunState state() const { return state_; }
  bool finished() const { return is_terminal(state_); }
  double setpoint_c() const { return setpoint_c_; }
  bool acquiring() const { return state_ == RunState::kAcquiring || state_ == RunState::kRamping; }
  // Index of the current step (== steps().size() once finished).
  std::size_t step_index() const { return index_; }
  const Plan& plan() const { return plan_; }
  const StepTimes& step_times() const { return times_; }

 private:
  void set_state(RunState to, double t_s, const std::string& reason);
  void begin_step(std::size_t index, double t_s);
  void finish_step(double t_s, bool completed);
  // Closes the current step as completed and starts the next (or completes the run).
  void advance(double t_s);
  void finish_run(RunState final_state, double t_s, const std::string& reason);
  void tick_soak(double t_s, const Readings& readings);

  Plan plan_;
  SequencerOptions options_;
  SequencerObserver& observer_;
  RunState state_ = RunState::kQueued;
  std::size_t index_ = 0;
  StepTimes times_;
  double setpoint_c_ = 0;
  double ramp_from_c_ = 0;
  analysis::StabilityWindow shell_window_{600.0};
  analysis::StabilityWindow chamber_window_{600.0};
  std::optional<double> last_shell_c_;
};

}  // namespace gyrotherm::schedules
