// The judgement of an adaptive soak (docs/schedules.md, "Adaptive soaks"):
// is each gated DUT axis's mean known to the soak's target yet?
//
// While an adaptive soak acquires, every kEveryS of station time the control
// thread hands tick() the 1 s means of every gated axis (the required DUTs'
// rate axes of the run, DutAcquisition::gated_seconds) inside the soak's
// windows so far; each axis gets analysis::project_acquisition (its noise
// model from its octave Allan curve, U95 of its mean now, the length that
// would reach the target). done() says the soak may end once every axis has
// reached the target or has it out of reach; the sequencer ends it then
// (after the soak's min_min). The judgement runs on the control thread: a
// day's soak is 86 400 means per axis, a few ms each, at most once every
// kEveryS, and a judgement made on the control thread is the same whatever
// the machine's load (one on a thread of its own would land at a
// load-dependent station time, and the soak's end with it).
#pragma once

#include <cstddef>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "dut_acquisition.h"
#include "gyrotherm/schedules/progress.h"
#include "gyrotherm/schedules/schedule.h"

namespace gyrotherm::station {

class AcquireWatch {
 public:
  static constexpr double kEveryS = 120;  // station s between judgements

  using Seconds = std::function<std::vector<DutAcquisition::AxisSeconds>(
      std::span<const std::pair<double, double>> windows)>;

  // One control tick at t_run_s. `step`: the current step, with its index
  // (nullptr: none; another step than the last forgets the judgement);
  // `acquiring`: it acquires now (held or settling again, the judgement is
  // kept for the status but no longer ends the soak: the next one comes
  // kEveryS after acquiring resumes); `windows` its acquisition so far
  // (closed windows and the open one up to now); `seconds` the gated axes'
  // 1 s means inside them.
  void tick(double t_run_s, std::size_t index, const schedules::PlanStep* step, bool acquiring,
            std::span<const std::pair<double, double>> windows, const Seconds& seconds);

  // Why the soak may end now (every axis reached, or out of reach), for
  // schedules::Readings::acquisition_done; nullopt otherwise.
  const std::optional<std::string>& done() const { return done_; }

  // The last judgement, its age counted to t_run_s; nullopt when none was
  // made for the current step.
  std::optional<schedules::AcquireForecast> forecast(double t_run_s) const;

  void forget();

 private:
  void judge(double t_run_s, const schedules::PlanStep& step,
             std::vector<DutAcquisition::AxisSeconds> axes);

  std::optional<std::size_t> step_;
  std::optional<double> due_s_;
  std::optional<schedules::AcquireForecast> last_;
  double last_at_s_ = 0;
  std::optional<std::string> done_;
};

}  // namespace gyrotherm::station
