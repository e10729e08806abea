#include "gyrotherm/calibration/run_analysis.h"

#include <fmt/format.h>
#include <sqlite3.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <numbers>
#include <span>

#include "gyrotherm/analysis/scale_factor.h"
#include "gyrotherm/calibration/scale_factor_run.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/core/clock.h"

namespace gyrotherm::calibration {
namespace {

// Station seconds of samples read at a time for a whole-run series: 600 s
// of a 1 kHz gyro is 6e5 samples, ~25 MB.
constexpr double kRunChunkS = 600.0;
// After a rate step the table decelerates (500 °/s at 100 °/s²: 5 s): the
// drift fit leaves this much after each spinning step out too.
constexpr double kSpinDownMarginS = 10.0;
// [table] rest_rate_dps of a run that did not store it (its default).
constexpr double kRestRateDps = 0.01;

nlohmann::json num(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); }

nlohmann::json windows_json(const std::vector<std::pair<double, double>>& windows) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& [from_s, to_s] : windows) out.push_back({from_s, to_s});
  return out;
}

void append(analysis::AnalysisSeries& dst, const analysis::AnalysisSeries& src) {
  dst.bin_s = src.bin_s;
  dst.binned = src.binned;
  for (auto [d, s] : {std::pair{&dst.t_s, &src.t_s}, std::pair{&dst.rate_dph, &src.rate_dph},
                      std::pair{&dst.top_c, &src.top_c}, std::pair{&dst.side_c, &src.side_c}}) {
    d->insert(d->end(), s->begin(), s->end());
  }
}

std::string soak_name(const SoakWindow& soak) {
  return fmt::format("run {} segment {}", soak.run_id, soak.segment_index + 1);
}

}  // namespace

AnalysisSettings analysis_settings(const config::StationConfig& config) {
  AnalysisSettings s;
  s.table1.bin_s = config.analysis.bin_s;
  s.table1.ma_window = static_cast<std::size_t>(config.analysis.ma_window);
  s.table1.earth_rate_dph =
      analysis::earth_rate_component_dph(config.station.latitude_deg, config.station.orientation);
  if (auto taus = analysis::parse_tau_set(config.analysis.allan_taus)) s.allan_taus = *taus;
  if (auto spec = analysis::parse_model_spec(config.analysis.model)) s.model = *spec;
  s.fit.derivative_window_s = config.analysis.derivative_window_s;
  s.fit.l0_window_s = config.analysis.l0_window_s;
  s.compare_smooth_points = static_cast<std::size_t>(config.analysis.compare_smooth_points);
  s.rate_guard_s = config.analysis.rate_guard_s;
  s.flatness.n_sigma = config.analysis.rate_flatness_sigma;
  s.flatness.tolerance_ppm = config.analysis.rate_flatness_ppm;
  s.quality.min_coverage = config.quality.min_coverage;
  s.quality.k_min = config.quality.k_min;
  s.quality.k_max = config.quality.k_max;
  s.quality.max_nonlinearity_ppm = config.quality.max_nonlinearity_ppm;
  s.quality.max_residual_ratio = config.quality.max_residual_ratio;
  return s;
}

config::RunConfig read_run_config(const storage::RunRecord& run) {
  return config::read_run_config(run.config_json.empty() ? run.config_toml : run.config_json);
}

Result<AnalysisSettings> analysis_settings_of_run(const storage::RunRecord& run) {
  const config::RunConfig cfg = read_run_config(run);
  AnalysisSettings s;
  if (cfg.bin_s) s.table1.bin_s = *cfg.bin_s;
  if (cfg.ma_window) s.table1.ma_window = static_cast<std::size_t>(*cfg.ma_window);
  if (cfg.l0_window_s) s.fit.l0_window_s = *cfg.l0_window_s;
  if (cfg.derivative_window_s) s.fit.derivative_window_s = *cfg.derivative_window_s;
  if (cfg.compare_smooth_points && *cfg.compare_smooth_points >= 1) {
    s.compare_smooth_points = static_cast<std::size_t>(*cfg.compare_smooth_points);
  }
  if (cfg.rate_guard_s && *cfg.rate_guard_s >= 0) s.rate_guard_s = *cfg.rate_guard_s;
  if (cfg.rate_flatness_sigma && *cfg.rate_flatness_sigma > 0) {
    s.flatness.n_sigma = *cfg.rate_flatness_sigma;
  }
  if (cfg.rate_flatness_ppm && *cfg.rate_flatness_ppm >= 0) {
    s.flatness.tolerance_ppm = *cfg.rate_flatness_ppm;
  }
  if (cfg.min_coverage) s.quality.min_coverage = *cfg.min_coverage;
  if (cfg.k_min) s.quality.k_min = *cfg.k_min;
  if (cfg.k_max) s.quality.k_max = *cfg.k_max;
  if (cfg.max_nonlinearity_ppm) s.quality.max_nonlinearity_ppm = *cfg.max_nonlinearity_ppm;
  if (cfg.max_residual_ratio) s.quality.max_residual_ratio = *cfg.max_residual_ratio;
  const auto bad = [&run](std::string_view what, const std::string& value, const Error& e) {
    return Error::Permanent(
        fmt::format("run {}: stored {} \"{}\": {}", run.id, what, value, e.message));
  };
  if (cfg.model) {
    auto spec = analysis::parse_model_spec(*cfg.model);
    if (!spec) return bad("[analysis] model", *cfg.model, spec.error());
    s.model = *spec;
  }
  if (cfg.allan_taus) {
    auto taus = analysis::parse_tau_set(*cfg.allan_taus);
    if (!taus) return bad("[analysis] allan_taus", *cfg.allan_taus, taus.error());
    s.allan_taus = *taus;
  }
  const std::string orientation = run.orientation.empty() ? "up" : run.orientation;
  auto o = analysis::parse_orientation(orientation);
  if (!o) return bad("orientation", orientation, o.error());
  s.table1.earth_rate_dph = analysis::earth_rate_component_dph(run.latitude_deg, *o);
  std::string why;
  if (!s.table1.is_valid(&why) || !s.fit.is_valid(&why) || !s.flatness.is_valid(&why)) {
    return Error::Permanent(fmt::format("run {}: stored [analysis]: {}", run.id, why));
  }
  return s;
}

Result<std::vector<SoakWindow>> soak_windows(storage::Database& db, int64_t run_id) {
  auto run = db.run(run_id);
  if (!run) return run.error();
  auto segments = db.segments(run_id);
  if (!segments) return segments.error();
  std::vector<SoakWindow> out;
  for (const auto& seg : *segments) {
    // Static soaks only: Table I is the zero bias at rest.
    if (seg.kind != "soak" || seg.state != "completed" || seg.table_mode == "rate") continue;
    SoakWindow soak;
    soak.run_id = run_id;
    soak.segment_id = seg.id;
    soak.segment_index = seg.index;
    soak.setpoint_c = seg.setpoint_c;
    soak.windows = seg.windows;
    if (soak.windows.empty() && seg.t_acquire_start_s && seg.t_acquire_end_s) {
      soak.windows.emplace_back(*seg.t_acquire_start_s, *seg.t_acquire_end_s);
    }
    if (soak.windows.empty()) continue;
    soak.t_from_s = soak.windows.front().first;
    soak.t_to_s = soak.windows.back().second;
    out.push_back(std::move(soak));
  }
  return out;
}

std::string AnalysedAxis::name() const {
  if (dut_serial.empty() && axis.empty()) return "the gyro";
  return fmt::format("{} {}", dut_serial.empty() ? "the unnamed gyro" : "SN " + dut_serial,
                     axis.empty() ? "(primary axis)" : axis);
}

std::string file_suffix(const AnalysedAxis& axis, bool only_stream) {
  if (only_stream && axis.dut_serial.empty()) return "";
  std::string serial = axis.dut_serial.empty() ? "unnamed" : axis.dut_serial;
  for (char& c : serial) {
    const auto u = static_cast<unsigned char>(c);
    if (!std::isalnum(u) && c != '.' && c != '_' && c != '-') c = '_';
  }
  return fmt::format("-{}-{}", serial, axis.axis.empty() ? "primary" : axis.axis);
}

namespace {

// What the analysis reads from a DUT's stored [[dut]] (dut_config_json):
// the orientation of each axis, the table axis, own probes. Read leniently
// (a missing or malformed key is not stored); an orientation that is
// stored but not up/down/horizontal is an error.
struct StoredDutConfig {
  std::vector<std::pair<std::string, std::string>> orientation;  // axis -> as stored
  // axis -> heading, degrees; runs stored before headings have none.
  std::vector<std::pair<std::string, double>> heading_deg;
  std::string table_axis;
  bool probes = false;
};

StoredDutConfig read_dut_config(const std::string& text, const std::string& primary_axis) {
  using json = nlohmann::json;
  StoredDutConfig c;
  const json j = json::parse(text.empty() ? std::string("{}") : text, nullptr, false);
  if (!j.is_object()) return c;
  if (j.contains("orientation")) {
    const json& o = j["orientation"];
    if (o.is_string()) {  // one direction: the primary axis's
      c.orientation.emplace_back(primary_axis, o.get<std::string>());
    } else if (o.is_object()) {
      for (const auto& [axis, v] : o.items()) {
        if (v.is_string()) c.orientation.emplace_back(axis, v.get<std::string>());
      }
    } else if (o.is_array()) {  // [["z", "up"], ...]
      for (const auto& e : o) {
        if (e.is_array() && e.size() == 2 && e[0].is_string() && e[1].is_string()) {
          c.orientation.emplace_back(e[0].get<std::string>(), e[1].get<std::string>());
        }
      }
    }
  }
  if (j.contains("heading_deg") && j["heading_deg"].is_object()) {
    for (const auto& [axis, v] : j["heading_deg"].items()) {
      if (v.is_number() && std::isfinite(v.get<double>())) {
        c.heading_deg.emplace_back(axis, v.get<double>());
      }
    }
  }
  if (j.contains("table_axis") && j["table_axis"].is_string()) {
    c.table_axis = j["table_axis"].get<std::string>();
  }
  c.probes = j.contains("probes") && j["probes"].is_object();
  return c;
}

}  // namespace

Result<std::vector<AnalysedAxis>> analysed_axes(storage::Database& db, int64_t run_id) {
  auto run = db.run(run_id);
  if (!run) return run.error();
  auto duts = db.run_duts(run_id);
  if (!duts) return duts.error();
  std::vector<AnalysedAxis> out;
  // The unnamed gyro's rate when its record has none: the run's [gyro].
  const double gyro_rate_hz = read_run_config(*run).gyro_rate_hz.value_or(0.0);
  if (duts->empty()) {
    out.emplace_back();  // the run's gyro as the first-DUT API reads it
    out.back().rate_hz = gyro_rate_hz;
    return out;
  }
  for (const storage::RunDutRecord& d : *duts) {
    const std::string who = fmt::format("run {} DUT {}", run_id,
                                        d.dut.serial.empty() ? "(unnamed)" : "SN " + d.dut.serial);
    std::string primary = d.primary_axis;
    std::vector<std::string> axes;
    if (!primary.empty()) axes.push_back(primary);
    for (const auto& a : d.axes) {
      if (std::find(axes.begin(), axes.end(), a) == axes.end()) axes.push_back(a);
    }
    if (axes.empty()) {  // no axis recorded: its rate channels
      for (const auto& ch : d.channels) {
        if (ch.spec.kind == ChannelKind::kRate) axes.push_back(ch.spec.axis);
      }
      if (!axes.empty()) primary = axes.back();
      std::stable_partition(axes.begin(), axes.end(),
                            [&](const std::string& a) { return a == primary; });
    }
    const StoredDutConfig cfg = read_dut_config(d.config_json, primary);
    const std::string table_axis = cfg.table_axis.empty() ? primary : cfg.table_axis;
    if (!table_axis.empty() && std::find(axes.begin(), axes.end(), table_axis) == axes.end()) {
      axes.push_back(table_axis);  // the scale factor needs it analysed
    }
    for (const std::string& a : axes) {
      AnalysedAxis s;
      s.dut_serial = d.dut.serial;
      s.dut_model = d.dut.model;
      s.axis = a;
      s.dut_position = d.position;
      s.primary = a == primary;
      s.table_axis = a == table_axis;
      s.own_probes = cfg.probes;
      s.rate_hz = d.rate_hz > 0 ? d.rate_hz : (d.dut.serial.empty() ? gyro_rate_hz : 0.0);
      for (const auto& ch : d.channels) {
        if (ch.spec.kind == ChannelKind::kRate && ch.spec.axis == a) s.channel_id = ch.id;
      }
      if (s.channel_id == 0) {
        return Error::Permanent(
            fmt::format("{}: axis \"{}\" has no rate channel recorded", who, a));
      }
      for (const auto& [axis, value] : cfg.orientation) {
        if (axis != a) continue;
        auto o = analysis::parse_orientation(value);
        if (!o) {
          return Error::Permanent(fmt::format("{}: stored orientation of axis {} \"{}\": {}", who,
                                              a, value, o.error().message));
        }
        s.orientation = *o;
      }
      // Not stored: the primary axis sits as the run says (the station's
      // orientation); another axis is horizontal ([[dut]] orientation).
      if (!s.orientation && !s.primary) s.orientation = analysis::AxisOrientation::kHorizontal;
      for (const auto& [axis, heading] : cfg.heading_deg) {
        if (axis == a) s.heading_deg = heading;
      }
      out.push_back(std::move(s));
    }
  }
  return out;
}

Result<AnalysedAxis> first_axis(storage::Database& db, int64_t run_id) {
  auto axes = analysed_axes(db, run_id);
  if (!axes) return axes.error();
  return axes->front();
}

namespace {

std::string soak_name(const SoakWindow& soak, const AnalysedAxis& axis) {
  if (axis.dut_serial.empty() && axis.axis.empty()) return soak_name(soak);
  return fmt::format("{} ({})", soak_name(soak), axis.name());
}

// One stream's samples in [from_s, to_s): the first-DUT API for a run
// without DUT records, the DUT's axis otherwise.
Result<std::vector<GyroSample>> stream_samples(storage::Database& db, int64_t run_id,
                                               const AnalysedAxis& axis, double from_s,
                                               double to_s) {
  auto gyro = axis.channel_id == 0 ? db.gyro_samples(run_id, from_s, to_s)
                                   : db.gyro_samples(run_id, axis.key(), from_s, to_s);
  if (!gyro) return gyro.error();
  // A value the frame flagged invalid is NaN: not a sample.
  std::erase_if(*gyro, [](const GyroSample& g) { return !std::isfinite(g.rate_dph); });
  return gyro;
}

// Rows of a run without DUT records read at a time (at 1 kHz: 0.6 M samples).
constexpr double kLegacySliceS = 600.0;

// One stream's rate samples in [from_s, to_s) as a source the analysis can
// read more than once (analysis/sample_source.h), a storage block at a time:
// the DUT axis's channel, or the first-DUT rows of a run without DUT records
// a slice at a time. A value the frame flagged invalid is NaN: not a sample.
analysis::SampleSource axis_source(storage::Database& db, int64_t run_id, const AnalysedAxis& axis,
                                   double from_s, double to_s) {
  return [&db, run_id, channel_id = axis.channel_id, from_s,
          to_s](const analysis::SampleBlock& block) -> Status {
    std::vector<double> t, v;
    bool stopped = false;
    const auto deliver = [&] {
      if (!t.empty() && !block(t, v)) stopped = true;
      t.clear();
      v.clear();
      return !stopped;
    };
    if (channel_id != 0) {
      return db.for_each_channel_block(
          channel_id, from_s, to_s,
          [&](std::span<const double> t_s, std::span<const double> value,
              std::span<const uint32_t>) {
            bool all_finite = true;
            for (const double x : value) all_finite &= std::isfinite(x);
            if (all_finite) return t_s.empty() || block(t_s, value);
            for (std::size_t i = 0; i < t_s.size(); ++i) {
              if (!std::isfinite(value[i])) continue;
              t.push_back(t_s[i]);
              v.push_back(value[i]);
            }
            return deliver();
          });
    }
    for (double a = from_s; a < to_s && !stopped; a += kLegacySliceS) {
      auto rows = db.gyro_samples(run_id, a, std::min(a + kLegacySliceS, to_s));
      if (!rows) return rows.error();
      for (const GyroSample& g : *rows) {
        if (!std::isfinite(g.rate_dph)) continue;
        t.push_back(g.t_s);
        v.push_back(g.rate_dph);
      }
      deliver();
    }
    return Status::Ok();
  };
}

// `source` whose first pass also feeds `counter` (when given): the
// analysis's first pass is its scan, every sample once, in order.
analysis::SampleSource counting_first_pass(analysis::SampleSource source,
                                           analysis::CoverageCounter* counter) {
  return [source = std::move(source), counter,
          pass = std::make_shared<int>(0)](const analysis::SampleBlock& block) {
    const bool count = counter != nullptr && (*pass)++ == 0;
    return source([&](std::span<const double> t_s, std::span<const double> rate) {
      if (count) {
        for (const double t : t_s) counter->add(t);
      }
      return block(t_s, rate);
    });
  };
}

}  // namespace

// The temperature rows of [from_s, to_s) that carry both shell probes. A row
// without them is a recorded gap (the probe module did not answer that tick),
// not a reading: the analysis bins the gyro against the rows around it.
Result<std::vector<TemperatureSample>> shell_readings(storage::Database& db, int64_t run_id,
                                                      double from_s, double to_s) {
  auto temps = db.temperature_samples(run_id, from_s, to_s);
  if (!temps) return temps.error();
  std::erase_if(*temps, [](const TemperatureSample& t) {
    return std::isnan(t.top_c) || std::isnan(t.side_c);
  });
  return temps;
}

Result<std::vector<TemperatureSample>> dut_shell_readings(storage::Database& db, int64_t run_id,
                                                          const AnalysedAxis& axis, double from_s,
                                                          double to_s) {
  auto station = shell_readings(db, run_id, from_s, to_s);
  if (!station || !axis.own_probes) return station;
  // The DUT's own probes: its channels probe_top_c and probe_side_c, read
  // each control tick beside the station's (the station stores both at the
  // same station time). The station's set point and chamber stay.
  auto duts = db.run_duts(run_id);
  if (!duts) return duts.error();
  int64_t top_id = 0, side_id = 0;
  for (const auto& d : *duts) {
    if (d.dut.serial != axis.dut_serial) continue;
    for (const auto& c : d.channels) {
      if (c.spec.name == "probe_top_c") top_id = c.id;
      if (c.spec.name == "probe_side_c") side_id = c.id;
    }
  }
  if (top_id == 0 || side_id == 0) return station;  // configured, never recorded: the station's
  std::vector<std::pair<double, double>> top, side;
  auto collect = [&](int64_t channel_id, std::vector<std::pair<double, double>>& out) {
    return db.for_each_channel_block(
        channel_id, from_s, to_s,
        [&](std::span<const double> t_s, std::span<const double> v, std::span<const uint32_t>) {
          for (std::size_t i = 0; i < t_s.size(); ++i) out.emplace_back(t_s[i], v[i]);
          return true;
        });
  };
  if (auto st = collect(top_id, top); !st) return st.error();
  if (auto st = collect(side_id, side); !st) return st.error();
  std::vector<TemperatureSample> out;
  std::size_t j = 0, k = 0;
  for (const auto& [t_s, top_c] : top) {
    while (k < side.size() && side[k].first < t_s - 1e-6) ++k;
    if (k == side.size() || std::fabs(side[k].first - t_s) > 1e-6) continue;
    while (j + 1 < station->size() && (*station)[j + 1].t_s <= t_s + 1e-6) ++j;
    TemperatureSample s = station->empty() ? TemperatureSample{} : (*station)[j];
    s.t_s = t_s;
    s.top_c = top_c;
    s.side_c = side[k].second;
    out.push_back(s);
  }
  return out;
}

Result<analysis::AnalysisSeries> soak_series(storage::Database& db, const SoakWindow& soak,
                                             double bin_s) {
  auto axis = first_axis(db, soak.run_id);
  if (!axis) return axis.error();
  return soak_series(db, soak, bin_s, *axis);
}

namespace {

// soak_series(), counting the samples into `counter` (when given) and
// setting `median_hz` (when given) to the output rate read off the first
// window with samples.
Result<analysis::AnalysisSeries> soak_series_counted(storage::Database& db, const SoakWindow& soak,
                                                     double bin_s, const AnalysedAxis& axis,
                                                     analysis::CoverageCounter* counter,
                                                     double* median_hz) {
  const std::string where = soak_name(soak, axis);
  analysis::AnalysisSeries joined;
  joined.bin_s = bin_s;
  for (const auto& [from_s, to_s] : soak.windows) {
    auto temps = dut_shell_readings(db, soak.run_id, axis, from_s, to_s);
    if (!temps) return Error::Transient(fmt::format("{}: {}", where, temps.error().message));
    // No scan when the samples did not scan clean: a window with a bad
    // sample is an error below, not an empty window.
    std::optional<analysis::SeriesScan> scan;
    auto part = analysis::make_analysis_series(
        counting_first_pass(analysis::prefetched(axis_source(db, soak.run_id, axis, from_s, to_s)),
                            counter),
        *temps, bin_s, &scan);
    if (median_hz != nullptr && *median_hz <= 0 && scan && scan->n >= 2) {
      *median_hz = 2.0 / (scan->spacing_lower_s + scan->spacing_upper_s);
    }
    if (!part && part.error().transient) {
      return Error::Transient(fmt::format("{}: {}", where, part.error().message));
    }
    if (!part && scan && scan->n == 0 && soak.windows.size() > 1) {
      continue;  // a window shorter than a sample
    }
    if (!part) {
      return Error::Permanent(fmt::format("{} window [{:.1f}, {:.1f}) s: {}", where, from_s, to_s,
                                          part.error().message));
    }
    append(joined, *part);
  }
  return joined;
}

}  // namespace

storage::ResultQuality result_quality(const analysis::Coverage& c,
                                      std::vector<std::string> reasons) {
  storage::ResultQuality q;
  q.samples = c.samples;
  q.expected = c.expected;
  q.coverage = c.fraction;
  q.longest_gap_s = c.longest_gap_s;
  q.reasons = std::move(reasons);
  q.verdict = q.reasons.empty() ? "ok" : "flagged";
  return q;
}

std::optional<storage::BiasUncertainty> bias_uncertainty_record(
    const std::optional<analysis::MeanUncertainty>& u) {
  if (!u) return std::nullopt;
  return storage::BiasUncertainty{.u_dph = u->u_dph,
                                  .expanded_dph = u->expanded_dph,
                                  .k = u->k,
                                  .dof = u->dof,
                                  .floor_dph = u->floor_dph,
                                  .random_walk_dominated = u->random_walk_dominated};
}

std::optional<analysis::MeanUncertainty> mean_uncertainty_of(const storage::SegmentStatsRecord& r) {
  if (!r.bias_u) return std::nullopt;
  analysis::MeanUncertainty u;
  u.window_s = r.duration_s;
  u.u_dph = r.bias_u->u_dph;
  u.dof = r.bias_u->dof;
  u.k = r.bias_u->k;
  u.expanded_dph = r.bias_u->expanded_dph;
  u.floor_dph = r.bias_u->floor_dph;
  u.random_walk_dominated = r.bias_u->random_walk_dominated;
  return u;
}

analysis::Table1Row table1_row_of(const storage::SegmentStatsRecord& r) {
  analysis::Table1Row row;
  row.n = static_cast<std::size_t>(std::max<int64_t>(r.n, 0));
  row.duration_s = r.duration_s;
  row.temp_mean_c = r.temp_mean_c;
  row.bias_mean_dph = r.bias_mean_dph;
  row.bias_std_dph = r.bias_std_dph;
  row.bias_std_ma_dph = r.bias_std_ma_dph;
  row.bias_mean_earth_removed_dph = r.bias_mean_earth_removed_dph;
  row.bias_u = mean_uncertainty_of(r);
  row.bias_u_note = r.bias_u_note;
  return row;
}

nlohmann::json mean_uncertainty_json(const std::optional<analysis::MeanUncertainty>& u) {
  if (!u) return nullptr;
  const auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nullptr; };
  return {{"window_s", num(u->window_s)},
          {"u_dph", num(u->u_dph)},
          {"dof", num(u->dof)},
          {"k", num(u->k)},
          {"expanded_dph", num(u->expanded_dph)},
          {"coverage", num(u->coverage)},
          {"floor_dph", num(u->floor_dph)},
          {"random_walk_dominated", u->random_walk_dominated}};
}

std::vector<std::pair<double, double>> sorted_windows(std::vector<std::pair<double, double>> w) {
  std::sort(w.begin(), w.end());
  std::vector<std::pair<double, double>> out;
  for (const auto& [from_s, to_s] : w) {
    if (!out.empty() && from_s <= out.back().second) {
      out.back().second = std::max(out.back().second, to_s);
    } else {
      out.emplace_back(from_s, to_s);
    }
  }
  return out;
}

Result<analysis::AnalysisSeries> soak_series(storage::Database& db, const SoakWindow& soak,
                                             double bin_s, const AnalysedAxis& axis) {
  return soak_series_counted(db, soak, bin_s, axis, nullptr, nullptr);
}

Result<RecordedSamples> soak_recorded_samples(storage::Database& db, const SoakWindow& soak) {
  auto axis = first_axis(db, soak.run_id);
  if (!axis) return axis.error();
  return soak_recorded_samples(db, soak, *axis);
}

Result<RecordedSamples> soak_recorded_samples(storage::Database& db, const SoakWindow& soak,
                                              const AnalysedAxis& axis) {
  if (soak.windows.empty()) {
    return Error::Permanent(fmt::format("{}: no acquisition window", soak_name(soak, axis)));
  }
  const auto longest = std::max_element(
      soak.windows.begin(), soak.windows.end(),
      [](const auto& a, const auto& b) { return a.second - a.first < b.second - b.first; });
  auto gyro = stream_samples(db, soak.run_id, axis, longest->first, longest->second);
  if (!gyro) {
    return Error::Transient(fmt::format("{}: {}", soak_name(soak, axis), gyro.error().message));
  }
  RecordedSamples out;
  out.t_from_s = longest->first;
  out.t_to_s = longest->second;
  out.t_s.reserve(gyro->size());
  out.rate_dph.reserve(gyro->size());
  for (const auto& s : *gyro) {
    out.t_s.push_back(s.t_s);
    out.rate_dph.push_back(s.rate_dph);
  }
  return out;
}

namespace {

// Table readings read at a time when looking for motion (1 h: 3600 rows at
// a 1 s control tick).
constexpr double kTableChunkS = 3600.0;
// A position change between consecutive readings larger than this is a
// move (encoder dither of a servo holding position is far below).
constexpr double kMovedDeg = 0.01;

// The stretches of a run when the table was not at rest: the steps that
// demanded a rate (to their end + kSpinDownMarginS; a step not ended yet
// to the end of the run), and by the table's own record each reading that
// turned faster than `rest_rate_dps` or had moved since the previous one,
// from the reading before it to the one after, widened by
// kSpinDownMarginS each side. Merged, in time order. The drift model is
// of the gyro at rest.
Result<std::vector<std::pair<double, double>>> spinning_spans(storage::Database& db, int64_t run_id,
                                                              double rest_rate_dps) {
  auto segments = db.segments(run_id);
  if (!segments) return segments.error();
  std::vector<std::pair<double, double>> out;
  for (const auto& seg : *segments) {
    if (seg.table_mode != "rate") continue;
    out.emplace_back(seg.t_start_s, seg.t_end_s ? *seg.t_end_s + kSpinDownMarginS
                                                : std::numeric_limits<double>::infinity());
  }
  auto last = db.last_sample_t_s(run_id);
  if (!last) return last.error();
  std::optional<TableSample> previous;
  bool previous_moving = false;
  for (double from_s = 0; *last && from_s <= **last; from_s += kTableChunkS) {
    auto readings =
        db.table_samples(run_id, from_s == 0 ? -kTableChunkS : from_s, from_s + kTableChunkS);
    if (!readings) return readings.error();
    for (const TableSample& t : *readings) {
      bool moving = std::isfinite(t.rate_dps) && std::fabs(t.rate_dps) > rest_rate_dps;
      if (previous && std::isfinite(t.position_deg) && std::isfinite(previous->position_deg)) {
        const double d = std::fmod(std::fabs(t.position_deg - previous->position_deg), 360.0);
        moving = moving || std::min(d, 360.0 - d) > kMovedDeg;
      }
      if (moving || previous_moving) {
        const double from = previous ? previous->t_s : t.t_s;
        out.emplace_back(from - kSpinDownMarginS, t.t_s + kSpinDownMarginS);
      }
      previous = t;
      previous_moving = moving;
    }
  }
  if (previous_moving) out.emplace_back(previous->t_s, std::numeric_limits<double>::infinity());
  return sorted_windows(std::move(out));
}

// The stretches of [from_s, to_s) outside `excluded` (merged, in order).
std::vector<std::pair<double, double>> complement(
    double from_s, double to_s, const std::vector<std::pair<double, double>>& excluded) {
  std::vector<std::pair<double, double>> out;
  double at = from_s;
  for (const auto& [a, b] : excluded) {
    if (b <= at) continue;
    if (a >= to_s) break;
    if (a > at) out.emplace_back(at, a);
    at = std::max(at, b);
  }
  if (at < to_s) out.emplace_back(at, to_s);
  return out;
}

}  // namespace

Result<analysis::AnalysisSeries> run_series(storage::Database& db, int64_t run_id, double bin_s) {
  auto axis = first_axis(db, run_id);
  if (!axis) return axis.error();
  return run_series(db, run_id, bin_s, *axis);
}

Result<analysis::AnalysisSeries> run_series(storage::Database& db, int64_t run_id, double bin_s,
                                            const AnalysedAxis& axis, RunSeriesCoverage* coverage) {
  const std::string who = axis.dut_serial.empty() && axis.axis.empty()
                              ? fmt::format("run {}", run_id)
                              : fmt::format("run {} ({})", run_id, axis.name());
  if (axis.channel_id == 0) {
    return Error::Permanent(fmt::format("{}: no gyro samples recorded", who));
  }
  auto run = db.run(run_id);
  if (!run) return run.error();
  const config::RunConfig cfg = read_run_config(*run);
  auto spinning = spinning_spans(db, run_id, cfg.table_rest_rate_dps.value_or(kRestRateDps));
  if (!spinning) return spinning.error();
  // What the coverage expects: the spans of the run's steps (a step not
  // ended yet: to the last sample), less the stretches left out.
  auto segments = db.segments(run_id);
  if (!segments) return segments.error();
  auto last = db.last_gyro_sample_t_s(run_id);
  if (!last) return last.error();
  std::vector<std::pair<double, double>> steps;
  for (const auto& seg : *segments) {
    const double end_s =
        seg.t_end_s ? *seg.t_end_s : (*last ? std::nextafter(**last, INFINITY) : seg.t_start_s);
    if (end_s > seg.t_start_s) steps.emplace_back(seg.t_start_s, end_s);
  }
  std::vector<std::pair<double, double>> expected;
  for (const auto& [from_s, to_s] : sorted_windows(std::move(steps))) {
    for (const auto& w : complement(from_s, to_s, *spinning)) expected.push_back(w);
  }
  analysis::CoverageCounter counter(std::move(expected));
  double median_hz = 0;
  analysis::AnalysisSeries joined;
  joined.bin_s = bin_s;
  // One pass over the channel, a storage block at a time, binned a stretch
  // of chunk_s at a time: the stretches start on the stream's first sample,
  // so the bins of consecutive stretches line up with the bins of one pass
  // over the whole run (and the series is what it was when the analysis
  // read the run in stretches of chunk_s through gyro_samples).
  const double chunk_s = std::max(kRunChunkS, std::ceil(kRunChunkS / bin_s) * bin_s);
  std::vector<GyroSample> chunk;
  bool started = false;
  double chunk_from_s = 0, last_s = 0;
  std::size_t spin_at = 0;  // the first span that may still hold a sample (time order)
  std::optional<Error> failure;
  const auto flush = [&](double from_s, double to_s) -> Status {
    if (median_hz <= 0 && chunk.size() >= 2) {
      std::vector<double> t_s;
      for (const GyroSample& g : chunk) t_s.push_back(g.t_s);
      median_hz = analysis::median_rate_hz(t_s);
    }
    std::erase_if(chunk, [&](const GyroSample& g) {
      while (spin_at < spinning->size() && (*spinning)[spin_at].second <= g.t_s) ++spin_at;
      return spin_at < spinning->size() && g.t_s >= (*spinning)[spin_at].first;
    });
    for (const GyroSample& g : chunk) counter.add(g.t_s);
    if (chunk.empty()) return Status::Ok();
    auto temps = dut_shell_readings(db, run_id, axis, from_s, to_s);
    if (!temps) return temps.error();
    if (!temps->empty()) {  // no temperature in this stretch: nothing to fit it with
      auto part = analysis::make_analysis_series(chunk, *temps, bin_s);
      if (!part) {
        return Error::Permanent(
            fmt::format("{} [{:.1f}, {:.1f}) s: {}", who, from_s, to_s, part.error().message));
      }
      append(joined, *part);
    }
    chunk.clear();
    return Status::Ok();
  };
  Status scanned = db.for_each_channel_block(
      axis.channel_id, std::numeric_limits<double>::lowest(), std::numeric_limits<double>::max(),
      [&](std::span<const double> t_s, std::span<const double> value,
          std::span<const uint32_t> seq) {
        for (std::size_t i = 0; i < t_s.size(); ++i) {
          if (!std::isfinite(value[i])) continue;  // flagged invalid
          if (!started) {
            started = true;
            chunk_from_s = t_s[i];
          }
          while (t_s[i] >= chunk_from_s + chunk_s) {
            if (Status st = flush(chunk_from_s, chunk_from_s + chunk_s); !st) {
              failure = st.error();
              return false;
            }
            chunk_from_s += chunk_s;
          }
          GyroSample g;
          g.t_s = t_s[i];
          g.rate_dph = value[i];
          g.seq = static_cast<uint8_t>(i < seq.size() ? seq[i] : 0);
          chunk.push_back(g);
          last_s = t_s[i];
        }
        return true;
      });
  if (!scanned) return scanned.error();
  if (failure) return *failure;
  if (!started) return Error::Permanent(fmt::format("{}: no gyro samples recorded", who));
  if (Status st = flush(chunk_from_s, std::nextafter(last_s, INFINITY)); !st) return st.error();
  if (joined.t_s.empty()) {
    return Error::Permanent(
        fmt::format("{}: no stretch of gyro samples with temperatures recorded", who));
  }
  if (coverage != nullptr) {
    coverage->excluded = *spinning;
    coverage->coverage = counter.result(axis.rate_hz > 0 ? axis.rate_hz : median_hz);
  }
  return joined;
}

namespace {

Result<double> soak_earth_rate_dph(storage::Database& db, const SoakWindow& soak,
                                   const AnalysedAxis& axis, double default_dph) {
  auto run = db.run(soak.run_id);
  if (!run) return run.error();
  const bool horizontal = axis.orientation == analysis::AxisOrientation::kHorizontal;
  const std::optional<double> heading_deg = horizontal ? axis.heading_deg : std::nullopt;
  const double axis_dph = axis.orientation ? analysis::earth_rate_component_dph(
                                                 run->latitude_deg, *axis.orientation, heading_deg)
                                           : default_dph;
  const config::RunConfig cfg = read_run_config(*run);
  // The table's rule is for the axis along the table's spin axis; the
  // DUT's other axes keep their own orientation. A horizontal axis with a
  // heading turns with the table (the DUTs are on it): its heading is at
  // table position 0.
  const bool radial = axis.table_axis && cfg.table_present &&
                      cfg.table_sensitive_axis.value_or("along_table") == "radial";
  const bool turning = !radial && cfg.table_present && heading_deg;
  if (!radial && !turning) return axis_dph;
  auto means = db.mean_table_over_windows(soak.run_id, soak.windows);
  if (!means) {
    return Error::Transient(fmt::format("{}: {}", soak_name(soak, axis), means.error().message));
  }
  if (radial) {
    if (!means->position_deg) {
      return Error::Permanent(fmt::format(
          "{}: no table position recorded over the soak: the Earth-rate projection of a radial "
          "sensitive axis is unknown",
          soak_name(soak, axis)));
    }
    // The axis's own heading when its [[dut]] gives one, else the table's.
    return analysis::earth_rate_projection_dph(
        run->latitude_deg, analysis::SensitiveAxis::kRadial,
        heading_deg.value_or(cfg.table_heading_at_zero_deg.value_or(0.0)), *means->position_deg);
  }
  if (means->n == 0) {
    return Error::Permanent(fmt::format(
        "{}: no table position recorded over the soak: the Earth-rate component of a horizontal "
        "axis turning with the table (heading {:g}° at position 0) is unknown",
        soak_name(soak, axis), *heading_deg));
  }
  // The mean of Ω cos φ cos(h + p) over the table's positions: the circular
  // mean p̄ weighted by the resultant length (1 at rest; 0 over whole turns).
  const double horizontal_dph = analysis::earth_rate_component_dph(
      run->latitude_deg, analysis::AxisOrientation::kHorizontal, 0.0);
  return horizontal_dph * means->position_resultant *
         std::cos((*heading_deg + means->position_deg.value_or(0.0)) * std::numbers::pi / 180.0);
}

}  // namespace

Result<storage::SegmentStatsRecord> soak_table1(storage::Database& db, const SoakWindow& soak,
                                                const analysis::Table1Options& table1_options) {
  auto axis = first_axis(db, soak.run_id);
  if (!axis) return axis.error();
  return soak_table1(db, soak, table1_options, *axis);
}

Result<storage::SegmentStatsRecord> soak_table1(storage::Database& db, const SoakWindow& soak,
                                                const analysis::Table1Options& table1_options,
                                                const AnalysedAxis& axis,
                                                const analysis::QualityRules& rules) {
  analysis::Table1Options options = table1_options;
  auto earth = soak_earth_rate_dph(db, soak, axis, options.earth_rate_dph);
  if (!earth) return earth.error();
  options.earth_rate_dph = *earth;
  analysis::CoverageCounter counter(sorted_windows(soak.windows));
  double median_hz = 0;
  auto series = soak_series_counted(db, soak, options.bin_s, axis, &counter, &median_hz);
  if (!series) return series.error();
  auto row = analysis::table1_row(*series, options);
  if (!row) {
    return Error::Permanent(fmt::format("{}: {}", soak_name(soak, axis), row.error().message));
  }
  storage::SegmentStatsRecord rec;
  rec.segment_id = soak.segment_id;
  rec.run_id = soak.run_id;
  rec.dut_serial = axis.dut_serial;
  rec.axis = axis.axis;
  rec.segment_index = soak.segment_index;
  rec.setpoint_c = soak.setpoint_c;
  rec.n = static_cast<int64_t>(row->n);
  rec.duration_s = row->duration_s;
  rec.temp_mean_c = row->temp_mean_c;
  rec.bias_mean_dph = row->bias_mean_dph;
  rec.bias_std_dph = row->bias_std_dph;
  rec.bias_std_ma_dph = row->bias_std_ma_dph;
  rec.bias_mean_earth_removed_dph = row->bias_mean_earth_removed_dph;
  rec.bin_s = options.bin_s;
  rec.ma_window = static_cast<int>(options.ma_window);
  rec.earth_rate_dph = options.earth_rate_dph;
  rec.t_from_s = soak.t_from_s;
  rec.t_to_s = soak.t_to_s;
  rec.computed_utc = db.utc_now();
  const analysis::Coverage coverage = counter.result(axis.rate_hz > 0 ? axis.rate_hz : median_hz);
  rec.quality = result_quality(coverage, analysis::coverage_reasons(coverage, rules));
  rec.bias_u = bias_uncertainty_record(row->bias_u);
  rec.bias_u_note = row->bias_u_note;
  return rec;
}

Result<storage::AllanRecord> soak_allan(storage::Database& db, const SoakWindow& soak,
                                        analysis::TauSet taus) {
  auto axis = first_axis(db, soak.run_id);
  if (!axis) return axis.error();
  return soak_allan(db, soak, taus, *axis);
}

Result<storage::AllanRecord> soak_allan(storage::Database& db, const SoakWindow& soak,
                                        analysis::TauSet taus, const AnalysedAxis& axis,
                                        const analysis::QualityRules& rules) {
  if (soak.windows.empty()) {
    return Error::Permanent(fmt::format("{}: no acquisition window", soak_name(soak, axis)));
  }
  // The longest window, streamed: the prefix sums spill to a scratch file
  // past analysis::StreamLimits, so any soak length fits in bounded memory.
  const auto [from_s, to_s] = *std::max_element(
      soak.windows.begin(), soak.windows.end(),
      [](const auto& a, const auto& b) { return a.second - a.first < b.second - b.first; });
  analysis::CoverageCounter counter({{from_s, to_s}});
  auto adev = analysis::allan_deviation(
      counting_first_pass(analysis::prefetched(axis_source(db, soak.run_id, axis, from_s, to_s)),
                          &counter),
      {.taus = taus});
  if (!adev && adev.error().transient) {
    return Error::Transient(fmt::format("{}: {}", soak_name(soak, axis), adev.error().message));
  }
  if (!adev) {
    return Error::Permanent(fmt::format("{} window [{:.1f}, {:.1f}) s: Allan deviation: {}",
                                        soak_name(soak, axis), from_s, to_s, adev.error().message));
  }
  storage::AllanRecord rec;
  rec.run_id = soak.run_id;
  rec.dut_serial = axis.dut_serial;
  rec.axis = axis.axis;
  rec.segment_id = soak.segment_id;
  rec.segment_index = soak.segment_index;
  rec.t_from_s = from_s;
  rec.t_to_s = to_s;
  rec.taus = std::string(analysis::to_string(taus));
  rec.tau0_s = adev->tau0_s;
  rec.n_samples = static_cast<int64_t>(adev->n_samples);
  rec.tau_s = adev->tau_s;
  rec.adev_dph = adev->adev_dph;
  rec.adev_lo_dph = adev->adev_lo_dph;
  rec.edf = adev->edf;
  rec.noise_alpha = adev->noise_alpha;
  rec.adev_hi_dph = adev->adev_hi_dph;
  rec.angle_random_walk_dprh = adev->angle_random_walk_dprh;
  rec.bias_instability_dph = adev->bias_instability_dph;
  rec.bias_instability_tau_s = adev->bias_instability_tau_s;
  rec.rate_random_walk_dphprh = adev->rate_random_walk_dphprh;
  rec.bias_instability_method = adev->bias_instability_method;
  nlohmann::json inputs = {{"run_id", soak.run_id},
                           {"segment", soak.segment_index + 1},
                           {"taus", rec.taus},
                           {"samples", "as recorded"},
                           {"window", {from_s, to_s}},
                           {"windows", windows_json(soak.windows)},
                           {"window_rule", "the longest acquisition window"}};
  if (!axis.dut_serial.empty() || !axis.axis.empty()) {
    inputs["dut_serial"] = axis.dut_serial;
    inputs["axis"] = axis.axis;
  }
  rec.inputs_json = inputs.dump();
  rec.computed_utc = db.utc_now();
  const analysis::Coverage coverage =
      counter.result(axis.rate_hz > 0 ? axis.rate_hz : 1.0 / adev->tau0_s);
  rec.quality = result_quality(coverage, analysis::coverage_reasons(coverage, rules));
  return rec;
}

storage::FitRecord fit_record(const analysis::DriftFit& fit, const std::vector<int64_t>& run_ids,
                              const analysis::DriftFitOptions& options, double bin_s) {
  storage::FitRecord rec;
  rec.run_ids = run_ids;
  rec.model = analysis::to_string(fit.spec);
  rec.form = std::string(analysis::to_string(fit.form));
  rec.n = static_cast<int64_t>(fit.n);
  nlohmann::json coefficients = nlohmann::json::object();
  nlohmann::json errors = nlohmann::json::object();
  for (const auto& [name, value] : fit.coefficients) coefficients[name] = num(value);
  for (const auto& [name, value] : fit.std_errors) errors[name] = num(value);
  rec.coefficients_json = coefficients.dump();
  rec.standard_errors_json = errors.dump();
  rec.residual_std_dph = fit.residual_std_dph;
  rec.r_squared = fit.r_squared;
  nlohmann::json l0 = nlohmann::json::array();
  for (double v : fit.l0_per_series_dph) l0.push_back(num(v));
  rec.inputs_json = nlohmann::json{{"runs", run_ids},
                                   {"model", rec.model},
                                   {"form", rec.form},
                                   {"series", "whole run, every recorded sample"},
                                   {"bin_s", bin_s},
                                   {"derivative_window_s", options.derivative_window_s},
                                   {"l0_window_s", options.l0_window_s},
                                   {"l0_dph", l0},
                                   {"condition_estimate", num(fit.condition_estimate)}}
                        .dump();
  rec.computed_utc = wall_time_utc_iso();
  return rec;
}

storage::ResultQuality fit_quality(const analysis::DriftFit& fit,
                                   std::span<const analysis::AnalysisSeries> series,
                                   std::span<const analysis::Coverage> coverage,
                                   const analysis::QualityRules& rules) {
  analysis::Coverage total;
  bool expected_known = !coverage.empty();
  for (const analysis::Coverage& c : coverage) {
    total.samples += c.samples;
    total.window_s += c.window_s;
    total.expected += c.expected;
    total.longest_gap_s = std::max(total.longest_gap_s, c.longest_gap_s);
    expected_known = expected_known && c.expected > 0;
  }
  if (expected_known) {
    total.fraction = static_cast<double>(total.samples) / total.expected;
  } else {
    total.expected = 0;
  }
  double noise_dph = NAN;
  for (const analysis::AnalysisSeries& s : series) {
    const double n = analysis::series_noise_dph(s.rate_dph);
    if (std::isfinite(n) && !(n <= noise_dph)) noise_dph = n;
  }
  std::vector<std::string> reasons = analysis::coverage_reasons(total, rules);
  for (std::string& r : analysis::residual_reasons(fit.residual_std_dph, noise_dph, rules)) {
    reasons.push_back(std::move(r));
  }
  return result_quality(total, std::move(reasons));
}

namespace {

// "run 7 segment 3 (SN 17-0042 z) Table I: coverage 70.0 % ...": a
// flagged result for the analysis event.
std::string flagged_line(std::string_view what, const storage::ResultQuality& q) {
  return fmt::format("{}: {}", what, fmt::join(q.reasons, "; "));
}

}  // namespace

Result<RunAnalysisSummary> analyse_run(storage::Database& db, int64_t run_id,
                                       const AnalysisSettings& settings) {
  auto soaks = soak_windows(db, run_id);
  if (!soaks) return soaks.error();
  auto axes = analysed_axes(db, run_id);
  RunAnalysisSummary summary;
  const auto problem = [&summary](const Error& e) -> Status {
    if (e.transient) return e;  // a database failure: the caller retries or reports
    summary.problems.push_back(e.message);
    return Status::Ok();
  };
  if (!axes) {
    if (Status st = problem(axes.error()); !st.ok()) return st.error();
    return summary;
  }
  summary.streams = static_cast<int>(axes->size());
  for (const AnalysedAxis& axis : *axes) {
    for (const SoakWindow& soak : *soaks) {
      if (auto row = soak_table1(db, soak, settings.table1, axis, settings.quality)) {
        if (auto st = db.put_segment_stats(*row); !st) return st.error();
        ++summary.table1_rows;
        if (row->quality.flagged()) {
          summary.flagged.push_back(
              flagged_line(fmt::format("{} Table I", soak_name(soak, axis)), row->quality));
        }
      } else if (Status st = problem(row.error()); !st.ok()) {
        return st.error();
      }
      if (auto adev = soak_allan(db, soak, settings.allan_taus, axis, settings.quality)) {
        if (auto id = db.put_allan(*adev); id) {
          ++summary.allan_records;
          if (adev->quality.flagged()) {
            summary.flagged.push_back(flagged_line(
                fmt::format("{} Allan deviation", soak_name(soak, axis)), adev->quality));
          }
        } else if (Status st = problem(id.error()); !st.ok()) {
          return st.error();
        }
      } else if (Status st = problem(adev.error()); !st.ok()) {
        return st.error();
      }
    }
  }
  if (auto sf = analyse_scale_factor(db, run_id, settings)) {
    summary.scale_factor_points = sf->points;
    summary.scale_factor_sequences = sf->sequences;
    for (auto& p : sf->problems) summary.problems.push_back(std::move(p));
    for (auto& f : sf->flagged) summary.flagged.push_back(std::move(f));
  } else if (Status st = problem(sf.error()); !st.ok()) {
    return st.error();
  }
  for (const AnalysedAxis& axis : *axes) {
    RunSeriesCoverage coverage;
    auto series = run_series(db, run_id, settings.table1.bin_s, axis, &coverage);
    if (!series) {
      if (Status st = problem(series.error()); !st.ok()) return st.error();
      continue;
    }
    const std::string who = axis.dut_serial.empty() && axis.axis.empty()
                                ? fmt::format("run {}", run_id)
                                : fmt::format("run {} ({})", run_id, axis.name());
    for (analysis::DriftModelForm form : settings.forms) {
      auto fit = analysis::fit_drift_model(*series, settings.model, form, settings.fit);
      if (!fit) {
        summary.problems.push_back(fmt::format("{}: fit {} ({} form): {}", who,
                                               analysis::to_string(settings.model),
                                               analysis::to_string(form), fit.error().message));
        continue;
      }
      storage::FitRecord rec = fit_record(*fit, {run_id}, settings.fit, settings.table1.bin_s);
      rec.dut_serial = axis.dut_serial;
      rec.axis = axis.axis;
      nlohmann::json inputs = nlohmann::json::parse(rec.inputs_json);
      if (!axis.dut_serial.empty() || !axis.axis.empty()) {
        inputs["dut_serial"] = axis.dut_serial;
        inputs["axis"] = axis.axis;
      }
      inputs["series"] = "whole run at rest, every recorded sample";
      inputs["excluded_not_at_rest"] = windows_json(coverage.excluded);
      rec.inputs_json = inputs.dump();
      rec.quality = fit_quality(*fit, std::span(&*series, 1), std::span(&coverage.coverage, 1),
                                settings.quality);
      auto id = db.add_fit(rec);
      if (!id) return id.error();
      summary.fit_ids.push_back(*id);
      if (rec.quality.flagged()) {
        summary.flagged.push_back(flagged_line(
            fmt::format("{} fit {} ({} form, #{})", who, rec.model, rec.form, *id), rec.quality));
      }
    }
  }
  return summary;
}

}  // namespace gyrotherm::calibration
