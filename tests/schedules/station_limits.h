// The station limits the schedule tests plan against: -20..60 °C, 2 °C/min,
// with and without a rate table (500 °/s, 100 °/s²).
#pragma once

#include "gyrotherm/schedules/schedule.h"

namespace gyrotherm::schedules {

inline const StationLimits kNoTable{-20.0, 60.0, 2.0};
inline const StationLimits kTable{-20.0, 60.0, 2.0, StationLimits::Table{500.0, 100.0}};

}  // namespace gyrotherm::schedules
