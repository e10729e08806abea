// When will a soak's stability gate hold? A prediction from the shell
// temperature so far, with P10/P50/P90 (docs/analysis.md, "Settle time").
//
// The gate (schedules/sequencer.h): over the last `window_s`, the shell's
// least-squares slope is below `stability_c_per_min` in magnitude and its
// mean is within `tolerance_c` of the set point. The chamber's own condition
// is not modelled: the air settles long before the shell.
//
// Model. The shell approaches its final value as a first-order lag,
//   T(t) = T_inf + A exp(-(t - t_0) / tau).
// The series is averaged into bins of `bin_s`, and (T_inf, A, 1/tau) fitted
// to the bins by nonlinear least squares (Gauss-Newton from the linear
// recursion T[k+1] = a T[k] + c that the sampled exponential satisfies,
// a = exp(-h / tau), T_inf = c / (1 - a)), with the covariance s² (J'J)^-1.
// Chamber air to shell is really a lag on a lag: the shell's response starts
// slowly (an S curve) and only later decays as one exponential, so only the
// later half of the bins past the steepest point is fitted (at least
// `min_bins` of them when there are that many).
// Prediction. From the last bin the fitted recursion is run forward, and the
// gate is evaluated on the model as the sequencer evaluates it on data
// (least-squares slope and mean over the window). The times at which it first
// holds, for (a, c) drawn from the fit's normal distribution (`draws` draws,
// a fixed seed: the prediction is deterministic), give P10, P50 and P90.
// A draw that never passes within `horizon_s` counts as infinitely late, so
// P90 (or P50) may be "beyond the horizon" (nullopt) when a final value
// outside the tolerance is likely. No prediction ("not enough curvature
// yet") while the decay is not resolved: fewer than `min_bins` bins past the
// steepest point, no decay to fit, or more than a tenth of the draws without
// a decay. A final value outside the tolerance by more than twice its
// uncertainty, from bins that span at least one time constant, is said: the
// gate would never hold.
#pragma once

#include <optional>
#include <span>
#include <string>

#include "gyrotherm/core/result.h"

namespace gyrotherm::analysis {

struct SettleGate {
  double setpoint_c = 0;
  double tolerance_c = 0.5;
  double stability_c_per_min = 0.02;
  double window_s = 600;
};

struct SettleOptions {
  double bin_s = 10;             // h, the recursion's step
  int min_bins = 12;             // fitted bins needed past the steepest point
  int draws = 400;               // Monte Carlo draws of (a, c)
  double horizon_s = 48 * 3600;  // no draw looks further ahead than this
  unsigned long long seed = 1;   // of the draws

  bool is_valid(std::string* why) const;
};

enum class SettleVerdict {
  kPredicted,  // p10 set; p50, p90 unless beyond the horizon
  kHoldsNow,   // the gate holds on the data's last window already
  kNotEnoughCurvature,
  kNeverWithinTolerance,  // the final value is outside the tolerance
};
std::string_view to_string(SettleVerdict v);  // "predicted", "holds_now", ...

struct SettlePrediction {
  SettleVerdict verdict = SettleVerdict::kNotEnoughCurvature;
  std::string note;  // one line: how, or why not
  // Station times (the series' time base) at which the gate first holds.
  std::optional<double> p10_s, p50_s, p90_s;
  // The fit (set whenever a fit was made): time constant, final value and
  // its standard uncertainty.
  std::optional<double> tau_s, final_c, final_u_c;
  int fitted_bins = 0;
};

// Predicts from the shell series (t_s strictly increasing, both finite) of
// the current settling step. With `air_c` (the chamber air at the same
// times; empty: none) the shell is modelled as driven by the measured air
// (below); without, as the first-order lag above. Errors (permanent): sizes
// differ, a value not finite or times not increasing (names the index),
// invalid gate or options.
//
// Driven by the air. The shell follows the chamber air through one lag,
// with a gain and an offset for the fixture and self-heating:
//   S[k+1] = a S[k] + b (A[k] + A[k+1]) / 2 + c        (bins of bin_s)
// fitted by least squares over every bin since the soak began (the input
// is measured, so the S curve of the lag on a lag needs no modelling), with
// the covariance widened for correlated residuals as above. The air ahead:
// if it has settled (its least-squares slope over the last stability window
// below the gate's limit) it stays at its mean over that window, else it
// relaxes to the set point with its own time constant fitted to its bins
// (A[k+1] - SP = alpha (A[k] - SP)). Each draw takes (a, b, c) from the
// fit's normal distribution, the air's level from its mean's uncertainty,
// the air's fluctuations as an AR(1) process with the lag-1 correlation and
// spread of its residuals, and the shell's misfit as white noise of the
// fit's residual spread; the gate is evaluated on that trajectory as on
// data. No prediction while a draw in ten has no decay (a >= 1) or the
// fitted bins are fewer than min_bins.
Result<SettlePrediction> predict_settle(std::span<const double> t_s,
                                        std::span<const double> shell_c, const SettleGate& gate,
                                        const SettleOptions& options = {},
                                        std::span<const double> air_c = {});

}  // namespace gyrotherm::analysis
