#include "gyrotherm/schedules/interlocks.h"

#include <fmt/format.h>

#include <cmath>
#include <utility>

namespace gyrotherm::schedules {

namespace interlock_checks {

std::optional<std::string> out_of_limits(const Readings& r, const InterlockOptions& o,
                                         bool tripped) {
  // Once tripped, a temperature must come back hysteresis_c inside the
  // limit band before the condition clears.
  const double inset = tripped ? o.hysteresis_c : 0.0;
  const double lo = o.min_temp_c - o.limit_margin_c + inset;
  const double hi = o.max_temp_c + o.limit_margin_c - inset;
  std::string what;
  for (auto [name, value] : {std::pair{"chamber air", r.chamber_c}, std::pair{"top probe", r.top_c},
                             std::pair{"side probe", r.side_c}}) {
    if (value && (*value < lo || *value > hi || !std::isfinite(*value))) {
      what += fmt::format("{}{} {:.2f} °C", what.empty() ? "" : ", ", name, *value);
    }
  }
  if (what.empty()) return std::nullopt;
  return fmt::format("{} outside the station limits {:g} … {:g} °C (± {:g} °C margin)", what,
                     o.min_temp_c, o.max_temp_c, o.limit_margin_c);
}

std::optional<std::string> probe_disagreement(const Readings& r, const InterlockOptions& o,
                                              bool tripped) {
  if (!r.top_c || !r.side_c) return std::nullopt;
  const double limit_c = o.probe_disagreement_c - (tripped ? o.hysteresis_c : 0.0);
  const double diff_c = *r.top_c - *r.side_c;
  // Written as "trips when beyond", so a NaN difference does not trip.
  if (std::abs(diff_c) > limit_c) {
    return fmt::format(
        "top {:.2f} °C and side {:.2f} °C probes disagree by {:.2f} °C (limit {:g} °C)", *r.top_c,
        *r.side_c, std::abs(diff_c), o.probe_disagreement_c);
  }
  return std::nullopt;
}

namespace {
std::optional<std::string> silent(double silent_s, double timeout_s, std::string_view what) {
  if (silent_s > timeout_s) {
    return fmt::format("{} silent for {:.0f} s (timeout {:g} s)", what, silent_s, timeout_s);
  }
  return std::nullopt;
}
}  // namespace

std::optional<std::string> chamber_silent(const Readings& r, const InterlockOptions& o, bool) {
  return silent(r.chamber_silent_s, o.chamber_timeout_s, "chamber controller");
}

std::optional<std::string> probes_silent(const Readings& r, const InterlockOptions& o, bool) {
  return silent(r.probes_silent_s, o.probes_timeout_s, "probe module");
}

std::optional<std::string> gyro_lost(const Readings& r, const InterlockOptions& o, bool) {
  return silent(r.gyro_silent_s, o.gyro_timeout_s, r.gyro_stream);
}

std::optional<std::string> chamber_alarm(const Readings& r, const InterlockOptions&, bool) {
  if (!r.chamber_alarm) return std::nullopt;
  return "the chamber controller reports an alarm";
}

std::optional<std::string> storage_failing(const Readings& r, const InterlockOptions& o, bool) {
  if (r.storage_failing_s > o.storage_timeout_s) {
    return fmt::format(
        "storage failing for {:.0f} s (timeout {:g} s): {}; acquisition suspended, {} samples "
        "held in memory until commits succeed",
        r.storage_failing_s, o.storage_timeout_s,
        r.storage_error.empty() ? "commits fail" : r.storage_error, r.storage_pending);
  }
  return std::nullopt;
}

std::optional<std::string> table_fault(const Readings& r, const InterlockOptions&, bool) {
  if (!r.table_present || !r.table_fault) return std::nullopt;
  return fmt::format(
      "the rate table's interlock is in fault{}{}; the station resets it once the table is at "
      "rest (at most {} times); if the fault stays, clear its cause at the table and run "
      "`gyrotherm table reset`",
      r.table_fault_text.empty() ? "" : ": ", r.table_fault_text, kTableFaultResets);
}

std::optional<std::string> table_silent(const Readings& r, const InterlockOptions& o, bool) {
  if (!r.table_present) return std::nullopt;
  return silent(r.table_silent_s, o.table_timeout_s, "rate table controller");
}

}  // namespace interlock_checks

namespace {
// The row of `kind`, or nullptr for a value outside the enum (a cast from a
// number).
const InterlockDefinition* definition(InterlockKind kind) {
  const int k = static_cast<int>(kind);
  if (k < 0 || k >= kInterlockKindCount) return nullptr;
  return &kInterlockDefinitions[k];
}
}  // namespace

std::string_view to_string(InterlockKind kind) {
  const InterlockDefinition* d = definition(kind);
  return d ? d->name : "?";
}

std::optional<InterlockKind> parse_interlock_kind(std::string_view name) {
  for (const InterlockDefinition& d : kInterlockDefinitions) {
    if (d.name == name) return d.kind;
  }
  return std::nullopt;
}

bool InterlockOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  for (const auto& [name, value] :
       {std::pair{"min_temp_c", min_temp_c}, std::pair{"max_temp_c", max_temp_c}}) {
    if (!std::isfinite(value)) return fail(fmt::format("{} = {} must be finite", name, value));
  }
  if (!(min_temp_c < max_temp_c)) {
    return fail(
        fmt::format("max_temp_c = {} must be above min_temp_c = {}", max_temp_c, min_temp_c));
  }
  // A margin or hysteresis of 0 is a sharp limit; a limit or timeout of 0
  // would trip at every reading.
  for (const auto& [name, value] :
       {std::pair{"limit_margin_c", limit_margin_c}, std::pair{"hysteresis_c", hysteresis_c}}) {
    if (!(value >= 0) || !std::isfinite(value)) {
      return fail(fmt::format("{} = {} must be finite and >= 0", name, value));
    }
  }
  for (const auto& [name, value] : {std::pair{"probe_disagreement_c", probe_disagreement_c},
                                    std::pair{"chamber_timeout_s", chamber_timeout_s},
                                    std::pair{"probes_timeout_s", probes_timeout_s},
                                    std::pair{"gyro_timeout_s", gyro_timeout_s},
                                    std::pair{"storage_timeout_s", storage_timeout_s},
                                    std::pair{"table_timeout_s", table_timeout_s}}) {
    if (!(value > 0) || !std::isfinite(value)) {
      return fail(fmt::format("{} = {} must be finite and > 0", name, value));
    }
  }
  // A tripped disagreement clears below probe_disagreement_c - hysteresis_c:
  // at or below 0 it never would.
  if (!(hysteresis_c < probe_disagreement_c)) {
    return fail(fmt::format("hysteresis_c = {} must be below probe_disagreement_c = {}",
                            hysteresis_c, probe_disagreement_c));
  }
  for (const InterlockDefinition& d : kInterlockDefinitions) {
    const double grace = grace_for(d.kind);
    if (!(grace >= 0) || !std::isfinite(grace)) {
      return fail(fmt::format("grace_s[{}] = {} must be finite and >= 0", d.name, grace));
    }
  }
  return true;
}

bool readings_can_clear(InterlockKind kind, const Readings& r) {
  const InterlockDefinition* d = definition(kind);
  return d && d->can_clear(r);
}

std::vector<InterlockCondition> evaluate_interlocks(const Readings& r, const InterlockOptions& o,
                                                    const bool (&tripped)[kInterlockKindCount]) {
  std::vector<InterlockCondition> out;
  for (const InterlockDefinition& d : kInterlockDefinitions) {
    if (!d.check) continue;  // tripped by the sequencer
    if (auto message = d.check(r, o, tripped[static_cast<int>(d.kind)])) {
      out.push_back({d.kind, std::move(*message)});
    }
  }
  return out;
}

}  // namespace gyrotherm::schedules
