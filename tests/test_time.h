// Wall-clock allowances for tests. Tests wait on conditions with deadlines,
// never sleep-and-hope; those deadlines and the few wall-time bounds some
// tests check are stretched by GYROTHERM_TEST_TIME_FACTOR (default 1, values
// below 1 count as 1), which scripts/test-sanitizers sets for its slower
// instrumented builds and which a loaded machine may set too. Station time
// (virtual, from a ManualClock or the --time-scale) is never stretched.
#pragma once

#include <chrono>
#include <cstdlib>
#include <thread>

namespace gyrotherm::testing {

inline double time_factor() {
  static const double factor = [] {
    const char* v = std::getenv("GYROTHERM_TEST_TIME_FACTOR");
    const double f = v && *v ? std::atof(v) : 1.0;
    return f >= 1.0 ? f : 1.0;
  }();
  return factor;
}

// `d` stretched by time_factor().
template <class Rep, class Period>
std::chrono::milliseconds scaled(std::chrono::duration<Rep, Period> d) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(d * time_factor());
}

// Polls `pred` every `poll` until it holds or `timeout` (stretched by
// time_factor()) passes; true when it held.
template <class Pred>
bool wait_for_condition(Pred pred, std::chrono::milliseconds timeout,
                        std::chrono::milliseconds poll = std::chrono::milliseconds(2)) {
  const auto deadline = std::chrono::steady_clock::now() + scaled(timeout);
  for (;;) {
    if (pred()) return true;
    if (std::chrono::steady_clock::now() >= deadline) return false;
    std::this_thread::sleep_for(poll);
  }
}

}  // namespace gyrotherm::testing
