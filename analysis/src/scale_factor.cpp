// Scale-factor fit, its figures of merit, the fit over temperature and the
// Earth-rate projection; see scale_factor.h.
#include "gyrotherm/analysis/scale_factor.h"

#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <tuple>

#include "common.h"
#include "compensated_sum.h"
#include "gyrotherm/analysis/csv_window.h"
#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/core/units.h"

namespace gyrotherm::analysis {
namespace {

constexpr double kPpm = 1e6;

double mean_of(const std::vector<double>& v) {
  CompensatedSum s;
  for (double x : v) s.add(x);
  return s.value() / static_cast<double>(v.size());
}

// y = k·x + b by least squares from centred sums (two passes). The caller
// guarantees ≥ 2 distinct x, so sxx > 0.
struct Line {
  double k = 0, b = 0, x_mean = 0, sxx = 0;
};
Line fit_line(const std::vector<double>& x, const std::vector<double>& y) {
  Line line;
  line.x_mean = mean_of(x);
  const double y_mean = mean_of(y);
  CompensatedSum sxx, sxy;
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double dx = x[i] - line.x_mean;
    sxx.add(dx * dx);
    sxy.add(dx * (y[i] - y_mean));
  }
  line.sxx = sxx.value();
  line.k = sxy.value() / line.sxx;
  line.b = y_mean - line.k * line.x_mean;
  return line;
}

std::size_t distinct(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return static_cast<std::size_t>(std::unique(v.begin(), v.end()) - v.begin());
}

// y = k₊·x⁺ + k₋·x⁻ + b by least squares (Householder QR on x / scale_x,
// the slopes scaled back), for the asymmetry. The caller guarantees a
// positive and a negative x and ≥ 3 distinct x, so the design has rank 3.
struct SplitLine {
  double k_positive = 0, k_negative = 0, b = 0;
};
SplitLine fit_split_line(const std::vector<double>& x, const std::vector<double>& y,
                         double scale_x) {
  const auto rows = static_cast<Eigen::Index>(x.size());
  Eigen::MatrixXd design(rows, 3);
  Eigen::VectorXd rhs(rows);
  for (Eigen::Index i = 0; i < rows; ++i) {
    const double u = x[static_cast<std::size_t>(i)] / scale_x;
    design(i, 0) = std::max(u, 0.0);
    design(i, 1) = std::min(u, 0.0);
    design(i, 2) = 1;
    rhs(i) = y[static_cast<std::size_t>(i)];
  }
  const Eigen::VectorXd coef = design.householderQr().solve(rhs);
  return {coef(0) / scale_x, coef(1) / scale_x, coef(2)};
}

}  // namespace

Result<ScaleFactorFit> fit_scale_factor(std::span<const RatePoint> points) {
  if (points.empty()) return Error::Permanent("scale-factor fit: no rate points");
  std::vector<double> x, y;
  x.reserve(points.size());
  y.reserve(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    const RatePoint& p = points[i];
    const std::pair<const char*, double> fields[] = {{"rate_dps", p.rate_dps},
                                                     {"output_dps", p.output_dps},
                                                     {"temperature_c", p.temperature_c},
                                                     {"duration_s", p.duration_s}};
    for (const auto& [name, value] : fields) {
      if (!std::isfinite(value)) {
        return Error::Permanent(fmt::format(
            "scale-factor fit: point {} (repetition {}, rate {} °/s) has {} = {}, not a finite "
            "number",
            i, p.repetition, p.rate_dps, name, value));
      }
    }
    x.push_back(p.rate_dps);
    y.push_back(p.output_dps);
  }

  ScaleFactorFit fit;
  fit.points = points.size();
  fit.distinct_rates = distinct(x);
  if (fit.distinct_rates < 2) {
    return Error::Permanent(fmt::format(
        "scale-factor fit: the {} point(s) are all at the same rate {} °/s; the scale factor needs "
        "at least 2 distinct rates",
        points.size(), x[0]));
  }
  for (double r : x) fit.full_scale_dps = std::max(fit.full_scale_dps, std::fabs(r));
  {
    std::vector<double> t;
    for (const RatePoint& p : points) t.push_back(p.temperature_c);
    fit.temperature_mean_c = mean_of(t);
  }

  const Line line = fit_line(x, y);
  fit.k = line.k;
  fit.bias_dps = line.b;
  fit.bias_dph = units::dps_to_dph(line.b);

  CompensatedSum rss;
  fit.residuals_dps.resize(x.size());
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double r = y[i] - (fit.k * x[i] + fit.bias_dps);
    fit.residuals_dps[i] = r;
    rss.add(r * r);
  }
  const double n = static_cast<double>(x.size());
  if (x.size() > 2) {
    const double s2 = rss.value() / (n - 2);
    fit.residual_std_dps = std::sqrt(s2);
    fit.k_std_error = std::sqrt(s2 / line.sxx);
    fit.bias_std_error_dps = std::sqrt(s2 * (1.0 / n + line.x_mean * line.x_mean / line.sxx));
  } else {
    fit.residual_std_dps = fit.k_std_error = fit.bias_std_error_dps = kNaN;
  }
  fit.bias_std_error_dph = units::dps_to_dph(fit.bias_std_error_dps);

  // Nonlinearity: relative to K·Ω (the headline) and to full scale.
  double worst = -1, worst_abs = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double r = std::fabs(fit.residuals_dps[i]);
    worst_abs = std::max(worst_abs, r);
    if (x[i] == 0) continue;
    const double rel = r / std::fabs(fit.k * x[i]);
    if (rel > worst) {
      worst = rel;
      fit.nonlinearity_point = i;
    }
  }
  fit.nonlinearity_ppm = worst * kPpm;  // some Ω ≠ 0 exists: 2 distinct rates
  fit.nonlinearity_fs_ppm = worst_abs / (std::fabs(fit.k) * fit.full_scale_dps) * kPpm;

  const bool has_positive = std::any_of(x.begin(), x.end(), [](double r) { return r > 0; });
  const bool has_negative = std::any_of(x.begin(), x.end(), [](double r) { return r < 0; });
  if (has_positive && has_negative && fit.distinct_rates >= 3) {
    const SplitLine split = fit_split_line(x, y, fit.full_scale_dps);
    fit.k_positive = split.k_positive;
    fit.k_negative = split.k_negative;
    fit.asymmetry_bias_dps = split.b;
    const double k_mean = (split.k_positive + split.k_negative) / 2;
    if (k_mean != 0) fit.asymmetry_ppm = (split.k_positive - split.k_negative) / k_mean * kPpm;
  }

  std::map<int, std::pair<std::vector<double>, std::vector<double>>> by_repetition;
  for (const RatePoint& p : points) {
    auto& [rx, ry] = by_repetition[p.repetition];
    rx.push_back(p.rate_dps);
    ry.push_back(p.output_dps);
  }
  std::vector<double> ks;
  for (const auto& [rep, xy] : by_repetition) {
    if (distinct(xy.first) < 2) continue;
    const Line l = fit_line(xy.first, xy.second);
    fit.repetitions.push_back({rep, xy.first.size(), l.k, l.b});
    ks.push_back(l.k);
  }
  if (ks.size() >= 2) {
    const double k_mean = mean_of(ks);
    CompensatedSum ss;
    for (double k : ks) ss.add((k - k_mean) * (k - k_mean));
    const double sd = std::sqrt(ss.value() / static_cast<double>(ks.size() - 1));
    fit.repeatability_ppm = sd / k_mean * kPpm;
  }
  return fit;
}

namespace {

constexpr CsvColumn kRatePointColumns[] = {
    {"rate_dps", true}, {"output_dps", true}, {"repetition", false}, {"temperature_c", false}};

Result<RatePointsCsv> rate_points_of(const CsvColumns& table) {
  RatePointsCsv out;
  out.source = table.source;
  out.has_repetition = table.present[2];
  out.has_temperature = table.present[3];
  std::string errors;
  std::size_t error_count = 0;
  for (std::size_t i = 0; i < table.row_count; ++i) {
    RatePoint p;
    p.rate_dps = table.values[0][i];
    p.output_dps = table.values[1][i];
    if (out.has_repetition) {
      const double rep = table.values[2][i];
      if (rep != std::floor(rep) || std::fabs(rep) > 1e9) {
        if (++error_count <= kMaxCsvErrors) {
          errors += fmt::format("{}{}:{}: column repetition: {} is not a whole number",
                                errors.empty() ? "" : "\n", table.source, table.line[i], rep);
        }
        continue;
      }
      p.repetition = static_cast<int>(rep);
    }
    if (out.has_temperature) p.temperature_c = table.values[3][i];
    out.points.push_back(p);
    out.lines.push_back(table.line[i]);
  }
  if (error_count > kMaxCsvErrors) {
    errors += fmt::format("\n... and {} more errors", error_count - kMaxCsvErrors);
  }
  if (error_count > 0) return Error::Permanent(std::move(errors));
  return out;
}

}  // namespace

Result<RatePointsCsv> parse_rate_points_csv(std::string_view text, const std::string& source_name) {
  auto table = parse_csv_columns(text, source_name, kRatePointColumns);
  if (!table) return table.error();
  return rate_points_of(*table);
}

Result<RatePointsCsv> read_rate_points_csv(const std::string& path) {
  auto table = read_csv_columns(path, kRatePointColumns);
  if (!table) return table.error();
  return rate_points_of(*table);
}

Result<ScaleFactorTemperatureFit> fit_scale_factor_over_temperature(
    std::span<const ScaleFactorAtTemperature> plateaus, int order) {
  if (order != 1 && order != 2) {
    return Error::Permanent(
        fmt::format("scale factor over temperature: order must be 1 or 2, got {}", order));
  }
  std::vector<double> t;
  for (std::size_t i = 0; i < plateaus.size(); ++i) {
    const ScaleFactorAtTemperature& p = plateaus[i];
    const std::pair<const char*, double> fields[] = {
        {"temperature_c", p.temperature_c}, {"k", p.k}, {"bias_dph", p.bias_dph}};
    for (const auto& [name, value] : fields) {
      if (!std::isfinite(value)) {
        return Error::Permanent(fmt::format(
            "scale factor over temperature: plateau {} has {} = {}, not a finite number", i, name,
            value));
      }
    }
    t.push_back(p.temperature_c);
  }
  const std::size_t temps = distinct(t);
  if (static_cast<std::size_t>(order) >= temps) {
    return Error::Permanent(fmt::format(
        "scale factor over temperature: a polynomial of order {} needs at least {} distinct "
        "temperatures, got {}",
        order, order + 1, temps));
  }

  ScaleFactorTemperatureFit fit;
  fit.order = order;
  fit.temperatures = plateaus.size();
  fit.temperature_mean_c = mean_of(t);
  double scale_c = 0;
  for (double v : t) scale_c = std::max(scale_c, std::fabs(v - fit.temperature_mean_c));

  const auto rows = static_cast<Eigen::Index>(plateaus.size());
  const Eigen::Index cols = order + 1;
  Eigen::MatrixXd design(rows, cols);
  Eigen::MatrixXd rhs(rows, 2);
  for (Eigen::Index i = 0; i < rows; ++i) {
    const double u = (t[static_cast<std::size_t>(i)] - fit.temperature_mean_c) / scale_c;
    double power = 1;
    for (Eigen::Index j = 0; j < cols; ++j, power *= u) design(i, j) = power;
    rhs(i, 0) = plateaus[static_cast<std::size_t>(i)].k;
    rhs(i, 1) = plateaus[static_cast<std::size_t>(i)].bias_dph;
  }
  const Eigen::MatrixXd coef = design.householderQr().solve(rhs);
  const Eigen::MatrixXd residuals = rhs - design * coef;
  double scale_power = 1;
  for (Eigen::Index j = 0; j < cols; ++j, scale_power *= scale_c) {
    fit.k_coefficients.push_back(coef(j, 0) / scale_power);
    fit.bias_coefficients_dph.push_back(coef(j, 1) / scale_power);
  }
  for (Eigen::Index i = 0; i < rows; ++i) {
    fit.k_residuals.push_back(residuals(i, 0));
    fit.bias_residuals_dph.push_back(residuals(i, 1));
  }
  fit.k_at_mean = fit.k_coefficients[0];
  if (!(fit.k_at_mean != 0) || !std::isfinite(fit.k_at_mean)) {
    return Error::Permanent(fmt::format(
        "scale factor over temperature: K at the mean temperature {} °C is {}; no relative "
        "temperature coefficient",
        fit.temperature_mean_c, fit.k_at_mean));
  }
  fit.sf_temperature_coefficient_ppm_per_c = fit.k_coefficients[1] / fit.k_at_mean * kPpm;
  fit.bias_temperature_coefficient_dph_per_c = fit.bias_coefficients_dph[1];
  return fit;
}

Result<SensitiveAxis> parse_sensitive_axis(std::string_view s) {
  if (s == "along_table") return SensitiveAxis::kAlongTable;
  if (s == "radial") return SensitiveAxis::kRadial;
  return Error::Permanent(
      fmt::format("unknown sensitive axis '{}' (expected along_table or radial)", s));
}

std::string_view to_string(SensitiveAxis axis) {
  switch (axis) {
    case SensitiveAxis::kAlongTable:
      return "along_table";
    case SensitiveAxis::kRadial:
      return "radial";
  }
  return "unknown";
}

bool RatePointFlatnessOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  // A tolerance of 0 sigma would refuse every noisy point.
  if (!(n_sigma > 0) || !std::isfinite(n_sigma)) {
    return fail(fmt::format("n_sigma = {} must be finite and > 0", n_sigma));
  }
  if (!(tolerance_ppm >= 0) || !std::isfinite(tolerance_ppm)) {
    return fail(fmt::format("tolerance_ppm = {} must be finite and >= 0", tolerance_ppm));
  }
  return true;
}

RatePointFlatness check_rate_point_flatness(std::span<const double> samples, double demanded_dps,
                                            const RatePointFlatnessOptions& options,
                                            bool at_demand) {
  RatePointFlatness out;
  if (std::string why; !options.is_valid(&why)) {
    out.checked = true;
    out.ok = false;
    out.why = "invalid flatness options: " + why;
    return out;
  }
  std::vector<double> y;
  for (double v : samples) {
    if (std::isfinite(v)) y.push_back(v);
  }
  if (y.size() < 6) return out;
  out.checked = true;
  const std::size_t third = y.size() / 3;
  // Mean and the variance of the mean.
  const auto stats = [](std::span<const double> part) {
    CompensatedSum sum;
    for (double v : part) sum.add(v);
    const double mean = sum.value() / static_cast<double>(part.size());
    CompensatedSum sq;
    for (double v : part) sq.add((v - mean) * (v - mean));
    const double var = sq.value() / static_cast<double>(part.size() - 1);
    return std::pair{mean, var / static_cast<double>(part.size())};
  };
  const auto [first, first_var] = stats(std::span<const double>(y).first(third));
  const auto [last, last_var] = stats(std::span<const double>(y).last(third));
  out.first_mean = first;
  out.last_mean = last;
  const double rate_term = options.tolerance_ppm * 1e-6 * std::fabs(demanded_dps);
  out.tolerance = options.n_sigma * std::sqrt(first_var + last_var) + rate_term;
  const double step = std::fabs(first - last);
  if (!(step <= out.tolerance)) {
    out.ok = false;
    out.why = fmt::format(
        "not flat: the first third of its samples reads {:.7g} °/s, the last third {:.7g} °/s "
        "({:.3g} °/s apart; tolerance {:.3g} °/s)",
        first, last, step, out.tolerance);
    return out;
  }
  if (!at_demand) return out;
  for (const auto& [name, mean, var] :
       {std::tuple{"first", first, first_var}, std::tuple{"last", last, last_var}}) {
    const double tolerance = options.n_sigma * std::sqrt(var) + rate_term;
    if (!(std::fabs(mean - demanded_dps) <= tolerance)) {
      out.ok = false;
      out.why = fmt::format(
          "not at the demanded rate: the {} third reads {:.7g} °/s for a demand of {:g} °/s "
          "({:.3g} °/s off; tolerance {:.3g} °/s)",
          name, mean, demanded_dps, std::fabs(mean - demanded_dps), tolerance);
      return out;
    }
  }
  return out;
}

double earth_rate_projection_dph(double latitude_deg, SensitiveAxis axis,
                                 double heading_at_zero_deg, double position_deg) {
  switch (axis) {
    case SensitiveAxis::kAlongTable:
      return earth_rate_component_dph(latitude_deg, AxisOrientation::kUp);
    case SensitiveAxis::kRadial:
      return units::kEarthRateDph * std::cos(units::deg_to_rad(latitude_deg)) *
             std::cos(units::deg_to_rad(heading_at_zero_deg + position_deg));
  }
  return kNaN;
}

}  // namespace gyrotherm::analysis
