// Analysis speed benchmark (issue 5): Table I statistics, a 10 M x 9 drift
// model fit and the octave Allan deviation on 10 M samples, to set beside the
// same computations in numpy (bench/analysis_numpy.py; scripts/bench-analysis
// runs both). Prints figures; it is not a pass/fail test. See bench/README.md.
//
// The data is an analysis series at 1 s spacing, built once before any
// timing: a shell temperature cycling 20 ... 60 °C over a day, a top - side
// gradient on an unrelated 7 h cycle, both with 0.01 °C noise, and a rate of
// 0.8 °/h bias + a temperature drift (T, T^2, dT/dt, gradient) + white noise
// of 0.05 °/h. bench/analysis_numpy.py builds the same series.
#include <benchmark/benchmark.h>

#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <map>
#include <numbers>
#include <random>
#include <string>

#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/table1.h"

namespace {

namespace ga = gyrotherm::analysis;

constexpr std::size_t kSamples = 10'000'000;

const ga::AnalysisSeries& series() {
  static const ga::AnalysisSeries s = [] {
    ga::AnalysisSeries out;
    out.t_s.resize(kSamples);
    out.rate_dph.resize(kSamples);
    out.top_c.resize(kSamples);
    out.side_c.resize(kSamples);
    std::mt19937_64 rng(20261121);
    std::normal_distribution<double> temp_noise(0.0, 0.01);
    std::normal_distribution<double> rate_noise(0.0, 0.05);
    const double w_day = 2 * std::numbers::pi / 86400.0;
    const double w_grad = 2 * std::numbers::pi / 25200.0;
    for (std::size_t i = 0; i < kSamples; ++i) {
      const double t = static_cast<double>(i);
      const double shell = 40.0 + 20.0 * std::sin(w_day * t);
      const double dshell = 20.0 * w_day * std::cos(w_day * t);  // °C/s
      const double grad = 0.5 * std::sin(w_grad * t) + 0.1;
      out.t_s[i] = t;
      out.top_c[i] = shell + grad / 2 + temp_noise(rng);
      out.side_c[i] = shell - grad / 2 + temp_noise(rng);
      const double dt = shell - 40.0;
      out.rate_dph[i] =
          0.8 + 0.01 * dt + 2e-4 * dt * dt + 50.0 * dshell + 0.3 * grad + rate_noise(rng);
    }
    return out;
  }();
  return s;
}

// Milliseconds per iteration of each benchmark's last run, for the summary
// lines scripts/bench-analysis reads.
std::map<std::string, double>& ms_per_iteration() {
  static std::map<std::string, double> m;
  return m;
}

// A few results, printed after the run as a sanity check (they should match
// the numpy script's to a few digits; the data is the same model, not the same
// random numbers). Storing them also keeps the calls from being optimised
// away. Not benchmark::DoNotOptimize on a double: Debian's Google Benchmark
// 1.7 binds it with a "+m,r" constraint, and with GCC 12 the double read back
// was garbage.
std::map<std::string, double>& results() {
  static std::map<std::string, double> r;
  return r;
}

void record(const benchmark::State& state, const char* name, double total_s) {
  if (state.iterations() > 0) {
    ms_per_iteration()[name] = total_s * 1e3 / static_cast<double>(state.iterations());
  }
}

// table1_row: validation + shell temperature, mean of it, mean and std (ddof 1)
// of the rate, std after the 101-point moving average.
void BM_Table1Stats_10M(benchmark::State& state) {
  const ga::AnalysisSeries& s = series();
  const ga::Table1Options options;
  double total_s = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    auto row = ga::table1_row(s, options);
    total_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!row) {
      state.SkipWithError(row.error().message.c_str());
      return;
    }
    results()["table1 std_dph"] = row->bias_std_dph;
    results()["table1 std_ma_dph"] = row->bias_std_ma_dph;
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(kSamples));
  record(state, "table1", total_s);
}
BENCHMARK(BM_Table1Stats_10M)->Unit(benchmark::kMillisecond)->Iterations(5)->UseRealTime();

// fit_drift_model, centred form with an intercept, T4+R2+G2: 9 parameters.
// Includes building the design (the smoothing derivative dT/dt, the scaling
// pass) as well as the least-squares solve.
void BM_DriftFit_10Mx9(benchmark::State& state) {
  const ga::AnalysisSeries& s = series();
  const ga::DriftModelSpec spec{.t_order = 4, .r_order = 2, .g_order = 2};
  double total_s = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    auto fit = ga::fit_drift_model(s, spec, ga::DriftModelForm::kCentered);
    total_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!fit) {
      state.SkipWithError(fit.error().message.c_str());
      return;
    }
    state.counters["params"] = static_cast<double>(fit->parameters);
    state.counters["condition"] = fit->condition_estimate;
    state.SetLabel(fit->solver);
    results()["drift_fit residual_std_dph"] = fit->residual_std_dph;
    results()["drift_fit r_squared"] = fit->r_squared;
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(kSamples));
  record(state, "drift_fit", total_s);
}
BENCHMARK(BM_DriftFit_10Mx9)->Unit(benchmark::kMillisecond)->Iterations(3)->UseRealTime();

// allan_deviation with TauSet::kOctave: m = 1, 2, 4, ... 2^22 (23 taus), with
// the chi-squared bounds and the noise terms.
void BM_AllanOctave_10M(benchmark::State& state) {
  const ga::AnalysisSeries& s = series();
  double total_s = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    auto r = ga::allan_deviation(s.t_s, s.rate_dph, {.taus = ga::TauSet::kOctave});
    total_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!r) {
      state.SkipWithError(r.error().message.c_str());
      return;
    }
    state.counters["taus"] = static_cast<double>(r->tau_s.size());
    results()["allan_octave adev_1s_dph"] = r->adev_dph.front();
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(kSamples));
  record(state, "allan_octave", total_s);
}
BENCHMARK(BM_AllanOctave_10M)->Unit(benchmark::kMillisecond)->Iterations(3)->UseRealTime();

}  // namespace

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  series();  // build the data before the first benchmark
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  for (const auto& [name, ms] : ms_per_iteration()) {
    std::printf("summary: %s %.3f ms\n", name.c_str(), ms);
  }
  for (const auto& [name, value] : results()) std::printf("check: %s %.6g\n", name.c_str(), value);
  return 0;
}
