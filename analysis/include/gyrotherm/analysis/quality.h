// How complete a result's input was, and the rules that flag implausible
// results (docs/analysis.md "Result quality"). Pure functions of their
// arguments, safe from any thread.
//
// Coverage over a set of windows: the samples in them against those
// expected (Σ window length × the output rate), and the longest stretch of
// a window without a sample (from the window's start to its first sample,
// between samples, from the last sample to the window's end).
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

namespace gyrotherm::analysis {

struct Coverage {
  int64_t samples = 0;
  double expected = 0;             // 0: the output rate is not known
  std::optional<double> fraction;  // samples / expected; nullopt when expected is 0
  double longest_gap_s = 0;        // station s
  double window_s = 0;             // Σ window length
};

// Coverage fed one sample time at a time, in time order. The windows are
// half-open [from, to), sorted and disjoint; samples outside every window
// are not counted. result(): rate_hz <= 0 means no expectation (fraction
// nullopt).
class CoverageCounter {
 public:
  explicit CoverageCounter(std::vector<std::pair<double, double>> windows);
  void add(double t_s);
  Coverage result(double rate_hz) const;

 private:
  std::vector<std::pair<double, double>> windows_;
  std::size_t at_ = 0;  // the window being filled
  double last_s_ = 0;   // its last sample, or its start
  int64_t samples_ = 0;
  double longest_gap_s_ = 0;
};

Coverage coverage_of(std::span<const double> t_s,
                     const std::vector<std::pair<double, double>>& windows, double rate_hz);

// 1 / the median spacing of consecutive samples (time order); 0 with fewer
// than 2 samples or no positive spacing. The output rate of a stream whose
// nominal rate is not recorded.
double median_rate_hz(std::span<const double> t_s);

// The verdict's rules ([quality] in the station config, docs/configuration.md).
struct QualityRules {
  double min_coverage = 0.99;             // samples stored / expected
  double k_min = 0.5, k_max = 2.0;        // scale factor K (nominal 1, output in °/s per °/s)
  double max_nonlinearity_ppm = 10000.0;  // relative to K
  double max_residual_ratio = 20.0;       // drift fit: residual std / the series' noise
  // Below this the noise is taken to be this (noise-free or quantised
  // data would otherwise flag any residual), °/h.
  double noise_floor_dph = 1e-3;
};

// Why a result with this coverage is flagged: coverage under min_coverage
// ("coverage 6.0 % (600 of 10000 samples expected) is under 99 %"); none
// when it is met or not known.
std::vector<std::string> coverage_reasons(const Coverage& c, const QualityRules& rules);
// A scale-factor line: K ≤ 0, K outside [k_min, k_max], nonlinearity over
// max_nonlinearity_ppm (a NaN is a reason too).
std::vector<std::string> scale_factor_reasons(double k, double nonlinearity_ppm,
                                              const QualityRules& rules);
// The noise of a (binned) rate series: 1.4826 · median |xᵢ₊₁ − xᵢ − median| / √2,
// the white-noise σ of one point, robust to steps and drift; NaN with
// fewer than 3 points.
double series_noise_dph(std::span<const double> rate_dph);
// A drift fit whose residual std is more than max_residual_ratio times
// max(noise, noise_floor_dph).
std::vector<std::string> residual_reasons(double residual_std_dph, double noise_dph,
                                          const QualityRules& rules);

}  // namespace gyrotherm::analysis
