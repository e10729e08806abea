// The paper's comparison of compensation models (Tables II-IV, docs/analysis.md).
//
// For polynomial orders 1 ... max_order of the temperature T and the term sets
// {T}, {T, dT} and {T, dT, dT/dt} (the gradient and rate terms at the paper's
// order 1 unless set otherwise), the drift model (eq. 1) is fitted and the
// gyro output compensated: compensated = rate - drift_terms(fit) (L0 plus
// the residual in the paper form). Each cell reports the mean and sample std
// (ddof = 1) of the compensated output over every point of every run, beside
// the uncompensated ("none") row, each run's output first smoothed by a
// smooth_points-point centred moving average (default 101, as Table I's last
// column; at 1 s bins the raw white noise hides every temperature term):
// - in-sample, as the paper did: one fit on all runs together, applied to
//   them;
// - leave-one-run-out (what the paper did not do): for each run, a fit on
//   the other runs, applied to the held-out run; the compensated outputs of
//   all held-out runs are pooled. Needs >= 2 runs.
// A cell whose fit fails (constant temperature, too few points, rank) keeps
// the error text instead of numbers; the grid as a whole still succeeds.
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/core/result.h"

namespace gyrotherm::analysis {

enum class TermSet { kT, kTG, kTGR };     // {T}, {T, dT}, {T, dT, dT/dt}
std::string_view to_string(TermSet set);  // "T", "T+G", "T+G+R"

struct ComparisonOptions {
  int max_order = 4;  // T orders 1 ... max_order (1..4)
  int g_order = 1;    // order of dT in {T, dT} and {T, dT, dT/dt}
  int r_order = 1;    // order of dT/dt in {T, dT, dT/dt}
  DriftModelForm form = kDefaultDriftModelForm;
  DriftFitOptions fit;  // derivative and L0 windows, tolerances
  // Each run's compensated output (and its uncompensated rate, "none") is
  // smoothed by this many points' centred moving average before the pooled
  // mean and std: Table I's last column (101 points, the n - 100 full
  // windows of each run). 1 = the raw bins. Odd, 1 ... 100001. The fits
  // themselves are always made on the raw series.
  std::size_t smooth_points = 101;
  bool cross_validate = true;  // leave-one-run-out when >= 2 runs

  // False with a message naming the bad field.
  bool is_valid(std::string* why) const;
};

struct CompensatedStats {
  std::size_t n = 0;
  double mean_dph = 0;
  double std_dph = 0;  // ddof = 1
};

struct ComparisonCell {
  TermSet terms = TermSet::kT;
  int order = 1;        // of T
  DriftModelSpec spec;  // e.g. T2+G1
  std::optional<CompensatedStats> in_sample;
  std::string in_sample_error;  // why in_sample is empty
  std::optional<CompensatedStats> cross_validated;
  std::string cross_validated_error;  // why cross_validated is empty (e.g. "needs >= 2 runs")
  std::optional<DriftFit> fit;        // the in-sample fit
};

struct Comparison {
  std::size_t runs = 0;
  CompensatedStats none;  // the uncompensated output
  // Term set major, then order: {T} 1..max, {T, dT} 1..max, {T, dT, dT/dt} 1..max.
  std::vector<ComparisonCell> cells;
  ComparisonOptions options;
};

// "raw bins (not smoothed)" or "after a 101-point centred moving average of
// each run (full windows only)", for people.
std::string smoothing_label(std::size_t smooth_points);

// Errors (permanent): invalid options; no runs; a run that is invalid as a
// series (non-finite, not increasing; names the 1-based run), has < 2 points
// or fewer points than smooth_points.
Result<Comparison> compare_models(std::span<const AnalysisSeries> runs,
                                  const ComparisonOptions& options = {});

}  // namespace gyrotherm::analysis
