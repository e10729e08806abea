// Overlapping Allan deviation of allan.h.
#include "gyrotherm/analysis/allan.h"

#include <fmt/format.h>

#include <algorithm>
#include <boost/math/distributions/chi_squared.hpp>
#include <cmath>
#include <limits>

namespace gyrotherm::analysis {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kBiasInstabilityFactor = 0.664;
constexpr double kSlopeTolerance = 0.25;

double median_spacing(std::span<const double> t) {
  std::vector<double> d(t.size() - 1);
  for (std::size_t i = 0; i + 1 < t.size(); ++i) d[i] = t[i + 1] - t[i];
  const std::size_t mid = d.size() / 2;
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(mid), d.end());
  const double upper = d[mid];
  if (d.size() % 2 == 1) return upper;
  const double lower = *std::max_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(mid));
  return lower + (upper - lower) / 2;
}

long double mean_ld(std::span<const double> x) {
  long double sum = 0;
  for (double v : x) sum += v;
  const auto n = static_cast<long double>(x.size());
  const long double m0 = sum / n;
  long double residual = 0;
  for (double v : x) residual += static_cast<long double>(v) - m0;
  return m0 + residual / n;
}

// Overlapping Allan variance for cluster size m on d = rate - mean: two
// adjacent cluster sums slide along the data, updated in long double.
double allan_variance(std::span<const double> y, long double mean, std::size_t m) {
  auto d = [&](std::size_t i) { return static_cast<long double>(y[i]) - mean; };
  long double a = 0;  // sum of d[k .. k+m-1]
  long double b = 0;  // sum of d[k+m .. k+2m-1]
  for (std::size_t i = 0; i < m; ++i) {
    a += d(i);
    b += d(i + m);
  }
  const std::size_t terms = y.size() - 2 * m + 1;
  long double ss = 0;
  for (std::size_t k = 0;; ++k) {
    const long double diff = b - a;
    ss += diff * diff;
    if (k + 1 == terms) break;
    a += d(k + m) - d(k);
    b += d(k + 2 * m) - d(k + m);
  }
  const auto ml = static_cast<long double>(m);
  return static_cast<double>(ss / (ml * ml) / (2.0L * static_cast<long double>(terms)));
}

// C of the fixed-slope line log sigma = log C + slope log tau (allan.h).
std::optional<double> fit_fixed_slope(const AllanResult& r, double slope) {
  const std::size_t n = r.tau_s.size();
  if (n < 3) return std::nullopt;
  std::vector<double> lt(n), ls(n);
  for (std::size_t i = 0; i < n; ++i) {
    if (!(r.adev_dph[i] > 0) || !std::isfinite(r.adev_dph[i])) return std::nullopt;
    lt[i] = std::log(r.tau_s[i]);
    ls[i] = std::log(r.adev_dph[i]);
  }
  double wsum = 0;
  double sum = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t lo = i == 0 ? 0 : i - 1;
    const std::size_t hi = i + 1 == n ? n - 1 : i + 1;
    const double local = (ls[hi] - ls[lo]) / (lt[hi] - lt[lo]);
    if (std::abs(local - slope) > kSlopeTolerance) continue;
    wsum += r.edf[i];
    sum += r.edf[i] * (ls[i] - slope * lt[i]);
  }
  if (!(wsum > 0)) return std::nullopt;
  return std::exp(sum / wsum);
}

double chi2_quantile(double dof, double p) {
  try {
    return boost::math::quantile(boost::math::chi_squared_distribution<double>(dof), p);
  } catch (const std::exception&) {
    return kNaN;
  }
}

}  // namespace

Result<TauSet> parse_tau_set(std::string_view s) {
  if (s == "octave") return TauSet::kOctave;
  if (s == "decade") return TauSet::kDecade;
  if (s == "all") return TauSet::kAll;
  return Error::Permanent(fmt::format("unknown tau set '{}' (expected octave, decade or all)", s));
}

std::string_view to_string(TauSet set) {
  switch (set) {
    case TauSet::kOctave:
      return "octave";
    case TauSet::kDecade:
      return "decade";
    case TauSet::kAll:
      return "all";
  }
  return "?";
}

std::vector<std::size_t> allan_cluster_sizes(std::size_t n, TauSet set) {
  std::vector<std::size_t> ms;
  switch (set) {
    case TauSet::kOctave:
      for (std::size_t m = 1; 2 * m < n + 1; m *= 2) ms.push_back(m);
      break;
    case TauSet::kDecade:
      for (std::size_t decade = 1;; decade *= 10) {
        for (std::size_t f : {1, 2, 5}) {
          const std::size_t m = f * decade;
          if (2 * m >= n + 1) return ms;
          ms.push_back(m);
        }
      }
    case TauSet::kAll:
      for (std::size_t m = 1; 2 * m < n + 1; ++m) ms.push_back(m);
      break;
  }
  return ms;
}

double allan_edf_white_fm(std::size_t n_rate_samples, std::size_t m) {
  const double n = static_cast<double>(n_rate_samples) + 1.0;  // phase points
  const double md = static_cast<double>(m);
  return (3.0 * (n - 1.0) / (2.0 * md) - 2.0 * (n - 2.0) / n) * 4.0 * md * md /
         (4.0 * md * md + 5.0);
}

Result<AllanResult> allan_deviation(std::span<const double> t_s, std::span<const double> rate_dph,
                                    const AllanOptions& options) {
  if (t_s.size() != rate_dph.size()) {
    return Error::Permanent(
        fmt::format("allan_deviation: {} times but {} rates", t_s.size(), rate_dph.size()));
  }
  const std::size_t n = t_s.size();
  if (n < 2) {
    return Error::Permanent(fmt::format("allan_deviation: {} sample(s), at least 2 are needed", n));
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isfinite(t_s[i])) {
      return Error::Permanent(
          fmt::format("allan_deviation: t_s[{}] is not finite ({})", i, t_s[i]));
    }
    if (!std::isfinite(rate_dph[i])) {
      return Error::Permanent(fmt::format(
          "allan_deviation: rate_dph[{}] is not finite ({}) at t_s = {}", i, rate_dph[i], t_s[i]));
    }
    if (i > 0 && !(t_s[i] > t_s[i - 1])) {
      return Error::Permanent(fmt::format(
          "allan_deviation: times not strictly increasing: t_s[{}] = {} after t_s[{}] = {}", i,
          t_s[i], i - 1, t_s[i - 1]));
    }
  }

  AllanResult r;
  r.n_samples = n;
  r.tau0_s = median_spacing(t_s);
  const long double mean = mean_ld(rate_dph);
  for (std::size_t m : allan_cluster_sizes(n, options.taus)) {
    const double adev = std::sqrt(allan_variance(rate_dph, mean, m));
    const double edf = allan_edf_white_fm(n, m);
    r.tau_s.push_back(static_cast<double>(m) * r.tau0_s);
    r.m.push_back(m);
    r.adev_dph.push_back(adev);
    r.adev_lo_dph.push_back(adev * std::sqrt(edf / chi2_quantile(edf, 0.8415)));
    r.adev_hi_dph.push_back(adev * std::sqrt(edf / chi2_quantile(edf, 0.1585)));
    r.n_terms.push_back(n - 2 * m + 1);
    r.edf.push_back(edf);
  }

  if (auto c = fit_fixed_slope(r, -0.5)) r.angle_random_walk_dprh = *c / 60.0;  // sigma(1 s) / 60
  if (auto c = fit_fixed_slope(r, 0.5)) {
    r.rate_random_walk_dphprh = 60.0 * *c * std::sqrt(3.0);  // 60 sigma(3 s)
  }
  if (r.adev_dph.size() >= 3) {
    const auto it = std::min_element(r.adev_dph.begin(), r.adev_dph.end());
    const auto i = static_cast<std::size_t>(it - r.adev_dph.begin());
    if (i > 0 && i + 1 < r.adev_dph.size()) {
      r.bias_instability_dph = *it / kBiasInstabilityFactor;
      r.bias_instability_tau_s = r.tau_s[i];
    }
  }
  return r;
}

}  // namespace gyrotherm::analysis
