// Planned durations and the progress of a run and of the queue
// (docs/schedules.md, "Planned duration and progress").
//
// A plan's time has two parts. The fixed-length part is known before the
// run: ramps (|target − where the previous step left the set point| / rate),
// soak acquisitions, holds, and rate points (their dwell plus a spin-up
// estimated as |rate − the previous step's table rate| / the table's
// acceleration). Settling is not: a soak waits for its stability gate as
// long as the chamber needs. So a duration is "fixed time + N settles of
// unknown length", and an ETA exists only when no settle remains.
//
// Pure functions of the plan and the sequencer's snapshot, so they are tested
// with hand-computed figures; the station calls them each tick.
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/schedules/sequencer.h"

namespace gyrotherm::schedules {

// Fixed-length station seconds and the number of settles of unknown length.
struct PlannedDuration {
  double fixed_s = 0;
  int settles = 0;

  PlannedDuration& operator+=(const PlannedDuration& o) {
    fixed_s += o.fixed_s;
    settles += o.settles;
    return *this;
  }
};

// The table's rate demand a step leaves behind (0 unless it spins the table).
double step_table_rate_dps(const PlanStep& step);

// The fixed-length station seconds of one step entered with the set point at
// from_setpoint_c and the table demand at from_rate_dps: a soak's acquisition
// (its settle is not counted), a ramp's |target − from| / rate, a hold's
// duration, a rate point's spin-up (|rate − from_rate| / accel; none without
// an acceleration) plus its dwell.
double step_fixed_s(const PlanStep& step, double from_setpoint_c, double from_rate_dps,
                    double table_accel_dps2);

// Whether a step has a settle of unknown length (a soak's stability gate).
bool step_settles(const PlanStep& step);

// The whole plan, started with the chamber at start_setpoint_c (a queued run
// starts where the previous one left the chamber: the safe set point) and the
// table at rest.
PlannedDuration planned_duration(const Plan& plan, double start_setpoint_c);

// The steps after step `index` (the set point and table rate being those
// step `index` leaves).
PlannedDuration planned_duration_after(const Plan& plan, std::size_t index);

// "5 h 20 min", "2 d 3 h", "12 min 30 s", "45 s": the two largest units,
// rounded to the smaller one.
std::string format_duration(double s);
// "5 h 20 min (+ 4 settles of unknown length)"; without settles just the time.
std::string format_planned(const PlannedDuration& d);

// What the station predicts of the current soak's settle (the daemon's
// settle watch over analysis::predict_settle): station seconds from now until
// the stability gate holds, P10/P50/P90. A P90 (or P50) beyond the
// predictor's horizon is nullopt; no quantile at all unless the verdict is
// "predicted".
struct SettleForecast {
  std::string verdict;  // predicted, holds_now, not_enough_curvature, never_within_tolerance
  std::string note;     // one line: how, or why not
  std::optional<double> p10_s, p50_s, p90_s;
  // Station s since the last reading the forecast used (forecasts are made
  // every minute of station time, on a thread of their own).
  double age_s = 0;
};

// What the chamber's past soaks say a settle takes: P10/P50/P90 of the
// station's last settles (station s each), the prior of every soak not yet
// forecast. The same chamber, fixture and gate repeat, so its settles do.
struct SettlePrior {
  int settles = 0;  // how many past settles it comes from
  double p10_s = 0, p50_s = 0, p90_s = 0;
};
inline constexpr int kMinPriorSettles = 3;
inline constexpr int kMaxPriorSettles = 50;  // the newest this many
// Empirical quantiles (linear between order statistics, as numpy's default
// percentile) of the finite, non-negative durations; nullopt with fewer than
// kMinPriorSettles of them.
std::optional<SettlePrior> settle_prior(std::vector<double> settles_s);

// An adaptive soak's acquisition as the station projects it (the daemon's
// acquisition watch over analysis::project_acquisition), per gated DUT axis
// (docs/schedules.md, "Adaptive soaks").
struct AcquireAxis {
  std::string name;               // "<serial> <axis>"
  std::string verdict;            // continue, reached, out_of_reach, no_model
  std::optional<double> u95_dph;  // U95 of its mean so far
  std::optional<double> reach_s;  // continue: the acquisition length projected to reach the target
  std::optional<double> floor_dph;  // the flicker floor of its model
  std::string note;                 // one line: how far, or why not
  // The fitted noise model (analysis::NoiseModel::q and gm_tc_s, 0 without
  // a Gauss-Markov term; k the coverage factor now).
  struct Model {
    double q_n = 0, q_b = 0, q_k = 0, q_g = 0, gm_tc_s = 0, k = 0;
  };
  std::optional<Model> model;
  // The projection judged, U95(T) at log-spaced T from the soak's start to
  // its cap (analysis::mean_uncertainty; what the dashboard draws).
  struct Point {
    double t_s = 0, u95_dph = 0;
  };
  std::vector<Point> projection;
};
struct AcquireForecast {
  double target_u95_dph = 0, min_s = 0, max_s = 0;
  double acquired_s = 0;  // the acquisition the axes were judged on, station s
  // The acquisition's projected length: the longest axis's reach (at least
  // min_s, at most max_s); nullopt when an axis has no projection (the cap).
  std::optional<double> planned_s;
  std::vector<AcquireAxis> axes;
  double age_s = 0;  // station s since that judgement
};

// Where a run and the queue are; the fields of station::Progress (see
// gyrotherm/station/status.h and docs/api.md, "Progress").
struct RunProgress {
  // ramping, settling, acquiring, holding, spinning_up; idle without a run;
  // aborting, completed, failed, interrupted once the steps are over.
  std::string phase = "idle";
  std::optional<double> step_elapsed_s;
  std::optional<double> step_planned_s;
  std::optional<double> step_fraction;  // nullopt while a soak settles
  std::optional<double> gate_held_s;
  std::optional<double> gate_needed_s;
  double run_remaining_fixed_s = 0;
  int run_settles_remaining = 0;  // the current settle included
  // When every settle left is known: none left ("fixed"), the current
  // soak's forecast ("forecast"), the chamber's prior for the soaks not
  // forecast ("prior", "forecast+prior"). The fixed time plus each settle's
  // P50, and the band from their P10s and P90s: the prior is one chamber's,
  // so its settles are taken to run long or short together (the band is not
  // narrowed as for independent ones). A settling soak whose forecast has
  // no P50 (none yet, too little curvature, beyond the horizon, a final
  // value outside the tolerance) takes the prior less what it has settled.
  // run_eta_p90_s is nullopt when
  // the forecast's P90 is beyond its horizon.
  std::optional<double> run_eta_s;
  std::optional<double> run_eta_p10_s;
  std::optional<double> run_eta_p90_s;
  std::string run_eta_basis;  // fixed, forecast, prior, forecast+prior; "" without an ETA
  int prior_settles = 0;      // past settles behind the prior (0 without one)
  std::optional<SettleForecast> settle;  // while a soak settles and a forecast was given
  // While an adaptive soak acquires and its axes were judged: the step's
  // planned time is then the projected acquisition (planned_s), not the cap.
  std::optional<AcquireForecast> acquire;
  double queue_fixed_s = 0;
  int queue_settles = 0;
  // The queued entries' time with their settles from the prior (fixed only
  // when they have none); nullopt when they have settles and there is no
  // prior.
  std::optional<double> queue_eta_s, queue_eta_p10_s, queue_eta_p90_s;
};

// The progress of the run the sequencer's `snapshot` describes (taken at
// snapshot.t_s), with `gate` its gate_progress() at that time, `queue`
// the planned duration of the queued entries, `settle` the forecast of the
// current soak's settle (used only while a soak settles) and `prior` the
// chamber's settles.
RunProgress run_progress(const Plan& plan, const SequencerSnapshot& snapshot,
                         const std::optional<GateProgress>& gate, const PlannedDuration& queue,
                         const std::optional<SettleForecast>& settle = std::nullopt,
                         const std::optional<SettlePrior>& prior = std::nullopt,
                         const std::optional<AcquireForecast>& acquire = std::nullopt);
// The queue's part alone (no run): its fixed time and settles, with the
// ETA from the prior.
RunProgress queue_progress(const PlannedDuration& queue, const std::optional<SettlePrior>& prior);

// The queued entries' planned durations, each entry's schedule text parsed
// once (cached by entry id). An entry whose text does not parse (station
// limits changed since it was queued) counts nothing: its run will fail at
// start.
class QueueDurations {
 public:
  struct Entry {
    int64_t id = 0;
    std::string_view toml_text;
    std::string_view source;
  };
  // The sum over `entries`, each started at start_setpoint_c; entries no
  // longer given are forgotten.
  PlannedDuration update(const std::vector<Entry>& entries, const StationLimits& limits,
                         double start_setpoint_c);
  std::size_t parsed() const { return parses_; }  // schedule texts parsed so far

 private:
  std::map<int64_t, PlannedDuration> cache_;
  std::size_t parses_ = 0;
};

}  // namespace gyrotherm::schedules
