// Calibration reports (docs/reports.md): what a test engineer hands to a
// customer for a run, and the campaign summary of several runs.
//
// collect_run_report() gathers a run's numbers: the Table I rows, Allan
// records and drift-model fits the daemon stored after the run (computed
// here with the same code, run_analysis.h, only when none are stored), the
// paper's Tables II-IV comparison grid and the series the figures plot.
// collect_campaign_report() adds what needs several runs: the grid with
// leave-one-run-out, the joint fit and the start-temperature model (eq. 3).
// The render_* functions turn them into files: one self-contained HTML page
// (tables as HTML, plots drawn by uPlot from the data embedded in the page,
// no external request), CSV of the statistics, coefficients as JSON and C
// header. Numbers in CSV and JSON carry 17 significant digits, so they read
// back exactly as stored.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/analysis/comparison.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/start_temperature.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/daemon/run_analysis.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::daemon {

struct ReportOptions {
  int max_plot_points = 2000;  // per plotted series (bucket means over time)
  std::string station_name;    // "" = from the run's config
  std::string generated_utc;   // "" = now
  std::string database_path;   // shown in the provenance
  std::string export_label;    // e.g. "nightly export of 2026-11-21 02:00 CET"
};

// One plotted series as report.js draws it (daemon/calibration/report/report.js).
struct PlotSeries {
  std::string label;
  std::vector<double> x, y;    // y NaN = gap
  std::string style = "line";  // line, points, markers
  std::string axis = "y";      // y, y2
  bool dash = false;
  std::vector<double> band_lo, band_hi;  // empty, or the length of x
  std::string band_label;
};
struct PlotAxis {
  std::string label;
  bool log = false;
};
struct Plot {
  std::string id;  // the chart's element id
  std::string title;
  PlotAxis x, y;
  std::optional<PlotAxis> y2;
  std::vector<PlotSeries> series;
  int height_px = 340;
};

// A run's scale-factor results as the daemon stored them after the run
// (schema v7; docs/analysis.md "Scale factor"): the report repeats them, it
// recomputes nothing. Rates and outputs in °/s, biases in °/h where the
// name says so.
struct ReportScaleFactor {
  std::vector<storage::ScaleFactorFitRecord> fits;      // by sf_sequence
  std::vector<storage::ScaleFactorPointRecord> points;  // by sequence, repetition, rate
  std::optional<storage::ScaleFactorTemperatureFitRecord> temperature_fit;
  // The temperature fit's polynomials read from its JSON, lowest power
  // first: K(T) = Σ k_coeffs[j] (T − t_centre_c)^j, bias in °/h (the stored
  // °/s × 3600). Empty without a temperature fit, or when its JSON is not
  // an array of order + 1 numbers (then listed in the run's problems).
  std::vector<double> k_coeffs;
  std::vector<double> bias_coeffs_dph;
};

// A fit the report shows, with where it came from.
struct ReportFit {
  analysis::DriftFit fit;
  int64_t stored_id = 0;  // fits.id; 0 = computed for the report
  std::vector<int64_t> run_ids;
  double l0_window_s = 120.0;
};

struct RunReport {
  storage::RunRecord run;
  AnalysisSettings settings;
  std::string station_name;
  std::vector<storage::SegmentStatsRecord> table1;
  bool table1_stored = true;  // false: computed for the report
  std::vector<storage::AllanRecord> allan;
  bool allan_stored = true;
  std::vector<ReportFit> fits;  // the configured model, centred (default) then paper form
  std::optional<analysis::Comparison> comparison;
  std::string comparison_error;
  std::vector<Plot> plots;
  std::vector<std::string> problems;               // what could not be computed, one line each
  std::optional<analysis::AnalysisSeries> series;  // the whole run, binned (campaign analyses)
  // nullopt when the run has no scale-factor rows (no rate table, or an
  // older database): no section, no file, nothing said.
  std::optional<ReportScaleFactor> scale_factor;
};

// Reads run `run_id` and builds its report. Errors: an unknown run, a run
// without samples, database failures; an analysis that fails is a problem
// listed in the report, not an error.
Result<RunReport> collect_run_report(storage::Database& db, int64_t run_id,
                                     const ReportOptions& options);

struct CampaignReport {
  std::vector<RunReport> runs;  // in id order
  std::string station_name;
  std::optional<ReportFit> joint_fit;  // the configured model on all runs (>= 2 runs)
  std::string joint_fit_error;
  std::optional<analysis::Comparison> comparison;  // all runs, leave-one-run-out
  std::string comparison_error;
  std::optional<analysis::StartTemperatureModel> start_model;
  std::string start_model_note;  // why there is none (e.g. too few distinct T0)
  std::vector<Plot> plots;
  std::vector<std::string> problems;
};

// The runs' reports (already collected) and the campaign-wide analyses on
// their series; the settings are the first run's. Analyses that fail are
// listed in `problems` or their *_error / note.
CampaignReport collect_campaign_report(std::vector<RunReport> runs, const ReportOptions& options);

// A file of an export: its path relative to the export directory, and text.
struct ReportFile {
  std::string path;
  std::string content;
};

// The files of one run's report, under "run-<id>/": report.html, table1.csv,
// allan.csv, allan-curves.csv, comparison.csv, drift-fit-<form>.json/.h;
// with scale-factor results also scale-factor.csv, scale-factor-points.csv,
// scale-factor.json and scale-factor.h.
std::vector<ReportFile> render_run_files(const RunReport& report, const ReportOptions& options);
// The campaign files at the top: index.html (summary, links to each run's
// report), table1.csv (every run), allan.csv, comparison.csv, drift-fit.json/.h
// (joint fit), start-model.json/.h (when there is a model), scale-factor.csv
// (every run's sequences, when a run has any).
std::vector<ReportFile> render_campaign_files(const CampaignReport& report,
                                              const ReportOptions& options);

// Pieces, exposed for tests.
// Fig. 4 (terms kT) / Fig. 6 (kTGR): the output over the run and the output
// compensated by the order-2 and order-4 fits of `terms`, each as its
// ma_window-point centred moving average (Table I's last column; NaN where
// the window does not fit), over the raw 1 s output as faint dots; the mean
// shell temperature on y2. A compensation that fails is listed in `problems`.
Plot output_plot(const analysis::AnalysisSeries& s, const analysis::Comparison& comparison,
                 analysis::TermSet terms, std::string id, std::string title, std::size_t max_points,
                 std::size_t ma_window, std::vector<std::string>& problems);
std::string table1_csv(const std::vector<storage::SegmentStatsRecord>& rows);
std::string allan_csv(const std::vector<storage::AllanRecord>& records);
std::string comparison_csv(const analysis::Comparison& comparison);
// The report-data JSON that report.js reads; "</" is written "<\/" so the
// text can sit inside a <script> element.
std::string plots_json(const std::vector<Plot>& plots);
// A fit as the export JSON / C header (analysis::drift_fit_json) from a
// stored record.
Result<ReportFit> report_fit_of_record(const storage::FitRecord& record);

// Scale factor. A run's stored rows (nullopt when it has none); a database
// error is an error, a temperature fit whose JSON does not parse a line in
// `problems`.
Result<std::optional<ReportScaleFactor>> collect_scale_factor(storage::Database& db, int64_t run_id,
                                                              std::vector<std::string>& problems);
// A rate point's residual from its sequence's line, output − (K·Ω + B), °/s,
// with Ω the demanded rate (as docs/storage.md's query of the points).
double scale_factor_residual_dps(const storage::ScaleFactorPointRecord& point,
                                 const storage::ScaleFactorFitRecord& fit);
// The figures: K relative to K at the centre temperature (ppm) with the K(T)
// polynomial, bias (°/h) with B(T), and the nonlinearity, each against
// temperature. None with fewer than 2 sequences.
std::vector<Plot> scale_factor_plots(const ReportScaleFactor& sf);
// CSV of the sequences' fits (runs in the given order) and of the rate
// points with their residuals.
std::string scale_factor_csv(const std::vector<const ReportScaleFactor*>& runs);
std::string scale_factor_points_csv(const ReportScaleFactor& sf);
// The coefficients for the gyro's computer (docs/reports.md): JSON, and a
// C99 header whose names start with `prefix` (a C identifier).
std::string scale_factor_json(const ReportScaleFactor& sf, const analysis::ExportInfo& info);
std::string scale_factor_c_header(const ReportScaleFactor& sf, const analysis::ExportInfo& info,
                                  const std::string& prefix = "gyrotherm_sf");

}  // namespace gyrotherm::daemon
