// A station clock that is paced by its consumers.
//
// Most clocks run on their own (ScaledClock, ManualClock). A PacedClock's
// station time is owned elsewhere (a simulator's shared clock,
// shared_clock.h) and waits for the parts of this process that consume
// what happens in it: the control loop and each DUT reader take a
// ClockConsumer and mark how far they have consumed; the owner never runs
// more than a lead past the slowest mark. Code that takes a `const Clock&`
// asks for the capability with as_paced().
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string_view>

#include "gyrotherm/core/clock.h"

namespace gyrotherm {

// One consumer's slot. Thread-compatible (one thread marks it).
class ClockConsumer {
 public:
  virtual ~ClockConsumer() = default;  // releases the slot: it no longer holds the clock
  // Everything up to station time `t_s` has been consumed.
  virtual void consumed(double t_s) = 0;
};

class PacedClock : public Clock {
 public:
  // A slot named `name` (for status and logs); null when none is left.
  virtual std::unique_ptr<ClockConsumer> consumer(std::string_view name) const = 0;
  // Waits until station time reaches `t_s` or `max_wall` passed; true when
  // it was reached.
  virtual bool wait_until(double t_s, std::chrono::nanoseconds max_wall) const = 0;
  // Random, new with each owner: station times from two clocks with the same
  // epoch are on one time line (across restarts of this process).
  virtual uint64_t epoch() const = 0;
};

// The clock's PacedClock side, or null for a clock that runs on its own.
inline const PacedClock* as_paced(const Clock& clock) {
  return dynamic_cast<const PacedClock*>(&clock);
}

}  // namespace gyrotherm
