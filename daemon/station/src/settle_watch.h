// The forecast of the current soak's settle (docs/api.md, "Progress"): when
// will its stability gate hold, P10/P50/P90 (analysis::predict_settle).
//
// While a soak waits for its gate, the control thread hands each tick's
// shell temperature ((top + side) / 2) to tick(); they are kept as means of
// kPackS (a week's settle timeout is 300 k pairs at most). Every kEveryS of
// station time a prediction over the step's series so far runs on a thread of
// its own (it takes tens of ms, up to a few hundred when draws run to the
// horizon; the control thread must not wait on it), one at a time; a later
// tick takes its result. The series starts over with each step, and when a
// soak goes back to settling after a hold broke its acquisition.
#pragma once

#include <cstddef>
#include <future>
#include <optional>
#include <vector>

#include "gyrotherm/analysis/settle_prediction.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/schedules/progress.h"

namespace gyrotherm::station {

class SettleWatch {
 public:
  static constexpr double kPackS = 2;    // station s per kept mean
  static constexpr double kEveryS = 60;  // station s between predictions

  SettleWatch() = default;
  SettleWatch(const SettleWatch&) = delete;
  SettleWatch& operator=(const SettleWatch&) = delete;
  ~SettleWatch();  // waits for a prediction in flight

  // One control tick of a run at t_run_s. `settling_step`: the index of the
  // soak whose gate is awaited, nullopt otherwise (the watch forgets its
  // series); `gate` that soak's; `shell_c` the tick's shell temperature when
  // both probes read; `air_c` the chamber air's reading (the forecast
  // models the shell as driven by it: analysis::predict_settle).
  void tick(double t_run_s, std::optional<std::size_t> settling_step,
            const analysis::SettleGate& gate, std::optional<double> shell_c,
            std::optional<double> air_c = std::nullopt);

  // The last prediction for the soak settling now, its times counted from
  // t_run_s (never below 0); nullopt when none has been made for it yet.
  std::optional<schedules::SettleForecast> forecast(double t_run_s) const;

  // Drops the series and the last prediction (the run ended).
  void forget();

 private:
  void take_result();

  std::optional<std::size_t> step_;
  std::vector<double> t_s_, shell_c_, air_c_;  // kept means (air: NaN when none read)
  double pack_t_sum_ = 0, pack_c_sum_ = 0, pack_air_sum_ = 0;
  int pack_n_ = 0, pack_air_n_ = 0;
  double pack_start_s_ = 0;
  std::optional<double> due_s_;  // the next prediction's station time
  // A prediction in flight, and the series position (generation) it is for.
  std::future<Result<analysis::SettlePrediction>> pending_;
  unsigned generation_ = 0, pending_generation_ = 0;
  double pending_as_of_s_ = 0;  // the last kept time of the series in flight
  std::optional<analysis::SettlePrediction> last_;
  double last_as_of_s_ = 0;
};

}  // namespace gyrotherm::station
