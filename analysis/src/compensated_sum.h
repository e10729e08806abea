// Neumaier-compensated running sum, shared by the analysis sources (private
// header): the rounding error of every addition is carried in `comp`, so
// summing 10 M doubles loses no more than a few ulps of the result.
#pragma once

#include <cmath>

namespace gyrotherm::analysis {

struct CompensatedSum {
  double sum = 0, comp = 0;
  void add(double v) {
    const double t = sum + v;
    comp += std::abs(sum) >= std::abs(v) ? (sum - t) + v : (v - t) + sum;
    sum = t;
  }
  double value() const { return sum + comp; }
};

}  // namespace gyrotherm::analysis
