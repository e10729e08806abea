#include "gyrotherm/daemon/config.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <toml++/toml.h>
#include <unistd.h>

#include <algorithm>
#include <boost/asio/ip/address.hpp>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>

#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/core/files.h"
#include "gyrotherm/core/toml_reader.h"
#include "gyrotherm/daemon/nightly.h"

static_assert(TOML_LIB_MAJOR == 3, "config.h declares toml::table as toml::v3::table");

namespace gyrotherm::daemon {

OptionalTomlTable::OptionalTomlTable() noexcept = default;
OptionalTomlTable::OptionalTomlTable(const OptionalTomlTable& other)
    : table_(other.table_ ? std::make_unique<toml::table>(*other.table_) : nullptr) {}
OptionalTomlTable::OptionalTomlTable(OptionalTomlTable&& other) noexcept = default;
OptionalTomlTable& OptionalTomlTable::operator=(const OptionalTomlTable& other) {
  if (this != &other)
    table_ = other.table_ ? std::make_unique<toml::table>(*other.table_) : nullptr;
  return *this;
}
OptionalTomlTable& OptionalTomlTable::operator=(OptionalTomlTable&& other) noexcept = default;
OptionalTomlTable::~OptionalTomlTable() = default;

OptionalTomlTable& OptionalTomlTable::operator=(toml::table&& table) {
  table_ = std::make_unique<toml::table>(std::move(table));
  return *this;
}

namespace {

// Reads "{ address = N, function = "holding", type = "float32", word_order = "low-first",
// scale = 1.0 }" into a RegisterSpec.
// `base`: the spec the keys change (a profile's); without it, address is
// required. `extra` reads further keys of the table before it is finished.
std::optional<drivers::RegisterSpec> read_register(
    TableReader t, std::optional<drivers::RegisterSpec> base = std::nullopt,
    const std::function<bool(TableReader&)>& extra = {}) {
  drivers::RegisterSpec spec = base.value_or(drivers::RegisterSpec{});
  bool ok = true;
  if (auto a = t.integer("address")) {
    if (*a < 0 || *a > 65535) {
      t.error("address", fmt::format("{} is not a register address (0..65535)", *a));
      ok = false;
    }
    spec.address = static_cast<int>(*a);
  } else if (!base) {
    if (!t.raw().contains("address")) t.error("address", "missing (required integer)");
    ok = false;
  }
  // An enumerated field: parsed by `parse`, stored in `field`.
  auto enumerated = [&](std::string_view key, auto parse, auto& field) {
    if (auto text = t.string(key)) {
      if (auto r = parse(*text)) {
        field = *r;
      } else {
        t.error(key, r.error().message);
        ok = false;
      }
    }
  };
  enumerated("function", drivers::parse_register_function, spec.function);
  enumerated("type", drivers::parse_register_type, spec.type);
  enumerated("word_order", drivers::parse_word_order, spec.word_order);
  if (auto s = t.number("scale")) {
    if (*s == 0.0) {
      t.error("scale", "must not be 0");
      ok = false;
    }
    spec.scale = *s;
  }
  if (extra && !extra(t)) ok = false;
  t.finish();
  if (!ok) return std::nullopt;
  return spec;
}

// [chamber.alarm]: the register (defaults: the profile's alarm) and either
// ok_values or alarm_values, lists of numbers.
std::optional<drivers::ChamberAlarm> read_alarm(TableReader t, const std::string& profile) {
  const auto profile_alarm = drivers::chamber_alarm_default(profile);
  drivers::ChamberAlarm alarm = profile_alarm.value_or(drivers::ChamberAlarm{});
  auto read_values = [&](TableReader& r) {
    const bool has_ok = r.raw().contains("ok_values");
    const bool has_alarm = r.raw().contains("alarm_values");
    if (has_ok && has_alarm) {
      r.error("alarm_values", "give either ok_values or alarm_values, not both");
      r.skip("ok_values");
      r.skip("alarm_values");
      return false;
    }
    if (!has_ok && !has_alarm) return true;
    const char* key = has_ok ? "ok_values" : "alarm_values";
    const toml::array* list = r.array(key);
    if (!list) return false;  // the reader reported the wrong type
    std::vector<double> values;
    for (std::size_t i = 0; i < list->size(); ++i) {
      auto v = list->get(i)->value<double>();
      if (!v || !std::isfinite(*v)) {
        r.error(key, fmt::format("entry {} is not a number", i + 1));
        return false;
      }
      values.push_back(*v);
    }
    if (values.empty()) {
      r.error(key, "must list at least one value");
      return false;
    }
    alarm.mode =
        has_ok ? drivers::ChamberAlarm::Mode::kOkValues : drivers::ChamberAlarm::Mode::kAlarmValues;
    alarm.values = std::move(values);
    return true;
  };
  std::optional<drivers::RegisterSpec> base;
  if (profile_alarm) base = profile_alarm->reg;
  auto reg = read_register(t, base, read_values);
  if (!reg) return std::nullopt;
  alarm.reg = *reg;
  alarm.reg.read_only = true;
  return alarm;
}

void read_endpoint(TableReader& t, drivers::ModbusEndpoint& ep, int default_unit) {
  ep.transport = t.choice("transport", {"tcp", "rtu"}, "tcp").value_or("tcp");
  if (auto h = t.string("host")) {
    if (const std::string problem = drivers::tcp_host_problem(*h); !problem.empty())
      t.error("host", problem);
    else
      ep.host = *h;
  }
  if (auto p = t.integer("port")) {
    if (*p < 0 || *p > 65535)
      t.error("port", fmt::format("{} is not a TCP port", *p));
    else
      ep.port = static_cast<int>(*p);
  }
  if (auto d = t.string("device")) ep.device = *d;
  if (auto b = t.integer("baud")) {
    if (*b <= 0)
      t.error("baud", "must be positive");
    else
      ep.baud = static_cast<int>(*b);
  }
  if (auto p = t.choice("parity", {"none", "even", "odd"}, std::nullopt)) {
    ep.parity = *p == "none" ? 'N' : (*p == "even" ? 'E' : 'O');
  }
  ep.unit_id = default_unit;
  if (auto u = t.integer("unit_id")) {
    if (*u < 0 || *u > 247)
      t.error("unit_id", fmt::format("{} is not a Modbus unit id (0..247)", *u));
    else
      ep.unit_id = static_cast<int>(*u);
  }
  ep.response_timeout_s = t.number_in("response_timeout_s", ep.response_timeout_s, 0.01, 60.0);
  if (ep.transport == "rtu" && ep.device.empty()) t.error("device", "missing (required for rtu)");
}

void read_station(TableReader t, StationSection& s) {
  if (auto n = t.string("name")) s.name = *n;
  s.latitude_deg = t.number_in("latitude_deg", s.latitude_deg, -90.0, 90.0);
  if (auto o = t.choice("orientation", {"up", "down", "horizontal"}, std::nullopt)) {
    s.orientation = *analysis::parse_orientation(*o);
  }
  s.min_temp_c = t.number_in("min_temp_c", s.min_temp_c, -100.0, 200.0);
  s.max_temp_c = t.number_in("max_temp_c", s.max_temp_c, -100.0, 200.0);
  if (s.min_temp_c >= s.max_temp_c) t.error("max_temp_c", "must be above min_temp_c");
  s.max_ramp_c_per_min = t.number_in("max_ramp_c_per_min", s.max_ramp_c_per_min, 0.001, 100.0);
  s.safe_setpoint_c = t.number_in("safe_setpoint_c", s.safe_setpoint_c, -100.0, 200.0);
  if (s.safe_setpoint_c < s.min_temp_c || s.safe_setpoint_c > s.max_temp_c) {
    t.error("safe_setpoint_c", "must lie within [min_temp_c, max_temp_c]");
  }
  t.finish();
}

void read_chamber(TableReader t, ChamberSection& c) {
  read_endpoint(t, c.endpoint, 1);
  c.silent_timeout_s = t.number_in("silent_timeout_s", c.silent_timeout_s, 0.1, 86400.0);
  auto profile = t.string("profile");
  auto regs = t.table("registers");
  if (profile && regs) t.error("registers", "give either profile or registers, not both");
  if (regs) {
    c.profile = "custom";
    auto sp = regs->table("setpoint");
    auto pv = regs->table("process_value");
    if (!sp) regs->error("setpoint", "missing (required register)");
    if (!pv) regs->error("process_value", "missing (required register)");
    if (sp)
      if (auto r = read_register(*sp)) c.map.setpoint = *r;
    if (pv) {
      if (auto r = read_register(*pv)) {
        c.map.process_value = *r;
        c.map.process_value.read_only = true;
      }
    }
    regs->finish();
  } else {
    if (profile) c.profile = *profile;
    auto map = drivers::chamber_profile(c.profile, c.endpoint.transport);
    if (map)
      c.map = *map;
    else
      t.error("profile", map.error().message);
  }
  if (auto alarm = t.table("alarm")) {
    if (auto a = read_alarm(*alarm, c.profile)) c.map.alarm = *a;
  }
  t.finish();
}

void read_probes(TableReader t, ProbesSection& p) {
  read_endpoint(t, p.endpoint, 2);
  p.silent_timeout_s = t.number_in("silent_timeout_s", p.silent_timeout_s, 0.1, 86400.0);
  auto profile = t.string("profile");
  auto regs = t.table("registers");
  if (profile && regs) t.error("registers", "give either profile or registers, not both");
  if (regs) {
    p.profile = "custom";
    auto top = regs->table("top");
    auto side = regs->table("side");
    if (!top) regs->error("top", "missing (required register)");
    if (!side) regs->error("side", "missing (required register)");
    if (top)
      if (auto r = read_register(*top)) p.top = *r;
    if (side)
      if (auto r = read_register(*side)) p.side = *r;
    regs->finish();
  } else {
    if (profile) p.profile = *profile;
    if (auto ch = t.table("channels")) {
      for (auto [role, field] :
           {std::pair{"top", &p.top_channel}, std::pair{"side", &p.side_channel}}) {
        if (auto v = ch->integer(role)) {
          if (*v < 0 || *v > 255)
            ch->error(role, "channel must be in 0..255");
          else
            *field = static_cast<int>(*v);
        }
      }
      ch->finish();
    }
    if (p.top_channel == p.side_channel) t.error("channels", "top and side use the same channel");
    auto top = drivers::probe_channel_spec(p.profile, p.top_channel);
    auto side = drivers::probe_channel_spec(p.profile, p.side_channel);
    if (!top)
      t.error("profile", top.error().message);
    else
      p.top = *top;
    if (side) p.side = *side;
  }
  t.finish();
}

void read_gyro(TableReader t, GyroSection& g) {
  if (auto d = t.string("device")) g.serial.device = *d;
  if (auto b = t.integer("baud")) {
    if (*b <= 0)
      t.error("baud", "must be positive");
    else
      g.serial.baud = static_cast<int>(*b);
  }
  if (auto p = t.choice("parity", {"none", "even", "odd"}, std::nullopt)) {
    g.serial.parity = *drivers::parse_parity(*p);
  }
  if (auto p = t.choice("protocol", {"kvh1750"}, std::nullopt)) g.protocol = *p;
  if (auto u = t.choice("unit", {"rad", "deg"}, std::nullopt)) {
    g.format.unit = *u == "rad" ? drivers::AngleUnit::kRad : drivers::AngleUnit::kDeg;
  }
  if (auto o = t.choice("output", {"rate", "delta"}, std::nullopt)) {
    g.format.kind = *o == "rate" ? drivers::OutputKind::kRate : drivers::OutputKind::kDeltaAngle;
  }
  if (auto a = t.choice("axis", {"x", "y", "z"}, std::nullopt)) g.format.axis = (*a)[0] - 'x';
  g.format.rate_hz = t.number_in("rate_hz", g.format.rate_hz, 0.1, 10000.0);
  g.silent_timeout_s = t.number_in("silent_timeout_s", g.silent_timeout_s, 0.1, 86400.0);
  t.finish();
}

// [table]: the rate table (docs/configuration.md, docs/table.md).
// `simulated`: [simulator] endpoints_file is set (the simulator then names
// the AERO device).
void read_table(TableReader t, TableSection& s, bool simulated) {
  drivers::TableConnection& c = s.connection;
  if (auto p = t.choice("profile", {"acutrol", "aero"}, std::nullopt)) c.profile = *p;
  if (auto h = t.string("host")) {
    if (const std::string problem = drivers::tcp_host_problem(*h); !problem.empty())
      t.error("host", problem);
    else
      c.host = *h;
  }
  if (auto p = t.integer("port")) {
    if (*p < 1 || *p > 65535)
      t.error("port", fmt::format("{} is not a TCP port (1..65535)", *p));
    else
      c.port = static_cast<int>(*p);
  }
  if (auto r = t.choice("reply_header", {"ascii", "binary-le", "binary-be", "line"}, std::nullopt))
    c.reply_header = *r;
  if (auto d = t.string("device")) {
    if (d->empty())
      t.error("device", "must not be empty");
    else
      c.device = *d;
  }
  if (auto b = t.integer("baud")) {
    if (*b <= 0)
      t.error("baud", "must be positive");
    else
      c.baud = static_cast<int>(*b);
  }
  if (auto a = t.integer("axis")) {
    if (*a < 1 || *a > 64)
      t.error("axis", fmt::format("{} is not an axis number (1..64)", *a));
    else
      c.axis = static_cast<int>(*a);
  }
  // Positive numbers: 0 or less is refused, with the key's line.
  const auto positive = [&](std::string_view key, double value, double hi) {
    if (auto v = t.number(key)) {
      if (!(*v > 0) || *v > hi)
        t.error(key, fmt::format("{:g} must be positive (and at most {:g})", *v, hi));
      else
        return *v;
    }
    return value;
  };
  c.timeout_s = positive("timeout_s", c.timeout_s, 60.0);
  s.max_rate_dps = positive("max_rate_dps", s.max_rate_dps, 1e5);
  s.max_accel_dps2 = positive("max_accel_dps2", s.max_accel_dps2, 1e6);
  s.at_rate_tolerance_dps = positive("at_rate_tolerance_dps", s.at_rate_tolerance_dps, 1e3);
  s.at_rate_tolerance_ppm = positive("at_rate_tolerance_ppm", s.at_rate_tolerance_ppm, 1e5);
  s.at_rate_hold_s = positive("at_rate_hold_s", s.at_rate_hold_s, 3600.0);
  s.spin_up_timeout_s = positive("spin_up_timeout_s", s.spin_up_timeout_s, 86400.0);
  s.rest_rate_dps = positive("rest_rate_dps", s.rest_rate_dps, 1e3);
  s.silent_timeout_s = positive("silent_timeout_s", s.silent_timeout_s, 86400.0);
  if (auto a = t.choice("sensitive_axis", {"along_table", "radial"}, std::nullopt))
    s.sensitive_axis = *a;
  s.heading_at_zero_deg = t.number_in("heading_at_zero_deg", s.heading_at_zero_deg, -360.0, 360.0);
  if (c.profile == "aero" && c.device.empty() && !simulated) {
    t.error("device",
            "missing (required for profile aero unless [simulator] endpoints_file is set)");
  }
  t.finish();
}

void read_storage(TableReader t, StorageSection& s) {
  if (auto d = t.string("db")) s.db_path = *d;
  s.commit_interval_s = t.number_in("commit_interval_s", s.commit_interval_s, 0.01, 1.0);
  t.finish();
}

void read_api(TableReader t, ApiSection& a) {
  if (auto b = t.string("bind")) a.bind = *b;
  if (auto p = t.integer("port")) {
    if (*p < 0 || *p > 65535)
      t.error("port", fmt::format("{} is not a TCP port", *p));
    else
      a.port = static_cast<int>(*p);
  }
  // Tokens are never quoted in errors: the message names the key, line and
  // entry instead.
  const auto read_token_list = [&](std::string_view key, std::vector<std::string>& out) {
    const toml::array* tokens = t.array(key);
    if (!tokens) return;
    const auto line = [&](const toml::node& node) {
      const int l = static_cast<int>(node.source().begin.line);
      return l > 0 ? l : t.line_of(key);
    };
    for (std::size_t i = 0; i < tokens->size(); ++i) {
      const toml::node& node = *tokens->get(i);
      auto s = node.value_exact<std::string>();
      if (!s || s->size() < 16) {
        t.errors().add(line(node), t.key_path(key),
                       fmt::format("each token must be a string of at least 16 characters "
                                   "(entry {})",
                                   i + 1));
        continue;
      }
      const auto same = [&](const std::string& other) { return other == *s; };
      if (std::find_if(out.begin(), out.end(), same) != out.end()) {
        t.errors().add(line(node), t.key_path(key),
                       fmt::format("entry {} repeats an earlier entry", i + 1));
      } else if (&out == &a.read_tokens &&
                 std::find_if(a.tokens.begin(), a.tokens.end(), same) != a.tokens.end()) {
        t.errors().add(line(node), t.key_path(key),
                       fmt::format("entry {} is also in [api] tokens: a token has one role "
                                   "(tokens may read and change, read_tokens only read)",
                                   i + 1));
      }
      out.push_back(*s);
    }
  };
  read_token_list("tokens", a.tokens);
  read_token_list("read_tokens", a.read_tokens);
  if (auto r = t.choice("read_access", {"open", "token"}, std::nullopt)) {
    a.read_access = *r;
    if (*r == "token" && a.tokens.empty() && a.read_tokens.empty()) {
      t.error("read_access",
              "\"token\" needs at least one token in [api] tokens or read_tokens (else "
              "nothing could read)");
    }
  }
  a.read_timeout_s = t.number_in("read_timeout_s", a.read_timeout_s, 0.1, 3600.0);
  const auto count_in = [&](std::string_view key, auto value, int64_t lo, int64_t hi) {
    if (auto v = t.integer(key)) {
      if (*v >= lo && *v <= hi) return static_cast<decltype(value)>(*v);
      t.error(key, fmt::format("{} is out of range: must be an integer in [{}, {}]", *v, lo, hi));
    }
    return value;
  };
  a.max_connections = count_in("max_connections", a.max_connections, 2, 10000);
  a.max_header_bytes = count_in("max_header_bytes", a.max_header_bytes, 1024, 1 << 20);
  a.max_body_bytes = count_in("max_body_bytes", a.max_body_bytes, 1024, 64 << 20);
  a.max_stream_clients = count_in("max_stream_clients", a.max_stream_clients, 0, 1000);
  a.stream_queue_bytes = count_in("stream_queue_bytes", a.stream_queue_bytes, 4096, 64 << 20);
  a.max_auth_failures = count_in("max_auth_failures", a.max_auth_failures, 1, 1000000);
  if (auto w = t.string("web_root")) a.web_root = *w;
  t.finish();
}

}  // namespace

schedules::StationLimits station_limits(const StationConfig& config) {
  schedules::StationLimits limits{config.station.min_temp_c, config.station.max_temp_c,
                                  config.station.max_ramp_c_per_min, std::nullopt};
  if (config.table) {
    limits.table =
        schedules::StationLimits::Table{config.table->max_rate_dps, config.table->max_accel_dps2};
  }
  return limits;
}

std::optional<std::string> api_exposure_warning(const ApiSection& api) {
  boost::system::error_code ec;
  const auto address = boost::asio::ip::make_address(api.bind, ec);
  if (ec || address.is_loopback() || api.read_access != "open") return std::nullopt;
  return fmt::format(
      "[api] bind = \"{}\" is not a loopback address and read_access = \"open\": anyone who "
      "can reach port {} reads the station's status, runs and data without a token (set "
      "read_access = \"token\" with read_tokens, or bind 127.0.0.1 behind a proxy){}",
      api.bind, api.port, api.tokens.empty() ? "; changes are disabled (no [api] tokens)" : "");
}

std::string redact_config_secrets(std::string_view toml_text, const ApiSection& api) {
  static constexpr std::string_view kRedacted = "<redacted>";
  TomlErrors errors("config");
  auto root = parse_toml_string(toml_text, errors);
  if (!root) return "# station config not recorded: it no longer parses as TOML\n";
  const auto secrets_in = [](const toml::table& table) {
    std::vector<std::string> out;
    for (const char* key : {"tokens", "read_tokens"}) {
      if (const auto* list = table["api"][key].as_array()) {
        for (const auto& node : *list) {
          if (auto s = node.value_exact<std::string>(); s && *s != kRedacted) out.push_back(*s);
        }
      }
    }
    return out;
  };
  std::vector<std::string> secrets = secrets_in(*root);
  secrets.insert(secrets.end(), api.tokens.begin(), api.tokens.end());
  secrets.insert(secrets.end(), api.read_tokens.begin(), api.read_tokens.end());
  // Longest first: a token inside another is not left half-replaced.
  std::sort(secrets.begin(), secrets.end(),
            [](const auto& a, const auto& b) { return a.size() > b.size(); });
  std::string out(toml_text);
  for (const auto& secret : secrets) {
    if (secret.size() < 8) continue;  // too short to replace blindly; see below
    for (auto pos = out.find(secret); pos != std::string::npos;
         pos = out.find(secret, pos + kRedacted.size())) {
      out.replace(pos, secret.size(), kRedacted);
    }
  }
  TomlErrors again_errors("config");
  auto again = parse_toml_string(out, again_errors);
  if (again && secrets_in(*again).empty()) return out;
  // Spelled with escapes (or very short): replace the values, lose comments.
  if (auto* api_table = root->get_as<toml::table>("api")) {
    for (const char* key : {"tokens", "read_tokens"}) {
      if (auto* list = api_table->get_as<toml::array>(key)) {
        const std::size_t n = list->size();
        list->clear();
        for (std::size_t i = 0; i < n; ++i) list->push_back(std::string(kRedacted));
      }
    }
  }
  std::ostringstream serialised;
  serialised << toml::toml_formatter(*root);
  return serialised.str();
}

namespace {

void read_export(TableReader t, ExportSection& e) {
  if (auto n = t.boolean("nightly")) e.nightly = *n;
  if (auto d = t.string("directory")) {
    if (d->empty()) {
      t.error("directory", "must not be empty");
    } else {
      e.directory = *d;
    }
  }
  if (auto z = t.string("time_zone")) {
    if (auto zone = TimeZone::posix(*z); !z->empty() && !zone) {
      t.error("time_zone", zone.error().message);
    } else {
      e.time_zone = *z;
    }
  }
  if (auto lt = t.string("local_time")) {
    if (auto parsed = parse_local_time_of_day(*lt); !parsed) {
      t.error("local_time", parsed.error().message);
    } else {
      e.local_time = *lt;
    }
  }
  t.finish();
}

void read_analysis(TableReader t, AnalysisSection& a) {
  a.bin_s = t.number_in("bin_s", a.bin_s, 1e-3, 3600.0);
  if (auto w = t.integer("ma_window")) {
    if (*w < 2 || *w > 100000)
      t.error("ma_window", "must be in [2, 100000]");
    else
      a.ma_window = static_cast<int>(*w);
  }
  if (auto w = t.integer("compare_smooth_points")) {
    if (*w < 1 || *w > 100001 || *w % 2 == 0)
      t.error("compare_smooth_points", "must be odd, in [1, 100001] (1 = not smoothed)");
    else
      a.compare_smooth_points = static_cast<int>(*w);
  }
  a.l0_window_s = t.number_in("l0_window_s", a.l0_window_s, 1.0, 86400.0);
  if (auto m = t.string("model")) {
    if (auto spec = analysis::parse_model_spec(*m); !spec) {
      t.error("model", spec.error().message);
    } else {
      a.model = analysis::to_string(*spec);
    }
  }
  a.derivative_window_s = t.number_in("derivative_window_s", a.derivative_window_s, 1.0, 86400.0);
  if (auto taus = t.string("allan_taus")) {
    if (auto set = analysis::parse_tau_set(*taus); !set) {
      t.error("allan_taus", set.error().message);
    } else {
      a.allan_taus = *taus;
    }
  }
  t.finish();
}

void read_control(TableReader t, ControlSection& c) {
  c.tick_s = t.number_in("tick_s", c.tick_s, 0.01, 60.0);
  c.min_tick_wall_s = t.number_in("min_tick_wall_s", c.min_tick_wall_s, 0.0005, 10.0);
  c.min_silent_wall_s = t.number_in("min_silent_wall_s", c.min_silent_wall_s, 0.0, 3600.0);
  t.finish();
}

void read_interlocks(TableReader t, schedules::InterlockOptions& o) {
  o.limit_margin_c = t.number_in("limit_margin_c", o.limit_margin_c, 0.0, 50.0);
  o.probe_disagreement_c = t.number_in("probe_disagreement_c", o.probe_disagreement_c, 0.01, 50.0);
  o.hysteresis_c = t.number_in("hysteresis_c", o.hysteresis_c, 0.0, 10.0);
  for (int k = 0; k < schedules::kInterlockKindCount; ++k) {
    const std::string key =
        fmt::format("{}_grace_min", schedules::to_string(static_cast<schedules::InterlockKind>(k)));
    o.grace_s[k] = 60.0 * t.number_in(key, o.grace_s[k] / 60.0, 0.0, 7 * 24 * 60.0);
  }
  t.finish();
}

Result<StationConfig> build_config(std::optional<toml::table> root, TomlErrors& errors,
                                   const std::string& source) {
  if (!root) return Error::Permanent(errors.joined());
  StationConfig cfg;
  cfg.source_path = source;
  TableReader top(*root, "", errors);
  auto section = [&](std::string_view name, bool required, auto&& fn) {
    if (auto t = top.table(name)) {
      fn(*t);
    } else if (required && !root->contains(name)) {
      errors.add(0, name, "missing section");
    }
  };
  section("station", true, [&](TableReader t) { read_station(t, cfg.station); });
  section("chamber", true, [&](TableReader t) { read_chamber(t, cfg.chamber); });
  section("probes", true, [&](TableReader t) { read_probes(t, cfg.probes); });
  section("gyro", true, [&](TableReader t) { read_gyro(t, cfg.gyro); });
  const bool simulated = root->at_path("simulator.endpoints_file").is_string();
  section("table", false, [&](TableReader t) { read_table(t, cfg.table.emplace(), simulated); });
  section("storage", false, [&](TableReader t) { read_storage(t, cfg.storage); });
  section("api", false, [&](TableReader t) { read_api(t, cfg.api); });
  section("export", false, [&](TableReader t) { read_export(t, cfg.export_); });
  section("analysis", false, [&](TableReader t) { read_analysis(t, cfg.analysis); });
  section("control", false, [&](TableReader t) { read_control(t, cfg.control); });
  section("interlocks", false, [&](TableReader t) { read_interlocks(t, cfg.interlocks); });
  section("simulator", false, [&](TableReader t) {
    if (auto f = t.string("endpoints_file")) cfg.simulator.endpoints_file = *f;
  });
  top.finish();
  // The rest of [simulator] belongs to gyrotherm-sim. Moved, not copied:
  // toml++ keeps source positions (for error lines) only through a move.
  if (auto* sim = root->get_as<toml::table>("simulator")) cfg.simulator_table = std::move(*sim);
  if (cfg.gyro.serial.device.empty() && cfg.simulator.endpoints_file.empty()) {
    errors.add(0, "gyro.device", "missing (required unless [simulator] endpoints_file is set)");
  }
  if (!errors.empty()) return Error::Permanent(errors.joined());
  cfg.interlocks.min_temp_c = cfg.station.min_temp_c;
  cfg.interlocks.max_temp_c = cfg.station.max_temp_c;
  cfg.interlocks.chamber_timeout_s = cfg.chamber.silent_timeout_s;
  cfg.interlocks.probes_timeout_s = cfg.probes.silent_timeout_s;
  cfg.interlocks.gyro_timeout_s = cfg.gyro.silent_timeout_s;
  return cfg;
}

}  // namespace

Result<StationConfig> load_station_config(const std::string& path) {
  TomlErrors errors(path);
  return build_config(parse_toml_file(path, errors), errors, path);
}

Result<StationConfig> parse_station_config(std::string_view toml_text,
                                           const std::string& source_name) {
  TomlErrors errors(source_name);
  return build_config(parse_toml_string(toml_text, errors), errors, source_name);
}

Result<SimEndpoints> read_sim_endpoints(const std::string& path) {
  TomlErrors errors(path);
  auto root = parse_toml_file(path, errors);
  if (!root) return Error::Transient(errors.joined());
  SimEndpoints ep;
  TableReader t(*root, "", errors);
  if (auto h = t.required_string("modbus_host")) ep.modbus_host = *h;
  if (auto p = t.integer("modbus_port"))
    ep.modbus_port = static_cast<int>(*p);
  else
    t.error("modbus_port", "missing");
  if (auto d = t.required_string("gyro_device")) ep.gyro_device = *d;
  if (auto p = t.integer("pid")) ep.pid = static_cast<long>(*p);
  if (auto c = t.string("control_socket")) ep.control_socket = *c;
  if (auto p = t.integer("table_port")) {
    if (*p < 0 || *p > 65535)
      t.error("table_port", fmt::format("{} is not a TCP port", *p));
    else
      ep.table_port = static_cast<int>(*p);
  }
  if (auto d = t.string("table_device")) ep.table_device = *d;
  if (auto s = t.number("time_scale")) {
    if (*s > 0)
      ep.time_scale = *s;
    else
      t.error("time_scale", "must be positive");
  }
  t.finish();
  if (!errors.empty()) return Error::Permanent(errors.joined());
  return ep;
}

Status write_sim_endpoints(const std::string& path, const SimEndpoints& ep) {
  toml::table t{{"modbus_host", ep.modbus_host},
                {"modbus_port", ep.modbus_port},
                {"gyro_device", ep.gyro_device},
                {"pid", static_cast<int64_t>(ep.pid)}};
  if (!ep.control_socket.empty()) t.insert("control_socket", ep.control_socket);
  if (ep.time_scale > 0) t.insert("time_scale", ep.time_scale);
  if (ep.table_port > 0) t.insert("table_port", ep.table_port);
  if (!ep.table_device.empty()) t.insert("table_device", ep.table_device);
  std::ostringstream ss;
  ss << "# written by gyrotherm-sim; read by gyrothermd ([simulator] endpoints_file)\n"
     << t << "\n";
  return write_file_creating_folders(path, ss.str());
}

std::string sim_time_scale_mismatch(const SimEndpoints& ep, double daemon_time_scale,
                                    const std::string& endpoints_file) {
  if (ep.time_scale <= 0) return "";  // an older simulator: nothing to compare
  if (std::fabs(ep.time_scale - daemon_time_scale) <= 1e-9 * ep.time_scale) return "";
  return fmt::format(
      "the simulator runs at time scale {:g} ({}) but the daemon was asked for {:g}; the two "
      "clocks would disagree (set points, ramps and acquisition windows would be wrong): start "
      "both with the same --time-scale",
      ep.time_scale, endpoints_file, daemon_time_scale);
}

void apply_sim_endpoints(StationConfig& config, const SimEndpoints& ep) {
  for (auto* endpoint : {&config.chamber.endpoint, &config.probes.endpoint}) {
    endpoint->transport = "tcp";
    endpoint->host = ep.modbus_host;
    endpoint->port = ep.modbus_port;
  }
  config.gyro.serial.device = ep.gyro_device;
  // The simulator's table, for a station that has one: ACL on loopback TCP,
  // the AERO grammar on a pty.
  if (config.table) {
    drivers::TableConnection& c = config.table->connection;
    if (c.profile == "acutrol" && ep.table_port > 0) {
      c.host = "127.0.0.1";
      c.port = ep.table_port;
    } else if (c.profile == "aero" && !ep.table_device.empty()) {
      c.device = ep.table_device;
    }
  }
}

}  // namespace gyrotherm::daemon
