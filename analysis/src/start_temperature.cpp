// Start-temperature model (paper eq. 3) and coefficient export; see
// start_temperature.h.
#include "gyrotherm/analysis/start_temperature.h"

#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <nlohmann/json.hpp>

#include "common.h"
#include "gyrotherm/core/text.h"

namespace gyrotherm::analysis {
namespace {

constexpr int kCubic = 4;  // A_0 .. A_3

// 17 significant digits: reads back as the same double.
std::string num(double v) { return fmt::format("{:.17g}", v); }

double horner_cubic(const std::array<double, 4>& a, double x) {
  return a[0] + x * (a[1] + x * (a[2] + x * a[3]));
}

double binomial(int n, int k) {
  double r = 1;
  for (int i = 1; i <= k; ++i) r = r * (n - k + i) / i;
  return r;
}

std::string join_c(const std::vector<double>& v) {
  std::string out;
  for (double x : v) out += (out.empty() ? "" : ", ") + fmt::format("{:.2f}", x);
  return out;
}

std::string c_identifier(const std::string& prefix) {
  std::string out = prefix.empty() ? std::string("gyrotherm") : prefix;
  for (char& c : out) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_') c = '_';
  }
  if (std::isdigit(static_cast<unsigned char>(out.front()))) out.insert(out.begin(), '_');
  return out;
}

std::string upper(std::string s) {
  for (char& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

// "x * (c1 + x * (c2 + x * c3))" for the names c1..ck; "" when none.
std::string horner_c(const std::string& x, const std::vector<std::string>& coefficient_exprs) {
  if (coefficient_exprs.empty()) return "";
  std::string inner = coefficient_exprs.back();
  for (std::size_t i = coefficient_exprs.size() - 1; i-- > 0;) {
    inner = fmt::format("{} + {} * {}", coefficient_exprs[i], x,
                        i + 2 == coefficient_exprs.size() ? inner : "(" + inner + ")");
  }
  return coefficient_exprs.size() == 1 ? fmt::format("{} * {}", x, inner)
                                       : fmt::format("{} * ({})", x, inner);
}

struct Family {
  char letter;
  int order;
  const char* variable;  // C parameter name
};

std::array<Family, 3> families(const DriftModelSpec& spec) {
  return {{{'T', spec.t_order, "t_c"},
           {'R', spec.r_order, "dtdt_c_per_s"},
           {'G', spec.g_order, "dt_c"}}};
}

// The body of a C function summing the three families by Horner's rule;
// `coef(name)` is the C expression of coefficient `name` ("T1", ...).
template <class Coef>
std::string c_terms_body(const DriftModelSpec& spec, Coef coef) {
  std::string body = "  double drift_dph = 0.0;\n";
  for (const Family& f : families(spec)) {
    if (f.order == 0) {
      body += fmt::format("  (void){};\n", f.variable);
      continue;
    }
    std::vector<std::string> exprs;
    for (int i = 1; i <= f.order; ++i) exprs.push_back(coef(fmt::format("{}{}", f.letter, i)));
    body += fmt::format("  drift_dph += {};\n", horner_c(f.variable, exprs));
  }
  body += "  return drift_dph;\n";
  return body;
}

}  // namespace

std::string export_metadata_c(const ExportInfo& info) {
  if (info.gyro_model.empty() && info.axis.empty() && info.operator_name.empty() &&
      info.comment.empty() && info.tags.empty()) {
    return "";
  }
  std::string tags;
  for (const auto& t : info.tags) tags += (tags.empty() ? "" : ", ") + t;
  const auto or_dash = [](const std::string& s) { return s.empty() ? std::string("-") : s; };
  return fmt::format(
      " * Model: {}; axis: {}; operator: {}; tags: {}\n * Comment: {}\n",
      text::c_comment_text(or_dash(info.gyro_model)), text::c_comment_text(or_dash(info.axis)),
      text::c_comment_text(or_dash(info.operator_name)), text::c_comment_text(or_dash(tags)),
      text::c_comment_text(or_dash(info.comment)));
}

namespace {

std::string provenance_c(const ExportInfo& info) {
  std::string runs;
  for (int64_t id : info.run_ids) runs += (runs.empty() ? "" : ", ") + std::to_string(id);
  std::string out = fmt::format(
      " * Station: {}; gyro: {}; runs: {}; computed: {}\n",
      text::c_comment_text(info.station.empty() ? "(unnamed)" : info.station),
      text::c_comment_text(info.gyro_serial.empty() ? "(no serial)" : info.gyro_serial),
      runs.empty() ? "(none)" : runs,
      text::c_comment_text(info.computed_utc.empty() ? "(unknown)" : info.computed_utc));
  out += export_metadata_c(info);
  return out;
}

// The include guard of a header: the prefix, the kind of header and the form,
// so headers of different forms or kinds can be included together (with
// distinct prefixes; the same prefix then fails to compile on the repeated
// names instead of silently skipping the second header).
std::string c_guard(const std::string& identifier, std::string_view kind, DriftModelForm form) {
  return fmt::format("{}_{}_{}_H_", upper(identifier), kind, upper(std::string(to_string(form))));
}

std::string variables_c(double derivative_window_s, double l0_window_s, DriftModelForm form) {
  std::string s = fmt::format(
      " * drift_dph = sum_i T_i * T^i + sum_j R_j * (dT/dt)^j + sum_k G_k * dT^k, where\n"
      " *   T     = mean shell temperature (top + side) / 2, degC\n"
      " *   dT/dt = its smoothing derivative (local linear fit over {} s), degC/s\n"
      " *   dT    = temperature gradient top - side, degC\n"
      " * Coefficients in deg/h per (unit of the variable)^power; drift_dph in deg/h.\n"
      " * Compensated rate = gyro rate - drift_dph.\n",
      num(derivative_window_s));
  if (form == DriftModelForm::kPaper) {
    s += fmt::format(
        " * Paper form: L - L0 = drift_dph, L0 = the run's mean rate over its first {} s.\n",
        num(l0_window_s));
  } else {
    s += " * Centred form: the intercept (deg/h) is the fitted rate at T = 0, dT/dt = 0, dT = 0;\n"
         " * it is not part of drift_dph.\n";
  }
  return s;
}

void add_info(nlohmann::ordered_json& j, const ExportInfo& info) {
  j["station"] = info.station;
  j["gyro_serial"] = info.gyro_serial;
  j["gyro_model"] = info.gyro_model;
  j["axis"] = info.axis;
  j["operator"] = info.operator_name;
  j["comment"] = info.comment;
  j["tags"] = info.tags;
  j["runs"] = info.run_ids;
  j["computed_utc"] = info.computed_utc;
}

nlohmann::ordered_json units_json() {
  return {{"rate", "deg/h"},
          {"T", "degC, mean shell temperature (top + side) / 2"},
          {"R", "degC/s, smoothing derivative of T"},
          {"G", "degC, gradient top - side"},
          {"coefficients", "deg/h per (unit of T, R or G)^power; intercept in deg/h"}};
}

}  // namespace

bool StartTemperatureOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  if (spec.t_order < 0 || spec.t_order > kMaxTermOrder || spec.r_order < 0 ||
      spec.r_order > kMaxTermOrder || spec.g_order < 0 || spec.g_order > kMaxTermOrder ||
      spec.parameters() == 0) {
    return fail(fmt::format("spec T{} R{} G{}: orders must be 0..{}, not all 0", spec.t_order,
                            spec.r_order, spec.g_order, kMaxTermOrder));
  }
  std::string sub_why;
  if (!fit.is_valid(&sub_why)) return fail("fit: " + sub_why);
  if (!(t0_window_s > 0) || !std::isfinite(t0_window_s)) {
    return fail(fmt::format("t0_window_s must be positive ({})", t0_window_s));
  }
  if (!(distinct_t0_c >= 0) || !std::isfinite(distinct_t0_c)) {
    return fail(fmt::format("distinct_t0_c must be >= 0 ({})", distinct_t0_c));
  }
  if (min_distinct_t0 < static_cast<std::size_t>(kCubic)) {
    return fail(fmt::format("min_distinct_t0 must be >= {} (a cubic has {} coefficients; {})",
                            kCubic, kCubic, min_distinct_t0));
  }
  return true;
}

Result<double> start_temperature_c(const AnalysisSeries& series, double t0_window_s) {
  if (!(t0_window_s > 0) || !std::isfinite(t0_window_s)) {
    return Error::Permanent(
        fmt::format("start temperature: window must be positive ({} s)", t0_window_s));
  }
  const std::size_t n = series.t_s.size();
  if (n == 0) return Error::Permanent("start temperature: the series is empty");
  if (series.top_c.size() != n || series.side_c.size() != n) {
    return Error::Permanent(
        fmt::format("start temperature: series vectors differ in length (t_s {}, top_c {}, "
                    "side_c {})",
                    n, series.top_c.size(), series.side_c.size()));
  }
  if (!std::isfinite(series.t_s[0])) {
    return Error::Permanent(
        fmt::format("start temperature: t_s[0] is not finite ({})", series.t_s[0]));
  }
  long double sum = 0;
  std::size_t count = 0;
  for (std::size_t i = 0; i < n && series.t_s[i] - series.t_s[0] < t0_window_s; ++i) {
    if (!std::isfinite(series.top_c[i]) || !std::isfinite(series.side_c[i])) {
      return Error::Permanent(
          fmt::format("start temperature: top_c[{}]={} or side_c[{}]={} is not finite", i,
                      series.top_c[i], i, series.side_c[i]));
    }
    sum += (static_cast<long double>(series.top_c[i]) + series.side_c[i]) / 2;
    ++count;
  }
  if (count == 0) {
    return Error::Permanent(
        fmt::format("start temperature: t_s[0] is not finite ({})", series.t_s[0]));
  }
  return static_cast<double>(sum / static_cast<long double>(count));
}

Result<StartTemperatureModel> fit_start_temperature_model(std::span<const AnalysisSeries> runs,
                                                          const StartTemperatureOptions& options) {
  std::string why;
  if (!options.is_valid(&why)) return Error::Permanent("start-temperature model options: " + why);
  if (runs.empty()) return Error::Permanent("start-temperature model: no runs");

  StartTemperatureModel model;
  model.spec = options.spec;
  model.form = options.form;
  model.derivative_window_s = options.fit.derivative_window_s;
  model.l0_window_s = options.fit.l0_window_s;
  model.t0_window_s = options.t0_window_s;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    auto t0 = start_temperature_c(runs[r], options.t0_window_s);
    if (!t0) {
      return Error::Permanent(
          fmt::format("start-temperature model: run {}: {}", r + 1, t0.error().message));
    }
    model.t0_c.push_back(*t0);
  }

  std::vector<double> sorted = model.t0_c;
  std::sort(sorted.begin(), sorted.end());
  std::vector<double> distinct;
  for (double t : sorted) {
    if (distinct.empty() || t - distinct.back() > options.distinct_t0_c) distinct.push_back(t);
  }
  if (distinct.size() < options.min_distinct_t0) {
    return Error::Permanent(fmt::format(
        "start-temperature model needs runs started at >= {} distinct temperatures T0 (differing "
        "by more than {} °C); found {}: {} °C (T0 of the {} run(s): {} °C)",
        options.min_distinct_t0, options.distinct_t0_c, distinct.size(), join_c(distinct),
        runs.size(), join_c(model.t0_c)));
  }

  for (std::size_t r = 0; r < runs.size(); ++r) {
    auto fit = fit_drift_model(runs[r], options.spec, options.form, options.fit);
    if (!fit) {
      return Error::Permanent(fmt::format("start-temperature model: run {} (T0 = {:.2f} °C): {}",
                                          r + 1, model.t0_c[r], fit.error().message));
    }
    model.run_coefficients.push_back(fit->coefficients);
  }

  // Cubic in u = (T0 - c) / s by Householder QR, then expanded to powers of T0.
  const std::size_t k = runs.size();
  double center = 0;
  for (double t : model.t0_c) center += t;
  center /= static_cast<double>(k);
  double scale = 0;
  for (double t : model.t0_c) scale = std::max(scale, std::abs(t - center));
  Eigen::MatrixXd u(static_cast<Eigen::Index>(k), kCubic);
  for (std::size_t r = 0; r < k; ++r) {
    const double x = (model.t0_c[r] - center) / scale;
    const auto i = static_cast<Eigen::Index>(r);
    u(i, 0) = 1;
    for (int j = 1; j < kCubic; ++j) u(i, j) = u(i, j - 1) * x;
  }
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(u);
  for (const std::string& name : coefficient_names(options.spec, options.form)) {
    Eigen::VectorXd v(static_cast<Eigen::Index>(k));
    for (std::size_t r = 0; r < k; ++r) {
      v(static_cast<Eigen::Index>(r)) = model.run_coefficients[r].at(name);
    }
    const Eigen::VectorXd b = qr.solve(v);
    std::array<double, 4> a{};
    for (int j = 0; j < kCubic; ++j) {
      for (int m = j; m < kCubic; ++m) {
        a[static_cast<std::size_t>(j)] +=
            b(m) * binomial(m, j) * std::pow(-center, m - j) / std::pow(scale, m);
      }
    }
    model.cubic[name] = a;
    const double rss = (v - u * b).squaredNorm();
    model.cubic_residual_std[name] = k > static_cast<std::size_t>(kCubic)
                                         ? std::sqrt(rss / static_cast<double>(k - kCubic))
                                         : 0.0;
  }
  return model;
}

Result<StartTemperatureCoefficients> coefficients_at(const StartTemperatureModel& model,
                                                     double t0_c) {
  if (!std::isfinite(t0_c)) {
    return Error::Permanent(fmt::format("start-temperature model: T0 = {} is not finite", t0_c));
  }
  const std::vector<std::string> names = coefficient_names(model.spec, model.form);
  if (names.empty() || model.t0_c.empty()) {
    return Error::Permanent("start-temperature model: the model is empty (not fitted)");
  }
  StartTemperatureCoefficients out;
  out.t0_c = t0_c;
  const auto [lo, hi] = std::minmax_element(model.t0_c.begin(), model.t0_c.end());
  out.extrapolated = t0_c < *lo || t0_c > *hi;
  DriftFit& fit = out.fit;
  fit.spec = model.spec;
  fit.form = model.form;
  fit.parameters = names.size();
  fit.derivative_window_s = model.derivative_window_s;
  // Raw (unscaled) variables: the scaled coefficients are the physical ones.
  fit.t_center = fit.r_center = fit.g_center = 0;
  fit.t_scale = fit.r_scale = fit.g_scale = 1;
  for (const std::string& name : names) {
    const auto it = model.cubic.find(name);
    if (it == model.cubic.end()) {
      return Error::Permanent(
          fmt::format("start-temperature model: no cubic for coefficient {}", name));
    }
    const double a = horner_cubic(it->second, t0_c);
    fit.column_names.push_back(name);
    fit.scaled_coefficients.push_back(a);
    fit.coefficients[name] = a;
  }
  return out;
}

Result<std::vector<double>> compensate_from_start(const StartTemperatureModel& model,
                                                  const AnalysisSeries& series) {
  auto t0 = start_temperature_c(series, model.t0_window_s);
  if (!t0) return t0.error();
  auto at = coefficients_at(model, *t0);
  if (!at) return at.error();
  auto terms = drift_terms(at->fit, series);
  if (!terms) return terms.error();
  std::vector<double> out(series.rate_dph.size());
  for (std::size_t i = 0; i < out.size(); ++i) out[i] = series.rate_dph[i] - (*terms)[i];
  return out;
}

// ---- export ------------------------------------------------------------------

std::string drift_fit_json(const DriftFit& fit, const ExportInfo& info) {
  nlohmann::ordered_json j;
  j["kind"] = "gyrotherm drift model (paper eq. 1)";
  j["model"] = to_string(fit.spec);
  j["form"] = std::string(to_string(fit.form));
  j["units"] = units_json();
  nlohmann::ordered_json coefficients = nlohmann::ordered_json::object();
  nlohmann::ordered_json std_errors = nlohmann::ordered_json::object();
  for (const std::string& name : coefficient_names(fit.spec, fit.form)) {
    const auto c = fit.coefficients.find(name);
    if (c != fit.coefficients.end()) coefficients[name] = c->second;
    const auto s = fit.std_errors.find(name);
    if (s != fit.std_errors.end()) std_errors[name] = s->second;
  }
  j["coefficients"] = coefficients;
  j["std_errors"] = std_errors;
  j["l0_dph"] = fit.l0_dph;
  j["l0_window_s"] = info.l0_window_s;
  j["derivative_window_s"] = fit.derivative_window_s;
  j["residual_std_dph"] = fit.residual_std_dph;
  j["r_squared"] = fit.r_squared;
  j["condition_estimate"] = fit.condition_estimate;
  j["n"] = fit.n;
  j["parameters"] = fit.parameters;
  add_info(j, info);
  return j.dump(2);
}

std::string drift_fit_c_header(const DriftFit& fit, const ExportInfo& info,
                               const std::string& prefix) {
  const std::string p = c_identifier(prefix);
  const std::string guard = c_guard(p, "DRIFT_FIT", fit.form);
  std::string out = fmt::format(
      "/* {}.h: temperature drift model of a fiber-optic gyro (paper eq. 1).\n"
      " * Generated by gyrotherm; do not edit.\n",
      p);
  out += provenance_c(info);
  out += fmt::format(" * Model {} ({} form): n = {}, residual std = {} deg/h, R^2 = {}\n",
                     to_string(fit.spec), to_string(fit.form), fit.n, num(fit.residual_std_dph),
                     num(fit.r_squared));
  out += " *\n" + variables_c(fit.derivative_window_s, info.l0_window_s, fit.form) + " */\n";
  out += fmt::format("#ifndef {0}\n#define {0}\n\n", guard);
  for (const std::string& name : coefficient_names(fit.spec, fit.form)) {
    const auto c = fit.coefficients.find(name);
    out += fmt::format("static const double {}_{} = {};\n", p, name,
                       num(c == fit.coefficients.end() ? 0.0 : c->second));
  }
  out += fmt::format("static const double {}_derivative_window_s = {};\n", p,
                     num(fit.derivative_window_s));
  if (fit.form == DriftModelForm::kPaper) {
    out += fmt::format("static const double {}_l0_window_s = {};\n", p, num(info.l0_window_s));
  }
  out += fmt::format(
      "\n/* Temperature-induced drift, deg/h, from T (degC), dT/dt (degC/s), dT (degC). */\n"
      "static inline double {}_terms(double t_c, double dtdt_c_per_s, double dt_c) {{\n",
      p);
  out += c_terms_body(fit.spec, [&p](const std::string& name) { return p + "_" + name; });
  out += fmt::format("}}\n\n#endif /* {} */\n", guard);
  return out;
}

std::string start_model_json(const StartTemperatureModel& model, const ExportInfo& info) {
  nlohmann::ordered_json j;
  j["kind"] = "gyrotherm start-temperature model (paper eq. 3)";
  j["model"] = to_string(model.spec);
  j["form"] = std::string(to_string(model.form));
  j["units"] = units_json();
  j["cubic_form"] = "a(T0) = A0 + A1*T0 + A2*T0^2 + A3*T0^3, T0 in degC";
  nlohmann::ordered_json cubic = nlohmann::ordered_json::object();
  nlohmann::ordered_json residual = nlohmann::ordered_json::object();
  for (const std::string& name : coefficient_names(model.spec, model.form)) {
    const auto c = model.cubic.find(name);
    if (c == model.cubic.end()) continue;
    cubic[name] = c->second;
    const auto s = model.cubic_residual_std.find(name);
    residual[name] = s == model.cubic_residual_std.end() ? 0.0 : s->second;
  }
  j["cubic"] = cubic;
  j["cubic_residual_std"] = residual;
  j["t0_c"] = model.t0_c;
  j["run_coefficients"] = model.run_coefficients;
  j["t0_window_s"] = model.t0_window_s;
  j["l0_window_s"] = model.l0_window_s;
  j["derivative_window_s"] = model.derivative_window_s;
  add_info(j, info);
  return j.dump(2);
}

std::string start_model_c_header(const StartTemperatureModel& model, const ExportInfo& info,
                                 const std::string& prefix) {
  const std::string p = c_identifier(prefix);
  const std::string up = upper(p);
  const std::string guard = c_guard(p, "START_MODEL", model.form);
  const std::vector<std::string> names = coefficient_names(model.spec, model.form);
  std::string out = fmt::format(
      "/* {}.h: start-temperature drift model of a fiber-optic gyro (paper eq. 1 and 3).\n"
      " * Generated by gyrotherm; do not edit.\n",
      p);
  out += provenance_c(info);
  double lo = 0, hi = 0;
  if (!model.t0_c.empty()) {
    lo = *std::min_element(model.t0_c.begin(), model.t0_c.end());
    hi = *std::max_element(model.t0_c.begin(), model.t0_c.end());
  }
  out += fmt::format(
      " * Model {} ({} form) from {} runs, start temperatures T0 {} ... {} degC\n"
      " * (T0 = mean shell temperature over the first {} s of a run).\n"
      " * Each coefficient a(T0) = A[0] + A[1] T0 + A[2] T0^2 + A[3] T0^3, T0 in degC.\n *\n",
      to_string(model.spec), to_string(model.form), model.t0_c.size(), num(lo), num(hi),
      num(model.t0_window_s));
  out += variables_c(model.derivative_window_s, model.l0_window_s, model.form) + " */\n";
  out += fmt::format("#ifndef {0}\n#define {0}\n\n", guard);
  out += fmt::format("#define {}_N_COEFFICIENTS {}\n", up, names.size());
  for (std::size_t i = 0; i < names.size(); ++i) {
    out += fmt::format("#define {}_{} {}\n", up, upper(names[i]), i);
  }
  out += "\n";
  for (const std::string& name : names) {
    const auto c = model.cubic.find(name);
    const std::array<double, 4> a = c == model.cubic.end() ? std::array<double, 4>{} : c->second;
    out += fmt::format("static const double {}_{}_A[4] = {{{}, {}, {}, {}}};\n", p, name, num(a[0]),
                       num(a[1]), num(a[2]), num(a[3]));
  }
  out += fmt::format("static const double {}_t0_min_c = {};\n", p, num(lo));
  out += fmt::format("static const double {}_t0_max_c = {};\n", p, num(hi));
  out += fmt::format("static const double {}_t0_window_s = {};\n", p, num(model.t0_window_s));
  out += fmt::format("static const double {}_derivative_window_s = {};\n", p,
                     num(model.derivative_window_s));
  if (model.form == DriftModelForm::kPaper) {
    out += fmt::format("static const double {}_l0_window_s = {};\n", p, num(model.l0_window_s));
  }
  out += fmt::format(
      "\n/* The coefficients a(T0) of a run started at t0_c (degC), indexed by {0}_<TERM>. */\n"
      "static inline void {1}_coefficients(double t0_c, double out[{0}_N_COEFFICIENTS]) {{\n",
      up, p);
  for (const std::string& name : names) {
    const std::string a = p + "_" + name + "_A";
    out += fmt::format(
        "  out[{0}_{1}] = {2}[0] + t0_c * ({2}[1] + t0_c * ({2}[2] + t0_c * {2}[3]));\n", up,
        upper(name), a);
  }
  out += "}\n\n";
  out += fmt::format(
      "/* Temperature-induced drift, deg/h, of a run started at t0_c (degC), from T (degC),\n"
      " * dT/dt (degC/s) and dT (degC). */\n"
      "static inline double {}_terms(double t0_c, double t_c, double dtdt_c_per_s, double dt_c) "
      "{{\n"
      "  double a[{}_N_COEFFICIENTS];\n"
      "  {}_coefficients(t0_c, a);\n",
      p, up, p);
  out += c_terms_body(model.spec, [&up](const std::string& name) {
    return fmt::format("a[{}_{}]", up, upper(name));
  });
  out += fmt::format("}}\n\n#endif /* {} */\n", guard);
  return out;
}

}  // namespace gyrotherm::analysis
