// The simulated rate table (docs/simulator.md, "The rate table"): one
// servoed axis, stepped in station time by the simulator's loop.
//
// State: interlock {open, closed, fault}, mode {off, rate, position}, true
// rate, acceleration and an unwrapped position. While the interlock is
// closed the servo takes the rate toward a target (rate mode: the rate
// demand; off mode: zero; position mode: a rate that brings the axis to
// the position demand along the shortest path and holds it there) within
// the acceleration and jerk limits: within a substep the jerk is constant,
// so rate and position are integrated exactly (a piecewise-cubic position).
// While the interlock is open or faulted the axis is not servoed and coasts
// to rest at the acceleration limit (no jerk limit: the brake).
//
// Safety, as an Acutrol (TM-8004 §4.6.9 Limit:VelocityTrip, §4.5.6
// Interlock:Reset): a true |rate| beyond the velocity trip faults the
// interlock (mode goes to off); the fault is latched until reset(), and
// closing the interlock from fault is refused until then.
//
// Measured rate = true rate x (1 + ε), ε Gaussian with relative std
// rate_noise_rel, drawn once per step(); deterministic given the seed.
// Position is reported in [0, 360). Angles in degrees, rates °/s,
// positive counter-clockwise. Not thread-safe (the simulator holds its lock).
#pragma once

#include <cstdint>
#include <random>
#include <string>

#include "gyrotherm/drivers/rate_table.h"

namespace gyrotherm::sim {

// [simulator.table] in the station config. The rate limit is an Acutronic
// BD125's (datasheet: 1000 °/s; it gives 4200 °/s² without load, the
// default acceleration here is a loaded table's 1000 °/s²); the rate noise
// is the paper's table's.
struct TableParams {
  double max_rate_dps = 1000.0;  // rate limit (and the gyro model's full scale)
  double max_accel_dps2 = 1000.0;
  double max_jerk_dps3 = 5000.0;
  double trip_rate_dps = 1100.0;  // velocity trip
  double rate_noise_rel = 1e-4;   // relative std of the measured rate
  double max_substep_s = 1e-3;    // dynamics substep, station s
  // How ACL replies are framed: "ascii", "binary-le", "binary-be" or "line"
  // (table_server.h).
  std::string reply_header = "ascii";

  // False with a message naming the first bad field.
  bool is_valid(std::string* why) const;
};

// Why a command was not carried out.
enum class TableCommandResult {
  kOk,
  kOutOfRange,  // a demand or limit beyond what the table takes (nothing changed)
  kRefused,     // not in this state (closing the interlock from fault)
};

struct TableModelState {
  drivers::TableMode mode = drivers::TableMode::kOff;
  drivers::TableInterlock interlock = drivers::TableInterlock::kOpen;
  double rate_dps = 0;           // true rate
  double measured_rate_dps = 0;  // with the measurement noise of the last step
  double accel_dps2 = 0;
  double position_deg = 0;  // [0, 360)
  double rate_demand_dps = 0;
  double position_demand_deg = 0;  // [0, 360)
  double rate_limit_dps = 0;
  double accel_limit_dps2 = 0;
  double trip_rate_dps = 0;
  std::string fault;  // what latched the fault; "" when none
};

class RateTableModel {
 public:
  RateTableModel(TableParams params, uint64_t seed);

  // Advances `dt_s` station seconds (substeps of at most max_substep_s),
  // then draws the measurement noise for measured_rate_dps().
  void step(double dt_s);

  // Commands (ACL/AERO). Each leaves the model unchanged unless kOk.
  TableCommandResult set_mode(drivers::TableMode mode);  // kOff, kRate or kPosition
  // Stored in any mode; followed in rate mode. |rate| > the rate limit: kOutOfRange.
  TableCommandResult set_rate_demand(double rate_dps);
  TableCommandResult set_position_demand(double position_deg);  // any finite angle
  TableCommandResult close_interlock();                         // kRefused from fault
  void open_interlock();
  void reset_faults();            // fault -> open; no effect otherwise
  void trip(std::string reason);  // interlock to fault now (latched), mode off
  // Limits, > 0: rate ≤ params.max_rate_dps, accel ≤ 10 x params.max_accel_dps2,
  // trip ≤ 2 x params.trip_rate_dps.
  TableCommandResult set_rate_limit(double rate_dps);
  TableCommandResult set_accel_limit(double accel_dps2);
  TableCommandResult set_trip_rate(double rate_dps);

  TableModelState state() const;
  double rate_dps() const { return rate_dps_; }
  double measured_rate_dps() const { return measured_rate_dps_; }
  double accel_dps2() const { return accel_dps2_; }
  double position_deg() const;  // [0, 360)
  double unwrapped_position_deg() const { return position_deg_; }
  const TableParams& params() const { return params_; }

 private:
  void substep(double dt_s);
  // The rate the servo heads for now.
  double target_rate_dps() const;

  TableParams params_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  drivers::TableMode mode_ = drivers::TableMode::kOff;
  drivers::TableInterlock interlock_ = drivers::TableInterlock::kOpen;
  double rate_dps_ = 0;
  double measured_rate_dps_ = 0;
  double accel_dps2_ = 0;
  double position_deg_ = 0;  // unwrapped
  double rate_demand_dps_ = 0;
  double position_demand_deg_ = 0;
  double rate_limit_dps_;
  double accel_limit_dps2_;
  double trip_rate_dps_;
  std::string fault_;
};

// Shortest signed angle from `from_deg` to `to_deg`, in (-180, 180].
double shortest_angle_deg(double from_deg, double to_deg);
// `deg` in [0, 360).
double wrap_360(double deg);

}  // namespace gyrotherm::sim
