// RunClock: the run id and its start time are read as one pair while the
// control thread publishes new runs.
#include "gyrotherm/daemon/run_clock.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>

namespace gyrotherm::daemon {
namespace {

// Run k starts at station time 10·k: a reader must never see run k with
// another run's start (a batch of samples timed against the previous run).
TEST(RunClock, IdAndStartTimeAreReadTogether) {
  RunClock clock;
  std::atomic<bool> stop{false};
  std::atomic<int64_t> reads{0}, torn{0}, runs_seen{0};
  std::thread reader([&] {
    int64_t last = 0;
    while (!stop.load(std::memory_order_relaxed)) {
      const RunClock::Value v = clock.load();
      if (v.t0_s != 10.0 * static_cast<double>(v.run_id)) ++torn;
      if (v.run_id != last) ++runs_seen;
      last = v.run_id;
      ++reads;
    }
  });
  // Bounded in wall time; long enough for the two threads to overlap on a
  // loaded machine many times over.
  const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(1500);
  int64_t run = 0;
  while (std::chrono::steady_clock::now() < end) {
    for (int i = 0; i < 1000; ++i) {
      ++run;
      clock.publish(run, 10.0 * static_cast<double>(run));
    }
  }
  stop = true;
  reader.join();
  EXPECT_EQ(torn.load(), 0) << "of " << reads.load() << " reads over " << run << " runs";
  EXPECT_GE(runs_seen.load(), 2) << "the reader saw the runs change";
}

}  // namespace
}  // namespace gyrotherm::daemon
