// The settle forecast's calibration on the simulator's plant (issue 27):
// over 50 seeded plants (air lag, case lag, control noise and the set point
// drawn per seed), a soak is stepped in-process at 1 s from 23 °C; the shell
// ((top + side) / 2 of the noisy, quantised probes) and the chamber air (as
// the chamber reports it, to 0.1 °C) are kept as the daemon's settle watch
// keeps them (2 s means), and the time the station's stability gate first
// holds (shell and air as the sequencer judges them) is the truth. At 25, 50
// and 75 % of each soak's true settle the forecast is made on the data so
// far; the test counts how often the truth falls inside its P10-P90 band
// (target: about 80 %) and prints the figures with the median error of P50.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <optional>
#include <random>
#include <vector>

#include "gyrotherm/analysis/settle_prediction.h"
#include "gyrotherm/sim/thermal_plant.h"
#include "test_trials.h"

namespace gyrotherm::analysis {
namespace {

constexpr int kPlants = gyrotherm::testing::trials(50);
constexpr double kFractions[] = {0.25, 0.5, 0.75};

// The sequencer's gate over 1 s readings: the shell's least-squares slope
// and the means of shell and air over the last window_s.
class Gate {
 public:
  explicit Gate(const SettleGate& g) : g_(g) {}
  bool add(double t, double shell, double air) {
    pts_.push_back({t, shell, air});
    while (pts_.front().t <= t - g_.window_s) pts_.pop_front();
    if (t - pts_.front().t < g_.window_s - 1.5) return false;
    double st = 0, sy = 0, sa = 0;
    for (const auto& p : pts_) {
      st += p.t;
      sy += p.shell;
      sa += p.air;
    }
    const double n = static_cast<double>(pts_.size());
    const double mt = st / n, my = sy / n, ma = sa / n;
    double stt = 0, sty = 0;
    for (const auto& p : pts_) {
      stt += (p.t - mt) * (p.t - mt);
      sty += (p.t - mt) * (p.shell - my);
    }
    const double slope_c_per_min = sty / stt * 60.0;
    return std::fabs(slope_c_per_min) < g_.stability_c_per_min &&
           std::fabs(my - g_.setpoint_c) <= g_.tolerance_c &&
           std::fabs(ma - g_.setpoint_c) <= g_.tolerance_c;
  }

 private:
  struct P {
    double t, shell, air;
  };
  SettleGate g_;
  std::deque<P> pts_;
};

struct Soak {
  std::vector<double> t_s, shell_c, air_c;  // 2 s means
  double settled_s = 0;                     // the gate's first hold (1 s ticks)
};

// One seeded plant's soak from 23 °C to its set point, stepped until the
// gate holds (at most 8 h).
std::optional<Soak> play(int seed, SettleGate& gate) {
  std::mt19937_64 rng(static_cast<uint64_t>(seed) * 7919 + 13);
  auto log_uniform = [&](double lo, double hi) {
    return std::exp(std::uniform_real_distribution<double>(std::log(lo), std::log(hi))(rng));
  };
  sim::ThermalParams p;
  p.air_tau_s = log_uniform(60, 300);
  p.case_tau_s = log_uniform(600, 2400);
  p.control_noise_c = std::uniform_real_distribution<double>(0.1, 0.5)(rng);
  double sp = std::uniform_real_distribution<double>(-15, 60)(rng);
  if (std::fabs(sp - 23) < 8) sp = sp < 23 ? sp - 8 : sp + 8;
  gate.setpoint_c = sp;
  sim::ThermalPlant plant(p, static_cast<uint64_t>(seed) + 1);
  Gate g(gate);
  Soak s;
  double pack_t = 0, pack_s = 0, pack_a = 0;
  int pack_n = 0;
  for (int k = 1; k <= 8 * 3600; ++k) {
    plant.step(1.0, sp);
    const double t = k;
    const double shell = (plant.readings().top_c + plant.readings().side_c) / 2;
    const double air = std::round(plant.truth().air_c * 10) / 10;
    pack_t += t;
    pack_s += shell;
    pack_a += air;
    if (++pack_n == 2) {
      s.t_s.push_back(pack_t / 2);
      s.shell_c.push_back(pack_s / 2);
      s.air_c.push_back(pack_a / 2);
      pack_t = pack_s = pack_a = 0;
      pack_n = 0;
    }
    if (g.add(t, shell, air)) {
      s.settled_s = t;
      return s;
    }
  }
  return std::nullopt;
}

struct Tally {
  int made = 0, inside = 0, early = 0, late = 0, none = 0;
  std::vector<double> p50_error_frac;  // (P50 - truth) / the time left
};

TEST(SettleCalibration, TheBandHoldsTheGateOnSeededPlants) {
  Tally all;
  Tally by_fraction[3];
  for (int seed = 0; seed < kPlants; ++seed) {
    SettleGate gate{
        .setpoint_c = 0, .tolerance_c = 0.5, .stability_c_per_min = 0.02, .window_s = 600};
    auto soak = play(seed, gate);
    ASSERT_TRUE(soak) << "plant " << seed << " did not settle in 8 h";
    for (int f = 0; f < 3; ++f) {
      const double at_s = kFractions[f] * soak->settled_s;
      const auto n = static_cast<std::size_t>(
          std::upper_bound(soak->t_s.begin(), soak->t_s.end(), at_s) - soak->t_s.begin());
      std::span<const double> t(soak->t_s.data(), n), shell(soak->shell_c.data(), n),
          air(soak->air_c.data(), n);
      auto pred = predict_settle(t, shell, gate, {}, air);
      ASSERT_TRUE(pred) << pred.error().message;
      for (Tally* tally : {&all, &by_fraction[f]}) {
        if (pred->verdict != SettleVerdict::kPredicted || !pred->p10_s) {
          ++tally->none;
          continue;
        }
        ++tally->made;
        const double truth = soak->settled_s;
        const double hi = pred->p90_s.value_or(std::numeric_limits<double>::infinity());
        if (truth < *pred->p10_s) {
          ++tally->early;
        } else if (truth > hi) {
          ++tally->late;
        } else {
          ++tally->inside;
        }
        if (pred->p50_s) tally->p50_error_frac.push_back((*pred->p50_s - truth) / (truth - at_s));
      }
    }
  }
  auto median = [](std::vector<double> v) {
    if (v.empty()) return std::nan("");
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  for (int f = 0; f < 3; ++f) {
    const Tally& t = by_fraction[f];
    std::printf(
        "settle forecast at %2.0f %% of the settle: %2d made, %2d inside P10-P90 (%.0f %%), "
        "%2d truth before P10, %2d after P90, %2d without a forecast; median P50 error "
        "%+.0f %% of the time left\n",
        100 * kFractions[f], t.made, t.inside, t.made ? 100.0 * t.inside / t.made : 0.0, t.early,
        t.late, t.none, 100 * median(t.p50_error_frac));
  }
  const double coverage = all.made ? static_cast<double>(all.inside) / all.made : 0.0;
  std::printf("settle forecast over %d plants: %d of %d inside P10-P90 (%.1f %%), %d without one\n",
              kPlants, all.inside, all.made, 100 * coverage, all.none);
  // About 80 % is the band's nominal coverage; a band that holds the truth
  // far less often is not calibrated, one that holds it always is too wide
  // to plan with.
  if (!gyrotherm::testing::statistics_checked()) return;
  EXPECT_GE(all.made, kPlants);  // a forecast at least at half the soaks' checks
  EXPECT_GE(coverage, 0.65);
  EXPECT_LE(coverage, 0.95);
}

}  // namespace
}  // namespace gyrotherm::analysis
