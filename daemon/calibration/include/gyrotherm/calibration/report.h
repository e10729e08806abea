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
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/analysis/comparison.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/start_temperature.h"
#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::calibration {

struct ReportOptions {
  int max_plot_points = 2000;  // per plotted series (bucket means over time)
  std::string station_name;    // "" = from the run's config
  std::string generated_utc;   // "" = now
  std::string database_path;   // shown in the provenance
  std::string export_label;    // e.g. "nightly export of 2026-11-21 02:00 CET"
  // Write the C header of a flagged result too (`gyrotherm export
  // --force`), with a comment saying so and why it is flagged. Without it
  // the header is not written and the export's problems name it.
  bool force_flagged = false;
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
  storage::ResultQuality quality{};  // as stored, or assessed for the report
};

// One report is of one DUT axis of a run (schema v8; run_analysis.h
// AnalysedAxis): its Table I, Allan, fits, Tables II-IV and scale factor.
// A run without DUT records has one, of its gyro (serial "", axis "").
struct RunReport {
  storage::RunRecord run;  // with its metadata (operator, comment, tags)
  AnalysedAxis stream;     // the DUT (serial, model) and axis
  // Appended to every file name of this report: "" for a run whose only
  // stream is the unnamed gyro (today's names), else "-<serial>-<axis>"
  // (file_suffix()).
  std::string file_suffix;
  AnalysisSettings settings;
  std::string station_name;
  std::vector<storage::SegmentStatsRecord> table1;
  bool table1_stored = true;  // false: computed for the report
  // Adaptive soaks: why each one's acquisition ended, by segment index
  // (segments.acquire_stop; docs/schedules.md "Adaptive soaks").
  std::map<int, std::string> acquire_stops;
  std::vector<storage::AllanRecord> allan;
  bool allan_stored = true;
  std::vector<ReportFit> fits;  // the configured model, centred (default) then paper form
  std::optional<analysis::Comparison> comparison;
  std::string comparison_error;
  std::vector<Plot> plots;
  std::vector<std::string> problems;               // what could not be computed, one line each
  std::optional<analysis::AnalysisSeries> series;  // the whole run, binned (campaign analyses)
  RunSeriesCoverage series_coverage;               // of `series` (run_series)
  // nullopt when the run has no scale-factor rows (no rate table, or an
  // older database): no section, no file, nothing said.
  std::optional<ReportScaleFactor> scale_factor;
};

// Reads run `run_id` and builds its report. Errors: an unknown run, a run
// without samples, database failures; an analysis that fails is a problem
// listed in the report, not an error. The first form: the run's first DUT,
// primary axis (with the suffix it has among the run's streams).
Result<RunReport> collect_run_report(storage::Database& db, int64_t run_id,
                                     const ReportOptions& options);
Result<RunReport> collect_run_report(storage::Database& db, int64_t run_id,
                                     const ReportOptions& options, const AnalysedAxis& stream,
                                     bool only_stream);
// One report per DUT and analysed axis, in analysed_axes() order.
Result<std::vector<RunReport>> collect_run_reports(storage::Database& db, int64_t run_id,
                                                   const ReportOptions& options);
// Whether a stored result row of (dut_serial, axis) belongs to `stream`:
// serial "" means the run's first DUT, axis "" that DUT's primary axis.
bool result_of_stream(const std::string& dut_serial, const std::string& axis,
                      const AnalysedAxis& stream);

struct CampaignReport {
  std::vector<RunReport> runs;  // in id order; one DUT axis (same serial and axis)
  // The DUT axis (from the first run) and the suffix of the summary's file
  // names: "" when the export is of one unnamed gyro (today's names).
  std::string dut_serial, dut_model, axis;
  std::string file_suffix;
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
// The nightly summary across DUTs: the runs' reports grouped by DUT serial
// and axis, a CampaignReport per group (in order of first appearance). One
// group of the unnamed gyro keeps file_suffix ""; otherwise every group
// has its "-<serial>-<axis>".
std::vector<CampaignReport> collect_campaign_reports(std::vector<RunReport> runs,
                                                     const ReportOptions& options);

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
// With a file_suffix: summary<suffix>.html instead of index.html, every
// other name with the suffix too.
std::vector<ReportFile> render_campaign_files(const CampaignReport& report,
                                              const ReportOptions& options);
// A run with several DUT axes: run-<id>/report.html, the run's metadata and
// DUTs with a link to each DUT axis's report.
ReportFile render_run_index(const std::vector<RunReport>& reports, const ReportOptions& options);
// The summary across DUTs (index.html) when an export has several groups:
// the runs with their operator, DUTs and tags, and a link to each group's
// summary and each run's reports.
ReportFile render_summary_index(const std::vector<CampaignReport>& groups,
                                const ReportOptions& options);
// Every file of an export of these runs (what write_export writes): each
// run's reports (and its index with several DUT axes), the summary per
// DUT axis and, with several, the index across DUTs.
std::vector<ReportFile> render_export_files(const std::vector<std::vector<RunReport>>& runs,
                                            const ReportOptions& options,
                                            std::vector<std::string>& problems);

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
// The first form: the run's first DUT, primary axis.
Result<std::optional<ReportScaleFactor>> collect_scale_factor(storage::Database& db, int64_t run_id,
                                                              std::vector<std::string>& problems);
Result<std::optional<ReportScaleFactor>> collect_scale_factor(storage::Database& db, int64_t run_id,
                                                              std::vector<std::string>& problems,
                                                              const AnalysedAxis& stream);
// The K(T) fit of one DUT axis of a run (nullopt: none stored for it).
Result<std::optional<storage::ScaleFactorTemperatureFitRecord>> scale_factor_temperature_fit_of(
    storage::Database& db, int64_t run_id, const AnalysedAxis& stream);
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
// The quality of what the scale-factor header carries: flagged when a
// sequence's line is, with each such line's reasons ("sequence 2: K = ...").
storage::ResultQuality scale_factor_header_quality(const ReportScaleFactor& sf);
// The comment a C header of a flagged result written with --force starts
// with (what the result is flagged for); "" for a result not flagged.
std::string forced_header_comment(const storage::ResultQuality& quality);

}  // namespace gyrotherm::calibration
