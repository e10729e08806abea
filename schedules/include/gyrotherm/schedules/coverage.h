// Which stretches of station time a stream's samples cover.
//
// A soak is credited for the time its gyros' samples cover, not for the time
// the clock says passed: a silent line, a stalled daemon or a reader that
// lost frames leaves a stretch uncovered, and the soak acquires on until
// every required DUT has its acquisition time of covered data
// (Readings::data_covered, sequencer.h).
//
// A sample at t covers [t, t + period). A gap of one missing sample is
// covered (two periods between samples); a longer one is not. Memory is a
// span per gap; forget_before() drops the past.
#pragma once

#include <optional>
#include <utility>
#include <vector>

namespace gyrotherm::schedules {

class CoverageSpans {
 public:
  // `period_s` > 0: the stream's sample period.
  explicit CoverageSpans(double period_s);

  // A sample at `t_s` (station or run seconds, the caller's choice; in order:
  // one before the last is ignored).
  void add(double t_s);
  // Seconds of [from_s, to_s) covered.
  double covered_s(double from_s, double to_s) const;
  // The earliest end at which [from_s, end) holds `need_s` covered seconds;
  // nullopt while it does not.
  std::optional<double> reached_at(double from_s, double need_s) const;
  // Where coverage ends now (the last sample + one period); nullopt before any.
  std::optional<double> end_s() const;
  // Drops what ends before `t_s`.
  void forget_before(double t_s);
  std::size_t spans() const { return spans_.size(); }

 private:
  double period_s_;
  std::vector<std::pair<double, double>> spans_;  // disjoint, in order, [from, to)
};

}  // namespace gyrotherm::schedules
