// What the calibration reports show: collected from the database and the
// analysis library (report.h). Rendering is in report_render.cpp.
#include "gyrotherm/calibration/report.h"

#include <fmt/format.h>
#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "gyrotherm/core/clock.h"

namespace gyrotherm::calibration {

namespace {

using json = nlohmann::json;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Bucket means of y over consecutive index ranges, so a series of any length
// plots as at most max_points points. NaN values are left out of a bucket's
// mean (a bucket of only NaN is NaN).
std::vector<double> bucket_means(const std::vector<double>& y, std::size_t max_points) {
  const std::size_t n = y.size();
  if (n <= max_points || max_points == 0) return y;
  const std::size_t per = (n + max_points - 1) / max_points;
  std::vector<double> out;
  out.reserve(n / per + 1);
  for (std::size_t i = 0; i < n; i += per) {
    double sum = 0;
    std::size_t count = 0;
    for (std::size_t j = i; j < std::min(n, i + per); ++j) {
      if (std::isfinite(y[j])) {
        sum += y[j];
        ++count;
      }
    }
    out.push_back(count > 0 ? sum / static_cast<double>(count) : kNaN);
  }
  return out;
}

// The mean of the `window` consecutive points centred on each point (the
// window of Table I's last column; an even window reaches one point further
// right); NaN where the window does not fit or holds a NaN. A running sum,
// restarted from a fresh sum every 1024 points so rounding cannot build up.
std::vector<double> centred_moving_average(const std::vector<double>& y, std::size_t window) {
  const std::size_t n = y.size();
  std::vector<double> out(n, kNaN);
  if (window == 0 || window > n) return out;
  const std::size_t left = (window - 1) / 2;
  const double w = static_cast<double>(window);
  double sum = 0;
  for (std::size_t start = 0; start + window <= n; ++start) {
    if (start % 1024 == 0) {
      sum = 0;
      for (std::size_t j = start; j < start + window; ++j) sum += y[j];
    } else {
      sum += y[start + window - 1] - y[start - 1];
    }
    out[start + left] = sum / w;
  }
  return out;
}

std::vector<double> mean_temperature_c(const analysis::AnalysisSeries& s) {
  std::vector<double> t(s.top_c.size());
  for (std::size_t i = 0; i < t.size(); ++i) t[i] = 0.5 * (s.top_c[i] + s.side_c[i]);
  return t;
}

std::vector<double> gradient_c(const analysis::AnalysisSeries& s) {
  std::vector<double> g(s.top_c.size());
  for (std::size_t i = 0; i < g.size(); ++i) g[i] = s.top_c[i] - s.side_c[i];
  return g;
}

// rate - the fit's temperature terms: the compensated output of Tables II-IV.
Result<std::vector<double>> compensated_dph(const analysis::DriftFit& fit,
                                            const analysis::AnalysisSeries& s) {
  auto terms = analysis::drift_terms(fit, s);
  if (!terms) return terms.error();
  std::vector<double> out(s.rate_dph.size());
  for (std::size_t i = 0; i < out.size(); ++i) out[i] = s.rate_dph[i] - (*terms)[i];
  return out;
}

PlotSeries make_series(std::string label, std::vector<double> x, std::vector<double> y,
                       std::string style = "line") {
  PlotSeries s;
  s.label = std::move(label);
  s.x = std::move(x);
  s.y = std::move(y);
  s.style = std::move(style);
  return s;
}

// L0 + sum_i T_i t^i: a temperature-only fit as a curve over [lo, hi].
PlotSeries temperature_curve(const analysis::DriftFit& fit, double lo_c, double hi_c,
                             std::string label) {
  PlotSeries c;
  c.label = std::move(label);
  double l0 = 0;
  if (!fit.l0_per_series_dph.empty()) {
    for (double v : fit.l0_per_series_dph) l0 += v;
    l0 /= static_cast<double>(fit.l0_per_series_dph.size());
  }
  const auto intercept = fit.coefficients.find("intercept");
  if (intercept != fit.coefficients.end()) l0 += intercept->second;
  constexpr int kPoints = 121;
  for (int k = 0; k < kPoints; ++k) {
    const double t = lo_c + (hi_c - lo_c) * k / (kPoints - 1);
    double y = l0;
    for (int i = fit.spec.t_order; i >= 1; --i) {
      const auto a = fit.coefficients.find(fmt::format("T{}", i));
      if (a != fit.coefficients.end()) y += a->second * std::pow(t, i);
    }
    c.x.push_back(t);
    c.y.push_back(y);
  }
  return c;
}

const analysis::ComparisonCell* find_cell(const analysis::Comparison& c, analysis::TermSet terms,
                                          int order) {
  for (const auto& cell : c.cells) {
    if (cell.terms == terms && cell.order == order && cell.fit) return &cell;
  }
  return nullptr;
}

std::string step_label(int segment_index, double setpoint_c) {
  return fmt::format("step {} · {:g} °C", segment_index + 1, setpoint_c);
}

// Fig. 2: bias against mean shell temperature, the Table I means and the
// temperature-only polynomials of orders 1-4.
Plot bias_temperature_plot(const std::vector<const analysis::AnalysisSeries*>& series,
                           const std::vector<std::pair<std::string, const RunReport*>>& table1,
                           const analysis::Comparison* comparison, std::size_t max_points) {
  Plot p;
  p.id = "chart-bias-temperature";
  p.title = "Zero bias vs mean shell temperature";
  p.x = {"mean shell temperature (°C)", false};
  p.y = {"gyro output (°/h)", false};
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (std::size_t k = 0; k < series.size(); ++k) {
    PlotSeries pts;
    pts.label = series.size() == 1 ? "1 s bins (means)" : fmt::format("{} bins", table1[k].first);
    pts.style = "points";
    const auto t = mean_temperature_c(*series[k]);
    const std::size_t per_run = std::max<std::size_t>(200, max_points / series.size());
    pts.x = bucket_means(t, per_run);
    pts.y = bucket_means(series[k]->rate_dph, per_run);
    for (double v : t) {
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
    p.series.push_back(std::move(pts));
  }
  for (const auto& [name, run] : table1) {
    PlotSeries m;
    m.label = table1.size() == 1 ? "Table I means" : fmt::format("Table I, {}", name);
    m.style = "markers";
    for (const auto& row : run->table1) {
      m.x.push_back(row.temp_mean_c);
      m.y.push_back(row.bias_mean_dph);
    }
    if (!m.x.empty()) p.series.push_back(std::move(m));
  }
  if (comparison != nullptr && std::isfinite(lo) && hi > lo) {
    for (int order = 1; order <= 4; ++order) {
      if (const auto* cell = find_cell(*comparison, analysis::TermSet::kT, order)) {
        p.series.push_back(
            temperature_curve(*cell->fit, lo, hi, fmt::format("order {} fit in T", order)));
      }
    }
  }
  return p;
}

}  // namespace

// Fig. 4 / Fig. 6 (report.h): smoothed raw and compensated output over the
// run over the faint raw output, temperature on y2.
Plot output_plot(const analysis::AnalysisSeries& s, const analysis::Comparison& comparison,
                 analysis::TermSet terms, std::string id, std::string title, std::size_t max_points,
                 std::size_t ma_window, std::vector<std::string>& problems) {
  Plot p;
  p.id = std::move(id);
  p.title = std::move(title);
  p.x = {"time since run start (h)", false};
  p.y = {"gyro output (°/h)", false};
  p.y2 = PlotAxis{"mean shell temperature (°C)", false};
  p.height_px = 380;
  std::vector<double> t_h(s.t_s.size());
  for (std::size_t i = 0; i < t_h.size(); ++i) t_h[i] = s.t_s[i] / 3600.0;
  const auto x = bucket_means(t_h, max_points);
  // The 1 s noise (tenths of a °/h) is larger than what the compensation
  // removes: the lines are the moving averages, the raw output faint dots.
  p.series.push_back(
      make_series("raw (1 s bins)", x, bucket_means(s.rate_dph, max_points), "points"));
  const std::string smoothed = fmt::format("{}-point moving average", ma_window);
  p.series.push_back(
      make_series(fmt::format("raw, {}", smoothed), x,
                  bucket_means(centred_moving_average(s.rate_dph, ma_window), max_points)));
  for (int order : {2, 4}) {
    const auto* cell = find_cell(comparison, terms, order);
    if (cell == nullptr) continue;
    auto comp = compensated_dph(*cell->fit, s);
    if (!comp) {
      problems.push_back(fmt::format("{}: compensated output of {}: {}", p.title,
                                     analysis::to_string(cell->spec), comp.error().message));
      continue;
    }
    p.series.push_back(
        make_series(fmt::format("compensated, {}, {}", analysis::to_string(cell->spec), smoothed),
                    x, bucket_means(centred_moving_average(*comp, ma_window), max_points)));
  }
  PlotSeries temperature =
      make_series("temperature", x, bucket_means(mean_temperature_c(s), max_points));
  temperature.axis = "y2";
  temperature.dash = true;
  p.series.push_back(std::move(temperature));
  return p;
}

namespace {

// Fig. 5: bias against the shell gradient, raw and after the order-4
// temperature compensation (what is left for the gradient term to explain).
Plot bias_gradient_plot(const analysis::AnalysisSeries& s, const analysis::Comparison& comparison,
                        std::size_t max_points) {
  Plot p;
  p.id = "chart-bias-gradient";
  p.title = "Zero bias vs shell temperature gradient";
  p.x = {"gradient dT = top − side (°C)", false};
  p.y = {"gyro output (°/h)", false};
  const auto x = bucket_means(gradient_c(s), max_points);
  p.series.push_back(make_series("raw", x, bucket_means(s.rate_dph, max_points), "points"));
  for (int order = 4; order >= 1; --order) {
    const auto* cell = find_cell(comparison, analysis::TermSet::kT, order);
    if (cell == nullptr) continue;
    if (auto comp = compensated_dph(*cell->fit, s)) {
      p.series.push_back(make_series(fmt::format("after the T{} compensation", order), x,
                                     bucket_means(*comp, max_points), "points"));
    }
    break;
  }
  return p;
}

Plot allan_plot(const std::vector<std::pair<std::string, const storage::AllanRecord*>>& records) {
  Plot p;
  p.id = "chart-allan";
  p.title = "Allan deviation of each soak";
  p.x = {"averaging time τ (s)", true};
  p.y = {"Allan deviation (°/h)", true};
  p.height_px = 400;
  for (const auto& [label, a] : records) {
    PlotSeries s = make_series(label, a->tau_s, a->adev_dph);
    s.band_lo = a->adev_lo_dph;
    s.band_hi = a->adev_hi_dph;
    s.band_label = "1σ bounds";
    p.series.push_back(std::move(s));
  }
  return p;
}

// The fits of the configured model stored for this run alone, newest first
// by form; computed when none is stored.
void collect_fits(storage::Database& db, RunReport& r) {
  const std::string model = analysis::to_string(r.settings.model);
  std::map<std::string, ReportFit> stored;
  if (auto fits = db.fits(r.run.id)) {
    for (const auto& rec : *fits) {
      if (rec.model != model || rec.run_ids != std::vector<int64_t>{r.run.id}) continue;
      if (!result_of_stream(rec.dut_serial, rec.axis, r.stream)) continue;
      if (stored.count(rec.form)) continue;  // newest first: keep the first
      auto f = report_fit_of_record(rec);
      if (!f) {
        r.problems.push_back(f.error().message);
        continue;
      }
      stored.emplace(rec.form, std::move(*f));
    }
  } else {
    r.problems.push_back(fits.error().message);
  }
  for (const auto form : r.settings.forms) {
    const std::string name(analysis::to_string(form));
    if (auto it = stored.find(name); it != stored.end()) {
      r.fits.push_back(std::move(it->second));
      continue;
    }
    if (!r.series) continue;
    auto fit = analysis::fit_drift_model(*r.series, r.settings.model, form, r.settings.fit);
    if (!fit) {
      r.problems.push_back(fmt::format("fit {} ({} form): {}", model, name, fit.error().message));
      continue;
    }
    storage::ResultQuality quality =
        fit_quality(*fit, std::span(&*r.series, 1), std::span(&r.series_coverage.coverage, 1),
                    r.settings.quality);
    r.fits.push_back({.fit = std::move(*fit),
                      .stored_id = 0,
                      .run_ids = {r.run.id},
                      .l0_window_s = r.settings.fit.l0_window_s,
                      .quality = std::move(quality)});
  }
}

// The problem line of a flagged result's header: not written (or written
// with --force), and why.
std::string withheld_header(const std::string& file, std::string_view what,
                            const storage::ResultQuality& q, bool forced) {
  return fmt::format("{} {}: {} is flagged: {}{}", file,
                     forced ? "written with --force" : "not written", what,
                     fmt::join(q.reasons, "; "),
                     forced ? "" : " (gyrotherm export --force writes it, marked as forced)");
}

analysis::ComparisonOptions comparison_options(const AnalysisSettings& s, bool cross_validate) {
  analysis::ComparisonOptions o;
  o.fit = s.fit;
  o.smooth_points = s.compare_smooth_points;
  o.cross_validate = cross_validate;
  return o;
}

}  // namespace

Result<ReportFit> report_fit_of_record(const storage::FitRecord& record) {
  const auto bad = [&record](const std::string& why) {
    return Error::Permanent(fmt::format("stored fit {}: {}", record.id, why));
  };
  ReportFit out;
  out.stored_id = record.id;
  out.run_ids = record.run_ids;
  out.quality = record.quality;
  analysis::DriftFit& f = out.fit;
  auto spec = analysis::parse_model_spec(record.model);
  if (!spec) return bad(fmt::format("model \"{}\": {}", record.model, spec.error().message));
  auto form = analysis::parse_drift_model_form(record.form);
  if (!form) return bad(fmt::format("form \"{}\": {}", record.form, form.error().message));
  f.spec = *spec;
  f.form = *form;
  const json coefficients = json::parse(record.coefficients_json, nullptr, false);
  const json errors = json::parse(record.standard_errors_json, nullptr, false);
  const json inputs = json::parse(record.inputs_json, nullptr, false);
  if (!coefficients.is_object()) return bad("coefficients_json is not a JSON object");
  for (const auto& [name, v] : coefficients.items()) {
    if (!v.is_number()) return bad(fmt::format("coefficient {} is not a number", name));
    f.coefficients[name] = v.get<double>();
  }
  if (errors.is_object()) {
    for (const auto& [name, v] : errors.items()) {
      f.std_errors[name] = v.is_number() ? v.get<double>() : kNaN;
    }
  }
  f.n = static_cast<std::size_t>(record.n);
  f.parameters = f.coefficients.size();
  f.residual_std_dph = record.residual_std_dph;
  f.r_squared = record.r_squared;
  f.solver = "stored";
  if (inputs.is_object()) {
    const auto number = [&inputs](const char* key, double fallback) {
      return inputs.contains(key) && inputs[key].is_number() ? inputs[key].get<double>() : fallback;
    };
    f.derivative_window_s = number("derivative_window_s", 60.0);
    out.l0_window_s = number("l0_window_s", 120.0);
    f.condition_estimate = number("condition_estimate", kNaN);
    if (inputs.contains("l0_dph") && inputs["l0_dph"].is_array()) {
      for (const auto& v : inputs["l0_dph"]) {
        f.l0_per_series_dph.push_back(v.is_number() ? v.get<double>() : kNaN);
      }
    }
  }
  if (f.form == analysis::DriftModelForm::kPaper && !f.l0_per_series_dph.empty()) {
    f.l0_dph = f.l0_per_series_dph.front();
  }
  // drift_terms() evaluates through the scaled coefficients: the physical
  // ones with unit scales and no centring are the same polynomial.
  for (const std::string& name : analysis::coefficient_names(f.spec, f.form)) {
    const auto c = f.coefficients.find(name);
    if (c == f.coefficients.end()) return bad(fmt::format("coefficient {} is missing", name));
    f.column_names.push_back(name);
    f.scaled_coefficients.push_back(c->second);
  }
  return out;
}

namespace {

// A JSON array of numbers, or nullopt.
std::optional<std::vector<double>> number_list(const std::string& text) {
  const json j = json::parse(text, nullptr, false);
  if (!j.is_array()) return std::nullopt;
  std::vector<double> out;
  for (const auto& v : j) {
    if (!v.is_number()) return std::nullopt;
    out.push_back(v.get<double>());
  }
  return out;
}

double polynomial(const std::vector<double>& coeffs, double x) {
  double y = 0;
  for (auto c = coeffs.rbegin(); c != coeffs.rend(); ++c) y = y * x + *c;
  return y;
}

// y_of(Σ coeffs[j] (T − t_centre_c)^j) over T in [lo_c, hi_c], 121 points.
PlotSeries polynomial_curve(const std::vector<double>& coeffs, double t_centre_c, double lo_c,
                            double hi_c, std::string label,
                            const std::function<double(double)>& y_of) {
  PlotSeries c;
  c.label = std::move(label);
  constexpr int kPoints = 121;
  for (int k = 0; k < kPoints; ++k) {
    const double t = k == kPoints - 1 ? hi_c : lo_c + (hi_c - lo_c) * k / (kPoints - 1);
    c.x.push_back(t);
    c.y.push_back(y_of(polynomial(coeffs, t - t_centre_c)));
  }
  return c;
}

}  // namespace

Result<std::optional<storage::ScaleFactorTemperatureFitRecord>> scale_factor_temperature_fit_of(
    storage::Database& db, int64_t run_id, const AnalysedAxis& stream) {
  using Record = storage::ScaleFactorTemperatureFitRecord;
  // The API gives one K(T) fit per run; a run with several DUTs has one per
  // DUT's table axis (schema v8 keys the table by run, DUT and axis), read
  // here from the table itself.
  sqlite3_stmt* stmt = nullptr;
  const char* sql =
      "SELECT dut_serial, axis, poly_order, t_centre_c, k_coeffs_json, bias_coeffs_json, "
      "k_ppm_per_c, bias_dph_per_c, created_utc FROM scale_factor_temperature_fits "
      "WHERE run_id = ?";
  if (sqlite3_prepare_v2(db.handle(), sql, -1, &stmt, nullptr) != SQLITE_OK) {
    sqlite3_finalize(stmt);  // a database without the v8 columns: the one fit of the run
    auto one = db.scale_factor_temperature_fit(run_id);
    if (!one) return one.error();
    if (*one && !result_of_stream((*one)->dut_serial, (*one)->axis, stream)) {
      return std::optional<Record>();
    }
    return one;
  }
  sqlite3_bind_int64(stmt, 1, run_id);
  std::optional<Record> found;
  const auto text = [stmt](int col) {
    const auto* t = sqlite3_column_text(stmt, col);
    return t ? std::string(reinterpret_cast<const char*>(t)) : std::string();
  };
  const auto real = [stmt](int col) {
    return sqlite3_column_type(stmt, col) == SQLITE_NULL ? kNaN : sqlite3_column_double(stmt, col);
  };
  int rc;
  while ((rc = sqlite3_step(stmt)) == SQLITE_ROW) {
    Record r;
    r.run_id = run_id;
    r.dut_serial = text(0);
    r.axis = text(1);
    if (!result_of_stream(r.dut_serial, r.axis, stream)) continue;
    r.order = sqlite3_column_int(stmt, 2);
    r.t_centre_c = real(3);
    r.k_coeffs_json = text(4);
    r.bias_coeffs_json = text(5);
    r.k_ppm_per_c = real(6);
    r.bias_dph_per_c = real(7);
    r.created_utc = text(8);
    found = std::move(r);
    break;
  }
  const std::string message = sqlite3_errmsg(db.handle());
  sqlite3_finalize(stmt);
  if (rc != SQLITE_ROW && rc != SQLITE_DONE) {
    return Error::Transient(fmt::format(
        "{}: reading the scale-factor temperature fits of run {}: {}", db.path(), run_id, message));
  }
  return found;
}

Result<std::optional<ReportScaleFactor>> collect_scale_factor(storage::Database& db, int64_t run_id,
                                                              std::vector<std::string>& problems) {
  return collect_scale_factor(db, run_id, problems, AnalysedAxis{});
}

Result<std::optional<ReportScaleFactor>> collect_scale_factor(storage::Database& db, int64_t run_id,
                                                              std::vector<std::string>& problems,
                                                              const AnalysedAxis& stream) {
  ReportScaleFactor sf;
  auto fits = db.scale_factor_fits(run_id);
  if (!fits) return fits.error();
  auto points = db.scale_factor_points(run_id);
  if (!points) return points.error();
  auto temperature = scale_factor_temperature_fit_of(db, run_id, stream);
  if (!temperature) return temperature.error();
  std::erase_if(*fits,
                [&](const auto& f) { return !result_of_stream(f.dut_serial, f.axis, stream); });
  std::erase_if(*points,
                [&](const auto& p) { return !result_of_stream(p.dut_serial, p.axis, stream); });
  if (fits->empty() && points->empty() && !temperature->has_value()) {
    return std::optional<ReportScaleFactor>();
  }
  sf.fits = std::move(*fits);
  sf.points = std::move(*points);
  sf.temperature_fit = std::move(*temperature);
  if (sf.temperature_fit) {
    const auto& t = *sf.temperature_fit;
    const auto k = number_list(t.k_coeffs_json);
    const auto b = number_list(t.bias_coeffs_json);
    const auto size = static_cast<std::size_t>(std::max(0, t.order) + 1);
    if (!k || k->size() != size) {
      problems.push_back(fmt::format(
          "scale-factor temperature fit of run {}: k_coeffs_json \"{}\" is not an array of {} "
          "numbers (order {})",
          run_id, t.k_coeffs_json, size, t.order));
    } else if (!b || b->size() != size) {
      problems.push_back(fmt::format(
          "scale-factor temperature fit of run {}: bias_coeffs_json \"{}\" is not an array of "
          "{} numbers (order {})",
          run_id, t.bias_coeffs_json, size, t.order));
    } else {
      sf.k_coeffs = *k;
      for (double v : *b) sf.bias_coeffs_dph.push_back(v * 3600.0);
    }
  }
  return std::optional<ReportScaleFactor>(std::move(sf));
}

double scale_factor_residual_dps(const storage::ScaleFactorPointRecord& point,
                                 const storage::ScaleFactorFitRecord& fit) {
  return point.output_dps - (fit.k * point.rate_dps + fit.bias_dps);
}

std::vector<Plot> scale_factor_plots(const ReportScaleFactor& sf) {
  std::vector<Plot> plots;
  if (sf.fits.size() < 2) return plots;
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const auto& f : sf.fits) {
    if (!std::isfinite(f.temperature_c)) continue;
    lo = std::min(lo, f.temperature_c);
    hi = std::max(hi, f.temperature_c);
  }
  const bool curves = !sf.k_coeffs.empty() && std::isfinite(lo) && hi > lo;
  // K near 1 varies by ppm: plotted relative to K at the centre temperature
  // (the fit's k0), or to the sequences' mean K without a fit.
  double k_ref = 0;
  if (!sf.k_coeffs.empty() && sf.k_coeffs.front() != 0) {
    k_ref = sf.k_coeffs.front();
  } else {
    for (const auto& f : sf.fits) k_ref += f.k / static_cast<double>(sf.fits.size());
  }
  const auto ppm_of_ref = [k_ref](double k) { return (k / k_ref - 1.0) * 1e6; };
  const std::string order =
      sf.temperature_fit ? fmt::format("order {}", sf.temperature_fit->order) : std::string();
  const double t_centre_c = sf.temperature_fit ? sf.temperature_fit->t_centre_c : 0.0;

  Plot k;
  k.id = "chart-sf-k-temperature";
  k.title = "Scale factor vs temperature";
  k.x = {"mean shell temperature (°C)", false};
  k.y = {fmt::format("K / {:.9f} − 1 (ppm)", k_ref), false};
  PlotSeries k_points;
  k_points.label = "K of each sequence";
  k_points.style = "markers";
  for (const auto& f : sf.fits) {
    k_points.x.push_back(f.temperature_c);
    k_points.y.push_back(ppm_of_ref(f.k));
  }
  k.series.push_back(std::move(k_points));
  if (curves) {
    k.series.push_back(polynomial_curve(sf.k_coeffs, t_centre_c, lo, hi,
                                        fmt::format("K(T), {} fit", order), ppm_of_ref));
  }
  plots.push_back(std::move(k));

  Plot b;
  b.id = "chart-sf-bias-temperature";
  b.title = "Scale-factor bias vs temperature";
  b.x = {"mean shell temperature (°C)", false};
  b.y = {"bias of the line (°/h)", false};
  PlotSeries b_points;
  b_points.label = "bias of each sequence";
  b_points.style = "markers";
  for (const auto& f : sf.fits) {
    b_points.x.push_back(f.temperature_c);
    b_points.y.push_back(f.bias_dps * 3600.0);
  }
  b.series.push_back(std::move(b_points));
  if (curves) {
    b.series.push_back(polynomial_curve(sf.bias_coeffs_dph, t_centre_c, lo, hi,
                                        fmt::format("B(T), {} fit", order),
                                        [](double v) { return v; }));
  }
  plots.push_back(std::move(b));

  Plot n;
  n.id = "chart-sf-nonlinearity";
  n.title = "Scale-factor nonlinearity vs temperature";
  n.x = {"mean shell temperature (°C)", false};
  n.y = {"nonlinearity (ppm)", false};
  PlotSeries rel_k, rel_fs;
  rel_k.label = "relative to K";
  rel_fs.label = "relative to full scale";
  for (const auto& f : sf.fits) {
    rel_k.x.push_back(f.temperature_c);
    rel_k.y.push_back(f.nonlinearity_ppm);
    rel_fs.x.push_back(f.temperature_c);
    rel_fs.y.push_back(f.nonlinearity_fs_ppm);
  }
  n.series.push_back(std::move(rel_k));
  n.series.push_back(std::move(rel_fs));
  plots.push_back(std::move(n));
  return plots;
}

bool result_of_stream(const std::string& dut_serial, const std::string& axis,
                      const AnalysedAxis& stream) {
  const bool dut = dut_serial.empty() ? stream.dut_position == 0 || stream.dut_serial.empty()
                                      : dut_serial == stream.dut_serial;
  const bool of_axis = axis.empty() ? stream.primary : axis == stream.axis;
  return dut && of_axis;
}

Result<RunReport> collect_run_report(storage::Database& db, int64_t run_id,
                                     const ReportOptions& options) {
  auto axes = analysed_axes(db, run_id);
  if (!axes) return axes.error();
  return collect_run_report(db, run_id, options, axes->front(), axes->size() == 1);
}

Result<std::vector<RunReport>> collect_run_reports(storage::Database& db, int64_t run_id,
                                                   const ReportOptions& options) {
  auto axes = analysed_axes(db, run_id);
  if (!axes) return axes.error();
  std::vector<RunReport> out;
  for (const AnalysedAxis& axis : *axes) {
    auto r = collect_run_report(db, run_id, options, axis, axes->size() == 1);
    if (!r) return r.error();
    out.push_back(std::move(*r));
  }
  return out;
}

Result<RunReport> collect_run_report(storage::Database& db, int64_t run_id,
                                     const ReportOptions& options, const AnalysedAxis& stream,
                                     bool only_stream) {
  RunReport r;
  auto run = db.run(run_id);
  if (!run) return run.error();
  r.run = std::move(*run);
  r.stream = stream;
  r.file_suffix = file_suffix(stream, only_stream);
  if (auto settings = analysis_settings_of_run(r.run)) {
    r.settings = std::move(*settings);
  } else {
    r.problems.push_back(settings.error().message + " (the defaults are used)");
  }
  r.station_name =
      options.station_name.empty() ? read_run_config(r.run).station_name : options.station_name;
  const std::size_t max_points = static_cast<std::size_t>(std::max(100, options.max_plot_points));

  auto soaks = soak_windows(db, run_id);
  if (!soaks) return soaks.error();
  auto segments = db.segments(run_id);
  if (!segments) return segments.error();
  for (const auto& seg : *segments) {
    if (!seg.acquire_stop.empty()) r.acquire_stops[seg.index] = seg.acquire_stop;
  }

  // Table I: as stored after the run; computed only if the daemon never did.
  auto stats = db.segment_stats(run_id);
  if (!stats) return stats.error();
  for (auto& row : *stats) {
    if (!result_of_stream(row.dut_serial, row.axis, stream)) continue;
    // A row stored before DUTs (axis "") and one of a later analysis naming
    // the axis are the same soak: the named one is kept.
    auto same = std::find_if(r.table1.begin(), r.table1.end(),
                             [&](const auto& o) { return o.segment_id == row.segment_id; });
    if (same == r.table1.end()) {
      r.table1.push_back(std::move(row));
    } else if (same->axis.empty()) {
      *same = std::move(row);
    }
  }
  if (r.table1.empty() && !soaks->empty()) {
    r.table1_stored = false;
    for (const auto& soak : *soaks) {
      if (auto row = soak_table1(db, soak, r.settings.table1, stream, r.settings.quality)) {
        r.table1.push_back(std::move(*row));
      } else {
        r.problems.push_back(fmt::format("Table I, {}: {}",
                                         step_label(soak.segment_index, soak.setpoint_c),
                                         row.error().message));
      }
    }
  }

  const std::string taus(analysis::to_string(r.settings.allan_taus));
  auto allan = db.allan(run_id);
  if (!allan) return allan.error();
  for (auto& a : *allan) {
    if (a.taus != taus || !result_of_stream(a.dut_serial, a.axis, stream)) continue;
    auto same = std::find_if(r.allan.begin(), r.allan.end(),
                             [&](const auto& o) { return o.segment_index == a.segment_index; });
    if (same == r.allan.end()) {
      r.allan.push_back(std::move(a));
    } else if (same->axis.empty()) {
      *same = std::move(a);
    }
  }
  if (r.allan.empty() && !soaks->empty()) {
    r.allan_stored = false;
    for (const auto& soak : *soaks) {
      if (auto a = soak_allan(db, soak, r.settings.allan_taus, stream, r.settings.quality)) {
        r.allan.push_back(std::move(*a));
      } else {
        r.problems.push_back(fmt::format("Allan deviation, {}: {}",
                                         step_label(soak.segment_index, soak.setpoint_c),
                                         a.error().message));
      }
    }
  }

  if (auto series = run_series(db, run_id, r.settings.table1.bin_s, stream, &r.series_coverage)) {
    r.series = std::move(*series);
  } else {
    r.problems.push_back(
        fmt::format("run {}: no analysis series: {}", run_id, series.error().message));
  }
  collect_fits(db, r);

  if (r.series) {
    auto c =
        analysis::compare_models(std::span(&*r.series, 1), comparison_options(r.settings, false));
    if (c) {
      r.comparison = std::move(*c);
    } else {
      r.comparison_error = c.error().message;
    }
  }

  // Figures.
  std::vector<const analysis::AnalysisSeries*> series;
  if (r.series) series.push_back(&*r.series);
  const std::vector<std::pair<std::string, const RunReport*>> table1{{"", &r}};
  const analysis::Comparison* comparison = r.comparison ? &*r.comparison : nullptr;
  if (!series.empty() || !r.table1.empty()) {
    r.plots.push_back(bias_temperature_plot(series, table1, comparison, max_points));
  }
  if (r.series && comparison != nullptr) {
    r.plots.push_back(output_plot(*r.series, *comparison, analysis::TermSet::kT, "chart-output-t",
                                  "Raw and compensated output, temperature terms (Fig. 4)",
                                  max_points, r.settings.table1.ma_window, r.problems));
    r.plots.push_back(bias_gradient_plot(*r.series, *comparison, max_points));
    r.plots.push_back(
        output_plot(*r.series, *comparison, analysis::TermSet::kTGR, "chart-output-tgr",
                    "Raw and compensated output, temperature, gradient and rate terms (Fig. 6)",
                    max_points, r.settings.table1.ma_window, r.problems));
  }
  std::vector<std::pair<std::string, const storage::AllanRecord*>> allan_records;
  for (const auto& a : r.allan) {
    double setpoint_c = kNaN;
    for (const auto& soak : *soaks) {
      if (soak.segment_index == a.segment_index) setpoint_c = soak.setpoint_c;
    }
    allan_records.emplace_back(step_label(a.segment_index, setpoint_c), &a);
  }
  if (!allan_records.empty()) r.plots.push_back(allan_plot(allan_records));

  auto sf = collect_scale_factor(db, run_id, r.problems, stream);
  if (!sf) return sf.error();
  r.scale_factor = std::move(*sf);
  if (r.scale_factor) {
    for (auto& p : scale_factor_plots(*r.scale_factor)) r.plots.push_back(std::move(p));
  }
  for (const auto& rf : r.fits) {
    if (!rf.quality.flagged()) continue;
    r.problems.push_back(withheld_header(
        fmt::format("drift-fit-{}{}.h", analysis::to_string(rf.fit.form), r.file_suffix),
        fmt::format("the {} fit ({} form)", analysis::to_string(rf.fit.spec),
                    analysis::to_string(rf.fit.form)),
        rf.quality, options.force_flagged));
  }
  if (r.scale_factor && !r.scale_factor->fits.empty()) {
    const storage::ResultQuality q = scale_factor_header_quality(*r.scale_factor);
    if (q.flagged()) {
      r.problems.push_back(withheld_header(fmt::format("scale-factor{}.h", r.file_suffix),
                                           "the scale factor", q, options.force_flagged));
    }
  }
  return r;
}

CampaignReport collect_campaign_report(std::vector<RunReport> runs, const ReportOptions& options) {
  CampaignReport c;
  c.runs = std::move(runs);
  std::sort(c.runs.begin(), c.runs.end(),
            [](const RunReport& a, const RunReport& b) { return a.run.id < b.run.id; });
  if (c.runs.empty()) return c;
  const std::size_t max_points = static_cast<std::size_t>(std::max(100, options.max_plot_points));
  c.station_name = c.runs.front().station_name;
  c.dut_serial = c.runs.front().stream.dut_serial;
  c.dut_model = c.runs.front().stream.dut_model;
  c.axis = c.runs.front().stream.axis;
  c.file_suffix = c.runs.front().file_suffix;
  const AnalysisSettings& settings = c.runs.front().settings;

  std::vector<analysis::AnalysisSeries> series;
  std::vector<analysis::Coverage> coverage;
  std::vector<int64_t> series_runs;
  std::vector<const analysis::AnalysisSeries*> series_ptrs;
  std::vector<std::pair<std::string, const RunReport*>> table1;
  for (const auto& r : c.runs) {
    table1.emplace_back(fmt::format("run {}", r.run.id), &r);
    if (!r.series) continue;
    series.push_back(*r.series);
    coverage.push_back(r.series_coverage.coverage);
    series_runs.push_back(r.run.id);
  }
  for (const auto& s : series) series_ptrs.push_back(&s);

  if (!series.empty()) {
    auto comparison = analysis::compare_models(series, comparison_options(settings, true));
    if (comparison) {
      c.comparison = std::move(*comparison);
    } else {
      c.comparison_error = comparison.error().message;
    }
  } else {
    c.comparison_error = "no run has an analysis series";
  }
  if (series.size() >= 2) {
    auto fit = analysis::fit_drift_model(series, settings.model, analysis::kDefaultDriftModelForm,
                                         settings.fit);
    if (fit) {
      storage::ResultQuality quality = fit_quality(*fit, series, coverage, settings.quality);
      c.joint_fit = ReportFit{.fit = std::move(*fit),
                              .stored_id = 0,
                              .run_ids = series_runs,
                              .l0_window_s = settings.fit.l0_window_s,
                              .quality = std::move(quality)};
      if (c.joint_fit->quality.flagged()) {
        c.problems.push_back(withheld_header(fmt::format("drift-fit{}.h", c.file_suffix),
                                             "the joint fit", c.joint_fit->quality,
                                             options.force_flagged));
      }
    } else {
      c.joint_fit_error = fit.error().message;
    }
  } else {
    c.joint_fit_error = "needs at least 2 runs with samples";
  }

  analysis::StartTemperatureOptions start;
  start.spec = settings.model;
  start.fit = settings.fit;
  if (series.size() >= start.min_distinct_t0) {
    auto model = analysis::fit_start_temperature_model(series, start);
    if (model) {
      c.start_model = std::move(*model);
    } else {
      c.start_model_note = model.error().message;
    }
  } else {
    c.start_model_note = fmt::format(
        "the start-temperature model (eq. 3) needs runs from at least {} distinct start "
        "temperatures; this export has {} run{} with samples",
        start.min_distinct_t0, series.size(), series.size() == 1 ? "" : "s");
  }

  c.plots.push_back(bias_temperature_plot(series_ptrs, table1,
                                          c.comparison ? &*c.comparison : nullptr, max_points));
  std::vector<std::pair<std::string, const storage::AllanRecord*>> allan_records;
  for (const auto& r : c.runs) {
    for (const auto& a : r.allan) {
      double setpoint_c = kNaN;
      for (const auto& row : r.table1) {
        if (row.segment_index == a.segment_index) setpoint_c = row.setpoint_c;
      }
      allan_records.emplace_back(
          fmt::format("run {}, {}", r.run.id, step_label(a.segment_index, setpoint_c)), &a);
    }
  }
  if (!allan_records.empty()) c.plots.push_back(allan_plot(allan_records));
  for (const auto& r : c.runs) {
    for (const auto& p : r.problems) c.problems.push_back(fmt::format("run {}: {}", r.run.id, p));
  }
  return c;
}

std::vector<CampaignReport> collect_campaign_reports(std::vector<RunReport> runs,
                                                     const ReportOptions& options) {
  // Grouped by DUT serial and axis: a run without DUT records (axis "")
  // is its gyro's primary axis, grouped with the unnamed gyro's.
  std::vector<std::pair<std::string, std::string>> keys;
  std::vector<std::vector<RunReport>> groups;
  for (auto& r : runs) {
    const std::pair<std::string, std::string> key{r.stream.dut_serial, r.stream.axis};
    auto it = std::find_if(keys.begin(), keys.end(), [&](const auto& k) {
      return k.first == key.first &&
             (k.second == key.second ||
              (key.first.empty() && (k.second.empty() || key.second.empty())));
    });
    if (it == keys.end()) {
      keys.push_back(key);
      groups.emplace_back();
      it = keys.end() - 1;
    }
    groups[static_cast<std::size_t>(it - keys.begin())].push_back(std::move(r));
  }
  std::vector<CampaignReport> out;
  for (auto& g : groups) out.push_back(collect_campaign_report(std::move(g), options));
  // One unnamed gyro: the summary keeps today's names. Several DUT axes:
  // each summary has its own, index.html is the summary across DUTs.
  const bool one_unnamed = out.size() == 1 && out.front().dut_serial.empty();
  for (auto& c : out) {
    if (one_unnamed) {
      c.file_suffix.clear();
    } else if (!c.runs.empty()) {
      c.file_suffix = file_suffix(c.runs.front().stream, false);
    }
  }
  return out;
}

}  // namespace gyrotherm::calibration
