// RunClock: the run id and its start time are read as one pair while the
// control thread publishes new runs.
#include "gyrotherm/station/run_clock.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <thread>

namespace gyrotherm::station {
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

// A batch being handed over when the run ends is stored under it before
// close_samples returns; batches after it belong to no run, while the
// control thread still reads the run's id and start.
TEST(RunClock, CloseSamplesWaitsForTheBatchBeingStored) {
  RunClock clock;
  clock.publish(7, 70.0);
  std::promise<void> entered, release;
  std::atomic<int64_t> stored_under{0};
  std::thread reader([&] {
    clock.with_samples_run([&](const RunClock::Value& run) {
      entered.set_value();
      release.get_future().wait();
      stored_under = run.run_id;
    });
  });
  entered.get_future().wait();
  auto closed = std::async(std::launch::async, [&] { clock.close_samples(); });
  EXPECT_EQ(closed.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout)
      << "close_samples returned while a batch was still being stored";
  release.set_value();
  closed.get();
  reader.join();
  EXPECT_EQ(stored_under.load(), 7);
  int64_t after = -1;
  clock.with_samples_run([&](const RunClock::Value& run) { after = run.run_id; });
  EXPECT_EQ(after, 0) << "no batch is stored under a closed run";
  EXPECT_EQ(clock.load().run_id, 7) << "the control thread still reads the run";
  clock.publish(8, 80.0);
  clock.with_samples_run([&](const RunClock::Value& run) { after = run.run_id; });
  EXPECT_EQ(after, 8) << "the next run stores samples again";
}

}  // namespace
}  // namespace gyrotherm::station
