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
#pragma once

#include <cstdint>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::daemon {

struct StationConfig;

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
};
// From the config: [analysis] and the Earth rate of [station] latitude and
// orientation. The model spec was checked when the config was loaded.
AnalysisSettings analysis_settings(const StationConfig& config);

// The configuration a run is stored with (runs.config_json): the station
// config in force, as loaded at start-up and completed with the defaults,
// as a JSON object laid out like the TOML file ({"station": {"name": ...},
// "analysis": {"ma_window": 101, ...}, ...}); API tokens are replaced by
// "<redacted>" (the lists keep their length).
nlohmann::json run_config_json(const StationConfig& config);

// What a run's stored station config says under [analysis] and [station]
// name: runs.config_json (JSON), or for runs stored before schema v6
// runs.config_toml (the config file's TOML text). Read leniently: a config
// that is missing or does not parse, or a key of the wrong type, leaves the
// value unset. The text overload takes either (JSON when it starts with '{').
struct RunConfig {
  std::optional<double> bin_s, l0_window_s, derivative_window_s;
  std::optional<int> ma_window, compare_smooth_points;
  std::optional<std::string> model;
  std::optional<std::string> allan_taus;
  std::string station_name;
  // [table]: whether the run had one, and how the gyro sits on it.
  bool table_present = false;
  std::optional<std::string> table_sensitive_axis;
  std::optional<double> table_heading_at_zero_deg;
};
RunConfig read_run_config(const std::string& text);
RunConfig read_run_config(const storage::RunRecord& run);

// The settings a stored run is analysed with offline (reports, the CLI's
// defaults): its own config's [analysis] over the defaults, and the Earth
// rate of the run's latitude and orientation. A stored value that does not
// parse (model, taus, orientation) is an error naming the run and the value.
Result<AnalysisSettings> analysis_settings_of_run(const storage::RunRecord& run);

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

// The gyro samples as recorded of the soak's longest window (for Allan).
struct RecordedSamples {
  double t_from_s = 0, t_to_s = 0;  // the window used
  std::vector<double> t_s, rate_dph;
};
Result<RecordedSamples> soak_recorded_samples(storage::Database& db, const SoakWindow& soak);

// The whole run's analysis series, read in chunks of station time so memory
// stays bounded by the chunk, not the run. Errors: a run without samples
// (names it), database errors, those of make_analysis_series.
Result<analysis::AnalysisSeries> run_series(storage::Database& db, int64_t run_id, double bin_s);

// Compute and return (not stored).
Result<storage::SegmentStatsRecord> soak_table1(storage::Database& db, const SoakWindow& soak,
                                                const analysis::Table1Options& options);
Result<storage::AllanRecord> soak_allan(storage::Database& db, const SoakWindow& soak,
                                        analysis::TauSet taus);
// A fit as a record ready for Database::add_fit (inputs_json filled in).
storage::FitRecord fit_record(const analysis::DriftFit& fit, const std::vector<int64_t>& run_ids,
                              const analysis::DriftFitOptions& options, double bin_s);

// Everything above for one completed run, stored: Table I rows, Allan records
// and fits. A part that cannot be computed (a soak too short for the moving
// average, a fit of a run at one constant temperature) is not an error of
// the whole: it is listed in `problems` (one line each, naming the part) and
// the rest is still stored. Errors: database failures only.
struct RunAnalysisSummary {
  int table1_rows = 0;
  int allan_records = 0;
  std::vector<int64_t> fit_ids;
  int scale_factor_points = 0;     // rate points stored (0: the run had none)
  int scale_factor_sequences = 0;  // lines fitted
  std::vector<std::string> problems;
};
Result<RunAnalysisSummary> analyse_run(storage::Database& db, int64_t run_id,
                                       const AnalysisSettings& settings);

}  // namespace gyrotherm::daemon
