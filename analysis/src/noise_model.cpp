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
// K = sqrt(3 * 3600 q_k), the Gauss-Markov sigma = sqrt(q_g).
double term_of(int i, double q) {
  const double scale = i == 0   ? 1.0 / 3600.0
                       : i == 1 ? 1.0 / kFlicker
                       : i == 2 ? 3.0 * 3600.0
                                : 1.0;
  return std::sqrt(std::max(q, 0.0) * scale);
}

// The Gauss-Markov term's shapes, x = tau / T_c (or T / T_c): its Allan
// variance over sigma² (IEEE Std 952, annex C),
//   a(x) = (2 / x) [1 - (3 - 4 e^-x + e^-2x) / (2 x)],
// and the variance of a window's mean over sigma² (the process stationary,
// the window of length T),
//   v(x) = (2 / x) [1 - (1 - e^-x) / x].
// Their series below x = 1e-2 (the closed forms cancel there).
double gm_allan(double x) {
  if (x < 1e-2) return 2.0 * x / 3.0 - x * x / 2.0 + 7.0 * x * x * x / 30.0;
  return 2.0 / x * (1.0 - (3.0 - 4.0 * std::exp(-x) + std::exp(-2.0 * x)) / (2.0 * x));
}
double gm_mean(double x) {
  if (x < 1e-3) return 1.0 - x / 3.0 + x * x / 12.0;
  return 2.0 / x * (1.0 + std::expm1(-x) / x);
}

// The basis of term i at tau for a Gauss-Markov correlation time tc_s.
double basis_of(int i, double tau, double tc_s) {
  switch (i) {
    case 0:
      return 1.0 / tau;
    case 1:
      return 1.0;
    case 2:
      return tau;
    default:
      return gm_allan(tau / tc_s);
  }
}

using Vector = Eigen::Matrix<double, kNoiseTerms, 1>;
using Matrix = Eigen::Matrix<double, kNoiseTerms, kNoiseTerms>;
using Active = std::array<bool, kNoiseTerms>;

struct SubsetFit {
  Active active{};
  double tc_s = 0;  // the Gauss-Markov term's correlation time (when active)
  Vector q = Vector::Zero();
  Matrix cov = Matrix::Zero();
  double chi2 = 0;
  // The deviance of the measured variances from the model's, each a
  // chi²(edf) / edf multiple of its expected value:
  //   sum edf [s²/m - 1 - ln(s²/m)].
  // Equal to chi2 to second order for a model near the points; unlike chi2
  // with the model's own weights, it charges a model that overshoots the
  // few-edf points at long tau (whose weights it would shrink).
  double deviance = 0;
  bool ok = false;  // solved, every active q >= 0
};

// The weighted fit of the terms in `active`, reweighted kReweightRounds times.
SubsetFit fit_subset(const std::vector<double>& tau, const std::vector<double>& avar,
                     const std::vector<double>& edf, Active active, double tc_s) {
  SubsetFit f;
  f.active = active;
  f.tc_s = tc_s;
  std::vector<int> idx;
  for (int i = 0; i < kNoiseTerms; ++i) {
    if (active[static_cast<std::size_t>(i)]) idx.push_back(i);
  }
  const auto n = tau.size();
  const auto k = static_cast<Eigen::Index>(idx.size());
  std::vector<std::array<double, kNoiseTerms>> basis(n);
  for (std::size_t j = 0; j < n; ++j) {
    for (int i = 0; i < kNoiseTerms; ++i) {
      basis[j][static_cast<std::size_t>(i)] =
          active[static_cast<std::size_t>(i)] ? basis_of(i, tau[j], tc_s) : 0.0;
    }
  }
  const auto at = [&](std::size_t j, Eigen::Index a) {
    return basis[j][static_cast<std::size_t>(idx[static_cast<std::size_t>(a)])];
  };
  std::vector<double> model = avar;  // the first round weighs by the measured values
  Eigen::MatrixXd normal(k, k);
  for (int round = 0; round < kReweightRounds; ++round) {
    normal.setZero();
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(k);
    for (std::size_t j = 0; j < n; ++j) {
      // A model value far below the measured one (a term driven negative in
      // an earlier round) would weigh the point without bound.
      const double m = std::max(model[j], 0.05 * avar[j]);
      const double w = edf[j] / (2.0 * m * m);
      for (Eigen::Index a = 0; a < k; ++a) {
        rhs(a) += w * at(j, a) * avar[j];
        for (Eigen::Index b = 0; b < k; ++b) normal(a, b) += w * at(j, a) * at(j, b);
      }
    }
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(normal);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return f;
    const Eigen::VectorXd sol = ldlt.solve(rhs);
    f.q.setZero();
    for (Eigen::Index a = 0; a < k; ++a) f.q(idx[static_cast<std::size_t>(a)]) = sol(a);
    for (std::size_t j = 0; j < n; ++j) {
      model[j] = 0;
      for (int i = 0; i < kNoiseTerms; ++i) {
        model[j] += f.q(i) * basis[j][static_cast<std::size_t>(i)];
      }
    }
  }
  // Chi² and covariance at the last weights.
  f.chi2 = 0;
  normal.setZero();
  for (std::size_t j = 0; j < n; ++j) {
    const double m = std::max(model[j], 0.05 * avar[j]);
    const double w = edf[j] / (2.0 * m * m);
    f.chi2 += w * (avar[j] - model[j]) * (avar[j] - model[j]);
    const double ratio = avar[j] / m;
    f.deviance += edf[j] * (ratio - 1.0 - std::log(ratio));
    for (Eigen::Index a = 0; a < k; ++a) {
      for (Eigen::Index b = 0; b < k; ++b) normal(a, b) += w * at(j, a) * at(j, b);
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

// The Gauss-Markov correlation times tried: kGmGrid values, log-spaced from
// twice the shortest tau to twice the longest. Shorter, the term is white
// noise on the curve; much longer, a rate random walk (which wins then: one
// parameter fewer).
constexpr int kGmGrid = 16;
std::vector<double> gm_grid(const std::vector<double>& tau) {
  const double lo = 2.0 * tau.front(), hi = 2.0 * tau.back();
  std::vector<double> grid;
  if (hi <= lo) return grid;
  for (int i = 0; i < kGmGrid; ++i) {
    grid.push_back(lo * std::pow(hi / lo, static_cast<double>(i) / (kGmGrid - 1)));
  }
  return grid;
}

// The fits of `active` (with every correlation time of `grid` when the
// Gauss-Markov term is in it), each passed to `take`.
template <typename Take>
void fit_each(const std::vector<double>& tau, const std::vector<double>& avar,
              const std::vector<double>& edf, Active active, const std::vector<double>& grid,
              Take&& take) {
  if (!active[kGaussMarkov]) {
    take(fit_subset(tau, avar, edf, active, 0.0));
    return;
  }
  for (double tc : grid) take(fit_subset(tau, avar, edf, active, tc));
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
  double avar = q[0] / tau_s + q[1] + q[2] * tau_s;
  if (gm_tc_s > 0) avar += q[kGaussMarkov] * gm_allan(tau_s / gm_tc_s);
  return std::sqrt(std::max(avar, 0.0));
}

Result<NoiseModel> fit_noise_model(std::span<const double> tau_s, std::span<const double> adev_dph,
                                   std::span<const double> edf, unsigned allowed) {
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
    if (j > 0 && tau[j] <= tau[j - 1]) {
      return Error::Permanent(fmt::format(
          "fit_noise_model: tau {} s at point {} does not follow {} s: taus must ascend", tau[j], j,
          tau[j - 1]));
    }
    avar.push_back(adev_dph[j] * adev_dph[j]);
  }
  const std::vector<double> grid = gm_grid(tau);

  // Parameters a subset costs: one per term, two for the Gauss-Markov term
  // (its variance and its correlation time).
  const auto parameters = [](const Active& active) {
    int p = 0;
    for (int i = 0; i < kNoiseTerms; ++i) {
      if (active[static_cast<std::size_t>(i)]) p += i == kGaussMarkov ? 2 : 1;
    }
    return p;
  };
  std::optional<SubsetFit> best;
  double best_score = std::numeric_limits<double>::infinity();
  for (int mask = 1; mask < (1 << kNoiseTerms); ++mask) {
    if ((static_cast<unsigned>(mask) & ~allowed) != 0) continue;
    Active active{};
    for (int i = 0; i < kNoiseTerms; ++i) active[static_cast<std::size_t>(i)] = (mask >> i) & 1;
    const int p = parameters(active);
    if (static_cast<std::size_t>(p) > tau.size()) continue;
    fit_each(tau, avar, dof, active, grid, [&](const SubsetFit& f) {
      if (!f.ok) return;
      const double score = f.deviance + kTermPenalty * p;
      if (score < best_score) {
        best_score = score;
        best = f;
      }
    });
  }
  if (!best) {
    return Error::Permanent("fit_noise_model: no combination of the terms fits the curve");
  }

  NoiseModel model;
  model.n_taus = tau.size();
  model.chi2 = best->chi2;
  model.deviance = best->deviance;
  model.gm_tc_s = best->active[kGaussMarkov] ? best->tc_s : 0.0;
  for (int a = 0; a < kNoiseTerms; ++a) {
    model.q[static_cast<std::size_t>(a)] = best->q(a);
    for (int b = 0; b < kNoiseTerms; ++b) {
      model.cov[static_cast<std::size_t>(a)][static_cast<std::size_t>(b)] = best->cov(a, b);
    }
  }
  if (best->active[kGaussMarkov]) {
    fit_each(tau, avar, dof, best->active, grid, [&](const SubsetFit& f) {
      if (!f.ok || f.tc_s == best->tc_s || f.deviance > best->deviance + kGmProfileDeviance) return;
      NoiseModel::Alternative alt;
      alt.gm_tc_s = f.tc_s;
      for (int a = 0; a < kNoiseTerms; ++a) {
        alt.q[static_cast<std::size_t>(a)] = f.q(a);
        for (int b = 0; b < kNoiseTerms; ++b) {
          alt.cov[static_cast<std::size_t>(a)][static_cast<std::size_t>(b)] = f.cov(a, b);
        }
      }
      model.gm_alternatives.push_back(alt);
    });
  }
  NoiseModelTerm* terms[kNoiseTerms] = {&model.angle_random_walk_dprh, &model.bias_instability_dph,
                                        &model.rate_random_walk_dphprh, &model.gauss_markov_dph};
  for (int i = 0; i < kNoiseTerms; ++i) {
    if (best->active[static_cast<std::size_t>(i)]) {
      *terms[i] = term_interval(i, best->q(i), std::sqrt(std::max(best->cov(i, i), 0.0)), true);
      continue;
    }
    // Left out: its upper limit from the fit with it added (unconstrained;
    // the Gauss-Markov term at the correlation time that fits best).
    auto with = best->active;
    with[static_cast<std::size_t>(i)] = true;
    std::optional<SubsetFit> extended;
    fit_each(tau, avar, dof, with, grid, [&](const SubsetFit& f) {
      if (!extended || f.chi2 < extended->chi2) extended = f;
    });
    const double u = extended ? std::sqrt(std::max(extended->cov(i, i), 0.0)) : 0.0;
    *terms[i] =
        term_interval(i, extended ? extended->q(i) : 0.0, std::isfinite(u) ? u : 0.0, false);
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
  // u² and its variance under coefficients q, covariance cov and T_c. The
  // Gauss-Markov term's share is the variance of its mean over the window
  // (not its Allan variance at T, which is smaller near T_c).
  const auto u2_of = [&](const auto& q, const auto& cov, double tc_s) {
    const double g[kNoiseTerms] = {1.0 / window_s, 1.0, window_s,
                                   tc_s > 0 ? gm_mean(window_s / tc_s) : 0.0};
    std::pair<double, double> r{0.0, 0.0};
    for (std::size_t a = 0; a < kNoiseTerms; ++a) {
      r.first += g[a] * q[a];
      for (std::size_t b = 0; b < kNoiseTerms; ++b) r.second += g[a] * cov[a][b] * g[b];
    }
    return r;
  };
  auto [u2, var_u2] = u2_of(model.q, model.cov, model.gm_tc_s);
  for (const NoiseModel::Alternative& alt : model.gm_alternatives) {
    const auto [alt_u2, alt_var] = u2_of(alt.q, alt.cov, alt.gm_tc_s);
    if (alt_u2 > u2) {
      u2 = alt_u2;
      var_u2 = alt_var;
    }
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
