// Overlapping Allan deviation of the gyro rate, and the noise terms read off
// it (docs/analysis.md).
//
// On the samples as recorded (not the analysis bins): rates y_i in °/h at
// times t_i, taken as evenly spaced at tau0 = the median of the time
// differences. For a cluster size m (tau = m * tau0), with ybar_k the mean of
// y_k ... y_{k+m-1}:
//   sigma^2(tau) = 1 / (2 (N - 2m + 1)) * sum_{k=0}^{N-2m} (ybar_{k+m} - ybar_k)^2
// over every overlapping k. Computed from the prefix sums C of the rates minus
// a sample mean, in double, each C[k] rounded about once (blocked, with a
// compensated running offset): m ybar differences are C[k+2m] - 2C[k+m] + C[k]
// taken as (C[k+2m] - C[k+m]) - (C[k+m] - C[k]), so a large common offset
// (1e4 °/h) costs no digits and a slow drift only ~eps |C| / (m sigma(m)) per
// term. One pass builds C (with the input checks and the median spacing);
// the taus then sweep C in cache-sized chunks (the large octave m in an order
// that reuses each chunk for every m), per-tau sums compensated. O(N) memory
// (C, N + 1 doubles), O(N) per tau; series of >= 2^18 samples sweep on two
// threads (the result changes only by rounding).
//
// Confidence bounds: 1 sigma (68.3 %), chi-squared with the equivalent degrees
// of freedom of the overlapping estimator for the noise identified at that
// tau (identify_noise_lag1, allan_edf): white rate noise, flicker, rate random
// walk and white or flicker angle noise each have their own edf, and a random
// walk's is about half of white noise's at long tau.
//
// Noise terms read off the curve (IEEE Std 952 conventions), each a value, an
// upper bound or unavailable (NoiseTerm):
// - A line of fixed log-log slope s is fitted as log sigma = log C + s log tau,
//   C = the weighted mean of (log sigma_i - s log tau_i), weights edf_i (the
//   inverse variance of log sigma_i is ~2 edf_i; white noise's edf whatever
//   the noise identified, so a stored curve gives the same terms), over the taus whose local
//   slope is within ±0.25 of s. The local slope of point i is the log-log
//   slope between its neighbours i-1 and i+1 (one-sided at the two ends).
// - Angle random walk: the slope -½ line read at tau = 1 s (extrapolated when
//   1 s is off the grid), sigma(1 s) in °/h, divided by 60 -> °/√h.
// - Rate random walk: sigma(tau) = K sqrt(tau / 3) (tau in h, K in °/h/√h);
//   the slope +½ line read at tau = 3 s gives sigma(3 s) = K / 60, so
//   K = 60 * sigma_line(3 s).
// - Bias instability: the minimum of the curve divided by 0.664, with the tau
//   of the minimum.
// Bounds: the Allan variances of independent noises add, so each term's own
// curve lies below the measured one at every tau. When the curve shows no
// slope -½ region, ARW < sigma(tau_min) sqrt(tau_min) / 60 (its -½ line through
// the first point); no +½ region: RRW < 60 sigma(tau_max) sqrt(3 / tau_max)
// (its +½ line through the last point); the minimum at the last tau (the
// curve still falls): bias instability < sigma(tau_max) / 0.664, the floor at
// tau >= tau_max; the minimum at the first tau (the curve rises from the
// start): < sigma(tau_min) / 0.664, the floor at tau <= tau_min. The bounds use
// the estimates sigma(tau), not their confidence limits (the last tau has few
// degrees of freedom). Unavailable: fewer than 3 taus, or a sigma that is 0 or
// not finite (e.g. a constant rate).
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/analysis/sample_source.h"
#include "gyrotherm/core/result.h"

namespace gyrotherm::analysis {

// Which cluster sizes m are evaluated. All sets keep exactly the m >= 1 with
// 2m < N + 1 (at least one difference of two clusters).
//   kOctave: m = 1, 2, 4, 8, ...
//   kDecade: m = 1, 2, 5, 10, 20, 50, 100, ... (1, 2, 5 times powers of ten)
//   kAll:    every m = 1 ... N/2 — O(N^2) in total; for short records only.
enum class TauSet { kOctave, kDecade, kAll };
Result<TauSet> parse_tau_set(std::string_view s);  // "octave", "decade", "all"
std::string_view to_string(TauSet set);

// The cluster sizes of `set` for n samples, ascending (empty for n < 2).
std::vector<std::size_t> allan_cluster_sizes(std::size_t n, TauSet set);

// Equivalent degrees of freedom of the overlapping Allan variance for white
// FM noise (white rate noise for a gyro), from Howe, Allan & Barnes,
// "Properties of signal sources and measurement methods" (1981), as given in
// the simple edf formulas of NIST SP 1065 (Riley, 2008):
//   edf = (3(N-1)/(2m) - 2(N-2)/N) * 4m^2 / (4m^2 + 5)
// where N is the number of *phase* points; n rate samples integrate to
// N = n + 1 phase (angle) points. Positive for every m with 2m <= n.
double allan_edf_white_fm(std::size_t n_rate_samples, std::size_t m);

// A power-law noise S(f) ~ f^alpha of the rate, identified at one cluster
// size by the lag-1 autocorrelation method of Riley & Greenhall ("Power law
// noise identification using the lag 1 autocorrelation", EFTF 2004; NIST
// SP 1065 section 5.6): the rates are averaged in blocks of m and a straight
// line is removed; while delta = r1 / (1 + r1) (r1: the lag-1
// autocorrelation) is 0.25 or more and fewer than 2 differences were taken,
// the series is differenced. Then p = -2 (delta + d) estimates alpha.
// For a gyro's rate: alpha 0 white rate noise (angle random walk), -1
// flicker (bias instability), -2 rate random walk; +1 and +2 flicker and
// white angle noise (quantization).
struct NoiseIdentification {
  int alpha = 0;              // the estimate rounded, within [-2, 2]
  double alpha_estimate = 0;  // p = -2 (delta + d)
  int differences = 0;        // d
  double delta = 0;           // r1 / (1 + r1) of the last series
  std::size_t averages = 0;   // block means the identification used
};
// At least kMinNoiseIdAverages block means of m rates are needed; nullopt
// with fewer, or for a constant series.
inline constexpr std::size_t kMinNoiseIdAverages = 30;
std::optional<NoiseIdentification> identify_noise_lag1(std::span<const double> rate, std::size_t m);

// Equivalent degrees of freedom of the overlapping Allan variance of n rate
// samples (N = n + 1 phase points) at cluster size m, for noise alpha
// (clamped to [-2, 2]), by the simple formulas of NIST SP 1065 (Table 5,
// after Howe, Allan & Barnes 1981):
//   alpha  2: (N + 1)(N - 2m) / (2 (N - m))
//   alpha  1: exp(sqrt(ln((N - 1) / (2m)) ln((2m + 1)(N - 1) / 4)))
//   alpha  0: allan_edf_white_fm
//   alpha -1: 2 (N - 2)^2 / (2.3 N - 4.9) for m = 1, else 5 N^2 / (4m (N + 3m))
//   alpha -2: (N - 2) / m * ((N - 1)^2 - 3m (N - 1) + 4m^2) / (N - 3)^2
// Never below 1 (a formula taken beyond its range).
double allan_edf(int alpha, std::size_t n_rate_samples, std::size_t m);

struct AllanOptions {
  TauSet taus = TauSet::kOctave;

  // False with a message when taus is none of TauSet's enumerators (a
  // value cast from a number).
  bool is_valid(std::string* why) const;
};

enum class NoiseTermKind {
  kValue,        // read off the curve
  kUpperBound,   // the curve does not reach the term's region: the term is < value
  kUnavailable,  // not readable (note says why)
};
std::string_view to_string(NoiseTermKind kind);  // "value", "upper_bound", "unavailable"

// One noise term read off the curve (see the top of this file).
struct NoiseTerm {
  NoiseTermKind kind = NoiseTermKind::kUnavailable;
  double value = 0;  // the value, or the bound; 0 when unavailable. Unit of the term.
  // The tau it was read at: bias instability value: the minimum's tau; bounds:
  // the tau of the point the bound comes from (ARW: tau_min, RRW: tau_max, bias
  // instability: tau_max or tau_min). nullopt for ARW / RRW values and when
  // unavailable.
  std::optional<double> tau_s;
  // Where the term's region lies relative to tau_s: "=" (value), ">=" (not
  // reached yet, at longer tau), "<=" (at shorter tau than recorded); "" when
  // tau_s is nullopt.
  std::string tau_relation;
  std::string note;  // how it was read, or why it is a bound / unavailable; one line

  bool is_value() const { return kind == NoiseTermKind::kValue; }
  std::optional<double> value_if_read() const {
    return is_value() ? std::optional<double>(value) : std::nullopt;
  }
};

struct AllanNoiseTerms {
  NoiseTerm angle_random_walk_dprh;   // °/√h
  NoiseTerm bias_instability_dph;     // °/h
  NoiseTerm rate_random_walk_dphprh;  // °/h/√h
};

// The noise terms of a curve: tau_s ascending, adev_dph and edf per tau (all
// the same length; otherwise every term is unavailable).
AllanNoiseTerms allan_noise_terms(std::span<const double> tau_s, std::span<const double> adev_dph,
                                  std::span<const double> edf);
// The same for a stored curve without its edf: m = round(tau / tau0) and
// edf = allan_edf_white_fm(n_samples, m), as allan_deviation computed them.
AllanNoiseTerms allan_noise_terms(std::size_t n_samples, double tau0_s,
                                  std::span<const double> tau_s, std::span<const double> adev_dph);

struct AllanResult {
  double tau0_s = 0;  // median sample spacing
  std::size_t n_samples = 0;

  // Per tau, ascending; all the same length.
  std::vector<double> tau_s;         // m * tau0_s
  std::vector<std::size_t> m;        // cluster size, samples
  std::vector<double> adev_dph;      // overlapping Allan deviation
  std::vector<double> adev_lo_dph;   // adev * sqrt(edf / chi2_{0.8415}(edf))
  std::vector<double> adev_hi_dph;   // adev * sqrt(edf / chi2_{0.1585}(edf))
  std::vector<std::size_t> n_terms;  // N - 2m + 1 overlapping differences
  std::vector<double> edf;           // allan_edf(noise_alpha, N, m)
  // The noise identified at each tau (identify_noise_lag1); a tau with too
  // few block means for it takes the last identified one (white rate noise
  // when none was).
  std::vector<int> noise_alpha;

  // Noise terms (see the top of this file): value, bound or unavailable.
  AllanNoiseTerms noise;
  // The values alone (nullopt when a term is a bound or unavailable).
  std::optional<double> angle_random_walk_dprh;   // °/√h
  std::optional<double> rate_random_walk_dphprh;  // °/h/√h
  std::optional<double> bias_instability_dph;     // minimum adev / 0.664
  std::optional<double> bias_instability_tau_s;   // tau of that minimum
  std::string bias_instability_method = "minimum / 0.664";
};

// Errors (permanent): invalid options (the is_valid message); sizes differ; fewer than 2 samples; a
// non-finite time or rate (the message names the index); times not strictly increasing (names the
// index and both times).
Result<AllanResult> allan_deviation(std::span<const double> t_s, std::span<const double> rate_dph,
                                    const AllanOptions& options = {});

// The same over a streamed series (sample_source.h), in memory bounded
// whatever its length: one pass checks it and finds the median spacing
// (scan_series), a second builds the prefix sums C. Up to
// limits.prefix_in_memory samples C stays in memory and the result is
// exactly the in-memory one's (same C, same sweep). A longer series spills
// C to an unnamed scratch file (8 bytes a sample, deleted when done) and
// sweeps it in windows of limits.window: the variances then differ from the
// in-memory sweep by rounding only (each tau's sum is compensated), and the
// noise is identified from running sums of the block means fed as C is
// built (the same lag-1 statistic, rounding apart). Peak memory about
// 12 bytes x limits.window + 8 bytes x min(n, prefix_in_memory) + what the
// source holds. Errors: those of the span form (the message names the
// sample's index and time), the source's, the scratch file's (it names the
// directory), and tau set "all" on a series too long for memory (O(N^2)
// anyway).
Result<AllanResult> allan_deviation(const SampleSource& source, const AllanOptions& options = {},
                                    const StreamLimits& limits = {});

}  // namespace gyrotherm::analysis
