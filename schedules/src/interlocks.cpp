#include "gyrotherm/schedules/interlocks.h"

#include <fmt/format.h>

#include <cmath>

namespace gyrotherm::schedules {

std::string_view to_string(InterlockKind kind) {
  switch (kind) {
    case InterlockKind::kOutOfLimits:
      return "out_of_limits";
    case InterlockKind::kProbeDisagreement:
      return "probe_disagreement";
    case InterlockKind::kSettleTimeout:
      return "settle_timeout";
    case InterlockKind::kChamberSilent:
      return "chamber_silent";
    case InterlockKind::kProbesSilent:
      return "probes_silent";
    case InterlockKind::kGyroLost:
      return "gyro_lost";
    case InterlockKind::kChamberAlarm:
      return "chamber_alarm";
    case InterlockKind::kStorageFailing:
      return "storage_failing";
  }
  return "?";
}

std::optional<InterlockKind> parse_interlock_kind(std::string_view name) {
  for (int k = 0; k < kInterlockKindCount; ++k) {
    if (to_string(static_cast<InterlockKind>(k)) == name) return static_cast<InterlockKind>(k);
  }
  return std::nullopt;
}

bool readings_can_clear(InterlockKind kind, const Readings& r) {
  const bool probes = r.top_c && r.side_c;
  switch (kind) {
    case InterlockKind::kOutOfLimits:
      return r.chamber_c && probes;
    case InterlockKind::kProbeDisagreement:
    case InterlockKind::kProbesSilent:
      return probes;
    case InterlockKind::kChamberSilent:
    case InterlockKind::kChamberAlarm:
      return r.chamber_c.has_value();
    case InterlockKind::kGyroLost:
      return r.gyro_heard;
    case InterlockKind::kStorageFailing:
      return r.storage_committed;
    case InterlockKind::kSettleTimeout:
      return false;
  }
  return false;
}

std::vector<InterlockCondition> evaluate_interlocks(const Readings& r, const InterlockOptions& o,
                                                    const bool (&tripped)[kInterlockKindCount]) {
  auto was = [&](InterlockKind k) { return tripped[static_cast<int>(k)]; };
  std::vector<InterlockCondition> out;

  {
    // Once tripped, a temperature must come back hysteresis_c inside the
    // limit band before the condition clears.
    const double inset = was(InterlockKind::kOutOfLimits) ? o.hysteresis_c : 0.0;
    const double lo = o.min_temp_c - o.limit_margin_c + inset;
    const double hi = o.max_temp_c + o.limit_margin_c - inset;
    std::string what;
    for (auto [name, value] :
         {std::pair{"chamber air", r.chamber_c}, std::pair{"top probe", r.top_c},
          std::pair{"side probe", r.side_c}}) {
      if (value && (*value < lo || *value > hi || !std::isfinite(*value))) {
        what += fmt::format("{}{} {:.2f} °C", what.empty() ? "" : ", ", name, *value);
      }
    }
    if (!what.empty()) {
      out.push_back({InterlockKind::kOutOfLimits,
                     fmt::format("{} outside the station limits {:g} … {:g} °C (± {:g} °C margin)",
                                 what, o.min_temp_c, o.max_temp_c, o.limit_margin_c)});
    }
  }
  if (r.top_c && r.side_c) {
    const double limit =
        o.probe_disagreement_c - (was(InterlockKind::kProbeDisagreement) ? o.hysteresis_c : 0.0);
    const double diff = *r.top_c - *r.side_c;
    if (std::abs(diff) > limit) {
      out.push_back({InterlockKind::kProbeDisagreement,
                     fmt::format("top {:.2f} °C and side {:.2f} °C probes disagree by {:.2f} °C "
                                 "(limit {:g} °C)",
                                 *r.top_c, *r.side_c, std::abs(diff), o.probe_disagreement_c)});
    }
  }
  auto silent = [&](InterlockKind kind, double silent_s, double timeout_s, const char* what) {
    if (silent_s > timeout_s) {
      out.push_back({kind, fmt::format("{} silent for {:.0f} s (timeout {:g} s)", what, silent_s,
                                       timeout_s)});
    }
  };
  silent(InterlockKind::kChamberSilent, r.chamber_silent_s, o.chamber_timeout_s,
         "chamber controller");
  silent(InterlockKind::kProbesSilent, r.probes_silent_s, o.probes_timeout_s, "probe module");
  silent(InterlockKind::kGyroLost, r.gyro_silent_s, o.gyro_timeout_s, "gyro stream");
  if (r.chamber_alarm) {
    out.push_back({InterlockKind::kChamberAlarm, "the chamber controller reports an alarm"});
  }
  if (r.storage_failing_s > o.storage_timeout_s) {
    out.push_back({InterlockKind::kStorageFailing,
                   fmt::format("storage failing for {:.0f} s (timeout {:g} s): {}; acquisition "
                               "suspended, {} samples held in memory until commits succeed",
                               r.storage_failing_s, o.storage_timeout_s,
                               r.storage_error.empty() ? "commits fail" : r.storage_error,
                               r.storage_pending)});
  }
  return out;
}

}  // namespace gyrotherm::schedules
