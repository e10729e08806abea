// Temperature drift model of the reference paper, eq. 1 (docs/analysis.md):
//
//   L - L0 = sum_i=1..m A_i T^i + sum_j=1..n B_j (dT/dt)^j + sum_k=1..q C_k dT^k
//
// on an analysis series: L the rate (°/h), T the mean shell temperature
// (top + side) / 2 (°C), dT/dt its smoothing derivative (°C/s), dT = top - side
// (°C). Two forms: the paper's (L0 = mean rate over the first l0_window_s, no
// intercept) and a centred one (intercept, each variable centred and scaled
// before its powers are taken). Both are solved in the scaled variables,
// from the Gram matrix when the scaled design is well conditioned and by a
// block-sequential Householder QR otherwise (see fit_drift_model): the extra
// memory is O(block x p), independent of the number of points. Pure functions
// of their arguments; safe to call from several threads (long series use two
// threads internally).
#pragma once

#include <cstddef>
#include <map>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/core/result.h"

namespace gyrotherm::analysis {

// Orders 0..4 of each term family; 0 = absent.
struct DriftModelSpec {
  int t_order = 0;  // powers of T, mean shell temperature
  int r_order = 0;  // powers of dT/dt
  int g_order = 0;  // powers of dT = top - side
  int parameters() const { return t_order + r_order + g_order; }
  bool operator==(const DriftModelSpec&) const = default;
};

// "T4+R1+G1": terms joined by '+', each a letter (T, R, G; case-sensitive)
// and one digit 0..4, any order, each letter at most once; "T0" or a missing
// letter = absent. Spaces around terms are ignored. Errors name the bad part:
// empty spec or term, unknown letter, order out of range, a repeated letter,
// or a spec whose terms are all of order 0.
Result<DriftModelSpec> parse_model_spec(std::string_view s);
// Canonical "T4+R1+G1": T, R, G order, order-0 terms left out; "" when empty.
std::string to_string(const DriftModelSpec& spec);

enum class DriftModelForm {
  kPaper,     // y = L - L0, no intercept, powers of x / max|x| (coefficients reported raw)
  kCentered,  // y = L, intercept, powers of (x - mean(x)) / std(x)
};
std::string_view to_string(DriftModelForm form);
// The form every fit, export and report uses unless told otherwise: the
// centred one. The paper's form is biased whenever a run does not start at
// 0 °C: L0 (the first minutes' mean rate) holds the temperature terms at the
// start temperature, a constant no term of the no-intercept model can
// represent, so the T (and correlated R, G) coefficients absorb it.
inline constexpr DriftModelForm kDefaultDriftModelForm = DriftModelForm::kCentered;
// For people: "centred form" or "the paper's form (L − L0, no intercept; biased ...)".
std::string_view form_label(DriftModelForm form);
// The model's coefficient names in design order: "intercept" (centred form),
// T1..Tm, R1..Rn, G1..Gq.
std::vector<std::string> coefficient_names(const DriftModelSpec& spec, DriftModelForm form);
// The unit of a coefficient, for people: "°/h per °C²", "°/h per °C/s", ...
std::string coefficient_unit(const std::string& name);
Result<DriftModelForm> parse_drift_model_form(std::string_view s);  // "paper", "centered"

struct DriftFitOptions {
  double derivative_window_s = 60.0;  // width of the smoothing-derivative window
  double l0_window_s = 120.0;         // L0 = mean rate over t_s - t_s[0] < l0_window_s
  std::size_t block_rows = 256;  // rows per Householder QR update; the result does not depend on it
  // A design column whose R diagonal is below rank_tolerance x the largest
  // (after the columns are scaled to unit size) makes the fit fail.
  double rank_tolerance = 1e-10;
  // Always use the Householder path (tests; see fit_drift_model).
  bool force_householder = false;

  // False with a message when a value is out of range (window <= 0 or not
  // finite, block_rows == 0, rank_tolerance not in [0, 1)).
  bool is_valid(std::string* why) const;
};

// Smoothing derivative dy/dt: at point i, the least-squares slope of a straight
// line through the points j with |t_j - t_i| <= window_s / 2 (1e-9 relative
// tolerance on the half width), the window extended where needed to hold at
// least the immediate neighbours i - 1 and i + 1 (so at least 2 points). Near the
// ends the window is simply cut off (shrunk, not shifted). t must be strictly
// increasing and finite, y finite, both of the same size >= 2 (checked by
// fit_drift_model; here violations give NaN). O(n) time, in double: where the
// spacing is exactly uniform and every window is the same i - h .. i + h, a
// sliding window sum and first moment (sum_k k y_{i+k}) restarted every 64
// points; elsewhere sliding sums of t and y relative to an anchor point,
// re-anchored every max(16, 2 x window) points, so no cancellation builds up.
std::vector<double> smoothing_derivative(std::span<const double> t_s, std::span<const double> y,
                                         double window_s);

struct DriftFit {
  DriftModelSpec spec;
  DriftModelForm form = kDefaultDriftModelForm;
  // Physical units: "T1".."T4" in °/h per °C^i, "R1".."R4" in °/h per
  // (°C/s)^j, "G1".."G4" in °/h per °C^k, "intercept" (centred form) in °/h.
  std::map<std::string, double> coefficients;
  std::map<std::string, double> std_errors;  // same keys; sigma^2 (X'X)^-1, dof = n - p
  std::size_t n = 0;
  std::size_t parameters = 0;  // p, including the intercept
  // RSS is the last diagonal element (squared) of the QR factor of [X | y],
  // not ||y||^2 - ||Q'y||^2, so a close fit loses no digits.
  double residual_std_dph = 0;  // sqrt(RSS / (n - p))
  // 1 - RSS / TSS, TSS about the mean of y (Welford, one pass); 1 when TSS = 0.
  // Can be negative in the paper form, which has no intercept.
  double r_squared = 0;
  double l0_dph = 0;  // paper form: L0 of the (first) series; 0 in the centred form
  std::vector<double> l0_per_series_dph;  // paper form: L0 of each fitted series, in order
  // 2-norm condition number of the design with its columns scaled to unit
  // norm (from the SVD of the p x p factor R).
  double condition_estimate = 0;
  // "gram", "gram+refined" or "householder" (see fit_drift_model).
  std::string solver;

  // How the fit was obtained (predict_drift uses these, not the physical
  // coefficients, to avoid cancellation in the expanded polynomials).
  double derivative_window_s = 0;
  std::vector<std::string> column_names;  // in design order
  std::vector<double> scaled_coefficients;
  double t_center = 0, t_scale = 1, r_center = 0, r_scale = 1, g_center = 0, g_scale = 1;
};

// The fit's T, R and G coefficients (design order; not the intercept) whose
// value is within `sigmas` standard errors of zero (|c| < sigmas x SE, or a
// standard error that is not finite): the data do not determine them.
std::vector<std::string> near_zero_coefficients(const DriftFit& fit, double sigmas = 2.0);
// "" when near_zero_coefficients is empty, else a sentence for people naming
// them: "T3, G1 within 2 standard errors of zero: ...".
std::string near_zero_warning(const DriftFit& fit, double sigmas = 2.0);

// Checks a series as the fits need it: its four vectors of one length, every
// value finite, t_s strictly increasing. Errors name `what`, the vector and
// the index (e.g. "run 2: top_c[17] is not finite (nan)").
Status check_analysis_series(const AnalysisSeries& series, std::string_view what);

// Least-squares fit of the model to the series (its t_s, rate_dph, top_c,
// side_c). Errors (permanent): invalid options; vectors of different lengths;
// a non-finite value (names the vector and index); t_s not strictly
// increasing; n <= p (standard errors need n - p > 0); a variable of the spec
// that is constant over the series (names it: T, R or G); a rank-deficient
// design (names the first column that is a combination of the earlier ones:
// |R_jj| / |column j| <= rank_tolerance).
// Method: L0 from the first l0_window_s of each series. One pass computes the
// mean / population std / max |x| of T, dT/dt, dT and y (sums shifted by the
// first value) and, on the Gram path, G = [X | y]'[X | y] in provisional
// variables: centres and scales from a strided sample of ~4096 points (dT/dt
// there by a difference over the derivative window), 256 rows at a time,
// never the whole design. G is then mapped exactly to the documented scaled
// variables (centred form z = (x - mean) / std, paper form z = x / max|x|) by
// the binomial expansion of the powers, G <- M G M'; when a sample centre is
// more than 0.25 std from the exact one (or a scale is off by more than 1e4)
// G is accumulated again in the documented variables instead.
// - Gram path (unless options.force_householder): G = [X | y]'[X | y] summed
//   per block and compensated across blocks (y centred in the centred form),
//   so G has a relative error of a few u ~ 1e-14 of |X|'|X|. Its columns are scaled to
//   unit norm and Cholesky-factored, R = chol(X'X), Q'y = R^-T X'y,
//   RSS = y'y - |Q'y|^2. The errors of beta, the standard errors and the
//   fitted values are then ~ kappa^2 u relative, kappa the 2-norm condition
//   number of the column-scaled design (condition_estimate): the path is
//   taken only when kappa <= 100 (errors <= ~1e-10), and falls back to
//   Householder otherwise (or when G is not positive definite). When RSS <
//   1e-4 y'y its digits are gone: one more pass over r = y - X beta gives
//   RSS = r'r - |R^-T X'r|^2 and Q'y += R^-T X'r (one step of iterative
//   refinement; solver "gram+refined").
// - Householder path (another pass): each block of options.block_rows rows stacked under the
//   current (p + 1) x (p + 1) triangular factor and re-factored by Householder
//   QR (Eigen); RSS is the last diagonal element squared.
// Then beta = R^-1 Q'y, Cov = sigma^2 R^-1 R^-T, and both are mapped linearly
// to the physical coefficients (binomial expansion of the powers of z). Series
// of >= 2^18 points run the input checks and every pass on two threads
// (halves; every sum is compensated, so the split changes the result only by
// rounding).
Result<DriftFit> fit_drift_model(const AnalysisSeries& series, const DriftModelSpec& spec,
                                 DriftModelForm form, const DriftFitOptions& options = {});

// Several series (runs) fitted together: the rows of all of them in one
// least-squares problem. Each series keeps its own L0 (paper form: y = L - L0
// of that series) and its own smoothing derivative (never across two series).
// Used by the leave-one-run-out comparison and the start-temperature model.
// Errors as above; a bad series is named by its 1-based position.
Result<DriftFit> fit_drift_model(std::span<const AnalysisSeries> runs, const DriftModelSpec& spec,
                                 DriftModelForm form, const DriftFitOptions& options = {});

// The fitted rate L (°/h) at every point of `series` (the paper form adds L0).
// Errors as for fit_drift_model's input checks.
Result<std::vector<double>> predict_drift(const DriftFit& fit, const AnalysisSeries& series);

// The temperature-induced part of the fitted rate at every point: the sum of
// the fit's T, R and G terms in physical units, i.e. the model minus its value
// at T = 0 °C, dT/dt = 0, dT = 0 (L0 and the intercept left out). The
// compensated output of the paper's Tables II-IV is rate_dph - drift_terms:
// L0 + residual in the paper form. Works on any series (a run not fitted:
// leave-one-run-out). Errors as for fit_drift_model's input checks.
Result<std::vector<double>> drift_terms(const DriftFit& fit, const AnalysisSeries& series);

}  // namespace gyrotherm::analysis
