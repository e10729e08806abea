#include "gyrotherm/sim/rate_table_model.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace gyrotherm::sim {
namespace {

// Position mode: the rate toward the demand is at most sqrt(2 a |d|) with a
// = this fraction of the acceleration limit (headroom for the jerk-limited
// approach), and kPositionGainPerS x |d| near the target (a linear loop, so
// the axis settles instead of chattering).
constexpr double kPositionAccelFraction = 0.5;
constexpr double kPositionGainPerS = 2.0;
// Within these the axis is at the position demand and held exactly there.
constexpr double kPositionSettleDeg = 1e-6;
constexpr double kPositionSettleDps = 1e-5;

double sign(double x) { return x > 0 ? 1.0 : (x < 0 ? -1.0 : 0.0); }

}  // namespace

double wrap_360(double deg) {
  double w = std::fmod(deg, 360.0);
  if (w < 0) w += 360.0;
  if (w >= 360.0) w = 0.0;  // fmod of a tiny negative rounds up to 360
  return w;
}

double shortest_angle_deg(double from_deg, double to_deg) {
  double d = wrap_360(to_deg - from_deg);
  if (d > 180.0) d -= 360.0;
  return d;
}

bool TableParams::is_valid(std::string* why) const {
  auto bad = [&](const char* name, double v, double lo, double hi) {
    if (std::isfinite(v) && v >= lo && v <= hi) return false;
    if (why) *why = fmt::format("table {} = {} must be in [{}, {}]", name, v, lo, hi);
    return true;
  };
  if (bad("max_rate_dps", max_rate_dps, 1e-3, 1e5) ||
      bad("max_accel_dps2", max_accel_dps2, 1e-3, 1e6) ||
      bad("max_jerk_dps3", max_jerk_dps3, 1e-3, 1e8) ||
      bad("trip_rate_dps", trip_rate_dps, 1e-3, 2e5) ||
      bad("rate_noise_rel", rate_noise_rel, 0, 0.1) ||
      bad("max_substep_s", max_substep_s, 1e-6, 0.1)) {
    return false;
  }
  if (trip_rate_dps <= max_rate_dps) {
    if (why) {
      *why = fmt::format("table trip_rate_dps = {} must exceed max_rate_dps = {}", trip_rate_dps,
                         max_rate_dps);
    }
    return false;
  }
  if (reply_header != "ascii" && reply_header != "binary-le" && reply_header != "binary-be" &&
      reply_header != "line") {
    if (why) {
      *why =
          fmt::format("table reply_header = '{}' must be one of ascii, binary-le, binary-be, line",
                      reply_header);
    }
    return false;
  }
  return true;
}

RateTableModel::RateTableModel(TableParams params, uint64_t seed)
    : params_(std::move(params)),
      rng_(seed),
      rate_limit_dps_(params_.max_rate_dps),
      accel_limit_dps2_(params_.max_accel_dps2),
      trip_rate_dps_(params_.trip_rate_dps) {}

double RateTableModel::position_deg() const { return wrap_360(position_deg_); }

double RateTableModel::target_rate_dps() const {
  switch (mode_) {
    case drivers::TableMode::kRate:
      return rate_demand_dps_;
    case drivers::TableMode::kPosition: {
      const double d = shortest_angle_deg(position_deg_, position_demand_deg_);
      const double ramp = std::sqrt(2.0 * kPositionAccelFraction * accel_limit_dps2_ * std::abs(d));
      return sign(d) * std::min({rate_limit_dps_, ramp, kPositionGainPerS * std::abs(d)});
    }
    default:
      return 0.0;
  }
}

void RateTableModel::step(double dt_s) {
  if (!(dt_s > 0)) return;
  const int n = std::max(1, static_cast<int>(std::ceil(dt_s / params_.max_substep_s - 1e-9)));
  const double h = dt_s / n;
  for (int i = 0; i < n; ++i) substep(h);
  measured_rate_dps_ = rate_dps_ * (1.0 + params_.rate_noise_rel * normal_(rng_));
}

void RateTableModel::substep(double h) {
  const double v0 = rate_dps_;
  const double a0 = accel_dps2_;
  if (interlock_ != drivers::TableInterlock::kClosed) {
    // Not servoed: coasts to rest at the acceleration limit.
    accel_dps2_ = 0;
    if (v0 == 0) return;
    const double a = -sign(v0) * accel_limit_dps2_;
    const double t_stop = std::abs(v0) / accel_limit_dps2_;
    const double t = std::min(h, t_stop);
    position_deg_ += v0 * t + 0.5 * a * t * t;
    rate_dps_ = t < t_stop ? v0 + a * t : 0.0;
    accel_dps2_ = t < t_stop ? a : 0.0;
    return;
  }

  const double j_max = params_.max_jerk_dps3;
  const double a_max = accel_limit_dps2_;
  const double target = target_rate_dps();
  const double e = target - v0;
  if (std::abs(e) <= j_max * h * h && std::abs(a0) <= j_max * h * (1 + 1e-9)) {
    // At the target within what one substep of jerk can resolve.
    position_deg_ += 0.5 * (v0 + target) * h;
    rate_dps_ = target;
    accel_dps2_ = 0;
  } else {
    // Time-optimal under |j| ≤ J, |a| ≤ A: the acceleration a1 at the end of
    // this substep that, ramped to zero at J, uses up the rate error left
    // then exactly: a1² = 2 J (|e| − (a0 + a1) h / 2) (in the direction of e).
    const double s = sign(e);
    const double alpha0 = s * a0;
    const double c = 2.0 * j_max * std::abs(e) - j_max * h * alpha0;
    const double a1 =
        c > 0 ? 0.5 * (-j_max * h + std::sqrt(j_max * j_max * h * h + 4.0 * c)) : -a_max;
    const double a_des = s * std::min(a_max, a1);
    const double j = std::clamp((a_des - a0) / h, -j_max, j_max);
    position_deg_ += v0 * h + 0.5 * a0 * h * h + j * h * h * h / 6.0;
    rate_dps_ = v0 + a0 * h + 0.5 * j * h * h;
    accel_dps2_ = a0 + j * h;
  }
  if (mode_ == drivers::TableMode::kPosition) {
    const double d = shortest_angle_deg(position_deg_, position_demand_deg_);
    if (std::abs(d) < kPositionSettleDeg && std::abs(rate_dps_) < kPositionSettleDps) {
      position_deg_ += d;
      rate_dps_ = 0;
      accel_dps2_ = 0;
    }
  }
  if (std::abs(rate_dps_) > trip_rate_dps_) {
    trip(fmt::format("velocity trip: |rate| {:.3f} deg/s beyond the trip at {:.3f} deg/s",
                     std::abs(rate_dps_), trip_rate_dps_));
  }
}

TableCommandResult RateTableModel::set_mode(drivers::TableMode mode) {
  if (mode == drivers::TableMode::kUnknown) return TableCommandResult::kOutOfRange;
  mode_ = mode;
  return TableCommandResult::kOk;
}

TableCommandResult RateTableModel::set_rate_demand(double rate_dps) {
  if (!std::isfinite(rate_dps) || std::abs(rate_dps) > rate_limit_dps_) {
    return TableCommandResult::kOutOfRange;
  }
  rate_demand_dps_ = rate_dps;
  return TableCommandResult::kOk;
}

TableCommandResult RateTableModel::set_position_demand(double position_deg) {
  if (!std::isfinite(position_deg) || std::abs(position_deg) > 1e9) {
    return TableCommandResult::kOutOfRange;
  }
  position_demand_deg_ = wrap_360(position_deg);
  return TableCommandResult::kOk;
}

TableCommandResult RateTableModel::close_interlock() {
  if (interlock_ == drivers::TableInterlock::kFault) return TableCommandResult::kRefused;
  if (interlock_ == drivers::TableInterlock::kOpen) {
    interlock_ = drivers::TableInterlock::kClosed;
    accel_dps2_ = 0;  // the servo takes over from the coasting axis
  }
  return TableCommandResult::kOk;
}

void RateTableModel::open_interlock() {
  if (interlock_ == drivers::TableInterlock::kClosed) interlock_ = drivers::TableInterlock::kOpen;
}

void RateTableModel::reset_faults() {
  if (interlock_ != drivers::TableInterlock::kFault) return;
  interlock_ = drivers::TableInterlock::kOpen;
  fault_.clear();
}

void RateTableModel::trip(std::string reason) {
  if (interlock_ == drivers::TableInterlock::kFault) return;  // the first cause stays
  interlock_ = drivers::TableInterlock::kFault;
  mode_ = drivers::TableMode::kOff;
  fault_ = std::move(reason);
}

TableCommandResult RateTableModel::set_rate_limit(double rate_dps) {
  if (!(std::isfinite(rate_dps) && rate_dps > 0 && rate_dps <= params_.max_rate_dps)) {
    return TableCommandResult::kOutOfRange;
  }
  rate_limit_dps_ = rate_dps;
  rate_demand_dps_ = std::clamp(rate_demand_dps_, -rate_dps, rate_dps);
  return TableCommandResult::kOk;
}

TableCommandResult RateTableModel::set_accel_limit(double accel_dps2) {
  if (!(std::isfinite(accel_dps2) && accel_dps2 > 0 && accel_dps2 <= 10 * params_.max_accel_dps2)) {
    return TableCommandResult::kOutOfRange;
  }
  accel_limit_dps2_ = accel_dps2;
  return TableCommandResult::kOk;
}

TableCommandResult RateTableModel::set_trip_rate(double rate_dps) {
  if (!(std::isfinite(rate_dps) && rate_dps > 0 && rate_dps <= 2 * params_.trip_rate_dps)) {
    return TableCommandResult::kOutOfRange;
  }
  trip_rate_dps_ = rate_dps;
  return TableCommandResult::kOk;
}

TableModelState RateTableModel::state() const {
  TableModelState s;
  s.mode = mode_;
  s.interlock = interlock_;
  s.rate_dps = rate_dps_;
  s.measured_rate_dps = measured_rate_dps_;
  s.accel_dps2 = accel_dps2_;
  s.position_deg = position_deg();
  s.rate_demand_dps = rate_demand_dps_;
  s.position_demand_deg = position_demand_deg_;
  s.rate_limit_dps = rate_limit_dps_;
  s.accel_limit_dps2 = accel_limit_dps2_;
  s.trip_rate_dps = trip_rate_dps_;
  s.fault = fault_;
  return s;
}

}  // namespace gyrotherm::sim
