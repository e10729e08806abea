// When an adaptive soak has acquired enough (analysis/acquisition_target.h):
// the projection of a white-noise soak against the closed form, the coverage
// of the stop's interval when soaks stop as soon as the target is reached
// (optional stopping must not make the interval lie), a random walk that puts
// the target out of reach, series with no model yet, and input errors.
#include "gyrotherm/analysis/acquisition_target.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "test_trials.h"

namespace gyrotherm::analysis {
namespace {

struct Series {
  std::vector<double> t_s, rate_dph;
};

// 1 Hz bins: white rate noise of std sigma_dph, and a rate random walk of K
// (°/h/√h: a step of K / 60 °/h per second).
Series make_series(std::size_t n, double sigma_dph, double k_dphprh, std::mt19937_64& rng) {
  std::normal_distribution<double> normal;
  Series s;
  double walk = 0;
  for (std::size_t i = 0; i < n; ++i) {
    walk += k_dphprh / 60.0 * normal(rng);
    s.t_s.push_back(static_cast<double>(i));
    s.rate_dph.push_back(sigma_dph * normal(rng) + walk);
  }
  return s;
}

TEST(AcquisitionTarget, WhiteNoiseProjectsTheClosedFormLength) {
  // sigma 1 °/h at 1 Hz: U95(T) ~ 1.96 / sqrt(T), the target 0.1 °/h at
  // T = (1.96 / 0.1)^2 = 384 s. After 200 s the projection must say so
  // (within the noise of a 200-point fit and its coverage factor: 35 %).
  std::mt19937_64 rng(7);
  const Series s = make_series(200, 1.0, 0.0, rng);
  const AcquisitionTarget target{.target_u95_dph = 0.1, .min_s = 60, .max_s = 3600};
  auto p = project_acquisition(s.t_s, s.rate_dph, 200, target);
  ASSERT_TRUE(p) << p.error().message;
  EXPECT_EQ(p->verdict, AcquisitionVerdict::kContinue) << p->note;
  ASSERT_TRUE(p->reach_s) << p->note;
  EXPECT_NEAR(*p->reach_s, 384.0, 0.35 * 384.0) << p->note;
  ASSERT_TRUE(p->now);
  EXPECT_NEAR(p->now->expanded_dph, 1.96 / std::sqrt(200.0), 0.3 * 1.96 / std::sqrt(200.0));

  const Series longer = make_series(2000, 1.0, 0.0, rng);
  p = project_acquisition(longer.t_s, longer.rate_dph, 2000, target);
  ASSERT_TRUE(p) << p.error().message;
  EXPECT_EQ(p->verdict, AcquisitionVerdict::kReached) << p->note;
  EXPECT_NE(p->note.find("target reached"), std::string::npos) << p->note;
}

TEST(AcquisitionTarget, StoppingAtTheTargetKeepsTheIntervalHonest) {
  // 300 seeded white-noise soaks, each checked every 60 s from 60 s on and
  // stopped at the first "reached"; the true mean is 0. The stop's 95 %
  // interval must cover it about as often as a fixed-length soak's (optional
  // stopping on u alone, which does not depend on the mean for white noise,
  // keeps coverage), and every soak must stop near the closed-form length.
  constexpr int kSoaks = gyrotherm::testing::trials(300);
  const AcquisitionTarget target{.target_u95_dph = 0.1, .min_s = 60, .max_s = 1800};
  std::mt19937_64 rng(2026);
  int covered = 0, reached = 0;
  double sum_stop_s = 0;
  for (int i = 0; i < kSoaks; ++i) {
    const Series s = make_series(1800, 1.0, 0.0, rng);
    for (std::size_t n = 60; n <= s.t_s.size(); n += 60) {
      std::span<const double> t(s.t_s.data(), n), r(s.rate_dph.data(), n);
      auto p = project_acquisition(t, r, static_cast<double>(n), target);
      ASSERT_TRUE(p) << p.error().message;
      if (p->verdict != AcquisitionVerdict::kReached) continue;
      double mean = 0;
      for (double v : r) mean += v;
      mean /= static_cast<double>(n);
      covered += std::fabs(mean) <= p->now->expanded_dph ? 1 : 0;
      ++reached;
      sum_stop_s += static_cast<double>(n);
      break;
    }
  }
  const double coverage = static_cast<double>(covered) / reached;
  const double mean_stop_s = sum_stop_s / reached;
  std::printf(
      "adaptive white-noise soaks: %d of %d reached the target, coverage %.3f, mean stop "
      "%.0f s (closed form %.0f s)\n",
      reached, kSoaks, coverage, mean_stop_s, std::pow(1.96 / 0.1, 2));
  EXPECT_EQ(reached, kSoaks);
  if (!gyrotherm::testing::statistics_checked()) return;
  EXPECT_GE(coverage, 0.92);
  EXPECT_LE(coverage, 0.99);
  // (1.96 / 0.1)^2 = 384 s: the first check past it is 420 s; the noise of
  // each soak's own u moves the stop by a check or two either way, and a
  // spurious flicker term in a short fit can delay it.
  EXPECT_GE(mean_stop_s, 330.0);
  EXPECT_LE(mean_stop_s, 600.0);
}

TEST(AcquisitionTarget, ARandomWalkPutsTheTargetOutOfReach) {
  // K = 6 °/h/√h over 30 min: u grows with T beyond a few seconds, so no
  // longer soak helps; the target 0.05 °/h is out of reach and the note says
  // why, with the floor.
  std::mt19937_64 rng(11);
  const Series s = make_series(1800, 0.2, 6.0, rng);
  const AcquisitionTarget target{.target_u95_dph = 0.05, .min_s = 600, .max_s = 7200};
  auto p = project_acquisition(s.t_s, s.rate_dph, 1800, target);
  ASSERT_TRUE(p) << p.error().message;
  EXPECT_EQ(p->verdict, AcquisitionVerdict::kOutOfReach) << p->note;
  EXPECT_NE(p->note.find("floor = "), std::string::npos) << p->note;
  EXPECT_NE(p->note.find("random walk"), std::string::npos) << p->note;
  EXPECT_GT(p->best_u95_dph, target.target_u95_dph);
  EXPECT_FALSE(p->reach_s);
}

TEST(AcquisitionTarget, AWhiteNoiseAxisIsNotCalledOutOfReachOnAChanceTerm) {
  // 400 seeded white-noise axes of 14 min (1 °/h 1 s means), a target no
  // length up to the 30 min cap reaches (U95(1800 s) = 0.046 °/h): the
  // noise model now and then keeps a rate random walk or flicker term the
  // last, few-dof points of the curve suggest; projected, it makes U95 flat
  // and the target "out of reach". Only a term beyond doubt (kOutOfReachZ)
  // may say so: a white-noise axis must be told so rarely (measured: 0 of
  // 400; at 1.96 standard uncertainties, 14).
  const AcquisitionTarget target{.target_u95_dph = 0.01, .min_s = 600, .max_s = 1800};
  std::mt19937_64 rng(404);
  int out_of_reach = 0, flat_by_chance = 0;
  constexpr int kAxes = gyrotherm::testing::trials(400);
  for (int i = 0; i < kAxes; ++i) {
    const Series s = make_series(840, 1.0, 0.0, rng);
    auto p = project_acquisition(s.t_s, s.rate_dph, 840, target);
    ASSERT_TRUE(p) << p.error().message;
    if (p->verdict == AcquisitionVerdict::kOutOfReach) ++out_of_reach;
    if (p->note.find("but it is not certain yet") != std::string::npos) ++flat_by_chance;
  }
  std::printf("white-noise axes: %d of %d out of reach, %d kept on with a chance term\n",
              out_of_reach, kAxes, flat_by_chance);
  if (!gyrotherm::testing::statistics_checked()) return;
  EXPECT_LE(out_of_reach, kAxes / 100);
  EXPECT_GT(flat_by_chance, 0) << "no chance term met: the test no longer tests the guard";
}

// A wandering bias (Gauss-Markov, sigma_g 0.01 °/h, T_c 300 s; white noise
// 0.02 °/h at 1 s) judged after 10 min: its curve still rises like a rate
// random walk, but the mean's uncertainty falls past T_c, and a 2-h cap
// reaches 0.006 °/h (the variance of a 2-h mean, 2 sigma_g² T_c / T, gives
// U95 0.0056). The soak must not be ended out of reach on a walk that is
// not there; a real walk far steeper than any wandering bias that reaches
// the target still is.
TEST(AcquisitionTarget, AWanderingBiasThatHasNotTurnedIsNotCalledOutOfReach) {
  const AcquisitionTarget target{.target_u95_dph = 0.006, .min_s = 600, .max_s = 7200};
  const int soaks = gyrotherm::testing::trials(100);
  std::mt19937_64 rng(20261201);
  std::normal_distribution<double> normal(0.0, 1.0);
  const double phi = std::exp(-1.0 / 300.0);
  int out_of_reach = 0, unturned = 0;
  for (int i = 0; i < soaks; ++i) {
    std::vector<double> t, r;
    double gm = 0.01 * normal(rng);
    for (int k = 0; k < 600; ++k) {
      t.push_back(k);
      r.push_back(0.3 + 0.02 * normal(rng) + gm);
      gm = phi * gm + 0.01 * std::sqrt(1 - phi * phi) * normal(rng);
    }
    auto p = project_acquisition(t, r, 600, target);
    ASSERT_TRUE(p) << p.error().message;
    out_of_reach += p->verdict == AcquisitionVerdict::kOutOfReach;
    unturned += p->note.find("has not turned yet") != std::string::npos;
  }
  std::printf("wandering-bias axes after 10 min: %d of %d out of reach, %d kept on as unturned\n",
              out_of_reach, soaks, unturned);
  // Before the rule, 11 of the 100 were out of reach; with it, 1.
  if (gyrotherm::testing::statistics_checked()) {
    EXPECT_LE(out_of_reach, soaks / 20);
    EXPECT_GT(unturned, 0) << "no walk-like curve met: the test no longer tests the rule";
  }

  // A walk whose rise the 2-h cap cannot undo: K = 2 °/h/√h (the walk's
  // mean over 2 h alone has U95 ~1.9 °/h, far above 0.05).
  std::mt19937_64 walk_rng(7);
  const Series s = make_series(600, 0.02, 2.0, walk_rng);
  auto p = project_acquisition(s.t_s, s.rate_dph, 600,
                               {.target_u95_dph = 0.05, .min_s = 600, .max_s = 7200});
  ASSERT_TRUE(p) << p.error().message;
  EXPECT_EQ(p->verdict, AcquisitionVerdict::kOutOfReach) << p->note;
}

TEST(AcquisitionTarget, NoModelYetIsSaidNotGuessed) {
  const AcquisitionTarget target{.target_u95_dph = 0.1, .min_s = 0, .max_s = 600};
  const std::vector<double> t{0, 1, 2, 3, 4}, r{1, 2, 1, 2, 1};
  auto p = project_acquisition(t, r, 5, target);
  ASSERT_TRUE(p) << p.error().message;
  EXPECT_EQ(p->verdict, AcquisitionVerdict::kNoModel);
  EXPECT_FALSE(p->note.empty());
  EXPECT_FALSE(p->now);

  std::vector<double> tc(64), rc(64, 0.5);
  for (std::size_t i = 0; i < tc.size(); ++i) tc[i] = static_cast<double>(i);
  p = project_acquisition(tc, rc, 64, target);
  ASSERT_TRUE(p) << p.error().message;
  EXPECT_EQ(p->verdict, AcquisitionVerdict::kNoModel) << p->note;
}

TEST(AcquisitionTarget, BadInputIsRefusedByName) {
  const std::vector<double> t{0, 1, 2}, r{1, 2};
  auto p = project_acquisition(t, r, 3, {.target_u95_dph = 0.1, .min_s = 0, .max_s = 60});
  ASSERT_FALSE(p);
  EXPECT_NE(p.error().message.find("3 times but 2 rates"), std::string::npos);
  std::string why;
  EXPECT_FALSE((AcquisitionTarget{.target_u95_dph = 0, .min_s = 0, .max_s = 60}.is_valid(&why)));
  EXPECT_NE(why.find("target_u95_dph"), std::string::npos) << why;
  EXPECT_FALSE((AcquisitionTarget{.target_u95_dph = 1, .min_s = 90, .max_s = 60}.is_valid(&why)));
  EXPECT_NE(why.find("below min_s"), std::string::npos) << why;
  const std::vector<double> r3{1, 2, 3};
  p = project_acquisition(t, r3, 0, {.target_u95_dph = 0.1, .min_s = 0, .max_s = 60});
  ASSERT_FALSE(p);
  EXPECT_NE(p.error().message.find("acquired 0 s"), std::string::npos) << p.error().message;
}

}  // namespace
}  // namespace gyrotherm::analysis
