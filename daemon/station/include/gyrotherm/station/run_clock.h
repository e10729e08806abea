// RunClock: the current run's id and the station time it started, published
// together by the Station's control thread and read together by the gyro
// reader thread, so a sample batch is stored under a run and timed from that
// same run's start, never from the previous run's. (Two separate atomics
// would not do: a reader between the two stores sees the new run with the
// old start.) A mutex, held for two words, or for the handing over of one
// batch (with_samples_run).
//
// When a run ends, close_samples() stops sample batches being stored under
// it while the control thread still reads its id and start: once it returns,
// no batch is still on its way to the writer under that run, so a writer
// flush after it holds every sample the run will ever have.
#pragma once

#include <cstdint>
#include <mutex>

namespace gyrotherm::station {

class RunClock {
 public:
  struct Value {
    int64_t run_id = 0;  // 0: no run
    double t0_s = 0;     // station time of the run's t_s = 0
  };
  void publish(int64_t run_id, double t0_s) {
    std::lock_guard lock(mu_);
    value_ = {run_id, t0_s};
    samples_closed_ = false;
  }
  // From now until the next publish, with_samples_run sees no run.
  void close_samples() {
    std::lock_guard lock(mu_);
    samples_closed_ = true;
  }
  // Calls `store(value)` with the run that samples arriving now belong to
  // (run_id 0: none), holding the lock so close_samples waits for it.
  template <class Store>
  void with_samples_run(Store&& store) const {
    std::lock_guard lock(mu_);
    store(samples_closed_ ? Value{} : value_);
  }
  Value load() const {
    std::lock_guard lock(mu_);
    return value_;
  }

 private:
  mutable std::mutex mu_;
  Value value_;
  bool samples_closed_ = false;
};

}  // namespace gyrotherm::station
