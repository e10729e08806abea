// gyrotherm: the command-line tool. Daemon control over REST, offline
// analysis on a database or CSV files (analysis.h), a capture-file decoder,
// and commissioning on a station config.
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>

#include "analysis.h"
#include "control.h"
#include "export.h"
#include "gyrotherm/cli/http_client.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/config/sim_endpoints.h"
#include "gyrotherm/drivers/frame_parser.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/drivers/modbus_devices.h"
#include "gyrotherm/drivers/protocol.h"
#include "gyrotherm/drivers/rate_tables.h"
#include "gyrotherm/drivers/serial_port.h"
#include "gyrotherm/schedules/progress.h"
#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/station/station_lock.h"
#include "gyrotherm/storage/database.h"
#include "lab.h"
#include "output.h"
#include "samples.h"

namespace {

using namespace gyrotherm;

using cli::fail;

// ---------------------------------------------------------------- decode
// The summary of a decoded capture, on stderr: text, or one JSON object.
void print_decode_summary(const std::string& source, const drivers::ParserCounters& c, bool json) {
  if (json) {
    // The summary as one JSON object on stderr; the frames stay CSV on stdout.
    std::cerr << nlohmann::json({{"file", source},
                                 {"frames_ok", c.frames_ok},
                                 {"crc_failures", c.crc_failures},
                                 {"bytes_skipped", c.bytes_skipped},
                                 {"sequence_gaps", c.sequence_gaps},
                                 {"frames_missed", c.frames_missed}})
                     .dump()
              << "\n";
    return;
  }
  std::fprintf(stderr,
               "%s: %llu valid frames, %llu CRC failures, %llu bytes skipped, %llu sequence gaps "
               "(%llu frames missed)\n",
               source.c_str(), static_cast<unsigned long long>(c.frames_ok),
               static_cast<unsigned long long>(c.crc_failures),
               static_cast<unsigned long long>(c.bytes_skipped),
               static_cast<unsigned long long>(c.sequence_gaps),
               static_cast<unsigned long long>(c.frames_missed));
}

// Calls `feed` with each block of the capture at `path` ("" or "-":
// standard input). False when it cannot be opened.
bool read_capture(const std::string& path,
                  const std::function<void(std::span<const uint8_t>)>& feed) {
  std::ifstream file;
  std::istream* in = &std::cin;
  if (!path.empty() && path != "-") {
    file.open(path, std::ios::binary);
    if (!file) return false;
    in = &file;
  }
  std::vector<uint8_t> buf(1 << 16);
  while (*in) {
    in->read(reinterpret_cast<char*>(buf.data()), static_cast<std::streamsize>(buf.size()));
    const auto n = static_cast<std::size_t>(in->gcount());
    if (n == 0) break;
    feed(std::span<const uint8_t>(buf.data(), n));
  }
  return true;
}

// A KVH 1750 capture: the frames' values as sent.
int decode_kvh1750(const std::string& path, bool json) {
  auto parser = drivers::make_frame_parser("kvh1750");
  if (!parser) return fail(parser.error().message, 2);
  std::vector<drivers::GyroFrame> frames;
  bool header = false;
  const bool opened = read_capture(path, [&](std::span<const uint8_t> bytes) {
    if (!header) {
      std::printf("seq,status,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z,temp_c\n");
      header = true;
    }
    frames.clear();
    (*parser)->feed(bytes, frames);
    for (const auto& f : frames) {
      std::printf("%u,%u,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%d\n", f.seq, f.status, f.gyro[0], f.gyro[1],
                  f.gyro[2], f.accel[0], f.accel[1], f.accel[2], f.temp_c);
    }
  });
  if (!opened) return fail(fmt::format("{}: cannot open", path), 2);
  if (!header) std::printf("seq,status,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z,temp_c\n");
  print_decode_summary(path.empty() ? "-" : path, (*parser)->counters(), json);
  return 0;
}

// A capture of the [[dut]] `serial` of `config_path`, decoded by its
// protocol: the sequence counter, then every channel's value as sent
// (shortest digits that read back exactly; nan: flagged invalid).
int decode_dut(const std::string& protocol, const std::string& config_path,
               const std::string& serial, const std::string& path, bool json) {
  auto cfg = config::load_station_config(config_path);
  if (!cfg) return fail("bad station config:\n" + cfg.error().message, 2);
  const config::DutSection* dut = config::find_dut(cfg->duts, serial);
  if (!dut) {
    std::vector<std::string> serials;
    for (const auto& d : cfg->duts) serials.push_back(fmt::format("\"{}\"", d.serial));
    return fail(fmt::format("{}: no [[dut]] with serial \"{}\" (serials: {})", config_path, serial,
                            fmt::join(serials, ", ")),
                2);
  }
  if (dut->link.protocol != protocol) {
    return fail(fmt::format("{}: DUT \"{}\" speaks {}, not {}", config_path, serial,
                            dut->link.protocol, protocol),
                2);
  }
  auto decoder = drivers::make_dut_protocol(dut->link);
  if (!decoder) return fail(decoder.error().message, 2);
  drivers::DutProtocol& p = **decoder;
  const std::vector<ChannelSpec>& channels = p.channels();
  std::string header = "seq";
  for (const auto& c : channels) header += "," + c.name;
  std::vector<DutFrame> frames;
  bool started = false;
  const bool opened = read_capture(path, [&](std::span<const uint8_t> bytes) {
    if (!started) {
      std::printf("%s\n", header.c_str());
      started = true;
    }
    frames.clear();
    p.feed(bytes, frames);
    for (const auto& f : frames) {
      std::string line = fmt::format("{}", f.seq);
      for (std::size_t i = 0; i < channels.size(); ++i) {
        line += std::isnan(f.raw[i]) ? std::string(",nan") : fmt::format(",{}", f.raw[i]);
      }
      std::printf("%s\n", line.c_str());
    }
  });
  if (!opened) return fail(fmt::format("{}: cannot open", path), 2);
  if (!started) std::printf("%s\n", header.c_str());
  print_decode_summary(path.empty() ? "-" : path, p.counters(), json);
  return 0;
}

int cmd_decode(const std::string& protocol, const std::string& path, const std::string& config_path,
               const std::string& serial, bool json) {
  if (protocol == "ascii" && (config_path.empty() || serial.empty())) {
    return fail(
        "--protocol ascii needs --config FILE and --dut SERIAL: the line's layout is in "
        "that [[dut]]'s [dut.ascii]",
        2);
  }
  if (!config_path.empty() || !serial.empty()) {
    if (config_path.empty() || serial.empty())
      return fail("--config and --dut go together (the [[dut]] whose capture this is)", 2);
    return decode_dut(protocol, config_path, serial, path, json);
  }
  return decode_kvh1750(path, json);
}

// ---------------------------------------------------------------- station config helpers
Result<config::StationConfig> load_config_for_tools(const std::string& path) {
  auto cfg = config::load_station_config(path);
  if (!cfg) return cfg;
  if (!cfg->simulator.endpoints_file.empty()) {
    auto ep = config::read_sim_endpoints(cfg->simulator.endpoints_file);
    if (!ep) {
      return Error::Transient(
          fmt::format("{}: simulator endpoints not readable (is gyrotherm-sim "
                      "running?): {}",
                      cfg->simulator.endpoints_file, ep.error().message));
    }
    config::apply_sim_endpoints(*cfg, *ep);
  }
  return cfg;
}

// Commissioning talks to the devices directly, so it needs the station to
// itself: nullopt when it has it, else the exit code after saying who owns
// it. A daemon holds the station lock beside its database; a daemon started
// on another database (--db) is still caught by the gyro line's lock, which
// `gyro_port` tries to take (it is kept open, held, until the command ends).
std::optional<int> refuse_if_station_owned(const config::StationConfig& cfg,
                                           std::optional<drivers::SerialPort>& gyro_port,
                                           std::string& gyro_error) {
  if (const auto owner = station::station_owner(cfg.storage.db_path)) {
    std::string who = "gyrothermd";
    if (owner->pid > 0) who += fmt::format(" (pid {})", owner->pid);
    const std::string api = owner->api_url.empty() ? "" : fmt::format(" at {}", owner->api_url);
    return fail(
        fmt::format("the station is run by {}{} (station lock {}); commissioning commands talk to "
                    "the devices directly and would disturb it. Use `gyrotherm status` for live "
                    "readings and the queue for set points, or stop the daemon first.",
                    who, api, station::station_lock_path(cfg.storage.db_path)),
        2);
  }
  auto port = drivers::SerialPort::open(cfg.gyro.serial);
  if (port) {
    gyro_port.emplace(std::move(*port));
  } else if (drivers::serial_line_in_use(port.error())) {
    return fail(fmt::format("{}; a daemon seems to run this station (on another database?): "
                            "stop it before commissioning",
                            port.error().message),
                2);
  } else {
    gyro_error = port.error().message;
  }
  return std::nullopt;
}

std::string reading(const Result<double>& r, const char* unit) {
  return r ? fmt::format("{:.3f} {}", *r, unit) : fmt::format("ERROR: {}", r.error().message);
}

// The unit the chamber serves temperatures in: its units register where
// its map has one, else °C. Error when unreadable or neither.
Result<drivers::TemperatureUnit> chamber_unit(drivers::Chamber& chamber) {
  auto units = chamber.units();
  if (!units) return units.error();
  if (!units->unit) return Error::Permanent(units->note);
  return *units->unit;
}

// A chamber temperature (`read`: its process value or set point, in `unit`),
// in °C.
Result<double> chamber_c(const Result<double>& read, drivers::TemperatureUnit unit) {
  if (!read) return read;
  return drivers::to_celsius(*read, unit);
}

// One DUT's reading for `gyrotherm devices`: its line, its protocol and the
// frames heard.
struct DutReading {
  const config::DutSection* dut = nullptr;
  std::optional<drivers::SerialPort> port;
  std::unique_ptr<drivers::DutProtocol> protocol;
  std::vector<DutFrame> frames;
  std::string error;  // the line could not be opened, or the protocol not made
};

std::string dut_name(const config::DutSection& dut) {
  std::string name = dut.serial.empty() ? std::string("(no serial)") : dut.serial;
  if (!dut.model.empty()) name += fmt::format(" ({})", dut.model);
  return name;
}

// A channel's physical value as shown: status words in hex.
std::string channel_text(const ChannelSpec& c, double raw) {
  if (std::isnan(raw)) return "invalid";
  if (c.kind == ChannelKind::kStatus) return fmt::format("0x{:02x}", static_cast<uint64_t>(raw));
  const double v = raw * c.scale;
  const int decimals = c.kind == ChannelKind::kAccel ? 5 : (c.kind == ChannelKind::kRate ? 3 : 2);
  return c.unit.empty() ? fmt::format("{:.{}f}", v, decimals)
                        : fmt::format("{:.{}f} {}", v, decimals, c.unit);
}

// A channel's physical value in JSON: null when flagged invalid, status
// words as integers.
nlohmann::json physical_json(const ChannelSpec& c, double raw) {
  if (std::isnan(raw)) return nullptr;
  if (c.kind == ChannelKind::kStatus) return static_cast<uint64_t>(raw);
  return raw * c.scale;
}

int cmd_devices(const std::string& config_path, bool json) {
  auto cfg = load_config_for_tools(config_path);
  if (!cfg) return fail(cfg.error().message, 2);
  if (const std::string& file = cfg->simulator.endpoints_file; !file.empty()) {
    // load_config_for_tools read it already: it is there.
    if (auto ep = config::read_sim_endpoints(file)) {
      if (const std::string why = config::sim_dut_devices_mismatch(*cfg, *ep, file); !why.empty())
        return fail(why, 2);
    }
  }
  // The first DUT's line is taken (and held) with the station check; the
  // others here, each refused as a sign of a daemon when another process
  // holds it.
  std::vector<DutReading> readings(cfg->duts.size());
  if (auto refused = refuse_if_station_owned(*cfg, readings[0].port, readings[0].error))
    return *refused;
  for (std::size_t i = 0; i < cfg->duts.size(); ++i) {
    DutReading& r = readings[i];
    r.dut = &cfg->duts[i];
    if (i > 0) {
      auto port = drivers::SerialPort::open(r.dut->link.serial);
      if (port) {
        r.port.emplace(std::move(*port));
      } else if (drivers::serial_line_in_use(port.error())) {
        return fail(fmt::format("{}; a daemon seems to run this station (on another database?): "
                                "stop it before commissioning",
                                port.error().message),
                    2);
      } else {
        r.error = port.error().message;
      }
    }
    if (auto p = drivers::make_dut_protocol(r.dut->link)) {
      r.protocol = std::move(*p);
    } else {
      r.error = p.error().message;
      r.port.reset();
    }
  }
  drivers::ModbusChamber chamber(cfg->chamber.endpoint, cfg->chamber.map);
  drivers::ModbusProbes probes(cfg->probes.endpoint, cfg->probes.top, cfg->probes.side);
  const auto unit = chamber_unit(chamber);
  const Result<double> pv = unit ? chamber_c(chamber.process_value(), *unit) : unit.error();
  const Result<double> sp = unit ? chamber_c(chamber.setpoint(), *unit) : unit.error();
  const auto top = probes.top_c();
  const auto side = probes.side_c();

  // Every DUT's line for up to two seconds (wall), in turns, until each has
  // given 20 frames.
  std::vector<uint8_t> buf(4096);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(2);
  const auto listening = [&] {
    return std::any_of(readings.begin(), readings.end(),
                       [](const DutReading& r) { return r.port && r.frames.size() < 20; });
  };
  while (std::chrono::steady_clock::now() < deadline && listening()) {
    for (DutReading& r : readings) {
      if (!r.port || r.frames.size() >= 20) continue;
      auto n = r.port->read(buf, std::chrono::milliseconds(20));
      if (!n) {
        r.error = n.error().message;
        r.port.reset();
        continue;
      }
      r.protocol->feed(std::span<const uint8_t>(buf.data(), *n), r.frames);
    }
  }

  bool duts_ok = true;
  nlohmann::json duts_json = nlohmann::json::array();
  nlohmann::json gyro_json;  // the first DUT's primary axis, as before [[dut]]
  std::string duts_text;
  for (const DutReading& r : readings) {
    const config::DutSection& dut = *r.dut;
    nlohmann::json j = {{"serial", dut.serial},
                        {"model", dut.model},
                        {"device", dut.link.serial.device},
                        {"protocol", dut.link.protocol},
                        {"primary_axis", dut.primary_axis}};
    duts_text += fmt::format("dut      {} on {} ({})\n", dut_name(dut), dut.link.serial.device,
                             dut.link.protocol);
    std::string error = r.error;
    if (error.empty() && r.frames.empty()) {
      const auto& c = r.protocol->counters();
      error = fmt::format("no valid frame in 2 s ({} CRC failures, {} bytes skipped)",
                          c.crc_failures, c.bytes_skipped);
    }
    if (!error.empty()) {
      duts_ok = false;
      j["error"] = error;
      duts_text += fmt::format("  {}\n", error);
      if (&r == &readings.front()) gyro_json = {{"error", error}};
      duts_json.push_back(std::move(j));
      continue;
    }
    const auto& c = r.protocol->counters();
    const DutFrame& f = r.frames.back();
    const std::vector<ChannelSpec>& channels = r.protocol->channels();
    nlohmann::json channels_json = nlohmann::json::array();
    for (std::size_t i = 0; i < channels.size(); ++i) {
      const ChannelSpec& ch = channels[i];
      channels_json.push_back({{"name", ch.name},
                               {"unit", ch.unit},
                               {"kind", std::string(to_string(ch.kind))},
                               {"axis", ch.axis},
                               {"value", physical_json(ch, f.raw[i])}});
      const bool primary = ch.kind == ChannelKind::kRate && ch.axis == dut.primary_axis;
      duts_text += fmt::format("  {:<16} {}{}\n", ch.name, channel_text(ch, f.raw[i]),
                               primary ? "  (primary axis)" : "");
    }
    duts_text += fmt::format("  seq {}; {} frames, {} CRC failures, {} bytes skipped\n", f.seq,
                             c.frames_ok, c.crc_failures, c.bytes_skipped);
    j["channels"] = std::move(channels_json);
    j["seq"] = f.seq;
    j["frames_ok"] = c.frames_ok;
    j["crc_failures"] = c.crc_failures;
    j["bytes_skipped"] = c.bytes_skipped;
    if (&r == &readings.front()) {
      gyro_json = {{"seq", f.seq}, {"frames_ok", c.frames_ok}, {"crc_failures", c.crc_failures}};
      for (std::size_t i = 0; i < channels.size(); ++i) {
        const ChannelSpec& ch = channels[i];
        const nlohmann::json value = physical_json(ch, f.raw[i]);
        if (ch.kind == ChannelKind::kRate && ch.axis == dut.primary_axis)
          gyro_json["rate_dph"] = value;
        if (ch.kind == ChannelKind::kStatus) gyro_json["status"] = value;
        if (ch.kind == ChannelKind::kTemperature) gyro_json["temp_c"] = value;
      }
    }
    duts_json.push_back(std::move(j));
  }
  if (json) {
    auto v = [](const Result<double>& r) {
      return r ? nlohmann::json(*r) : nlohmann::json({{"error", r.error().message}});
    };
    nlohmann::json out = {
        {"chamber",
         {{"endpoint", cfg->chamber.endpoint.describe()},
          {"process_value_c", v(pv)},
          {"setpoint_c", v(sp)}}},
        {"probes",
         {{"endpoint", cfg->probes.endpoint.describe()}, {"top_c", v(top)}, {"side_c", v(side)}}},
        {"duts", std::move(duts_json)},
        {"gyro", std::move(gyro_json)}};
    out["gyro"]["device"] = cfg->duts.front().link.serial.device;
    std::cout << out.dump(2) << "\n";
  } else {
    std::cout << fmt::format("chamber  {}\n  air temperature  {}\n  set point        {}\n",
                             cfg->chamber.endpoint.describe(), reading(pv, "°C"),
                             reading(sp, "°C"));
    std::cout << fmt::format("probes   {}\n  top              {}\n  side             {}\n",
                             cfg->probes.endpoint.describe(), reading(top, "°C"),
                             reading(side, "°C"));
    std::cout << duts_text;
  }
  return (pv && sp && top && side && duts_ok) ? 0 : 1;
}

int cmd_chamber_setpoint(const std::string& config_path, double setpoint_c) {
  if (!std::isfinite(setpoint_c)) {
    return fail(fmt::format("{} is not a temperature", setpoint_c), 2);
  }
  auto cfg = load_config_for_tools(config_path);
  if (!cfg) return fail(cfg.error().message, 2);
  std::optional<drivers::SerialPort> gyro_line;  // held so no daemon starts meanwhile
  std::string gyro_error;
  if (auto refused = refuse_if_station_owned(*cfg, gyro_line, gyro_error)) return *refused;
  if (setpoint_c < cfg->station.min_temp_c || setpoint_c > cfg->station.max_temp_c) {
    return fail(fmt::format("{:g} °C is outside the station's limits [{:g}, {:g}] °C", setpoint_c,
                            cfg->station.min_temp_c, cfg->station.max_temp_c),
                2);
  }
  drivers::ModbusChamber chamber(cfg->chamber.endpoint, cfg->chamber.map);
  const auto unit = chamber_unit(chamber);
  if (!unit) return fail(unit.error().message);
  if (auto st = chamber.write_setpoint(drivers::from_celsius(setpoint_c, *unit)); !st) {
    return fail(st.error().message);
  }
  auto back = chamber_c(chamber.setpoint(), *unit);
  if (!back) return fail(back.error().message);
  std::cout << fmt::format("chamber set point {:.2f} °C\n", *back);
  return 0;
}

// ---------------------------------------------------------------- table
// Commissioning of the rate table ([table]; docs/table.md): one reading, or
// one demand, straight to the controller.
std::string table_endpoint(const drivers::TableConnection& c) {
  // The link as [table] transport chose it: either protocol on either.
  const std::string link = drivers::table_transport(c) == "serial"
                               ? fmt::format("{} ({} baud)", c.device, c.baud)
                               : fmt::format("{}:{}", c.host, c.port);
  if (c.profile == "aero") return fmt::format("aero {}", link);
  return fmt::format("acutrol {} axis {} ({} replies)", link, c.axis, c.reply_header);
}

// `table reset` on a station gyrothermd runs: the daemon resets the fault
// (POST /api/v1/control/table-reset), so the commissioning commands' rule
// (stop the daemon first) does not apply to it.
int table_reset_through_daemon(const station::StationOwner& owner, const std::string& reason,
                               const std::string& token, bool json) {
  std::string url = owner.api_url;
  if (url.empty()) {
    return fail(fmt::format("the station is run by gyrothermd{}, whose station lock names no API "
                            "address yet; try again once it listens",
                            owner.pid > 0 ? fmt::format(" (pid {})", owner.pid) : std::string()),
                1);
  }
  while (!url.empty() && url.back() == '/') url.pop_back();
  const std::string body = reason.empty() ? "" : nlohmann::json({{"reason", reason}}).dump();
  auto res = cli::http_request("POST", url + "/api/v1/control/table-reset", body, token);
  if (!res) return fail(fmt::format("gyrothermd runs the station: {}", res.error().message));
  if (json && !res->body.empty()) std::cout << res->body << (res->body.back() == '\n' ? "" : "\n");
  if (res->status < 200 || res->status > 299) {
    return fail(cli::format_http_error(res->status, res->body, !token.empty(), token));
  }
  if (!json) {
    const auto j = nlohmann::json::parse(res->body, nullptr, false);
    const std::string message = j.is_object() && j.value("message", nlohmann::json()).is_string()
                                    ? j["message"].get<std::string>()
                                    : std::string("done");
    std::cout << fmt::format("through gyrothermd at {}: {}\n", url, message);
  }
  return 0;
}

int cmd_table(const std::string& config_path, const std::string& action, double value, bool json,
              const std::string& reason = "", const std::string& token = "") {
  if ((action == "rate" || action == "position") && !std::isfinite(value)) {
    return fail(fmt::format("{} is not a {}", value, action), 2);
  }
  auto cfg = load_config_for_tools(config_path);
  if (!cfg) return fail(cfg.error().message, 2);
  if (!cfg->table) {
    return fail(fmt::format("{}: no [table] section: this station has no rate table", config_path),
                2);
  }
  const config::TableSection& section = *cfg->table;
  if (action == "rate" && std::fabs(value) > section.max_rate_dps) {
    return fail(fmt::format("{:g} °/s is beyond the station's table limit ±{:g} °/s ([table] "
                            "max_rate_dps in {})",
                            value, section.max_rate_dps, config_path),
                2);
  }
  if (action == "reset") {
    if (const auto owner = station::station_owner(cfg->storage.db_path)) {
      return table_reset_through_daemon(*owner, reason, token, json);
    }
  }
  std::optional<drivers::SerialPort> gyro_line;  // held so no daemon starts meanwhile
  std::string gyro_error;
  if (auto refused = refuse_if_station_owned(*cfg, gyro_line, gyro_error)) return *refused;
  auto made = drivers::make_rate_table(
      section.connection,
      drivers::TableLimits{section.max_rate_dps, section.max_accel_dps2, std::nullopt}, "table");
  if (!made) return fail(made.error().message, 2);
  drivers::RateTable& table = **made;
  const std::string where = table_endpoint(section.connection);
  if (auto st = table.connect(); !st) return fail(fmt::format("{}: {}", where, st.error().message));

  Status done;
  if (action == "rate") done = table.set_rate(value);
  if (action == "position") done = table.set_position(value);
  if (action == "stop") done = table.stop();
  if (action == "reset") done = table.reset_faults();
  if (!done) return fail(fmt::format("{}: {}", where, done.error().message));

  const auto state = table.read();
  const auto limits = table.limits();
  if (json) {
    nlohmann::json out = {{"device", where}, {"action", action}};
    if (state) {
      out["mode"] = std::string(drivers::to_string(state->mode));
      out["mode_text"] = state->mode_text;
      out["interlock"] = std::string(drivers::to_string(state->interlock));
      out["rate_dps"] = state->rate_dps;
      out["position_deg"] = state->position_deg;
      out["fault"] = state->fault;
    } else {
      out["error"] = state.error().message;
    }
    if (limits) {
      out["limits"] = {
          {"max_rate_dps", limits->max_rate_dps},
          {"max_accel_dps2", limits->max_accel_dps2},
          {"trip_rate_dps", limits->trip_rate_dps ? nlohmann::json(*limits->trip_rate_dps)
                                                  : nlohmann::json(nullptr)}};
    } else {
      out["limits"] = {{"error", limits.error().message}};
    }
    out["station_limits"] = {{"max_rate_dps", section.max_rate_dps},
                             {"max_accel_dps2", section.max_accel_dps2}};
    std::cout << out.dump(2) << "\n";
  } else {
    if (action == "rate") std::cout << fmt::format("table rate demand {:g} °/s sent\n", value);
    if (action == "position") std::cout << fmt::format("table position demand {:g}° sent\n", value);
    if (action == "stop") std::cout << "table stop sent (decelerates to rest, stays servoed)\n";
    if (action == "reset") std::cout << "table fault reset sent\n";
    std::cout << fmt::format("table    {}\n", where);
    if (state) {
      std::cout << fmt::format(
          "  mode             {} ({})\n  interlock        {}\n  rate             {:.4f} °/s\n"
          "  position         {:.4f}°\n",
          drivers::to_string(state->mode), state->mode_text, drivers::to_string(state->interlock),
          state->rate_dps, state->position_deg);
      if (!state->fault.empty()) std::cout << fmt::format("  fault            {}\n", state->fault);
    } else {
      std::cout << fmt::format("  ERROR: {}\n", state.error().message);
    }
    if (limits) {
      std::cout << fmt::format(
          "  limits           rate {:g} °/s, acceleration {:g} °/s², trip {}\n",
          limits->max_rate_dps, limits->max_accel_dps2,
          limits->trip_rate_dps ? fmt::format("{:g} °/s", *limits->trip_rate_dps)
                                : std::string("not reported"));
    } else {
      std::cout << fmt::format("  limits           ERROR: {}\n", limits.error().message);
    }
    std::cout << fmt::format("  station limits   rate {:g} °/s, acceleration {:g} °/s² ([table])\n",
                             section.max_rate_dps, section.max_accel_dps2);
  }
  return (state && limits) ? 0 : 1;
}

int cmd_schedule_check(const std::string& config_path, const std::string& schedule_path,
                       const std::string& db_path, bool json) {
  // Without a station config: the default limits (no rate table) and a run
  // starting from the default safe set point.
  schedules::StationLimits limits;
  double start_setpoint_c = config::StationSection{}.safe_setpoint_c;
  if (!config_path.empty()) {
    auto cfg = config::load_station_config(config_path);
    if (!cfg) return fail("bad station config:\n" + cfg.error().message, 2);
    limits = config::station_limits(*cfg);
    start_setpoint_c = cfg->station.safe_setpoint_c;
  }
  auto plan = schedules::load_schedule(schedule_path, limits);
  if (!plan) {
    if (json) {
      // The report ends with "... and N more errors" when it was cut.
      nlohmann::json errors = nlohmann::json::array();
      int64_t more = 0;
      std::istringstream ss(plan.error().message);
      for (std::string line; std::getline(ss, line);) {
        if (std::sscanf(line.c_str(), "... and %" SCNd64 " more error", &more) == 1) continue;
        errors.push_back(line);
      }
      std::cout
          << nlohmann::json({{"ok", false}, {"errors", errors}, {"more_errors", more}}).dump(2)
          << "\n";
      return 1;
    }
    return fail("schedule refused:\n" + plan.error().message, 1);
  }
  // A queued run starts where the previous one left the chamber: the safe
  // set point (docs/schedules.md, "Planned duration and progress").
  const schedules::PlannedDuration planned = schedules::planned_duration(*plan, start_setpoint_c);
  // --db: the station's own past settles stand for this schedule's
  // (schedules::settle_prior, as the daemon's ETA takes them).
  std::optional<schedules::SettlePrior> prior;
  std::size_t past_settles = 0;
  if (!db_path.empty()) {
    auto db = storage::Database::open_read_only(db_path);
    if (!db) return fail(db.error().message, 2);
    auto settles = db->recent_settles_s(schedules::kMaxPriorSettles);
    if (!settles) return fail(settles.error().message, 2);
    past_settles = settles->size();
    prior = schedules::settle_prior(std::move(*settles));
  }
  const auto with_prior = [&](double settle_s) {
    return planned.fixed_s + planned.settles * settle_s;
  };
  if (json) {
    nlohmann::json estimate = nullptr;
    if (prior && planned.settles > 0) {
      estimate = {{"prior_settles", prior->settles},
                  {"eta_s", with_prior(prior->p50_s)},
                  {"eta_p10_s", with_prior(prior->p10_s)},
                  {"eta_p90_s", with_prior(prior->p90_s)}};
    }
    nlohmann::json steps = nlohmann::json::array();
    for (const auto& s : plan->steps) steps.push_back(s.label);
    std::cout << nlohmann::json({{"ok", true},
                                 {"name", plan->name},
                                 {"steps", steps},
                                 {"planned",
                                  {{"fixed_s", planned.fixed_s},
                                   {"settles", planned.settles},
                                   {"start_setpoint_c", start_setpoint_c},
                                   {"text", schedules::format_planned(planned)},
                                   {"with_past_settles", estimate}}}})
                     .dump(2)
              << "\n";
    return 0;
  }
  std::cout << fmt::format("{}: ok, {} step{}\n", plan->name, plan->steps.size(),
                           plan->steps.size() == 1 ? "" : "s");
  for (const auto& s : plan->steps) std::cout << "  " << s.label << "\n";
  std::cout << fmt::format("planned duration: {}\n", schedules::format_planned(planned));
  if (!db_path.empty() && planned.settles > 0) {
    if (prior) {
      std::cout << fmt::format("with the station's last {} settles: ~{} (P10 {} – P90 {})\n",
                               prior->settles, schedules::format_duration(with_prior(prior->p50_s)),
                               schedules::format_duration(with_prior(prior->p10_s)),
                               schedules::format_duration(with_prior(prior->p90_s)));
    } else {
      std::cout << fmt::format(
          "the database holds {} settle{} without a pause; {} are needed to estimate them\n",
          past_settles, past_settles == 1 ? "" : "s", schedules::kMinPriorSettles);
    }
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"gyrotherm: FOG thermal test station tool"};
  app.require_subcommand(1);
  bool json = false;
  app.add_flag("--json", json, "machine-readable output");

  auto* decode = app.add_subcommand("decode", "decode a raw serial capture to CSV");
  std::string protocol = "kvh1750", capture, decode_config, decode_dut;
  decode->add_option("--protocol", protocol, "frame protocol")
      ->check(CLI::IsMember({"kvh1750", "ascii"}));
  decode->add_option("--config", decode_config,
                     "station config whose [[dut]] --dut made the capture (required for ascii)");
  decode->add_option("--dut", decode_dut, "the DUT's serial number (with --config)");
  decode->add_option("file", capture, "capture file (default, or -: standard input)");
  decode->add_flag("--json", json);

  auto* devices = app.add_subcommand("devices", "one live reading of every device");
  std::string config_path;
  devices->add_option("--config", config_path, "station config")->required();
  devices->add_flag("--json", json);

  auto* chamber = app.add_subcommand("chamber", "chamber commissioning");
  chamber->require_subcommand(1);
  auto* set_point = chamber->add_subcommand("set-point", "write the chamber set point (°C)");
  double setpoint_c = 0;
  set_point->add_option("celsius", setpoint_c, "set point, °C")->required();
  set_point->add_option("--config", config_path, "station config")->required();

  auto* table = app.add_subcommand("table", "rate table commissioning (docs/table.md)");
  table->require_subcommand(1);
  double table_value = 0;
  auto* table_status = table->add_subcommand("status", "mode, interlock, rate, position, limits");
  auto* table_rate = table->add_subcommand("rate", "spin at a rate (°/s, signed)");
  table_rate->add_option("dps", table_value, "rate, °/s")->required();
  auto* table_position = table->add_subcommand("position", "move to and hold a position (°)");
  table_position->add_option("deg", table_value, "position, °")->required();
  auto* table_stop = table->add_subcommand("stop", "decelerate to rest (stays servoed)");
  auto* table_reset = table->add_subcommand(
      "reset", "clear a latched fault (through gyrothermd when it runs the station)");
  std::string table_reason;
  std::string table_token;
  if (const char* env = std::getenv("GYROTHERM_TOKEN"); env) table_token = env;
  table_reset->add_option("--reason", table_reason, "text for the event log (through gyrothermd)");
  table_reset->add_option("--token", table_token,
                          "API token, when gyrothermd runs the station (env GYROTHERM_TOKEN)");
  for (auto* sub : {table_status, table_rate, table_position, table_stop, table_reset}) {
    sub->add_option("--config", config_path, "station config")->required();
    sub->add_flag("--json", json);
  }

  auto* schedule = app.add_subcommand("schedule", "schedule files");
  schedule->require_subcommand(1);
  auto* check = schedule->add_subcommand("check", "validate a schedule against a station");
  std::string schedule_path;
  check->add_option("file", schedule_path, "schedule file")->required();
  check->add_option("--config", config_path,
                    "station config (limits, table, safe set point); default limits without");
  std::string check_db_path;
  check->add_option("--db", check_db_path,
                    "station database: estimate the settles from its past soaks");
  check->add_flag("--json", json);

  auto* samples = app.add_subcommand("samples", "a run's exact samples as CSV (docs/storage.md)");
  gyrotherm::cli::SamplesArgs samples_args;
  double samples_from_s = 0, samples_to_s = 0;
  samples->add_option("--db", samples_args.db_path, "station database")->required();
  samples->add_option("--run", samples_args.run_id, "run id")->required();
  samples->add_option("--dut", samples_args.dut_serial, "DUT serial (default: the run's first)");
  samples->add_option("--channel", samples_args.channel, "one channel (default: all)");
  auto* samples_from = samples->add_option("--from", samples_from_s, "from, station s (inclusive)");
  auto* samples_to = samples->add_option("--to", samples_to_s, "to, station s (exclusive)");

  // status, queue add|list|remove|move, pause, resume, abort, stop, runs, run
  gyrotherm::cli::ControlCommands control(app);
  // stats, allan, fit, compare, start-model
  gyrotherm::cli::AnalysisCommands analysis(app);
  // export
  gyrotherm::cli::ExportCommand export_command(app);
  // lab stations|runs|run|dut|summary|migrate|add-station|add-reader
  gyrotherm::cli::LabCommands lab_commands(app);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // CLI11 echoes unexpected arguments, which may hold a token or a lab
    // URL's password.
    std::ostringstream out, err;
    const int code = app.exit(e, out, err);
    const std::vector<std::string> args(argv + 1, argv + argc);
    std::cout << out.str();
    std::cerr << gyrotherm::cli::redact_lab_passwords(
        gyrotherm::cli::redact_tokens(err.str(), args), args);
    return code == 0 ? 0 : 2;  // --help is not an error; usage errors exit 2
  }
  try {
    if (*decode) return cmd_decode(protocol, capture, decode_config, decode_dut, json);
    if (*devices) return cmd_devices(config_path, json);
    if (*set_point) return cmd_chamber_setpoint(config_path, setpoint_c);
    if (*check) return cmd_schedule_check(config_path, schedule_path, check_db_path, json);
    if (*samples) {
      if (*samples_from) samples_args.from_s = samples_from_s;
      if (*samples_to) samples_args.to_s = samples_to_s;
      return gyrotherm::cli::cmd_samples(samples_args, std::cout);
    }
    if (*table) {
      const char* action = *table_status     ? "status"
                           : *table_rate     ? "rate"
                           : *table_position ? "position"
                           : *table_reset    ? "reset"
                                             : "stop";
      return cmd_table(config_path, action, table_value, json, table_reason, table_token);
    }
    if (auto code = control.run(json)) return *code;
    if (auto code = analysis.run(json)) return *code;
    if (auto code = export_command.run(json)) return *code;
    if (auto code = lab_commands.run(json)) return *code;
  } catch (const std::exception& e) {
    return fail(e.what());
  }
  return 0;
}
