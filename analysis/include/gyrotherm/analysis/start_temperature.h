// Start-temperature model of the reference paper (eq. 3, docs/analysis.md), and
// coefficient export for the gyro's computer.
//
// Each run is fitted on its own with the drift model (centred form by
// default; the paper's form is biased, see kDefaultDriftModelForm),
// giving coefficients a_i (T1..T4, R1.., G1..). With runs started at >= 4
// distinct start temperatures T0, each coefficient is fitted as a cubic in T0:
//   a_i(T0) = A_i0 + A_i1 T0 + A_i2 T0^2 + A_i3 T0^3
// (least squares, in a centred and scaled T0 internally; exact interpolation
// with 4 runs). A new run is then compensated from its T0 alone: the
// coefficients a_i(T0) in eq. 1 with that run's own L0.
//
// T0 of a run: the mean shell temperature (top + side) / 2 over the points
// with t_s - t_s(first) < t0_window_s (default 120 s, the paper's "first two
// minutes"). Two start temperatures are distinct when they differ by more
// than distinct_t0_c.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <span>
#include <string>
#include <vector>

#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/core/result.h"

namespace gyrotherm::analysis {

struct StartTemperatureOptions {
  DriftModelSpec spec{.t_order = 4, .r_order = 1, .g_order = 1};
  DriftModelForm form = kDefaultDriftModelForm;
  DriftFitOptions fit;
  double t0_window_s = 120.0;
  double distinct_t0_c = 1.0;
  std::size_t min_distinct_t0 = 4;

  bool is_valid(std::string* why) const;
};

// T0 of one series (see above). Errors: empty series, non-finite values.
Result<double> start_temperature_c(const AnalysisSeries& series, double t0_window_s = 120.0);

struct StartTemperatureModel {
  DriftModelSpec spec;
  DriftModelForm form = kDefaultDriftModelForm;
  double derivative_window_s = 60.0;
  double l0_window_s = 120.0;
  double t0_window_s = 120.0;
  std::vector<double> t0_c;                                     // per run, in input order
  std::vector<std::map<std::string, double>> run_coefficients;  // per run's own fit
  // Per coefficient name (T1.., R1.., G1.., and "intercept" in the centred
  // form): A_0 ... A_3 of the cubic in T0 (physical units: coefficient unit
  // per °C^j).
  std::map<std::string, std::array<double, 4>> cubic;
  // Per coefficient: residual std of its cubic fit (0 with exactly 4 runs).
  std::map<std::string, double> cubic_residual_std;
};

// Errors (permanent): invalid options; fewer than min_distinct_t0 distinct T0
// (names the T0 found); a run whose fit fails (names the 1-based run and why).
Result<StartTemperatureModel> fit_start_temperature_model(
    std::span<const AnalysisSeries> runs, const StartTemperatureOptions& options = {});

// The drift fit for a run starting at t0_c: coefficients a_i(t0_c), usable
// with drift_terms()/predict_drift() (l0_dph = 0: the run's own L0 applies).
// A T0 outside the fitted range is allowed (extrapolation) and flagged by
// `extrapolated`.
struct StartTemperatureCoefficients {
  DriftFit fit;
  double t0_c = 0;
  bool extrapolated = false;
};
Result<StartTemperatureCoefficients> coefficients_at(const StartTemperatureModel& model,
                                                     double t0_c);

// Compensates a new run from its T0 alone: rate - drift terms with the
// coefficients at the run's T0. Errors as for start_temperature_c and
// drift_terms.
Result<std::vector<double>> compensate_from_start(const StartTemperatureModel& model,
                                                  const AnalysisSeries& series);

// Coefficient export (for the gyro's computer). Numbers are written with 17
// significant digits so they read back exactly.
struct ExportInfo {
  std::string station;           // station name
  std::string gyro_serial;       // may be empty
  std::vector<int64_t> run_ids;  // the runs the numbers come from
  std::string computed_utc;      // ISO-8601
  // The L0 window the fit used (DriftFitOptions::l0_window_s; DriftFit does
  // not carry it). The start-model export uses the model's own.
  double l0_window_s = 120.0;
  // The gyro and the run (schema v8): its model, the axis the numbers are
  // of ("" = the gyro's one axis), who ran it, why, and its tags. In the
  // JSON always; in the C header's provenance when any is set.
  std::string gyro_model = {};
  std::string axis = {};
  std::string operator_name = {};
  std::string comment = {};
  std::vector<std::string> tags = {};
};
// JSON object: {"model": "T4+R1+G1", "form": "paper", "units": {...},
// "coefficients": {"T1": ..}, "std_errors": {..}, "l0_window_s",
// "derivative_window_s", "residual_std_dph", "r_squared", "n", "runs", ...}.
std::string drift_fit_json(const DriftFit& fit, const ExportInfo& info);
// The C comment lines naming the gyro's model, axis, operator, tags and
// comment (" * Model: ...\n * Comment: ...\n"); "" when none is set, so a
// header of a run without metadata reads as before.
std::string export_metadata_c(const ExportInfo& info);
// C99 header: include guard, a comment with provenance and units, one
// `static const double` per coefficient and a `static inline double`
// function evaluating the model's temperature terms from (T °C, dT/dt °C/s,
// dT °C) by Horner's rule. `prefix` names everything (a C identifier;
// default "gyrotherm_drift"; characters other than [A-Za-z0-9_] become '_',
// and a leading digit gets a '_' in front).
std::string drift_fit_c_header(const DriftFit& fit, const ExportInfo& info,
                               const std::string& prefix = "gyrotherm_drift");
// The start-temperature model: the cubic coefficients A_ij per term, and in
// the header a function evaluating a_i(T0) and one evaluating the drift
// terms from (T0, T, dT/dt, dT). The header evaluates exactly as
// coefficients_at (Horner on A_i3 ... A_i0) and drift_terms' physical form.
// Header names: <prefix>_<term>_A[4] (A_0..A_3), <PREFIX>_N_COEFFICIENTS,
// <PREFIX>_<TERM> (index of a term), <prefix>_coefficients(t0_c, out[]),
// <prefix>_terms(t0_c, t_c, dtdt_c_per_s, dt_c).
std::string start_model_json(const StartTemperatureModel& model, const ExportInfo& info);
std::string start_model_c_header(const StartTemperatureModel& model, const ExportInfo& info,
                                 const std::string& prefix = "gyrotherm_start");

}  // namespace gyrotherm::analysis
