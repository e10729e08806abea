#include "gyrotherm/core/clock.h"

#include <fmt/format.h>

#include <ctime>

namespace gyrotherm {

std::chrono::nanoseconds Clock::wall_duration(double station_s) const {
  const double wall_s = station_s / time_scale();
  return std::chrono::nanoseconds(static_cast<long long>(wall_s * 1e9));
}

ScaledClock::ScaledClock(double time_scale, double start_s)
    : scale_(time_scale), start_s_(start_s), origin_(std::chrono::steady_clock::now()) {}

double ScaledClock::now_s() const {
  const std::chrono::duration<double> wall = std::chrono::steady_clock::now() - origin_;
  return start_s_ + wall.count() * scale_;
}

std::string wall_time_utc_iso() {
  const auto now = std::chrono::system_clock::now();
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count();
  const std::time_t secs = static_cast<std::time_t>(ms / 1000);
  std::tm tm{};
  gmtime_r(&secs, &tm);
  return fmt::format("{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z", tm.tm_year + 1900, tm.tm_mon + 1,
                     tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, ms % 1000);
}

}  // namespace gyrotherm
