#include "gyrotherm/schedules/coverage.h"

#include <algorithm>

namespace gyrotherm::schedules {

CoverageSpans::CoverageSpans(double period_s) : period_s_(period_s > 0 ? period_s : 1.0) {}

void CoverageSpans::add(double t_s) {
  if (!spans_.empty()) {
    auto& last = spans_.back();
    const double last_sample_s = last.second - period_s_;
    if (t_s < last_sample_s) return;
    // One missing sample is bridged: the next is at most two periods on
    // (with a little slack for the time stamps' rounding).
    if (t_s - last_sample_s <= 2.0 * period_s_ * (1.0 + 1e-6)) {
      last.second = std::max(last.second, t_s + period_s_);
      return;
    }
  }
  spans_.emplace_back(t_s, t_s + period_s_);
}

double CoverageSpans::covered_s(double from_s, double to_s) const {
  double sum = 0;
  for (const auto& [a, b] : spans_) {
    const double lo = std::max(a, from_s), hi = std::min(b, to_s);
    if (hi > lo) sum += hi - lo;
  }
  return sum;
}

std::optional<double> CoverageSpans::reached_at(double from_s, double need_s) const {
  if (need_s <= 0) return from_s;
  double have = 0;
  for (const auto& [a, b] : spans_) {
    const double lo = std::max(a, from_s);
    if (b <= lo) continue;
    if (have + (b - lo) >= need_s) return lo + (need_s - have);
    have += b - lo;
  }
  return std::nullopt;
}

std::optional<double> CoverageSpans::end_s() const {
  if (spans_.empty()) return std::nullopt;
  return spans_.back().second;
}

void CoverageSpans::forget_before(double t_s) {
  // The span in progress stays, whatever its age: the next sample extends it.
  const auto keep = std::find_if(spans_.begin(), spans_.end() - (spans_.empty() ? 0 : 1),
                                 [t_s](const auto& s) { return s.second >= t_s; });
  spans_.erase(spans_.begin(), keep);
}

}  // namespace gyrotherm::schedules
