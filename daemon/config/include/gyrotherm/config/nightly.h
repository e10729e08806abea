// When the nightly calibration export runs (docs/reports.md): every day at a
// local time of day ([export] local_time, "HH:MM") in the station's time
// zone, on the daemon's injected clock. Pure functions of their arguments, so
// tests can walk across daylight-saving changes and downtime in virtual time.
//
// Rules:
// - A local time that does not exist that day (the spring-forward gap, e.g.
//   02:30 when clocks jump from 02:00 to 03:00) runs at the end of the gap,
//   the first instant local clocks show after it.
// - A local time that happens twice (the fall-back overlap) runs once, at
//   the earlier instant.
// - Catching up: a daemon that was down over one or more slots exports once
//   when it comes back (one export covers every run completed since the last
//   one), not once per missed night.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"

namespace gyrotherm::config {

struct LocalTimeOfDay {
  int hour = 2;
  int minute = 0;
  int seconds_of_day() const { return hour * 3600 + minute * 60; }
};
// "HH:MM", 00:00 ... 23:59. Errors name the text.
Result<LocalTimeOfDay> parse_local_time_of_day(std::string_view text);

// A time zone as the UTC offset (seconds east of UTC, DST included) in force
// at each instant (Unix seconds).
class TimeZone {
 public:
  // The system's local zone (TZ, /etc/localtime) through localtime_r.
  static TimeZone system_local();
  // A POSIX TZ rule such as "CET-1CEST,M3.5.0,M10.5.0/3" or "UTC0" (Boost
  // local_time's posix_time_zone). Errors name the text.
  static Result<TimeZone> posix(const std::string& rule);
  // A fixed offset (tests).
  static TimeZone fixed(int offset_s);

  int offset_s(double unix_s) const { return offset_(unix_s); }
  const std::string& name() const { return name_; }

 private:
  TimeZone(std::string name, std::function<int(double)> offset)
      : name_(std::move(name)), offset_(std::move(offset)) {}
  std::string name_;
  std::function<int(double)> offset_;
};

// The first instant strictly after `after_unix_s` at which the export is
// scheduled (rules above).
double next_slot_unix_s(double after_unix_s, LocalTimeOfDay at, const TimeZone& zone);

// The latest scheduled slot in (last_slot_unix_s, now_unix_s], i.e. the
// export due now; nullopt when none is due. With no last slot (never
// exported), slots count from `since_unix_s` (e.g. the daemon's first start).
std::optional<double> due_slot_unix_s(std::optional<double> last_slot_unix_s, double since_unix_s,
                                      double now_unix_s, LocalTimeOfDay at, const TimeZone& zone);

}  // namespace gyrotherm::config
