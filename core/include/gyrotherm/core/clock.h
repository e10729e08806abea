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
// never comes from these clocks; see WallClock and wall_time_utc_iso().
#pragma once

#include <atomic>
#include <chrono>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"

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

// Wall time: Unix seconds for what is stamped for humans (event and run
// rows, the nightly export's local time of day, a run's downtime across a
// restart), and a monotonic reading for wall durations (how long a device
// has been silent, checkpoint intervals, uptime). Injected like the station
// clock: into the station, storage and the nightly export, so tests walk
// across days, daylight-saving changes and downtime without waiting.
class WallClock {
 public:
  virtual ~WallClock() = default;
  virtual double unix_now_s() const = 0;  // thread-safe
  // Seconds from an arbitrary origin, never going back: for durations only.
  // Defaults to unix_now_s() (right for the clocks that tests move).
  virtual double monotonic_s() const { return unix_now_s(); }
};

// The system's real-time clock; monotonic_s() is the steady clock, so a
// step of the system time does not change a duration.
class SystemWallClock final : public WallClock {
 public:
  double unix_now_s() const override;
  double monotonic_s() const override;
};

// One SystemWallClock for the process: what the daemon, storage and tools use
// unless a test hands them another.
const WallClock& system_wall_clock();

// Simulation: wall time that starts at `start_unix_s` when constructed and
// advances with a station clock (so at its time scale).
class StationWallClock final : public WallClock {
 public:
  StationWallClock(const Clock& station, double start_unix_s)
      : station_(station), start_unix_s_(start_unix_s), station_t0_s_(station.now_s()) {}
  double unix_now_s() const override { return start_unix_s_ + (station_.now_s() - station_t0_s_); }

 private:
  const Clock& station_;
  double start_unix_s_;
  double station_t0_s_;
};

// Moves only when told to. For tests. Thread-safe.
class ManualWallClock final : public WallClock {
 public:
  explicit ManualWallClock(double unix_s) : unix_s_(unix_s) {}
  double unix_now_s() const override { return unix_s_.load(); }
  void set(double unix_s) { unix_s_.store(unix_s); }
  void advance(double dt_s) { unix_s_.store(unix_s_.load() + dt_s); }

 private:
  std::atomic<double> unix_s_;
};

// Current wall time as ISO-8601 UTC with milliseconds, e.g.
// "2026-11-21T05:38:43.120Z". For event rows and reports, never for control.
std::string wall_time_utc_iso();
// Unix seconds as ISO-8601 UTC with milliseconds.
std::string utc_iso(double unix_s);
// The clock's wall time now, as ISO-8601 UTC with milliseconds.
std::string utc_iso(const WallClock& clock);
// ISO-8601 to Unix seconds: "2026-11-21" (midnight UTC),
// "2026-11-21T05:38" / "T05:38:43" / "T05:38:43.120" followed by "Z" or an
// offset "+01:00" / "-0500" (no zone: UTC). Errors name the text.
Result<double> parse_utc_iso(std::string_view text);

}  // namespace gyrotherm
