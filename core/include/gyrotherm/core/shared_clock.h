// One station clock for a simulated station.
//
// A simulated station is two processes: gyrotherm-sim, which makes the
// plant, the table and every DUT's frames, and gyrothermd, which reads them.
// Each scaling wall time on its own makes two clocks: a simulator slowed by
// a busy machine lags the daemon's clock, a reader descheduled for a wall
// second stamps its backlog a time-scale's worth of station seconds late,
// and the samples land in the wrong windows.
//
// Here the simulator owns station time and publishes it in a small file
// that both processes map (`SharedClockOwner`); the daemon reads its station
// time from it (`SharedStationClock`). The daemon's consumers (its control
// loop, each DUT reader) report how far they have consumed, and the owner
// never runs more than the daemon's lead past the slowest of them. A slow
// machine makes a campaign take longer in wall time, never wrong; a stopped
// daemon stops station time; a dead one (its pid gone) lets the simulator
// run on alone, as a real plant would.
//
// The page holds lock-free 64-bit atomics only (times in station
// nanoseconds); waits use a futex on a shared 32-bit sequence word with a
// bounded timeout, so neither side ever blocks forever on the other.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "gyrotherm/core/paced_clock.h"
#include "gyrotherm/core/result.h"

namespace gyrotherm {

struct SharedClockPage;

// At most this many consumers (the control loop and up to 8 DUT readers,
// with room to spare).
inline constexpr int kSharedClockSlots = 16;

// The mapping of one clock file, as either side sees it.
class SharedClockMap {
 public:
  ~SharedClockMap();
  SharedClockMap(const SharedClockMap&) = delete;
  SharedClockMap& operator=(const SharedClockMap&) = delete;

  SharedClockPage& page() const { return *page_; }
  const std::string& path() const { return path_; }

  // Creates (or truncates) `path` and maps it: a new clock at `start_s`,
  // with a new random epoch. Permanent error naming the path when the file
  // cannot be made.
  static Result<std::unique_ptr<SharedClockMap>> create(const std::string& path, double time_scale,
                                                        double start_s);
  // Maps an existing clock file. Permanent error naming the path when it is
  // missing, too short or not a clock file of this version.
  static Result<std::unique_ptr<SharedClockMap>> open(const std::string& path);

 private:
  SharedClockMap(std::string path, SharedClockPage* page) : path_(std::move(path)), page_(page) {}
  std::string path_;
  SharedClockPage* page_;
};

// What the daemon's side reads of the owner's page, for status and tests.
struct SharedClockReading {
  double t_s = 0;         // station time the owner published
  double time_scale = 0;  // the owner's nominal station seconds per wall second
  uint64_t epoch = 0;     // random, new with each owner
  long owner_pid = 0;
  long consumer_pid = 0;  // 0: no consumer attached
  double consumed_s = 0;  // the slowest attached consumer's mark (NaN: none)
  double lead_s = 0;      // how far past it the owner may run
};
SharedClockReading read_shared_clock(const SharedClockMap& map);

// The simulator's side: it publishes station time and asks how far it may
// go.
class SharedClockOwner {
 public:
  explicit SharedClockOwner(std::unique_ptr<SharedClockMap> map);
  ~SharedClockOwner();

  // Station time `t_s` is published: every stream the owner makes is
  // complete up to it. Monotonic (an earlier time is ignored). Wakes waiters.
  void publish(double t_s);
  double published_s() const;

  // How far the owner may advance now: +inf with no live consumer (none
  // attached, or its pid gone: then it is detached), else the slowest
  // consumer's mark plus its lead. A consumer that attached but has not
  // marked yet holds the clock where it attached.
  double limit_s();
  // Waits up to `max_wall` for any consumer's mark or attach (futex) since
  // the last limit_s(): none is missed between the two.
  void wait_for_consumers(std::chrono::nanoseconds max_wall) const;
  bool consumer_attached() const;

  const std::string& path() const { return map_->path(); }

 private:
  std::unique_ptr<SharedClockMap> map_;
  uint32_t seen_consumer_seq_ = 0;
};

// The daemon's side: a Clock whose station time is the owner's. Its
// consumer() slots pace the owner.
class SharedStationClock final : public PacedClock {
 public:
  // Attaches this process as the consumer (replacing any earlier one),
  // allowing the owner `lead_s` station seconds past the slowest mark.
  SharedStationClock(std::unique_ptr<SharedClockMap> map, double lead_s);
  ~SharedStationClock() override;  // detaches

  double now_s() const override;
  double time_scale() const override;
  std::unique_ptr<ClockConsumer> consumer(std::string_view name) const override;
  bool wait_until(double t_s, std::chrono::nanoseconds max_wall) const override;
  uint64_t epoch() const override;

  SharedClockReading reading() const { return read_shared_clock(*map_); }
  // True once the owner has gone (its pid gone, or it left): from then on
  // station time runs on from the owner's last time at its scale on this
  // process's steady clock, so a daemon whose simulator died keeps its
  // clock (and notices its devices gone) instead of freezing.
  bool orphaned() const;

 private:
  std::unique_ptr<SharedClockMap> map_;
  mutable std::mutex slots_mu_;
  struct Orphaned {
    double t_s;                                // the owner's last time
    std::chrono::steady_clock::time_point at;  // when it was found gone
  };
  mutable std::mutex orphan_mu_;  // below
  mutable std::optional<Orphaned> orphaned_;
  mutable std::chrono::steady_clock::time_point next_owner_check_{};
};

}  // namespace gyrotherm
