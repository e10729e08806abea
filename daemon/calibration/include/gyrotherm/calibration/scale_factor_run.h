// A run's scale-factor calibration: its rate points (segments of kind
// "rate", expanded from the schedule's scale_factor steps), a line per
// scale-factor sequence, and K(T), B(T) across the sequences' temperatures
// (docs/analysis.md, "Scale factor").
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::calibration {
struct AnalysisSettings;
}

namespace gyrotherm::calibration {

struct ScaleFactorSummary {
  int points = 0;
  int sequences = 0;  // fitted
  bool temperature_fit = false;
  std::vector<std::string> problems;  // a sequence or point that could not be used, and why
  std::vector<std::string> flagged;   // a point or line stored flagged, and why
};

// Fills each table step's measured means (segments.table_mean_*). Each
// completed rate point's mean gyro output (°/s) and the table's rate over
// its acquisition windows, each window cut by settings.rate_guard_s at
// both ends (and then to whole turns from its start, when at least one
// turn is left); each sequence's fit against the demanded rates (the
// controller holds the demand; the measured mean, stored beside it, is a
// check). A point is left out of its fit, stored with quality "excluded"
// and named in `problems` (rate, temperature, why) when the table's mean
// is off the demand by more than kMaxRateErrorPpm or its samples are not
// flat at the demanded rate (analysis::check_rate_point_flatness with
// settings.flatness). K(T) and B(T) of order 1 with two or three
// temperatures, 2 with four or more. Points and lines carry their
// coverage and the verdict of settings.quality (docs/analysis.md "Result
// quality"). Per DUT: on each DUT's table axis ([[dut]] table_axis,
// default its primary axis), the records carrying its serial and axis;
// one store_scale_factor() per DUT. Stores everything, replacing the run's
// earlier results. A run without rate points: nothing stored, a summary
// with no points. The first form: the run's own settings
// (analysis_settings_of_run; the defaults when they do not parse).
Result<ScaleFactorSummary> analyse_scale_factor(storage::Database& db, int64_t run_id);
Result<ScaleFactorSummary> analyse_scale_factor(storage::Database& db, int64_t run_id,
                                                const AnalysisSettings& settings);

inline constexpr double kMaxRateErrorPpm = 1000.0;

}  // namespace gyrotherm::calibration
