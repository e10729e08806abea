// The gyro's noise model fitted to its Allan curve, with intervals, and the
// uncertainty of a window's mean that the model projects (docs/analysis.md,
// "Uncertainty of a mean").
//
// Model. The Allan variances of independent noises add; with white rate noise
// (angle random walk N, °/√h), flicker rate noise (bias instability B, °/h),
// rate random walk (K, °/h/√h) and a first-order Gauss-Markov process (a
// bias that wanders with variance sigma_g² and correlation time T_c, the
// form many gyros' bias instability takes), in (°/h)² with tau in s:
//   sigma²(tau) = q_n / tau + q_b + q_k * tau + q_g * a(tau / T_c)
//   q_n = 3600 N²              (sigma(1 s) = 60 N: tau in h is tau_s / 3600)
//   q_b = (2 ln 2 / pi) B²      (the flicker floor, 0.664 B; IEEE Std 952)
//   q_k = K² / (3 * 3600)       (sigma(3 s) = K / 60)
//   q_g = sigma_g²,  a(x) = (2 / x) [1 - (3 - 4 e^-x + e^-2x) / (2 x)]
//                               (IEEE Std 952 annex C: rises as a rate random
//                               walk below T_c, peaks at 0.38 sigma_g² near
//                               1.9 T_c, falls as white noise beyond)
// The same conventions as the noise terms read off the curve (allan.h).
//
// Fit. Weighted least squares of the measured Allan variances on the model,
// linear in q = (q_n, q_b, q_k, q_g) for a given T_c; T_c is tried on a grid
// (16 values, log-spaced from twice the shortest tau to twice the longest)
// and the Gauss-Markov term costs two terms' penalty (sigma_g and T_c). An
// Allan variance estimate with edf degrees
// of freedom has variance 2 sigma⁴ / edf, so the weights are edf / (2 m⁴)
// with m the model's value at that tau, iterated from the measured values
// (iteratively reweighted; a fixed number of rounds). Every q is >= 0 (a
// variance): each non-empty subset of the terms is fitted, subsets
// with a negative q are dropped, and the subset with the smallest deviance
// plus kTermPenalty per parameter wins. The deviance,
// sum edf (s²/m - 1 - ln(s²/m)), is the weighted chi² to second order for a
// model near the points, but charges a model that overshoots the few-edf
// points at long tau, whose weights the model's own values would shrink (a
// random walk fitted where a Gauss-Markov curve turns down). The penalty
// keeps a term only when the curve shows it: the overlapping Allan points
// are correlated (one fluctuation at long tau moves several of them), which
// the deviance counts as independent evidence. Selected by chi² with a
// penalty of 10, 7 % of 2 000 seeded white-noise soaks (600 and 6 000
// points) kept a spurious flicker or random-walk term, each with an
// uncertainty two to five times too large (on the safe side); by the
// deviance, 3 of 400 (NoiseModelCoverage.WhiteNoise...). The
// covariance of q is the inverse of the weighted normal matrix; it ignores
// the correlation between the overlapping Allan points, which the coverage
// tests measure (tests/analysis/noise_model_test.cpp).
//
// Intervals of N, B, K (95 %): q ± 1.96 u(q), the lower end at 0, each end
// through the square root. A term the fit left out is 0, with the upper
// limit of the fit that adds it to the chosen ones: max(q, 0) + 1.96 u(q).
//
// Uncertainty of the mean of a window of length T (s):
//   u²(T) = q_n / T + q_b + q_k * T + q_g * v(T / T_c),
//   v(x) = (2 / x) [1 - (1 - e^-x) / x].
// For white rate noise q_n / T is exactly the variance of the mean of T
// seconds (sigma² tau0 / T); for a rate random walk starting at the window's
// start q_k T is the variance of the walk's mean over T; flicker noise puts a
// floor under it, u_floor = sqrt(q_b); q_g v(T / T_c) is the variance of a
// stationary Gauss-Markov process's mean over T (sigma_g² for T << T_c,
// 2 sigma_g² T_c / T for T >> T_c). The first three are the model's Allan
// variance at tau = T; the last is not: near T_c the Allan variance is a
// third smaller than the mean's variance (0.38 against 0.57 sigma_g² at
// T = 2 T_c), and a soak's interval taken from it would cover too seldom.
// The grid's T_c is taken as exact (its uncertainty is not propagated). The
// degrees of freedom (Welch-Satterthwaite) are nu = 2 u⁴ / var(u²),
// var(u²) = g' C g with g = (1/T, 1, T, v(T / T_c)) and C the covariance of
// q; the expanded uncertainty is
// U = k u with k the Student t quantile for nu. A window whose u² is mostly
// rate random walk is flagged: one realisation of the walk shows its size
// poorly, and the interval's coverage falls below its nominal level there
// (measured in the tests).
#pragma once

#include <array>
#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include "gyrotherm/core/result.h"

namespace gyrotherm::analysis {

// A term of the fitted model with its 95 % interval, in the term's unit.
struct NoiseModelTerm {
  double value = 0;
  double lo = 0;
  double hi = 0;
  bool fitted = false;  // false: the curve does not show it; value 0, hi its upper limit
};

// The model's terms, in the order of NoiseModel::q.
inline constexpr int kNoiseTerms = 4;
inline constexpr std::size_t kGaussMarkov = 3;  // q's index of the Gauss-Markov term

struct NoiseModel {
  // (q_n, q_b, q_k, q_g) in (°/h)² s, (°/h)², (°/h)² / s, (°/h)², and their
  // covariance.
  std::array<double, kNoiseTerms> q{};
  std::array<std::array<double, kNoiseTerms>, kNoiseTerms> cov{};
  double gm_tc_s = 0;                      // T_c of the Gauss-Markov term, 0 when not fitted
  NoiseModelTerm angle_random_walk_dprh;   // N, °/√h
  NoiseModelTerm bias_instability_dph;     // B, °/h
  NoiseModelTerm rate_random_walk_dphprh;  // K, °/h/√h
  NoiseModelTerm gauss_markov_dph;         // sigma_g, °/h (T_c in gm_tc_s)
  double chi2 = 0;                         // weighted chi² of the chosen fit
  double deviance = 0;                     // its deviance (the selection's measure)
  std::size_t n_taus = 0;                  // Allan points fitted
  // The same terms fitted at the other correlation times of the grid that
  // the curve cannot tell from gm_tc_s (deviance within kGmProfileDeviance
  // of the chosen fit's): mean_uncertainty takes the largest u(T) of them
  // all, so T_c's own uncertainty is in the interval.
  struct Alternative {
    std::array<double, kNoiseTerms> q{};
    std::array<std::array<double, kNoiseTerms>, kNoiseTerms> cov{};
    double gm_tc_s = 0;
  };
  std::vector<Alternative> gm_alternatives;

  // The model's Allan deviation at tau (s), °/h.
  double adev_dph(double tau_s) const;
};

// A term is kept when it lowers the deviance by more than this.
inline constexpr double kTermPenalty = 10.0;
// Correlation times within this deviance of the best one's are kept as
// alternatives (the 95 % profile interval of one parameter: chi²(1) 0.95).
inline constexpr double kGmProfileDeviance = 3.84;

// Fits the model to an Allan curve: tau_s ascending, adev_dph and edf per
// tau, as allan_deviation returns them. Errors (permanent): sizes differ;
// fewer than 3 taus; a tau, deviation or edf that is not finite and > 0
// (names the index; a constant series has a zero deviation); taus that do
// not ascend.
// `allowed` limits the terms tried (bit i: the term of q[i]; default all):
// e.g. without the rate random walk, to ask whether a wandering bias that has
// not turned yet explains the curve as well (acquisition_target.h).
Result<NoiseModel> fit_noise_model(std::span<const double> tau_s, std::span<const double> adev_dph,
                                   std::span<const double> edf,
                                   unsigned allowed = (1u << kNoiseTerms) - 1);

struct MeanUncertainty {
  double window_s = 0;
  double u_dph = 0;         // standard uncertainty of the window's mean
  double dof = 0;           // its effective degrees of freedom (may be +inf)
  double k = 0;             // coverage factor for `coverage`
  double expanded_dph = 0;  // k * u_dph
  double coverage = 0.95;
  double floor_dph = 0;  // sqrt(q_b): what no window length gets below
  // The share of u² that is rate random walk (q_k T / u²) is over one half:
  // the interval covers less often than it says (see the top of this file).
  bool random_walk_dominated = false;
};

// u(T) of the mean of a window of `window_s` seconds under `model`, with its
// expanded uncertainty at `coverage` (0 < coverage < 1). Errors (permanent):
// a window that is not finite and > 0, a coverage outside (0, 1).
Result<MeanUncertainty> mean_uncertainty(const NoiseModel& model, double window_s,
                                         double coverage = 0.95);

// The uncertainty of the plain average of several windows' means (e.g. the
// repetitions of a set point), from each window's own: the windows' noise
// taken as independent (separate soaks),
//   u = sqrt(sum u_i²) / n,   nu = u⁴ / sum((u_i / n)⁴ / nu_i)
// (Welch-Satterthwaite; an infinite nu_i adds nothing), U = k u with k the
// Student t quantile for nu. window_s is the windows' total, floor_dph the
// floors combined the same way, random_walk_dominated set when any window's
// is. It covers the noise within the windows only: how much the bias itself
// moves from one soak to the next (repeatability) is the spread of the
// means, which it does not include. Errors (permanent): no window, a
// coverage outside (0, 1), a u_i that is not finite and >= 0.
Result<MeanUncertainty> average_uncertainty(std::span<const MeanUncertainty> windows,
                                            double coverage = 0.95);

}  // namespace gyrotherm::analysis
