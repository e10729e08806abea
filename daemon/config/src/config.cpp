#include "gyrotherm/config/config.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <toml++/toml.h>
#include <unistd.h>

#include <algorithm>
#include <boost/asio/ip/address.hpp>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>

#include "config_readers.h"
#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/config/nightly.h"
#include "gyrotherm/core/toml_reader.h"

static_assert(TOML_LIB_MAJOR == 3, "config.h declares toml::table as toml::v3::table");

namespace gyrotherm::config {

// The readers of the other rooms (config_readers.h).
using internal::dut_from_gyro;
using internal::gyro_of;
using internal::read_duts;
using internal::read_gyro;
using internal::read_lab;

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

// [table]: the rate table (docs/configuration.md, docs/table.md).
// `simulated`: [simulator] endpoints_file is set (the simulator then names
// the table's TCP port or serial device).
void read_table(TableReader t, TableSection& s, bool simulated) {
  drivers::TableConnection& c = s.connection;
  if (auto p = t.choice("profile", {"acutrol", "aero"}, std::nullopt)) c.profile = *p;
  // The protocol and the link under it are separate choices; the default
  // link is each controller's own port (ACUTROL3000: Ethernet, TM-9384C;
  // AERO: RS-232).
  const std::string profile_transport = c.profile == "aero" ? "serial" : "tcp";
  const auto chosen = t.choice("transport", {"tcp", "serial"}, std::nullopt);
  c.transport = chosen.value_or(profile_transport);
  const std::string transport_said =
      chosen ? fmt::format("transport = \"{}\"", c.transport)
             : fmt::format("transport is \"{}\" (profile {}'s default)", c.transport, c.profile);
  // A key of the other transport is refused: it would be ignored, and the
  // station would talk to something other than what the file says.
  const auto for_transport = [&](std::string_view key, std::string_view transport) {
    if (c.transport == transport) return true;
    t.error(key, fmt::format("given, but {}: {} is for transport = \"{}\"", transport_said, key,
                             transport));
    return false;
  };
  // Each key: a bad value is reported as such, a good one of the other
  // transport as a contradiction.
  if (auto h = t.string("host")) {
    if (const std::string problem = drivers::tcp_host_problem(*h); !problem.empty())
      t.error("host", problem);
    else if (for_transport("host", "tcp"))
      c.host = *h;
  }
  if (auto p = t.integer("port")) {
    if (*p < 1 || *p > 65535)
      t.error("port", fmt::format("{} is not a TCP port (1..65535)", *p));
    else if (for_transport("port", "tcp"))
      c.port = static_cast<int>(*p);
  }
  if (auto r = t.choice("reply_header", {"ascii", "binary-le", "binary-be", "line"}, std::nullopt))
    c.reply_header = *r;
  if (auto d = t.string("device")) {
    if (d->empty())
      t.error("device", "must not be empty");
    else if (for_transport("device", "serial"))
      c.device = *d;
  }
  if (auto b = t.integer("baud")) {
    if (*b <= 0)
      t.error("baud", "must be positive");
    else if (for_transport("baud", "serial"))
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
  if (auto r = t.boolean("respin_after_fault")) s.respin_after_fault = *r;
  if (auto a = t.choice("sensitive_axis", {"along_table", "radial"}, std::nullopt))
    s.sensitive_axis = *a;
  s.heading_at_zero_deg = t.number_in("heading_at_zero_deg", s.heading_at_zero_deg, -360.0, 360.0);
  // What the link needs and has no default for: the serial device; for a
  // TCP link to anything but an ACUTROL3000 (whose address TM-9384C gives),
  // the serial server's host and port. The simulator names its own.
  if (!simulated && c.transport == "serial" && c.device.empty() && !t.raw().contains("device")) {
    t.error("device", fmt::format("missing: {} needs the serial device (unless [simulator] "
                                  "endpoints_file is set)",
                                  transport_said));
  }
  if (!simulated && c.transport == "tcp" && c.profile != "acutrol") {
    for (const char* key : {"host", "port"}) {
      if (!t.raw().contains(key)) {
        t.error(key, fmt::format("missing: {} needs the serial server's {} (profile {} has no "
                                 "default address; unless [simulator] endpoints_file is set)",
                                 transport_said, key, c.profile));
      }
    }
  }
  t.finish();
}

void read_storage(TableReader t, StorageSection& s) {
  if (auto d = t.string("db")) {
    s.db_path = *d;
    s.db_line = t.line_of("db");
  }
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
        schedules::StationLimits::Table{config.table->max_rate_dps, config.table->max_accel_dps2,
                                        config.table->connection.profile == "aero"};
  }
  return limits;
}

schedules::SequencerOptions sequencer_options(const StationConfig& config) {
  schedules::SequencerOptions o;
  o.safe_setpoint_c = config.station.safe_setpoint_c;
  o.interlocks = config.interlocks;
  if (config.table) {
    o.at_rate_tolerance_dps = config.table->at_rate_tolerance_dps;
    o.at_rate_tolerance_ppm = config.table->at_rate_tolerance_ppm;
    o.interlocks.table_timeout_s = config.table->silent_timeout_s;
    o.at_rate_hold_s = config.table->at_rate_hold_s;
    o.spin_up_timeout_s = config.table->spin_up_timeout_s;
  }
  return o;
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
  a.rate_guard_s = t.number_in("rate_guard_s", a.rate_guard_s, 0.0, 3600.0);
  a.rate_flatness_sigma = t.number_in("rate_flatness_sigma", a.rate_flatness_sigma, 1.0, 1000.0);
  a.rate_flatness_ppm = t.number_in("rate_flatness_ppm", a.rate_flatness_ppm, 0.0, 1e6);
  t.finish();
}

void read_quality(TableReader t, QualitySection& q) {
  q.min_coverage = t.number_in("min_coverage", q.min_coverage, 0.0, 1.0);
  q.k_min = t.number_in("k_min", q.k_min, 0.0, 1.0);
  q.k_max = t.number_in("k_max", q.k_max, 1.0, 1000.0);
  q.max_nonlinearity_ppm = t.number_in("max_nonlinearity_ppm", q.max_nonlinearity_ppm, 0.0, 1e9);
  q.max_residual_ratio = t.number_in("max_residual_ratio", q.max_residual_ratio, 1.0, 1e6);
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

// The config key that sets a field of SequencerOptions (as its is_valid
// names it); "interlocks" for one no key sets.
std::string config_key_of(std::string_view field, bool dut_form) {
  static constexpr std::pair<std::string_view, std::string_view> kKeys[] = {
      {"safe_setpoint_c", "station.safe_setpoint_c"},
      {"interlocks.min_temp_c", "station.min_temp_c"},
      {"interlocks.max_temp_c", "station.max_temp_c"},
      {"interlocks.limit_margin_c", "interlocks.limit_margin_c"},
      {"interlocks.probe_disagreement_c", "interlocks.probe_disagreement_c"},
      {"interlocks.hysteresis_c", "interlocks.hysteresis_c"},
      {"interlocks.chamber_timeout_s", "chamber.silent_timeout_s"},
      {"interlocks.probes_timeout_s", "probes.silent_timeout_s"},
      {"interlocks.table_timeout_s", "table.silent_timeout_s"},
      {"at_rate_tolerance_dps", "table.at_rate_tolerance_dps"},
      {"at_rate_tolerance_ppm", "table.at_rate_tolerance_ppm"},
      {"at_rate_hold_s", "table.at_rate_hold_s"},
      {"spin_up_timeout_s", "table.spin_up_timeout_s"},
  };
  for (const auto& [f, key] : kKeys) {
    if (f == field) return std::string(key);
  }
  if (field == "interlocks.gyro_timeout_s") {
    return dut_form ? "dut.silent_timeout_s" : "gyro.silent_timeout_s";
  }
  constexpr std::string_view kGrace = "interlocks.grace_s[";
  if (field.starts_with(kGrace) && field.ends_with("]")) {
    const std::string_view kind = field.substr(kGrace.size(), field.size() - kGrace.size() - 1);
    return fmt::format("interlocks.{}_grace_min", kind);
  }
  return "interlocks";
}

// The line of `key_path` in the file: of the key, else of its section
// (the first [[dut]] for dut.*), else 0.
int line_at(const toml::table& root, const std::string& key_path) {
  const auto line = [](const toml::node* n) {
    return n ? static_cast<int>(n->source().begin.line) : 0;
  };
  const std::string section = key_path.substr(0, key_path.find('.'));
  const std::string key = key_path.substr(std::min(key_path.size(), section.size() + 1));
  const toml::node* table = root.get(section);
  if (const toml::array* list = table ? table->as_array() : nullptr) {
    table = list->empty() ? nullptr : list->get(0);
  }
  const toml::table* t = table ? table->as_table() : nullptr;
  if (!t) return 0;
  if (int l = line(t->get(key)); l > 0) return l;
  return line(t);
}

Result<StationConfig> build_config(std::optional<toml::table> root, TomlErrors& errors,
                                   const std::string& source) {
  if (!root) return Error::Permanent(errors.joined());
  StationConfig cfg;
  cfg.source_path = source;
  TomlErrors warnings(source);
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
  const bool simulated = root->at_path("simulator.endpoints_file").is_string();
  // The devices under test: [[dut]], or the older single [gyro] as one DUT.
  const bool has_gyro = root->contains("gyro");
  const bool has_dut = root->contains("dut");
  if (has_gyro && has_dut) {
    top.error("dut", fmt::format("both [gyro] (line {}) and [[dut]] are given: describe every "
                                 "gyro as a [[dut]] and remove [gyro] (the older form of one DUT)",
                                 top.line_of("gyro")));
    top.skip("gyro");
    read_duts(top, cfg.duts, cfg.station, cfg.probes, simulated, warnings);
  } else if (has_dut) {
    read_duts(top, cfg.duts, cfg.station, cfg.probes, simulated, warnings);
  } else if (has_gyro) {
    section("gyro", true, [&](TableReader t) { read_gyro(t, cfg.gyro); });
    if (cfg.gyro.serial.device.empty() && !simulated) {
      errors.add(top.line_of("gyro"), "gyro.device",
                 "missing (required unless [simulator] endpoints_file is set)");
    }
    cfg.duts.push_back(dut_from_gyro(cfg.gyro, cfg.station.orientation));
    if (cfg.station.orientation == analysis::AxisOrientation::kHorizontal) {
      const toml::node* given = root->at_path("station.orientation").node();
      warnings.add(given ? static_cast<int>(given->source().begin.line) : top.line_of("station"),
                   "station.orientation",
                   "the gyro's axis is horizontal without a heading: its Earth-rate component is "
                   "taken as 0 (as if it pointed east or west); describe it as a [[dut]] with "
                   "heading_deg");
    }
  } else {
    errors.add(0, "dut",
               "missing: give each device under test as a [[dut]] (or one gyro as the older "
               "[gyro] section)");
  }
  section("table", false, [&](TableReader t) { read_table(t, cfg.table.emplace(), simulated); });
  section("storage", false, [&](TableReader t) { read_storage(t, cfg.storage); });
  section("api", false, [&](TableReader t) { read_api(t, cfg.api); });
  section("export", false, [&](TableReader t) { read_export(t, cfg.export_); });
  section("analysis", false, [&](TableReader t) { read_analysis(t, cfg.analysis); });
  section("quality", false, [&](TableReader t) { read_quality(t, cfg.quality); });
  section("control", false, [&](TableReader t) { read_control(t, cfg.control); });
  section("interlocks", false, [&](TableReader t) { read_interlocks(t, cfg.interlocks); });
  section("lab", false, [&](TableReader t) { read_lab(t, cfg.lab.emplace(), source); });
  section("simulator", false, [&](TableReader t) {
    if (auto f = t.string("endpoints_file")) cfg.simulator.endpoints_file = *f;
  });
  top.finish();
  // The rest of [simulator] belongs to gyrotherm-sim. Moved, not copied:
  // toml++ keeps source positions (for error lines) only through a move.
  if (auto* sim = root->get_as<toml::table>("simulator")) cfg.simulator_table = std::move(*sim);
  if (!errors.empty()) return Error::Permanent(errors.joined());
  cfg.warnings = warnings.messages();
  cfg.gyro = gyro_of(cfg.duts.front());
  cfg.interlocks.min_temp_c = cfg.station.min_temp_c;
  cfg.interlocks.max_temp_c = cfg.station.max_temp_c;
  cfg.interlocks.chamber_timeout_s = cfg.chamber.silent_timeout_s;
  cfg.interlocks.probes_timeout_s = cfg.probes.silent_timeout_s;
  // One stream lost is the gyro_lost interlock: the quickest DUT's timeout.
  cfg.interlocks.gyro_timeout_s = cfg.duts.front().silent_timeout_s;
  for (const auto& dut : cfg.duts)
    cfg.interlocks.gyro_timeout_s = std::min(cfg.interlocks.gyro_timeout_s, dut.silent_timeout_s);
  // Each key was range-checked above; what is left are combinations (the
  // hysteresis against the probe limit, the spin-up timeout against the
  // hold), reported at the key of the field the message starts with.
  if (std::string why; !sequencer_options(cfg).is_valid(&why)) {
    const std::string key = config_key_of(why.substr(0, why.find(' ')), has_dut);
    errors.add(line_at(*root, key), key, why);
    return Error::Permanent(errors.joined());
  }
  return cfg;
}

}  // namespace

Status check_database_directory(const StationConfig& config, std::string_view given_by) {
  const std::string& db = config.storage.db_path;
  if (db.empty() || db == ":memory:") return Status::Ok();
  const std::filesystem::path dir = std::filesystem::path(db).parent_path();
  if (dir.empty()) return Status::Ok();  // the working directory
  std::error_code ec;
  const std::filesystem::file_status st = std::filesystem::status(dir, ec);
  if (std::filesystem::is_directory(st)) return Status::Ok();
  std::string where(given_by);
  if (where.empty()) {
    where = config.storage.db_line > 0
                ? fmt::format("{}:{}: storage.db", config.source_path, config.storage.db_line)
                : fmt::format("{}: storage.db", config.source_path);
  }
  std::string what = "does not exist";
  if (std::filesystem::exists(st)) {
    what = "is not a directory";
  } else if (ec && ec != std::errc::no_such_file_or_directory && ec != std::errc::not_a_directory) {
    what = "cannot be reached: " + ec.message();
  }
  return Error::Permanent(fmt::format(
      "{}: the database's directory {} {}; create it (writable by the daemon's user) or fix the "
      "path{}",
      where, dir.string(), what,
      dir.is_relative() ? " (a relative path starts from the working directory)" : ""));
}

Result<StationConfig> load_station_config(const std::string& path) {
  TomlErrors errors(path);
  return build_config(parse_toml_file(path, errors), errors, path);
}

Result<StationConfig> parse_station_config(std::string_view toml_text,
                                           const std::string& source_name) {
  TomlErrors errors(source_name);
  return build_config(parse_toml_string(toml_text, errors), errors, source_name);
}

}  // namespace gyrotherm::config
