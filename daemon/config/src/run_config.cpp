#include "gyrotherm/config/run_config.h"

#include <fmt/format.h>
#include <toml++/toml.h>

#include <cstdint>
#include <nlohmann/json.hpp>
#include <utility>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/config/config.h"

namespace gyrotherm::config {

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
      c.rate_guard_s = get_num(a, "rate_guard_s");
      c.rate_flatness_sigma = get_num(a, "rate_flatness_sigma");
      c.rate_flatness_ppm = get_num(a, "rate_flatness_ppm");
    }
    if (j.contains("quality")) {
      const json& q = j["quality"];
      c.min_coverage = get_num(q, "min_coverage");
      c.k_min = get_num(q, "k_min");
      c.k_max = get_num(q, "k_max");
      c.max_nonlinearity_ppm = get_num(q, "max_nonlinearity_ppm");
      c.max_residual_ratio = get_num(q, "max_residual_ratio");
    }
    if (j.contains("gyro")) c.gyro_rate_hz = get_num(j["gyro"], "rate_hz");
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
      c.table_rest_rate_dps = get_num(t, "rest_rate_dps");
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
      c.table_rest_rate_dps = number(t["table"]["rest_rate_dps"]);
    }
    c.gyro_rate_hz = number(t["gyro"]["rate_hz"]);
  } catch (const toml::parse_error&) {
  }
  return c;
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
             {"transport", drivers::table_transport(c)},
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
  json duts = json::array();
  for (const DutSection& dut : config.duts) duts.push_back(dut_config_json(dut));
  // [lab]: where the connection string is (a file's path, a variable's
  // name), never the string itself.
  json lab = nullptr;
  if (const auto& l = config.lab) {
    lab = {{"station_id", l->station_id},
           {"relay", l->relay},
           {"url_file", l->url_file},
           {"url_env", l->url_env},
           {"sslmode", l->sslmode},
           {"sslrootcert", l->sslrootcert},
           {"sslcert", l->sslcert},
           {"sslkey", l->sslkey},
           {"batch_records", l->batch_records},
           {"batch_bytes", l->batch_bytes},
           {"poll_s", l->poll_s},
           {"retry_min_s", l->retry_min_s},
           {"retry_max_s", l->retry_max_s},
           {"connect_timeout_s", l->connect_timeout_s}};
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
        {"allan_taus", config.analysis.allan_taus},
        {"rate_guard_s", config.analysis.rate_guard_s},
        {"rate_flatness_sigma", config.analysis.rate_flatness_sigma},
        {"rate_flatness_ppm", config.analysis.rate_flatness_ppm}}},
      {"quality",
       {{"min_coverage", config.quality.min_coverage},
        {"k_min", config.quality.k_min},
        {"k_max", config.quality.k_max},
        {"max_nonlinearity_ppm", config.quality.max_nonlinearity_ppm},
        {"max_residual_ratio", config.quality.max_residual_ratio}}},
      {"control",
       {{"tick_s", config.control.tick_s},
        {"min_tick_wall_s", config.control.min_tick_wall_s},
        {"min_silent_wall_s", config.control.min_silent_wall_s}}},
      {"interlocks", std::move(interlocks)},
      {"simulator", {{"endpoints_file", config.simulator.endpoints_file}}},
      {"duts", std::move(duts)},
      {"lab", std::move(lab)},
  };
}

nlohmann::json dut_config_json(const DutSection& dut) {
  using json = nlohmann::json;
  const drivers::DutLink& link = dut.link;
  json orientation = json::object();
  for (const auto& [axis, o] : dut.orientation) orientation[axis] = analysis::to_string(o);
  json heading = json::object();
  for (const auto& [axis, h] : dut.heading_deg) heading[axis] = h;
  json ascii = nullptr;
  if (link.protocol == "ascii") {
    const drivers::AsciiLineOptions& a = link.ascii;
    json columns = json::array();
    for (const auto& c : a.columns) {
      columns.push_back(
          {{"name", c.name}, {"kind", to_string(c.kind)}, {"unit", c.unit}, {"axis", c.axis}});
    }
    json valid_bits = json::object();
    for (const auto& [axis, mask] : a.valid_bits) valid_bits[axis] = mask;
    ascii = {{"delimiter", a.delimiter},
             {"columns", std::move(columns)},
             {"seq_column", a.seq_column ? json(*a.seq_column) : json()},
             {"seq_modulo", a.seq_modulo},
             {"checksum", a.checksum},
             {"prefix", a.prefix},
             {"valid_bits", std::move(valid_bits)}};
  }
  json probes = nullptr;
  if (dut.probes) {
    probes = {{"top_channel", dut.probes->top_channel}, {"side_channel", dut.probes->side_channel}};
  }
  return json{{"serial", dut.serial},
              {"model", dut.model},
              {"protocol", link.protocol},
              {"device", link.serial.device},
              {"baud", link.serial.baud},
              {"parity", name_of(link.serial.parity)},
              {"unit", link.unit == drivers::AngleUnit::kDeg ? "deg" : "rad"},
              {"output", link.kind == drivers::OutputKind::kDeltaAngle ? "delta" : "rate"},
              {"rate_hz", link.rate_hz},
              {"axes", dut.axes},
              {"primary_axis", dut.primary_axis},
              {"table_axis", dut.table_axis.empty() ? dut.primary_axis : dut.table_axis},
              {"orientation", std::move(orientation)},
              {"heading_deg", std::move(heading)},
              {"silent_timeout_s", dut.silent_timeout_s},
              {"probes", std::move(probes)},
              {"ascii", std::move(ascii)}};
}

}  // namespace gyrotherm::config
