// TableControl: the station's side of the rate table. It reads the table
// each control tick (into the readings the interlocks see), brings it to
// what the current step demands, and takes it to its safe state.
//
// Demands: none or static without a position -> not spinning (a spinning
// table is stopped; a held position is kept); static at P -> position mode
// at P; rate R -> rate mode at R. A command is sent when the demand changes
// and again whenever the controller's mode or interlock does not match it
// (a reconnect; after an interruption, below, the station pauses the run
// first unless [table] respin_after_fault), at most once per wall second.
// Nothing is sent while the interlock is in fault: the table_fault
// interlock holds the run.
//
// Safe state (an abort, the end of a run, a pause, a tripped interlock,
// the daemon stopping): stop (decelerate at the controller's limits, the
// axis stays servoed); once the measured rate is below rest_rate_dps the
// interlock is opened (servo off), then the operator panel is handed back
// (RateTable::release_control). The station stops the table before it
// sends the chamber's safe set point, and opens the servo after. An axis
// that is not servoed (interlock open, or in fault: the drive is off) is
// already as safe as the station can make it. Idle, the station makes the
// table safe once (after a run, or at start-up: a daemon that died may have
// left it spinning) and then leaves it alone: a jog from the front panel is
// not the station's to stop (an Aerosmith reads as servoed and in the mode
// last commanded whatever happens at its panel).
//
// Interruptions: once the table has been seen at a moving demand (a rate,
// or a position), a reading that shows it taken off that demand by the
// controller (a fault, the servo opened by a reset or a restart of the
// controller, another mode, or the rate far off the demand while the mode
// still reads the same, as an Aerosmith's does) is an interruption, which
// the station takes (take_interruption()) to hold the run's acquisition
// and, unless [table] respin_after_fault, to pause the run.
//
// Latched faults: while a run is held by the table_fault interlock the
// station resets the fault (reset_latched_fault()) once the axis is at
// rest, at most schedules::kTableFaultResets times a run, 10 station
// seconds apart.
#pragma once

#include <optional>
#include <string>

#include "gyrotherm/config/config.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/drivers/rate_table.h"
#include "gyrotherm/schedules/interlocks.h"
#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/station/status.h"

namespace gyrotherm::station {

class TableControl {
 public:
  TableControl(drivers::RateTable& table, const config::TableSection& config);

  // Reads the table at station time now_s (wall: monotonic wall seconds)
  // and fills the table fields of `r`. Silence counts in station time once
  // it is also min_silent_wall_s of wall time, like the other devices.
  void read(double now_s, double wall_s, double min_silent_wall_s, schedules::Readings& r);
  // Brings the table towards `demand` (see above). Cancels a safe state in
  // progress when the demand is a rate or a position.
  void drive(const schedules::TableDemand& demand, double wall_s);
  // Stops the table now (once per safe state) and arms the servo off.
  void make_safe(double wall_s);
  // Opens the interlock once a safe state's stop has brought the table to
  // rest. Each tick, whatever else happens.
  void finish_safe_state(double wall_s);
  // At rest and stopped (or not servoed): the safe state is reached.
  bool at_rest() const;
  bool safing() const { return safing_; }
  // Whether the safe state is still owed: not reached since the daemon
  // started, or since the station last set the table moving.
  bool owes_safe_state() const { return !safe_reached_; }
  // The last read answered (and one has, ever).
  bool answering() const { return ok_ && state_.has_value(); }
  // The stop of the safe state in progress was accepted.
  bool stop_sent() const { return stop_sent_; }
  const std::optional<drivers::TableState>& last_state() const { return state_; }
  // The last failed read's or command's error ("" before any).
  const std::string& last_error() const { return last_error_; }

  // What took the table off its demand since the last call, once.
  std::optional<std::string> take_interruption();
  // A run starts (or resumes): its fault resets are counted afresh, and an
  // interruption the last run ended without taking is dropped.
  void begin_run();
  // Resets a latched fault (see above) when one is due at station time
  // now_s; the event's message when something was done or given up.
  std::optional<std::string> reset_latched_fault(double now_s);

  // The record of this tick's reading (nullopt before any good reading).
  std::optional<TableSample> sample(double t_run_s) const;
  TableStatus status() const;
  drivers::RateTable& device() { return table_; }

 private:
  bool matches(const schedules::TableDemand& demand) const;
  void release_panel();  // the safe state is reached
  Status send(const schedules::TableDemand& demand);
  void log_failure(const Status& st, const std::string& what);
  // After a good reading: whether the controller took the table off sent_.
  void watch_demand();

  drivers::RateTable& table_;
  config::TableSection config_;
  std::optional<drivers::TableState> state_;  // last good reading
  bool ok_ = true;                            // the last read answered
  double ok_s_ = 0, ok_wall_s_ = 0;           // last good reading
  bool started_ = false;
  schedules::TableDemand demand_;  // the demand drive() was last given
  std::optional<schedules::TableDemand> sent_;
  double last_send_wall_s_ = -1e9;
  bool safing_ = false;
  bool stop_sent_ = false;
  bool failing_ = false;  // a command failed; logged once per spell
  std::string last_error_;
  bool safe_reached_ = false;
  // A moving demand or a stop was sent after state_ was read: state_ may
  // still say "at rest, servo off" of an axis now servoed and spinning up,
  // or "at rest" of one that had not yet stopped.
  bool moved_since_read_ = false;
  // The table has matched sent_ (a moving demand) since it was sent; at its
  // rate, for a rate demand.
  bool matched_ = false;
  bool at_rate_ = false;
  std::optional<std::string> interruption_;
  int fault_resets_ = 0;  // this run's
  double last_fault_reset_s_ = -1e9;
  bool fault_resets_spent_said_ = false;
};

// "static at 90.0°", "rate +10 °/s", "none".
std::string describe(const schedules::TableDemand& demand);

}  // namespace gyrotherm::station
