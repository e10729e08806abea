// RunClock: the current run's id and the station time it started, published
// together by the Station's control thread and read together by the gyro
// reader thread, so a sample batch is stored under a run and timed from that
// same run's start, never from the previous run's. (Two separate atomics
// would not do: a reader between the two stores sees the new run with the
// old start.) A mutex, held for two words.
#pragma once

#include <cstdint>
#include <mutex>

namespace gyrotherm::daemon {

class RunClock {
 public:
  struct Value {
    int64_t run_id = 0;  // 0: no run
    double t0_s = 0;     // station time of the run's t_s = 0
  };
  void publish(int64_t run_id, double t0_s) {
    std::lock_guard lock(mu_);
    value_ = {run_id, t0_s};
  }
  Value load() const {
    std::lock_guard lock(mu_);
    return value_;
  }

 private:
  mutable std::mutex mu_;
  Value value_;
};

}  // namespace gyrotherm::daemon
