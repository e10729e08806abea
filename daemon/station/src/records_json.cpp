// JSON forms of the stored records, as docs/api.md describes them.
#include <fmt/format.h>

#include <cmath>
#include <map>

#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/station/control.h"

namespace gyrotherm::station {
namespace {

nlohmann::json opt(const std::optional<double>& v) {
  return v && std::isfinite(*v) ? nlohmann::json(*v) : nlohmann::json(nullptr);
}
nlohmann::json opt(const std::optional<int64_t>& v) {
  return v ? nlohmann::json(*v) : nlohmann::json(nullptr);
}
nlohmann::json num(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}
nlohmann::json text_or_null(const std::string& s) {
  return s.empty() ? nlohmann::json(nullptr) : nlohmann::json(s);
}
nlohmann::json numbers(const std::vector<double>& v) {
  nlohmann::json a = nlohmann::json::array();
  for (double x : v) a.push_back(num(x));
  return a;
}
// A stored JSON text as JSON; an object when it does not parse (an old or
// hand-edited row must not break the route).
nlohmann::json stored_json(const std::string& text) {
  auto j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  return j.is_discarded() ? nlohmann::json::object() : j;
}

// A result's quality (schema v11; docs/api.md "Result quality").
nlohmann::json quality_json(const storage::ResultQuality& q) {
  const bool assessed = q.verdict != "unassessed";
  return {{"verdict", q.verdict},
          {"reasons", q.reasons},
          {"coverage", opt(q.coverage)},
          {"coverage_samples", assessed ? nlohmann::json(q.samples) : nlohmann::json(nullptr)},
          {"coverage_expected", q.expected > 0 ? num(q.expected) : nlohmann::json(nullptr)},
          {"longest_gap_s", opt(q.longest_gap_s)}};
}

}  // namespace

nlohmann::json to_json(const storage::QueueEntry& e, int step_count) {
  return {{"id", e.id},
          {"position", e.position},
          {"schedule_name", e.schedule_name},
          {"source", e.source_path},
          {"steps", step_count},
          {"ignore_failures", e.ignore_failures},
          {"added_utc", e.added_utc},
          {"state", e.state},
          {"run_id", opt(e.run_id)},
          {"metadata", to_json(e.metadata)}};
}

nlohmann::json to_json(const storage::RunRecord& r) {
  return {{"id", r.id},
          {"schedule_name", r.schedule_name},
          {"state", r.state},
          {"started_utc", r.started_utc},
          {"ended_utc", text_or_null(r.ended_utc)},
          {"queue_id", opt(r.queue_id)},
          {"time_scale", num(r.time_scale)},
          {"metadata", to_json(r.metadata)}};
}

nlohmann::json to_json(const storage::SegmentRecord& s) {
  nlohmann::json windows = nlohmann::json::array();
  for (const auto& [from_s, to_s] : s.windows) windows.push_back({from_s, to_s});
  return {{"index", s.index},
          {"kind", s.kind},
          {"label", s.label},
          {"setpoint_c", num(s.setpoint_c)},
          {"ramp_rate_c_per_min", num(s.ramp_rate_c_per_min)},
          {"t_start_s", num(s.t_start_s)},
          {"t_settled_s", opt(s.t_settled_s)},
          {"t_acquire_start_s", opt(s.t_acquire_start_s)},
          {"t_acquire_end_s", opt(s.t_acquire_end_s)},
          {"t_end_s", opt(s.t_end_s)},
          {"paused_s", num(s.paused_s)},
          {"state", s.state},
          {"windows", windows},
          {"table",
           {{"mode", s.table_mode},
            {"rate_dps", opt(s.table_rate_dps)},
            {"position_deg", opt(s.table_position_deg)},
            {"mean_rate_dps", opt(s.table_mean_rate_dps)},
            {"mean_position_deg", opt(s.table_mean_position_deg)}}},
          {"turns", s.turns},
          {"dwell_s", num(s.dwell_s)},
          {"sf_sequence", s.sf_sequence},
          {"sf_repetition", s.sf_repetition},
          {"acquire_stop", s.acquire_stop}};
}

nlohmann::json to_json(const storage::ScaleFactorPointRecord& p) {
  return {{"dut_serial", p.dut_serial},
          {"axis", p.axis},
          {"segment_id", p.segment_id},
          {"sf_sequence", p.sf_sequence},
          {"repetition", p.repetition},
          {"rate_dps", num(p.rate_dps)},
          {"measured_rate_dps", num(p.measured_rate_dps)},
          {"output_dps", num(p.output_dps)},
          {"n", p.n},
          {"temperature_c", num(p.temperature_c)},
          {"duration_s", num(p.duration_s)},
          {"turns", num(p.turns)},
          {"guard_s", num(p.guard_s)},
          {"quality", quality_json(p.quality)}};
}

nlohmann::json to_json(const storage::ScaleFactorFitRecord& f) {
  return {{"dut_serial", f.dut_serial},
          {"axis", f.axis},
          {"sf_sequence", f.sf_sequence},
          {"temperature_c", num(f.temperature_c)},
          {"k", num(f.k)},
          {"k_se", num(f.k_se)},
          {"bias_dps", num(f.bias_dps)},
          {"bias_dph", num(f.bias_dps * 3600.0)},
          {"nonlinearity_ppm", num(f.nonlinearity_ppm)},
          {"nonlinearity_fs_ppm", num(f.nonlinearity_fs_ppm)},
          {"asymmetry_ppm", opt(f.asymmetry_ppm)},
          {"repeatability_ppm", opt(f.repeatability_ppm)},
          {"n_points", f.n_points},
          {"created_utc", f.created_utc},
          {"guard_s", num(f.guard_s)},
          {"quality", quality_json(f.quality)}};
}

nlohmann::json to_json(const storage::ScaleFactorTemperatureFitRecord& t) {
  auto array = [](const std::string& text) {
    auto j = nlohmann::json::parse(text.empty() ? "[]" : text, nullptr, false);
    return j.is_array() ? j : nlohmann::json::array();
  };
  return {{"dut_serial", t.dut_serial},
          {"axis", t.axis},
          {"order", t.order},
          {"t_centre_c", num(t.t_centre_c)},
          {"k_coefficients", array(t.k_coeffs_json)},
          {"bias_coefficients_dps", array(t.bias_coeffs_json)},
          {"k_ppm_per_c", num(t.k_ppm_per_c)},
          {"bias_dph_per_c", num(t.bias_dph_per_c)},
          {"created_utc", t.created_utc}};
}

nlohmann::json to_json(const storage::EventRecord& e) {
  return {{"id", e.id},
          {"t_s", num(e.t_s)},
          {"wall_utc", e.wall_utc},
          {"kind", e.kind},
          {"from_state", text_or_null(e.from_state)},
          {"to_state", text_or_null(e.to_state)},
          {"message", e.message}};
}

nlohmann::json to_json(const storage::SegmentStatsRecord& s) {
  return {{"segment_id", s.segment_id},
          {"run_id", s.run_id},
          {"dut_serial", s.dut_serial},
          {"axis", s.axis},
          {"segment_index", s.segment_index},
          {"setpoint_c", num(s.setpoint_c)},
          {"n", s.n},
          {"duration_s", num(s.duration_s)},
          {"temp_mean_c", num(s.temp_mean_c)},
          {"bias_mean_dph", num(s.bias_mean_dph)},
          {"bias_std_dph", num(s.bias_std_dph)},
          {"bias_std_ma_dph", num(s.bias_std_ma_dph)},
          {"bias_mean_earth_removed_dph", num(s.bias_mean_earth_removed_dph)},
          {"bin_s", num(s.bin_s)},
          {"ma_window", s.ma_window},
          {"earth_rate_dph", num(s.earth_rate_dph)},
          {"t_from_s", num(s.t_from_s)},
          {"t_to_s", num(s.t_to_s)},
          {"computed_utc", s.computed_utc},
          {"quality", quality_json(s.quality)},
          {"bias_u", calibration::mean_uncertainty_json(calibration::mean_uncertainty_of(s))},
          {"bias_u_note", s.bias_u_note}};
}

nlohmann::json to_json(const storage::FitRecord& f) {
  return {{"id", f.id},
          {"dut_serial", f.dut_serial},
          {"axis", f.axis},
          {"run_ids", f.run_ids},
          {"model", f.model},
          {"form", f.form},
          {"n", f.n},
          {"coefficients", stored_json(f.coefficients_json)},
          {"standard_errors", stored_json(f.standard_errors_json)},
          {"residual_std_dph", num(f.residual_std_dph)},
          {"r_squared", num(f.r_squared)},
          {"inputs", stored_json(f.inputs_json)},
          {"computed_utc", f.computed_utc},
          {"quality", quality_json(f.quality)}};
}

nlohmann::json to_json(const storage::ExportRecord& e) {
  return {{"id", e.id},
          {"kind", e.kind},
          {"slot_unix_s", e.slot_unix_s ? num(*e.slot_unix_s) : nlohmann::json(nullptr)},
          {"slot_local", e.slot_local},
          {"state", e.state},
          {"directory", e.directory},
          {"run_ids", e.run_ids},
          {"files", e.files},
          {"started_utc", e.started_utc},
          {"finished_utc",
           e.finished_utc.empty() ? nlohmann::json(nullptr) : nlohmann::json(e.finished_utc)},
          {"message", e.message}};
}

nlohmann::json to_json(const storage::AllanRecord& a) {
  const auto numbers = [](const std::vector<double>& v) {
    nlohmann::json out = nlohmann::json::array();
    for (double x : v) out.push_back(num(x));
    return out;
  };
  const auto optional = [](const std::optional<double>& v) {
    return v ? num(*v) : nlohmann::json(nullptr);
  };
  return {{"id", a.id},
          {"run_id", a.run_id},
          {"dut_serial", a.dut_serial},
          {"axis", a.axis},
          {"segment", a.segment_index + 1},
          {"t_from_s", num(a.t_from_s)},
          {"t_to_s", num(a.t_to_s)},
          {"taus", a.taus},
          {"tau0_s", num(a.tau0_s)},
          {"n_samples", a.n_samples},
          {"tau_s", numbers(a.tau_s)},
          {"adev_dph", numbers(a.adev_dph)},
          {"adev_lo_dph", numbers(a.adev_lo_dph)},
          {"adev_hi_dph", numbers(a.adev_hi_dph)},
          {"angle_random_walk_dprh", optional(a.angle_random_walk_dprh)},
          {"bias_instability_dph", optional(a.bias_instability_dph)},
          {"bias_instability_tau_s", optional(a.bias_instability_tau_s)},
          {"bias_instability_method", a.bias_instability_method},
          {"rate_random_walk_dphprh", optional(a.rate_random_walk_dphprh)},
          {"inputs", stored_json(a.inputs_json)},
          {"computed_utc", a.computed_utc},
          {"quality", quality_json(a.quality)}};
}

namespace {
// The rate table's series; null for a run without a table.
nlohmann::json table_series(const storage::DecimatedSamples::Table& t) {
  if (t.t_s.empty()) return nullptr;
  return {{"t_s", numbers(t.t_s)},
          {"n", t.n},
          {"mean_rate_dps", numbers(t.mean_rate_dps)},
          {"min_rate_dps", numbers(t.min_rate_dps)},
          {"max_rate_dps", numbers(t.max_rate_dps)},
          {"position_deg", numbers(t.position_deg)},
          {"demand_rate_dps", numbers(t.demand_rate_dps)},
          {"demand_mode", t.demand_mode},
          {"mode", t.mode},
          {"interlock", t.interlock}};
}
}  // namespace

nlohmann::json to_json(const storage::DecimatedSamples& d) {
  const auto& g = d.gyro;
  const auto& t = d.temperature;
  return {{"dut", d.dut_serial},
          {"channel", d.channel},
          {"unit", d.unit},
          {"from_s", num(d.from_s)},
          {"to_s", num(d.to_s)},
          {"bucket_s", num(d.bucket_s)},
          {"source", d.from_rollup ? "rollup" : "raw"},
          {"gyro",
           {{"t_s", numbers(g.t_s)},
            {"n", g.n},
            {"mean_dph", numbers(g.mean_dph)},
            {"min_dph", numbers(g.min_dph)},
            {"max_dph", numbers(g.max_dph)}}},
          {"temperature",
           {{"t_s", numbers(t.t_s)},
            {"setpoint_c", numbers(t.setpoint_c)},
            {"chamber_c", numbers(t.chamber_c)},
            {"top_c", numbers(t.top_c)},
            {"side_c", numbers(t.side_c)}}},
          {"table", table_series(d.table)}};
}

// ---------------------------------------------------------------- run metadata and DUTs

nlohmann::json to_json(const storage::RunMetadata& m) {
  return {{"operator", m.operator_name},
          {"comment", m.comment},
          {"tags", m.tags},
          {"duts", m.dut_serials}};
}

nlohmann::json to_json(const storage::RunDutRecord& d) {
  nlohmann::json channels = nlohmann::json::array();
  for (const auto& c : d.channels) {
    channels.push_back({{"name", c.spec.name},
                        {"unit", c.spec.unit},
                        {"kind", std::string(to_string(c.spec.kind))},
                        {"axis", c.spec.axis}});
  }
  return {{"serial", d.dut.serial},
          {"model", d.dut.model},
          {"position", d.position},
          {"primary_axis", d.primary_axis},
          {"axes", d.axes},
          {"rate_hz", d.rate_hz > 0 ? num(d.rate_hz) : nlohmann::json(nullptr)},
          {"channels", std::move(channels)}};
}

nlohmann::json to_json(const storage::DutRecord& d, int64_t run_count) {
  return {{"serial", d.serial},
          {"model", d.model},
          {"first_seen_utc", d.first_seen_utc},
          {"runs", run_count}};
}

nlohmann::json to_json(const storage::DutHistory& h) {
  const auto array_of = [](const auto& records) {
    nlohmann::json out = nlohmann::json::array();
    for (const auto& r : records) out.push_back(to_json(r));
    return out;
  };
  nlohmann::json runs = nlohmann::json::array();
  for (const auto& r : h.runs) {
    nlohmann::json run = to_json(r.run);
    run["dut"] = to_json(r.in_run);
    run["segments"] = array_of(r.segments);
    run["stats"] = array_of(r.stats);
    run["allan"] = array_of(r.allan);
    run["scale_factor"] = array_of(r.scale_factor);
    runs.push_back(std::move(run));
  }
  nlohmann::json out = to_json(h.dut, static_cast<int64_t>(h.runs.size()));
  out["runs"] = std::move(runs);
  out["fits"] = array_of(h.fits);
  return out;
}

Result<nlohmann::json> run_detail_json(storage::Database& db, int64_t run_id) {
  auto run = db.run(run_id);
  if (!run) return run.error();
  auto segments = db.segments(run_id);
  if (!segments) return segments.error();
  auto duts = db.run_duts(run_id);
  if (!duts) return duts.error();
  nlohmann::json j = to_json(*run);
  j["segments"] = nlohmann::json::array();
  for (const auto& s : *segments) j["segments"].push_back(to_json(s));
  j["duts"] = nlohmann::json::array();
  for (const auto& d : *duts) j["duts"].push_back(to_json(d));
  return j;
}

Result<nlohmann::json> duts_json(storage::Database& db) {
  auto duts = db.duts();
  if (!duts) return duts.error();
  auto runs = db.runs();
  if (!runs) return runs.error();
  // Runs per DUT id: one small query per run (run_duts), none per DUT.
  std::map<int64_t, int64_t> run_count;
  for (const auto& r : *runs) {
    auto in_run = db.run_duts(r.id);
    if (!in_run) return in_run.error();
    for (const auto& d : *in_run) ++run_count[d.dut.id];
  }
  nlohmann::json out = nlohmann::json::array();
  for (const auto& d : *duts) {
    const auto it = run_count.find(d.id);
    out.push_back(to_json(d, it == run_count.end() ? 0 : it->second));
  }
  return out;
}

Result<nlohmann::json> dut_history_json(storage::Database& db, const std::string& serial) {
  auto dut = db.dut(serial);
  if (!dut) return dut.error();
  if (!*dut) return Error::Permanent(fmt::format("no DUT with serial '{}'", serial));
  auto history = db.dut_history(serial);
  if (!history) return history.error();
  return to_json(*history);
}

}  // namespace gyrotherm::station
