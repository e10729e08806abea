// Drift model (paper eq. 1): spec parsing, smoothing derivative, and the
// block-sequential QR least-squares fit; see drift_model.h.
#include "gyrotherm/analysis/drift_model.h"

#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace gyrotherm::analysis {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr int kMaxOrder = 4;
constexpr double kWindowTol = 1e-9;  // relative to the derivative half width
// A variable is "constant" when its std is below this times its size.
constexpr double kConstantTol = 1e-10;

std::string_view trim(std::string_view s) {
  while (!s.empty() && s.front() == ' ') s.remove_prefix(1);
  while (!s.empty() && s.back() == ' ') s.remove_suffix(1);
  return s;
}

// Least-squares slope at each point over a window of points around it, in
// O(1) amortised per point. Sums are kept relative to an anchor point near the
// window; the anchor moves (and the sums are recomputed) once the window has
// advanced by its own length, so the sums never hold large offsets.
template <class YAt>
class SlidingSlope {
 public:
  SlidingSlope(std::span<const double> t_s, YAt y_at, double window_s)
      : t_(t_s), y_at_(y_at), half_(window_s / 2), tol_(kWindowTol * window_s / 2) {}

  // Slope at point i; i must go 0, 1, 2, ... in order.
  double next(std::size_t i) {
    const std::size_t n = t_.size();
    if (n < 2) return kNaN;
    std::size_t lo = lo_, hi = hi_;
    while (t_[lo] < t_[i] - half_ - tol_) ++lo;
    if (hi < i) hi = i;
    while (hi + 1 < n && t_[hi + 1] <= t_[i] + half_ + tol_) ++hi;
    if (i > 0) lo = std::min(lo, i - 1);
    if (i + 1 < n) hi = std::max(hi, i + 1);
    if (!started_ || i - anchor_ > hi_ - lo_ + 1) {
      anchor_ = i;
      t_ref_ = t_[i];
      y_ref_ = y_at_(i);
      s_t_ = s_y_ = s_tt_ = s_ty_ = 0;
      for (std::size_t j = lo; j <= hi; ++j) add(j, +1);
      started_ = true;
    } else {
      for (std::size_t j = hi_ + 1; j <= hi; ++j) add(j, +1);
      for (std::size_t j = lo_; j < lo; ++j) add(j, -1);
    }
    lo_ = lo;
    hi_ = hi;
    const long double m = static_cast<long double>(hi - lo + 1);
    const long double sxx = s_tt_ - s_t_ * s_t_ / m;
    const long double sxy = s_ty_ - s_t_ * s_y_ / m;
    return static_cast<double>(sxy / sxx);
  }

 private:
  void add(std::size_t j, int sign) {
    const long double dt = static_cast<long double>(t_[j]) - t_ref_;
    const long double dy = static_cast<long double>(y_at_(j)) - y_ref_;
    s_t_ += sign * dt;
    s_y_ += sign * dy;
    s_tt_ += sign * dt * dt;
    s_ty_ += sign * dt * dy;
  }

  std::span<const double> t_;
  YAt y_at_;
  double half_, tol_;
  bool started_ = false;
  std::size_t lo_ = 0, hi_ = 0, anchor_ = 0;
  long double t_ref_ = 0, y_ref_ = 0;
  long double s_t_ = 0, s_y_ = 0, s_tt_ = 0, s_ty_ = 0;
};

struct ShellTemp {
  const AnalysisSeries* s;
  double operator()(std::size_t i) const { return (s->top_c[i] + s->side_c[i]) / 2; }
};

// Welford running mean / sum of squared deviations, plus the largest |x|.
struct RunningStats {
  std::size_t n = 0;
  double mean = 0, m2 = 0, max_abs = 0;
  void add(double x) {
    ++n;
    const double d = x - mean;
    mean += d / static_cast<double>(n);
    m2 += d * (x - mean);
    max_abs = std::max(max_abs, std::abs(x));
  }
  double std_ddof0() const { return n > 0 ? std::sqrt(m2 / static_cast<double>(n)) : 0; }
};

Status check_series(const AnalysisSeries& s) {
  const std::size_t n = s.t_s.size();
  if (s.rate_dph.size() != n || s.top_c.size() != n || s.side_c.size() != n) {
    return Error::Permanent(fmt::format(
        "drift model: series vectors differ in length (t_s {}, rate_dph {}, top_c {}, side_c {})",
        n, s.rate_dph.size(), s.top_c.size(), s.side_c.size()));
  }
  const std::array<std::pair<const char*, const std::vector<double>*>, 4> vecs = {
      {{"t_s", &s.t_s}, {"rate_dph", &s.rate_dph}, {"top_c", &s.top_c}, {"side_c", &s.side_c}}};
  for (std::size_t i = 0; i < n; ++i) {
    for (const auto& [name, v] : vecs) {
      if (!std::isfinite((*v)[i])) {
        return Error::Permanent(
            fmt::format("drift model: {}[{}] is not finite ({})", name, i, (*v)[i]));
      }
    }
    if (i > 0 && !(s.t_s[i] > s.t_s[i - 1])) {
      return Error::Permanent(fmt::format("drift model: t_s[{}]={} does not increase (t_s[{}]={})",
                                          i, s.t_s[i], i - 1, s.t_s[i - 1]));
    }
  }
  return Status::Ok();
}

struct Column {
  char var;   // 'T', 'R', 'G', or 'C' for the intercept
  int power;  // 0 for the intercept
};

std::vector<Column> design_columns(const DriftModelSpec& spec, DriftModelForm form) {
  std::vector<Column> cols;
  if (form == DriftModelForm::kCentered) cols.push_back({'C', 0});
  for (int i = 1; i <= spec.t_order; ++i) cols.push_back({'T', i});
  for (int i = 1; i <= spec.r_order; ++i) cols.push_back({'R', i});
  for (int i = 1; i <= spec.g_order; ++i) cols.push_back({'G', i});
  return cols;
}

std::string column_name(const Column& c) {
  return c.var == 'C' ? std::string("intercept") : fmt::format("{}{}", c.var, c.power);
}

double ipow(double x, int k) {
  double r = 1;
  for (int i = 0; i < k; ++i) r *= x;
  return r;
}

double binomial(int n, int k) {
  double r = 1;
  for (int i = 1; i <= k; ++i) r = r * (n - k + i) / i;
  return r;
}

// Scaled variables of one point: z = (x - center) / scale.
struct Scaling {
  double t_center, t_scale, r_center, r_scale, g_center, g_scale;
};

void fill_row(const std::vector<Column>& cols, const Scaling& sc, double temp, double rate,
              double grad, double* row) {
  const double zt = (temp - sc.t_center) / sc.t_scale;
  const double zr = (rate - sc.r_center) / sc.r_scale;
  const double zg = (grad - sc.g_center) / sc.g_scale;
  for (std::size_t c = 0; c < cols.size(); ++c) {
    const double z = cols[c].var == 'T' ? zt : cols[c].var == 'R' ? zr : zg;
    row[c] = cols[c].var == 'C' ? 1.0 : ipow(z, cols[c].power);
  }
}

}  // namespace

Result<DriftModelSpec> parse_model_spec(std::string_view s) {
  if (trim(s).empty()) return Error::Permanent("model spec is empty (e.g. \"T4+R1+G1\")");
  DriftModelSpec spec;
  bool seen[3] = {false, false, false};
  std::string_view rest = s;
  while (true) {
    const std::size_t plus = rest.find('+');
    const std::string_view term = trim(rest.substr(0, plus));
    if (term.empty()) {
      return Error::Permanent(fmt::format("model spec \"{}\": empty term", s));
    }
    const char letter = term[0];
    int slot = letter == 'T' ? 0 : letter == 'R' ? 1 : letter == 'G' ? 2 : -1;
    if (slot < 0) {
      return Error::Permanent(fmt::format("{}: unknown term (T, R, G)", term));
    }
    if (term.size() != 2 || term[1] < '0' || term[1] > '9' || term[1] - '0' > kMaxOrder) {
      return Error::Permanent(fmt::format("{}: order must be 0..{}", term, kMaxOrder));
    }
    if (seen[slot]) {
      return Error::Permanent(fmt::format("{}: term {} given more than once", term, letter));
    }
    seen[slot] = true;
    const int order = term[1] - '0';
    (slot == 0 ? spec.t_order : slot == 1 ? spec.r_order : spec.g_order) = order;
    if (plus == std::string_view::npos) break;
    rest = rest.substr(plus + 1);
  }
  if (spec.parameters() == 0) {
    return Error::Permanent(fmt::format("model spec \"{}\" has no term of order >= 1", s));
  }
  return spec;
}

std::string to_string(const DriftModelSpec& spec) {
  std::string out;
  const auto add = [&out](char letter, int order) {
    if (order == 0) return;
    if (!out.empty()) out += '+';
    out += fmt::format("{}{}", letter, order);
  };
  add('T', spec.t_order);
  add('R', spec.r_order);
  add('G', spec.g_order);
  return out;
}

std::string_view to_string(DriftModelForm form) {
  return form == DriftModelForm::kPaper ? "paper" : "centered";
}

Result<DriftModelForm> parse_drift_model_form(std::string_view s) {
  if (s == "paper") return DriftModelForm::kPaper;
  if (s == "centered" || s == "centred") return DriftModelForm::kCentered;
  return Error::Permanent(fmt::format("drift model form \"{}\": expected paper or centered", s));
}

bool DriftFitOptions::IsValid(std::string* error) const {
  const auto fail = [error](std::string msg) {
    if (error) *error = std::move(msg);
    return false;
  };
  if (!(derivative_window_s > 0) || !std::isfinite(derivative_window_s)) {
    return fail(fmt::format("derivative_window_s must be positive ({})", derivative_window_s));
  }
  if (!(l0_window_s > 0) || !std::isfinite(l0_window_s)) {
    return fail(fmt::format("l0_window_s must be positive ({})", l0_window_s));
  }
  if (block_rows == 0) return fail("block_rows must be at least 1");
  if (!(rank_tolerance >= 0 && rank_tolerance < 1)) {
    return fail(fmt::format("rank_tolerance must be in [0, 1) ({})", rank_tolerance));
  }
  return true;
}

std::vector<double> smoothing_derivative(std::span<const double> t_s, std::span<const double> y,
                                         double window_s) {
  std::vector<double> out(t_s.size(), kNaN);
  if (t_s.size() != y.size() || t_s.size() < 2 || !(window_s > 0)) return out;
  const auto y_at = [y](std::size_t j) { return y[j]; };
  SlidingSlope<decltype(y_at)> slope(t_s, y_at, window_s);
  for (std::size_t i = 0; i < t_s.size(); ++i) out[i] = slope.next(i);
  return out;
}

Result<DriftFit> fit_drift_model(const AnalysisSeries& series, const DriftModelSpec& spec,
                                 DriftModelForm form, const DriftFitOptions& options) {
  return fit_drift_model(std::span<const AnalysisSeries>(&series, 1), spec, form, options);
}

Result<DriftFit> fit_drift_model(std::span<const AnalysisSeries> runs, const DriftModelSpec& spec,
                                 DriftModelForm form, const DriftFitOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) return Error::Permanent("drift model options: " + why);
  if (spec.t_order < 0 || spec.t_order > kMaxOrder || spec.r_order < 0 ||
      spec.r_order > kMaxOrder || spec.g_order < 0 || spec.g_order > kMaxOrder ||
      spec.parameters() == 0) {
    return Error::Permanent(
        fmt::format("drift model spec T{} R{} G{}: orders must be 0..{}, not all 0", spec.t_order,
                    spec.r_order, spec.g_order, kMaxOrder));
  }
  if (runs.empty()) return Error::Permanent("drift model: no series to fit");
  std::size_t n = 0;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    if (Status st = check_series(runs[r]); !st.ok()) {
      if (runs.size() == 1) return st.error();
      return Error::Permanent(fmt::format("series {}: {}", r + 1, st.error().message));
    }
    if (runs[r].t_s.size() < 2) {
      return Error::Permanent(fmt::format("drift model: series {} has {} point(s) (need 2)", r + 1,
                                          runs[r].t_s.size()));
    }
    n += runs[r].t_s.size();
  }

  const std::vector<Column> cols = design_columns(spec, form);
  const std::size_t p = cols.size();
  if (n <= p) {
    return Error::Permanent(fmt::format(
        "drift model {}: {} points for {} parameters (need more points than parameters)",
        to_string(spec), n, p));
  }

  // Pass 1: L0 of each series and the statistics of T, dT/dt and top - side.
  std::vector<double> l0(runs.size(), 0.0);
  RunningStats ts, rs, gs;
  double max_side_top = 0;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const AnalysisSeries& series = runs[r];
    if (form == DriftModelForm::kPaper) {
      long double sum = 0;
      std::size_t count = 0;
      for (std::size_t i = 0;
           i < series.t_s.size() && series.t_s[i] - series.t_s[0] < options.l0_window_s; ++i) {
        sum += series.rate_dph[i];
        ++count;
      }
      l0[r] = static_cast<double>(sum / static_cast<long double>(count));
    }
    const ShellTemp temp_at{&series};
    SlidingSlope<ShellTemp> slope(series.t_s, temp_at, options.derivative_window_s);
    for (std::size_t i = 0; i < series.t_s.size(); ++i) {
      ts.add(temp_at(i));
      rs.add(slope.next(i));
      gs.add(series.top_c[i] - series.side_c[i]);
      max_side_top =
          std::max({max_side_top, std::abs(series.top_c[i]), std::abs(series.side_c[i])});
    }
  }
  const auto constant = [&](char var, const RunningStats& st, double size) -> Status {
    if (st.std_ddof0() <= kConstantTol * size) {
      const char* what = var == 'T'   ? "the mean shell temperature"
                         : var == 'R' ? "dT/dt"
                                      : "the gradient top - side";
      return Error::Permanent(
          fmt::format("drift model {}: term {} cannot be fitted: {} is constant over the series "
                      "(mean {}, std {})",
                      to_string(spec), var, what, st.mean, st.std_ddof0()));
    }
    return Status::Ok();
  };
  if (spec.t_order > 0) {
    if (Status st = constant('T', ts, ts.max_abs); !st.ok()) return st.error();
  }
  if (spec.r_order > 0) {
    if (Status st = constant('R', rs, ts.max_abs / options.derivative_window_s); !st.ok()) {
      return st.error();
    }
  }
  if (spec.g_order > 0) {
    if (Status st = constant('G', gs, max_side_top); !st.ok()) return st.error();
  }
  Scaling sc{};
  if (form == DriftModelForm::kPaper) {
    sc = {0, ts.max_abs, 0, rs.max_abs, 0, gs.max_abs};
  } else {
    sc = {ts.mean, ts.std_ddof0(), rs.mean, rs.std_ddof0(), gs.mean, gs.std_ddof0()};
  }
  // Unused variables keep a harmless scale.
  if (!(sc.t_scale > 0)) sc.t_scale = 1;
  if (!(sc.r_scale > 0)) sc.r_scale = 1;
  if (!(sc.g_scale > 0)) sc.g_scale = 1;

  // Pass 2: R of [X | y] by Householder QR of [R; next block], block by block.
  const std::size_t q = p + 1;
  const std::size_t block = options.block_rows;
  Eigen::MatrixXd stack =
      Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(q + block), static_cast<Eigen::Index>(q));
  Eigen::HouseholderQR<Eigen::MatrixXd> qr(stack.rows(), stack.cols());
  Eigen::MatrixXd r_aug =
      Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(q), static_cast<Eigen::Index>(q));
  RunningStats ys;
  std::vector<double> row(p);
  std::size_t filled = 0;  // rows of the current block
  const auto flush_block = [&] {
    qr.compute(stack.topRows(static_cast<Eigen::Index>(q + filled)));
    r_aug = qr.matrixQR().topRows(static_cast<Eigen::Index>(q)).triangularView<Eigen::Upper>();
    stack.topRows(static_cast<Eigen::Index>(q)) = r_aug;
    filled = 0;
  };
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const AnalysisSeries& series = runs[r];
    const ShellTemp temp_at{&series};
    SlidingSlope<ShellTemp> slope(series.t_s, temp_at, options.derivative_window_s);
    for (std::size_t i = 0; i < series.t_s.size(); ++i) {
      const double y = series.rate_dph[i] - l0[r];
      ys.add(y);
      fill_row(cols, sc, temp_at(i), slope.next(i), series.top_c[i] - series.side_c[i], row.data());
      const auto k = static_cast<Eigen::Index>(q + filled);
      for (std::size_t c = 0; c < p; ++c) stack(k, static_cast<Eigen::Index>(c)) = row[c];
      stack(k, static_cast<Eigen::Index>(p)) = y;
      if (++filled == block) flush_block();
    }
  }
  if (filled > 0) flush_block();

  const auto ip = static_cast<Eigen::Index>(p);
  const Eigen::MatrixXd rx = r_aug.topLeftCorner(ip, ip);
  const Eigen::VectorXd qty = r_aug.topRightCorner(ip, 1);
  const double rss = r_aug(ip, ip) * r_aug(ip, ip);

  // Rank: |R_jj| / |column j| is the sine of the angle between column j and the
  // span of the columns before it.
  Eigen::VectorXd col_norm(ip);
  for (Eigen::Index j = 0; j < ip; ++j) col_norm(j) = rx.col(j).head(j + 1).norm();
  for (Eigen::Index j = 0; j < ip; ++j) {
    const double sine = col_norm(j) > 0 ? std::abs(rx(j, j)) / col_norm(j) : 0;
    if (!(sine > options.rank_tolerance)) {
      return Error::Permanent(fmt::format(
          "drift model {} ({} form): design is rank-deficient at term {}: it is (nearly) a "
          "combination of the terms before it (relative size {:.3g}, tolerance {:.3g})",
          to_string(spec), to_string(form), column_name(cols[static_cast<std::size_t>(j)]), sine,
          options.rank_tolerance));
    }
  }
  const Eigen::MatrixXd rn = rx * col_norm.cwiseInverse().asDiagonal();
  const Eigen::VectorXd sv = Eigen::JacobiSVD<Eigen::MatrixXd>(rn).singularValues();

  const auto upper = rx.triangularView<Eigen::Upper>();
  const Eigen::VectorXd beta = upper.solve(qty);
  const Eigen::MatrixXd rinv = upper.solve(Eigen::MatrixXd::Identity(ip, ip));
  const double dof = static_cast<double>(n - p);
  const double sigma2 = rss / dof;
  const Eigen::MatrixXd cov_beta = sigma2 * (rinv * rinv.transpose());

  // Physical coefficients a = M beta: expand sum_i b_i ((x - c) / s)^i.
  Eigen::MatrixXd m = Eigen::MatrixXd::Zero(ip, ip);
  for (std::size_t a = 0; a < p; ++a) {
    for (std::size_t b = 0; b < p; ++b) {
      const Column& ca = cols[a];
      const Column& cb = cols[b];
      if (cb.var == 'C') {
        if (ca.var == 'C') m(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)) = 1;
        continue;
      }
      const double c = cb.var == 'T' ? sc.t_center : cb.var == 'R' ? sc.r_center : sc.g_center;
      const double s = cb.var == 'T' ? sc.t_scale : cb.var == 'R' ? sc.r_scale : sc.g_scale;
      const int k = ca.var == 'C' ? 0 : ca.power;
      if ((ca.var != 'C' && ca.var != cb.var) || k > cb.power) continue;
      m(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)) =
          binomial(cb.power, k) * ipow(-c, cb.power - k) / ipow(s, cb.power);
    }
  }
  const Eigen::VectorXd phys = m * beta;
  const Eigen::MatrixXd cov_phys = m * cov_beta * m.transpose();

  DriftFit fit;
  fit.spec = spec;
  fit.form = form;
  fit.n = n;
  fit.parameters = p;
  fit.residual_std_dph = std::sqrt(sigma2);
  const double tss = ys.m2;
  fit.r_squared = tss > 0 ? 1 - rss / tss : 1.0;
  fit.l0_dph = l0.front();
  fit.l0_per_series_dph = l0;
  fit.condition_estimate = sv(0) / sv(ip - 1);
  fit.derivative_window_s = options.derivative_window_s;
  fit.t_center = sc.t_center;
  fit.t_scale = sc.t_scale;
  fit.r_center = sc.r_center;
  fit.r_scale = sc.r_scale;
  fit.g_center = sc.g_center;
  fit.g_scale = sc.g_scale;
  for (std::size_t c = 0; c < p; ++c) {
    const auto j = static_cast<Eigen::Index>(c);
    const std::string name = column_name(cols[c]);
    fit.column_names.push_back(name);
    fit.scaled_coefficients.push_back(beta(j));
    fit.coefficients[name] = phys(j);
    fit.std_errors[name] = std::sqrt(std::max(0.0, cov_phys(j, j)));
  }
  return fit;
}

Result<std::vector<double>> predict_drift(const DriftFit& fit, const AnalysisSeries& series) {
  if (Status st = check_series(series); !st.ok()) return st.error();
  const std::vector<Column> cols = design_columns(fit.spec, fit.form);
  if (cols.size() != fit.scaled_coefficients.size()) {
    return Error::Permanent("predict_drift: the fit's coefficients do not match its spec");
  }
  const Scaling sc{fit.t_center, fit.t_scale, fit.r_center, fit.r_scale, fit.g_center, fit.g_scale};
  const ShellTemp temp_at{&series};
  SlidingSlope<ShellTemp> slope(series.t_s, temp_at, fit.derivative_window_s);
  std::vector<double> out(series.t_s.size());
  std::vector<double> row(cols.size());
  for (std::size_t i = 0; i < out.size(); ++i) {
    fill_row(cols, sc, temp_at(i), slope.next(i), series.top_c[i] - series.side_c[i], row.data());
    double v = fit.l0_dph;
    for (std::size_t c = 0; c < cols.size(); ++c) v += fit.scaled_coefficients[c] * row[c];
    out[i] = v;
  }
  return out;
}

Result<std::vector<double>> drift_terms(const DriftFit& fit, const AnalysisSeries& series) {
  auto predicted = predict_drift(fit, series);
  if (!predicted) return predicted;
  // The model at T = 0, dT/dt = 0, dT = 0 in the fit's scaled variables.
  const std::vector<Column> cols = design_columns(fit.spec, fit.form);
  const Scaling sc{fit.t_center, fit.t_scale, fit.r_center, fit.r_scale, fit.g_center, fit.g_scale};
  std::vector<double> row(cols.size());
  fill_row(cols, sc, 0.0, 0.0, 0.0, row.data());
  double at_zero = fit.l0_dph;
  for (std::size_t c = 0; c < cols.size(); ++c) at_zero += fit.scaled_coefficients[c] * row[c];
  for (double& v : *predicted) v -= at_zero;
  return predicted;
}

}  // namespace gyrotherm::analysis
