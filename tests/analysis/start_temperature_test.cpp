// Start-temperature model (paper eq. 3): against numpy
// (tools/reference/multirun_reference.py, data in
// tests/analysis/data/start_temperature_cubic.txt), exact recovery of
// coefficients that are cubics in T0, compensation from T0 alone, errors.
// Tolerances: T0 (a statistic) 1e-10 relative; each run's coefficients and
// the cubic's values a_i(T0) (fitted values) 1e-9 relative; the cubic's
// coefficients A_ij 1e-9 relative too (the design in T0 is small and well
// conditioned once centred; stated per check below).
#include "gyrotherm/analysis/start_temperature.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include "multirun_data.h"

namespace gyrotherm::analysis {
namespace {

using testing::load_runs;
using testing::read_reference_lines;
using testing::Tokens;

const char* const kStartTemperatureScript = "tools/reference/multirun_reference.py";

TEST(StartTemperatureReference, MatchesNumpy) {
  const std::vector<Tokens> lines =
      read_reference_lines("start_temperature_cubic.txt", kStartTemperatureScript);
  const std::vector<AnalysisSeries> runs = load_runs(lines);
  ASSERT_EQ(runs.size(), 5u);
  StartTemperatureOptions base;
  for (const Tokens& t : lines) {
    if (t[0] == "derivative_window_s") base.fit.derivative_window_s = std::stod(t[1]);
    if (t[0] == "l0_window_s") base.fit.l0_window_s = std::stod(t[1]);
    if (t[0] == "t0_window_s") base.t0_window_s = std::stod(t[1]);
    if (t[0] == "t0") {
      auto t0 = start_temperature_c(runs.at(std::stoul(t[1])), base.t0_window_s);
      ASSERT_TRUE(t0.ok()) << t0.error().message;
      EXPECT_NEAR(*t0, std::stod(t[2]), 1e-10 * std::abs(std::stod(t[2]))) << "run " << t[1];
    }
  }

  std::size_t cases = 0;
  for (std::size_t li = 0; li < lines.size(); ++li) {
    if (lines[li][0] != "case") continue;
    ++cases;
    StartTemperatureOptions options = base;
    options.form = *parse_drift_model_form(lines[li][1]);
    options.spec = *parse_model_spec(lines[li][2]);
    SCOPED_TRACE(lines[li][1] + " " + lines[li][2]);
    auto model = fit_start_temperature_model(runs, options);
    ASSERT_TRUE(model.ok()) << model.error().message;
    ASSERT_EQ(model->t0_c.size(), 5u);
    ASSERT_EQ(model->run_coefficients.size(), 5u);

    std::map<std::string, std::vector<std::pair<double, double>>> at;  // name -> (T0, a)
    std::size_t checked = 0;
    for (++li; li < lines.size() && lines[li][0] != "end_case"; ++li) {
      const Tokens& t = lines[li];
      if (t[0] == "run_coef") {
        const double expected = std::stod(t[3]);
        EXPECT_NEAR(model->run_coefficients.at(std::stoul(t[1])).at(t[2]), expected,
                    1e-9 * std::abs(expected))
            << "run " << t[1] << " " << t[2];
        ++checked;
      } else if (t[0] == "cubic") {
        ASSERT_TRUE(model->cubic.count(t[1])) << t[1];
        const std::array<double, 4>& a = model->cubic.at(t[1]);
        for (std::size_t j = 0; j < 4; ++j) {
          const double expected = std::stod(t[2 + j]);
          EXPECT_NEAR(a[j], expected, 1e-9 * std::abs(expected)) << t[1] << " A" << j;
        }
        EXPECT_GT(model->cubic_residual_std.at(t[1]), 0.0) << t[1];  // 5 runs, 4 parameters
        ++checked;
      } else if (t[0] == "at") {
        at[t[1]].emplace_back(std::stod(t[2]), std::stod(t[3]));
      }
    }
    EXPECT_GT(checked, 20u);
    ASSERT_EQ(at.size(), model->cubic.size());
    const double lo = *std::min_element(model->t0_c.begin(), model->t0_c.end());
    const double hi = *std::max_element(model->t0_c.begin(), model->t0_c.end());
    // a_i(T0) over a grid that includes extrapolation (-25 and 55 degC), to
    // 1e-9 of the largest |a_i| over the grid.
    for (const auto& [name, points] : at) {
      double scale = 0;
      for (const auto& [t0, a] : points) scale = std::max(scale, std::abs(a));
      for (const auto& [t0, a] : points) {
        auto c = coefficients_at(*model, t0);
        ASSERT_TRUE(c.ok()) << c.error().message;
        EXPECT_NEAR(c->fit.coefficients.at(name), a, 1e-9 * scale) << name << " at " << t0;
        EXPECT_EQ(c->extrapolated, t0 < lo || t0 > hi) << t0;
      }
    }
  }
  EXPECT_EQ(cases, 2u);
}

// ---- exact recovery ----------------------------------------------------------

struct Truth {
  std::array<double, 4> intercept, t1, t2, r1, g1;  // each a cubic in T0
};

double cubic(const std::array<double, 4>& a, double x) {
  return a[0] + a[1] * x + a[2] * x * x + a[3] * x * x * x;
}

// A noiseless run started near t0_c whose rate follows the centred model
// exactly, with coefficients given by the cubics at its measured T0.
AnalysisSeries exact_run(double t0_c, std::size_t period, const Truth& truth) {
  testing::RunParams p = {{"n", 900},      {"t_start", 5000}, {"t0", t0_c},      {"span", 10},
                          {"period", 0},   {"tri_amp", 1.2},  {"g0", 0.1},       {"g_amp", 0.35},
                          {"g_period", 0}, {"seed", 1},       {"temp_sigma", 0}, {"rate_sigma", 0},
                          {"bias", 0},     {"a1", 0},         {"a2", 0},         {"a3", 0},
                          {"b1", 0},       {"c1", 0}};
  p["period"] = static_cast<double>(period);
  p["g_period"] = static_cast<double>(period + 137);
  AnalysisSeries s = testing::make_run(p);
  const double t0 = *start_temperature_c(s);
  std::vector<double> temp(s.t_s.size());
  for (std::size_t i = 0; i < temp.size(); ++i) temp[i] = (s.top_c[i] + s.side_c[i]) / 2;
  const std::vector<double> rate = smoothing_derivative(s.t_s, temp, 60.0);
  for (std::size_t i = 0; i < temp.size(); ++i) {
    s.rate_dph[i] = cubic(truth.intercept, t0) + cubic(truth.t1, t0) * temp[i] +
                    cubic(truth.t2, t0) * temp[i] * temp[i] + cubic(truth.r1, t0) * rate[i] +
                    cubic(truth.g1, t0) * (s.top_c[i] - s.side_c[i]);
  }
  return s;
}

const Truth kTruth = {{8.0, 0.01, -2e-4, 3e-6},
                      {0.02, 2e-4, -3e-6, 1e-8},
                      {-4e-4, 2e-6, 5e-8, -1e-9},
                      {25.0, 0.1, -2e-3, 3e-5},
                      {0.2, -2e-3, 1e-5, 2e-7}};

TEST(StartTemperature, RecoversCubicCoefficientsAndCompensatesFromT0) {
  std::vector<AnalysisSeries> runs;
  const double t0s[] = {-15.0, 2.0, 24.0, 45.0};
  for (std::size_t i = 0; i < 4; ++i) runs.push_back(exact_run(t0s[i], 200 + 30 * i, kTruth));
  StartTemperatureOptions options;
  options.spec = *parse_model_spec("T2+R1+G1");
  options.form = DriftModelForm::kCentered;
  auto model = fit_start_temperature_model(runs, options);
  ASSERT_TRUE(model.ok()) << model.error().message;
  const std::map<std::string, const std::array<double, 4>*> truth = {
      {"intercept", &kTruth.intercept},
      {"T1", &kTruth.t1},
      {"T2", &kTruth.t2},
      {"R1", &kTruth.r1},
      {"G1", &kTruth.g1}};
  ASSERT_EQ(model->cubic.size(), truth.size());
  // Exact interpolation by 4 runs: A_ij back to 1e-7 relative of the
  // coefficient's size over the T0 range (the per-run fits carry ~1e-12
  // relative rounding, amplified by the cubic's conditioning in raw T0).
  for (const auto& [name, a] : truth) {
    const std::array<double, 4>& got = model->cubic.at(name);
    for (std::size_t j = 0; j < 4; ++j) {
      const double size = std::abs((*a)[j]) * std::pow(45.0, static_cast<double>(j));
      double total = 0;
      for (std::size_t m = 0; m < 4; ++m) {
        total += std::abs((*a)[m]) * std::pow(45.0, static_cast<double>(m));
      }
      EXPECT_NEAR(got[j] * std::pow(45.0, static_cast<double>(j)),
                  (*a)[j] * std::pow(45.0, static_cast<double>(j)), 1e-9 * total)
          << name << " A" << j << " (size " << size << ")";
    }
    EXPECT_EQ(model->cubic_residual_std.at(name), 0.0) << name;
  }

  // A new run, started at a T0 no run had, compensated from its T0 alone:
  // rate - drift terms is its intercept a_0(T0), a constant.
  const AnalysisSeries fresh = exact_run(13.0, 251, kTruth);
  const double t0 = *start_temperature_c(fresh);
  auto compensated = compensate_from_start(*model, fresh);
  ASSERT_TRUE(compensated.ok()) << compensated.error().message;
  ASSERT_EQ(compensated->size(), fresh.t_s.size());
  for (std::size_t i = 0; i < compensated->size(); ++i) {
    ASSERT_NEAR((*compensated)[i], cubic(kTruth.intercept, t0), 1e-9 * 8.0) << i;
  }
  auto c = coefficients_at(*model, t0);
  ASSERT_TRUE(c.ok());
  EXPECT_FALSE(c->extrapolated);
  EXPECT_DOUBLE_EQ(c->t0_c, t0);
  EXPECT_EQ(c->fit.spec, options.spec);
  auto predicted = predict_drift(c->fit, fresh);
  ASSERT_TRUE(predicted.ok());
  for (std::size_t i = 0; i < fresh.t_s.size(); i += 50) {
    EXPECT_NEAR((*predicted)[i], fresh.rate_dph[i], 1e-9 * 8.0) << i;
  }
  EXPECT_TRUE(coefficients_at(*model, 80.0)->extrapolated);
  EXPECT_FALSE(coefficients_at(*model, std::nan("")).ok());
}

// ---- errors ----------------------------------------------------------------

TEST(StartTemperature, FewerThanFourDistinctT0NamesThemAll) {
  std::vector<AnalysisSeries> runs;
  for (double t0 : {20.0, 20.4, 35.0, 50.0}) runs.push_back(exact_run(t0, 240, kTruth));
  StartTemperatureOptions options;
  options.spec = *parse_model_spec("T1");
  auto model = fit_start_temperature_model(runs, options);
  ASSERT_FALSE(model.ok());
  const std::string& m = model.error().message;
  EXPECT_NE(m.find(">= 4 distinct"), std::string::npos) << m;
  EXPECT_NE(m.find("found 3"), std::string::npos) << m;
  for (const AnalysisSeries& r : runs) {
    const std::string t = fmt::format("{:.2f}", *start_temperature_c(r));
    EXPECT_NE(m.find(t), std::string::npos) << t << " in " << m;
  }
  EXPECT_FALSE(fit_start_temperature_model(std::span<const AnalysisSeries>(), options).ok());
  options.min_distinct_t0 = 3;
  std::string why;
  EXPECT_FALSE(options.is_valid(&why));
  EXPECT_NE(why.find("min_distinct_t0"), std::string::npos) << why;
}

TEST(StartTemperature, AFailingRunIsNamed) {
  std::vector<AnalysisSeries> runs;
  for (double t0 : {-10.0, 5.0, 20.0, 35.0}) runs.push_back(exact_run(t0, 240, kTruth));
  // Run 3 soaks at one temperature: T cannot be fitted on it alone.
  for (std::size_t i = 0; i < runs[2].t_s.size(); ++i) {
    runs[2].top_c[i] = 21.5;
    runs[2].side_c[i] = 21.0;
  }
  StartTemperatureOptions options;
  options.spec = *parse_model_spec("T2+G1");
  auto model = fit_start_temperature_model(runs, options);
  ASSERT_FALSE(model.ok());
  EXPECT_NE(model.error().message.find("run 3 (T0 = 21.25 °C)"), std::string::npos)
      << model.error().message;
  EXPECT_NE(model.error().message.find("term T"), std::string::npos) << model.error().message;

  // Too few points for the model in one run.
  runs[2] = exact_run(20.0, 240, kTruth);
  for (auto* v : {&runs[1].t_s, &runs[1].top_c, &runs[1].side_c, &runs[1].rate_dph}) v->resize(3);
  model = fit_start_temperature_model(runs, options);
  ASSERT_FALSE(model.ok());
  EXPECT_NE(model.error().message.find("run 2"), std::string::npos) << model.error().message;
  EXPECT_NE(model.error().message.find("3 points for 4 parameters"), std::string::npos)
      << model.error().message;
}

TEST(StartTemperature, StartTemperatureErrors) {
  EXPECT_FALSE(start_temperature_c(AnalysisSeries{}).ok());
  AnalysisSeries s = exact_run(10.0, 240, kTruth);
  auto t0 = start_temperature_c(s, 120.0);
  ASSERT_TRUE(t0.ok());
  double sum = 0;
  for (std::size_t i = 0; i < 120; ++i) sum += (s.top_c[i] + s.side_c[i]) / 2;
  EXPECT_NEAR(*t0, sum / 120, 1e-12 * std::abs(*t0));
  s.side_c[7] = std::nan("");
  auto bad = start_temperature_c(s, 120.0);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("side_c[7]"), std::string::npos) << bad.error().message;
  EXPECT_FALSE(start_temperature_c(exact_run(10.0, 240, kTruth), 0.0).ok());
  EXPECT_FALSE(coefficients_at(StartTemperatureModel{}, 20.0).ok());
}

}  // namespace
}  // namespace gyrotherm::analysis
