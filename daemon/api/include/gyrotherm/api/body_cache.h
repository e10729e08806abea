// A rendered response body that many readers share for a short while: the
// status and the metrics are built from the station's snapshot at most once
// per `max_age_s` of real time, whatever the request rate, so a client never
// pays for (or waits on) building them under load (the approach of EPICS
// asyn's parameter library: clients read a snapshot, not the devices).
//
// Freshness: a body is at most max_age_s old, except after invalidate(),
// which makes the next get() render anew: the API invalidates the status at
// every request that changes something, so a client that changed something
// reads a status rendered after its change.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>

#include "gyrotherm/core/clock.h"

namespace gyrotherm::api {

class BodyCache {
 public:
  // `render` is called from the readers' threads, one at a time.
  // `wall` measures the body's age (monotonic_s()); it must outlive the cache.
  BodyCache(std::function<std::string()> render, double max_age_s,
            const WallClock& wall = system_wall_clock());

  // The body: the kept one while it is younger than max_age_s and nothing
  // invalidated it; else one rendered now. While one reader renders a body
  // that has merely aged, the others get the aged one rather than wait
  // (it is older than max_age_s by at most one rendering); after
  // invalidate() nobody gets a body rendered before it.
  std::shared_ptr<const std::string> get();
  void invalidate();

  // How many times render was called (for tests and the benchmark).
  uint64_t renders() const;

 private:
  bool fresh() const;  // mu_ held

  std::function<std::string()> render_;
  double max_age_s_;
  const WallClock& wall_;
  mutable std::mutex mu_;
  std::mutex render_mu_;  // one rendering at a time, taken before mu_
  std::shared_ptr<const std::string> body_;
  double rendered_at_s_ = 0;
  uint64_t generation_ = 0;       // bumped by invalidate()
  uint64_t body_generation_ = 0;  // the generation body_ was rendered in
  bool rendering_ = false;
  uint64_t renders_ = 0;
};

}  // namespace gyrotherm::api
