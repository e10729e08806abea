// When the soak's stability gate will hold (analysis/settle_prediction.h):
// first-order and two-node (air lag, then shell) plants with a known truth,
// the gate evaluated here by brute force on the noise-free series, the
// calibration of P10-P90 over seeded plants, the verdicts, input errors.
#include "gyrotherm/analysis/settle_prediction.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "test_trials.h"

namespace gyrotherm::analysis {
namespace {

struct Series {
  std::vector<double> t_s, c;
};

// Air: an exponential from `from_c` to `to_c` + `offset_c` with tau_air_s
// (0: a step); shell: a first-order lag on the air with tau_shell_s, so
//   shell(t) = end + (from - end) (tau_s e^(-t/tau_s) - tau_a e^(-t/tau_a)) / (tau_s - tau_a)
// (the lag equation's solution; a plain exponential for a step). `offset_c`:
// a shell that settles off the set point. Sampled at 1 Hz from 0 to
// `until_s`, plus white noise of std noise_c.
Series plant(double from_c, double to_c, double tau_air_s, double tau_shell_s, double until_s,
             double noise_c, std::mt19937_64& rng, double offset_c = 0) {
  std::normal_distribution<double> normal(0.0, 1.0);
  const double end = to_c + offset_c;
  Series s;
  for (int sec = 0; sec <= static_cast<int>(until_s); ++sec) {
    const double t = sec;
    const double shape =
        tau_air_s > 0
            ? (tau_shell_s * std::exp(-t / tau_shell_s) - tau_air_s * std::exp(-t / tau_air_s)) /
                  (tau_shell_s - tau_air_s)
            : std::exp(-t / tau_shell_s);
    s.t_s.push_back(t);
    s.c.push_back(end + (from_c - end) * shape + (noise_c > 0 ? noise_c * normal(rng) : 0.0));
  }
  return s;
}

// The gate as the sequencer states it, by brute force over the samples:
// the first sample time at which the window's least-squares slope and mean
// pass. -1 when never within the series.
double gate_time_brute_force(const Series& s, const SettleGate& g) {
  for (std::size_t end = 0; end < s.t_s.size(); ++end) {
    if (s.t_s[end] < g.window_s) continue;
    double st = 0, sy = 0, n = 0;
    for (std::size_t i = 0; i <= end; ++i) {
      if (s.t_s[i] > s.t_s[end] - g.window_s) {
        st += s.t_s[i];
        sy += s.c[i];
        ++n;
      }
    }
    const double mt = st / n, my = sy / n;
    double stt = 0, sty = 0;
    for (std::size_t i = 0; i <= end; ++i) {
      if (s.t_s[i] > s.t_s[end] - g.window_s) {
        stt += (s.t_s[i] - mt) * (s.t_s[i] - mt);
        sty += (s.t_s[i] - mt) * (s.c[i] - my);
      }
    }
    if (std::fabs(sty / stt * 60) < g.stability_c_per_min &&
        std::fabs(my - g.setpoint_c) <= g.tolerance_c) {
      return s.t_s[end];
    }
  }
  return -1;
}

Series head(const Series& s, double until_s) {
  Series h;
  for (std::size_t i = 0; i < s.t_s.size() && s.t_s[i] <= until_s; ++i) {
    h.t_s.push_back(s.t_s[i]);
    h.c.push_back(s.c[i]);
  }
  return h;
}

const SettleGate kGate{
    .setpoint_c = 40, .tolerance_c = 0.5, .stability_c_per_min = 0.02, .window_s = 600};

TEST(SettlePrediction, FirstOrderPlantIsPredictedWithinItsBand) {
  std::mt19937_64 rng(7);
  std::mt19937_64 none(0);
  const Series truth = plant(20, 40, 0, 1500, 20'000, 0, none);
  const double gate_s = gate_time_brute_force(truth, kGate);
  ASSERT_GT(gate_s, 0);
  const Series data = head(plant(20, 40, 0, 1500, 20'000, 0.01, rng), 2400);
  auto p = predict_settle(data.t_s, data.c, kGate);
  ASSERT_TRUE(p.ok()) << p.error().message;
  ASSERT_EQ(p->verdict, SettleVerdict::kPredicted) << p->note;
  ASSERT_TRUE(p->p10_s && p->p50_s && p->p90_s);
  EXPECT_LE(*p->p10_s, *p->p50_s);
  EXPECT_LE(*p->p50_s, *p->p90_s);
  // One plant: P10-P90 is an 80 % band, so whether it holds this truth is
  // measured over many plants (below); the median is near it.
  EXPECT_NEAR(*p->p50_s, gate_s, 0.05 * gate_s) << "P10 " << *p->p10_s << " P90 " << *p->p90_s;
  EXPECT_NEAR(*p->tau_s, 1500, 75);
  EXPECT_NEAR(*p->final_c, 40, 0.1);
}

TEST(SettlePrediction, TwoNodePlantIsFittedFromItsSteepestPoint) {
  std::mt19937_64 rng(8);
  std::mt19937_64 none(0);
  const Series truth = plant(20, 40, 300, 1200, 20'000, 0, none);
  const double gate_s = gate_time_brute_force(truth, kGate);
  ASSERT_GT(gate_s, 0);
  const Series data = head(plant(20, 40, 300, 1200, 20'000, 0.01, rng), 3000);
  auto p = predict_settle(data.t_s, data.c, kGate);
  ASSERT_TRUE(p.ok()) << p.error().message;
  ASSERT_EQ(p->verdict, SettleVerdict::kPredicted) << p->note;
  EXPECT_NEAR(*p->p50_s, gate_s, 0.10 * gate_s) << "P10 " << *p->p10_s << " P90 " << *p->p90_s;
}

TEST(SettlePrediction, EarlyInTheRiseThereIsNotEnoughCurvature) {
  std::mt19937_64 rng(9);
  const Series data = head(plant(20, 40, 300, 1200, 20'000, 0.01, rng), 90);
  auto p = predict_settle(data.t_s, data.c, kGate);
  ASSERT_TRUE(p.ok()) << p.error().message;
  EXPECT_EQ(p->verdict, SettleVerdict::kNotEnoughCurvature);
  EXPECT_NE(p->note.find("not enough curvature yet"), std::string::npos) << p->note;
  EXPECT_FALSE(p->p50_s);
}

TEST(SettlePrediction, AGateThatHoldsAlreadyIsSaid) {
  std::mt19937_64 rng(10);
  const Series data = plant(20, 40, 0, 600, 9000, 0.01, rng);
  auto p = predict_settle(data.t_s, data.c, kGate);
  ASSERT_TRUE(p.ok()) << p.error().message;
  EXPECT_EQ(p->verdict, SettleVerdict::kHoldsNow) << p->note;
  EXPECT_EQ(*p->p50_s, data.t_s.back());
}

TEST(SettlePrediction, AShellThatSettlesOutsideTheToleranceIsSaid) {
  std::mt19937_64 rng(11);
  // Four time constants of data: the decay is seen, the final value known.
  const Series data = head(plant(20, 40, 0, 1500, 20'000, 0.01, rng, 1.0), 6000);
  auto p = predict_settle(data.t_s, data.c, kGate);
  ASSERT_TRUE(p.ok()) << p.error().message;
  EXPECT_EQ(p->verdict, SettleVerdict::kNeverWithinTolerance) << p->note;
  EXPECT_NEAR(*p->final_c, 41, 0.1);
  EXPECT_NE(p->note.find("outside 40 ± 0.5 °C"), std::string::npos) << p->note;
}

// Over seeded plants (shell tau 600-2400 s, air lag 0-400 s, probe noise
// 0.005-0.03 °C), predicted at a third of the truth's gate time: the share
// of true gate times inside P10-P90. The goal is about 80 %; measured 59 %
// (docs/analysis.md, "Settle time": the first-order fit of a two-node plant
// this early is too sure of itself). The bounds guard what is reached.
TEST(SettlePrediction, TheP10ToP90BandIsMeasuredOverFiftySeededPlants) {
  std::mt19937_64 params(2026);
  std::uniform_real_distribution<double> tau_shell(600, 2400), tau_air(0, 400), noise(0.005, 0.03);
  int inside = 0, predicted = 0, open = 0;
  const int plants = gyrotherm::testing::trials(50);
  for (int i = 0; i < plants; ++i) {
    const double ts = tau_shell(params), ta = tau_air(params), sd = noise(params);
    std::mt19937_64 none(0), rng(100 + i);
    const Series truth = plant(20, 40, ta, ts, 40'000, 0, none);
    const double gate_s = gate_time_brute_force(truth, kGate);
    ASSERT_GT(gate_s, 0);
    const Series data =
        head(plant(20, 40, ta, ts, 40'000, sd, rng), std::max(gate_s / 3, ta * 2 + 600));
    auto p = predict_settle(data.t_s, data.c, kGate);
    ASSERT_TRUE(p.ok()) << p.error().message;
    if (p->verdict != SettleVerdict::kPredicted || !p->p10_s) {
      std::printf("plant %d (tau %.0f s, air %.0f s): %s: %s\n", i, ts, ta,
                  std::string(to_string(p->verdict)).c_str(), p->note.c_str());
      continue;
    }
    ++predicted;
    // No P90: beyond the horizon, an open band.
    if (*p->p10_s <= gate_s && (!p->p90_s || gate_s <= *p->p90_s)) ++inside;
    if (!p->p90_s) ++open;
  }
  const double share = predicted > 0 ? static_cast<double>(inside) / predicted : 0;
  std::printf(
      "settle prediction: %d of %d plants predicted at a third of their gate time, "
      "truth inside P10-P90 in %.0f %% of them (%d with P90 beyond the horizon)\n",
      predicted, plants, 100 * share, open);
  if (!gyrotherm::testing::statistics_checked()) return;
  EXPECT_GE(predicted, plants * 9 / 10);
  EXPECT_GE(share, 0.5);
  EXPECT_LE(share, 0.97);
}

TEST(SettlePrediction, BadInputIsNamed) {
  const std::vector<double> t = {0, 1, 2}, c = {20, 21, 22};
  EXPECT_FALSE(predict_settle(t, std::vector<double>{20, 21}, kGate).ok());
  auto nan = predict_settle(t, std::vector<double>{20, std::nan(""), 22}, kGate);
  ASSERT_FALSE(nan.ok());
  EXPECT_NE(nan.error().message.find("sample 1"), std::string::npos) << nan.error().message;
  auto back = predict_settle(std::vector<double>{0, 2, 1}, c, kGate);
  ASSERT_FALSE(back.ok());
  EXPECT_NE(back.error().message.find("sample 2"), std::string::npos) << back.error().message;
  SettleGate bad = kGate;
  bad.window_s = 0;
  EXPECT_FALSE(predict_settle(t, c, bad).ok());
  EXPECT_FALSE(predict_settle(t, c, kGate, {.bin_s = 0}).ok());
  auto empty = predict_settle(std::vector<double>{}, std::vector<double>{}, kGate);
  ASSERT_TRUE(empty.ok());
  EXPECT_EQ(empty->verdict, SettleVerdict::kNotEnoughCurvature);
}

}  // namespace
}  // namespace gyrotherm::analysis
