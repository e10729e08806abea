// Overlapping Allan deviation of allan.h.
#include "gyrotherm/analysis/allan.h"

#include <fmt/format.h>

#include <algorithm>
#include <boost/math/distributions/chi_squared.hpp>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <memory>
#include <thread>
#include <vector>

#include "allan_detail.h"
#include "common.h"
#include "compensated_sum.h"
#include "target_clones.h"

namespace gyrotherm::analysis {
namespace {

constexpr double kBiasInstabilityFactor = 0.664;
constexpr double kSlopeTolerance = 0.25;

double median_spacing(std::span<const double> t) {
  std::vector<double> d(t.size() - 1);
  for (std::size_t i = 0; i + 1 < t.size(); ++i) d[i] = t[i + 1] - t[i];
  const std::size_t mid = d.size() / 2;
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(mid), d.end());
  const double upper = d[mid];
  if (d.size() % 2 == 1) return upper;
  const double lower = *std::max_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(mid));
  return lower + (upper - lower) / 2;
}

// What one pass over (t, y) tells: whether the input is clean (finite,
// strictly increasing), and the counts that locate the median spacing between
// the sample bounds lo <= hi (the spacings inside [lo, hi] are collected when
// lo < hi). The same pass writes the prefix sums (see scan_and_prefix).
struct ScanResult {
  bool clean = true;
  std::size_t below = 0, above = 0;
  std::vector<double> inside;
};

// One pass over (t, y): the checks and median counts of ScanResult, and
// C[k] = sum_{j<k} (y_j - shift), k = 0 .. n, into c, a block of kBlock at a
// time (prefix_block).
ScanResult scan_and_prefix(std::span<const double> t, std::span<const double> y, double lo,
                           double hi, double shift, double* c) {
  ScanResult out;
  CompensatedSum offset;
  const std::size_t n = t.size();
  c[0] = 0;
  for (std::size_t b = 0; b < n; b += allan_detail::kBlock) {
    const std::size_t e = std::min(b + allan_detail::kBlock, n);
    double zero = t[b] * 0.0 + y[b] * 0.0;  // NaN for a NaN or infinite value
    double bad = 0, below = 0, above = 0;
    for (std::size_t i = std::max<std::size_t>(b, 1); i < e; ++i) {
      const double d = t[i] - t[i - 1];
      zero += t[i] * 0.0 + y[i] * 0.0;
      bad += d > 0 ? 0.0 : 1.0;
      below += d < lo ? 1.0 : 0.0;
      above += d > hi ? 1.0 : 0.0;
    }
    if (bad != 0 || zero != 0) {
      out.clean = false;
      return out;
    }
    out.below += static_cast<std::size_t>(below);
    out.above += static_cast<std::size_t>(above);
    if (lo < hi) {
      for (std::size_t i = std::max<std::size_t>(b, 1); i < e; ++i) {
        const double d = t[i] - t[i - 1];
        if (d >= lo && d <= hi) out.inside.push_back(d);
      }
    }

    allan_detail::prefix_block(y.data() + b, e - b, shift, offset, c + b + 1);
  }
  return out;
}

// The sample bounds for scan(): about the 45 % and 55 % quantiles of an even
// sample of 2048 spacings (all of them for short series); and the prefix-sum
// shift (first_block_mean: what a streamed pass knows before it starts).
struct Sample {
  double lo, hi, shift;
};
Sample sample_series(std::span<const double> t, std::span<const double> y) {
  const std::size_t nd = t.size() - 1;
  const std::size_t k = std::min<std::size_t>(nd, 2048);
  std::vector<double> sample(k);
  for (std::size_t j = 0; j < k; ++j) {
    const std::size_t i = 1 + j * nd / k;
    sample[j] = t[i] - t[i - 1];
  }
  std::sort(sample.begin(), sample.end());
  const double shift = allan_detail::first_block_mean(y);
  return {sample[k * 45 / 100], sample[std::min(k - 1, (k * 55 + 99) / 100)], shift};
}

// The median spacing from a clean scan, or nullopt when the middle ranks are
// outside [lo, hi] (the caller then sorts all spacings).
std::optional<double> median_from_scan(const ScanResult& s, std::size_t nd, double lo, double hi) {
  const std::size_t mid = nd / 2;
  const std::size_t first = nd % 2 == 1 ? mid : mid - 1;  // lowest rank needed
  if (s.below > first || mid >= nd - s.above) return std::nullopt;
  if (!(lo < hi)) return lo;
  std::vector<double> in = s.inside;
  auto at = [&](std::size_t rank) {
    const auto r = static_cast<std::ptrdiff_t>(rank - s.below);
    std::nth_element(in.begin(), in.begin() + r, in.end());
    return in[static_cast<std::size_t>(r)];
  };
  const double upper = at(mid);
  if (nd % 2 == 1) return upper;
  const double lower = at(mid - 1);
  return lower + (upper - lower) / 2;
}

}  // namespace

namespace allan_detail {

GYROTHERM_AVX2_CLONES double cluster_diff_squares(const double* c0, const double* c1,
                                                  const double* c2, std::size_t n) {
  double a[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    for (std::size_t j = 0; j < 8; ++j) {
      const double d = (c2[i + j] - c1[i + j]) - (c1[i + j] - c0[i + j]);
      a[j] += d * d;
    }
  }
  for (; i < n; ++i) {
    const double d = (c2[i] - c1[i]) - (c1[i] - c0[i]);
    a[0] += d * d;
  }
  return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
}

void prefix_block(const double* y, std::size_t nb, double shift, CompensatedSum& offset,
                  double* c) {
  const std::size_t len = nb / kLanes;
  double s[kLanes] = {0, 0, 0, 0};
  for (std::size_t i = 0; i < len; ++i) {
    for (std::size_t l = 0; l < kLanes; ++l) {
      const std::size_t k = l * len + i;
      s[l] += y[k] - shift;
      c[k] = s[l];
    }
  }
  for (std::size_t k = kLanes * len; k < nb; ++k) {  // the rest, on the last lane
    s[kLanes - 1] += y[k] - shift;
    c[k] = s[kLanes - 1];
  }
  for (std::size_t l = 0; l < kLanes; ++l) {
    const std::size_t k0 = l * len;
    const std::size_t k1 = l + 1 == kLanes ? nb : k0 + len;
    const double off_hi = offset.sum, off_lo = offset.comp;
    for (std::size_t k = k0; k < k1; ++k) c[k] = off_hi + (off_lo + c[k]);
    offset.add(s[l]);
  }
}

double first_block_mean(std::span<const double> y) {
  const std::size_t k = std::min(y.size(), kBlock);
  double sum = 0;
  for (std::size_t i = 0; i < k; ++i) sum += y[i];
  const double mean = k == 0 ? 0.0 : sum / static_cast<double>(k);
  return std::isfinite(mean) ? mean : 0.0;
}

// Overlapping Allan variances for the cluster sizes ms (ascending), from the
// prefix sums c of n points, in two sweeps that each read C from memory
// about once:
// - small m (< kLarge): the offsets k in chunks of kChunk, every m per chunk;
//   the stretches C[k..], C[k+m..], C[k+2m..] of all of them are in cache.
// - large m, when all are multiples of kLarge (octave): the chunks of C are
//   visited in the order X = base + j kLarge (base < kLarge in steps of
//   kChunk, then j = 0, 1, ...), and at each X every large m does the terms
//   k = X - 2m ... : C[k + m] and C[k] were visited 2m / kLarge steps before
//   (<= 256 chunks, in cache). Other tau sets sweep the large m like the small.
std::vector<double> allan_variances(const double* c, std::size_t n,
                                    const std::vector<std::size_t>& ms) {
  // Series at least this long sweep the taus on two threads.
  constexpr std::size_t kParallelSamples = std::size_t{1} << 18;
  constexpr std::size_t kChunk = 1024;
  constexpr std::size_t kLarge = std::size_t{1} << 15;
  std::vector<CompensatedSum> ss(ms.size());
  const auto terms = [&](std::size_t j) { return n - 2 * ms[j] + 1; };
  std::size_t first_large = ms.size();
  for (std::size_t j = 0; j < ms.size(); ++j) {
    if (ms[j] >= kLarge) {
      first_large = j;
      break;
    }
  }
  bool strided = true;
  for (std::size_t j = first_large; j < ms.size(); ++j) strided &= ms[j] % kLarge == 0;
  const std::size_t sequential_end = strided ? first_large : ms.size();

  // Two threads for long series: the first takes the first half of the
  // offsets (small m) and of the bases (large m), the second the rest; the
  // per-tau sums are compensated, so the split changes only rounding.
  const auto sweep = [&](std::vector<CompensatedSum>& acc, std::size_t k_begin, std::size_t k_end,
                         std::size_t base_begin, std::size_t base_end) {
    for (std::size_t k0 = k_begin; k0 < k_end; k0 += kChunk) {
      for (std::size_t j = 0; j < sequential_end; ++j) {
        if (k0 >= terms(j)) break;  // larger m have fewer terms still
        const std::size_t k1 = std::min(k0 + kChunk, terms(j));
        acc[j].add(cluster_diff_squares(c + k0, c + k0 + ms[j], c + k0 + 2 * ms[j], k1 - k0));
      }
    }
    if (!strided || first_large == ms.size()) return;
    // X = k0 + 2m runs up to the last term's k0 + 2m = n (inclusive): when n
    // is a multiple of kChunk, the chunk holding the last difference of every
    // large m starts exactly at X = n.
    for (std::size_t base = base_begin; base < base_end; base += kChunk) {
      for (std::size_t x = base; x <= n; x += kLarge) {
        for (std::size_t j = first_large; j < ms.size(); ++j) {
          if (x < 2 * ms[j]) break;
          const std::size_t k0 = x - 2 * ms[j];
          if (k0 >= terms(j)) continue;
          const std::size_t k1 = std::min(k0 + kChunk, terms(j));
          acc[j].add(cluster_diff_squares(c + k0, c + k0 + ms[j], c + k0 + 2 * ms[j], k1 - k0));
        }
      }
    }
  };
  if (n < kParallelSamples) {
    sweep(ss, 0, n, 0, kLarge);
  } else {
    std::vector<CompensatedSum> other_ss(ms.size());
    const std::size_t k_mid = n / 2 / kChunk * kChunk;
    std::thread other([&] { sweep(other_ss, k_mid, n, kLarge / 2, kLarge); });
    sweep(ss, 0, k_mid, 0, kLarge / 2);
    other.join();
    for (std::size_t j = 0; j < ms.size(); ++j) {
      ss[j].add(other_ss[j].sum);
      ss[j].add(other_ss[j].comp);
    }
  }
  std::vector<double> var(ms.size());
  for (std::size_t j = 0; j < ms.size(); ++j) {
    const auto m = static_cast<double>(ms[j]);
    var[j] = ss[j].value() / (m * m) / (2.0 * static_cast<double>(terms(j)));
  }
  return var;
}

}  // namespace allan_detail

namespace {

// C of the fixed-slope line log sigma = log C + slope log tau (allan.h), over
// a curve whose sigmas are all positive and finite and that has >= 3 taus.
std::optional<double> fit_fixed_slope(std::span<const double> tau_s,
                                      std::span<const double> adev_dph, std::span<const double> edf,
                                      double slope) {
  const std::size_t n = tau_s.size();
  std::vector<double> lt(n), ls(n);
  for (std::size_t i = 0; i < n; ++i) {
    lt[i] = std::log(tau_s[i]);
    ls[i] = std::log(adev_dph[i]);
  }
  double wsum = 0;
  double sum = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t lo = i == 0 ? 0 : i - 1;
    const std::size_t hi = i + 1 == n ? n - 1 : i + 1;
    const double local = (ls[hi] - ls[lo]) / (lt[hi] - lt[lo]);
    if (std::abs(local - slope) > kSlopeTolerance) continue;
    wsum += edf[i];
    sum += edf[i] * (ls[i] - slope * lt[i]);
  }
  if (!(wsum > 0)) return std::nullopt;
  return std::exp(sum / wsum);
}

NoiseTerm term_value(double value, std::string note) {
  NoiseTerm t;
  t.kind = NoiseTermKind::kValue;
  t.value = value;
  t.note = std::move(note);
  return t;
}

NoiseTerm term_bound(double bound, double tau_s, std::string relation, std::string note) {
  NoiseTerm t;
  t.kind = NoiseTermKind::kUpperBound;
  t.value = bound;
  t.tau_s = tau_s;
  t.tau_relation = std::move(relation);
  t.note = std::move(note);
  return t;
}

double chi2_quantile(double dof, double p) {
  try {
    return boost::math::quantile(boost::math::chi_squared_distribution<double>(dof), p);
  } catch (const std::exception&) {
    return kNaN;
  }
}

}  // namespace

Result<TauSet> parse_tau_set(std::string_view s) {
  if (s == "octave") return TauSet::kOctave;
  if (s == "decade") return TauSet::kDecade;
  if (s == "all") return TauSet::kAll;
  return Error::Permanent(fmt::format("unknown tau set '{}' (expected octave, decade or all)", s));
}

std::string_view to_string(TauSet set) {
  switch (set) {
    case TauSet::kOctave:
      return "octave";
    case TauSet::kDecade:
      return "decade";
    case TauSet::kAll:
      return "all";
  }
  return "?";
}

bool AllanOptions::is_valid(std::string* why) const {
  switch (taus) {
    case TauSet::kOctave:
    case TauSet::kDecade:
    case TauSet::kAll:
      return true;
  }
  if (why) {
    *why =
        fmt::format("taus = {} is not a tau set (octave, decade or all)", static_cast<int>(taus));
  }
  return false;
}

std::vector<std::size_t> allan_cluster_sizes(std::size_t n, TauSet set) {
  std::vector<std::size_t> ms;
  switch (set) {
    case TauSet::kOctave:
      for (std::size_t m = 1; 2 * m < n + 1; m *= 2) ms.push_back(m);
      break;
    case TauSet::kDecade:
      for (std::size_t decade = 1;; decade *= 10) {
        for (std::size_t f : {1, 2, 5}) {
          const std::size_t m = f * decade;
          if (2 * m >= n + 1) return ms;
          ms.push_back(m);
        }
      }
    case TauSet::kAll:
      for (std::size_t m = 1; 2 * m < n + 1; ++m) ms.push_back(m);
      break;
  }
  return ms;
}

double allan_edf_white_fm(std::size_t n_rate_samples, std::size_t m) {
  const double n = static_cast<double>(n_rate_samples) + 1.0;  // phase points
  const double md = static_cast<double>(m);
  return (3.0 * (n - 1.0) / (2.0 * md) - 2.0 * (n - 2.0) / n) * 4.0 * md * md /
         (4.0 * md * md + 5.0);
}

double allan_edf(int alpha, std::size_t n_rate_samples, std::size_t m) {
  const double n = static_cast<double>(n_rate_samples) + 1.0;  // phase points
  const double md = static_cast<double>(m);
  double edf = 0;
  switch (std::clamp(alpha, -2, 2)) {
    case 2:
      edf = (n + 1.0) * (n - 2.0 * md) / (2.0 * (n - md));
      break;
    case 1:
      edf = std::exp(std::sqrt(std::max(
          0.0, std::log((n - 1.0) / (2.0 * md)) * std::log((2.0 * md + 1.0) * (n - 1.0) / 4.0))));
      break;
    case 0:
      edf = allan_edf_white_fm(n_rate_samples, m);
      break;
    case -1:
      edf = m == 1 ? 2.0 * (n - 2.0) * (n - 2.0) / (2.3 * n - 4.9)
                   : 5.0 * n * n / (4.0 * md * (n + 3.0 * md));
      break;
    default:  // -2
      edf = (n - 2.0) / md * ((n - 1.0) * (n - 1.0) - 3.0 * md * (n - 1.0) + 4.0 * md * md) /
            ((n - 3.0) * (n - 3.0));
      break;
  }
  return std::isfinite(edf) ? std::max(1.0, edf) : 1.0;
}

namespace allan_detail {

std::optional<NoiseIdentification> identify_block_means(std::vector<double> x) {
  const std::size_t k = x.size();
  if (k < kMinNoiseIdAverages) return std::nullopt;
  const double kd = static_cast<double>(k);
  const double i_mean = (kd - 1.0) / 2.0;
  double x_mean = 0;
  for (const double v : x) x_mean += v;
  x_mean /= kd;
  double sxy = 0, sxx = 0;
  for (std::size_t b = 0; b < k; ++b) {
    const double di = static_cast<double>(b) - i_mean;
    sxy += di * (x[b] - x_mean);
    sxx += di * di;
  }
  const double slope = sxy / sxx;
  for (std::size_t b = 0; b < k; ++b) {
    x[b] -= x_mean + slope * (static_cast<double>(b) - i_mean);
  }
  NoiseIdentification id;
  id.averages = k;
  constexpr int kMaxDifferences = 2;  // the Allan variance's own order
  for (int d = 0;; ++d) {
    double mean = 0;
    for (const double v : x) mean += v;
    mean /= static_cast<double>(x.size());
    double num = 0, den = 0;
    for (std::size_t i = 0; i < x.size(); ++i) {
      const double c = x[i] - mean;
      den += c * c;
      if (i + 1 < x.size()) num += c * (x[i + 1] - mean);
    }
    if (!(den > 0)) return std::nullopt;  // constant: no noise to identify
    const double r1 = num / den;
    const double delta = r1 / (1.0 + r1);
    if (delta < 0.25 || d >= kMaxDifferences) {
      id.differences = d;
      id.delta = delta;
      id.alpha_estimate = -2.0 * (delta + d);
      id.alpha = std::clamp(static_cast<int>(std::lround(id.alpha_estimate)), -2, 2);
      return id;
    }
    for (std::size_t i = 0; i + 1 < x.size(); ++i) x[i] = x[i + 1] - x[i];
    x.pop_back();
  }
}

// c[i]: the sum of the first i rates less a common offset; O(n / m).
std::vector<double> block_means_from_prefix(const double* c, std::size_t n, std::size_t m) {
  std::vector<double> x(n / m);
  for (std::size_t b = 0; b < x.size(); ++b) {
    x[b] = (c[(b + 1) * m] - c[b * m]) / static_cast<double>(m);
  }
  return x;
}

}  // namespace allan_detail

std::optional<NoiseIdentification> identify_noise_lag1(std::span<const double> rate,
                                                       std::size_t m) {
  if (m == 0 || rate.size() / m < kMinNoiseIdAverages) return std::nullopt;
  std::vector<double> x(rate.size() / m);
  for (std::size_t b = 0; b < x.size(); ++b) {
    double sum = 0;
    for (std::size_t i = 0; i < m; ++i) sum += rate[b * m + i];
    x[b] = sum / static_cast<double>(m);
  }
  return allan_detail::identify_block_means(std::move(x));
}

std::string_view to_string(NoiseTermKind kind) {
  switch (kind) {
    case NoiseTermKind::kValue:
      return "value";
    case NoiseTermKind::kUpperBound:
      return "upper_bound";
    case NoiseTermKind::kUnavailable:
      return "unavailable";
  }
  return "?";
}

AllanNoiseTerms allan_noise_terms(std::span<const double> tau_s, std::span<const double> adev_dph,
                                  std::span<const double> edf) {
  AllanNoiseTerms out;
  const auto unavailable = [&](const std::string& why) {
    for (NoiseTerm* t :
         {&out.angle_random_walk_dprh, &out.bias_instability_dph, &out.rate_random_walk_dphprh}) {
      t->note = why;
    }
    return out;
  };
  const std::size_t n = tau_s.size();
  if (adev_dph.size() != n || edf.size() != n) {
    return unavailable(
        fmt::format("the curve's arrays differ in length ({} taus, {} sigmas, {} edf)", n,
                    adev_dph.size(), edf.size()));
  }
  if (n < 3) {
    return unavailable(fmt::format("{} tau(s) on the curve, at least 3 are needed", n));
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (!(adev_dph[i] > 0) || !std::isfinite(adev_dph[i]) || !(tau_s[i] > 0) ||
        !std::isfinite(tau_s[i])) {
      return unavailable(
          fmt::format("sigma is {} at tau = {:g} s (a constant rate?)", adev_dph[i], tau_s[i]));
    }
  }
  const double tau_min = tau_s.front(), tau_max = tau_s.back();
  const double sigma_first = adev_dph.front(), sigma_last = adev_dph.back();

  // Angle random walk: sigma_line(1 s) / 60.
  if (auto c = fit_fixed_slope(tau_s, adev_dph, edf, -0.5)) {
    const bool on_grid = tau_min <= 1.0 && 1.0 <= tau_max;
    out.angle_random_walk_dprh =
        term_value(*c / 60.0, on_grid ? "slope -1/2 line at tau = 1 s"
                                      : "slope -1/2 line extrapolated to tau = 1 s");
  } else {
    out.angle_random_walk_dprh =
        term_bound(sigma_first * std::sqrt(tau_min) / 60.0, tau_min, "<=",
                   fmt::format("no slope -1/2 region on the curve: the -1/2 line through the "
                               "first point (tau = {:g} s) bounds it",
                               tau_min));
  }

  // Rate random walk: K = 60 sigma_line(3 s) = 60 sqrt(3) C.
  if (auto c = fit_fixed_slope(tau_s, adev_dph, edf, 0.5)) {
    out.rate_random_walk_dphprh = term_value(60.0 * *c * std::sqrt(3.0), "slope +1/2 line");
  } else {
    out.rate_random_walk_dphprh = term_bound(
        60.0 * sigma_last * std::sqrt(3.0 / tau_max), tau_max, ">=",
        fmt::format("no slope +1/2 region up to tau_max = {:g} s: the +1/2 line through the last "
                    "point bounds it",
                    tau_max));
  }

  // Bias instability: the minimum / 0.664.
  const auto it = std::min_element(adev_dph.begin(), adev_dph.end());
  const auto i = static_cast<std::size_t>(it - adev_dph.begin());
  if (i > 0 && i + 1 < n) {
    out.bias_instability_dph = term_value(*it / kBiasInstabilityFactor, "minimum / 0.664");
    out.bias_instability_dph.tau_s = tau_s[i];
    out.bias_instability_dph.tau_relation = "=";
  } else if (i + 1 == n) {
    out.bias_instability_dph =
        term_bound(sigma_last / kBiasInstabilityFactor, tau_max, ">=",
                   fmt::format("no minimum yet: the curve still falls at tau_max = {:g} s "
                               "(record longer to reach the floor); sigma(tau_max) / 0.664",
                               tau_max));
  } else {
    out.bias_instability_dph =
        term_bound(sigma_first / kBiasInstabilityFactor, tau_min, "<=",
                   fmt::format("the curve rises from the first tau = {:g} s: the floor lies at "
                               "shorter tau; sigma(tau_min) / 0.664",
                               tau_min));
  }
  return out;
}

AllanNoiseTerms allan_noise_terms(std::size_t n_samples, double tau0_s,
                                  std::span<const double> tau_s, std::span<const double> adev_dph) {
  std::vector<double> edf;
  edf.reserve(tau_s.size());
  for (const double tau : tau_s) {
    const double m = tau0_s > 0 ? std::round(tau / tau0_s) : 0.0;
    edf.push_back(m >= 1 && 2 * m <= static_cast<double>(n_samples)
                      ? allan_edf_white_fm(n_samples, static_cast<std::size_t>(m))
                      : kNaN);
  }
  for (const double e : edf) {
    if (!(e > 0)) {
      AllanNoiseTerms out;
      const std::string why = fmt::format(
          "the stored curve does not fit n = {} samples at tau0 = {:g} s", n_samples, tau0_s);
      out.angle_random_walk_dprh.note = out.bias_instability_dph.note =
          out.rate_random_walk_dphprh.note = why;
      return out;
    }
  }
  return allan_noise_terms(tau_s, adev_dph, edf);
}

Result<AllanResult> allan_deviation(std::span<const double> t_s, std::span<const double> rate_dph,
                                    const AllanOptions& options) {
  if (std::string why; !options.is_valid(&why)) {
    return Error::Permanent("allan_deviation: invalid options: " + why);
  }
  if (t_s.size() != rate_dph.size()) {
    return Error::Permanent(
        fmt::format("allan_deviation: {} times but {} rates", t_s.size(), rate_dph.size()));
  }
  const std::size_t n = t_s.size();
  if (n < 2) {
    return Error::Permanent(fmt::format("allan_deviation: {} sample(s), at least 2 are needed", n));
  }
  const Sample sample = sample_series(t_s, rate_dph);
  allan_detail::ScratchBuffer prefix(n + 1);
  const ScanResult scanned =
      scan_and_prefix(t_s, rate_dph, sample.lo, sample.hi, sample.shift, prefix.data());
  if (!scanned.clean) {
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(t_s[i])) {
        return Error::Permanent(
            fmt::format("allan_deviation: t_s[{}] is not finite ({})", i, t_s[i]));
      }
      if (!std::isfinite(rate_dph[i])) {
        return Error::Permanent(
            fmt::format("allan_deviation: rate_dph[{}] is not finite ({}) at t_s = {}", i,
                        rate_dph[i], t_s[i]));
      }
      if (i > 0 && !(t_s[i] > t_s[i - 1])) {
        return Error::Permanent(fmt::format(
            "allan_deviation: times not strictly increasing: t_s[{}] = {} after t_s[{}] = {}", i,
            t_s[i], i - 1, t_s[i - 1]));
      }
    }
    return Error::Permanent("allan_deviation: the input could not be checked");  // not reached
  }
  if (!std::isfinite(prefix.data()[n])) {
    return Error::Permanent("allan_deviation: the rates are too large (their sum overflows)");
  }

  double tau0_s = median_from_scan(scanned, n - 1, sample.lo, sample.hi).value_or(0.0);
  if (!(tau0_s > 0)) tau0_s = median_spacing(t_s);
  const std::vector<std::size_t> ms = allan_cluster_sizes(n, options.taus);
  const std::vector<double> var = allan_detail::allan_variances(prefix.data(), n, ms);
  std::vector<std::optional<NoiseIdentification>> ids(ms.size());
  for (std::size_t j = 0; j < ms.size(); ++j) {
    if (n / ms[j] >= kMinNoiseIdAverages) {
      ids[j] = allan_detail::identify_block_means(
          allan_detail::block_means_from_prefix(prefix.data(), n, ms[j]));
    }
  }
  return allan_detail::assemble_allan(n, tau0_s, ms, var, ids);
}

namespace allan_detail {

AllanResult assemble_allan(std::size_t n, double tau0_s, const std::vector<std::size_t>& ms,
                           const std::vector<double>& var,
                           const std::vector<std::optional<NoiseIdentification>>& ids) {
  AllanResult r;
  r.n_samples = n;
  r.tau0_s = tau0_s;
  int alpha = 0;  // white rate noise until one is identified
  for (std::size_t j = 0; j < ms.size(); ++j) {
    const std::size_t m = ms[j];
    const double adev = std::sqrt(var[j]);
    if (ids[j]) alpha = ids[j]->alpha;
    const double edf = allan_edf(alpha, n, m);
    r.noise_alpha.push_back(alpha);
    r.tau_s.push_back(static_cast<double>(m) * r.tau0_s);
    r.m.push_back(m);
    r.adev_dph.push_back(adev);
    r.adev_lo_dph.push_back(adev * std::sqrt(edf / chi2_quantile(edf, 0.8415)));
    r.adev_hi_dph.push_back(adev * std::sqrt(edf / chi2_quantile(edf, 0.1585)));
    r.n_terms.push_back(n - 2 * m + 1);
    r.edf.push_back(edf);
  }

  // The lines are read with white noise's edf as weights, whatever the noise:
  // a stored curve (which keeps no edf) gives the same terms.
  std::vector<double> line_weights;
  line_weights.reserve(ms.size());
  for (const std::size_t m : ms) line_weights.push_back(allan_edf_white_fm(n, m));
  r.noise = allan_noise_terms(r.tau_s, r.adev_dph, line_weights);
  r.angle_random_walk_dprh = r.noise.angle_random_walk_dprh.value_if_read();
  r.rate_random_walk_dphprh = r.noise.rate_random_walk_dphprh.value_if_read();
  r.bias_instability_dph = r.noise.bias_instability_dph.value_if_read();
  if (r.bias_instability_dph) r.bias_instability_tau_s = r.noise.bias_instability_dph.tau_s;
  return r;
}

}  // namespace allan_detail

}  // namespace gyrotherm::analysis
