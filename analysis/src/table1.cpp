// Analysis series (binning) and Table I rows; see table1.h for the rules.
#include "gyrotherm/analysis/table1.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <optional>

#include "common.h"
#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/core/units.h"

namespace gyrotherm::analysis {
namespace {

// Relative to the bin width: how far short of a boundary a time stamp may be
// and still count in the later bin.
constexpr double kBoundaryTol = 1e-9;

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

Status check_gyro(std::span<const GyroSample> gyro) {
  for (std::size_t i = 0; i < gyro.size(); ++i) {
    const GyroSample& g = gyro[i];
    if (!std::isfinite(g.t_s)) {
      return Error::Permanent(fmt::format("gyro sample {}: time is not finite ({})", i, g.t_s));
    }
    if (!std::isfinite(g.rate_dph)) {
      return Error::Permanent(
          fmt::format("gyro sample {} at t_s={}: rate is not finite ({})", i, g.t_s, g.rate_dph));
    }
    if (i > 0 && !(g.t_s > gyro[i - 1].t_s)) {
      return Error::Permanent(
          fmt::format("gyro sample {}: time t_s={} does not increase (previous sample at t_s={})",
                      i, g.t_s, gyro[i - 1].t_s));
    }
  }
  return Status::Ok();
}

Status check_temps(std::span<const TemperatureSample> temps) {
  for (std::size_t i = 0; i < temps.size(); ++i) {
    const TemperatureSample& s = temps[i];
    if (!std::isfinite(s.t_s)) {
      return Error::Permanent(
          fmt::format("temperature sample {}: time is not finite ({})", i, s.t_s));
    }
    if (!std::isfinite(s.top_c) || !std::isfinite(s.side_c)) {
      return Error::Permanent(
          fmt::format("temperature sample {} at t_s={}: top_c={} side_c={} is not finite", i, s.t_s,
                      s.top_c, s.side_c));
    }
    if (i > 0 && !(s.t_s > temps[i - 1].t_s)) {
      return Error::Permanent(fmt::format(
          "temperature sample {}: time t_s={} does not increase (previous sample at t_s={})", i,
          s.t_s, temps[i - 1].t_s));
    }
  }
  return Status::Ok();
}

double median_spacing(std::span<const GyroSample> gyro) {
  std::vector<double> d(gyro.size() - 1);
  for (std::size_t i = 1; i < gyro.size(); ++i) d[i - 1] = gyro[i].t_s - gyro[i - 1].t_s;
  const std::size_t mid = d.size() / 2;
  std::nth_element(d.begin(), d.begin() + mid, d.end());
  if (d.size() % 2 == 1) return d[mid];
  const double upper = d[mid];
  const double lower_mid = *std::max_element(d.begin(), d.begin() + mid);
  return (lower_mid + upper) / 2;
}

// Linear interpolation of the temperature series at t, clamped at the ends.
struct TopSide {
  double top_c;
  double side_c;
};
TopSide interpolate(std::span<const TemperatureSample> temps, double t) {
  if (t <= temps.front().t_s) return {temps.front().top_c, temps.front().side_c};
  if (t >= temps.back().t_s) return {temps.back().top_c, temps.back().side_c};
  const auto hi = std::upper_bound(temps.begin(), temps.end(), t,
                                   [](double v, const TemperatureSample& s) { return v < s.t_s; });
  const TemperatureSample& b = *hi;
  const TemperatureSample& a = *(hi - 1);
  const double f = (t - a.t_s) / (b.t_s - a.t_s);
  return {a.top_c + f * (b.top_c - a.top_c), a.side_c + f * (b.side_c - a.side_c)};
}

// Per-bin sums of the temperature samples, then means or interpolation.
struct TempAccumulator {
  std::vector<double> top_sum, side_sum;
  std::vector<std::size_t> count;
  explicit TempAccumulator(std::size_t bins) : top_sum(bins), side_sum(bins), count(bins) {}
  void add(std::size_t bin, const TemperatureSample& s) {
    top_sum[bin] += s.top_c;
    side_sum[bin] += s.side_c;
    ++count[bin];
  }
  TopSide get(std::size_t bin, std::span<const TemperatureSample> temps, double centre_s) const {
    if (count[bin] == 0) return interpolate(temps, centre_s);
    const double c = static_cast<double>(count[bin]);
    return {top_sum[bin] / c, side_sum[bin] / c};
  }
};

AnalysisSeries as_is(std::span<const GyroSample> gyro, std::span<const TemperatureSample> temps,
                     double tau) {
  AnalysisSeries out;
  out.binned = false;
  out.bin_s = tau;
  const std::size_t n = gyro.size();
  auto end_of = [&](std::size_t i) { return i + 1 < n ? gyro[i + 1].t_s : gyro[i].t_s + tau; };
  TempAccumulator acc(n);
  // Both series increase: one sweep matches each temperature to its sample.
  std::size_t i = 0;
  for (const TemperatureSample& s : temps) {
    if (s.t_s < gyro.front().t_s) continue;
    while (i < n && s.t_s >= end_of(i)) ++i;
    if (i == n) break;
    acc.add(i, s);
  }
  out.t_s.reserve(n);
  out.rate_dph.reserve(n);
  out.top_c.reserve(n);
  out.side_c.reserve(n);
  for (std::size_t k = 0; k < n; ++k) {
    const TopSide ts = acc.get(k, temps, (gyro[k].t_s + end_of(k)) / 2);
    out.t_s.push_back(gyro[k].t_s);
    out.rate_dph.push_back(gyro[k].rate_dph);
    out.top_c.push_back(ts.top_c);
    out.side_c.push_back(ts.side_c);
  }
  return out;
}

// 116 days of 1 s bins; the per-bin temperature sums then take ~400 MB.
constexpr double kMaxBins = 1e7;

// The bin means of gyro samples fed in time order: bin k = floor((t - t0) /
// bin_s + kBoundaryTol), t0 the first sample; a bin's mean is emitted when
// a sample of a later bin arrives (or at the end). Which bins are complete
// is decided afterwards (series_of_bins).
class BinMeans {
 public:
  BinMeans(double bin_s, double t0) : bin_s_(bin_s), t0_(t0) {}
  void reserve(std::size_t bins) {
    k_.reserve(bins);
    mean_.reserve(bins);
  }
  void add(double t_s, double rate_dph) {
    // Times increase: a sample before check_s is in the bin of the last
    // one (check_s lies 1e-6 bins short of its end), so the bin is computed
    // only near a boundary, by the same formula.
    if (!(t_s < check_s_)) {
      const double k = std::floor((t_s - t0_) / bin_s_ + kBoundaryTol);
      if (k != bin_) emit();
      bin_ = k;
      check_s_ = t0_ + (k + 1.0 - 1e-6) * bin_s_;
    }
    rates_.push_back(rate_dph);
  }
  // The bins from k = 0 on, ascending, with their means.
  const std::vector<double>& bins() {
    emit();
    return k_;
  }
  const std::vector<double>& means() const { return mean_; }
  double t0() const { return t0_; }

 private:
  void emit() {
    if (rates_.empty()) return;
    k_.push_back(bin_);
    mean_.push_back(mean(rates_));
    rates_.clear();
  }
  double bin_s_, t0_;
  double bin_ = -1;
  double check_s_ = -std::numeric_limits<double>::infinity();
  std::vector<double> rates_, k_, mean_;
};

// The analysis series of the bin means below nbins (the complete bins), with
// the temperatures over the same bins.
AnalysisSeries series_of_bins(BinMeans& b, std::size_t nbins,
                              std::span<const TemperatureSample> temps, double bin_s) {
  const double t0 = b.t0();
  TempAccumulator acc(nbins);
  for (const TemperatureSample& s : temps) {
    const double k = std::floor((s.t_s - t0) / bin_s + kBoundaryTol);
    if (k >= 0 && k < static_cast<double>(nbins)) acc.add(static_cast<std::size_t>(k), s);
  }
  const std::vector<double>& ks = b.bins();
  const std::vector<double>& means = b.means();
  AnalysisSeries out;
  out.binned = true;
  out.bin_s = bin_s;
  std::size_t count = 0;
  while (count < ks.size() && ks[count] < static_cast<double>(nbins)) ++count;
  out.t_s.reserve(count);
  out.rate_dph.reserve(count);
  out.top_c.reserve(count);
  out.side_c.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    const auto k = static_cast<std::size_t>(ks[i]);
    const double start_s = t0 + static_cast<double>(k) * bin_s;
    const TopSide ts = acc.get(k, temps, start_s + bin_s / 2);
    out.t_s.push_back(start_s);
    out.rate_dph.push_back(means[i]);
    out.top_c.push_back(ts.top_c);
    out.side_c.push_back(ts.side_c);
  }
  return out;
}

std::size_t complete_bins(double t0, double t_last, double tau, double bin_s) {
  return static_cast<std::size_t>(std::floor(((t_last - t0) + tau) / bin_s + kBoundaryTol));
}

AnalysisSeries binned(std::span<const GyroSample> gyro, std::span<const TemperatureSample> temps,
                      double bin_s, double tau) {
  const std::size_t nbins = complete_bins(gyro.front().t_s, gyro.back().t_s, tau, bin_s);
  BinMeans b(bin_s, gyro.front().t_s);
  b.reserve(std::min(nbins, gyro.size()));
  for (const GyroSample& g : gyro) b.add(g.t_s, g.rate_dph);
  return series_of_bins(b, nbins, temps, bin_s);
}

Status check_bin_count(double t_first_s, double t_last_s, double bin_s) {
  // Bins are indexed over the whole span: a time column with a far outlier
  // would ask for more bins than memory holds.
  const double span_s = t_last_s - t_first_s;
  if (span_s / bin_s > kMaxBins) {
    return Error::Permanent(fmt::format(
        "the gyro samples span {:g} s (t_s {:g} to {:g}): more than {:g} bins of {:g} s; check the "
        "time column",
        span_s, t_first_s, t_last_s, kMaxBins, bin_s));
  }
  return Status::Ok();
}

}  // namespace

Result<AxisOrientation> parse_orientation(std::string_view s) {
  const std::string v = lower(s);
  if (v == "up") return AxisOrientation::kUp;
  if (v == "down") return AxisOrientation::kDown;
  if (v == "horizontal") return AxisOrientation::kHorizontal;
  return Error::Permanent(
      fmt::format("unknown axis orientation '{}' (expected up, down or horizontal)", s));
}

std::string_view to_string(AxisOrientation o) {
  switch (o) {
    case AxisOrientation::kUp:
      return "up";
    case AxisOrientation::kDown:
      return "down";
    case AxisOrientation::kHorizontal:
      return "horizontal";
  }
  return "unknown";
}

double earth_rate_component_dph(double latitude_deg, AxisOrientation orientation,
                                std::optional<double> heading_deg) {
  const double latitude_rad = units::deg_to_rad(latitude_deg);
  switch (orientation) {
    case AxisOrientation::kUp:
      return units::kEarthRateDph * std::sin(latitude_rad);
    case AxisOrientation::kDown:
      return -units::kEarthRateDph * std::sin(latitude_rad);
    case AxisOrientation::kHorizontal:
      // The Earth's spin axis has Ω cos φ along the local north; a
      // horizontal axis at azimuth h takes its cos h.
      if (!heading_deg) return 0.0;
      return units::kEarthRateDph * std::cos(latitude_rad) *
             std::cos(units::deg_to_rad(*heading_deg));
  }
  return kNaN;
}

double earth_rate_component_dph(double latitude_deg, AxisOrientation orientation) {
  return earth_rate_component_dph(latitude_deg, orientation, std::nullopt);
}

bool Table1Options::is_valid(std::string* why) const {
  auto fail = [&](std::string msg) {
    if (why != nullptr) *why = std::move(msg);
    return false;
  };
  if (!(bin_s > 0) || !std::isfinite(bin_s)) {
    return fail(fmt::format("bin_s must be a positive number of seconds, got {}", bin_s));
  }
  if (ma_window < 2) {
    return fail(fmt::format("ma_window must be at least 2 points, got {}", ma_window));
  }
  if (!std::isfinite(earth_rate_dph)) {
    return fail(fmt::format("earth_rate_dph must be finite, got {}", earth_rate_dph));
  }
  return true;
}

Result<AnalysisSeries> make_analysis_series(std::span<const GyroSample> gyro,
                                            std::span<const TemperatureSample> temps,
                                            double bin_s) {
  if (!(bin_s > 0) || !std::isfinite(bin_s)) {
    return Error::Permanent(
        fmt::format("bin_s must be a positive number of seconds, got {}", bin_s));
  }
  if (gyro.empty()) return Error::Permanent("no gyro samples in the window");
  if (temps.empty()) return Error::Permanent("no temperature samples in the window");
  if (Status st = check_gyro(gyro); !st.ok()) return st.error();
  if (Status st = check_temps(temps); !st.ok()) return st.error();

  const double tau = gyro.size() > 1 ? median_spacing(gyro) : bin_s;
  if (tau >= bin_s * (1 - kBoundaryTol)) return as_is(gyro, temps, tau);
  if (Status st = check_bin_count(gyro.front().t_s, gyro.back().t_s, bin_s); !st) {
    return st.error();
  }
  return binned(gyro, temps, bin_s, tau);
}

Result<AnalysisSeries> make_analysis_series(const SampleSource& gyro,
                                            std::span<const TemperatureSample> temps, double bin_s,
                                            std::optional<SeriesScan>* scanned) {
  if (!(bin_s > 0) || !std::isfinite(bin_s)) {
    return Error::Permanent(
        fmt::format("bin_s must be a positive number of seconds, got {}", bin_s));
  }
  // One pass: the checks and spacings, the bin means, and the samples
  // themselves while they are sparse enough to be used as is (a median
  // spacing >= bin_s puts half the spacings at >= bin_s: then n - 1 <=
  // 2 span / bin_s, about twice the bins). A dense stretch before a sparse
  // series drops them; a second pass then reads them back.
  SeriesScanner scanner;
  std::optional<BinMeans> bins;
  std::vector<GyroSample> sparse;
  bool keep_sparse = true;
  Status st = gyro([&](std::span<const double> t, std::span<const double> rate) {
    if (!scanner.add(t, rate)) return false;
    if (!t.empty() && !bins) bins.emplace(bin_s, t.front());
    for (std::size_t i = 0; i < t.size(); ++i) {
      bins->add(t[i], rate[i]);
      if (!keep_sparse) continue;
      GyroSample g;
      g.t_s = t[i];
      g.rate_dph = rate[i];
      sparse.push_back(g);
      if (static_cast<double>(sparse.size()) > 2.0 * (t[i] - bins->t0()) / bin_s + 3.0) {
        keep_sparse = false;
        std::vector<GyroSample>().swap(sparse);
      }
    }
    return true;
  });
  if (!st) return st.error();
  if (scanned != nullptr) scanned->reset();
  auto scan = scanner.finish(gyro);
  if (!scan) {
    Error e = scan.error();
    if (!e.transient) e.message = "gyro " + e.message;
    return e;
  }
  if (scanned != nullptr) *scanned = *scan;
  if (scan->n == 0) return Error::Permanent("no gyro samples in the window");
  if (temps.empty()) return Error::Permanent("no temperature samples in the window");
  if (Status ok = check_temps(temps); !ok.ok()) return ok.error();

  const double tau = scan->n > 1 ? (scan->spacing_lower_s + scan->spacing_upper_s) / 2 : bin_s;
  if (tau >= bin_s * (1 - kBoundaryTol)) {
    if (!keep_sparse) {
      sparse.reserve(scan->n);
      st = gyro([&](std::span<const double> t, std::span<const double> rate) {
        for (std::size_t i = 0; i < t.size() && sparse.size() < scan->n; ++i) {
          GyroSample g;
          g.t_s = t[i];
          g.rate_dph = rate[i];
          sparse.push_back(g);
        }
        return sparse.size() < scan->n;
      });
      if (!st) return st.error();
    }
    if (sparse.size() != scan->n) {
      return Error::Transient(fmt::format("the gyro samples changed between two passes: {} then {}",
                                          scan->n, sparse.size()));
    }
    return as_is(sparse, temps, tau);
  }
  if (Status ok = check_bin_count(scan->t_first_s, scan->t_last_s, bin_s); !ok) {
    return ok.error();
  }
  return series_of_bins(*bins, complete_bins(scan->t_first_s, scan->t_last_s, tau, bin_s), temps,
                        bin_s);
}

Result<Table1Row> table1_row(const AnalysisSeries& series, const Table1Options& options) {
  std::string why;
  if (!options.is_valid(&why)) return Error::Permanent("invalid Table I options: " + why);
  const std::size_t n = series.rate_dph.size();
  if (series.top_c.size() != n || series.side_c.size() != n) {
    return Error::Permanent(
        fmt::format("analysis series has {} rates but {} top and {} side temperatures", n,
                    series.top_c.size(), series.side_c.size()));
  }
  if (n < 2) {
    return Error::Permanent(
        fmt::format("a Table I row needs at least 2 points in the analysis series, got {}", n));
  }
  const Table1Statistics st =
      table1_statistics(series.rate_dph, series.top_c, series.side_c, options.ma_window);
  if (!st.finite) {
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(series.rate_dph[i]) || !std::isfinite(series.top_c[i]) ||
          !std::isfinite(series.side_c[i])) {
        const double t = i < series.t_s.size() ? series.t_s[i] : kNaN;
        return Error::Permanent(fmt::format(
            "analysis series point {} at t_s={}: rate_dph={} top_c={} side_c={} is not finite", i,
            t, series.rate_dph[i], series.top_c[i], series.side_c[i]));
      }
    }
    return Error::Permanent(
        "analysis series: the values are too large for Table I statistics (a sum overflows)");
  }

  Table1Row row;
  row.n = n;
  row.duration_s = static_cast<double>(n) * series.bin_s;
  row.temp_mean_c = st.temp_mean_c;
  row.bias_mean_dph = st.bias_mean_dph;
  row.bias_std_dph = st.bias_std_dph;
  row.bias_std_ma_dph = st.bias_std_ma_dph;
  row.bias_mean_earth_removed_dph = row.bias_mean_dph - options.earth_rate_dph;
  row.bias_u = series_mean_uncertainty(series, row.duration_s, &row.bias_u_note);
  return row;
}

std::optional<MeanUncertainty> series_mean_uncertainty(const AnalysisSeries& series,
                                                       double window_s, std::string* note) {
  const std::size_t n = series.rate_dph.size();
  std::vector<double> spaced;
  std::span<const double> t_s = series.t_s;
  if (t_s.size() != n) {
    spaced.resize(n);
    for (std::size_t i = 0; i < n; ++i) spaced[i] = static_cast<double>(i) * series.bin_s;
    t_s = spaced;
  }
  auto allan = allan_deviation(t_s, series.rate_dph, {.taus = TauSet::kOctave});
  if (!allan) {
    *note = "no Allan curve: " + allan.error().message;
    return std::nullopt;
  }
  auto model = fit_noise_model(allan->tau_s, allan->adev_dph, allan->edf);
  if (!model) {
    *note = "no noise model: " + model.error().message;
    return std::nullopt;
  }
  auto u = mean_uncertainty(*model, window_s);
  if (!u) {
    *note = u.error().message;
    return std::nullopt;
  }
  return *u;
}

namespace {

MeanSpread mean_spread(std::vector<double> values) {
  std::erase_if(values, [](double v) { return std::isnan(v); });
  MeanSpread out;
  out.n = values.size();
  out.mean = values.empty() ? kNaN : mean(values);
  out.std = values.size() < 2 ? kNaN : std_ddof1(values);
  return out;
}

}  // namespace

Result<std::vector<Table1SetpointRow>> table1_by_setpoint(std::span<const Table1Soak> soaks) {
  std::vector<std::size_t> order(soaks.size());
  for (std::size_t i = 0; i < soaks.size(); ++i) {
    if (!std::isfinite(soaks[i].setpoint_c)) {
      return Error::Permanent(fmt::format(
          "Table I by set point: soak {} has no finite set point ({})", i, soaks[i].setpoint_c));
    }
    order[i] = i;
  }
  // Stable: the repetitions of a set point keep their order (run, then step).
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return soaks[a].setpoint_c < soaks[b].setpoint_c;
  });
  std::vector<Table1SetpointRow> out;
  for (std::size_t k = 0; k < order.size();) {
    const double first_c = soaks[order[k]].setpoint_c;
    std::vector<double> temp, bias, sd, sd_ma, bias_e;
    std::vector<MeanUncertainty> bias_u;
    std::string bias_u_missing;
    std::size_t j = k;
    for (; j < order.size() && soaks[order[j]].setpoint_c - first_c < kSetpointGroupTolC; ++j) {
      const Table1Row& r = soaks[order[j]].row;
      if (!std::isnan(r.bias_mean_dph)) {
        if (r.bias_u) {
          bias_u.push_back(*r.bias_u);
        } else if (bias_u_missing.empty()) {
          bias_u_missing = fmt::format("soak {} has no uncertainty of its mean{}", order[j],
                                       r.bias_u_note.empty() ? "" : ": " + r.bias_u_note);
        }
      }
      temp.push_back(r.temp_mean_c);
      bias.push_back(r.bias_mean_dph);
      sd.push_back(r.bias_std_dph);
      sd_ma.push_back(r.bias_std_ma_dph);
      bias_e.push_back(r.bias_mean_earth_removed_dph);
    }
    Table1SetpointRow g;
    g.setpoint_c = first_c;
    g.repetitions = j - k;
    g.soaks.assign(order.begin() + static_cast<std::ptrdiff_t>(k),
                   order.begin() + static_cast<std::ptrdiff_t>(j));
    std::sort(g.soaks.begin(), g.soaks.end());
    g.temp_mean_c = mean_spread(std::move(temp));
    g.bias_mean_dph = mean_spread(std::move(bias));
    g.bias_std_dph = mean_spread(std::move(sd));
    g.bias_std_ma_dph = mean_spread(std::move(sd_ma));
    g.bias_mean_earth_removed_dph = mean_spread(std::move(bias_e));
    if (!bias_u_missing.empty()) {
      g.bias_mean_u_note = std::move(bias_u_missing);
    } else if (bias_u.empty()) {
      g.bias_mean_u_note = "no soak with a bias mean";
    } else if (auto u = average_uncertainty(bias_u)) {
      g.bias_mean_u = *u;
    } else {
      g.bias_mean_u_note = u.error().message;
    }
    out.push_back(g);
    k = j;
  }
  return out;
}

}  // namespace gyrotherm::analysis
