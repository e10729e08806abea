// Sliding window of a station signal for the soak stability gate (docs/schedules.md, the soak
// step).
//
// The sequencer pushes the shell temperature (or any signal) with its station
// time; the window keeps the last window_s seconds and answers whether the
// signal is flat: the least-squares slope over the window and the largest
// deviation from a reference (the set point). Not thread-safe; one per gate.
#pragma once

#include <cstddef>
#include <deque>

namespace gyrotherm::analysis {

class StabilityWindow {
 public:
  // window_s: station seconds to keep (e.g. 600 for the default 10 min gate).
  explicit StabilityWindow(double window_s);

  // Adds a sample at station time t_s and drops those older than
  // t_s - window_s. A sample at the same time as the last one replaces it; an
  // earlier time (a clock reset) or a non-finite time or value clears the
  // window first (a non-finite sample is not kept), so the gate must be
  // earned again from good readings.
  void push(double t_s, double value);

  // True when the kept samples span at least window_s, within one sample
  // spacing (the mean spacing of the kept samples): 1 Hz samples at
  // t = 0 ... 599 fill a 600 s window.
  bool full() const;

  // Least-squares slope of value on t_s over the window, value units per
  // second (divide a °C/min limit by 60). NaN when fewer than 2 samples or
  // the window is not full().
  double slope_per_s() const;

  // max |value - ref| over the kept samples; NaN when empty.
  double max_abs_dev(double ref) const;

  // Mean of the kept values; NaN when empty.
  double mean() const;

  void clear() { samples_.clear(); }
  std::size_t size() const { return samples_.size(); }
  // Time between the oldest and newest kept samples, s (0 when < 2 samples).
  double span_s() const;
  double window_s() const { return window_s_; }

 private:
  struct Sample {
    double t_s;
    double value;
  };
  double window_s_;
  std::deque<Sample> samples_;
};

}  // namespace gyrotherm::analysis
