#include "gyrotherm/config/nightly.h"

#include <fmt/format.h>

#include <algorithm>
#include <boost/date_time/local_time/local_time.hpp>
#include <cctype>
#include <cmath>
#include <ctime>
#include <exception>
#include <memory>
#include <optional>
#include <vector>

namespace gyrotherm::config {
namespace {

constexpr double kDayS = 86400.0;

// Local "clock seconds" (seconds since 1970-01-01 00:00 local) of an instant.
double local_s(double unix_s, const TimeZone& zone) { return unix_s + zone.offset_s(unix_s); }

// The instant at which local clocks first show `target_local_s` or later,
// knowing that local time is increasing except at fall-back steps. Offsets
// in force around the target are tried; a match is exact. In a gap (no
// instant shows the target), the end of the gap: the earliest instant whose
// local time is past the target, found by bisection.
double first_instant_at_local(double target_local_s, const TimeZone& zone) {
  // Every offset that could apply within a day of the target.
  std::vector<int> offsets;
  for (double probe = -kDayS; probe <= kDayS; probe += 3600.0) {
    const int o = zone.offset_s(target_local_s + probe);
    if (std::find(offsets.begin(), offsets.end(), o) == offsets.end()) offsets.push_back(o);
  }
  std::optional<double> best;
  for (int o : offsets) {
    const double u = target_local_s - o;
    if (zone.offset_s(u) == o && (!best || u < *best)) best = u;
  }
  if (best) return *best;
  // A gap: bisect for the first instant whose local time passes the target.
  double lo = target_local_s - kDayS, hi = target_local_s + kDayS;
  while (hi - lo > 1.0) {
    const double mid = std::floor((lo + hi) / 2);
    if (local_s(mid, zone) >= target_local_s) {
      hi = mid;
    } else {
      lo = mid;
    }
  }
  return std::ceil(hi);
}

}  // namespace

Result<LocalTimeOfDay> parse_local_time_of_day(std::string_view text) {
  const auto digit = [](char c) { return c >= '0' && c <= '9'; };
  if (text.size() != 5 || text[2] != ':' || !digit(text[0]) || !digit(text[1]) || !digit(text[3]) ||
      !digit(text[4])) {
    return Error::Permanent(fmt::format("\"{}\" is not a local time HH:MM", text));
  }
  LocalTimeOfDay t;
  t.hour = (text[0] - '0') * 10 + (text[1] - '0');
  t.minute = (text[3] - '0') * 10 + (text[4] - '0');
  if (t.hour > 23 || t.minute > 59) {
    return Error::Permanent(
        fmt::format("\"{}\" is not a local time HH:MM (00:00 ... 23:59)", text));
  }
  return t;
}

TimeZone TimeZone::system_local() {
  return TimeZone("local", [](double unix_s) {
    const std::time_t t = static_cast<std::time_t>(std::floor(unix_s));
    std::tm tm{};
    if (localtime_r(&t, &tm) == nullptr) return 0;
    return static_cast<int>(tm.tm_gmtoff);
  });
}

namespace {

// Checks a POSIX TZ rule before Boost reads it (Boost's parser trusts its
// input and reads past the end of some malformed rules):
//   std offset [dst [offset] ,start[/time],end[/time]]
// names of >= 3 letters; offsets [+-]hh[:mm[:ss]], hh <= 24; start and end
// both Jn (1..365) or both Mm.w.d (m 1..12, w 1..5, d 0..6) — Boost reads
// the end in the start's form (it asserts on "M10.5.0,6") and mis-reads the
// zero-based n form, so neither a mix nor n is let through; times
// hh[:mm[:ss]], hh <= 24. A zone with DST must give its rule. Returns why
// the rule is not one, or "" when it is.
std::string posix_tz_problem(std::string_view r) {
  std::size_t i = 0;
  const auto number = [&](int max, int& out) {
    const std::size_t from = i;
    out = 0;
    while (i < r.size() && i - from < 3 && std::isdigit(static_cast<unsigned char>(r[i]))) {
      out = out * 10 + (r[i++] - '0');
    }
    return i > from && out <= max;
  };
  const auto name = [&] {
    const std::size_t from = i;
    while (i < r.size() && std::isalpha(static_cast<unsigned char>(r[i]))) ++i;
    return i - from >= 3;
  };
  const auto clock = [&](bool signed_ok) {
    if (signed_ok && i < r.size() && (r[i] == '+' || r[i] == '-')) ++i;
    int v = 0;
    if (!number(24, v)) return false;
    for (int part = 0; part < 2 && i < r.size() && r[i] == ':'; ++part) {
      ++i;
      if (i + 2 > r.size() || !std::isdigit(static_cast<unsigned char>(r[i])) ||
          !std::isdigit(static_cast<unsigned char>(r[i + 1]))) {
        return false;
      }
      if ((r[i] - '0') * 10 + (r[i + 1] - '0') > 59) return false;
      i += 2;
    }
    return true;
  };
  const auto date = [&](char form) {
    int a = 0, b = 0, c = 0;
    if (i >= r.size() || r[i] != form) return false;
    if (r[i] == 'J') {
      ++i;
      return number(365, a) && a >= 1;
    }
    ++i;
    if (!number(12, a) || a < 1 || i >= r.size() || r[i++] != '.') return false;
    if (!number(5, b) || b < 1 || i >= r.size() || r[i++] != '.') return false;
    return number(6, c);
  };
  const auto transition = [&](char form) {
    if (!date(form)) return false;
    if (i < r.size() && r[i] == '/') {
      ++i;
      return clock(false);
    }
    return true;
  };
  if (!name()) return "the standard zone name must be 3 or more letters";
  if (!clock(true)) return "the UTC offset after the name must be [+-]hh[:mm[:ss]], hh <= 24";
  if (i == r.size()) return "";
  if (!name()) return "the daylight-saving zone name must be 3 or more letters";
  if (i < r.size() && r[i] != ',' && !clock(true)) {
    return "the daylight-saving offset must be [+-]hh[:mm[:ss]], hh <= 24";
  }
  if (i == r.size() || r[i] != ',') {
    return "a zone with daylight saving needs its rule: ,start[/time],end[/time] (e.g. "
           ",M3.5.0,M10.5.0/3)";
  }
  ++i;
  const char form = i < r.size() && r[i] == 'J' ? 'J' : 'M';
  if (!transition(form)) return "the start of daylight saving must be Jn or Mm.w.d[/hh[:mm]]";
  if (i >= r.size() || r[i++] != ',') return "expected ',' before the end of daylight saving";
  if (!transition(form)) {
    return form == 'J' ? "the end of daylight saving must be Jn[/hh[:mm]], like its start"
                       : "the end of daylight saving must be Mm.w.d[/hh[:mm]], like its start";
  }
  if (i != r.size()) return "unexpected text after the rule";
  return "";
}

}  // namespace

Result<TimeZone> TimeZone::posix(const std::string& rule) {
  if (const std::string why = posix_tz_problem(rule); !why.empty()) {
    return Error::Permanent(fmt::format(
        "time zone \"{}\": not a POSIX TZ rule: {} (e.g. \"CET-1CEST,M3.5.0,M10.5.0/3\", "
        "\"UTC0\")",
        rule, why));
  }
  std::shared_ptr<boost::local_time::posix_time_zone> tz;
  try {
    tz = std::make_shared<boost::local_time::posix_time_zone>(rule);
  } catch (const std::exception& e) {
    return Error::Permanent(
        fmt::format("time zone \"{}\": not a POSIX TZ rule ({})", rule, e.what()));
  }
  return TimeZone(rule, [tz](double unix_s) {
    namespace pt = boost::posix_time;
    // Boost reads the offset east-positive ("CET+1"); a POSIX TZ rule, as in
    // the TZ variable, writes it west-positive ("CET-1"): flip it.
    const int base_s = -static_cast<int>(tz->base_utc_offset().total_seconds());
    if (!tz->has_dst()) return base_s;
    const int dst_s = static_cast<int>(tz->dst_offset().total_seconds());
    const pt::ptime epoch(boost::gregorian::date(1970, 1, 1));
    const auto standard_local =
        epoch + pt::seconds(static_cast<long>(std::floor(unix_s))) + pt::seconds(base_s);
    const auto year = standard_local.date().year();
    // DST starts at a local standard time and ends at a local daylight time.
    const double start_utc_s =
        static_cast<double>((tz->dst_local_start_time(year) - epoch).total_seconds()) - base_s;
    const double end_utc_s =
        static_cast<double>((tz->dst_local_end_time(year) - epoch).total_seconds()) - base_s -
        dst_s;
    const bool in_dst = start_utc_s < end_utc_s
                            ? (unix_s >= start_utc_s && unix_s < end_utc_s)   // northern
                            : (unix_s >= start_utc_s || unix_s < end_utc_s);  // southern
    return in_dst ? base_s + dst_s : base_s;
  });
}

TimeZone TimeZone::fixed(int offset_s) {
  return TimeZone(fmt::format("UTC{:+}s", offset_s), [offset_s](double) { return offset_s; });
}

double next_slot_unix_s(double after_unix_s, LocalTimeOfDay at, const TimeZone& zone) {
  // Local midnight of the local day of `after`, then that day's slot and the
  // following days' until one is strictly later.
  const double local_day_start = std::floor(local_s(after_unix_s, zone) / kDayS) * kDayS;
  for (int day = -1; day <= 3; ++day) {
    const double slot =
        first_instant_at_local(local_day_start + day * kDayS + at.seconds_of_day(), zone);
    if (slot > after_unix_s) return slot;
  }
  return after_unix_s + kDayS;  // not reached for any real zone
}

std::optional<double> due_slot_unix_s(std::optional<double> last_slot_unix_s, double since_unix_s,
                                      double now_unix_s, LocalTimeOfDay at, const TimeZone& zone) {
  double slot = next_slot_unix_s(last_slot_unix_s ? *last_slot_unix_s : since_unix_s, at, zone);
  if (slot > now_unix_s) return std::nullopt;
  // Skip to the latest slot not after now: one catch-up export, not one per night.
  for (;;) {
    const double next = next_slot_unix_s(slot, at, zone);
    if (next > now_unix_s) return slot;
    slot = next;
  }
}

}  // namespace gyrotherm::config
