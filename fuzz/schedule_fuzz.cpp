// Fuzzes schedule parsing and validation (schedules/schedule.h,
// parse_schedule) against two stations: the default limits without a rate
// table, and the same with a 500 °/s, 100 °/s² table. A refused schedule is
// fine; an accepted one must hold every bound of docs/schedules.md
// ("Validation"): the plan is what the sequencer trusts.
#include <cmath>
#include <string>
#include <string_view>

#include "fuzz_check.h"
#include "gyrotherm/schedules/schedule.h"

using namespace gyrotherm::schedules;

namespace {

void check_table(const PlanStep& s, const StationLimits& limits) {
  const TableDemand& d = s.table;
  if (!limits.table) {
    // A station without a table takes no demand and no rate point.
    FUZZ_CHECK(d.mode == TableDemandMode::kNone);
    FUZZ_CHECK(s.kind != StepKind::kRate);
  }
  switch (d.mode) {
    case TableDemandMode::kNone:
      FUZZ_CHECK(!d.position_deg && d.rate_dps == 0);
      break;
    case TableDemandMode::kStatic:
      FUZZ_CHECK(d.rate_dps == 0);
      if (d.position_deg) FUZZ_CHECK(*d.position_deg >= 0 && *d.position_deg < 360);
      break;
    case TableDemandMode::kRate:
      FUZZ_CHECK(!d.position_deg);
      FUZZ_CHECK(std::isfinite(d.rate_dps) && d.rate_dps != 0);
      FUZZ_CHECK(std::abs(d.rate_dps) <= kMaxTableRateDps);
      FUZZ_CHECK(limits.table && std::abs(d.rate_dps) <= limits.table->max_rate_dps);
      break;
  }
  if (s.kind == StepKind::kRate) {
    // A rate point dwells over whole turns, within the bounds.
    FUZZ_CHECK(d.mode == TableDemandMode::kRate);
    FUZZ_CHECK(s.turns >= 1);
    FUZZ_CHECK(s.dwell_s > 0 && s.dwell_s <= kMaxRateDwellMin * 60);
    FUZZ_CHECK(std::abs(s.dwell_s * std::abs(d.rate_dps) - 360.0 * s.turns) <=
               1e-9 * 360.0 * s.turns);
    FUZZ_CHECK(s.sf_sequence >= 1);
    FUZZ_CHECK(s.sf_repetition >= 1 && s.sf_repetition <= kMaxScaleFactorRepetitions);
    FUZZ_CHECK(s.acquire_s == 0 && s.hold_s == 0);
  } else {
    FUZZ_CHECK(s.turns == 0 && s.dwell_s == 0 && s.sf_sequence == 0 && s.sf_repetition == 0);
  }
}

// The plan accepted for `limits`, checked; its step count, or -1 if refused.
long check(std::string_view text, const StationLimits& limits) {
  const auto plan = parse_schedule(text, "fuzz.toml", limits);
  if (!plan.ok()) {
    FUZZ_CHECK(!plan.error().message.empty());
    return -1;
  }
  FUZZ_CHECK(!plan->steps.empty());
  FUZZ_CHECK(plan->steps.size() <= kMaxPlanSteps);
  int last_sequence = 0;
  for (const PlanStep& s : plan->steps) {
    FUZZ_CHECK(s.setpoint_c >= limits.min_temp_c && s.setpoint_c <= limits.max_temp_c);
    FUZZ_CHECK(!s.label.empty());
    check_table(s, limits);
    // Sequences are numbered from 1 in plan order.
    if (s.sf_sequence != 0) {
      FUZZ_CHECK(s.sf_sequence == last_sequence || s.sf_sequence == last_sequence + 1);
      last_sequence = s.sf_sequence;
    }
    switch (s.kind) {
      case StepKind::kSoak:
        FUZZ_CHECK(s.tolerance_c >= kMinToleranceC && s.tolerance_c <= kMaxToleranceC);
        FUZZ_CHECK(s.stability_c_per_min > 0 && s.stability_c_per_min <= kMaxStabilityCPerMin);
        FUZZ_CHECK(s.stability_window_s >= kMinStabilityWindowMin * 60 &&
                   s.stability_window_s <= kMaxStabilityWindowMin * 60);
        FUZZ_CHECK(s.settle_timeout_s > 0 && s.settle_timeout_s <= kMaxSettleTimeoutMin * 60);
        FUZZ_CHECK(s.stability_window_s <= s.settle_timeout_s);
        FUZZ_CHECK(s.acquire_s > 0 && s.acquire_s <= kMaxAcquireMin * 60);
        break;
      case StepKind::kRamp:
        FUZZ_CHECK(s.rate_c_per_min > 0 && s.rate_c_per_min <= limits.max_ramp_c_per_min);
        break;
      case StepKind::kHold:
        FUZZ_CHECK(s.hold_s > 0 && s.hold_s <= kMaxHoldMin * 60);
        break;
      case StepKind::kRate:
        break;  // check_table
    }
  }
  const double total_s = plan->nominal_duration_s();
  FUZZ_CHECK(std::isfinite(total_s) && total_s >= 0);  // 0: only ramps (not counted)
  return static_cast<long>(plan->steps.size());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const StationLimits no_table;
  StationLimits with_table;
  with_table.table = StationLimits::Table{500.0, 100.0};
  const long without = check(text, no_table);
  const long with = check(text, with_table);
  // What a station without a table accepts asks nothing of a table: a
  // station with one accepts it too, as the same plan.
  if (without >= 0) FUZZ_CHECK(with == without);
  return 0;
}
