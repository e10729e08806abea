// Fuzzes schedule parsing and validation (schedules/schedule.h,
// parse_schedule) with the default station limits. A refused schedule is
// fine; an accepted one must hold every bound of docs/schedules.md
// ("Validation"): the plan is what the sequencer trusts.
#include <cmath>
#include <string>
#include <string_view>

#include "fuzz_check.h"
#include "gyrotherm/schedules/schedule.h"

using namespace gyrotherm::schedules;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const StationLimits limits;
  const auto plan = parse_schedule(text, "fuzz.toml", limits);
  if (!plan.ok()) {
    FUZZ_CHECK(!plan.error().message.empty());
    return 0;
  }
  FUZZ_CHECK(!plan->steps.empty());
  FUZZ_CHECK(plan->steps.size() <= kMaxPlanSteps);
  for (const PlanStep& s : plan->steps) {
    FUZZ_CHECK(s.setpoint_c >= limits.min_temp_c && s.setpoint_c <= limits.max_temp_c);
    FUZZ_CHECK(std::abs(s.table_rate_dps) <= kMaxTableRateDps);
    FUZZ_CHECK(!s.label.empty());
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
    }
  }
  const double total_s = plan->nominal_duration_s();
  FUZZ_CHECK(std::isfinite(total_s) && total_s >= 0);  // 0: only ramps (not counted)
  return 0;
}
