// Analysis of stored runs (docs/analysis.md): what the daemon computes and
// stores after each run, and what `gyrotherm stats|allan|fit|compare` compute
// offline from a database. One code path, so the CLI reproduces the stored
// numbers exactly.
//
// - Table I: per completed soak, on its acquisition windows (pauses cut out),
//   each window binned on its own and the series joined.
// - Allan deviation: per completed soak, on the samples as recorded of its
//   longest acquisition window (the overlapping estimator needs evenly spaced
//   samples; the window used is stored in the record's inputs).
// - Drift model: on the whole run's analysis series (every recorded sample,
//   soaks and ramps, binned; gaps are not filled), in the paper and the
//   centred forms.
// Every stored result carries its inputs (runs, windows, model, options) as
// JSON so it can be reproduced.
//
// Per DUT and axis (schema v8): each of the above is computed for every DUT
// of the run (run_duts) and every axis it analyses (analysed_axes), and the
// records carry the DUT's serial and the axis. A run without DUT records
// (stored before schema v8, or a database not migrated) has one stream: its
// gyro, serial "" and axis "" (the first DUT's primary axis).
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/quality.h"
#include "gyrotherm/analysis/scale_factor.h"
#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/config/run_config.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::calibration {

// The [analysis] settings of a station (or the CLI's options).
struct AnalysisSettings {
  analysis::Table1Options table1;  // bin_s, ma_window, earth_rate_dph
  analysis::TauSet allan_taus = analysis::TauSet::kOctave;
  analysis::DriftModelSpec model{.t_order = 4, .r_order = 1, .g_order = 1};
  // Stored in this order: the default (unbiased, centred) form first, then
  // the paper's form for comparison with the paper.
  std::vector<analysis::DriftModelForm> forms = {analysis::kDefaultDriftModelForm,
                                                 analysis::DriftModelForm::kPaper};
  std::size_t compare_smooth_points = 101;  // Tables II-IV, [analysis] compare_smooth_points
  analysis::DriftFitOptions fit;            // derivative_window_s, l0_window_s
  // Rate points: [analysis] rate_guard_s, rate_flatness_sigma and
  // rate_flatness_ppm.
  double rate_guard_s = 1.0;
  analysis::RatePointFlatnessOptions flatness;
  analysis::QualityRules quality;  // [quality]
};
// From the config: [analysis] and the Earth rate of [station] latitude and
// orientation. The model spec was checked when the config was loaded.
AnalysisSettings analysis_settings(const config::StationConfig& config);

// read_run_config() (run_config.h) of a stored run: its runs.config_json,
// or for runs stored before schema v6 its runs.config_toml.
config::RunConfig read_run_config(const storage::RunRecord& run);

// The settings a stored run is analysed with offline (reports, the CLI's
// defaults): its own config's [analysis] over the defaults, and the Earth
// rate of the run's latitude and orientation. A stored value that does not
// parse (model, taus, orientation) is an error naming the run and the value.
Result<AnalysisSettings> analysis_settings_of_run(const storage::RunRecord& run);

// One rate series of a run the analysis runs on: a DUT and one of its
// analysed axes.
struct AnalysedAxis {
  std::string dut_serial;  // "" = the unnamed gyro
  std::string dut_model;
  std::string axis;  // "x", "y", "z"; "" = the primary axis of a run without DUT records
  int dut_position = 0;
  bool primary = true;  // the DUT's primary axis
  // The axis's direction for the Earth-rate removal, from the DUT's stored
  // config (run_duts.config_json "orientation"); nullopt: not stored, the
  // run's orientation applies (Table1Options::earth_rate_dph as given).
  std::optional<analysis::AxisOrientation> orientation;
  // A horizontal axis's heading, degrees from true north, clockwise (the
  // stored "heading_deg"; at table position 0 on a run with a table, where
  // the axis turns with the table): its Earth-rate component is
  // Ω·cos φ·cos(heading [+ the table's position]). nullopt (runs stored
  // before headings, or none given): 0, the axis taken as east–west.
  std::optional<double> heading_deg;
  // The axis along the rate table's spin axis (the DUT's table_axis; the
  // primary axis when not stored): the scale factor, and the table's
  // radial/along-table rule of Table I, are for this axis.
  bool table_axis = true;
  // Index of the rate channel (channels.id); 0 for a run without DUT
  // records (read through the first-DUT API).
  int64_t channel_id = 0;
  // The DUT's shell probes, when its config has them ([[dut]] probes):
  // see dut_shell_readings().
  bool own_probes = false;
  // Nominal output rate (run_duts.rate_hz; a run without DUT records: its
  // [gyro] rate_hz), Hz; 0 when not recorded (coverage then takes the
  // median spacing of the samples).
  double rate_hz = 0;
  storage::StreamKey key() const { return {dut_serial, axis}; }
  // "SN 17-0042 z" / "the gyro": how messages and reports name it.
  std::string name() const;
};
// The run's DUTs (by position) and their analysed axes (primary axis
// first, then the others in x, y, z order); one stream {"" , ""} for a run
// without DUT records. Errors: unknown run, database errors, a stored
// orientation that does not parse (names the DUT and axis).
Result<std::vector<AnalysedAxis>> analysed_axes(storage::Database& db, int64_t run_id);
// The stream an old-style call means: the run's first DUT, primary axis.
Result<AnalysedAxis> first_axis(storage::Database& db, int64_t run_id);
// A short, file-name-safe tag of a stream: "" when the run's only stream is
// the unnamed gyro's primary axis (the files keep today's names), else
// "-<serial>-<axis>" (serial "" -> "unnamed"; characters other than
// [A-Za-z0-9._-] become '_').
std::string file_suffix(const AnalysedAxis& axis, bool only_stream);

// A completed soak of a run and its acquisition windows.
struct SoakWindow {
  int64_t run_id = 0;
  int64_t segment_id = 0;
  int segment_index = 0;  // 0-based step index
  double setpoint_c = 0;
  double t_from_s = 0, t_to_s = 0;                 // first window start, last window end
  std::vector<std::pair<double, double>> windows;  // station s since run start
};
// The completed soaks of a run that have at least one acquisition window, in
// step order. Errors: unknown run (names it), database errors.
Result<std::vector<SoakWindow>> soak_windows(storage::Database& db, int64_t run_id);

// The soak's analysis series: each window binned on its own (bin_s), joined.
Result<analysis::AnalysisSeries> soak_series(storage::Database& db, const SoakWindow& soak,
                                             double bin_s);
Result<analysis::AnalysisSeries> soak_series(storage::Database& db, const SoakWindow& soak,
                                             double bin_s, const AnalysedAxis& axis);

// The shell temperatures a DUT's series is binned against, in [from_s,
// to_s), rows with both probes only. Hook for DUTs with their own probes
// ([[dut]] probes): today every DUT uses the station's top/side probes
// (the rows of the temperatures table); when a DUT's own probe readings
// are stored, this is where they are read instead.
Result<std::vector<TemperatureSample>> dut_shell_readings(storage::Database& db, int64_t run_id,
                                                          const AnalysedAxis& axis, double from_s,
                                                          double to_s);

// The gyro samples as recorded of the soak's longest window (for Allan).
struct RecordedSamples {
  double t_from_s = 0, t_to_s = 0;  // the window used
  std::vector<double> t_s, rate_dph;
};
Result<RecordedSamples> soak_recorded_samples(storage::Database& db, const SoakWindow& soak);
Result<RecordedSamples> soak_recorded_samples(storage::Database& db, const SoakWindow& soak,
                                              const AnalysedAxis& axis);

// The whole run's analysis series of one stream, streamed: the rate
// channel is read a storage block at a time (Database::
// for_each_channel_block) and binned 600 s of station time at a time, so
// memory is bounded by one such stretch (at 1 kHz: 6e5 samples, ~15 MB)
// plus the 1 s series itself (32 bytes a bin: 9 MB for 80 h), whatever the
// run's length. Errors: a run without samples (names it), database errors,
// those of make_analysis_series. The first form: the run's first DUT,
// primary axis.
//
// The series is of the gyro at rest: left out are the steps that demanded
// a rate (to their end + 10 s) and every stretch where the table was not
// at rest by its own record (table_samples: |rate| above the run's [table]
// rest_rate_dps, or the position moving), from the last reading at rest
// before to the first after, widened by 10 s each side.
// `coverage`, when given: the stretches left out, and the coverage of the
// rest of the run's steps (each from its start to its end; a step not ended
// yet to the last sample).
struct RunSeriesCoverage {
  std::vector<std::pair<double, double>> excluded;  // merged, in time order
  analysis::Coverage coverage;
};
Result<analysis::AnalysisSeries> run_series(storage::Database& db, int64_t run_id, double bin_s);
Result<analysis::AnalysisSeries> run_series(storage::Database& db, int64_t run_id, double bin_s,
                                            const AnalysedAxis& axis,
                                            RunSeriesCoverage* coverage = nullptr);
// A drift fit's quality: the coverage of its series (several runs' summed,
// the longest gap of any) and the rules' verdict on it and on the
// residual against the series' noise (analysis::series_noise_dph of each
// series, the largest).
storage::ResultQuality fit_quality(const analysis::DriftFit& fit,
                                   std::span<const analysis::AnalysisSeries> series,
                                   std::span<const analysis::Coverage> coverage,
                                   const analysis::QualityRules& rules);

// Compute and return (not stored).
// Every record carries its quality (storage::ResultQuality): coverage over
// its windows against the axis's output rate, and the verdict of `rules`
// (docs/analysis.md "Result quality").
// The first forms: the run's first DUT, primary axis (options.earth_rate_dph
// unless its stored config gives the axis an orientation). Per axis: the
// Earth rate of the axis's orientation at the run's latitude (given
// options.earth_rate_dph when the orientation is not stored); for the
// DUT's table axis on a table with a radial sensitive axis, the projection
// of the table's recorded position (as before DUTs).
Result<storage::SegmentStatsRecord> soak_table1(storage::Database& db, const SoakWindow& soak,
                                                const analysis::Table1Options& options);
Result<storage::SegmentStatsRecord> soak_table1(storage::Database& db, const SoakWindow& soak,
                                                const analysis::Table1Options& options,
                                                const AnalysedAxis& axis,
                                                const analysis::QualityRules& rules = {});
Result<storage::AllanRecord> soak_allan(storage::Database& db, const SoakWindow& soak,
                                        analysis::TauSet taus);
Result<storage::AllanRecord> soak_allan(storage::Database& db, const SoakWindow& soak,
                                        analysis::TauSet taus, const AnalysedAxis& axis,
                                        const analysis::QualityRules& rules = {});
// A result's quality from its coverage and the reasons it is flagged
// (none: verdict "ok").
storage::ResultQuality result_quality(const analysis::Coverage& coverage,
                                      std::vector<std::string> reasons);
// A Table I row's mean uncertainty as stored (nullopt stays nullopt), and
// back (the CLI's --stored rows).
std::optional<storage::BiasUncertainty> bias_uncertainty_record(
    const std::optional<analysis::MeanUncertainty>& u);
std::optional<analysis::MeanUncertainty> mean_uncertainty_of(const storage::SegmentStatsRecord& r);
// A stored Table I row as the analysis' row (its numbers, bias_u and its
// note; the series and MA window stay empty).
analysis::Table1Row table1_row_of(const storage::SegmentStatsRecord& r);
// Its JSON form wherever results are shown (REST, the CLI, exports):
// {"window_s", "u_dph", "dof", "k", "expanded_dph", "coverage", "floor_dph",
// "random_walk_dominated"}, a non-finite number (infinite dof) as null;
// null for nullopt.
nlohmann::json mean_uncertainty_json(const std::optional<analysis::MeanUncertainty>& u);
// Windows sorted by start, overlapping ones merged.
std::vector<std::pair<double, double>> sorted_windows(
    std::vector<std::pair<double, double>> windows);

// A fit as a record ready for Database::add_fit (inputs_json filled in).
storage::FitRecord fit_record(const analysis::DriftFit& fit, const std::vector<int64_t>& run_ids,
                              const analysis::DriftFitOptions& options, double bin_s);

// Everything above for one completed run, stored: Table I rows, Allan records
// and fits. A part that cannot be computed (a soak too short for the moving
// average, a fit of a run at one constant temperature) is not an error of
// the whole: it is listed in `problems` (one line each, naming the part) and
// the rest is still stored. Errors: database failures only.
struct RunAnalysisSummary {
  int streams = 0;  // DUT axes analysed
  int table1_rows = 0;
  int allan_records = 0;
  std::vector<int64_t> fit_ids;
  int scale_factor_points = 0;     // rate points stored (0: the run had none)
  int scale_factor_sequences = 0;  // lines fitted
  std::vector<std::string> problems;
  // Results stored flagged (storage::ResultQuality), one line each naming
  // the result and its reasons.
  std::vector<std::string> flagged;
};
Result<RunAnalysisSummary> analyse_run(storage::Database& db, int64_t run_id,
                                       const AnalysisSettings& settings);

}  // namespace gyrotherm::calibration
