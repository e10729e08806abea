// Analysis results in the station database (database.h), per DUT and
// axis (schema v8): Table I rows, drift-model fits, Allan deviations and
// the scale factor, each with the quality of its input (schema v11).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/runs.h"

struct sqlite3;

namespace gyrotherm::storage {

class Database;

// How complete a result's input was and whether the result is plausible
// (schema v11; docs/analysis.md "Result quality"). Coverage: the samples
// stored over the result's windows against those expected (window length ×
// the DUT's output rate); the longest gap: the longest stretch of a window
// without a sample. verdict "ok" or "flagged", with the reasons; a rate
// point left out of its sequence's fit is "excluded" (the reasons say
// why); a result nobody assessed (rows stored before v11, a record left
// as constructed) is "unassessed". Columns coverage_samples,
// coverage_expected, coverage, longest_gap_s, quality, quality_reasons_json.
struct ResultQuality {
  int64_t samples = 0;
  double expected = 0;                  // 0: not known (no output rate)
  std::optional<double> coverage{};     // samples / expected; nullopt: not known
  std::optional<double> longest_gap_s;  // nullopt: not known
  std::string verdict = "unassessed";   // ok, flagged, excluded, unassessed
  std::vector<std::string> reasons{};   // what a technician reads, one each
  bool flagged() const { return verdict == "flagged"; }
  bool excluded() const { return verdict == "excluded"; }
};

// The standard uncertainty of a Table I row's mean (schema v13): the noise
// model fitted to the soak's Allan curve, projected to the row's duration
// (analysis::MeanUncertainty, docs/analysis.md "Uncertainty of a mean").
// Columns bias_u_dph, bias_u_expanded_dph, bias_u_k, bias_u_dof (capped at
// kMaxStoredDof), bias_u_floor_dph, bias_u_random_walk.
struct BiasUncertainty {
  double u_dph = 0;                    // standard uncertainty of bias_mean_dph
  double expanded_dph = 0;             // k * u_dph, at 95 %
  double k = 0;                        // coverage factor (Student t for dof)
  double dof = 0;                      // effective degrees of freedom
  double floor_dph = 0;                // what no soak length gets below (bias instability)
  bool random_walk_dominated = false;  // the interval covers less than it says
};
// Degrees of freedom are stored up to this (white noise alone gives
// infinitely many; k is then 1.960 to four figures).
inline constexpr double kMaxStoredDof = 1e6;

// One Table I row (docs/analysis.md) with the inputs it was computed with.
struct SegmentStatsRecord {
  int64_t segment_id = 0;
  int64_t run_id = 0;
  // Schema v8: the DUT and axis (one row per segment, DUT and axis). ""
  // when written means the run's first DUT and its primary axis.
  std::string dut_serial;
  std::string axis;
  int segment_index = 0;
  double setpoint_c = 0;
  int64_t n = 0;
  double duration_s = 0;
  double temp_mean_c = 0;
  double bias_mean_dph = 0;
  double bias_std_dph = 0;
  double bias_std_ma_dph = 0;  // after the ma_window-point moving average
  double bias_mean_earth_removed_dph = 0;
  double bin_s = 1.0;
  int ma_window = 101;
  double earth_rate_dph = 0;        // the component that was removed
  double t_from_s = 0, t_to_s = 0;  // window, station s since run start
  std::string computed_utc;         // ISO-8601 UTC; "" = now
  ResultQuality quality;            // schema v11: over the soak's windows
  // Schema v13: nullopt for rows stored before it, or when the soak gave
  // no noise model; bias_u_note then says why (column bias_u_note).
  std::optional<BiasUncertainty> bias_u;
  std::string bias_u_note;
};

// A stored drift-model fit (paper eq. 1) with what it was computed from.
struct FitRecord {
  int64_t id = 0;
  std::string dut_serial;        // schema v8; "" = the runs' first DUT
  std::string axis;              // schema v8; "" = its primary axis
  std::vector<int64_t> run_ids;  // the runs whose data were fitted
  std::string model;             // e.g. "T4+R1+G1"
  std::string form;              // paper, centered
  int64_t n = 0;
  std::string coefficients_json;     // JSON object, physical units
  std::string standard_errors_json;  // JSON object, same keys
  double residual_std_dph = 0;
  double r_squared = 0;
  std::string inputs_json;   // JSON object
  std::string computed_utc;  // "" = now (add_fit)
  ResultQuality quality;     // schema v11: over the stretches fitted
};

// The Allan deviation of one soak's acquisition (docs/analysis.md) with what it
// was computed from (schema v4, table `allan`). The curve is stored as JSON
// arrays of the same length so sqlite3's json functions can read it.
struct AllanRecord {
  int64_t id = 0;
  int64_t run_id = 0;
  std::string dut_serial;  // schema v8, as SegmentStatsRecord
  std::string axis;
  int64_t segment_id = 0;           // the soak's segment (0: not tied to a segment)
  int segment_index = 0;            // 0-based step index
  double t_from_s = 0, t_to_s = 0;  // samples used, station s since run start
  std::string taus;                 // octave, decade, all
  double tau0_s = 0;
  int64_t n_samples = 0;
  std::vector<double> tau_s, adev_dph, adev_lo_dph, adev_hi_dph;  // same length
  // Per tau, from the computation that made the record; not stored (empty
  // when read back): the edf of the bounds and the noise identified
  // (analysis::AllanResult::edf, noise_alpha).
  std::vector<double> edf;
  std::vector<int> noise_alpha;
  std::optional<double> angle_random_walk_dprh;  // °/√h
  std::optional<double> bias_instability_dph;    // minimum / 0.664
  std::optional<double> bias_instability_tau_s;
  std::optional<double> rate_random_walk_dphprh;  // °/h/√h
  std::string bias_instability_method = "minimum / 0.664";
  std::string inputs_json;   // JSON object: windows, taus, ...
  std::string computed_utc;  // "" = now (put_allan)
  ResultQuality quality;     // schema v11: over [t_from_s, t_to_s)
};

// One rate point of a scale-factor sequence (schema v7, table
// scale_factor_points): the gyro's mean output against the table's rate over
// the point's acquisition windows. Rates in °/s (the gyro output converted
// from °/h). NaN is stored as NULL and read back as NaN.
struct ScaleFactorPointRecord {
  int64_t id = 0;          // set when read
  int64_t run_id = 0;      // 0: the run store_scale_factor() is given
  std::string dut_serial;  // schema v8, as SegmentStatsRecord
  std::string axis;
  int64_t segment_id = 0;        // the rate point's segment (0: not tied to one)
  int sf_sequence = 0;           // segments.sf_sequence
  int repetition = 0;            // segments.sf_repetition
  double rate_dps = 0;           // demanded table rate
  double measured_rate_dps = 0;  // table rate measured over the windows
  double output_dps = 0;         // mean gyro output over the windows
  int64_t n = 0;                 // gyro samples averaged
  double temperature_c = 0;      // mean shell temperature (top + side) / 2
  double duration_s = 0;         // acquisition time, station s
  double turns = 0;              // table turns over the acquisition
  // Schema v11: cut from each end of each acquisition window before the
  // mean (docs/analysis.md "Rate points"), station s; the quality is over
  // what is left. verdict "excluded": left out of the sequence's fit.
  double guard_s = 0;
  ResultQuality quality;
};

// The fit output = K * rate + bias of one scale-factor sequence (table
// scale_factor_fits; docs/analysis.md defines the figures).
struct ScaleFactorFitRecord {
  int64_t run_id = 0;      // 0: the run store_scale_factor() is given
  std::string dut_serial;  // schema v8, as SegmentStatsRecord
  std::string axis;
  int sf_sequence = 0;
  double temperature_c = 0;  // mean temperature of the sequence's points
  double k = 0;              // scale factor, (°/s) / (°/s)
  double k_se = 0;           // its standard error
  double bias_dps = 0;
  double nonlinearity_ppm = 0;                // relative to K
  double nonlinearity_fs_ppm = 0;             // relative to the full-scale output
  std::optional<double> asymmetry_ppm{};      // nullopt: one direction only
  std::optional<double> repeatability_ppm{};  // nullopt: fewer than 2 repetitions
  int64_t n_points = 0;
  std::string created_utc{};  // ISO-8601 UTC; "" = now (store_scale_factor)
  double guard_s = 0;         // schema v11: the points' guard bands, station s
  ResultQuality quality{};    // schema v11: over the points fitted
};

// K(T) and bias(T) of a run as polynomials in (T - t_centre_c) (table
// scale_factor_temperature_fits, column poly_order for `order`). The
// coefficients are JSON arrays of numbers, lowest power first; bias in °/s.
struct ScaleFactorTemperatureFitRecord {
  int64_t run_id = 0;      // 0: the run store_scale_factor() is given
  std::string dut_serial;  // schema v8, as SegmentStatsRecord
  std::string axis;
  int order = 0;  // polynomial degree
  double t_centre_c = 0;
  std::string k_coeffs_json{};     // e.g. "[1.0000123, 2.1e-6]"; "" stores "[]"
  std::string bias_coeffs_json{};  // °/s; "" stores "[]"
  double k_ppm_per_c = 0;          // dK/dT / K at t_centre_c, ppm/°C
  double bias_dph_per_c = 0;       // dbias/dT at t_centre_c, (°/h)/°C
  std::string created_utc{};       // "" = now (store_scale_factor)
};

// Part of Database (database.h): call these on a Database. Defined in
// storage/src/results.cpp (Table I rows, Allan deviations, fits) and
// storage/src/scale_factor.cpp (the scale factor).
class ResultStore {
 public:
  // Table I rows. put_segment_stats inserts or replaces by (segment, DUT,
  // axis); dut_serial/axis "" are resolved when the run has DUTs (the first
  // DUT, its primary axis; docs/storage.md "Results per DUT and axis"); a
  // serial not in the run is refused. Storing a DUT's primary axis replaces
  // that DUT's row of the segment stored before v8 (axis '').
  Status put_segment_stats(const SegmentStatsRecord& stats);
  // All rows (run_id nullopt) or one run's, ordered by run, segment index,
  // DUT position in the run, serial, axis.
  Result<std::vector<SegmentStatsRecord>> segment_stats(std::optional<int64_t> run_id);

  // Fits.
  // The DUT and axis are resolved against the first of run_ids, as
  // put_segment_stats does.
  Result<int64_t> add_fit(const FitRecord& fit);
  // A run's fits (every fit that used it), newest first.
  Result<std::vector<FitRecord>> fits(int64_t run_id);
  Result<std::optional<FitRecord>> fit(int64_t fit_id);

  // Allan deviation. put_allan inserts, or replaces the row of the same
  // (run_id, segment_index, taus, dut_serial, axis), DUT and axis resolved
  // as put_segment_stats does; returns the row id.
  Result<int64_t> put_allan(const AllanRecord& allan);
  // A run's Allan records, by segment_index, DUT position, serial, axis,
  // taus.
  Result<std::vector<AllanRecord>> allan(int64_t run_id);

  // Scale factor (schema v7). store_scale_factor replaces the points,
  // fits and temperature fit (none stored when `temperature_fit` is nullopt)
  // of one DUT and axis of the run (schema v8) in one transaction: after a
  // failure the previous rows are intact; other DUTs' and axes' rows stay.
  // The DUT and axis are the ones the records name (dut_serial/axis; every
  // record naming one must name the same, else refused naming both); when
  // none names one, the run's first DUT and its primary axis.
  // Records with run_id 0 take `run_id`; another run_id is refused (named).
  // Rows are stamped created_utc from the wall clock when theirs is "".
  Status store_scale_factor(int64_t run_id, const std::vector<ScaleFactorPointRecord>& points,
                            const std::vector<ScaleFactorFitRecord>& fits,
                            const std::optional<ScaleFactorTemperatureFitRecord>& temperature_fit);
  // The same for the DUT and axis `stream` names (resolved like results:
  // "" = the run's first DUT, its primary axis). Records with dut_serial
  // or axis "" take the stream's; a record naming another is refused.
  Status store_scale_factor(int64_t run_id, const StreamKey& stream,
                            const std::vector<ScaleFactorPointRecord>& points,
                            const std::vector<ScaleFactorFitRecord>& fits,
                            const std::optional<ScaleFactorTemperatureFitRecord>& temperature_fit);
  // Every DUT and axis of the run: by DUT position, serial, axis, then
  // sf_sequence, repetition, demanded rate.
  Result<std::vector<ScaleFactorPointRecord>> scale_factor_points(int64_t run_id);
  // Every DUT and axis: by DUT position, serial, axis, then sf_sequence.
  Result<std::vector<ScaleFactorFitRecord>> scale_factor_fits(int64_t run_id);
  // The run's first DUT, primary axis (as before v8: the run's one fit).
  Result<std::optional<ScaleFactorTemperatureFitRecord>> scale_factor_temperature_fit(
      int64_t run_id);
  // One DUT and axis ("" as in store_scale_factor).
  Result<std::optional<ScaleFactorTemperatureFitRecord>> scale_factor_temperature_fit(
      int64_t run_id, const StreamKey& stream);
  // Every DUT and axis of the run, by DUT position, serial, axis.
  Result<std::vector<ScaleFactorTemperatureFitRecord>> scale_factor_temperature_fits(
      int64_t run_id);

 private:
  friend class Database;
  ResultStore() = default;
  ~ResultStore() = default;
  ResultStore(const ResultStore&) = delete;
  ResultStore& operator=(const ResultStore&) = delete;
  // The Database this store is part of, its connection and its path
  // (results.cpp).
  Database& self();
  sqlite3* db();
  const std::string& path();
};

}  // namespace gyrotherm::storage
