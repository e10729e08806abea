// Adaptive soaks against fixed ones on the paper's campaign (issue 27, item
// 6): chamber hours and the bias uncertainty they buy, on simulated gyros
// whose truth is known. Prints tables; not a pass/fail test. See
// bench/README.md, "Adaptive soaks against fixed ones (issue 27)".
//
// Per seed, one "station": one DUT with three axes whose noise is drawn per
// axis from the simulator's [simulator.randomize] ranges by its own rule
// (docs/simulator.md): white_noise_dph log-uniform in [0.005, 0.05] (std of
// a 1 s mean), bias_instability_dph uniform in [0, 0.01] (tau 300 s),
// rate_random_walk_dph_per_sqrt_h log-uniform in [0.0005, 0.005]; bias_dph
// uniform in [-1, 1] °/h. The campaign is config/schedules/paper-table1.toml
// (load_schedule, default StationLimits): 32 soaks whose acquire_s are the
// fixed lengths (68 ... 153 min).
//
// Each soak, each axis: a fresh sim::GyroModel (1 Hz output, so a sample is
// a 1 s mean; constant case temperature, no temperature, rate or gradient
// terms, Earth rate 0) started at the soak's first acquired second, seeded
// by (seed, soak, axis): its rate random walk starts at 0 there and its
// bias instability from its stationary distribution. That is the window u(T)
// describes (noise_model.h: the walk from the window's start), so the truth
// of a soak's mean is bias_dph. 2 x the fixed length is generated; the fixed
// soak reads the first L seconds, the adaptive soaks a prefix of the same
// stream (paired). A twin GyroModel with the same seed and the white noise
// and bias instability set to 0 (it draws the same normals) gives
// bias_dph + the walk alone: the second truth, "bias + the walk's mean over
// the soak", against which only the white noise and the bias instability
// are errors.
//
// Fixed: Table I's U95 = series_mean_uncertainty(series of L, L).expanded.
// Targets, per station, from its 32 x 3 fixed U95s: (a) their median,
// (b) their 90th percentile (linear interpolation), (c) their maximum.
// Adaptive with target T, min_min 10 (--min-min), cap 2 x L and cap L: as the station's
// AcquireWatch (every 120 s of acquiring) and the sequencer: at each
// judgement t = 120 k s with min_s <= t < cap, every axis's 1 s means so far
// (times 0 ... t - 1) go to project_acquisition(.., t, {T, min, cap}); the
// soak ends at the first judgement where every axis is reached or
// out_of_reach ("out of reach" when any axis is), else at the cap. The
// station also judges before min_s; those judgements cannot end a soak and
// are skipped here (in the station a verdict at 480 s may end the soak at
// 600 s; here the 600 s one does). The axes of a judgement are taken
// blocking axis first and stop at the first one not final: the same stop,
// fewer calls. The adaptive soak's U95 is series_mean_uncertainty at its
// stop length, as Table I would print it.
//
// Chamber hours = 32 x a 60 min settle + the acquisitions (the schedule has
// soaks only, no ramps).
//
// Usage: gyrotherm_bench_adaptive [--seeds N (50)] [--quick (8 seeds)]
//          [--first-seed S (1)] [--schedule PATH] [--min-min M (10)]
//          [--terms gk|g|k|- (the noises besides white: g bias instability,
//          k rate random walk; '-': white only, a check of the bench itself,
//          where the noise model is exact)]
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "gyrotherm/analysis/acquisition_target.h"
#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/sim/gyro_model.h"

namespace {

using namespace gyrotherm;
using BenchClock = std::chrono::steady_clock;

constexpr int kAxes = 3;
constexpr double kEveryS = 120;    // station::AcquireWatch::kEveryS
double g_min_s = 600;              // min_min = 10 (--min-min)
constexpr double kSettleS = 3600;  // per soak, for the chamber hours

double seconds_since(BenchClock::time_point t0) {
  return std::chrono::duration<double>(BenchClock::now() - t0).count();
}

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "adaptive_campaign_bench: %s\n", what.c_str());
  std::exit(1);
}

uint64_t mix(uint64_t x) {  // splitmix64's finaliser
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

struct AxisNoise {
  double white_dph = 0, bi_dph = 0, rrw_dphrh = 0, bias_dph = 0;
};

AxisNoise draw_axis(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u01(0, 1);
  auto log_uniform = [&](double lo, double hi) {
    return std::exp(std::log(lo) + u01(rng) * (std::log(hi) - std::log(lo)));
  };
  AxisNoise a;
  a.white_dph = log_uniform(0.005, 0.05);
  a.bi_dph = 0.01 * u01(rng);
  a.rrw_dphrh = log_uniform(0.0005, 0.005);
  a.bias_dph = -1 + 2 * u01(rng);
  return a;
}

// One soak of one axis: the gyro's 1 s means and the twin's bias + walk.
struct AxisStream {
  std::vector<double> rate_dph;
  std::vector<double> walk_dph;
};

AxisStream generate(const AxisNoise& a, std::size_t n, uint64_t seed) {
  sim::GyroParams p;
  p.bias_dph = a.bias_dph;
  p.white_noise_dph = a.white_dph;
  p.bias_instability_dph = a.bi_dph;
  p.bias_instability_tau_s = 300;
  p.rate_random_walk_dph_per_sqrt_h = a.rrw_dphrh;
  sim::GyroParams twin_p = p;
  twin_p.white_noise_dph = 0;
  twin_p.bias_instability_dph = 0;
  drivers::GyroFormat format;
  format.rate_hz = 1.0;
  sim::GyroModel gyro(p, format, 0.0, seed);
  sim::GyroModel twin(twin_p, format, 0.0, seed);
  sim::ThermalTruth truth;
  truth.case_c = 25;
  AxisStream s;
  s.rate_dph.resize(n);
  s.walk_dph.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    s.rate_dph[i] = gyro.next_rate_dph(truth);
    s.walk_dph[i] = twin.next_rate_dph(truth);
  }
  return s;
}

double mean_of(std::span<const double> x) {
  double s = 0;
  for (double v : x) s += v;
  return s / static_cast<double>(x.size());
}

// What Table I says of the first n seconds of an axis's soak, and its errors.
struct AxisOutcome {
  bool has_u = false;
  double u95_dph = 0;
  bool rw_dominated = false;
  double err_bias_dph = 0;  // mean - bias_dph
  double err_walk_dph = 0;  // mean - (bias_dph + the walk's mean over the n s)
};

AxisOutcome table1_outcome(const AxisStream& s, const AxisNoise& a, std::size_t n) {
  analysis::AnalysisSeries series;
  series.rate_dph.assign(s.rate_dph.begin(), s.rate_dph.begin() + static_cast<std::ptrdiff_t>(n));
  series.t_s.resize(n);
  for (std::size_t i = 0; i < n; ++i) series.t_s[i] = static_cast<double>(i);
  series.bin_s = 1.0;
  AxisOutcome o;
  const double m = mean_of(series.rate_dph);
  o.err_bias_dph = m - a.bias_dph;
  o.err_walk_dph = m - mean_of(std::span(s.walk_dph).first(n));
  std::string note;
  if (auto u = analysis::series_mean_uncertainty(series, static_cast<double>(n), &note)) {
    o.has_u = true;
    o.u95_dph = u->expanded_dph;
    o.rw_dominated = u->random_walk_dominated;
  }
  return o;
}

enum class StopKind { kReached, kOutOfReach, kCap };

struct SoakOutcome {
  double acquired_s = 0;
  StopKind stop = StopKind::kCap;
  int axes_out_of_reach = 0;  // at the stop
  std::array<AxisOutcome, kAxes> axes;
};

struct JudgeStats {
  long calls = 0;
  double seconds = 0;
};

// One adaptive soak: judged every kEveryS from the minimum until every axis is
// final, or the cap.
SoakOutcome adaptive_soak(const std::array<AxisStream, kAxes>& streams,
                          const std::array<AxisNoise, kAxes>& noise, double target_u95,
                          double cap_s, JudgeStats& stats) {
  const analysis::AcquisitionTarget target{target_u95, g_min_s, cap_s};
  std::vector<double> t_s(static_cast<std::size_t>(cap_s));
  for (std::size_t i = 0; i < t_s.size(); ++i) t_s[i] = static_cast<double>(i);
  int first = 0;  // the axis that blocked the last judgement is asked first
  SoakOutcome out;
  std::optional<double> stop_s;
  for (double t = kEveryS; t < cap_s && !stop_s; t += kEveryS) {
    if (t < g_min_s) continue;
    const auto n = static_cast<std::size_t>(t);
    bool all_final = true;
    int out_of_reach = 0;
    for (int k = 0; k < kAxes && all_final; ++k) {
      const int axis = (first + k) % kAxes;
      const auto t0 = BenchClock::now();
      auto p = analysis::project_acquisition(std::span(t_s).first(n),
                                             std::span(streams[axis].rate_dph).first(n), t, target);
      stats.seconds += seconds_since(t0);
      ++stats.calls;
      if (!p) die("project_acquisition: " + p.error().message);
      if (p->verdict == analysis::AcquisitionVerdict::kOutOfReach) {
        ++out_of_reach;
      } else if (p->verdict != analysis::AcquisitionVerdict::kReached) {
        all_final = false;
        first = axis;
      }
    }
    if (all_final) {
      stop_s = t;
      out.stop = out_of_reach > 0 ? StopKind::kOutOfReach : StopKind::kReached;
      out.axes_out_of_reach = out_of_reach;
    }
  }
  out.acquired_s = stop_s.value_or(cap_s);
  for (int a = 0; a < kAxes; ++a) {
    out.axes[a] = table1_outcome(streams[a], noise[a], static_cast<std::size_t>(out.acquired_s));
  }
  return out;
}

double percentile(std::vector<double> v, double q) {  // linear interpolation
  std::sort(v.begin(), v.end());
  const double pos = q * static_cast<double>(v.size() - 1);
  const auto i = static_cast<std::size_t>(std::floor(pos));
  if (i + 1 >= v.size()) return v.back();
  return v[i] + (pos - static_cast<double>(i)) * (v[i + 1] - v[i]);
}

// Pooled over stations: one column of a target's table.
struct Column {
  std::vector<double> acquire_h;  // per station
  std::vector<double> ratio;      // per station, to its fixed
  long soaks = 0, reached = 0, out_of_reach = 0, cap = 0, longer = 0, shorter = 0;
  long axis_soaks = 0, axes_out_of_reach = 0, no_u = 0, within_target = 0;
  double u95_sum = 0, u95_rel_sum = 0, u95_rel_max = 0, err2_sum = 0;
  // coverage counts [flagged][covered]; against bias_dph and against the walk
  long n_flag[2] = {0, 0}, cov_bias[2] = {0, 0}, cov_walk[2] = {0, 0};

  void add_axis(const AxisOutcome& o, double target) {
    ++axis_soaks;
    if (!o.has_u) {
      ++no_u;
      return;
    }
    u95_sum += o.u95_dph;
    err2_sum += o.err_bias_dph * o.err_bias_dph;
    u95_rel_sum += o.u95_dph / target;
    u95_rel_max = std::max(u95_rel_max, o.u95_dph / target);
    if (o.u95_dph <= target) ++within_target;
    const int f = o.rw_dominated ? 1 : 0;
    ++n_flag[f];
    if (std::abs(o.err_bias_dph) <= o.u95_dph) ++cov_bias[f];
    if (std::abs(o.err_walk_dph) <= o.u95_dph) ++cov_walk[f];
  }
};

double mean_v(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? NAN : s / static_cast<double>(v.size());
}

std::string pct(long k, long n) {
  return n == 0 ? std::string("—") : fmt::format("{:.1f}", 100.0 * static_cast<double>(k) / n);
}

std::string coverage(const long* cov, const long* n, int which) {
  // which: 0 not flagged, 1 flagged, 2 all
  const long k = which == 2 ? cov[0] + cov[1] : cov[which];
  const long m = which == 2 ? n[0] + n[1] : n[which];
  return fmt::format("{} (n {})", pct(k, m), m);
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = 50;
  std::string terms = "gk";  // the noises besides white (--terms)
  uint64_t first_seed = 1;
  std::string schedule_path =
      std::string(GYROTHERM_SOURCE_DIR) + "/config/schedules/paper-table1.toml";
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--seeds" && i + 1 < argc) {
      seeds = std::atoi(argv[++i]);
    } else if (a == "--quick") {
      seeds = 8;
    } else if (a == "--min-min" && i + 1 < argc) {
      g_min_s = 60 * std::atof(argv[++i]);
    } else if (a == "--terms" && i + 1 < argc) {
      terms = argv[++i];
      if (terms != "-" && (terms.empty() || terms.find_first_not_of("gk") != std::string::npos)) {
        die("--terms: letters g (bias instability) and k (rate random walk), or - for none");
      }
    } else if (a == "--first-seed" && i + 1 < argc) {
      first_seed = std::strtoull(argv[++i], nullptr, 10);
    } else if (a == "--schedule" && i + 1 < argc) {
      schedule_path = argv[++i];
    } else {
      die(
          fmt::format("unknown argument '{}' (usage: [--seeds N] [--quick] [--first-seed S] "
                      "[--schedule PATH] [--min-min M] [--terms gk|g|k|-])",
                      a));
    }
  }
  if (seeds < 1) die("--seeds must be >= 1");

  const auto wall0 = BenchClock::now();
  auto plan = schedules::load_schedule(schedule_path, schedules::StationLimits{});
  if (!plan) die(plan.error().message);
  std::vector<double> fixed_s;
  std::vector<double> setpoint_c;
  for (const auto& step : plan->steps) {
    if (step.kind != schedules::StepKind::kSoak) continue;
    if (step.adaptive) die("the schedule's soaks must be fixed");
    fixed_s.push_back(step.acquire_s);
    setpoint_c.push_back(step.setpoint_c);
  }
  const std::size_t n_soaks = fixed_s.size();
  double fixed_total_s = 0;
  for (double s : fixed_s) {
    if (s < g_min_s || std::fmod(s, 60) != 0)
      die(fmt::format("a soak of {} s: shorter than min_min, or not whole minutes", s));
    fixed_total_s += s;
  }
  const double fixed_h = fixed_total_s / 3600;
  const double settle_h = static_cast<double>(n_soaks) * kSettleS / 3600;

  static constexpr const char* kTargetNames[] = {"(a) median", "(b) 90th percentile",
                                                 "(c) maximum"};
  static constexpr double kTargetQ[] = {0.5, 0.9, 1.0};
  static constexpr const char* kCapNames[] = {"adaptive, cap 2 x fixed", "adaptive, cap = fixed"};
  static constexpr double kCapFactor[] = {2.0, 1.0};

  Column fixed_cols[3];        // per target (the fixed soaks, judged against it)
  Column adaptive_cols[3][2];  // per target, per cap
  std::vector<double> targets[3];
  // Mean adaptive minutes per set point (cap 2x), per target.
  std::map<double, std::array<double, 3>> per_setpoint_min;
  std::map<double, double> per_setpoint_fixed_min;
  std::map<double, long> per_setpoint_n;
  JudgeStats judge;
  double generate_s = 0, fixed_analysis_s = 0;
  long walk_dominated_axes = 0, floor_dominated_axes = 0, white_dominated_axes = 0;

  for (int si = 0; si < seeds; ++si) {
    const uint64_t seed = first_seed + static_cast<uint64_t>(si);
    std::mt19937_64 rng(mix(seed));
    std::array<AxisNoise, kAxes> noise;
    for (auto& a : noise) {
      a = draw_axis(rng);
      if (terms.find('g') == std::string::npos) a.bi_dph = 0;
      if (terms.find('k') == std::string::npos) a.rrw_dphrh = 0;
    }
    // Which noise dominates u² of a fixed soak's mean (~2 h) by the truth's
    // parameters, roughly: white q_n/T, flicker-ish GM ~ 2 tau sigma² / T, walk
    // K² T_h / 3.
    for (const auto& a : noise) {
      const double t = 7200;
      const double w = a.white_dph * a.white_dph / t;
      const double g = 2 * 300 * a.bi_dph * a.bi_dph / t;
      const double k = a.rrw_dphrh * a.rrw_dphrh * (t / 3600) / 3;
      if (k >= w && k >= g) {
        ++walk_dominated_axes;
      } else if (g >= w) {
        ++floor_dominated_axes;
      } else {
        ++white_dominated_axes;
      }
    }

    // The streams of the 32 soaks.
    const auto g0 = BenchClock::now();
    std::vector<std::array<AxisStream, kAxes>> streams(n_soaks);
    for (std::size_t s = 0; s < n_soaks; ++s) {
      const auto n = static_cast<std::size_t>(2 * fixed_s[s]);
      for (int a = 0; a < kAxes; ++a) {
        streams[s][a] = generate(noise[a], n, mix(mix(seed) ^ (s * 16 + a + 1)));
      }
    }
    if (si == 0) {
      // The twin draws the same normals: rate - twin is white noise + GM.
      const auto& st = streams[0][0];
      double s2 = 0;
      for (std::size_t i = 0; i < st.rate_dph.size(); ++i) {
        const double d = st.rate_dph[i] - st.walk_dph[i];
        s2 += d * d;
      }
      const double rms = std::sqrt(s2 / static_cast<double>(st.rate_dph.size()));
      const double expect = std::hypot(noise[0].white_dph, noise[0].bi_dph);
      if (std::abs(rms / expect - 1) > 0.2) {
        die(fmt::format("the twin does not follow the gyro: rms {} against {}", rms, expect));
      }
    }
    generate_s += seconds_since(g0);

    // Fixed soaks.
    const auto f0 = BenchClock::now();
    std::vector<std::array<AxisOutcome, kAxes>> fixed(n_soaks);
    std::vector<double> u95s;
    for (std::size_t s = 0; s < n_soaks; ++s) {
      for (int a = 0; a < kAxes; ++a) {
        fixed[s][a] = table1_outcome(streams[s][a], noise[a], static_cast<std::size_t>(fixed_s[s]));
        if (fixed[s][a].has_u) u95s.push_back(fixed[s][a].u95_dph);
      }
    }
    fixed_analysis_s += seconds_since(f0);
    if (u95s.empty()) die("no fixed soak has a U95");

    for (int ti = 0; ti < 3; ++ti) {
      const double target = percentile(u95s, kTargetQ[ti]);
      targets[ti].push_back(target);
      Column& fc = fixed_cols[ti];
      fc.acquire_h.push_back(fixed_h);
      fc.ratio.push_back(1.0);
      for (std::size_t s = 0; s < n_soaks; ++s) {
        ++fc.soaks;
        for (int a = 0; a < kAxes; ++a) fc.add_axis(fixed[s][a], target);
      }
      for (int ci = 0; ci < 2; ++ci) {
        Column& col = adaptive_cols[ti][ci];
        double total_s = 0;
        for (std::size_t s = 0; s < n_soaks; ++s) {
          const SoakOutcome o =
              adaptive_soak(streams[s], noise, target, kCapFactor[ci] * fixed_s[s], judge);
          total_s += o.acquired_s;
          ++col.soaks;
          switch (o.stop) {
            case StopKind::kReached:
              ++col.reached;
              break;
            case StopKind::kOutOfReach:
              ++col.out_of_reach;
              break;
            case StopKind::kCap:
              ++col.cap;
              break;
          }
          col.axes_out_of_reach += o.axes_out_of_reach;
          if (o.acquired_s > fixed_s[s]) ++col.longer;
          if (o.acquired_s < fixed_s[s]) ++col.shorter;
          for (int a = 0; a < kAxes; ++a) col.add_axis(o.axes[a], target);
          if (ci == 0) per_setpoint_min[setpoint_c[s]][ti] += o.acquired_s / 60;
          if (ci == 0 && ti == 0) {
            per_setpoint_fixed_min[setpoint_c[s]] += fixed_s[s] / 60;
            ++per_setpoint_n[setpoint_c[s]];
          }
        }
        col.acquire_h.push_back(total_s / 3600);
        col.ratio.push_back(total_s / fixed_total_s);
      }
    }
    std::fprintf(stderr, "\rstation %d/%d (%.0f s)", si + 1, seeds, seconds_since(wall0));
  }
  std::fprintf(stderr, "\n");
  const double wall_s = seconds_since(wall0);

  fmt::print(
      "Adaptive soaks against fixed ones: {} ({} soaks, fixed acquisition {:.2f} h), {} "
      "stations (seeds {} ... {}), 3 axes each\n",
      plan->name, n_soaks, fixed_h, seeds, first_seed, first_seed + seeds - 1);
  fmt::print(
      "noise drawn per axis: white log-uniform [0.005, 0.05] °/h (1 s mean), bias instability "
      "uniform [0, 0.01] °/h (tau 300 s), rate random walk log-uniform [0.0005, 0.005] °/h/√h\n");
  fmt::print(
      "axes by the truth's largest term of u² at 2 h: white {}, bias instability {}, rate "
      "random walk {}\n",
      white_dominated_axes, floor_dominated_axes, walk_dominated_axes);
  fmt::print(
      "adaptive: judged every {:g} s, min_min {:g}, max_min 2 x or 1 x the fixed length; chamber "
      "h = {} x {:g} min settle + acquisition{}\n\n",
      kEveryS, g_min_s / 60, n_soaks, kSettleS / 60,
      terms == "gk"
          ? ""
          : fmt::format("\n--terms {}: {}", terms,
                        terms.find('g') == std::string::npos
                            ? (terms.find('k') == std::string::npos ? "white noise only"
                                                                    : "no bias instability")
                            : "no rate random walk"));

  for (int ti = 0; ti < 3; ++ti) {
    const auto& tv = targets[ti];
    fmt::print(
        "Target {} of each station's {} fixed-soak U95s: mean {:.4f} °/h ({:.4f} … {:.4f})\n\n",
        kTargetNames[ti], n_soaks * kAxes, mean_v(tv), *std::min_element(tv.begin(), tv.end()),
        *std::max_element(tv.begin(), tv.end()));
    const Column* cols[3] = {&fixed_cols[ti], &adaptive_cols[ti][0], &adaptive_cols[ti][1]};
    fmt::print("| | fixed | {} | {} |\n|---|---|---|---|\n", kCapNames[0], kCapNames[1]);
    auto row = [&](const std::string& name, auto cell) {
      fmt::print("| {} | {} | {} | {} |\n", name, cell(*cols[0], 0), cell(*cols[1], 1),
                 cell(*cols[2], 2));
    };
    row("acquisition h per campaign (mean over stations)",
        [](const Column& c, int) { return fmt::format("{:.1f}", mean_v(c.acquire_h)); });
    row("ratio to fixed (of the means; stations' range)", [&](const Column& c, int) {
      return fmt::format("{:.2f} ({:.2f} … {:.2f})", mean_v(c.acquire_h) / fixed_h,
                         *std::min_element(c.ratio.begin(), c.ratio.end()),
                         *std::max_element(c.ratio.begin(), c.ratio.end()));
    });
    row("chamber h (settles + acquisition)", [&](const Column& c, int) {
      return fmt::format("{:.1f}", settle_h + mean_v(c.acquire_h));
    });
    row("soaks ending reached / out of reach / cap, %", [](const Column& c, int i) {
      if (i == 0) return std::string("—");
      return fmt::format("{} / {} / {}", pct(c.reached, c.soaks), pct(c.out_of_reach, c.soaks),
                         pct(c.cap, c.soaks));
    });
    row("axes out of reach at the stop, % of axis-soaks", [](const Column& c, int i) {
      return i == 0 ? std::string("—") : pct(c.axes_out_of_reach, c.axis_soaks);
    });
    row("soaks longer / shorter than fixed, %", [](const Column& c, int i) {
      return i == 0 ? std::string("—")
                    : fmt::format("{} / {}", pct(c.longer, c.soaks), pct(c.shorter, c.soaks));
    });
    row("U95 mean, °/h", [](const Column& c, int) {
      return fmt::format("{:.4f}", c.u95_sum / static_cast<double>(c.axis_soaks - c.no_u));
    });
    row("RMS of mean − bias, °/h (1.96 x it: what a U95 should be)", [](const Column& c, int) {
      const double rms = std::sqrt(c.err2_sum / static_cast<double>(c.axis_soaks - c.no_u));
      return fmt::format("{:.4f} ({:.4f})", rms, 1.96 * rms);
    });
    row("U95 / target: mean, max", [](const Column& c, int) {
      return fmt::format("{:.2f}, {:.2f}",
                         c.u95_rel_sum / static_cast<double>(c.axis_soaks - c.no_u), c.u95_rel_max);
    });
    row("axis-soaks with U95 <= target, %",
        [](const Column& c, int) { return pct(c.within_target, c.axis_soaks); });
    row("coverage \\|mean − bias\\| <= U95, %: all",
        [](const Column& c, int) { return coverage(c.cov_bias, c.n_flag, 2); });
    row("  random_walk_dominated",
        [](const Column& c, int) { return coverage(c.cov_bias, c.n_flag, 1); });
    row("  not flagged", [](const Column& c, int) { return coverage(c.cov_bias, c.n_flag, 0); });
    row("coverage against bias + the walk's mean over the soak, %: all",
        [](const Column& c, int) { return coverage(c.cov_walk, c.n_flag, 2); });
    row("  random_walk_dominated",
        [](const Column& c, int) { return coverage(c.cov_walk, c.n_flag, 1); });
    row("  not flagged", [](const Column& c, int) { return coverage(c.cov_walk, c.n_flag, 0); });
    long no_u = 0;
    for (const Column* c : cols) no_u += c->no_u;
    if (no_u > 0) fmt::print("({} axis-soaks without a U95 left out)\n", no_u);
    fmt::print("\n");
  }

  fmt::print("Mean acquisition per soak by set point, min (adaptive: cap 2 x fixed)\n\n");
  fmt::print(
      "| set point °C | fixed | target (a) | target (b) | target (c) |\n|---|---|---|---|---|\n");
  for (const auto& [sp, sums] : per_setpoint_min) {
    const double n = static_cast<double>(per_setpoint_n[sp]);
    fmt::print("| {:g} | {:.0f} | {:.0f} | {:.0f} | {:.0f} |\n", sp, per_setpoint_fixed_min[sp] / n,
               sums[0] / n, sums[1] / n, sums[2] / n);
  }
  fmt::print(
      "\nwall {:.1f} s: streams {:.1f} s, fixed soaks' Table I {:.1f} s, {} project_acquisition "
      "calls {:.1f} s ({:.2f} ms each), the rest (adaptive Table I) {:.1f} s\n",
      wall_s, generate_s, fixed_analysis_s, judge.calls, judge.seconds,
      judge.calls ? 1e3 * judge.seconds / static_cast<double>(judge.calls) : 0.0,
      wall_s - generate_s - fixed_analysis_s - judge.seconds);
  return 0;
}
