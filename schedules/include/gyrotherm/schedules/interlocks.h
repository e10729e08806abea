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
#pragma once

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
};
inline constexpr int kInterlockKindCount = 8;
std::string_view to_string(InterlockKind kind);
std::optional<InterlockKind> parse_interlock_kind(std::string_view name);

// One control-loop reading; nullopt where the device gave no value this tick.
// The *_silent_s fields are station seconds since the device's last good
// value (0 when it answered this tick).
struct Readings {
  std::optional<double> chamber_c;
  std::optional<double> top_c;
  std::optional<double> side_c;
  double chamber_silent_s = 0;
  double probes_silent_s = 0;
  double gyro_silent_s = 0;
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
};

struct InterlockOptions {
  double min_temp_c = -20.0;  // station limits
  double max_temp_c = 60.0;
  double limit_margin_c = 2.0;
  double probe_disagreement_c = 2.0;
  double hysteresis_c = 0.2;  // a temperature condition clears this far inside its limit
  double chamber_timeout_s = 10.0;
  double probes_timeout_s = 10.0;
  double gyro_timeout_s = 5.0;
  double storage_timeout_s = 10.0;
  // Station seconds an interlock may stay tripped before the run is aborted
  // to the safe state; indexed by InterlockKind. 0 aborts at once.
  double grace_s[kInterlockKindCount] = {300, 1800, 3600, 1800, 1800, 1800, 600, 3600};

  double grace_for(InterlockKind kind) const { return grace_s[static_cast<int>(kind)]; }
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
