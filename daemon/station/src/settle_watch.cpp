#include "settle_watch.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <string>
#include <system_error>
#include <utility>

namespace gyrotherm::station {

SettleWatch::~SettleWatch() {
  if (pending_.valid()) pending_.wait();
}

void SettleWatch::forget() {
  step_.reset();
  t_s_.clear();
  shell_c_.clear();
  air_c_.clear();
  pack_n_ = pack_air_n_ = 0;
  pack_t_sum_ = pack_c_sum_ = pack_air_sum_ = 0;
  due_s_.reset();
  last_.reset();
  ++generation_;  // a prediction in flight is for a series that is gone
}

void SettleWatch::take_result() {
  if (!pending_.valid() ||
      pending_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) {
    return;
  }
  auto result = pending_.get();
  if (pending_generation_ != generation_) return;
  if (result) {
    last_ = std::move(*result);
    last_as_of_s_ = pending_as_of_s_;
  } else {
    // The series is checked as it is kept: not expected; said once per soak.
    if (!last_) spdlog::warn("settle forecast: {}", result.error().message);
  }
}

void SettleWatch::tick(double t_run_s, std::optional<std::size_t> settling_step,
                       const analysis::SettleGate& gate, std::optional<double> shell_c,
                       std::optional<double> air_c) {
  take_result();
  if (settling_step != step_) {
    forget();
    step_ = settling_step;
  }
  if (!step_) return;
  if (shell_c && std::isfinite(*shell_c)) {
    if (pack_n_ > 0 && t_run_s - pack_start_s_ >= kPackS) {
      const double t = pack_t_sum_ / pack_n_;
      if (t_s_.empty() || t > t_s_.back()) {
        t_s_.push_back(t);
        shell_c_.push_back(pack_c_sum_ / pack_n_);
        air_c_.push_back(pack_air_n_ > 0 ? pack_air_sum_ / pack_air_n_
                                         : std::numeric_limits<double>::quiet_NaN());
      }
      pack_n_ = pack_air_n_ = 0;
      pack_t_sum_ = pack_c_sum_ = pack_air_sum_ = 0;
    }
    if (pack_n_ == 0) pack_start_s_ = t_run_s;
    pack_t_sum_ += t_run_s;
    pack_c_sum_ += *shell_c;
    ++pack_n_;
    if (air_c && std::isfinite(*air_c)) {
      pack_air_sum_ += *air_c;
      ++pack_air_n_;
    }
  }
  if (!due_s_) due_s_ = t_run_s + kEveryS;
  if (t_run_s < *due_s_ || pending_.valid() || t_s_.size() < 2) return;
  due_s_ = t_run_s + kEveryS;
  pending_generation_ = generation_;
  pending_as_of_s_ = t_s_.back();
  try {
    // The air drives the shell's model when every kept mean has it (a
    // chamber that did not answer for 2 s leaves a gap: the shell alone).
    const bool with_air =
        std::all_of(air_c_.begin(), air_c_.end(), [](double v) { return std::isfinite(v); });
    std::vector<double> air = with_air ? air_c_ : std::vector<double>{};
    pending_ =
        std::async(std::launch::async, [t = t_s_, c = shell_c_, a = std::move(air), g = gate] {
          return analysis::predict_settle(t, c, g, {}, a);
        });
  } catch (const std::system_error& e) {
    // No thread to be had (a process limit): the forecast waits a minute;
    // the run goes on.
    spdlog::warn("settle forecast: no thread for it ({})", e.what());
  }
}

std::optional<schedules::SettleForecast> SettleWatch::forecast(double t_run_s) const {
  if (!step_ || !last_) return std::nullopt;
  schedules::SettleForecast f;
  f.verdict = std::string(analysis::to_string(last_->verdict));
  f.note = last_->note;
  const auto from_now = [t_run_s](std::optional<double> t) -> std::optional<double> {
    if (!t) return std::nullopt;
    return std::max(0.0, *t - t_run_s);
  };
  f.p10_s = from_now(last_->p10_s);
  f.p50_s = from_now(last_->p50_s);
  f.p90_s = from_now(last_->p90_s);
  f.age_s = std::max(0.0, t_run_s - last_as_of_s_);
  return f;
}

}  // namespace gyrotherm::station
