// Constants the analysis library's files share (one definition each, as a
// unity build compiles several of these files together).
#pragma once

#include <limits>

namespace gyrotherm::analysis {

// The "no value" the analysis returns.
inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// The highest order of a drift-model term (the paper's T4).
inline constexpr int kMaxTermOrder = 4;

}  // namespace gyrotherm::analysis
