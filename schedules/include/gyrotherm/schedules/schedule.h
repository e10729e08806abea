// Schedule files (TOML) -> a validated, expanded plan of steps.
//
// A schedule is a list of [[step]] tables: soak, ramp, hold, scale_factor,
// repeat (with its own [[step.steps]]). Durations are in minutes of station
// time, temperatures in °C, rates in °C/min, table rates in °/s;
// docs/schedules.md lists every key and default. A scale_factor step expands
// into rate points (StepKind::kRate), each dwelling over whole turns.
// Validation against the station (temperature limits, max ramp rate, its rate
// table) happens here too, so a bad schedule is refused with every error
// listed by file, line and key, and nothing runs.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/analysis/acquisition_target.h"
#include "gyrotherm/core/result.h"

namespace gyrotherm::schedules {

// kRate: one rate point of a scale-factor sequence (a [[step]] of type
// "scale_factor" expands into one per rate, direction and repetition): the
// set point is held, the table spins up to the rate, then the step acquires
// over whole turns (dwell_s).
enum class StepKind { kSoak, kRamp, kHold, kRate };
std::string_view to_string(StepKind kind);

// What the table does during a step.
enum class TableDemandMode {
  kNone,    // the step says nothing: the table is left at rest where it is
  kStatic,  // at rest (stopped), at position_deg if given: zero-bias soaks
  kRate,    // spinning at rate_dps
};
std::string_view to_string(TableDemandMode mode);

struct TableDemand {
  TableDemandMode mode = TableDemandMode::kNone;
  std::optional<double> position_deg;  // kStatic: move there first, then hold
  double rate_dps = 0;                 // kRate
};

// One executable step of the expanded plan (repeats unrolled).
struct PlanStep {
  StepKind kind = StepKind::kSoak;
  std::string label;      // "soak 20 °C", shown to technicians
  int source_line = 0;    // line of the [[step]] in the schedule file
  double setpoint_c = 0;  // soak/hold set point; ramp target
  // soak
  double tolerance_c = 0.5;            // chamber and shell within ± of the set point
  double stability_c_per_min = 0.02;   // shell |dT/dt| limit for the gate
  double stability_window_s = 600;     // gate evaluated over this window
  double settle_timeout_s = 3 * 3600;  // gate must hold within this time
  double acquire_s = 0;                // acquisition after the gate held (adaptive: its cap)
  // An adaptive soak (`acquire = { ... }`): it ends once every gated DUT
  // axis's mean is known to the target, or the target is out of reach, after
  // at least min_s and at most max_s (== acquire_s). nullopt: fixed.
  std::optional<analysis::AcquisitionTarget> adaptive;
  // ramp
  double rate_c_per_min = 0;
  // hold
  double hold_s = 0;
  // any: the table during the step (table_rate_dps = R is a kRate demand)
  TableDemand table;
  // rate point (kRate): acquisition at rate, a whole number of turns
  double dwell_s = 0;
  int turns = 0;
  // rate point: which scale-factor sequence of the plan (from 1, in plan
  // order) and which repetition of it (from 1); 0 for other steps
  int sf_sequence = 0;
  int sf_repetition = 0;
};

struct Plan {
  std::string name;
  std::string description;
  std::string source_path;
  std::vector<PlanStep> steps;
  // The station's table acceleration the plan was checked against ([table]
  // max_accel_dps2; 0 without a table): the spin-up time of rate points.
  double table_accel_dps2 = 0;

  // Station seconds the plan takes at least: soak acquisition, holds, and
  // each rate point's dwell plus its spin-up (|rate - the previous step's
  // rate| / table_accel_dps2). Settling and ramps are not counted.
  double nominal_duration_s() const;
};

// The station's limits a schedule is checked against.
struct StationLimits {
  double min_temp_c = -20.0;
  double max_temp_c = 60.0;
  double max_ramp_c_per_min = 2.0;
  // The rate table ([table]); nullopt: the station has none, and a step
  // that asks for a rate (or a position) is refused.
  struct Table {
    double max_rate_dps = 500.0;
    double max_accel_dps2 = 100.0;
    // The controller takes whole °/s and whole degrees only (the AERO
    // driver sends JOG and MOV as whole numbers: docs/table.md).
    bool whole_numbers = false;
  };
  std::optional<Table> table{};
};

// Sanity bounds every schedule is held to besides the station's limits
// (docs/schedules.md, "Validation"). Durations in minutes of station time.
inline constexpr std::size_t kMaxPlanSteps = 10000;  // after repeats are expanded
inline constexpr int kMaxRepeatDepth = 4;            // repeats inside repeats
inline constexpr int64_t kMaxRepeatCount = 1000;
inline constexpr double kMaxAcquireMin = 30 * 24 * 60;       // soak acquisition: 30 days
inline constexpr double kMaxHoldMin = 30 * 24 * 60;          // hold: 30 days
inline constexpr double kMaxRampMin = 30 * 24 * 60;          // a ramp, where its start is known
inline constexpr double kMaxSettleTimeoutMin = 7 * 24 * 60;  // 7 days
inline constexpr double kMinStabilityWindowMin = 1;          // the gate fits a slope over it
inline constexpr double kMaxStabilityWindowMin = 24 * 60;    // and never above the timeout
inline constexpr double kMinToleranceC = 0.01;               // below probe resolution
inline constexpr double kMaxToleranceC = 10;
inline constexpr double kMaxStabilityCPerMin = 10;  // and > 0
inline constexpr double kMaxTableRateDps = 1000;    // |table_rate_dps|, |rate_dps|, rates_dps
// scale_factor steps
inline constexpr int64_t kMaxTurnsPerPoint = 1000;          // turns
inline constexpr double kMaxMinDwellS = 12 * 3600;          // min_dwell_s: 12 h
inline constexpr double kMaxRateDwellMin = 24 * 60;         // a rate point's dwell: 24 h
inline constexpr int64_t kMaxScaleFactorRepetitions = 100;  // repetitions

// Parses and validates. On failure the error lists every problem, one per
// line in file order, as "file:line: key: message".
Result<Plan> load_schedule(const std::string& path, const StationLimits& limits);
Result<Plan> parse_schedule(std::string_view toml_text, const std::string& source_name,
                            const StationLimits& limits);

}  // namespace gyrotherm::schedules
