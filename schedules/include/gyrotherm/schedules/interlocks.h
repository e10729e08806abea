// Interlocks (docs/schedules.md, "Interlocks"; docs/api.md, "Interlock kinds"): conditions under
// which a run must not go on.
//
// Each tick the sequencer evaluates the readings against these limits. A
// tripped interlock suspends the run (the set point is held, the acquisition
// clock stops); the run resumes by itself once every interlock has cleared,
// and aborts to the safe state when one stays tripped beyond its grace
// period. A condition clears only past a small hysteresis, so a reading that
// sits on a limit does not flood the event log.
//
// evaluate_interlocks() is a pure function of the readings, so each
// condition is tested on its own; the settle timeout is the sequencer's
// (it depends on the step).
//
// Every interlock is one row of kInterlockDefinitions: its name, default
// grace, check and clear rule; the functions below only look the table up.
// To add one: an enumerator at the end of InterlockKind, its check in
// interlocks.cpp (declared in interlock_checks), a row at the end of the
// table, and a row in the interlock tests (tests/schedules/). A row out of
// the enum's order, or a duplicate name, does not compile; the name is the
// user's (events, REST, `<name>_grace_min` in [interlocks]), so it never
// changes once released.
#pragma once

#include <array>
#include <cstddef>
#include <functional>
#include <iterator>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace gyrotherm::schedules {

enum class InterlockKind {
  kOutOfLimits,        // chamber air or a shell probe outside the station limits + margin
  kProbeDisagreement,  // |top − side| beyond the limit
  kSettleTimeout,      // a soak's gate did not hold within its settle timeout
  kChamberSilent,      // no good chamber reading for longer than its timeout
  kProbesSilent,       // no good probe reading for longer than its timeout
  kGyroLost,           // no gyro sample for longer than its timeout
  kChamberAlarm,       // the controller reports an alarm
  kStorageFailing,     // samples cannot be committed (disk full, I/O error) for too long
  kTableFault,         // the rate table's interlock is in fault (over-speed, a safety input)
  kTableSilent,        // no good rate-table reading for longer than its timeout
};

// One control-loop reading; nullopt where the device gave no value this tick.
// The *_silent_s fields are station seconds since the device's last good
// value (0 when it answered this tick).
struct Readings {
  std::optional<double> chamber_c;
  std::optional<double> top_c;
  std::optional<double> side_c;
  double chamber_silent_s = 0;
  double probes_silent_s = 0;
  double gyro_silent_s = 0;                 // the most silent DUT's
  std::string gyro_stream = "gyro stream";  // which: "DUT 17-0042 stream" with several
  bool chamber_alarm = false;
  // Station seconds the sample writer's commits have been failing (0 while
  // they succeed), with the last error and the samples held in memory.
  double storage_failing_s = 0;
  std::string storage_error{};
  std::size_t storage_pending = 0;
  // Whether a gyro sample has arrived, and a sample commit succeeded, since
  // the daemon started. Until then gyro_silent_s and storage_failing_s only
  // count from the start, so they cannot tell that a trip restored from a
  // checkpoint is over.
  bool gyro_heard = true;
  bool storage_committed = true;
  // The rate table (when the station has one: table_present).
  bool table_present = false;
  std::optional<double> table_rate_dps{};      // measured
  std::optional<double> table_position_deg{};  // measured
  bool table_fault = false;                    // interlock in fault
  std::string table_fault_text{};              // what the controller says
  double table_silent_s = 0;
  // Data accounting of a soak's acquisition (the daemon sets both; unset:
  // the clock is credited). Run seconds that every required DUT's samples
  // cover in [from_s, to_s); the earliest end at which every required DUT's
  // samples cover need_s from from_s (nullopt: not yet). coverage.h.
  std::function<double(double from_s, double to_s)> data_covered_s{};
  std::function<std::optional<double>(double from_s, double need_s)> data_reached_at_s{};
  // An adaptive soak (PlanStep::adaptive) may end now: the station's verdict
  // on every gated DUT axis of the data so far, why (target reached or out of
  // reach). The sequencer ends the acquisition once min_s is acquired.
  std::optional<std::string> acquisition_done{};
};

struct InterlockOptions;

// The checks of the table's rows (interlocks.cpp). Each returns the message a
// technician reads when its condition holds now; `tripped` tells that the
// interlock is already tripped, so a temperature condition clears only past
// the hysteresis.
namespace interlock_checks {
using Check = std::optional<std::string> (*)(const Readings&, const InterlockOptions&,
                                             bool tripped);
std::optional<std::string> out_of_limits(const Readings&, const InterlockOptions&, bool tripped);
std::optional<std::string> probe_disagreement(const Readings&, const InterlockOptions&,
                                              bool tripped);
std::optional<std::string> chamber_silent(const Readings&, const InterlockOptions&, bool tripped);
std::optional<std::string> probes_silent(const Readings&, const InterlockOptions&, bool tripped);
std::optional<std::string> gyro_lost(const Readings&, const InterlockOptions&, bool tripped);
std::optional<std::string> chamber_alarm(const Readings&, const InterlockOptions&, bool tripped);
std::optional<std::string> storage_failing(const Readings&, const InterlockOptions&, bool tripped);
std::optional<std::string> table_fault(const Readings&, const InterlockOptions&, bool tripped);
std::optional<std::string> table_silent(const Readings&, const InterlockOptions&, bool tripped);
}  // namespace interlock_checks

struct InterlockDefinition {
  InterlockKind kind;
  std::string_view name;     // in events, REST and `<name>_grace_min`: never renamed
  double default_grace_min;  // tripped this long, the run is aborted
  // nullptr: not a condition of the readings (settle_timeout: the sequencer
  // trips it from the step's clock).
  interlock_checks::Check check;
  // Whether the readings can show that the condition is over (see
  // readings_can_clear).
  bool (*can_clear)(const Readings&);
};

// How many times a run's station resets a latched table fault by itself
// (table_fault): once the axis is at rest, each an event.
inline constexpr int kTableFaultResets = 3;

// One row per InterlockKind, in the enum's order.
inline constexpr InterlockDefinition kInterlockDefinitions[] = {
    {InterlockKind::kOutOfLimits, "out_of_limits", 5, &interlock_checks::out_of_limits,
     [](const Readings& r) { return r.chamber_c && r.top_c && r.side_c; }},
    {InterlockKind::kProbeDisagreement, "probe_disagreement", 30,
     &interlock_checks::probe_disagreement, [](const Readings& r) { return r.top_c && r.side_c; }},
    // Cleared by the stability gate only.
    {InterlockKind::kSettleTimeout, "settle_timeout", 60, nullptr,
     [](const Readings&) { return false; }},
    {InterlockKind::kChamberSilent, "chamber_silent", 30, &interlock_checks::chamber_silent,
     [](const Readings& r) { return r.chamber_c.has_value(); }},
    {InterlockKind::kProbesSilent, "probes_silent", 30, &interlock_checks::probes_silent,
     [](const Readings& r) { return r.top_c && r.side_c; }},
    {InterlockKind::kGyroLost, "gyro_lost", 30, &interlock_checks::gyro_lost,
     [](const Readings& r) { return r.gyro_heard; }},
    // The station reads the alarm register only with the air temperature.
    {InterlockKind::kChamberAlarm, "chamber_alarm", 10, &interlock_checks::chamber_alarm,
     [](const Readings& r) { return r.chamber_c.has_value(); }},
    {InterlockKind::kStorageFailing, "storage_failing", 60, &interlock_checks::storage_failing,
     [](const Readings& r) { return r.storage_committed; }},
    // A fault is latched by the controller: the station resets it (ACL :I:R)
    // while the run is held, at most kTableFaultResets times a run, so a
    // cleared reading shows the cause is gone.
    {InterlockKind::kTableFault, "table_fault", 5, &interlock_checks::table_fault,
     [](const Readings& r) { return r.table_rate_dps.has_value(); }},
    {InterlockKind::kTableSilent, "table_silent", 5, &interlock_checks::table_silent,
     [](const Readings& r) { return r.table_rate_dps.has_value(); }},
};
inline constexpr int kInterlockKindCount = static_cast<int>(std::size(kInterlockDefinitions));

namespace interlock_table {
// Row k defines the kind whose value is k, so the table can be indexed by
// kind: a missing or swapped row fails here.
constexpr bool in_enum_order() {
  for (int k = 0; k < kInterlockKindCount; ++k) {
    if (static_cast<int>(kInterlockDefinitions[k].kind) != k) return false;
  }
  return true;
}
// Names are config keys and parsed back from events and checkpoints.
constexpr bool names_unique() {
  for (int a = 0; a < kInterlockKindCount; ++a) {
    if (kInterlockDefinitions[a].name.empty()) return false;
    for (int b = a + 1; b < kInterlockKindCount; ++b) {
      if (kInterlockDefinitions[a].name == kInterlockDefinitions[b].name) return false;
    }
  }
  return true;
}
constexpr std::array<double, kInterlockKindCount> default_grace_s() {
  std::array<double, kInterlockKindCount> out{};
  for (int k = 0; k < kInterlockKindCount; ++k) {
    out[k] = 60.0 * kInterlockDefinitions[k].default_grace_min;
  }
  return out;
}
}  // namespace interlock_table
static_assert(interlock_table::in_enum_order(),
              "kInterlockDefinitions: one row per InterlockKind, in the enum's order");
static_assert(interlock_table::names_unique(),
              "kInterlockDefinitions: every interlock needs its own non-empty name");

std::string_view to_string(InterlockKind kind);
std::optional<InterlockKind> parse_interlock_kind(std::string_view name);

struct InterlockOptions {
  double min_temp_c = -20.0;
  double max_temp_c = 60.0;
  double limit_margin_c = 2.0;
  double probe_disagreement_c = 2.0;
  double hysteresis_c = 0.2;  // a temperature condition clears this far inside its limit
  double chamber_timeout_s = 10.0;
  double probes_timeout_s = 10.0;
  double gyro_timeout_s = 5.0;
  double storage_timeout_s = 10.0;
  double table_timeout_s = 10.0;
  // Station seconds an interlock may stay tripped before the run is aborted
  // to the safe state; indexed by InterlockKind. 0 aborts at once.
  std::array<double, kInterlockKindCount> grace_s = interlock_table::default_grace_s();

  double grace_for(InterlockKind kind) const { return grace_s[static_cast<int>(kind)]; }

  // False with a message naming the field and its bound when a value is out
  // of range: min_temp_c not below max_temp_c, a margin or the hysteresis
  // negative, the probe limit or a device timeout not positive, hysteresis_c
  // not below probe_disagreement_c (a disagreement would never clear), a
  // grace negative; any of them not finite.
  bool is_valid(std::string* why) const;
};

struct InterlockCondition {
  InterlockKind kind;
  std::string message;  // what a technician reads, with the values
};

// Whether `readings` can show that a tripped interlock's condition is over.
// A tick without the readings a condition depends on (a device silent, a
// daemon just restarted) does not clear it, so the grace of a fault that
// persists runs on. The chamber alarm is judged with a chamber reading (the
// station reads the alarm register only with the air temperature). The
// settle timeout is cleared by the stability gate only: never here.
bool readings_can_clear(InterlockKind kind, const Readings& readings);

// The conditions that hold now. `tripped` tells which kinds are already
// tripped: those clear only past the hysteresis. The settle timeout is
// never returned here.
std::vector<InterlockCondition> evaluate_interlocks(const Readings& readings,
                                                    const InterlockOptions& options,
                                                    const bool (&tripped)[kInterlockKindCount]);

}  // namespace gyrotherm::schedules
