#include "gyrotherm/analysis/quality.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace gyrotherm::analysis {
namespace {

// The median (the mean of the two middle values of an even count).
double median_of(std::vector<double> v) {
  const std::size_t n = v.size();
  auto mid = v.begin() + static_cast<std::ptrdiff_t>(n / 2);
  std::nth_element(v.begin(), mid, v.end());
  if (n % 2 == 1) return *mid;
  return (*mid + *std::max_element(v.begin(), mid)) / 2.0;
}

}  // namespace

CoverageCounter::CoverageCounter(std::vector<std::pair<double, double>> windows)
    : windows_(std::move(windows)) {
  if (!windows_.empty()) last_s_ = windows_.front().first;
}

void CoverageCounter::add(double t_s) {
  while (at_ < windows_.size() && t_s >= windows_[at_].second) {
    longest_gap_s_ = std::max(longest_gap_s_, windows_[at_].second - last_s_);
    if (++at_ < windows_.size()) last_s_ = windows_[at_].first;
  }
  if (at_ == windows_.size() || t_s < windows_[at_].first) return;
  longest_gap_s_ = std::max(longest_gap_s_, t_s - last_s_);
  last_s_ = t_s;
  ++samples_;
}

Coverage CoverageCounter::result(double rate_hz) const {
  Coverage c;
  c.samples = samples_;
  c.longest_gap_s = longest_gap_s_;
  double last = last_s_;
  for (std::size_t i = at_; i < windows_.size(); ++i) {
    if (i > at_) last = windows_[i].first;
    c.longest_gap_s = std::max(c.longest_gap_s, windows_[i].second - last);
  }
  for (const auto& [from_s, to_s] : windows_) c.window_s += std::max(0.0, to_s - from_s);
  if (rate_hz > 0 && std::isfinite(rate_hz)) {
    c.expected = c.window_s * rate_hz;
    if (c.expected > 0) c.fraction = static_cast<double>(c.samples) / c.expected;
  }
  return c;
}

Coverage coverage_of(std::span<const double> t_s,
                     const std::vector<std::pair<double, double>>& windows, double rate_hz) {
  CoverageCounter counter(windows);
  for (double t : t_s) counter.add(t);
  return counter.result(rate_hz);
}

double median_rate_hz(std::span<const double> t_s) {
  std::vector<double> steps;
  for (std::size_t i = 1; i < t_s.size(); ++i) {
    if (t_s[i] > t_s[i - 1]) steps.push_back(t_s[i] - t_s[i - 1]);
  }
  if (steps.empty()) return 0;
  return 1.0 / median_of(std::move(steps));
}

std::vector<std::string> coverage_reasons(const Coverage& c, const QualityRules& rules) {
  if (!c.fraction || *c.fraction >= rules.min_coverage) return {};
  return {fmt::format(
      "coverage {:.1f} % ({} of {:.0f} samples expected) is under {:g} %; longest gap {:.3g} s",
      *c.fraction * 100.0, c.samples, c.expected, rules.min_coverage * 100.0, c.longest_gap_s)};
}

std::vector<std::string> scale_factor_reasons(double k, double nonlinearity_ppm,
                                              const QualityRules& rules) {
  std::vector<std::string> out;
  if (!std::isfinite(k)) {
    out.push_back(fmt::format("K is {} (not a number)", k));
  } else if (k <= 0) {
    out.push_back(fmt::format("K = {:.6g} is not positive", k));
  } else if (k < rules.k_min || k > rules.k_max) {
    out.push_back(
        fmt::format("K = {:.6g} is outside [{:g}, {:g}] (nominal 1)", k, rules.k_min, rules.k_max));
  }
  if (!std::isfinite(nonlinearity_ppm)) {
    out.push_back(fmt::format("nonlinearity is {} (not a number)", nonlinearity_ppm));
  } else if (nonlinearity_ppm > rules.max_nonlinearity_ppm) {
    out.push_back(fmt::format("nonlinearity {:.4g} ppm is over {:g} ppm", nonlinearity_ppm,
                              rules.max_nonlinearity_ppm));
  }
  return out;
}

double series_noise_dph(std::span<const double> rate_dph) {
  std::vector<double> d;
  for (std::size_t i = 1; i < rate_dph.size(); ++i) {
    const double step = rate_dph[i] - rate_dph[i - 1];
    if (std::isfinite(step)) d.push_back(step);
  }
  if (d.size() < 2) return NAN;
  const double centre = median_of(d);
  for (double& x : d) x = std::fabs(x - centre);
  return 1.4826 * median_of(std::move(d)) / std::sqrt(2.0);
}

std::vector<std::string> residual_reasons(double residual_std_dph, double noise_dph,
                                          const QualityRules& rules) {
  if (!std::isfinite(residual_std_dph)) {
    return {fmt::format("residual std is {} (not a number)", residual_std_dph)};
  }
  const double noise =
      std::isfinite(noise_dph) ? std::max(noise_dph, rules.noise_floor_dph) : rules.noise_floor_dph;
  if (residual_std_dph <= rules.max_residual_ratio * noise) return {};
  return {
      fmt::format("residual std {:.4g} °/h is {:.3g} times the series' noise ({:.3g} °/h; "
                  "limit {:g} times)",
                  residual_std_dph, residual_std_dph / noise, noise, rules.max_residual_ratio)};
}

}  // namespace gyrotherm::analysis
