#include "acquire_watch.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>

#include "gyrotherm/analysis/acquisition_target.h"

namespace gyrotherm::station {

void AcquireWatch::forget() {
  step_.reset();
  due_s_.reset();
  last_.reset();
  done_.reset();
}

void AcquireWatch::tick(double t_run_s, std::size_t index, const schedules::PlanStep* step,
                        bool acquiring, std::span<const std::pair<double, double>> windows,
                        const Seconds& seconds) {
  if (!step || !step->adaptive || step_ != index) {
    forget();
    if (step && step->adaptive) step_ = index;
  }
  if (!step_) return;
  if (!acquiring) {
    // Held, or settling again after a hold broke the acquisition: the last
    // judgement is shown, but ends nothing until the next one.
    due_s_.reset();
    done_.reset();
    return;
  }
  if (!due_s_) due_s_ = t_run_s + kEveryS;  // the first judgement after kEveryS of acquiring
  if (t_run_s < *due_s_) return;
  due_s_ = t_run_s + kEveryS;
  judge(t_run_s, *step, seconds(windows));
}

namespace {

// U95(T) of `model` at kProjectionPoints log-spaced lengths from kFromS to
// the cap (at least twice kFromS).
std::vector<schedules::AcquireAxis::Point> projection(const analysis::NoiseModel& model,
                                                      double max_s) {
  constexpr int kProjectionPoints = 41;
  constexpr double kFromS = 60;
  const double to_s = std::max(max_s, 2 * kFromS);
  std::vector<schedules::AcquireAxis::Point> points;
  for (int i = 0; i < kProjectionPoints; ++i) {
    const double t = kFromS * std::pow(to_s / kFromS, i / (kProjectionPoints - 1.0));
    if (auto u = analysis::mean_uncertainty(model, t)) points.push_back({t, u->expanded_dph});
  }
  return points;
}

}  // namespace

void AcquireWatch::judge(double t_run_s, const schedules::PlanStep& step,
                         std::vector<DutAcquisition::AxisSeconds> axes) {
  const analysis::AcquisitionTarget& target = *step.adaptive;
  schedules::AcquireForecast f;
  f.target_u95_dph = target.target_u95_dph;
  f.min_s = target.min_s;
  f.max_s = target.max_s;
  f.acquired_s = axes.empty() ? 0.0 : std::numeric_limits<double>::infinity();
  bool all_projected = !axes.empty();
  bool all_final = !axes.empty();
  double planned_s = 0;
  std::vector<std::string> reached, out_of_reach;
  double worst_u95 = 0;
  std::string worst;
  for (auto& a : axes) {
    schedules::AcquireAxis axis;
    axis.name = a.name;
    const double n_s = static_cast<double>(a.rate_dph.size());
    f.acquired_s = std::min(f.acquired_s, n_s);
    std::vector<double> t_s(a.rate_dph.size());
    for (std::size_t i = 0; i < t_s.size(); ++i) t_s[i] = static_cast<double>(i);
    auto p = n_s > 0 ? analysis::project_acquisition(t_s, a.rate_dph, n_s, target)
                     : Result<analysis::AcquisitionProjection>(analysis::AcquisitionProjection{});
    if (!p) {
      axis.verdict = "no_model";
      axis.note = p.error().message;
    } else {
      axis.verdict = std::string(analysis::to_string(p->verdict));
      axis.note = n_s > 0 ? p->note : "no data in the soak's windows yet";
      if (p->now) {
        axis.u95_dph = p->now->expanded_dph;
        axis.floor_dph = p->now->floor_dph;
      }
      if (p->model && p->now) {
        const analysis::NoiseModel& m = *p->model;
        axis.model = schedules::AcquireAxis::Model{.q_n = m.q[0],
                                                   .q_b = m.q[1],
                                                   .q_k = m.q[2],
                                                   .q_g = m.q[analysis::kGaussMarkov],
                                                   .gm_tc_s = m.gm_tc_s,
                                                   .k = p->now->k};
        axis.projection = projection(m, target.max_s);
      }
      axis.reach_s = p->reach_s;
      switch (p->verdict) {
        case analysis::AcquisitionVerdict::kReached:
          planned_s = std::max(planned_s, n_s);
          reached.push_back(a.name);
          if (p->now->expanded_dph >= worst_u95) {
            worst_u95 = p->now->expanded_dph;
            worst = a.name;
          }
          break;
        case analysis::AcquisitionVerdict::kOutOfReach:
          planned_s = std::max(planned_s, n_s);
          out_of_reach.push_back(fmt::format("{} ({})", a.name, p->note));
          break;
        case analysis::AcquisitionVerdict::kContinue:
          all_final = false;
          if (p->reach_s) {
            planned_s = std::max(planned_s, *p->reach_s);
          } else {
            all_projected = false;
          }
          break;
        case analysis::AcquisitionVerdict::kNoModel:
          all_final = false;
          all_projected = false;
          break;
      }
    }
    if (axis.verdict == "no_model") all_final = all_projected = false;
    f.axes.push_back(std::move(axis));
  }
  if (all_projected) f.planned_s = planned_s;
  last_ = std::move(f);
  last_at_s_ = t_run_s;
  done_.reset();
  if (!all_final) return;
  if (out_of_reach.empty()) {
    done_ = fmt::format(
        "target reached: U95 <= {:g} °/h on every gated axis ({} of them) after {:.0f} min "
        "(widest: {}, U95 {:.3g} °/h)",
        target.target_u95_dph, reached.size(), last_->acquired_s / 60.0, worst, worst_u95);
  } else {
    std::string which;
    for (const auto& o : out_of_reach) which += (which.empty() ? "" : "; ") + o;
    done_ = fmt::format(
        "{}{}", which,
        reached.empty() ? "" : fmt::format("; {} other axes reached it", reached.size()));
  }
}

std::optional<schedules::AcquireForecast> AcquireWatch::forecast(double t_run_s) const {
  if (!last_) return std::nullopt;
  schedules::AcquireForecast f = *last_;
  f.age_s = std::max(0.0, t_run_s - last_at_s_);
  return f;
}

}  // namespace gyrotherm::station
