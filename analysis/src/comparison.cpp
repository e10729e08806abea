// The comparison of compensation models (paper Tables II-IV); see comparison.h.
#include "gyrotherm/analysis/comparison.h"

#include <fmt/format.h>

#include <array>
#include <cmath>
#include <utility>

#include "common.h"

namespace gyrotherm::analysis {
namespace {

// The means of every `points` consecutive values (the n - points + 1 full
// windows; x itself when points <= 1): a running sum in long double,
// restarted from a fresh sum every 1024 windows so rounding cannot build up.
std::vector<double> moving_average(std::vector<double> x, std::size_t points) {
  if (points <= 1 || x.size() < points) return x;
  const std::size_t windows = x.size() - points + 1;
  std::vector<double> out(windows);
  long double sum = 0;
  for (std::size_t w = 0; w < windows; ++w) {
    if (w % 1024 == 0) {
      sum = 0;
      for (std::size_t k = w; k < w + points; ++k) sum += x[k];
    } else {
      sum += static_cast<long double>(x[w + points - 1]) - x[w - 1];
    }
    out[w] = static_cast<double>(sum / static_cast<long double>(points));
  }
  return out;
}

// Pooled mean and sample std of several vectors (each smoothed first by a
// `points`-point moving average): two passes in long double.
class Pool {
 public:
  explicit Pool(std::size_t points) : points_(points) {}
  void add(std::vector<double> v) { parts_.push_back(moving_average(std::move(v), points_)); }

  Result<CompensatedStats> stats(std::string_view what) const {
    CompensatedStats s;
    long double sum = 0;
    for (const auto& p : parts_) {
      for (double v : p) {
        if (!std::isfinite(v)) {
          return Error::Permanent(fmt::format("{}: a compensated value is not finite", what));
        }
        sum += v;
      }
      s.n += p.size();
    }
    if (s.n < 2) {
      return Error::Permanent(fmt::format("{}: {} point(s), need 2 for a std", what, s.n));
    }
    const long double m0 = sum / static_cast<long double>(s.n);
    long double s1 = 0, s2 = 0;
    for (const auto& p : parts_) {
      for (double v : p) {
        const long double d = static_cast<long double>(v) - m0;
        s1 += d;
        s2 += d * d;
      }
    }
    const auto n = static_cast<long double>(s.n);
    s.mean_dph = static_cast<double>(m0 + s1 / n);
    s.std_dph = static_cast<double>(std::sqrt(std::max(0.0L, (s2 - s1 * s1 / n) / (n - 1))));
    return s;
  }

 private:
  std::size_t points_;
  std::vector<std::vector<double>> parts_;
};

Status check_run(const AnalysisSeries& s, std::size_t index, std::size_t smooth_points) {
  if (Status st = check_analysis_series(s, fmt::format("compare: run {}", index + 1)); !st.ok()) {
    return st;
  }
  if (s.t_s.size() < 2) {
    return Error::Permanent(
        fmt::format("compare: run {} has {} point(s) (need 2)", index + 1, s.t_s.size()));
  }
  if (s.t_s.size() < smooth_points) {
    return Error::Permanent(fmt::format(
        "compare: run {} has {} point(s), fewer than the {}-point moving average (smooth_points)",
        index + 1, s.t_s.size(), smooth_points));
  }
  return Status::Ok();
}

// rate - drift_terms(fit) of one run.
Result<std::vector<double>> compensate(const DriftFit& fit, const AnalysisSeries& run) {
  auto terms = drift_terms(fit, run);
  if (!terms) return terms.error();
  std::vector<double> out(run.rate_dph.size());
  for (std::size_t i = 0; i < out.size(); ++i) out[i] = run.rate_dph[i] - (*terms)[i];
  return out;
}

DriftModelSpec spec_of(TermSet set, int order, const ComparisonOptions& o) {
  DriftModelSpec spec;
  spec.t_order = order;
  if (set != TermSet::kT) spec.g_order = o.g_order;
  if (set == TermSet::kTGR) spec.r_order = o.r_order;
  return spec;
}

void in_sample(std::span<const AnalysisSeries> runs, const ComparisonOptions& o,
               ComparisonCell& cell) {
  auto fit = fit_drift_model(runs, cell.spec, o.form, o.fit);
  if (!fit) {
    cell.in_sample_error = fit.error().message;
    return;
  }
  Pool pool(o.smooth_points);
  for (std::size_t r = 0; r < runs.size(); ++r) {
    auto c = compensate(*fit, runs[r]);
    if (!c) {
      cell.in_sample_error = fmt::format("run {}: {}", r + 1, c.error().message);
      return;
    }
    pool.add(std::move(*c));
  }
  auto stats = pool.stats(to_string(cell.spec));
  if (!stats) {
    cell.in_sample_error = stats.error().message;
    return;
  }
  cell.in_sample = *stats;
  cell.fit = std::move(*fit);
}

// `work`: a copy of the runs (restored on return).
void cross_validated(std::span<const AnalysisSeries> runs, std::vector<AnalysisSeries>& work,
                     const ComparisonOptions& o, ComparisonCell& cell) {
  if (!o.cross_validate) {
    cell.cross_validated_error = "leave-one-run-out not requested";
    return;
  }
  if (runs.size() < 2) {
    cell.cross_validated_error =
        fmt::format("leave-one-run-out needs >= 2 runs ({} given)", runs.size());
    return;
  }
  Pool pool(o.smooth_points);
  // The held-out run is swapped to the end; the fit sees the others.
  const std::size_t last = work.size() - 1;
  for (std::size_t held = 0; held < runs.size(); ++held) {
    std::swap(work[held], work[last]);  // (held == last: no-op)
    auto fit = fit_drift_model(std::span<const AnalysisSeries>(work.data(), last), cell.spec,
                               o.form, o.fit);
    std::swap(work[held], work[last]);
    if (!fit) {
      cell.cross_validated_error =
          fmt::format("run {} held out: {}", held + 1, fit.error().message);
      return;
    }
    auto c = compensate(*fit, runs[held]);
    if (!c) {
      cell.cross_validated_error = fmt::format("run {} held out: {}", held + 1, c.error().message);
      return;
    }
    pool.add(std::move(*c));
  }
  auto stats = pool.stats(to_string(cell.spec));
  if (!stats) {
    cell.cross_validated_error = stats.error().message;
    return;
  }
  cell.cross_validated = *stats;
}

}  // namespace

std::string_view to_string(TermSet set) {
  switch (set) {
    case TermSet::kT:
      return "T";
    case TermSet::kTG:
      return "T+G";
    case TermSet::kTGR:
      return "T+G+R";
  }
  return "?";
}

bool ComparisonOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  if (max_order < 1 || max_order > kMaxTermOrder) {
    return fail(fmt::format("max_order must be 1..{} ({})", kMaxTermOrder, max_order));
  }
  if (g_order < 1 || g_order > kMaxTermOrder) {
    return fail(fmt::format("g_order must be 1..{} ({})", kMaxTermOrder, g_order));
  }
  if (r_order < 1 || r_order > kMaxTermOrder) {
    return fail(fmt::format("r_order must be 1..{} ({})", kMaxTermOrder, r_order));
  }
  if (smooth_points < 1 || smooth_points > 100001 || smooth_points % 2 == 0) {
    return fail(fmt::format("smooth_points must be odd, 1..100001 ({})", smooth_points));
  }
  std::string sub_why;
  if (!fit.is_valid(&sub_why)) return fail("fit: " + sub_why);
  return true;
}

std::string smoothing_label(std::size_t smooth_points) {
  if (smooth_points <= 1) return "of the raw bins (not smoothed)";
  return fmt::format(
      "after a {}-point centred moving average of each run (the n − {} full "
      "windows)",
      smooth_points, smooth_points - 1);
}

Result<Comparison> compare_models(std::span<const AnalysisSeries> runs,
                                  const ComparisonOptions& options) {
  std::string why;
  if (!options.is_valid(&why)) return Error::Permanent("compare options: " + why);
  if (runs.empty()) return Error::Permanent("compare: no runs");
  Pool none(options.smooth_points);
  for (std::size_t r = 0; r < runs.size(); ++r) {
    if (Status st = check_run(runs[r], r, options.smooth_points); !st.ok()) return st.error();
    none.add(runs[r].rate_dph);
  }

  Comparison out;
  out.runs = runs.size();
  out.options = options;
  auto none_stats = none.stats("compare: uncompensated output");
  if (!none_stats) return none_stats.error();
  out.none = *none_stats;
  std::vector<AnalysisSeries> work;
  if (options.cross_validate && runs.size() >= 2) work.assign(runs.begin(), runs.end());
  for (TermSet set : {TermSet::kT, TermSet::kTG, TermSet::kTGR}) {
    for (int order = 1; order <= options.max_order; ++order) {
      ComparisonCell cell;
      cell.terms = set;
      cell.order = order;
      cell.spec = spec_of(set, order, options);
      in_sample(runs, options, cell);
      cross_validated(runs, work, options, cell);
      out.cells.push_back(std::move(cell));
    }
  }
  return out;
}

}  // namespace gyrotherm::analysis
