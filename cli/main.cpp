// gyrotherm: the command-line tool. Daemon control over REST, offline
// analysis on a database or CSV files (analysis.h), a capture-file decoder,
// and commissioning on a station config.
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>

#include "analysis.h"
#include "control.h"
#include "export.h"
#include "gyrotherm/daemon/config.h"
#include "gyrotherm/daemon/station_lock.h"
#include "gyrotherm/drivers/frame_parser.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/drivers/modbus_devices.h"
#include "gyrotherm/drivers/rate_tables.h"
#include "gyrotherm/drivers/serial_port.h"
#include "gyrotherm/schedules/schedule.h"
#include "output.h"
#include "samples.h"

namespace {

using namespace gyrotherm;

using cli::fail;

// ---------------------------------------------------------------- decode
int cmd_decode(const std::string& protocol, const std::string& path, bool json) {
  auto parser = drivers::make_frame_parser(protocol);
  if (!parser) return fail(parser.error().message, 2);
  std::ifstream in(path, std::ios::binary);
  if (!in) return fail(fmt::format("{}: cannot open", path), 2);
  std::printf("seq,status,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z,temp_c\n");
  std::vector<uint8_t> buf(1 << 16);
  std::vector<drivers::GyroFrame> frames;
  while (in) {
    in.read(reinterpret_cast<char*>(buf.data()), static_cast<std::streamsize>(buf.size()));
    const auto n = static_cast<std::size_t>(in.gcount());
    if (n == 0) break;
    frames.clear();
    (*parser)->feed(std::span<const uint8_t>(buf.data(), n), frames);
    for (const auto& f : frames) {
      std::printf("%u,%u,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%d\n", f.seq, f.status, f.gyro[0], f.gyro[1],
                  f.gyro[2], f.accel[0], f.accel[1], f.accel[2], f.temp_c);
    }
  }
  const auto& c = (*parser)->counters();
  if (json) {
    // The summary as one JSON object on stderr; the frames stay CSV on stdout.
    std::cerr << nlohmann::json({{"file", path},
                                 {"frames_ok", c.frames_ok},
                                 {"crc_failures", c.crc_failures},
                                 {"bytes_skipped", c.bytes_skipped},
                                 {"sequence_gaps", c.sequence_gaps},
                                 {"frames_missed", c.frames_missed}})
                     .dump()
              << "\n";
    return 0;
  }
  std::fprintf(stderr,
               "%s: %llu valid frames, %llu CRC failures, %llu bytes skipped, %llu sequence gaps "
               "(%llu frames missed)\n",
               path.c_str(), static_cast<unsigned long long>(c.frames_ok),
               static_cast<unsigned long long>(c.crc_failures),
               static_cast<unsigned long long>(c.bytes_skipped),
               static_cast<unsigned long long>(c.sequence_gaps),
               static_cast<unsigned long long>(c.frames_missed));
  return 0;
}

// ---------------------------------------------------------------- station config helpers
Result<daemon::StationConfig> load_config_for_tools(const std::string& path) {
  auto cfg = daemon::load_station_config(path);
  if (!cfg) return cfg;
  if (!cfg->simulator.endpoints_file.empty()) {
    auto ep = daemon::read_sim_endpoints(cfg->simulator.endpoints_file);
    if (!ep) {
      return Error::Transient(
          fmt::format("{}: simulator endpoints not readable (is gyrotherm-sim "
                      "running?): {}",
                      cfg->simulator.endpoints_file, ep.error().message));
    }
    daemon::apply_sim_endpoints(*cfg, *ep);
  }
  return cfg;
}

// Commissioning talks to the devices directly, so it needs the station to
// itself: nullopt when it has it, else the exit code after saying who owns
// it. A daemon holds the station lock beside its database; a daemon started
// on another database (--db) is still caught by the gyro line's lock, which
// `gyro_port` tries to take (it is kept open, held, until the command ends).
std::optional<int> refuse_if_station_owned(const daemon::StationConfig& cfg,
                                           std::optional<drivers::SerialPort>& gyro_port,
                                           std::string& gyro_error) {
  if (const auto owner = daemon::station_owner(cfg.storage.db_path)) {
    std::string who = "gyrothermd";
    if (owner->pid > 0) who += fmt::format(" (pid {})", owner->pid);
    const std::string api = owner->api_url.empty() ? "" : fmt::format(" at {}", owner->api_url);
    return fail(
        fmt::format("the station is run by {}{} (station lock {}); commissioning commands talk to "
                    "the devices directly and would disturb it. Use `gyrotherm status` for live "
                    "readings and the queue for set points, or stop the daemon first.",
                    who, api, daemon::station_lock_path(cfg.storage.db_path)),
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

int cmd_devices(const std::string& config_path, bool json) {
  auto cfg = load_config_for_tools(config_path);
  if (!cfg) return fail(cfg.error().message, 2);
  std::optional<drivers::SerialPort> port;
  std::string gyro_error;
  if (auto refused = refuse_if_station_owned(*cfg, port, gyro_error)) return *refused;
  drivers::ModbusChamber chamber(cfg->chamber.endpoint, cfg->chamber.map);
  drivers::ModbusProbes probes(cfg->probes.endpoint, cfg->probes.top, cfg->probes.side);
  const auto unit = chamber_unit(chamber);
  const Result<double> pv = unit ? chamber_c(chamber.process_value(), *unit) : unit.error();
  const Result<double> sp = unit ? chamber_c(chamber.setpoint(), *unit) : unit.error();
  const auto top = probes.top_c();
  const auto side = probes.side_c();

  // Gyro: listen for up to two seconds (wall).
  std::string gyro_text;
  nlohmann::json gyro_json;
  bool gyro_ok = false;
  if (!port) {
    gyro_text = "ERROR: " + gyro_error;
    gyro_json = {{"error", gyro_error}};
  } else {
    auto parser = drivers::make_frame_parser(cfg->gyro.protocol);
    std::vector<uint8_t> buf(4096);
    std::vector<drivers::GyroFrame> frames;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(2);
    while (std::chrono::steady_clock::now() < deadline && frames.size() < 20) {
      auto n = port->read(buf, std::chrono::milliseconds(100));
      if (!n) break;
      (*parser)->feed(std::span<const uint8_t>(buf.data(), *n), frames);
    }
    const auto& c = (*parser)->counters();
    if (frames.empty()) {
      gyro_text = fmt::format("no valid frame in 2 s ({} CRC failures, {} bytes skipped)",
                              c.crc_failures, c.bytes_skipped);
      gyro_json = {{"error", gyro_text}};
    } else {
      const auto& f = frames.back();
      const double rate = drivers::to_rate_dph(
          f.gyro[static_cast<std::size_t>(cfg->gyro.format.axis)], cfg->gyro.format);
      gyro_text = fmt::format(
          "{:.3f} °/h (axis {}), seq {}, status 0x{:02x}, {} °C; {} frames, {} "
          "CRC failures",
          rate, static_cast<char>('x' + cfg->gyro.format.axis), f.seq, f.status, f.temp_c,
          c.frames_ok, c.crc_failures);
      gyro_ok = true;
      gyro_json = {{"rate_dph", rate},         {"seq", f.seq},
                   {"status", f.status},       {"temp_c", f.temp_c},
                   {"frames_ok", c.frames_ok}, {"crc_failures", c.crc_failures}};
    }
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
        {"gyro", gyro_json}};
    out["gyro"]["device"] = cfg->gyro.serial.device;
    std::cout << out.dump(2) << "\n";
  } else {
    std::cout << fmt::format("chamber  {}\n  air temperature  {}\n  set point        {}\n",
                             cfg->chamber.endpoint.describe(), reading(pv, "°C"),
                             reading(sp, "°C"));
    std::cout << fmt::format("probes   {}\n  top              {}\n  side             {}\n",
                             cfg->probes.endpoint.describe(), reading(top, "°C"),
                             reading(side, "°C"));
    std::cout << fmt::format("gyro     {}\n  {}\n", cfg->gyro.serial.device, gyro_text);
  }
  return (pv && sp && top && side && gyro_ok) ? 0 : 1;
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
  if (c.profile == "aero") return fmt::format("aero {} ({} baud)", c.device, c.baud);
  return fmt::format("acutrol {}:{} axis {} ({} replies)", c.host, c.port, c.axis, c.reply_header);
}

int cmd_table(const std::string& config_path, const std::string& action, double value, bool json) {
  if ((action == "rate" || action == "position") && !std::isfinite(value)) {
    return fail(fmt::format("{} is not a {}", value, action), 2);
  }
  auto cfg = load_config_for_tools(config_path);
  if (!cfg) return fail(cfg.error().message, 2);
  if (!cfg->table) {
    return fail(fmt::format("{}: no [table] section: this station has no rate table", config_path),
                2);
  }
  const daemon::TableSection& section = *cfg->table;
  if (action == "rate" && std::fabs(value) > section.max_rate_dps) {
    return fail(fmt::format("{:g} °/s is beyond the station's table limit ±{:g} °/s ([table] "
                            "max_rate_dps in {})",
                            value, section.max_rate_dps, config_path),
                2);
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
                       bool json) {
  auto cfg = daemon::load_station_config(config_path);
  if (!cfg) return fail("bad station config:\n" + cfg.error().message, 2);
  auto plan = schedules::load_schedule(schedule_path, daemon::station_limits(*cfg));
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
  if (json) {
    nlohmann::json steps = nlohmann::json::array();
    for (const auto& s : plan->steps) steps.push_back(s.label);
    std::cout << nlohmann::json({{"ok", true}, {"name", plan->name}, {"steps", steps}}).dump(2)
              << "\n";
    return 0;
  }
  std::cout << fmt::format("{}: ok, {} step{}\n", plan->name, plan->steps.size(),
                           plan->steps.size() == 1 ? "" : "s");
  for (const auto& s : plan->steps) std::cout << "  " << s.label << "\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"gyrotherm: FOG thermal test station tool"};
  app.require_subcommand(1);
  bool json = false;
  app.add_flag("--json", json, "machine-readable output");

  auto* decode = app.add_subcommand("decode", "decode a raw serial capture to CSV");
  std::string protocol = "kvh1750", capture;
  decode->add_option("--protocol", protocol, "frame protocol")->check(CLI::IsMember({"kvh1750"}));
  decode->add_option("file", capture, "capture file")->required();
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
  for (auto* sub : {table_status, table_rate, table_position, table_stop}) {
    sub->add_option("--config", config_path, "station config")->required();
    sub->add_flag("--json", json);
  }

  auto* schedule = app.add_subcommand("schedule", "schedule files");
  schedule->require_subcommand(1);
  auto* check = schedule->add_subcommand("check", "validate a schedule against a station");
  std::string schedule_path;
  check->add_option("file", schedule_path, "schedule file")->required();
  check->add_option("--config", config_path, "station config")->required();
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

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // CLI11 echoes unexpected arguments, which may hold a token.
    std::ostringstream out, err;
    const int code = app.exit(e, out, err);
    const std::vector<std::string> args(argv + 1, argv + argc);
    std::cout << out.str();
    std::cerr << gyrotherm::cli::redact_tokens(err.str(), args);
    return code == 0 ? 0 : 2;  // --help is not an error; usage errors exit 2
  }
  try {
    if (*decode) return cmd_decode(protocol, capture, json);
    if (*devices) return cmd_devices(config_path, json);
    if (*set_point) return cmd_chamber_setpoint(config_path, setpoint_c);
    if (*check) return cmd_schedule_check(config_path, schedule_path, json);
    if (*samples) {
      if (*samples_from) samples_args.from_s = samples_from_s;
      if (*samples_to) samples_args.to_s = samples_to_s;
      return gyrotherm::cli::cmd_samples(samples_args, std::cout);
    }
    if (*table) {
      const char* action = *table_status     ? "status"
                           : *table_rate     ? "rate"
                           : *table_position ? "position"
                                             : "stop";
      return cmd_table(config_path, action, table_value, json);
    }
    if (auto code = control.run(json)) return *code;
    if (auto code = analysis.run(json)) return *code;
    if (auto code = export_command.run(json)) return *code;
  } catch (const std::exception& e) {
    return fail(e.what());
  }
  return 0;
}
