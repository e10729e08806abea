// Numbers many tests share.
#pragma once

#include <limits>

namespace gyrotherm::testing {

// A quiet NaN: "no value" in the APIs under test.
inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

}  // namespace gyrotherm::testing
