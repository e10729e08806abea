// Plain statistics of table1.h: long-double two-pass sums, so that a large
// common offset (rates around 1e4 °/h) does not eat the digits of the spread.
#include <cmath>
#include <limits>
#include <vector>

#include "gyrotherm/analysis/table1.h"

namespace gyrotherm::analysis {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Mean in long double, refined by the mean of the residuals.
long double mean_ld(std::span<const double> x) {
  long double sum = 0;
  for (double v : x) sum += v;
  const long double n = static_cast<long double>(x.size());
  const long double m0 = sum / n;
  long double residual = 0;
  for (double v : x) residual += static_cast<long double>(v) - m0;
  return m0 + residual / n;
}

}  // namespace

double mean(std::span<const double> x) {
  if (x.empty()) return kNaN;
  return static_cast<double>(mean_ld(x));
}

double std_ddof1(std::span<const double> x) {
  if (x.size() < 2) return kNaN;
  const long double m = mean_ld(x);
  long double s1 = 0;
  long double s2 = 0;
  for (double v : x) {
    const long double d = static_cast<long double>(v) - m;
    s1 += d;
    s2 += d * d;
  }
  const long double n = static_cast<long double>(x.size());
  // s1 is ~0; the correction term removes what is left of the mean's rounding.
  const long double var = (s2 - s1 * s1 / n) / (n - 1);
  if (std::isnan(static_cast<double>(var))) return kNaN;
  return static_cast<double>(std::sqrt(var < 0 ? 0.0L : var));
}

double moving_average_std(std::span<const double> x, std::size_t window) {
  if (window == 0 || x.size() < window + 1) return kNaN;
  const long double m = mean_ld(x);
  if (!std::isfinite(static_cast<double>(m))) return kNaN;
  const long double w = static_cast<long double>(window);
  // The std is shift-invariant: work on x - m so the running sum stays small,
  // and update it in long double (64-bit mantissa) to keep the drift over 1e6
  // steps far below 1e-10 of the result.
  auto d = [&](std::size_t i) { return static_cast<long double>(x[i]) - m; };
  std::vector<double> means(x.size() - window + 1);
  long double sum = 0;
  for (std::size_t i = 0; i < window; ++i) sum += d(i);
  means[0] = static_cast<double>(sum / w);
  for (std::size_t k = 1; k < means.size(); ++k) {
    sum += d(k + window - 1) - d(k - 1);
    means[k] = static_cast<double>(sum / w);
  }
  return std_ddof1(means);
}

double linear_slope(std::span<const double> t, std::span<const double> y) {
  if (t.size() != y.size() || t.size() < 2) return kNaN;
  const long double tm = mean_ld(t);
  const long double ym = mean_ld(y);
  long double stt = 0;
  long double sty = 0;
  for (std::size_t i = 0; i < t.size(); ++i) {
    const long double dt = static_cast<long double>(t[i]) - tm;
    stt += dt * dt;
    sty += dt * (static_cast<long double>(y[i]) - ym);
  }
  if (!(stt > 0)) return kNaN;
  return static_cast<double>(sty / stt);
}

}  // namespace gyrotherm::analysis
