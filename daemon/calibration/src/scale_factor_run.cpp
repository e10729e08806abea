#include "gyrotherm/calibration/scale_factor_run.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>

#include "gyrotherm/analysis/scale_factor.h"
#include "gyrotherm/calibration/run_analysis.h"

namespace gyrotherm::calibration {
namespace {

constexpr double kDphPerDps = 3600.0;

std::string coefficients_json(const std::vector<double>& c) { return nlohmann::json(c).dump(); }

// A rate point's windows with the guard band cut from both ends of each,
// then cut to whole turns from its start when at least one is left.
// Windows shorter than two guards are dropped.
std::vector<std::pair<double, double>> guarded_windows(
    const std::vector<std::pair<double, double>>& windows, double rate_dps, double guard_s) {
  std::vector<std::pair<double, double>> out;
  const double turn_s = rate_dps != 0 ? 360.0 / std::abs(rate_dps) : 0.0;
  for (const auto& [from_s, to_s] : windows) {
    const double from = from_s + guard_s;
    double to = to_s - guard_s;
    if (!(to > from)) continue;
    if (turn_s > 0) {
      const double turns = std::floor((to - from) / turn_s * (1 + 1e-12));
      if (turns >= 1) to = std::min(to, from + turns * turn_s);
    }
    out.emplace_back(from, to);
  }
  return out;
}

// One rate point from its segment's windows; nullopt (with the reason in
// `problem`) when it cannot be used at all. A point that can be measured
// but is not trustworthy is returned with quality "excluded" and the
// reason in `problem` too.
using MaybePoint = std::optional<storage::ScaleFactorPointRecord>;

Result<MaybePoint> rate_point(storage::Database& db, const storage::SegmentRecord& seg,
                              const AnalysedAxis& axis, const AnalysisSettings& settings,
                              std::string& problem) {
  std::string where = fmt::format("run {} segment {} ({})", seg.run_id, seg.index + 1, seg.label);
  if (!axis.dut_serial.empty() || !axis.axis.empty()) where += ", " + axis.name();
  if (!seg.table_rate_dps || *seg.table_rate_dps == 0) {
    problem = where + ": no demanded rate stored";
    return MaybePoint{};
  }
  const double rate_dps = *seg.table_rate_dps;
  const auto windows =
      sorted_windows(guarded_windows(seg.windows, rate_dps, settings.rate_guard_s));
  if (windows.empty()) {
    problem = fmt::format("{}: its acquisition windows are shorter than two guard bands of {:g} s",
                          where, settings.rate_guard_s);
    return MaybePoint{};
  }
  std::vector<double> output_dps, t_s;
  double duration_s = 0;
  double temp_sum_c = 0;
  int64_t temp_n = 0;
  for (const auto& [from_s, to_s] : windows) {
    auto gyro = axis.channel_id == 0 ? db.gyro_samples(seg.run_id, from_s, to_s)
                                     : db.gyro_samples(seg.run_id, axis.key(), from_s, to_s);
    if (!gyro) return gyro.error();
    for (const auto& g : *gyro) {
      if (!std::isfinite(g.rate_dph)) continue;  // flagged invalid
      output_dps.push_back(g.rate_dph / kDphPerDps);
      t_s.push_back(g.t_s);
    }
    duration_s += to_s - from_s;
    auto temps = dut_shell_readings(db, seg.run_id, axis, from_s, to_s);
    if (!temps) return temps.error();
    for (const auto& t : *temps) {
      if (std::isnan(t.top_c) || std::isnan(t.side_c)) continue;
      temp_sum_c += (t.top_c + t.side_c) / 2.0;
      ++temp_n;
    }
  }
  if (output_dps.empty()) {
    problem = where + ": no gyro samples in its acquisition windows";
    return MaybePoint{};
  }
  auto table = db.mean_table_over_windows(seg.run_id, windows);
  if (!table) return table.error();
  double sum_dps = 0;
  for (double v : output_dps) sum_dps += v;
  storage::ScaleFactorPointRecord p;
  p.run_id = seg.run_id;
  p.dut_serial = axis.dut_serial;
  p.axis = axis.axis;
  p.segment_id = seg.id;
  p.sf_sequence = seg.sf_sequence;
  p.repetition = seg.sf_repetition;
  p.rate_dps = rate_dps;
  p.measured_rate_dps = table->rate_dps.value_or(NAN);
  p.output_dps = sum_dps / static_cast<double>(output_dps.size());
  p.n = static_cast<int64_t>(output_dps.size());
  p.temperature_c = temp_n > 0 ? temp_sum_c / static_cast<double>(temp_n) : NAN;
  p.duration_s = duration_s;
  p.turns = std::abs(p.rate_dps) * duration_s / 360.0;
  p.guard_s = settings.rate_guard_s;
  if (std::isnan(p.temperature_c)) {
    problem = where + ": no shell temperature in its acquisition windows";
    return MaybePoint{};
  }
  const analysis::Coverage coverage = analysis::coverage_of(
      t_s, windows, axis.rate_hz > 0 ? axis.rate_hz : analysis::median_rate_hz(t_s));
  p.quality = result_quality(coverage, analysis::coverage_reasons(coverage, settings.quality));
  std::string excluded;
  if (table->rate_dps) {
    const double error_ppm = std::abs(*table->rate_dps / p.rate_dps - 1.0) * 1e6;
    if (error_ppm > kMaxRateErrorPpm) {
      excluded = fmt::format(
          "the table measured {:.6g} °/s for a demand of {:g} °/s ({:.0f} ppm off, limit {:g})",
          *table->rate_dps, p.rate_dps, error_ppm, kMaxRateErrorPpm);
    }
  }
  if (excluded.empty()) {
    const auto flat = analysis::check_rate_point_flatness(output_dps, rate_dps, settings.flatness);
    if (!flat.ok) excluded = "gyro output " + flat.why;
  }
  if (excluded.empty()) {
    // The table's own readings over the windows: flat, and at the demand.
    std::vector<double> table_dps;
    for (const auto& [from_s, to_s] : windows) {
      auto readings = db.table_samples(seg.run_id, from_s, to_s);
      if (!readings) return readings.error();
      for (const auto& r : *readings) table_dps.push_back(r.rate_dps);
    }
    const auto flat =
        analysis::check_rate_point_flatness(table_dps, rate_dps, settings.flatness, true);
    if (!flat.ok) excluded = "table rate " + flat.why;
  }
  if (!excluded.empty()) {
    p.quality.verdict = "excluded";
    p.quality.reasons.insert(p.quality.reasons.begin(), excluded);
    problem = fmt::format("{}: point at {:g} °/s, {:.2f} °C left out of the fit: {}", where,
                          p.rate_dps, p.temperature_c, excluded);
  }
  return MaybePoint{p};
}

// One DUT's table axis: its points, lines and K(T), stored.
Status analyse_axis(storage::Database& db, int64_t run_id,
                    const std::vector<storage::SegmentRecord>& segments, const AnalysedAxis& axis,
                    const AnalysisSettings& settings, ScaleFactorSummary& summary) {
  const std::string who = axis.dut_serial.empty() && axis.axis.empty()
                              ? fmt::format("run {}", run_id)
                              : fmt::format("run {} ({})", run_id, axis.name());
  std::vector<storage::ScaleFactorPointRecord> points;
  std::map<int, std::vector<const storage::ScaleFactorPointRecord*>> by_sequence;
  for (const auto& seg : segments) {
    if (seg.kind != "rate" || seg.state != "completed" || seg.windows.empty()) continue;
    std::string problem;
    auto p = rate_point(db, seg, axis, settings, problem);
    if (!p) return p.error();
    if (!problem.empty()) summary.problems.push_back(problem);
    if (!*p) continue;
    if ((*p)->quality.flagged()) {
      summary.flagged.push_back(fmt::format("{} scale-factor point at {:g} °/s (segment {}): {}",
                                            who, (*p)->rate_dps, seg.index + 1,
                                            fmt::join((*p)->quality.reasons, "; ")));
    }
    points.push_back(**p);
  }
  if (points.empty()) return Status::Ok();
  summary.points += static_cast<int>(points.size());
  for (const auto& p : points) {
    if (!p.quality.excluded()) by_sequence[p.sf_sequence].push_back(&p);
  }

  std::vector<storage::ScaleFactorFitRecord> fits;
  std::vector<analysis::ScaleFactorAtTemperature> plateaus;
  for (const auto& [sequence, members] : by_sequence) {
    std::vector<analysis::RatePoint> input;
    for (const auto* p : members) {
      analysis::RatePoint r;
      r.rate_dps = p->rate_dps;
      r.output_dps = p->output_dps;
      r.repetition = p->repetition;
      r.temperature_c = p->temperature_c;
      r.n = static_cast<std::size_t>(p->n);
      r.duration_s = p->duration_s;
      input.push_back(r);
    }
    auto fit = analysis::fit_scale_factor(input);
    if (!fit) {
      summary.problems.push_back(
          fmt::format("{} scale-factor sequence {}: {}", who, sequence, fit.error().message));
      continue;
    }
    storage::ScaleFactorFitRecord rec;
    rec.run_id = run_id;
    rec.dut_serial = axis.dut_serial;
    rec.axis = axis.axis;
    rec.sf_sequence = sequence;
    rec.temperature_c = fit->temperature_mean_c;
    rec.k = fit->k;
    rec.k_se = fit->k_std_error;
    rec.bias_dps = fit->bias_dps;
    rec.nonlinearity_ppm = fit->nonlinearity_ppm;
    rec.nonlinearity_fs_ppm = fit->nonlinearity_fs_ppm;
    rec.asymmetry_ppm = fit->asymmetry_ppm;
    rec.repeatability_ppm = fit->repeatability_ppm;
    rec.n_points = static_cast<int64_t>(fit->points);
    rec.guard_s = settings.rate_guard_s;
    // Its points' coverage together: samples and expectation summed, the
    // longest gap of any.
    analysis::Coverage coverage;
    bool expected_known = true;
    for (const auto* p : members) {
      coverage.samples += p->quality.samples;
      coverage.expected += p->quality.expected;
      coverage.longest_gap_s =
          std::max(coverage.longest_gap_s, p->quality.longest_gap_s.value_or(0));
      expected_known = expected_known && p->quality.expected > 0;
    }
    if (expected_known && coverage.expected > 0) {
      coverage.fraction = static_cast<double>(coverage.samples) / coverage.expected;
    } else {
      coverage.expected = 0;
    }
    std::vector<std::string> reasons = analysis::coverage_reasons(coverage, settings.quality);
    for (std::string& r :
         analysis::scale_factor_reasons(fit->k, fit->nonlinearity_ppm, settings.quality)) {
      reasons.push_back(std::move(r));
    }
    rec.quality = result_quality(coverage, std::move(reasons));
    if (rec.quality.flagged()) {
      summary.flagged.push_back(fmt::format("{} scale-factor sequence {}: {}", who, sequence,
                                            fmt::join(rec.quality.reasons, "; ")));
    }
    fits.push_back(rec);
    plateaus.push_back({fit->temperature_mean_c, fit->k, fit->bias_dph});
  }
  summary.sequences += static_cast<int>(fits.size());

  std::optional<storage::ScaleFactorTemperatureFitRecord> over_t;
  if (plateaus.size() >= 2) {
    const int order = plateaus.size() >= 4 ? 2 : 1;
    auto tf = analysis::fit_scale_factor_over_temperature(plateaus, order);
    if (tf) {
      storage::ScaleFactorTemperatureFitRecord rec;
      rec.run_id = run_id;
      rec.dut_serial = axis.dut_serial;
      rec.axis = axis.axis;
      rec.order = tf->order;
      rec.t_centre_c = tf->temperature_mean_c;
      rec.k_coeffs_json = coefficients_json(tf->k_coefficients);
      std::vector<double> bias_dps;
      for (double c : tf->bias_coefficients_dph) bias_dps.push_back(c / kDphPerDps);
      rec.bias_coeffs_json = coefficients_json(bias_dps);
      rec.k_ppm_per_c = tf->sf_temperature_coefficient_ppm_per_c;
      rec.bias_dph_per_c = tf->bias_temperature_coefficient_dph_per_c;
      over_t = rec;
      summary.temperature_fit = true;
    } else {
      summary.problems.push_back(
          fmt::format("{}: scale factor over temperature: {}", who, tf.error().message));
    }
  }
  return db.store_scale_factor(run_id, points, fits, over_t);
}

}  // namespace

Result<ScaleFactorSummary> analyse_scale_factor(storage::Database& db, int64_t run_id) {
  auto run = db.run(run_id);
  if (!run) return run.error();
  auto settings = analysis_settings_of_run(*run);
  return analyse_scale_factor(db, run_id, settings ? *settings : AnalysisSettings{});
}

Result<ScaleFactorSummary> analyse_scale_factor(storage::Database& db, int64_t run_id,
                                                const AnalysisSettings& settings) {
  auto segments = db.segments(run_id);
  if (!segments) return segments.error();
  ScaleFactorSummary summary;
  // Each step with a table demand gets the table's measured means over its
  // windows (segments.table_mean_*), once.
  for (auto& seg : *segments) {
    if (seg.table_mode == "none" || seg.windows.empty() || seg.table_mean_rate_dps) continue;
    auto means = db.mean_table_over_windows(run_id, seg.windows);
    if (!means) return means.error();
    if (!means->rate_dps) continue;
    seg.table_mean_rate_dps = means->rate_dps;
    seg.table_mean_position_deg = means->position_deg;
    if (auto st = db.update_segment(seg); !st) return st.error();
  }
  const bool has_rate_points = std::any_of(segments->begin(), segments->end(), [](const auto& s) {
    return s.kind == "rate" && s.state == "completed" && !s.windows.empty();
  });
  if (!has_rate_points) return summary;
  auto axes = analysed_axes(db, run_id);
  if (!axes) return axes.error();
  // Each DUT's axis along the table's spin axis.
  for (const AnalysedAxis& axis : *axes) {
    if (!axis.table_axis) continue;
    if (Status st = analyse_axis(db, run_id, *segments, axis, settings, summary); !st) {
      return st.error();
    }
  }
  return summary;
}

}  // namespace gyrotherm::calibration
