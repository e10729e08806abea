#include "gyrotherm/daemon/run_analysis.h"

#include <fmt/format.h>
#include <sqlite3.h>
#include <toml++/toml.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "gyrotherm/analysis/scale_factor.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/daemon/config.h"
#include "gyrotherm/daemon/scale_factor_run.h"

namespace gyrotherm::daemon {
namespace {

// Station seconds of samples read at a time for a whole-run series: 600 s
// of a 1 kHz gyro is 6e5 samples, ~25 MB.
constexpr double kRunChunkS = 600.0;
// After a rate step the table decelerates (500 °/s at 100 °/s²: 5 s): the
// drift fit leaves this much after each spinning step out too.
constexpr double kSpinDownMarginS = 10.0;

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

// First and last gyro sample time of a run; nullopt when it has none.
Result<std::optional<std::pair<double, double>>> gyro_span(storage::Database& db, int64_t run_id) {
  sqlite3_stmt* stmt = nullptr;
  // The run's first DUT's primary axis, from its chunks (schema v9,
  // docs/storage.md): first sample and the end of the last chunk.
  const char* sql =
      "SELECT min(k.t0_s), max(k.t0_s + (k.n - 1) * k.period_s) FROM sample_chunks k "
      "WHERE k.channel_id = (SELECT c.id FROM channels c JOIN run_duts r ON r.run_id = c.run_id "
      "AND r.dut_id = c.dut_id WHERE c.run_id = ?1 AND c.kind = 'rate' AND c.axis = "
      "r.primary_axis ORDER BY r.position LIMIT 1)";
  if (sqlite3_prepare_v2(db.handle(), sql, -1, &stmt, nullptr) != SQLITE_OK) {
    return Error::Transient(fmt::format("{}: reading the sample span of run {}: {}", db.path(),
                                        run_id, sqlite3_errmsg(db.handle())));
  }
  sqlite3_bind_int64(stmt, 1, run_id);
  std::optional<std::pair<double, double>> span;
  const int rc = sqlite3_step(stmt);
  if (rc == SQLITE_ROW && sqlite3_column_type(stmt, 0) != SQLITE_NULL) {
    span.emplace(sqlite3_column_double(stmt, 0), sqlite3_column_double(stmt, 1));
  }
  const std::string message = sqlite3_errmsg(db.handle());
  sqlite3_finalize(stmt);
  if (rc != SQLITE_ROW && rc != SQLITE_DONE) {
    return Error::Transient(
        fmt::format("{}: reading the sample span of run {}: {}", db.path(), run_id, message));
  }
  return span;
}

std::string soak_name(const SoakWindow& soak) {
  return fmt::format("run {} segment {}", soak.run_id, soak.segment_index + 1);
}

}  // namespace

AnalysisSettings analysis_settings(const StationConfig& config) {
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
  return s;
}

RunConfig read_run_config(const std::string& text) {
  using json = nlohmann::json;
  RunConfig c;
  if (text.empty()) return c;
  auto number = [](auto node) -> std::optional<double> {
    if (auto v = node.template value<double>()) return *v;
    return std::nullopt;
  };
  if (text.find_first_not_of(" \t\r\n") != std::string::npos &&
      text[text.find_first_not_of(" \t\r\n")] == '{') {
    const json j = json::parse(text, nullptr, false);
    if (j.is_discarded() || !j.is_object()) return c;
    auto get_num = [](const json& o, const char* k) -> std::optional<double> {
      if (o.is_object() && o.contains(k) && o[k].is_number()) return o[k].get<double>();
      return std::nullopt;
    };
    if (j.contains("analysis")) {
      const json& a = j["analysis"];
      c.bin_s = get_num(a, "bin_s");
      c.l0_window_s = get_num(a, "l0_window_s");
      c.derivative_window_s = get_num(a, "derivative_window_s");
      if (auto w = get_num(a, "ma_window")) c.ma_window = static_cast<int>(*w);
      if (auto w = get_num(a, "compare_smooth_points")) {
        c.compare_smooth_points = static_cast<int>(*w);
      }
      if (a.is_object() && a.contains("model") && a["model"].is_string()) {
        c.model = a["model"].get<std::string>();
      }
      if (a.is_object() && a.contains("allan_taus") && a["allan_taus"].is_string()) {
        c.allan_taus = a["allan_taus"].get<std::string>();
      }
    }
    if (j.contains("station") && j["station"].is_object() && j["station"].contains("name") &&
        j["station"]["name"].is_string()) {
      c.station_name = j["station"]["name"].get<std::string>();
    }
    if (j.contains("table") && j["table"].is_object()) {
      const json& t = j["table"];
      c.table_present = true;
      if (t.contains("sensitive_axis") && t["sensitive_axis"].is_string()) {
        c.table_sensitive_axis = t["sensitive_axis"].get<std::string>();
      }
      c.table_heading_at_zero_deg = get_num(t, "heading_at_zero_deg");
    }
    return c;
  }
  try {
    const toml::table t = toml::parse(text);
    c.bin_s = number(t["analysis"]["bin_s"]);
    c.l0_window_s = number(t["analysis"]["l0_window_s"]);
    c.derivative_window_s = number(t["analysis"]["derivative_window_s"]);
    if (auto w = t["analysis"]["ma_window"].value<int64_t>()) c.ma_window = static_cast<int>(*w);
    if (auto w = t["analysis"]["compare_smooth_points"].value<int64_t>()) {
      c.compare_smooth_points = static_cast<int>(*w);
    }
    if (auto m = t["analysis"]["model"].value<std::string>()) c.model = *m;
    if (auto m = t["analysis"]["allan_taus"].value<std::string>()) c.allan_taus = *m;
    if (auto n = t["station"]["name"].value<std::string>()) c.station_name = *n;
    if (t["table"].is_table()) {
      c.table_present = true;
      if (auto a = t["table"]["sensitive_axis"].value<std::string>()) c.table_sensitive_axis = *a;
      c.table_heading_at_zero_deg = number(t["table"]["heading_at_zero_deg"]);
    }
  } catch (const toml::parse_error&) {
  }
  return c;
}

RunConfig read_run_config(const storage::RunRecord& run) {
  return read_run_config(run.config_json.empty() ? run.config_toml : run.config_json);
}

namespace {

std::string_view name_of(drivers::RegisterFunction f) {
  return f == drivers::RegisterFunction::kInput ? "input" : "holding";
}
std::string_view name_of(drivers::RegisterType t) {
  switch (t) {
    case drivers::RegisterType::kInt16:
      return "int16";
    case drivers::RegisterType::kUint16:
      return "uint16";
    case drivers::RegisterType::kFloat32:
      break;
  }
  return "float32";
}
std::string_view name_of(drivers::WordOrder w) {
  return w == drivers::WordOrder::kHighFirst ? "high-first" : "low-first";
}
std::string_view name_of(drivers::Parity p) {
  switch (p) {
    case drivers::Parity::kEven:
      return "even";
    case drivers::Parity::kOdd:
      return "odd";
    case drivers::Parity::kNone:
      break;
  }
  return "none";
}

nlohmann::json register_json(const drivers::RegisterSpec& r) {
  return {{"address", r.address},
          {"function", name_of(r.function)},
          {"type", name_of(r.type)},
          {"word_order", name_of(r.word_order)},
          {"scale", r.scale}};
}

nlohmann::json endpoint_json(const drivers::ModbusEndpoint& e) {
  nlohmann::json j = {{"transport", e.transport},
                      {"unit_id", e.unit_id},
                      {"response_timeout_s", e.response_timeout_s}};
  if (e.transport == "rtu") {
    j["device"] = e.device;
    j["baud"] = e.baud;
    j["parity"] = std::string(1, e.parity);
    j["data_bits"] = e.data_bits;
    j["stop_bits"] = e.stop_bits;
  } else {
    j["host"] = e.host;
    j["port"] = e.port;
  }
  return j;
}

nlohmann::json redacted(const std::vector<std::string>& tokens) {
  return nlohmann::json(std::vector<std::string>(tokens.size(), "<redacted>"));
}

}  // namespace

nlohmann::json run_config_json(const StationConfig& config) {
  using json = nlohmann::json;
  const StationSection& st = config.station;
  json chamber = endpoint_json(config.chamber.endpoint);
  chamber["profile"] = config.chamber.profile;
  chamber["silent_timeout_s"] = config.chamber.silent_timeout_s;
  const drivers::ChamberMap& map = config.chamber.map;
  json registers = {{"setpoint", register_json(map.setpoint)},
                    {"process_value", register_json(map.process_value)}};
  for (const auto& [key, reg] :
       {std::pair{"ramp_rate", &map.ramp_rate}, std::pair{"ramp_action", &map.ramp_action},
        std::pair{"ramp_scale", &map.ramp_scale}}) {
    if (*reg) registers[key] = register_json(**reg);
  }
  chamber["registers"] = std::move(registers);
  if (map.alarm) {
    json alarm = register_json(map.alarm->reg);
    const bool ok_values = map.alarm->mode == drivers::ChamberAlarm::Mode::kOkValues;
    alarm[ok_values ? "ok_values" : "alarm_values"] = map.alarm->values;
    chamber["alarm"] = std::move(alarm);
  }
  if (map.units) {
    json units = register_json(map.units->reg);
    units["celsius_value"] = map.units->celsius;
    units["fahrenheit_value"] = map.units->fahrenheit;
    chamber["units"] = std::move(units);
  }
  json probes = endpoint_json(config.probes.endpoint);
  probes["profile"] = config.probes.profile;
  probes["channels"] = {{"top", config.probes.top_channel}, {"side", config.probes.side_channel}};
  probes["registers"] = {{"top", register_json(config.probes.top)},
                         {"side", register_json(config.probes.side)}};
  probes["silent_timeout_s"] = config.probes.silent_timeout_s;
  const GyroSection& g = config.gyro;
  static constexpr const char* kAxes[] = {"x", "y", "z"};
  json interlocks = {{"limit_margin_c", config.interlocks.limit_margin_c},
                     {"probe_disagreement_c", config.interlocks.probe_disagreement_c},
                     {"hysteresis_c", config.interlocks.hysteresis_c}};
  for (int k = 0; k < schedules::kInterlockKindCount; ++k) {
    const auto kind = static_cast<schedules::InterlockKind>(k);
    interlocks[fmt::format("{}_grace_min", schedules::to_string(kind))] =
        config.interlocks.grace_for(kind) / 60.0;
  }
  json table = nullptr;
  if (const auto& t = config.table) {
    const drivers::TableConnection& c = t->connection;
    table = {{"profile", c.profile},
             {"host", c.host},
             {"port", c.port},
             {"reply_header", c.reply_header},
             {"device", c.device},
             {"baud", c.baud},
             {"axis", c.axis},
             {"timeout_s", c.timeout_s},
             {"max_rate_dps", t->max_rate_dps},
             {"max_accel_dps2", t->max_accel_dps2},
             {"at_rate_tolerance_dps", t->at_rate_tolerance_dps},
             {"at_rate_tolerance_ppm", t->at_rate_tolerance_ppm},
             {"at_rate_hold_s", t->at_rate_hold_s},
             {"spin_up_timeout_s", t->spin_up_timeout_s},
             {"rest_rate_dps", t->rest_rate_dps},
             {"silent_timeout_s", t->silent_timeout_s},
             {"sensitive_axis", t->sensitive_axis},
             {"heading_at_zero_deg", t->heading_at_zero_deg}};
  }
  const ApiSection& api = config.api;
  return json{
      {"source_path", config.source_path},
      {"station",
       {{"name", st.name},
        {"latitude_deg", st.latitude_deg},
        {"orientation", analysis::to_string(st.orientation)},
        {"min_temp_c", st.min_temp_c},
        {"max_temp_c", st.max_temp_c},
        {"max_ramp_c_per_min", st.max_ramp_c_per_min},
        {"safe_setpoint_c", st.safe_setpoint_c}}},
      {"chamber", std::move(chamber)},
      {"probes", std::move(probes)},
      {"table", std::move(table)},
      {"gyro",
       {{"device", g.serial.device},
        {"baud", g.serial.baud},
        {"parity", name_of(g.serial.parity)},
        {"protocol", g.protocol},
        {"unit", g.format.unit == drivers::AngleUnit::kDeg ? "deg" : "rad"},
        {"output", g.format.kind == drivers::OutputKind::kDeltaAngle ? "delta" : "rate"},
        {"axis", g.format.axis >= 0 && g.format.axis < 3 ? kAxes[g.format.axis] : "?"},
        {"rate_hz", g.format.rate_hz},
        {"silent_timeout_s", g.silent_timeout_s}}},
      {"storage",
       {{"db", config.storage.db_path}, {"commit_interval_s", config.storage.commit_interval_s}}},
      {"api",
       {{"bind", api.bind},
        {"port", api.port},
        {"tokens", redacted(api.tokens)},
        {"read_tokens", redacted(api.read_tokens)},
        {"read_access", api.read_access},
        {"max_auth_failures", api.max_auth_failures},
        {"read_timeout_s", api.read_timeout_s},
        {"max_connections", api.max_connections},
        {"max_header_bytes", api.max_header_bytes},
        {"max_body_bytes", api.max_body_bytes},
        {"max_stream_clients", api.max_stream_clients},
        {"stream_queue_bytes", api.stream_queue_bytes},
        {"web_root", api.web_root}}},
      {"export",
       {{"nightly", config.export_.nightly},
        {"directory", config.export_.directory},
        {"local_time", config.export_.local_time},
        {"time_zone", config.export_.time_zone}}},
      {"analysis",
       {{"bin_s", config.analysis.bin_s},
        {"ma_window", config.analysis.ma_window},
        {"l0_window_s", config.analysis.l0_window_s},
        {"model", config.analysis.model},
        {"derivative_window_s", config.analysis.derivative_window_s},
        {"compare_smooth_points", config.analysis.compare_smooth_points},
        {"allan_taus", config.analysis.allan_taus}}},
      {"control",
       {{"tick_s", config.control.tick_s},
        {"min_tick_wall_s", config.control.min_tick_wall_s},
        {"min_silent_wall_s", config.control.min_silent_wall_s}}},
      {"interlocks", std::move(interlocks)},
      {"simulator", {{"endpoints_file", config.simulator.endpoints_file}}},
  };
}

Result<AnalysisSettings> analysis_settings_of_run(const storage::RunRecord& run) {
  const RunConfig cfg = read_run_config(run);
  AnalysisSettings s;
  if (cfg.bin_s) s.table1.bin_s = *cfg.bin_s;
  if (cfg.ma_window) s.table1.ma_window = static_cast<std::size_t>(*cfg.ma_window);
  if (cfg.l0_window_s) s.fit.l0_window_s = *cfg.l0_window_s;
  if (cfg.derivative_window_s) s.fit.derivative_window_s = *cfg.derivative_window_s;
  if (cfg.compare_smooth_points && *cfg.compare_smooth_points >= 1) {
    s.compare_smooth_points = static_cast<std::size_t>(*cfg.compare_smooth_points);
  }
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
  if (!s.table1.IsValid(&why) || !s.fit.IsValid(&why)) {
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

Result<analysis::AnalysisSeries> soak_series(storage::Database& db, const SoakWindow& soak,
                                             double bin_s) {
  const std::string where = soak_name(soak);
  analysis::AnalysisSeries joined;
  joined.bin_s = bin_s;
  for (const auto& [from_s, to_s] : soak.windows) {
    auto gyro = db.gyro_samples(soak.run_id, from_s, to_s);
    if (!gyro) return Error::Transient(fmt::format("{}: {}", where, gyro.error().message));
    if (gyro->empty() && soak.windows.size() > 1) continue;  // a window shorter than a sample
    auto temps = shell_readings(db, soak.run_id, from_s, to_s);
    if (!temps) return Error::Transient(fmt::format("{}: {}", where, temps.error().message));
    auto part = analysis::make_analysis_series(*gyro, *temps, bin_s);
    if (!part) {
      return Error::Permanent(fmt::format("{} window [{:.1f}, {:.1f}) s: {}", where, from_s, to_s,
                                          part.error().message));
    }
    append(joined, *part);
  }
  return joined;
}

Result<RecordedSamples> soak_recorded_samples(storage::Database& db, const SoakWindow& soak) {
  if (soak.windows.empty()) {
    return Error::Permanent(fmt::format("{}: no acquisition window", soak_name(soak)));
  }
  const auto longest = std::max_element(
      soak.windows.begin(), soak.windows.end(),
      [](const auto& a, const auto& b) { return a.second - a.first < b.second - b.first; });
  auto gyro = db.gyro_samples(soak.run_id, longest->first, longest->second);
  if (!gyro) return Error::Transient(fmt::format("{}: {}", soak_name(soak), gyro.error().message));
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
// The stretches of a run when the table spun (steps demanding a rate, and a
// spin-down margin after each): the drift model is of the gyro at rest.
Result<std::vector<std::pair<double, double>>> spinning_spans(storage::Database& db, int64_t run_id,
                                                              double last_s) {
  auto segments = db.segments(run_id);
  if (!segments) return segments.error();
  std::vector<std::pair<double, double>> out;
  for (const auto& seg : *segments) {
    if (seg.table_mode != "rate") continue;
    out.emplace_back(seg.t_start_s, seg.t_end_s.value_or(last_s) + kSpinDownMarginS);
  }
  return out;
}
}  // namespace

Result<analysis::AnalysisSeries> run_series(storage::Database& db, int64_t run_id, double bin_s) {
  auto span = gyro_span(db, run_id);
  if (!span) return span.error();
  if (!*span) return Error::Permanent(fmt::format("run {}: no gyro samples recorded", run_id));
  const auto [first_s, last_s] = **span;
  auto spinning = spinning_spans(db, run_id, last_s);
  if (!spinning) return spinning.error();
  analysis::AnalysisSeries joined;
  joined.bin_s = bin_s;
  // Chunks start on the run's first sample so the bins of consecutive chunks
  // line up with the bins of one pass over the whole run.
  const double chunk_s = std::max(kRunChunkS, std::ceil(kRunChunkS / bin_s) * bin_s);
  for (double from_s = first_s; from_s <= last_s; from_s += chunk_s) {
    const double to_s =
        from_s + chunk_s > last_s ? std::nextafter(last_s, INFINITY) : from_s + chunk_s;
    auto gyro = db.gyro_samples(run_id, from_s, to_s);
    if (!gyro) return gyro.error();
    std::erase_if(*gyro, [&](const GyroSample& g) {
      return std::any_of(spinning->begin(), spinning->end(),
                         [&](const auto& w) { return g.t_s >= w.first && g.t_s < w.second; });
    });
    if (gyro->empty()) continue;
    auto temps = shell_readings(db, run_id, from_s, to_s);
    if (!temps) return temps.error();
    if (temps->empty()) continue;  // no temperature in this stretch: nothing to fit it with
    auto part = analysis::make_analysis_series(*gyro, *temps, bin_s);
    if (!part) {
      return Error::Permanent(
          fmt::format("run {} [{:.1f}, {:.1f}) s: {}", run_id, from_s, to_s, part.error().message));
    }
    append(joined, *part);
  }
  if (joined.t_s.empty()) {
    return Error::Permanent(
        fmt::format("run {}: no stretch of gyro samples with temperatures recorded", run_id));
  }
  return joined;
}

Result<double> soak_earth_rate_dph(storage::Database& db, const SoakWindow& soak,
                                   double default_dph) {
  auto run = db.run(soak.run_id);
  if (!run) return run.error();
  const RunConfig cfg = read_run_config(*run);
  if (!cfg.table_present || cfg.table_sensitive_axis.value_or("along_table") != "radial") {
    return default_dph;
  }
  auto means = db.mean_table_over_windows(soak.run_id, soak.windows);
  if (!means)
    return Error::Transient(fmt::format("{}: {}", soak_name(soak), means.error().message));
  if (!means->position_deg) {
    return Error::Permanent(fmt::format(
        "{}: no table position recorded over the soak: the Earth-rate projection of a radial "
        "sensitive axis is unknown",
        soak_name(soak)));
  }
  return analysis::earth_rate_projection_dph(run->latitude_deg, analysis::SensitiveAxis::kRadial,
                                             cfg.table_heading_at_zero_deg.value_or(0.0),
                                             *means->position_deg);
}

Result<storage::SegmentStatsRecord> soak_table1(storage::Database& db, const SoakWindow& soak,
                                                const analysis::Table1Options& table1_options) {
  analysis::Table1Options options = table1_options;
  auto earth = soak_earth_rate_dph(db, soak, options.earth_rate_dph);
  if (!earth) return earth.error();
  options.earth_rate_dph = *earth;
  auto series = soak_series(db, soak, options.bin_s);
  if (!series) return series.error();
  auto row = analysis::table1_row(*series, options);
  if (!row) return Error::Permanent(fmt::format("{}: {}", soak_name(soak), row.error().message));
  storage::SegmentStatsRecord rec;
  rec.segment_id = soak.segment_id;
  rec.run_id = soak.run_id;
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
  return rec;
}

Result<storage::AllanRecord> soak_allan(storage::Database& db, const SoakWindow& soak,
                                        analysis::TauSet taus) {
  auto samples = soak_recorded_samples(db, soak);
  if (!samples) return samples.error();
  auto adev = analysis::allan_deviation(samples->t_s, samples->rate_dph, {.taus = taus});
  if (!adev) {
    return Error::Permanent(fmt::format("{} window [{:.1f}, {:.1f}) s: Allan deviation: {}",
                                        soak_name(soak), samples->t_from_s, samples->t_to_s,
                                        adev.error().message));
  }
  storage::AllanRecord rec;
  rec.run_id = soak.run_id;
  rec.segment_id = soak.segment_id;
  rec.segment_index = soak.segment_index;
  rec.t_from_s = samples->t_from_s;
  rec.t_to_s = samples->t_to_s;
  rec.taus = std::string(analysis::to_string(taus));
  rec.tau0_s = adev->tau0_s;
  rec.n_samples = static_cast<int64_t>(adev->n_samples);
  rec.tau_s = adev->tau_s;
  rec.adev_dph = adev->adev_dph;
  rec.adev_lo_dph = adev->adev_lo_dph;
  rec.adev_hi_dph = adev->adev_hi_dph;
  rec.angle_random_walk_dprh = adev->angle_random_walk_dprh;
  rec.bias_instability_dph = adev->bias_instability_dph;
  rec.bias_instability_tau_s = adev->bias_instability_tau_s;
  rec.rate_random_walk_dphprh = adev->rate_random_walk_dphprh;
  rec.bias_instability_method = adev->bias_instability_method;
  rec.inputs_json = nlohmann::json{{"run_id", soak.run_id},
                                   {"segment", soak.segment_index + 1},
                                   {"taus", rec.taus},
                                   {"samples", "as recorded"},
                                   {"window", {samples->t_from_s, samples->t_to_s}},
                                   {"windows", windows_json(soak.windows)},
                                   {"window_rule", "the longest acquisition window"}}
                        .dump();
  rec.computed_utc = db.utc_now();
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

Result<RunAnalysisSummary> analyse_run(storage::Database& db, int64_t run_id,
                                       const AnalysisSettings& settings) {
  auto soaks = soak_windows(db, run_id);
  if (!soaks) return soaks.error();
  RunAnalysisSummary summary;
  const auto problem = [&summary](const Error& e) -> Status {
    if (e.transient) return e;  // a database failure: the caller retries or reports
    summary.problems.push_back(e.message);
    return Status::Ok();
  };
  for (const SoakWindow& soak : *soaks) {
    if (auto row = soak_table1(db, soak, settings.table1)) {
      if (auto st = db.put_segment_stats(*row); !st) return st.error();
      ++summary.table1_rows;
    } else if (Status st = problem(row.error()); !st.ok()) {
      return st.error();
    }
    if (auto adev = soak_allan(db, soak, settings.allan_taus)) {
      if (auto id = db.put_allan(*adev); id) {
        ++summary.allan_records;
      } else if (Status st = problem(id.error()); !st.ok()) {
        return st.error();
      }
    } else if (Status st = problem(adev.error()); !st.ok()) {
      return st.error();
    }
  }
  if (auto sf = analyse_scale_factor(db, run_id)) {
    summary.scale_factor_points = sf->points;
    summary.scale_factor_sequences = sf->sequences;
    for (auto& p : sf->problems) summary.problems.push_back(std::move(p));
  } else if (Status st = problem(sf.error()); !st.ok()) {
    return st.error();
  }
  auto series = run_series(db, run_id, settings.table1.bin_s);
  if (!series) {
    if (Status st = problem(series.error()); !st.ok()) return st.error();
    return summary;
  }
  for (analysis::DriftModelForm form : settings.forms) {
    auto fit = analysis::fit_drift_model(*series, settings.model, form, settings.fit);
    if (!fit) {
      summary.problems.push_back(fmt::format("run {}: fit {} ({} form): {}", run_id,
                                             analysis::to_string(settings.model),
                                             analysis::to_string(form), fit.error().message));
      continue;
    }
    auto id = db.add_fit(fit_record(*fit, {run_id}, settings.fit, settings.table1.bin_s));
    if (!id) return id.error();
    summary.fit_ids.push_back(*id);
  }
  return summary;
}

}  // namespace gyrotherm::daemon
