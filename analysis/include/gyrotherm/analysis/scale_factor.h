// Scale-factor calibration on a rate table (docs/analysis.md, "Scale
// factor"): the least-squares line output = K·Ω + B through the mean gyro
// output at each table rate, its nonlinearity, asymmetry and repeatability
// (IEEE Std 952 practice), K and B as polynomials in temperature, and the
// Earth-rate projection on the sensitive axis of a table at rest.
//
// Units: table rates Ω and gyro outputs in °/s (the output converted to the
// table's unit, so K is dimensionless and near 1); biases also in °/h;
// ratios in ppm. Pure functions of their arguments, safe from any thread.
// The line is fitted from centred sums (two passes; for a straight line this
// is as stable as a QR factorisation): about 1e-15 relative to the largest
// output in the fitted values.
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"

namespace gyrotherm::analysis {

// One dwell at a constant table rate.
struct RatePoint {
  double rate_dps = 0;       // table rate: demanded, or the measured mean over the dwell
  double output_dps = 0;     // mean gyro output over the dwell, °/s
  int repetition = 1;        // which pass through the rate sequence (repeatability)
  double temperature_c = 0;  // mean temperature over the dwell (carried, not fitted)
  std::size_t n = 0;         // gyro samples averaged (carried, not fitted)
  double duration_s = 0;     // dwell length (carried, not fitted)
};

// K of one repetition, fitted on that repetition's points alone.
struct RepetitionScaleFactor {
  int repetition = 0;
  std::size_t points = 0;
  double k = 0;
  double bias_dps = 0;
};

struct ScaleFactorFit {
  std::size_t points = 0;
  std::size_t distinct_rates = 0;
  double full_scale_dps = 0;      // max |Ω| over the points
  double temperature_mean_c = 0;  // mean of the points' temperature_c

  double k = 0;  // scale factor, (°/s out) per (°/s in)
  double bias_dps = 0;
  double bias_dph = 0;
  // Standard errors from s² = RSS / (points − 2) and (XᵀX)⁻¹; NaN with
  // exactly 2 points (no degree of freedom left).
  double k_std_error = 0;
  double bias_std_error_dps = 0;
  double bias_std_error_dph = 0;
  double residual_std_dps = 0;  // s; NaN with exactly 2 points

  // output_i − (K·Ω_i + B), °/s, in input order.
  std::vector<double> residuals_dps;

  // Relative to K: max over points with Ω ≠ 0 of |residual_i| / |K·Ω_i|, ppm;
  // the point where it is largest.
  double nonlinearity_ppm = 0;
  std::size_t nonlinearity_point = 0;
  // Relative to the full-scale output: max over all points of
  // |residual_i| / (|K| · full_scale_dps), ppm.
  double nonlinearity_fs_ppm = 0;

  // K₊, K₋ and B± minimise Σ (yᵢ − K₊·Ωᵢ⁺ − K₋·Ωᵢ⁻ − B±)² over all points
  // (Ω⁺ = max(Ω, 0), Ω⁻ = min(Ω, 0); one bias shared by both directions),
  // solved by Householder QR on the rates scaled by the full scale;
  // asymmetry = (K₊ − K₋) / ((K₊ + K₋)/2) × 1e6, ppm. An output
  // K(1 ± a/2)·Ω + B gives back a exactly whatever the rates; an even error
  // (Q·Ω²) still reads as asymmetry (docs/analysis.md). All four nullopt
  // unless a rate > 0 and a rate < 0 were measured and there are ≥ 3
  // distinct rates (with only +a and −b, K₊, K₋ and B± are not determined).
  std::optional<double> k_positive;
  std::optional<double> k_negative;
  std::optional<double> asymmetry_bias_dps;  // B± of that fit, °/s
  std::optional<double> asymmetry_ppm;

  // One entry per repetition number that has ≥ 2 distinct rates, in
  // increasing repetition order (repetitions with fewer are left out).
  std::vector<RepetitionScaleFactor> repetitions;
  // Sample std (ddof 1) of the repetitions' K / their mean × 1e6, ppm;
  // nullopt with fewer than 2 such repetitions.
  std::optional<double> repeatability_ppm;
};

// Fits output = K·Ω + B over all points (every repetition together).
// Errors (permanent, naming the point's index and field): no points; a rate,
// output, temperature or duration that is NaN or infinite; fewer than 2
// distinct rates (a constant rate leaves K undetermined).
Result<ScaleFactorFit> fit_scale_factor(std::span<const RatePoint> points);

// ---- Rate points from a CSV file ---------------------------------------------
// `gyrotherm scale-factor --csv FILE`: one row per dwell, columns rate_dps and
// output_dps (°/s, required), repetition (a whole number; 1 when the column
// is absent) and temperature_c (°C; 0 when absent), in any order, other
// columns ignored. The format rules and the errors (file:line: column ...)
// are those of analysis/csv_window.h; a repetition that is not a whole number
// between −1e9 and 1e9 is refused the same way.
struct RatePointsCsv {
  std::string source;
  std::vector<RatePoint> points;   // in file order
  std::vector<std::size_t> lines;  // the file line of each point
  bool has_repetition = false;
  bool has_temperature = false;
};
Result<RatePointsCsv> parse_rate_points_csv(std::string_view text, const std::string& source_name);
Result<RatePointsCsv> read_rate_points_csv(const std::string& path);

// ---- Over temperature -----------------------------------------------------

// The result of one plateau's fit.
struct ScaleFactorAtTemperature {
  double temperature_c = 0;
  double k = 0;
  double bias_dph = 0;
};

struct ScaleFactorTemperatureFit {
  int order = 0;
  std::size_t temperatures = 0;   // plateaus given
  double temperature_mean_c = 0;  // T̄, the mean of the plateaus' temperatures
  // K(T) = Σⱼ k_coefficients[j] · (T − T̄)ʲ, j = 0 … order (per °Cʲ).
  std::vector<double> k_coefficients;
  // B(T) = Σⱼ bias_coefficients_dph[j] · (T − T̄)ʲ, °/h per °Cʲ.
  std::vector<double> bias_coefficients_dph;
  double k_at_mean = 0;  // K(T̄) = k_coefficients[0]
  // (dK/dT at T̄) / K(T̄) × 1e6 = k_coefficients[1] / k_coefficients[0] × 1e6.
  double sf_temperature_coefficient_ppm_per_c = 0;
  // dB/dT at T̄ = bias_coefficients_dph[1], (°/h)/°C.
  double bias_temperature_coefficient_dph_per_c = 0;
  // Data − polynomial, in input order (all 0 when order = distinct − 1).
  std::vector<double> k_residuals;
  std::vector<double> bias_residuals_dph;
};

// Least squares (Householder QR on (T − T̄) / max|T − T̄|, the coefficients
// scaled back). Errors (permanent): order not 1 or 2; order ≥ the number of
// distinct temperatures; a non-finite value (naming the plateau's index and
// field); K(T̄) = 0.
Result<ScaleFactorTemperatureFit> fit_scale_factor_over_temperature(
    std::span<const ScaleFactorAtTemperature> plateaus, int order);

// ---- Flatness of a rate point ---------------------------------------------

// Whether a rate point's samples are flat (docs/analysis.md "Rate
// points"), samples in time order: the means of the first and last thirds
// (by count) agree within n_sigma · √(s₁²/n₁ + s₃²/n₃) + tolerance_ppm ·
// 10⁻⁶ · |Ω| (s the thirds' sample std, ddof 1; Ω the demanded rate).
// With `at_demand` (the table's own rate readings), each third's mean must
// also be Ω within n_sigma · s/√n + tolerance_ppm · 10⁻⁶ · |Ω|. The gyro's
// output is checked for flatness only (its K and bias are what the fit
// finds). Fewer than 6 finite samples: not checked (checked false, ok true).
// Invalid options: checked, not ok, `why` the is_valid message.
struct RatePointFlatnessOptions {
  double n_sigma = 5.0;
  double tolerance_ppm = 500.0;

  // False with a message naming the field when n_sigma is not positive or
  // tolerance_ppm is negative (or either is not finite).
  bool is_valid(std::string* why) const;
};
struct RatePointFlatness {
  bool checked = false;
  bool ok = true;
  double first_mean = 0, last_mean = 0;  // in the samples' unit
  double tolerance = 0;                  // of first − last
  std::string why;                       // what failed, with the numbers, when !ok
};
RatePointFlatness check_rate_point_flatness(std::span<const double> samples, double demanded_dps,
                                            const RatePointFlatnessOptions& options,
                                            bool at_demand = false);

// ---- Earth rate at a static table position ---------------------------------

// How the gyro's sensitive axis is mounted on the table (the [table]
// sensitive_axis setting).
enum class SensitiveAxis {
  kAlongTable,  // parallel to the table's rotation axis, which points up
  kRadial,      // horizontal, turning with the table
};
Result<SensitiveAxis> parse_sensitive_axis(std::string_view s);  // "along_table", "radial"
std::string_view to_string(SensitiveAxis axis);

// Earth-rate component on the sensitive axis, °/h, with Ω_E = 15.041067 °/h
// (units::kEarthRateDph) and φ the latitude:
//   along_table: Ω_E · sin φ, whatever the position (earth_rate_component_dph, up);
//   radial:      Ω_E · cos φ · cos(heading_at_zero_deg + position_deg),
// heading_at_zero_deg the axis' azimuth (from north, clockwise seen from
// above) at table position 0, the position counted the same way.
double earth_rate_projection_dph(double latitude_deg, SensitiveAxis axis,
                                 double heading_at_zero_deg, double position_deg);

}  // namespace gyrotherm::analysis
