// The drift model against the simulator's truth: the ThermalPlant and
// GyroModel of gyrotherm_sim are stepped in-process in virtual time (10 Hz
// gyro, probes read once a second as the station's control loop does)
// through a long ramp -20 -> 60 -> -20 degC at 1 degC/min; the analysis
// series (1 s bins) is fitted with the truth's orders in the centred form,
// and every truth coefficient must be recovered within kSigmas standard
// errors; the comparison grid must order the compensated std as the paper
// found, {T} > {T, dT} > {T, dT, dT/dt}, at every order 1..4.
//
// One run or several: with gradient_tau_s = 0 the plant's gradient is an
// exact affine function of the case heating rate (gradient = offset + k x
// rate, thermal_plant.h), so in one run the gradient and dT/dt columns are
// collinear and no fit can tell their coefficients apart. With the gradient
// lagging its target (gradient_tau_s = 900 s, heat crossing the gyro) one
// long ramp separates them. Without the lag, three runs with differently
// mounted probes (different k and offset) do, as a calibration campaign with
// several fixtures would; those three runs also exercise leave-one-run-out.
//
// Why white noise only: bias instability (a Gauss-Markov process) and rate
// random walk make the residuals correlated over minutes to hours, and the
// least-squares standard errors (which assume independent residuals) would
// then be far too small; with white noise the residuals are independent and
// the standard errors honest. Probes are given a fine resolution so that the
// errors in the measured gradient (errors-in-variables, which bias its
// coefficient towards zero) stay far below one standard error.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/analysis/comparison.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/sim/gyro_model.h"
#include "gyrotherm/sim/options.h"
#include "gyrotherm/sim/thermal_plant.h"

namespace gyrotherm::analysis {
namespace {

constexpr double kSigmas = 4.0;  // truth within 4 standard errors
constexpr double kGyroHz = 10.0;

sim::GyroParams truth_params() {
  sim::GyroParams g;
  g.bias_dph = 0.5;
  g.temp_coeffs = {0.01, -3e-4, 4e-6};  // T1..T3, deg/h per degC^i
  g.rate_coeffs = {30.0};               // R1, deg/h per degC/s
  g.gradient_coeffs = {0.8};            // G1, deg/h per degC
  g.white_noise_dph = 1.0;
  g.bias_instability_dph = 0.0;
  g.rate_random_walk_dph_per_sqrt_h = 0.0;
  return g;
}

// One run: soak at -20 degC for 30 min, ramp to 60 at 1 degC/min, soak 1 h,
// ramp back, soak 30 min (16800 s of station time), read as the station does.
AnalysisSeries simulate_run(double gradient_per_c_per_min, double gradient_offset_c, uint64_t seed,
                            double gradient_tau_s = 0.0) {
  sim::ThermalParams tp;
  tp.initial_temp_c = -20.0;
  tp.max_ramp_c_per_min = 1.0;
  tp.gradient_c_per_c_per_min = gradient_per_c_per_min;
  tp.gradient_offset_c = gradient_offset_c;
  tp.gradient_tau_s = gradient_tau_s;
  tp.probe_noise_c = 0.005;
  tp.probe_quantum_c = 0.001;
  sim::ThermalPlant plant(tp, seed);
  drivers::GyroFormat format;
  format.rate_hz = kGyroHz;
  const double earth_dph = earth_rate_component_dph(31.9, AxisOrientation::kUp);
  sim::GyroModel gyro(truth_params(), format, earth_dph, seed + 1);

  std::vector<GyroSample> samples;
  std::vector<TemperatureSample> temps;
  const double dt_s = 1.0 / kGyroHz;
  const long steps = 168000;
  samples.reserve(static_cast<std::size_t>(steps));
  for (long k = 1; k <= steps; ++k) {
    const double t_s = static_cast<double>(k) * dt_s;
    const double setpoint_c = t_s < 1800 ? -20.0 : t_s < 10200 ? 60.0 : -20.0;
    plant.step(dt_s, setpoint_c);
    const drivers::GyroFrame frame = gyro.next_frame(plant.truth());
    GyroSample g;
    g.t_s = t_s;
    g.rate_dph = drivers::to_rate_dph(frame.gyro[static_cast<std::size_t>(format.axis)], format);
    samples.push_back(g);
    if (k % 10 == 0) {
      TemperatureSample s;
      s.t_s = t_s;
      s.setpoint_c = setpoint_c;
      s.chamber_c = plant.truth().air_c;
      s.top_c = plant.readings().top_c;
      s.side_c = plant.readings().side_c;
      temps.push_back(s);
    }
  }
  auto series = make_analysis_series(samples, temps, 1.0);
  EXPECT_TRUE(series.ok()) << series.error().message;
  return *series;
}

const AnalysisSeries& one_ramp() {
  static const AnalysisSeries r = simulate_run(1.0, 0.05, 44, 1800.0);
  return r;
}

const std::vector<AnalysisSeries>& runs() {
  static const std::vector<AnalysisSeries> r = {
      simulate_run(0.3, 0.05, 11), simulate_run(-0.25, 0.4, 22), simulate_run(0.1, -0.3, 33)};
  return r;
}

std::map<std::string, double> truth_coefficients() {
  const sim::GyroParams g = truth_params();
  const double earth_dph = earth_rate_component_dph(31.9, AxisOrientation::kUp);
  return {{"intercept", earth_dph + g.bias_dph},
          {"T1", g.temp_coeffs[0]},
          {"T2", g.temp_coeffs[1]},
          {"T3", g.temp_coeffs[2]},
          {"R1", g.rate_coeffs[0]},
          {"G1", g.gradient_coeffs[0]}};
}

TEST(SimTruth, OneLongRampRecoversTheTruthWithinItsStandardErrors) {
  auto fit = fit_drift_model(one_ramp(), *parse_model_spec("T3+R1+G1"), DriftModelForm::kCentered);
  ASSERT_TRUE(fit.ok()) << fit.error().message;
  EXPECT_NEAR(fit->residual_std_dph, 1.0, 0.03);
  for (const auto& [name, value] : truth_coefficients()) {
    const double se = fit->std_errors.at(name);
    const double got = fit->coefficients.at(name);
    EXPECT_LE(std::abs(got - value), kSigmas * se)
        << name << ": fitted " << got << " +- " << se << ", truth " << value << " ("
        << (got - value) / se << " standard errors)";
    EXPECT_LT(se, 0.2 * std::abs(value)) << name << ": the ramp determines it";
  }
  // The same ramp with an instantaneous gradient cannot separate G from R:
  // their standard errors blow up (or the design is reported rank-deficient).
  const AnalysisSeries collinear = simulate_run(1.0, 0.05, 44, 0.0);
  auto bad = fit_drift_model(collinear, *parse_model_spec("T3+R1+G1"), DriftModelForm::kCentered);
  if (bad.ok()) {
    EXPECT_GT(bad->std_errors.at("G1"), 5 * fit->std_errors.at("G1"));
  } else {
    EXPECT_NE(bad.error().message.find("rank"), std::string::npos) << bad.error().message;
  }
}

TEST(SimTruth, CentredFitRecoversTheTruthWithinItsStandardErrors) {
  const sim::GyroParams g = truth_params();
  const double earth_dph = earth_rate_component_dph(31.9, AxisOrientation::kUp);
  const std::map<std::string, double> truth = {{"intercept", earth_dph + g.bias_dph},
                                               {"T1", g.temp_coeffs[0]},
                                               {"T2", g.temp_coeffs[1]},
                                               {"T3", g.temp_coeffs[2]},
                                               {"R1", g.rate_coeffs[0]},
                                               {"G1", g.gradient_coeffs[0]}};
  ASSERT_EQ(runs().size(), 3u);
  EXPECT_EQ(runs()[0].t_s.size(), 16800u);  // 1 s bins of 16800 s
  auto fit = fit_drift_model(runs(), *parse_model_spec("T3+R1+G1"), DriftModelForm::kCentered);
  ASSERT_TRUE(fit.ok()) << fit.error().message;
  // White noise of 1 deg/h per 1 s mean: the residual std is that.
  EXPECT_NEAR(fit->residual_std_dph, 1.0, 0.02);
  for (const auto& [name, value] : truth) {
    const double se = fit->std_errors.at(name);
    const double got = fit->coefficients.at(name);
    EXPECT_GT(se, 0.0) << name;
    EXPECT_LE(std::abs(got - value), kSigmas * se)
        << name << ": fitted " << got << " +- " << se << ", truth " << value << " ("
        << (got - value) / se << " standard errors)";
    // The standard errors are small enough to mean something: each
    // coefficient is determined to better than 10 % of its truth.
    EXPECT_LT(se, 0.1 * std::abs(value)) << name;
  }
}

TEST(SimTruth, CompensatedStdFollowsThePapersOrderOnOneRamp) {
  auto c = compare_models(std::vector<AnalysisSeries>{one_ramp()});
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_EQ(c->cells.size(), 12u);
  for (int order = 1; order <= 4; ++order) {
    SCOPED_TRACE(fmt::format("order {}", order));
    const auto& t = c->cells[static_cast<std::size_t>(order - 1)];
    const auto& tg = c->cells[static_cast<std::size_t>(4 + order - 1)];
    const auto& tgr = c->cells[static_cast<std::size_t>(8 + order - 1)];
    ASSERT_TRUE(t.in_sample && tg.in_sample && tgr.in_sample)
        << t.in_sample_error << tg.in_sample_error << tgr.in_sample_error;
    EXPECT_GT(c->none.std_dph, t.in_sample->std_dph);
    EXPECT_GT(t.in_sample->std_dph, tg.in_sample->std_dph);
    EXPECT_GT(tg.in_sample->std_dph, tgr.in_sample->std_dph);
    EXPECT_FALSE(tgr.cross_validated.has_value()) << "one run: nothing to leave out";
    EXPECT_FALSE(tgr.cross_validated_error.empty());
  }
}

TEST(SimTruth, CompensatedStdFollowsThePapersOrder) {
  auto c = compare_models(runs());
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_EQ(c->cells.size(), 12u);
  for (int order = 1; order <= 4; ++order) {
    const auto& t = c->cells[static_cast<std::size_t>(order - 1)];
    const auto& tg = c->cells[static_cast<std::size_t>(4 + order - 1)];
    const auto& tgr = c->cells[static_cast<std::size_t>(8 + order - 1)];
    ASSERT_EQ(to_string(tgr.spec), fmt::format("T{}+R1+G1", order));
    ASSERT_TRUE(t.in_sample && tg.in_sample && tgr.in_sample)
        << t.in_sample_error << tg.in_sample_error << tgr.in_sample_error;
    SCOPED_TRACE(fmt::format("order {}", order));
    EXPECT_GT(c->none.std_dph, t.in_sample->std_dph);
    EXPECT_GT(t.in_sample->std_dph, tg.in_sample->std_dph);
    EXPECT_GT(tg.in_sample->std_dph, tgr.in_sample->std_dph);
    // The full model leaves the white noise, 1 deg/h per bin and ~0.1 after
    // the default 101-point moving average (raw bins: ~1.0).
    EXPECT_LT(tgr.in_sample->std_dph, 1.05);
    // Leave-one-run-out works too on this data (no extrapolation in T).
    ASSERT_TRUE(tgr.cross_validated.has_value()) << tgr.cross_validated_error;
    EXPECT_LT(tgr.cross_validated->std_dph, 1.06);
  }
}

// At 1 s bins the white noise (1 deg/h) hides the temperature terms: every
// cell of the raw grid is within a few percent of "none". The default grid
// smooths each run's compensated output by a 101-point moving average (white
// noise / 10), so the models separate: the full model removes most of the
// smoothed spread.
TEST(SimTruth, SmoothedGridSeparatesTheModelsFromNone) {
  auto c = compare_models(runs());  // the defaults
  ASSERT_TRUE(c.ok()) << c.error().message;
  const auto& t2 = c->cells[1];
  const auto& tgr3 = c->cells[8 + 2];
  ASSERT_EQ(to_string(tgr3.spec), "T3+R1+G1");
  ASSERT_TRUE(t2.in_sample && tgr3.in_sample) << t2.in_sample_error << tgr3.in_sample_error;
  std::cout << fmt::format("default grid: none std {:.4f}, T2 {:.4f}, T3+R1+G1 {:.4f} deg/h\n",
                           c->none.std_dph, t2.in_sample->std_dph, tgr3.in_sample->std_dph);
  EXPECT_LT(tgr3.in_sample->std_dph, 0.5 * c->none.std_dph);
  EXPECT_LT(t2.in_sample->std_dph, 0.9 * c->none.std_dph);
}

// Table I's mean uncertainty against the simulator's truth, blind to the
// noise: 240 seeded soaks of the GyroModel at a steady 25 °C (600 s at
// 10 Hz), each with white noise drawn by [simulator.randomize]'s rule from
// 0.2-5 °/h (a 1 s mean's std). The 95 % interval of each Table I row's mean
// covers the model's noise-free output (Earth + bias + temperature term)
// 93-97 % of the time. The binomial spread of the count is ±1.4 %; the seed
// set is fixed, so the figure is the same on every run.
TEST(SimTruth, TableIMeanIntervalsCoverTheSimulatorsBiasNinetyFivePercentOfTheTime) {
  const int soaks = 240;
  const double earth_dph = earth_rate_component_dph(31.9, AxisOrientation::kUp);
  const sim::DrawRange white_range{0.2, 5.0};
  drivers::GyroFormat format;
  format.rate_hz = kGyroHz;
  sim::ThermalTruth steady;
  steady.air_c = steady.case_c = steady.top_c = steady.side_c = 25.0;
  std::vector<TemperatureSample> temps;
  for (int k = 0; k <= 601; ++k) {
    TemperatureSample s;
    s.t_s = k;
    s.setpoint_c = s.chamber_c = s.top_c = s.side_c = 25.0;
    temps.push_back(s);
  }
  int covered = 0;
  for (int i = 0; i < soaks; ++i) {
    std::mt19937_64 draw(sim::derive_seed(20261130, static_cast<uint64_t>(i)));
    sim::GyroParams g;
    g.bias_dph = -0.3;
    g.temp_coeffs = {0.004};
    g.white_noise_dph = white_range.draw(draw);
    sim::GyroModel gyro(g, format, earth_dph, sim::derive_seed(7, static_cast<uint64_t>(i)));
    std::vector<GyroSample> samples(6000);
    for (std::size_t k = 0; k < samples.size(); ++k) {
      samples[k].t_s = static_cast<double>(k + 1) / kGyroHz;
      samples[k].rate_dph = gyro.next_rate_dph(steady);
    }
    auto series = make_analysis_series(samples, temps, 1.0);
    ASSERT_TRUE(series.ok()) << series.error().message;
    auto row = table1_row(*series, {});
    ASSERT_TRUE(row.ok()) << row.error().message;
    ASSERT_TRUE(row->bias_u) << row->bias_u_note;
    const double truth_dph = earth_dph + g.bias_dph + 0.004 * 25.0;
    if (std::fabs(row->bias_mean_dph - truth_dph) <= row->bias_u->expanded_dph) ++covered;
  }
  const double coverage = static_cast<double>(covered) / soaks;
  std::printf("Table I on the simulator's gyro (white noise 0.2-5 °/h, blind): coverage %.2f %%\n",
              100.0 * coverage);
  EXPECT_GE(coverage, 0.93);
  EXPECT_LE(coverage, 0.97);
}

}  // namespace
}  // namespace gyrotherm::analysis
