#include "gyrotherm/analysis/stability.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "common.h"

namespace gyrotherm::analysis {
namespace {
constexpr double kRelTol = 1e-9;  // of window_s, to absorb rounding in time stamps
}  // namespace

StabilityWindow::StabilityWindow(double window_s) : window_s_(window_s) {}

void StabilityWindow::push(double t_s, double value) {
  if (!std::isfinite(t_s) || !std::isfinite(value)) {
    samples_.clear();
    return;
  }
  if (!samples_.empty()) {
    if (t_s == samples_.back().t_s) {
      samples_.back().value = value;
      return;
    }
    if (t_s < samples_.back().t_s) samples_.clear();
  }
  samples_.push_back({t_s, value});
  const double oldest_kept_s = t_s - window_s_ - kRelTol * window_s_;
  while (samples_.front().t_s < oldest_kept_s) samples_.pop_front();
}

double StabilityWindow::span_s() const {
  if (samples_.size() < 2) return 0.0;
  return samples_.back().t_s - samples_.front().t_s;
}

bool StabilityWindow::full() const {
  if (samples_.size() < 2) return false;
  const double span = span_s();
  const double spacing = span / static_cast<double>(samples_.size() - 1);
  return span + spacing >= window_s_ * (1 - kRelTol);
}

double StabilityWindow::slope_per_s() const {
  if (!full()) return kNaN;
  // Centred sums; times relative to the oldest sample keep the digits.
  const double t_ref = samples_.front().t_s;
  long double st = 0, sy = 0;
  for (const Sample& s : samples_) {
    st += s.t_s - t_ref;
    sy += s.value;
  }
  const long double n = static_cast<long double>(samples_.size());
  const long double tm = st / n;
  const long double ym = sy / n;
  long double stt = 0, sty = 0;
  for (const Sample& s : samples_) {
    const long double dt = (s.t_s - t_ref) - tm;
    stt += dt * dt;
    sty += dt * (s.value - ym);
  }
  if (!(stt > 0)) return kNaN;
  return static_cast<double>(sty / stt);
}

double StabilityWindow::max_abs_dev(double ref) const {
  if (samples_.empty() || std::isnan(ref)) return kNaN;
  double worst = 0;
  for (const Sample& s : samples_) worst = std::max(worst, std::abs(s.value - ref));
  return worst;
}

double StabilityWindow::mean() const {
  if (samples_.empty()) return kNaN;
  long double sum = 0;
  for (const Sample& s : samples_) sum += s.value;
  return static_cast<double>(sum / static_cast<long double>(samples_.size()));
}

}  // namespace gyrotherm::analysis
