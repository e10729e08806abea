#include "gyrotherm/core/clock.h"

#include <fmt/format.h>

#include <charconv>
#include <cmath>
#include <cstdint>
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

double SystemWallClock::unix_now_s() const {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

double SystemWallClock::monotonic_s() const {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

const WallClock& system_wall_clock() {
  static const SystemWallClock clock;
  return clock;
}

std::string wall_time_utc_iso() { return utc_iso(system_wall_clock()); }

std::string utc_iso(const WallClock& clock) { return utc_iso(clock.unix_now_s()); }

std::string utc_iso(double unix_s) {
  const auto ms = static_cast<int64_t>(std::floor(unix_s * 1000.0 + 0.5));
  const std::time_t secs = static_cast<std::time_t>(ms >= 0 ? ms / 1000 : (ms - 999) / 1000);
  std::tm tm{};
  gmtime_r(&secs, &tm);
  return fmt::format("{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z", tm.tm_year + 1900, tm.tm_mon + 1,
                     tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, ms - int64_t{secs} * 1000);
}

Result<double> parse_utc_iso(std::string_view text) {
  const auto bad = [text](std::string_view why) {
    return Error::Permanent(fmt::format(
        "\"{}\" is not an ISO-8601 date or time ({}); e.g. 2026-11-21 or 2026-11-21T02:00:00Z",
        text, why));
  };
  std::size_t pos = 0;
  const auto digits = [&](std::size_t n, int& out) {
    if (pos + n > text.size()) return false;
    const auto [end, ec] = std::from_chars(text.data() + pos, text.data() + pos + n, out);
    if (ec != std::errc() || end != text.data() + pos + n) return false;
    pos += n;
    return true;
  };
  const auto expect = [&](char c) {
    if (pos < text.size() && text[pos] == c) {
      ++pos;
      return true;
    }
    return false;
  };
  int year = 0, month = 0, day = 0, hour = 0, minute = 0, second = 0;
  double fraction = 0;
  if (!digits(4, year) || !expect('-') || !digits(2, month) || !expect('-') || !digits(2, day)) {
    return bad("the date must be YYYY-MM-DD");
  }
  if (month < 1 || month > 12 || day < 1 || day > 31) return bad("month or day out of range");
  int offset_s = 0;
  if (pos < text.size()) {
    if (!expect('T') && !expect(' ')) return bad("expected 'T' after the date");
    if (!digits(2, hour) || !expect(':') || !digits(2, minute))
      return bad("the time must be HH:MM");
    if (expect(':')) {
      if (!digits(2, second)) return bad("seconds must be two digits");
      if (expect('.')) {
        const std::size_t from = pos;
        while (pos < text.size() && text[pos] >= '0' && text[pos] <= '9') ++pos;
        if (pos == from) return bad("no digits after '.'");
        fraction = std::stod("0." + std::string(text.substr(from, pos - from)));
      }
    }
    if (hour > 23 || minute > 59 || second > 60) return bad("time out of range");
    if (expect('Z')) {
    } else if (pos < text.size() && (text[pos] == '+' || text[pos] == '-')) {
      const int sign = text[pos] == '-' ? -1 : 1;
      ++pos;
      int oh = 0, om = 0;
      if (!digits(2, oh)) return bad("the offset must be +HH:MM");
      expect(':');
      if (!digits(2, om) || oh > 23 || om > 59) return bad("the offset must be +HH:MM");
      offset_s = sign * (oh * 3600 + om * 60);
    }
    if (pos != text.size()) return bad("unexpected text after the time");
  }
  std::tm tm{};
  tm.tm_year = year - 1900;
  tm.tm_mon = month - 1;
  tm.tm_mday = day;
  tm.tm_hour = hour;
  tm.tm_min = minute;
  tm.tm_sec = second;
  const std::time_t t = timegm(&tm);
  if (tm.tm_mday != day) return bad("no such day in that month");
  return static_cast<double>(t) - offset_s + fraction;
}

}  // namespace gyrotherm
