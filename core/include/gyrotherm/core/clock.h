// Station time.
//
// Everything that schedules, integrates or timestamps takes "now" from a
// Clock: seconds of *station* time, monotonic, starting wherever the clock
// was constructed to start. The daemon and the simulator use a ScaledClock
// (station time = wall time x time_scale), so `--time-scale 100` runs a
// two-hour soak in 72 s of wall time; unit tests use a ManualClock and run
// hours of schedule in microseconds without sleeping.
//
// Wall time (UTC, for humans and the nightly export) is a different thing and
// never comes from these clocks; see wall_time_utc_iso().
#pragma once

#include <atomic>
#include <chrono>
#include <string>

namespace gyrotherm {

class Clock {
 public:
  virtual ~Clock() = default;
  // Station time in seconds. Monotonic non-decreasing. Thread-safe.
  virtual double now_s() const = 0;
  // Station seconds per wall second (1 on a real station).
  virtual double time_scale() const = 0;

  // Wall-clock duration that corresponds to a station duration.
  std::chrono::nanoseconds wall_duration(double station_s) const;
};

// Station time = start_s + (steady wall time since construction) x scale.
class ScaledClock final : public Clock {
 public:
  explicit ScaledClock(double time_scale = 1.0, double start_s = 0.0);
  double now_s() const override;
  double time_scale() const override { return scale_; }

 private:
  double scale_;
  double start_s_;
  std::chrono::steady_clock::time_point origin_;
};

// A clock that moves only when told to. For tests. Thread-safe.
class ManualClock final : public Clock {
 public:
  explicit ManualClock(double start_s = 0.0, double time_scale = 1.0)
      : now_s_(start_s), scale_(time_scale) {}
  double now_s() const override { return now_s_.load(); }
  double time_scale() const override { return scale_; }
  void set(double t_s) { now_s_.store(t_s); }
  void advance(double dt_s) { now_s_.store(now_s_.load() + dt_s); }

 private:
  std::atomic<double> now_s_;
  double scale_;
};

// Current wall time as ISO-8601 UTC with milliseconds, e.g.
// "2026-11-21T05:38:43.120Z". For event rows and reports, never for control.
std::string wall_time_utc_iso();

}  // namespace gyrotherm
