#include "gyrotherm/analysis/settle_prediction.h"

#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <optional>
#include <random>
#include <vector>

namespace gyrotherm::analysis {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

struct Bin {
  double t_s = 0;  // centre
  double c = 0;    // mean
  bool filled = false;
};

// The sequencer's gate over points (t, y) in a sliding window: running sums
// of the least-squares slope and the mean.
class GateWindow {
 public:
  explicit GateWindow(const SettleGate& gate) : gate_(gate) {}

  void add(double t, double y) {
    points_.push_back({t, y});
    sum_t_ += t;
    sum_y_ += y;
    sum_tt_ += t * t;
    sum_ty_ += t * y;
    while (!points_.empty() && points_.front().first <= t - gate_.window_s) {
      const auto [t0, y0] = points_.front();
      sum_t_ -= t0;
      sum_y_ -= y0;
      sum_tt_ -= t0 * t0;
      sum_ty_ -= t0 * y0;
      points_.pop_front();
    }
  }

  // The window is full (spans window_s less one step) and the gate holds.
  bool holds(double step_s) const {
    if (points_.size() < 3) return false;
    if (points_.back().first - points_.front().first < gate_.window_s - 1.5 * step_s) return false;
    const double n = static_cast<double>(points_.size());
    const double mean_t = sum_t_ / n;
    const double mean_y = sum_y_ / n;
    const double stt = sum_tt_ - n * mean_t * mean_t;
    if (!(stt > 0)) return false;
    const double slope_c_per_s = (sum_ty_ - n * mean_t * mean_y) / stt;
    return std::fabs(slope_c_per_s * 60.0) < gate_.stability_c_per_min &&
           std::fabs(mean_y - gate_.setpoint_c) <= gate_.tolerance_c;
  }

 private:
  const SettleGate& gate_;
  std::deque<std::pair<double, double>> points_;
  double sum_t_ = 0, sum_y_ = 0, sum_tt_ = 0, sum_ty_ = 0;
};

struct ExpFit {
  Eigen::Vector3d theta;  // (T_inf, A, k): T(t) = T_inf + A exp(-k (t - t_0))
  Eigen::Matrix3d cov;
};

// Starting values from the linear recursion T[k+1] = a T[k] + c over
// neighbouring bins (a = exp(-k h), T_inf = c / (1 - a)); nullopt when the
// series shows no decay.
std::optional<Eigen::Vector3d> recursion_start(const std::vector<double>& t,
                                               const std::vector<double>& c, double h) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0, n = 0;
  for (std::size_t i = 0; i + 1 < t.size(); ++i) {
    if (std::fabs(t[i + 1] - t[i] - h) > 1e-6 * h) continue;
    sx += c[i];
    sy += c[i + 1];
    sxx += c[i] * c[i];
    sxy += c[i] * c[i + 1];
    ++n;
  }
  const double d = n * sxx - sx * sx;
  if (n < 3 || !(d > 0)) return std::nullopt;
  const double a = (n * sxy - sx * sy) / d;
  const double b = (sy - a * sx) / n;
  if (!(a > 0 && a < 1)) return std::nullopt;
  const double t_inf = b / (1 - a);
  return Eigen::Vector3d(t_inf, c.front() - t_inf, -std::log(a) / h);
}

// Gauss-Newton (with step halving) on T(t) = T_inf + A exp(-k (t - t_0)),
// t_0 the first bin; the covariance s² (J'J)^-1 at the solution.
std::optional<ExpFit> fit_exponential(const std::vector<double>& t, const std::vector<double>& c,
                                      double h) {
  auto start = recursion_start(t, c, h);
  if (!start) return std::nullopt;
  Eigen::Vector3d th = *start;
  const auto n = static_cast<Eigen::Index>(t.size());
  const auto residuals = [&](const Eigen::Vector3d& p, Eigen::VectorXd& r, Eigen::MatrixXd* j) {
    r.resize(n);
    if (j) j->resize(n, 3);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double dt = t[static_cast<std::size_t>(i)] - t.front();
      const double e = std::exp(-p(2) * dt);
      r(i) = c[static_cast<std::size_t>(i)] - (p(0) + p(1) * e);
      if (j) {
        (*j)(i, 0) = 1;
        (*j)(i, 1) = e;
        (*j)(i, 2) = -p(1) * dt * e;
      }
    }
    return r.squaredNorm();
  };
  Eigen::VectorXd r;
  Eigen::MatrixXd jac;
  double cost = residuals(th, r, &jac);
  for (int iter = 0; iter < 50; ++iter) {
    const Eigen::Vector3d step = (jac.transpose() * jac).ldlt().solve(jac.transpose() * r);
    if (!step.allFinite()) return std::nullopt;
    double scale = 1;
    bool improved = false;
    for (int half = 0; half < 20; ++half, scale /= 2) {
      const Eigen::Vector3d trial = th + scale * step;
      if (!(trial(2) > 0)) continue;
      Eigen::VectorXd rt;
      const double ct = residuals(trial, rt, nullptr);
      if (ct < cost) {
        th = trial;
        cost = ct;
        improved = true;
        break;
      }
    }
    residuals(th, r, &jac);
    if (!improved || scale * step.norm() < 1e-12 * (1 + th.norm())) break;
  }
  if (n <= 3) return std::nullopt;
  const double s2 = cost / static_cast<double>(n - 3);
  // Residuals that run together (a model that is not quite the plant's: the
  // air's lag not yet died out) carry fewer independent bins than n: the
  // covariance is widened by (1 + rho) / (1 - rho), rho their lag-1
  // autocorrelation (an AR(1) view of the misfit), never narrowed.
  double r01 = 0;
  for (Eigen::Index i = 0; i + 1 < n; ++i) r01 += r(i) * r(i + 1);
  const double rho = std::clamp(cost > 0 ? r01 / cost : 0.0, 0.0, 0.95);
  const Eigen::Matrix3d jtj = jac.transpose() * jac;
  const Eigen::Matrix3d cov = s2 * (1 + rho) / (1 - rho) * jtj.inverse();
  if (!cov.allFinite() || !(th(2) > 0)) return std::nullopt;
  return ExpFit{th, cov};
}

std::string fit_failure(const std::vector<double>& t, const std::vector<double>& c) {
  return fmt::format("no exponential decay to fit in {} bins ({:.3f} to {:.3f} °C)", t.size(),
                     c.front(), c.back());
}

// numpy's default percentile (linear between closest ranks) of sorted x.
double percentile(const std::vector<double>& sorted, double p) {
  const double pos = p * static_cast<double>(sorted.size() - 1);
  const auto lo = static_cast<std::size_t>(std::floor(pos));
  const auto hi = std::min(lo + 1, sorted.size() - 1);
  if (std::isinf(sorted[lo]) || std::isinf(sorted[hi])) return sorted[hi];
  return sorted[lo] + (pos - static_cast<double>(lo)) * (sorted[hi] - sorted[lo]);
}

// The draws' verdict, shared by both models: a final value outside the
// tolerance by more than twice its uncertainty (the decay seen over at least
// one time constant) says the gate will not hold (note set, false);
// otherwise P10/P50/P90 of the gate times (true; the caller writes the
// note).
bool settle_quantiles(SettlePrediction& p, std::vector<double> times, const SettleGate& gate,
                      bool decay_seen) {
  if (decay_seen && p.final_c && p.final_u_c &&
      std::fabs(*p.final_c - gate.setpoint_c) - gate.tolerance_c > 2 * *p.final_u_c) {
    p.verdict = SettleVerdict::kNeverWithinTolerance;
    p.note = fmt::format(
        "the shell settles at {:.2f} ± {:.2f} °C, outside {:g} ± {:g} °C: the gate will not hold",
        *p.final_c, *p.final_u_c, gate.setpoint_c, gate.tolerance_c);
    return false;
  }
  std::sort(times.begin(), times.end());
  p.verdict = SettleVerdict::kPredicted;
  const auto finite_or_none = [](double v) {
    return std::isfinite(v) ? std::optional<double>(v) : std::nullopt;
  };
  p.p10_s = finite_or_none(percentile(times, 0.10));
  p.p50_s = finite_or_none(percentile(times, 0.50));
  p.p90_s = finite_or_none(percentile(times, 0.90));
  return true;
}

// Least-squares slope of y over the points of `v` (x = index).
double index_slope(const std::vector<double>& v) {
  const double n = static_cast<double>(v.size());
  if (n < 3) return 0;
  const double mx = (n - 1) / 2;
  double my = 0;
  for (double y : v) my += y;
  my /= n;
  double sxx = 0, sxy = 0;
  for (std::size_t i = 0; i < v.size(); ++i) {
    const double dx = static_cast<double>(i) - mx;
    sxx += dx * dx;
    sxy += dx * (v[i] - my);
  }
  return sxy / sxx;
}

// Lag-1 autocorrelation of residuals, clamped to [0, 0.95].
double lag1(const std::vector<double>& r) {
  double r0 = 0, r1 = 0;
  for (std::size_t i = 0; i < r.size(); ++i) {
    r0 += r[i] * r[i];
    if (i + 1 < r.size()) r1 += r[i] * r[i + 1];
  }
  return std::clamp(r0 > 0 ? r1 / r0 : 0.0, 0.0, 0.95);
}

// The shell driven by the measured air (see predict_settle in the header).
Result<SettlePrediction> predict_driven(const std::vector<Bin>& bins,
                                        const std::vector<double>& air, const SettleGate& gate,
                                        const SettleOptions& options) {
  SettlePrediction p;
  const double h = options.bin_s;
  // Rows k -> k+1 of neighbouring filled bins.
  std::vector<std::size_t> rows;
  for (std::size_t k = 0; k + 1 < bins.size(); ++k) {
    if (bins[k].filled && bins[k + 1].filled) rows.push_back(k);
  }
  p.fitted_bins = static_cast<int>(rows.size());
  if (static_cast<int>(rows.size()) < options.min_bins) {
    p.note = fmt::format("not enough curvature yet: {} bins of {:g} s, {} needed", rows.size(), h,
                         options.min_bins);
    return p;
  }
  const auto n = static_cast<Eigen::Index>(rows.size());
  Eigen::MatrixXd x(n, 3);
  Eigen::VectorXd y(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const std::size_t k = rows[static_cast<std::size_t>(i)];
    x(i, 0) = bins[k].c;
    x(i, 1) = (air[k] + air[k + 1]) / 2;
    x(i, 2) = 1;
    y(i) = bins[k + 1].c;
  }
  // Centred columns keep the normal equations well conditioned (the shell
  // and air levels are large next to their changes).
  const double mean_s = x.col(0).mean(), mean_a = x.col(1).mean();
  Eigen::MatrixXd xc = x;
  xc.col(0).array() -= mean_s;
  xc.col(1).array() -= mean_a;
  const Eigen::Matrix3d xtx = xc.transpose() * xc;
  const Eigen::Vector3d beta_c = xtx.ldlt().solve(xc.transpose() * y);
  if (!beta_c.allFinite()) {
    p.note = "not enough curvature yet: the shell has not moved against the air";
    return p;
  }
  const Eigen::VectorXd res = y - xc * beta_c;
  std::vector<double> shell_res(res.data(), res.data() + res.size());
  const double s2 = res.squaredNorm() / static_cast<double>(n - 3);
  const double rho = lag1(shell_res);
  Eigen::Matrix3d cov_c = s2 * (1 + rho) / (1 - rho) * xtx.inverse();
  // Back to (a, b, c): c = c' - a mean_s - b mean_a.
  Eigen::Matrix3d back = Eigen::Matrix3d::Identity();
  back(2, 0) = -mean_s;
  back(2, 1) = -mean_a;
  const Eigen::Vector3d theta = back * beta_c;
  const Eigen::Matrix3d cov = back * cov_c * back.transpose();
  if (!cov.allFinite()) {
    p.note = "not enough curvature yet: the fit has no covariance";
    return p;
  }
  const double a = theta(0), b = theta(1), c = theta(2);

  // The air ahead: its last stability window of bins.
  std::vector<double> air_tail;
  for (std::size_t k = 0; k < bins.size(); ++k) {
    if (bins[k].filled && bins[k].t_s > bins.back().t_s - gate.window_s) air_tail.push_back(air[k]);
  }
  double air_level = 0;
  for (double v : air_tail) air_level += v;
  air_level /= static_cast<double>(air_tail.size());
  const bool air_settled = std::fabs(index_slope(air_tail) / h * 60.0) < gate.stability_c_per_min;
  // Its relaxation to the set point when it has not settled: alpha per bin.
  double alpha = 0;
  if (!air_settled) {
    double sxx = 0, sxy = 0;
    for (std::size_t k : rows) {
      const double u = air[k] - gate.setpoint_c, v = air[k + 1] - gate.setpoint_c;
      sxx += u * u;
      sxy += u * v;
    }
    alpha = sxx > 0 ? std::clamp(sxy / sxx, 0.0, 0.999) : 0.0;
  }
  // Its fluctuations about its level over the tail: AR(1).
  std::vector<double> air_res;
  for (double v : air_tail) air_res.push_back(v - air_level);
  const double air_rho = lag1(air_res);
  double air_var = 0;
  for (double v : air_res) air_var += v * v;
  air_var /= std::max<std::size_t>(air_res.size() - 1, 1);
  const double air_level_u =
      std::sqrt(air_var / static_cast<double>(air_res.size()) * (1 + air_rho) / (1 - air_rho));
  const double innovation_sd = std::sqrt(air_var * (1 - air_rho * air_rho));

  const double steady = a < 1 ? (b * air_level + c) / (1 - a) : std::nan("");
  if (a > 0 && a < 1) {
    p.tau_s = -h / std::log(a);
    p.final_c = steady;
    // The final value's uncertainty by the delta method on (a, b, c).
    const Eigen::Vector3d g(steady / (1 - a), air_level / (1 - a), 1 / (1 - a));
    p.final_u_c = std::sqrt(std::max(0.0, g.dot(cov * g)) + std::pow(b / (1 - a) * air_level_u, 2));
  }

  const Eigen::LLT<Eigen::Matrix3d> llt(cov);
  const Eigen::Matrix3d l =
      llt.info() == Eigen::Success ? Eigen::Matrix3d(llt.matrixL()) : Eigen::Matrix3d::Zero();
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  const double shell_sd = std::sqrt(s2);
  std::vector<const Bin*> tail;
  for (const auto& bin : bins) {
    if (bin.filled && bin.t_s > bins.back().t_s - gate.window_s) tail.push_back(&bin);
  }
  const auto steps = static_cast<long>(std::ceil(options.horizon_s / h));
  int invalid = 0;
  std::vector<double> times;
  times.reserve(static_cast<std::size_t>(options.draws));
  const double last_air = air.back();
  for (int d = 0; d < options.draws; ++d) {
    const Eigen::Vector3d th = theta + l * Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
    if (!(th(0) > 0 && th(0) < 1)) {
      ++invalid;
      continue;
    }
    const double level = air_level + air_level_u * normal(rng);
    GateWindow w(gate);
    for (const Bin* bin : tail) w.add(bin->t_s, bin->c);
    double t = bins.back().t_s;
    double shell = bins.back().c;
    double deviation = air_settled ? last_air - air_level : last_air - gate.setpoint_c;
    double noise = 0;
    double air_prev = last_air;
    double when = kInf;
    for (long k = 0; k < steps; ++k) {
      t += h;
      noise = air_rho * noise + innovation_sd * normal(rng);
      double air_next;
      if (air_settled) {
        air_next = level + noise;
      } else {
        deviation *= alpha;
        air_next = gate.setpoint_c + deviation + noise;
      }
      shell = th(0) * shell + th(1) * (air_prev + air_next) / 2 + th(2);
      air_prev = air_next;
      w.add(t, shell + shell_sd * normal(rng));
      if (w.holds(h)) {
        when = t - h / 2;
        break;
      }
    }
    times.push_back(when);
  }
  if (invalid * 10 > options.draws) {
    p.note = fmt::format(
        "not enough curvature yet: the shell's lag behind the air is not resolved ({} of {} draws "
        "without a decay)",
        invalid, options.draws);
    return p;
  }
  const bool decay_seen = p.tau_s && bins.back().t_s - bins.front().t_s >= *p.tau_s;
  if (!settle_quantiles(p, std::move(times), gate, decay_seen)) return p;
  p.note = fmt::format(
      "shell driven by the chamber air, fitted over {} bins of {:g} s: tau {:.0f} s, final "
      "{:.3f} ± {:.3f} °C, air {}{}",
      rows.size(), h, p.tau_s.value_or(std::nan("")), p.final_c.value_or(std::nan("")),
      p.final_u_c.value_or(std::nan("")),
      air_settled ? fmt::format("settled at {:.2f} °C", air_level) : "still approaching",
      p.p90_s ? "" : "; P90 beyond the horizon (a final value outside the tolerance is likely)");
  return p;
}

}  // namespace

std::string_view to_string(SettleVerdict v) {
  switch (v) {
    case SettleVerdict::kPredicted:
      return "predicted";
    case SettleVerdict::kHoldsNow:
      return "holds_now";
    case SettleVerdict::kNotEnoughCurvature:
      return "not_enough_curvature";
    case SettleVerdict::kNeverWithinTolerance:
      return "never_within_tolerance";
  }
  return "unknown";
}

bool SettleOptions::is_valid(std::string* why) const {
  const auto fail = [&](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  if (!std::isfinite(bin_s) || bin_s <= 0) return fail(fmt::format("bin_s {}: must be > 0", bin_s));
  if (min_bins < 3) return fail(fmt::format("min_bins {}: must be at least 3", min_bins));
  if (draws < 10) return fail(fmt::format("draws {}: must be at least 10", draws));
  if (!std::isfinite(horizon_s) || horizon_s <= 0) {
    return fail(fmt::format("horizon_s {}: must be > 0", horizon_s));
  }
  return true;
}

Result<SettlePrediction> predict_settle(std::span<const double> t_s,
                                        std::span<const double> shell_c, const SettleGate& gate,
                                        const SettleOptions& options,
                                        std::span<const double> air_c) {
  if (std::string why; !options.is_valid(&why)) {
    return Error::Permanent("predict_settle: invalid options: " + why);
  }
  if (!std::isfinite(gate.setpoint_c) || !(gate.tolerance_c > 0) ||
      !(gate.stability_c_per_min > 0) || !(gate.window_s > 0)) {
    return Error::Permanent(fmt::format(
        "predict_settle: gate set point {} °C, tolerance {} °C, slope {} °C/min, window {} s: "
        "the last three must be > 0",
        gate.setpoint_c, gate.tolerance_c, gate.stability_c_per_min, gate.window_s));
  }
  if (t_s.size() != shell_c.size()) {
    return Error::Permanent(
        fmt::format("predict_settle: {} times and {} temperatures", t_s.size(), shell_c.size()));
  }
  if (!air_c.empty() && air_c.size() != t_s.size()) {
    return Error::Permanent(
        fmt::format("predict_settle: {} times and {} air temperatures", t_s.size(), air_c.size()));
  }
  for (std::size_t i = 0; i < air_c.size(); ++i) {
    if (!std::isfinite(air_c[i])) {
      return Error::Permanent(
          fmt::format("predict_settle: air sample {} is not finite ({} °C)", i, air_c[i]));
    }
  }
  for (std::size_t i = 0; i < t_s.size(); ++i) {
    if (!std::isfinite(t_s[i]) || !std::isfinite(shell_c[i])) {
      return Error::Permanent(fmt::format("predict_settle: sample {} is not finite ({} s, {} °C)",
                                          i, t_s[i], shell_c[i]));
    }
    if (i > 0 && !(t_s[i] > t_s[i - 1])) {
      return Error::Permanent(fmt::format(
          "predict_settle: time {} s at sample {} is not after {} s", t_s[i], i, t_s[i - 1]));
    }
  }
  SettlePrediction p;
  if (t_s.empty()) {
    p.note = "no shell temperature yet";
    return p;
  }

  // Does the gate hold on the data already?
  {
    GateWindow w(gate);
    for (std::size_t i = 0; i < t_s.size(); ++i) w.add(t_s[i], shell_c[i]);
    const double step =
        t_s.size() > 1 ? (t_s.back() - t_s.front()) / static_cast<double>(t_s.size() - 1) : 0.0;
    if (w.holds(step)) {
      p.verdict = SettleVerdict::kHoldsNow;
      p.p10_s = p.p50_s = p.p90_s = t_s.back();
      p.note = "the gate holds on the last window of data";
      return p;
    }
  }

  // Bins of h.
  const double h = options.bin_s;
  const auto n_bins = static_cast<std::size_t>(std::floor((t_s.back() - t_s.front()) / h)) + 1;
  std::vector<Bin> bins(n_bins);
  std::vector<double> air_bins(air_c.empty() ? 0 : n_bins, 0.0);
  std::vector<int> counts(n_bins, 0);
  for (std::size_t i = 0; i < t_s.size(); ++i) {
    const auto k = std::min(static_cast<std::size_t>((t_s[i] - t_s.front()) / h), n_bins - 1);
    bins[k].c += shell_c[i];
    if (!air_c.empty()) air_bins[k] += air_c[i];
    ++counts[k];
  }
  for (std::size_t k = 0; k < n_bins; ++k) {
    bins[k].t_s = t_s.front() + (static_cast<double>(k) + 0.5) * h;
    bins[k].filled = counts[k] > 0;
    if (bins[k].filled) {
      bins[k].c /= counts[k];
      if (!air_c.empty()) air_bins[k] /= counts[k];
    }
  }
  if (!air_c.empty()) return predict_driven(bins, air_bins, gate, options);
  // The steepest point: the largest |difference| of neighbouring bins,
  // averaged over three differences against the noise.
  std::size_t steepest = 0;
  double steepest_diff = -1;
  for (std::size_t k = 0; k + 3 < n_bins; ++k) {
    if (!bins[k].filled || !bins[k + 3].filled) continue;
    const double d = std::fabs(bins[k + 3].c - bins[k].c);
    if (d > steepest_diff) {
      steepest_diff = d;
      steepest = k + 1;
    }
  }
  // Pairs (T[k], T[k+1]) of filled bins over the later half of the series
  // past the steepest point (at least min_bins of them when there are): the
  // air's faster lag has died out most there, and the shell's own time
  // constant is what remains.
  std::size_t first = steepest;
  if (n_bins > steepest + 1) {
    const std::size_t span = n_bins - 1 - steepest;
    const auto min_pairs = static_cast<std::size_t>(options.min_bins);
    if (span / 3 >= min_pairs)
      first = steepest + span * 2 / 3;
    else if (span > min_pairs)
      first = n_bins - 1 - min_pairs;
  }
  // The bins fitted: filled ones from `first` on.
  std::vector<double> bt, bc;
  for (std::size_t k = first; k < n_bins; ++k) {
    if (bins[k].filled) {
      bt.push_back(bins[k].t_s);
      bc.push_back(bins[k].c);
    }
  }
  p.fitted_bins = static_cast<int>(bt.size());
  if (static_cast<int>(bt.size()) < options.min_bins) {
    p.note = fmt::format(
        "not enough curvature yet: {} bins of {:g} s past the steepest point, {} needed", bt.size(),
        h, options.min_bins);
    return p;
  }
  auto fit = fit_exponential(bt, bc, h);
  if (!fit) {
    p.note = "not enough curvature yet: " + fit_failure(bt, bc);
    return p;
  }
  const Eigen::Vector3d theta = fit->theta;  // (T_inf, A, k)
  const Eigen::Matrix3d cov = fit->cov;
  const double t_ref = bt.front();
  p.tau_s = 1.0 / theta(2);
  p.final_c = theta(0);
  p.final_u_c = std::sqrt(std::max(cov(0, 0), 0.0));

  // Draws of theta from the fit's normal distribution.
  const Eigen::LLT<Eigen::Matrix3d> llt(cov);
  const Eigen::Matrix3d l =
      llt.info() == Eigen::Success ? Eigen::Matrix3d(llt.matrixL()) : Eigen::Matrix3d::Zero();
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  int invalid = 0;
  std::vector<double> times;
  times.reserve(static_cast<std::size_t>(options.draws));
  // The last data bins seed every draw's window.
  std::vector<const Bin*> tail;
  for (const auto& b : bins) {
    if (b.filled && b.t_s > bins.back().t_s - gate.window_s) tail.push_back(&b);
  }
  const auto steps = static_cast<long>(std::ceil(options.horizon_s / h));
  for (int d = 0; d < options.draws; ++d) {
    const Eigen::Vector3d z(normal(rng), normal(rng), normal(rng));
    const Eigen::Vector3d th = theta + l * z;
    if (!(th(2) > 0)) {
      ++invalid;
      continue;
    }
    GateWindow w(gate);
    for (const Bin* b : tail) w.add(b->t_s, b->c);
    double t = bins.back().t_s;
    double when = kInf;
    for (long s = 0; s < steps; ++s) {
      t += h;
      w.add(t, th(0) + th(1) * std::exp(-th(2) * (t - t_ref)));
      if (w.holds(h)) {
        // The gate first holds somewhere in the last step: its middle.
        when = t - h / 2;
        break;
      }
    }
    times.push_back(when);
  }
  if (invalid * 10 > options.draws) {
    p.note = fmt::format(
        "not enough curvature yet: the decay is not resolved (tau {:.0f} s, {} of {} draws "
        "without a decay)",
        *p.tau_s, invalid, options.draws);
    return p;
  }
  // Outside the tolerance by more than twice its uncertainty, with the decay
  // seen over at least one time constant (earlier, a first-order fit of a
  // shell still following the air's lag can land far off): the gate will
  // not hold. Otherwise the draws say how likely it is.
  const bool decay_seen = bt.back() - bt.front() >= *p.tau_s;
  if (!settle_quantiles(p, std::move(times), gate, decay_seen)) return p;
  p.note = fmt::format(
      "first-order fit over {} bins of {:g} s: tau {:.0f} s, final {:.3f} ± {:.3f} °C{}", bt.size(),
      h, *p.tau_s, *p.final_c, *p.final_u_c,
      p.p90_s ? "" : "; P90 beyond the horizon (a final value outside the tolerance is likely)");
  return p;
}

}  // namespace gyrotherm::analysis
