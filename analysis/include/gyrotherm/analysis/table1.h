// Table I statistics of the reference paper (docs/analysis.md).
//
// Per soak acquisition window, on the *analysis series*: the gyro rate
// averaged into consecutive bins of bin_s (default 1 s, the paper's 1 Hz
// sampling; bins start at the window's first sample; a partial last bin is
// dropped; data already spaced >= bin_s is used as is), and the temperatures
// averaged over the same bins. Then: n, duration, mean shell temperature
// ((top + side) / 2), zero-bias mean, sample standard deviation (ddof = 1),
// and the standard deviation after a 101-point centred moving average (the
// mean of each 101 consecutive points, the n - 100 full windows only, then
// ddof = 1); and the bias with the Earth-rate component removed. The mean
// carries its standard uncertainty from the noise model (noise_model.h)
// fitted to the series' own Allan curve: u(T) at T = the row's duration.
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/analysis/noise_model.h"
#include "gyrotherm/analysis/sample_source.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"

namespace gyrotherm::analysis {

enum class AxisOrientation { kUp, kDown, kHorizontal };
Result<AxisOrientation> parse_orientation(std::string_view s);  // "up", "down", "horizontal"
std::string_view to_string(AxisOrientation o);

// Earth-rate component seen by the sensitive axis, °/h, Ω = 15.041067 °/h,
// φ = latitude:
//   up: +Ω sin φ; down: −Ω sin φ;
//   horizontal with a heading h (the azimuth the axis's positive direction
//   points to: clockwise from true north, seen from above): Ω cos φ cos h;
//   horizontal without a heading: 0 (the axis taken as east–west; what
//   configs and stored runs from before headings mean).
// A heading given with up or down is ignored (a vertical axis has none).
double earth_rate_component_dph(double latitude_deg, AxisOrientation orientation,
                                std::optional<double> heading_deg);
// The same without a heading (horizontal: 0).
double earth_rate_component_dph(double latitude_deg, AxisOrientation orientation);

// Plain statistics in double, accurate to ~1e-13 relative on well-scaled
// data: blocks of 4096 points each get exact two-pass moments while in cache,
// combined as M2 = sum M2_b + sum n_b (mean_b - mean)^2 with compensated block
// sums, so a large common offset costs no digits. Empty or too-short input
// gives NaN; a NaN or infinite input gives NaN.
double mean(std::span<const double> x);
double std_ddof1(std::span<const double> x);
// Std (ddof = 1) of the means of every `window` consecutive points (the
// n - window + 1 full windows). NaN when fewer than window + 1 points or
// window == 0. O(n): running window sums of the data minus a per-block shift,
// restarted from a fresh sum every 1024 windows so the rounding cannot build up.
double moving_average_std(std::span<const double> x, std::size_t window);
// Table I's statistics of one series in a single fused pass over the three
// vectors (blocked as above): mean of (top + side) / 2, mean and std (ddof 1)
// of the rate and the std (ddof 1) of its ma_window-point moving averages
// (NaN when n <= ma_window). finite = false (other fields unset) when the
// sizes differ, n < 2, ma_window == 0, or any value is NaN or infinite (or so
// large that a block sum overflows); the caller then finds and names it.
// Each block's moments come from one pass of sums shifted by the previous
// block's mean (two passes when that shift would cancel a digit); series of
// >= 2^18 points are summed on two threads (halves, combined exactly).
struct Table1Statistics {
  std::size_t n = 0;
  bool finite = true;
  double temp_mean_c = 0;
  double bias_mean_dph = 0;
  double bias_std_dph = 0;
  double bias_std_ma_dph = 0;
};
Table1Statistics table1_statistics(std::span<const double> rate_dph, std::span<const double> top_c,
                                   std::span<const double> side_c, std::size_t ma_window);

// Least-squares slope of y on t (units of y per unit of t). NaN for < 2 points,
// sizes that differ, or all t equal.
double linear_slope(std::span<const double> t, std::span<const double> y);

// The analysis series of one window.
struct AnalysisSeries {
  std::vector<double> t_s;       // bin start times (or the samples' times, if used as is)
  std::vector<double> rate_dph;  // bin means
  std::vector<double> top_c;     // temperatures over the same bins
  std::vector<double> side_c;
  double bin_s = 1.0;  // effective spacing
  bool binned = true;  // false when the data was used as is
};

struct Table1Options {
  double bin_s = 1.0;
  std::size_t ma_window = 101;
  double earth_rate_dph = 0.0;  // removed from the mean for bias_mean_earth_removed_dph

  // False with a message when a value is out of range (bin_s <= 0, window < 2).
  bool is_valid(std::string* why) const;
};

// Builds the analysis series from the raw window: gyro samples binned as
// above; for each bin the temperature samples inside it are averaged, and a
// bin with none takes the linear interpolation of the neighbouring samples.
//
// Precisely (t0 = the first gyro sample's time, all times station seconds):
// - The sample spacing tau is the median of the gyro time differences (a
//   single sample: tau = bin_s). The data covers [t0, t_last + tau).
// - If tau >= bin_s (within 1e-9 relative) the samples are used as is:
//   binned = false, bin_s = tau, t_s = the samples' times; sample i stands for
//   [t_i, t_{i+1}) (the last for [t_last, t_last + tau)) when temperatures are
//   matched to it.
// - Otherwise bin k is [t0 + k*bin_s, t0 + (k+1)*bin_s); a sample goes to bin
//   floor((t - t0)/bin_s + 1e-9), so a time stamp a rounding error short of a
//   boundary counts in the later bin. A bin is complete when its end is
//   <= t_last + tau + 1e-9*bin_s: 10 Hz samples at t0 ... t0 + 1199.9 give
//   exactly 1200 bins. The incomplete last bin, if any, is dropped with its
//   samples. A bin with no gyro sample inside the range (a gap in the stream)
//   is dropped too, not interpolated: t_s then jumps, and n x bin_s counts
//   only the time with data. rate_dph is the mean of the bin's samples.
// - Temperatures: top_c and side_c of a bin are the means of the temperature
//   samples inside it (same boundary rule); a bin with none takes the linear
//   interpolation of the temperature series at the bin centre, top and side
//   separately, clamped to the first/last sample outside their range.
// Errors (permanent, the message names the index and t_s): no gyro samples,
// no temperature samples, gyro or temperature times not strictly increasing,
// a non-finite time, rate, top_c or side_c; bin_s not positive and finite;
// samples that span more than 1e7 bins (a time column with an outlier).
// Allocates O(gyro.size() + temps.size() + number of bins).
Result<AnalysisSeries> make_analysis_series(std::span<const GyroSample> gyro,
                                            std::span<const TemperatureSample> temps, double bin_s);
// The same over a streamed window (sample_source.h; its values are the
// rates), in memory of the output series, not of the samples: one pass
// checks the samples, finds the median spacing (SeriesScanner) and takes the
// bin means; which bins are complete is decided at the end (a second pass
// only for samples used as is after a dense stretch). The result is exactly
// the span form's on the same samples. `scanned`, when given, receives the
// SeriesScan when the samples scanned clean (nullopt otherwise). Errors: the
// span form's, and the source's (transient, as it gave them).
Result<AnalysisSeries> make_analysis_series(const SampleSource& gyro,
                                            std::span<const TemperatureSample> temps, double bin_s,
                                            std::optional<SeriesScan>* scanned = nullptr);

struct Table1Row {
  std::size_t n = 0;
  double duration_s = 0;  // n x bin spacing
  double temp_mean_c = 0;
  double bias_mean_dph = 0;
  double bias_std_dph = 0;
  double bias_std_ma_dph = 0;  // NaN when n <= ma_window
  double bias_mean_earth_removed_dph = 0;
  // The uncertainty of bias_mean_dph (and of the Earth-removed mean, which
  // differs by a constant): the noise model fitted to the octave Allan curve
  // of the analysis series, projected to T = duration_s, at 95 %
  // (mean_uncertainty). nullopt when the series does not give a model;
  // bias_u_note then says why (fewer than 3 octave taus: under 8 points; a
  // constant series).
  std::optional<MeanUncertainty> bias_u;
  std::string bias_u_note;
};

// The uncertainty of the mean of an analysis series of `window_s` seconds
// (see Table1Row::bias_u); `note` gets the reason when there is none. A
// series without times takes bin_s spacing.
std::optional<MeanUncertainty> series_mean_uncertainty(const AnalysisSeries& series,
                                                       double window_s, std::string* note);

// Errors: invalid options (the is_valid message); n < 2; the series' vectors
// of different lengths; a non-finite value in the series.
Result<Table1Row> table1_row(const AnalysisSeries& series, const Table1Options& options);

// ---- Table I as the paper prints it: one row per set point ----------------
//
// The paper's campaign repeats each of its set points four times and prints,
// per set point, the mean of each column over the repetitions. Soaks are
// grouped by their schedule set point (the temperature the chamber was asked
// to hold), not by the measured shell temperature: the measured means of two
// repetitions differ by the chamber's tolerance and the gyro's self-heating,
// and would split or merge groups at random. Set points within
// kSetpointGroupTolC of the lowest set point of a group join it; groups come
// in increasing set point order.

constexpr double kSetpointGroupTolC = 1e-3;

// Mean and sample standard deviation (ddof = 1) of one column over the
// repetitions of a set point. Values that are NaN (e.g. a soak too short for
// the moving average) are left out; n counts the values used. mean is NaN
// when n = 0, std when n < 2.
struct MeanSpread {
  double mean = 0;
  double std = 0;
  std::size_t n = 0;
};

struct Table1Soak {
  double setpoint_c = 0;  // the schedule's set point of the soak
  Table1Row row;
};

struct Table1SetpointRow {
  double setpoint_c = 0;  // the group's lowest set point
  std::size_t repetitions = 0;
  std::vector<std::size_t> soaks;  // indices into the input, in input order
  MeanSpread temp_mean_c;
  MeanSpread bias_mean_dph;
  MeanSpread bias_std_dph;
  MeanSpread bias_std_ma_dph;
  MeanSpread bias_mean_earth_removed_dph;
  // The uncertainty of bias_mean_dph.mean from the noise within its soaks
  // (average_uncertainty of the soaks' bias_u; not the spread between
  // them, which bias_mean_dph.std shows). None when a soak with a bias mean
  // has no bias_u; bias_mean_u_note then names it and says why.
  std::optional<MeanUncertainty> bias_mean_u;
  std::string bias_mean_u_note;
};

// Errors: a set point that is not finite (the message names the soak's index).
Result<std::vector<Table1SetpointRow>> table1_by_setpoint(std::span<const Table1Soak> soaks);

}  // namespace gyrotherm::analysis
