#include "gyrotherm/analysis/noise_model.h"

#include <fmt/format.h>

#include <Eigen/Dense>
#include <boost/math/distributions/normal.hpp>
#include <boost/math/distributions/students_t.hpp>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>
#include <vector>

namespace gyrotherm::analysis {

namespace {

constexpr double kZ95 = 1.959963984540054;  // the normal distribution's 97.5 % point
constexpr int kReweightRounds = 8;
// q_b = kFlicker * B²: the flicker floor of the Allan variance, (2 ln 2 / pi) B².
const double kFlicker = 2.0 * std::numbers::ln2 / std::numbers::pi;

// Each term's unit from its q: N = sqrt(q_n / 3600), B = sqrt(q_b / kFlicker),
// K = sqrt(3 * 3600 q_k).
double term_of(int i, double q) {
  const double scale = i == 0 ? 1.0 / 3600.0 : i == 1 ? 1.0 / kFlicker : 3.0 * 3600.0;
  return std::sqrt(std::max(q, 0.0) * scale);
}

struct SubsetFit {
  std::array<bool, 3> active{};
  Eigen::Vector3d q = Eigen::Vector3d::Zero();
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  double chi2 = 0;
  bool ok = false;  // solved, every active q >= 0
};

// The weighted fit of the terms in `active`, reweighted kReweightRounds times.
SubsetFit fit_subset(const std::vector<double>& tau, const std::vector<double>& avar,
                     const std::vector<double>& edf, std::array<bool, 3> active) {
  SubsetFit f;
  f.active = active;
  std::vector<int> idx;
  for (int i = 0; i < 3; ++i) {
    if (active[static_cast<std::size_t>(i)]) idx.push_back(i);
  }
  const auto n = tau.size();
  const auto k = static_cast<Eigen::Index>(idx.size());
  std::vector<double> model = avar;  // the first round weighs by the measured values
  Eigen::MatrixXd normal(k, k);
  for (int round = 0; round < kReweightRounds; ++round) {
    normal.setZero();
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(k);
    for (std::size_t j = 0; j < n; ++j) {
      const double basis[3] = {1.0 / tau[j], 1.0, tau[j]};
      // A model value far below the measured one (a term driven negative in
      // an earlier round) would weigh the point without bound.
      const double m = std::max(model[j], 0.05 * avar[j]);
      const double w = edf[j] / (2.0 * m * m);
      for (Eigen::Index a = 0; a < k; ++a) {
        rhs(a) += w * basis[idx[static_cast<std::size_t>(a)]] * avar[j];
        for (Eigen::Index b = 0; b < k; ++b) {
          normal(a, b) +=
              w * basis[idx[static_cast<std::size_t>(a)]] * basis[idx[static_cast<std::size_t>(b)]];
        }
      }
    }
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(normal);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return f;
    const Eigen::VectorXd sol = ldlt.solve(rhs);
    f.q.setZero();
    for (Eigen::Index a = 0; a < k; ++a) f.q(idx[static_cast<std::size_t>(a)]) = sol(a);
    for (std::size_t j = 0; j < n; ++j) model[j] = f.q(0) / tau[j] + f.q(1) + f.q(2) * tau[j];
  }
  // Chi² and covariance at the last weights.
  f.chi2 = 0;
  normal.setZero();
  for (std::size_t j = 0; j < n; ++j) {
    const double basis[3] = {1.0 / tau[j], 1.0, tau[j]};
    const double m = std::max(model[j], 0.05 * avar[j]);
    const double w = edf[j] / (2.0 * m * m);
    f.chi2 += w * (avar[j] - model[j]) * (avar[j] - model[j]);
    for (Eigen::Index a = 0; a < k; ++a) {
      for (Eigen::Index b = 0; b < k; ++b) {
        normal(a, b) +=
            w * basis[idx[static_cast<std::size_t>(a)]] * basis[idx[static_cast<std::size_t>(b)]];
      }
    }
  }
  const Eigen::MatrixXd inv = normal.inverse();
  if (!inv.allFinite()) return f;
  for (Eigen::Index a = 0; a < k; ++a) {
    for (Eigen::Index b = 0; b < k; ++b) {
      f.cov(idx[static_cast<std::size_t>(a)], idx[static_cast<std::size_t>(b)]) = inv(a, b);
    }
  }
  f.ok = true;
  for (int i : idx) f.ok = f.ok && f.q(i) >= 0;
  return f;
}

NoiseModelTerm term_interval(int i, double q, double u, bool fitted) {
  NoiseModelTerm t;
  t.fitted = fitted;
  if (fitted) {
    t.value = term_of(i, q);
    t.lo = term_of(i, q - kZ95 * u);
    t.hi = term_of(i, q + kZ95 * u);
  } else {
    t.hi = term_of(i, std::max(q, 0.0) + kZ95 * u);
  }
  return t;
}

}  // namespace

double NoiseModel::adev_dph(double tau_s) const {
  return std::sqrt(std::max(q[0] / tau_s + q[1] + q[2] * tau_s, 0.0));
}

Result<NoiseModel> fit_noise_model(std::span<const double> tau_s, std::span<const double> adev_dph,
                                   std::span<const double> edf) {
  if (tau_s.size() != adev_dph.size() || tau_s.size() != edf.size()) {
    return Error::Permanent(
        fmt::format("fit_noise_model: {} taus, {} deviations and {} edf: one of each per tau",
                    tau_s.size(), adev_dph.size(), edf.size()));
  }
  if (tau_s.size() < 3) {
    return Error::Permanent(
        fmt::format("fit_noise_model: {} Allan point(s); the model's three terms need at least 3",
                    tau_s.size()));
  }
  std::vector<double> tau(tau_s.begin(), tau_s.end());
  std::vector<double> avar;
  std::vector<double> dof(edf.begin(), edf.end());
  for (std::size_t j = 0; j < tau.size(); ++j) {
    const auto bad = [](double v) { return !std::isfinite(v) || v <= 0; };
    if (bad(tau[j]) || bad(adev_dph[j]) || bad(dof[j])) {
      return Error::Permanent(fmt::format(
          "fit_noise_model: point {} has tau {} s, deviation {} °/h, edf {}: each must be finite "
          "and > 0 (a constant series has no noise to model)",
          j, tau[j], adev_dph[j], dof[j]));
    }
    avar.push_back(adev_dph[j] * adev_dph[j]);
  }

  std::optional<SubsetFit> best;
  double best_score = std::numeric_limits<double>::infinity();
  for (int mask = 1; mask < 8; ++mask) {
    const std::array<bool, 3> active = {(mask & 1) != 0, (mask & 2) != 0, (mask & 4) != 0};
    const int terms = (mask & 1) + ((mask >> 1) & 1) + ((mask >> 2) & 1);
    if (static_cast<std::size_t>(terms) > tau.size()) continue;
    SubsetFit f = fit_subset(tau, avar, dof, active);
    if (!f.ok) continue;
    const double score = f.chi2 + kTermPenalty * terms;
    if (score < best_score) {
      best_score = score;
      best = f;
    }
  }
  if (!best) {
    return Error::Permanent("fit_noise_model: no combination of the three terms fits the curve");
  }

  NoiseModel model;
  model.n_taus = tau.size();
  model.chi2 = best->chi2;
  for (int a = 0; a < 3; ++a) {
    model.q[static_cast<std::size_t>(a)] = best->q(a);
    for (int b = 0; b < 3; ++b) {
      model.cov[static_cast<std::size_t>(a)][static_cast<std::size_t>(b)] = best->cov(a, b);
    }
  }
  NoiseModelTerm* terms[3] = {&model.angle_random_walk_dprh, &model.bias_instability_dph,
                              &model.rate_random_walk_dphprh};
  for (int i = 0; i < 3; ++i) {
    if (best->active[static_cast<std::size_t>(i)]) {
      *terms[i] = term_interval(i, best->q(i), std::sqrt(std::max(best->cov(i, i), 0.0)), true);
      continue;
    }
    // Left out: its upper limit from the fit with it added (unconstrained).
    auto with = best->active;
    with[static_cast<std::size_t>(i)] = true;
    const SubsetFit extended = fit_subset(tau, avar, dof, with);
    const double u = std::sqrt(std::max(extended.cov(i, i), 0.0));
    *terms[i] = term_interval(i, extended.q(i), std::isfinite(u) ? u : 0.0, false);
  }
  return model;
}

namespace {

// The Student t quantile for `dof` at two-sided `coverage`; the normal one
// for very large or infinite dof.
double coverage_factor(double dof, double coverage) {
  const double p = 0.5 + 0.5 * coverage;
  if (std::isfinite(dof) && dof < 1e7) {
    return boost::math::quantile(boost::math::students_t_distribution<double>(std::max(dof, 1.0)),
                                 p);
  }
  return boost::math::quantile(boost::math::normal_distribution<double>(), p);
}

}  // namespace

Result<MeanUncertainty> mean_uncertainty(const NoiseModel& model, double window_s,
                                         double coverage) {
  if (!std::isfinite(window_s) || window_s <= 0) {
    return Error::Permanent(
        fmt::format("mean_uncertainty: window {} s: must be finite and > 0", window_s));
  }
  if (!(coverage > 0 && coverage < 1)) {
    return Error::Permanent(
        fmt::format("mean_uncertainty: coverage {}: must be between 0 and 1", coverage));
  }
  MeanUncertainty r;
  r.window_s = window_s;
  r.coverage = coverage;
  const double g[3] = {1.0 / window_s, 1.0, window_s};
  double u2 = 0;
  double var_u2 = 0;
  for (std::size_t a = 0; a < 3; ++a) {
    u2 += g[a] * model.q[a];
    for (std::size_t b = 0; b < 3; ++b) var_u2 += g[a] * model.cov[a][b] * g[b];
  }
  u2 = std::max(u2, 0.0);
  r.u_dph = std::sqrt(u2);
  r.floor_dph = std::sqrt(std::max(model.q[1], 0.0));
  r.random_walk_dominated = u2 > 0 && model.q[2] * window_s > 0.5 * u2;
  r.dof = var_u2 > 0 ? 2.0 * u2 * u2 / var_u2 : std::numeric_limits<double>::infinity();
  r.k = coverage_factor(r.dof, coverage);
  r.expanded_dph = r.k * r.u_dph;
  return r;
}

Result<MeanUncertainty> average_uncertainty(std::span<const MeanUncertainty> windows,
                                            double coverage) {
  if (windows.empty()) return Error::Permanent("average_uncertainty: no window");
  if (!(coverage > 0 && coverage < 1)) {
    return Error::Permanent(
        fmt::format("average_uncertainty: coverage {}: must be between 0 and 1", coverage));
  }
  const auto n = static_cast<double>(windows.size());
  MeanUncertainty r;
  r.coverage = coverage;
  double u2 = 0, floor2 = 0, dof_denominator = 0;
  for (std::size_t i = 0; i < windows.size(); ++i) {
    const MeanUncertainty& w = windows[i];
    if (!std::isfinite(w.u_dph) || w.u_dph < 0) {
      return Error::Permanent(fmt::format(
          "average_uncertainty: window {}: u {} °/h: must be finite and >= 0", i, w.u_dph));
    }
    const double share = w.u_dph / n;  // this window's part of the average's u
    u2 += share * share;
    floor2 += (w.floor_dph / n) * (w.floor_dph / n);
    if (w.dof > 0 && std::isfinite(w.dof)) dof_denominator += share * share * share * share / w.dof;
    r.window_s += w.window_s;
    r.random_walk_dominated = r.random_walk_dominated || w.random_walk_dominated;
  }
  r.u_dph = std::sqrt(u2);
  r.floor_dph = std::sqrt(floor2);
  r.dof = dof_denominator > 0 ? u2 * u2 / dof_denominator : std::numeric_limits<double>::infinity();
  r.k = coverage_factor(r.dof, coverage);
  r.expanded_dph = r.k * r.u_dph;
  return r;
}

}  // namespace gyrotherm::analysis
