#include "gyrotherm/analysis/acquisition_target.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "gyrotherm/analysis/allan.h"

namespace gyrotherm::analysis {

bool AcquisitionTarget::is_valid(std::string* why) const {
  auto fail = [&](std::string message) {
    if (why) *why = std::move(message);
    return false;
  };
  if (!std::isfinite(target_u95_dph) || target_u95_dph <= 0) {
    return fail(fmt::format("target_u95_dph {}: must be finite and > 0", target_u95_dph));
  }
  if (!std::isfinite(min_s) || min_s < 0) {
    return fail(fmt::format("min_s {}: must be finite and >= 0", min_s));
  }
  if (!std::isfinite(max_s) || max_s <= 0) {
    return fail(fmt::format("max_s {}: must be finite and > 0", max_s));
  }
  if (max_s < min_s) return fail(fmt::format("max_s {} is below min_s {}", max_s, min_s));
  return true;
}

std::string_view to_string(AcquisitionVerdict v) {
  switch (v) {
    case AcquisitionVerdict::kContinue:
      return "continue";
    case AcquisitionVerdict::kReached:
      return "reached";
    case AcquisitionVerdict::kOutOfReach:
      return "out_of_reach";
    case AcquisitionVerdict::kNoModel:
      return "no_model";
  }
  return "no_model";
}

namespace {

// The projected U95 at T; +inf when the model gives none there.
double projected_u95(const NoiseModel& model, double t_s) {
  auto u = mean_uncertainty(model, t_s);
  return u ? u->expanded_dph : std::numeric_limits<double>::infinity();
}

std::string format_min(double s) { return fmt::format("{:.0f} min", s / 60.0); }

}  // namespace

Result<AcquisitionProjection> project_acquisition(std::span<const double> t_s,
                                                  std::span<const double> rate_dph,
                                                  double acquired_s,
                                                  const AcquisitionTarget& target) {
  if (std::string why; !target.is_valid(&why)) {
    return Error::Permanent("project_acquisition: " + why);
  }
  if (t_s.size() != rate_dph.size()) {
    return Error::Permanent(
        fmt::format("project_acquisition: {} times but {} rates", t_s.size(), rate_dph.size()));
  }
  if (!std::isfinite(acquired_s) || acquired_s <= 0) {
    return Error::Permanent(
        fmt::format("project_acquisition: acquired {} s: must be finite and > 0", acquired_s));
  }
  AcquisitionProjection p;
  p.acquired_s = acquired_s;
  auto allan = allan_deviation(t_s, rate_dph, {.taus = TauSet::kOctave});
  if (!allan) {
    p.note = "no Allan curve yet: " + allan.error().message;
    return p;
  }
  auto model = fit_noise_model(allan->tau_s, allan->adev_dph, allan->edf);
  if (!model) {
    p.note = "no noise model yet: " + model.error().message;
    return p;
  }
  auto now = mean_uncertainty(*model, acquired_s);
  if (!now) {
    p.note = now.error().message;
    return p;
  }
  p.model = *model;
  p.now = *now;
  p.floor_u95_dph = now->k * now->floor_dph;

  // The projection on a log grid from the length acquired to the cap (U95(T)
  // is smooth: q_n / T falls, q_k T rises, k moves slowly with the dof).
  constexpr int kGrid = 200;
  const double from_s = acquired_s;
  const double to_s = std::max(target.max_s, acquired_s);
  const auto grid_s = [&](int i) {
    return from_s * std::pow(to_s / from_s, static_cast<double>(i) / kGrid);
  };
  p.best_u95_dph = now->expanded_dph;
  for (int i = 0; i <= kGrid; ++i) {
    const double t = grid_s(i);
    const double u95 = projected_u95(*model, t);
    p.best_u95_dph = std::min(p.best_u95_dph, u95);
    if (!p.reach_s && u95 <= target.target_u95_dph) p.reach_s = t;
  }

  if (now->expanded_dph <= target.target_u95_dph) {
    p.verdict = AcquisitionVerdict::kReached;
    p.note = fmt::format("target reached: U95 {:.3g} °/h <= {:.3g} °/h after {}", now->expanded_dph,
                         target.target_u95_dph, format_min(acquired_s));
    return p;
  }
  // What stands in the way: the flicker floor, or a rate random walk whose
  // share of u grows with the soak (K = sqrt(3 * 3600 q_k), noise_model.h).
  // Out of reach only when that term is there beyond doubt (kOutOfReachZ).
  // A term the curve's last few-dof points put in by chance (a bump at long
  // tau) would otherwise end a soak of a white-noise axis; more data settles
  // it.
  const bool walk = model->q[2] * acquired_s > model->q[1];
  const NoiseModelTerm& blocker =
      walk ? model->rate_random_walk_dphprh : model->bias_instability_dph;
  const std::size_t term = walk ? 2 : 1;
  const double term_z = model->q[term] / std::sqrt(std::max(model->cov[term][term], 0.0));
  const bool flat =
      p.best_u95_dph > target.target_u95_dph && now->expanded_dph <= kFlatRatio * p.best_u95_dph;
  // A record cannot tell a rate random walk, or a flicker floor, from a
  // wandering bias whose correlation time is near its own length or longer
  // (its curve rises like a walk below T_c and tops out near 1.9 T_c). The
  // term is in the way beyond doubt only if white noise and a wandering bias
  // alone (noise_model.h) either fit the curve clearly worse or cannot reach
  // the target within the cap either. On the simulator's gyros (a wandering
  // bias of T_c 300 s), 11 of 100 10-min soaks were otherwise ended out of
  // reach on a walk or a floor that was not there.
  std::optional<double> unturned_reach_s;
  if (flat && term_z > kOutOfReachZ) {
    constexpr unsigned kWhiteAndWandering = (1u << 0) | (1u << kGaussMarkov);
    auto wandering = fit_noise_model(allan->tau_s, allan->adev_dph, allan->edf, kWhiteAndWandering);
    if (wandering && wandering->gauss_markov_dph.fitted &&
        wandering->deviance <= model->deviance + kTermPenalty) {
      // Its correlation time is poorly known from a curve that has not
      // turned: any the curve cannot rule out (the fit's alternatives) will
      // do. Each is projected on its own (mean_uncertainty would take the
      // largest over them).
      std::vector<NoiseModel> candidates{*wandering};
      for (const NoiseModel::Alternative& alt : wandering->gm_alternatives) {
        NoiseModel m = *wandering;
        m.q = alt.q;
        m.cov = alt.cov;
        m.gm_tc_s = alt.gm_tc_s;
        candidates.push_back(m);
      }
      for (NoiseModel& m : candidates) {
        m.gm_alternatives.clear();
        for (int i = 0; i <= kGrid; ++i) {
          const double t = grid_s(i);
          if (projected_u95(m, t) > target.target_u95_dph) continue;
          if (!unturned_reach_s || t < *unturned_reach_s) unturned_reach_s = t;
          break;
        }
      }
    }
  }
  if (flat && term_z > kOutOfReachZ && !unturned_reach_s) {
    p.verdict = AcquisitionVerdict::kOutOfReach;
    const std::string floor = model->q[1] > 0 ? fmt::format("floor = {:.3g} °/h (U95 {:.3g})",
                                                            now->floor_dph, p.floor_u95_dph)
                                              : std::string("floor = 0 °/h (no flicker term)");
    p.note = fmt::format(
        "target {:.3g} °/h out of reach: U95 {:.3g} °/h after {}, at best {:.3g} °/h within the "
        "cap ({}); {}{}",
        target.target_u95_dph, now->expanded_dph, format_min(acquired_s), p.best_u95_dph,
        format_min(target.max_s), floor,
        walk ? fmt::format("; a rate random walk (K {:.3g} °/h/√h) grows it on longer soaks",
                           std::sqrt(3.0 * 3600.0 * model->q[2]))
             : "");
    return p;
  }
  p.verdict = AcquisitionVerdict::kContinue;
  if (unturned_reach_s) {
    p.note = fmt::format(
        "U95 {:.3g} °/h after {}: a {} would keep it above the target {:.3g} °/h, but a "
        "wandering bias that has not turned yet fits the curve as well and would reach it at {}: "
        "acquiring on",
        now->expanded_dph, format_min(acquired_s),
        walk ? fmt::format("rate random walk (K {:.3g} °/h/√h)",
                           std::sqrt(3.0 * 3600.0 * model->q[2]))
             : fmt::format("flicker floor ({:.3g} °/h)", now->floor_dph),
        target.target_u95_dph, format_min(*unturned_reach_s));
    return p;
  }
  if (flat) {
    p.note = fmt::format(
        "U95 {:.3g} °/h after {}: a {} ({:.3g} [{:.3g}, {:.3g}] {}) would keep it above the target "
        "{:.3g} °/h, but it is not certain yet ({:.1f} standard uncertainties): acquiring on",
        now->expanded_dph, format_min(acquired_s), walk ? "rate random walk" : "flicker floor",
        blocker.value, blocker.lo, blocker.hi, walk ? "°/h/√h" : "°/h", target.target_u95_dph,
        term_z);
    return p;
  }
  p.note = p.reach_s ? fmt::format("U95 {:.3g} °/h after {}; the target {:.3g} °/h projected at {}",
                                   now->expanded_dph, format_min(acquired_s), target.target_u95_dph,
                                   format_min(*p.reach_s))
                     : fmt::format(
                           "U95 {:.3g} °/h after {}; the target {:.3g} °/h not projected "
                           "within the cap ({}): at best {:.3g} °/h",
                           now->expanded_dph, format_min(acquired_s), target.target_u95_dph,
                           format_min(target.max_s), p.best_u95_dph);
  return p;
}

}  // namespace gyrotherm::analysis
