// Checking schedules with very many errors (issue 15, item 20): a schedule
// of the largest size read (1 MiB) made of the cheapest bad steps, every one
// reported. Before the fix, the de-duplication of the messages was quadratic
// (42 s and 330 MB for 190 000 lines); now the report is linear in the file
// and holds at most 50 lines.
#include <benchmark/benchmark.h>

#include <string>

#include "gyrotherm/core/toml_errors.h"
#include "gyrotherm/schedules/schedule.h"

namespace {

using gyrotherm::schedules::parse_schedule;
using gyrotherm::schedules::StationLimits;

// Steps of `[[step]]\nx = 1\n`: each one "type missing" and "unknown key",
// up to `bytes` of text.
std::string bad_schedule(std::size_t bytes) {
  const std::string step = "[[step]]\nx = 1\n";
  std::string text;
  text.reserve(bytes);
  while (text.size() + step.size() <= bytes) text += step;
  return text;
}

void BM_CheckScheduleWithManyErrors(benchmark::State& state) {
  const std::string text = bad_schedule(static_cast<std::size_t>(state.range(0)));
  const StationLimits limits{-20.0, 60.0, 2.0};
  std::size_t report_bytes = 0;
  for (auto _ : state) {
    auto plan = parse_schedule(text, "bad.toml", limits);
    report_bytes = plan.ok() ? 0 : plan.error().message.size();
    benchmark::DoNotOptimize(report_bytes);
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * text.size()));
  state.counters["steps"] = static_cast<double>(text.size() / 15);
  state.counters["report_bytes"] = static_cast<double>(report_bytes);
}
BENCHMARK(BM_CheckScheduleWithManyErrors)
    ->Arg(64 << 10)
    ->Arg(static_cast<int64_t>(gyrotherm::kMaxTomlFileBytes))
    ->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
