#include "gyrotherm/sim/control_server.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "gyrotherm/sim/options.h"

namespace gyrotherm::sim {
namespace {

using Kind = ControlCommand::Kind;

std::string errno_text(int error) { return std::strerror(error); }

// A word of the client's line, safe to quote in a reply: printable ASCII,
// at most 32 characters.
std::string quoted(std::string_view word) {
  std::string out;
  for (char c : word.substr(0, 32)) out += (c >= 0x20 && c < 0x7f) ? c : '?';
  if (word.size() > 32) out += "...";
  return "'" + out + "'";
}

class Words {
 public:
  explicit Words(std::string_view line) {
    std::size_t i = 0;
    while (i < line.size()) {
      while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
      const std::size_t start = i;
      while (i < line.size() && line[i] != ' ' && line[i] != '\t') ++i;
      if (i > start) words_.push_back(line.substr(start, i - start));
    }
  }
  bool empty() const { return words_.empty(); }
  std::size_t size() const { return words_.size(); }
  std::string_view operator[](std::size_t i) const { return words_[i]; }

 private:
  std::vector<std::string_view> words_;
};

Error bad(std::string message) { return Error::Permanent(std::move(message)); }

// `words` must be exactly `n` long; `name` is the command so far.
std::optional<Error> expect_count(const Words& words, std::size_t n, std::string_view name) {
  if (words.size() > n) {
    return bad(fmt::format("unexpected {} after '{}'", quoted(words[n]), name));
  }
  return std::nullopt;
}

// words[i] as a number in [lo, hi]; `what` describes the value for a
// missing one.
Result<double> number_at(const Words& words, std::size_t i, std::string_view name,
                         std::string_view what, double lo, double hi, std::size_t words_after = 0) {
  if (words.size() <= i) return bad(fmt::format("'{}' needs a value: {}", name, what));
  const std::string_view w = words[i];
  double v = 0;
  const auto [end, ec] = std::from_chars(w.data(), w.data() + w.size(), v);
  if (ec != std::errc() || end != w.data() + w.size() || !std::isfinite(v)) {
    return bad(fmt::format("'{}': {} is not a number", name, quoted(w)));
  }
  if (v < lo || v > hi) {
    return bad(fmt::format("'{}': {} is outside [{}, {}]", name, w, lo, hi));
  }
  if (auto e = expect_count(words, i + 1 + words_after, fmt::format("{} {}", name, w))) return *e;
  return v;
}

Result<ControlCommand> simple(const Words& words, std::size_t n, std::string_view name, Kind kind) {
  if (auto e = expect_count(words, n, name)) return *e;
  return ControlCommand{kind, 0, ProbeRole::kTop};
}

Result<ControlCommand> with_value(Result<double> v, Kind kind) {
  if (!v.ok()) return v.error();
  return ControlCommand{kind, *v, ProbeRole::kTop};
}

Result<ControlCommand> parse_modbus(const Words& w) {
  const std::string_view sub = w.size() > 1 ? w[1] : "";
  if (sub == "down") return simple(w, 2, "modbus down", Kind::kModbusDown);
  if (sub == "up") return simple(w, 2, "modbus up", Kind::kModbusUp);
  if (sub == "delay") {
    return with_value(
        number_at(w, 2, "modbus delay", "WALL_S (wall seconds, 0 = none)", 0, kMaxModbusDelayS),
        Kind::kModbusDelay);
  }
  if (sub.empty()) return bad("'modbus' needs one of: down, up, delay WALL_S");
  return bad(fmt::format("unknown 'modbus' subcommand {}; expected down, up or delay WALL_S",
                         quoted(sub)));
}

// words[i], when there, is the DUT's serial and the last word.
Result<ControlCommand> for_dut(Result<ControlCommand> c, const Words& w, std::size_t i,
                               std::string_view name) {
  if (!c.ok() || w.size() <= i) return c;
  if (auto e = expect_count(w, i + 1, fmt::format("{} {}", name, w[i]))) return *e;
  c->dut = std::string(w[i]);
  c->dut_given = true;
  return c;
}

std::optional<Kind> line_kind(std::string_view sub) {
  if (sub == "close") return Kind::kPtyClose;
  if (sub == "reopen") return Kind::kPtyReopen;
  if (sub == "hold") return Kind::kPtyHold;
  if (sub == "release") return Kind::kPtyRelease;
  return std::nullopt;
}

// pty close|reopen|hold|release [SN]
Result<ControlCommand> parse_pty(const Words& w) {
  const std::string_view sub = w.size() > 1 ? w[1] : "";
  if (auto kind = line_kind(sub)) {
    const std::string name = fmt::format("pty {}", sub);
    return for_dut(ControlCommand{*kind, 0, ProbeRole::kTop}, w, 2, name);
  }
  if (sub.empty()) return bad("'pty' needs one of: close, reopen, hold, release");
  return bad(fmt::format("unknown 'pty' subcommand {}; expected close, reopen, hold or release",
                         quoted(sub)));
}

// frames corrupt|drop P [SN]
Result<ControlCommand> parse_frames(const Words& w) {
  const std::string_view sub = w.size() > 1 ? w[1] : "";
  if (sub == "corrupt" || sub == "drop") {
    const std::string name = fmt::format("frames {}", sub);
    const Kind kind = sub == "corrupt" ? Kind::kFramesCorrupt : Kind::kFramesDrop;
    auto v = number_at(w, 2, name, "P (probability, 0..1)", 0, 1, /*words_after=*/1);
    if (!v.ok()) return v.error();
    return for_dut(ControlCommand{kind, *v, ProbeRole::kTop}, w, 3,
                   fmt::format("{} {}", name, w[2]));
  }
  if (sub.empty()) return bad("'frames' needs one of: corrupt P, drop P");
  return bad(
      fmt::format("unknown 'frames' subcommand {}; expected corrupt P or drop P", quoted(sub)));
}

// gyro close|reopen|hold|release [SN]; gyro corrupt|drop [SN] P
Result<ControlCommand> parse_gyro(const Words& w) {
  const std::string_view sub = w.size() > 1 ? w[1] : "";
  if (auto kind = line_kind(sub)) {
    return for_dut(ControlCommand{*kind, 0, ProbeRole::kTop}, w, 2, fmt::format("gyro {}", sub));
  }
  if (sub == "corrupt" || sub == "drop") {
    const std::string name = fmt::format("gyro {}", sub);
    const Kind kind = sub == "corrupt" ? Kind::kFramesCorrupt : Kind::kFramesDrop;
    // Two words after the subcommand: the serial, then P.
    const bool with_serial = w.size() > 3;
    auto v =
        number_at(w, with_serial ? 3 : 2, with_serial ? fmt::format("{} {}", name, w[2]) : name,
                  "P (probability, 0..1)", 0, 1);
    if (!v.ok()) return v.error();
    ControlCommand c{kind, *v, ProbeRole::kTop};
    if (with_serial) {
      c.dut = std::string(w[2]);
      c.dut_given = true;
    }
    return c;
  }
  if (sub.empty()) {
    return bad(
        "'gyro' needs one of: close, reopen, hold, release [SN], corrupt [SN] P, "
        "drop [SN] P");
  }
  return bad(fmt::format(
      "unknown 'gyro' subcommand {}; expected close, reopen, hold, release, corrupt or drop",
      quoted(sub)));
}

Result<ControlCommand> parse_probe(const Words& w) {
  const std::string_view sub = w.size() > 1 ? w[1] : "";
  Kind kind;
  if (sub == "stall") {
    kind = Kind::kProbeStall;
  } else if (sub == "release") {
    kind = Kind::kProbeRelease;
  } else if (sub.empty()) {
    return bad("'probe' needs one of: stall top|side [SN], release top|side [SN]");
  } else {
    return bad(
        fmt::format("unknown 'probe' subcommand {}; expected stall or release", quoted(sub)));
  }
  const std::string name = fmt::format("probe {}", sub);
  if (w.size() < 3) return bad(fmt::format("'{}' needs a probe: top or side", name));
  ProbeRole role;
  if (w[2] == "top") {
    role = ProbeRole::kTop;
  } else if (w[2] == "side") {
    role = ProbeRole::kSide;
  } else {
    return bad(fmt::format("'{}': unknown probe {}; expected top or side", name, quoted(w[2])));
  }
  // probe stall|release top|side [SN]: SN's own probe, else the station's.
  return for_dut(ControlCommand{kind, 0, role}, w, 3, fmt::format("{} {}", name, w[2]));
}

Result<ControlCommand> parse_chamber(const Words& w) {
  const std::string_view sub = w.size() > 1 ? w[1] : "";
  if (sub == "alarm") {
    if (w.size() < 3) return bad("'chamber alarm' needs on or off");
    if (w[2] == "on") return simple(w, 3, "chamber alarm on", Kind::kChamberAlarmOn);
    if (w[2] == "off") return simple(w, 3, "chamber alarm off", Kind::kChamberAlarmOff);
    return bad(fmt::format("'chamber alarm': expected on or off, got {}", quoted(w[2])));
  }
  if (sub == "force") {
    return with_value(
        number_at(w, 2, "chamber force", "TEMP_C (°C)", kMinForcedChamberC, kMaxForcedChamberC),
        Kind::kChamberForce);
  }
  if (sub == "release") return simple(w, 2, "chamber release", Kind::kChamberRelease);
  if (sub == "units") {
    if (w.size() < 3) return bad("'chamber units' needs c or f");
    if (w[2] == "c") return simple(w, 3, "chamber units c", Kind::kChamberUnitsC);
    if (w[2] == "f") return simple(w, 3, "chamber units f", Kind::kChamberUnitsF);
    return bad(fmt::format("'chamber units': expected c or f, got {}", quoted(w[2])));
  }
  if (sub.empty()) {
    return bad("'chamber' needs one of: alarm on|off, force TEMP_C, release, units c|f");
  }
  return bad(fmt::format(
      "unknown 'chamber' subcommand {}; expected alarm on|off, force TEMP_C, release or units c|f",
      quoted(sub)));
}

Result<ControlCommand> parse_table(const Words& w) {
  const std::string_view sub = w.size() > 1 ? w[1] : "";
  if (sub == "fault") return simple(w, 2, "table fault", Kind::kTableFault);
  if (sub == "hang") return simple(w, 2, "table hang", Kind::kTableHang);
  if (sub == "disconnect") return simple(w, 2, "table disconnect", Kind::kTableDisconnect);
  if (sub == "connect") return simple(w, 2, "table connect", Kind::kTableConnect);
  if (sub == "clear") return simple(w, 2, "table clear", Kind::kTableClear);
  if (sub == "status") return simple(w, 2, "table status", Kind::kTableStatus);
  constexpr const char* kChoices = "fault, hang, disconnect, connect, clear or status";
  if (sub.empty()) return bad(fmt::format("'table' needs one of: {}", kChoices));
  return bad(fmt::format("unknown 'table' subcommand {}; expected {}", quoted(sub), kChoices));
}

std::string_view mode_name(drivers::TableMode m) {
  switch (m) {
    case drivers::TableMode::kRate:
      return "rate";
    case drivers::TableMode::kPosition:
      return "position";
    case drivers::TableMode::kOff:
      return "off";
    default:
      return "unknown";
  }
}

std::string_view interlock_name(drivers::TableInterlock i) {
  switch (i) {
    case drivers::TableInterlock::kOpen:
      return "open";
    case drivers::TableInterlock::kClosed:
      return "closed";
    default:
      return "fault";
  }
}

nlohmann::ordered_json table_json(const TableStatus& t) {
  const TableModelState& s = t.state;
  nlohmann::ordered_json faults = nlohmann::ordered_json::array();
  if (s.interlock == drivers::TableInterlock::kFault) faults.push_back("interlock_fault");
  if (t.hung) faults.push_back("hang");
  if (t.disconnected) faults.push_back("disconnect");
  return {
      {"mode", mode_name(s.mode)},
      {"interlock", interlock_name(s.interlock)},
      {"rate_dps", s.rate_dps},
      {"measured_rate_dps", s.measured_rate_dps},
      {"accel_dps2", s.accel_dps2},
      {"position_deg", s.position_deg},
      {"demand", {{"rate_dps", s.rate_demand_dps}, {"position_deg", s.position_demand_deg}}},
      {"limits",
       {{"rate_dps", s.rate_limit_dps},
        {"accel_dps2", s.accel_limit_dps2},
        {"trip_rate_dps", s.trip_rate_dps}}},
      {"faults", faults},
      {"fault", s.fault},
      {"port", t.port},
      {"device", t.device},
      {"acl_device", t.acl_device},
      {"aero_port", t.aero_port},
      {"requests",
       {{"acl", t.acl_requests},
        {"acl_unanswered", t.acl_unanswered},
        {"acl_refused_connections", t.acl_refused_connections},
        {"aero", t.aero_requests},
        {"acl_serial", t.acl_serial_requests},
        {"aero_tcp", t.aero_tcp_requests}}},
  };
}

std::string ok_json(const nlohmann::ordered_json& j) { return "ok " + j.dump(); }

nlohmann::ordered_json optional_json(const std::optional<double>& v) {
  return v ? nlohmann::ordered_json(*v) : nlohmann::ordered_json(nullptr);
}

}  // namespace

const std::vector<ControlCommandHelp>& control_commands() {
  static const std::vector<ControlCommandHelp> commands = {
      {"modbus down", "close every Modbus connection and refuse new ones"},
      {"modbus up", "accept Modbus connections again"},
      {"modbus delay WALL_S", "answer every Modbus request WALL_S wall seconds late (0 = none)"},
      {"pty close", "hang up the gyro line; frames due while closed are dropped"},
      {"pty reopen", "open a new pty (new path; the gyro link and endpoints file follow)"},
      {"pty hold", "hold the gyro frames back (they queue; the line is quiet)"},
      {"pty release", "send the held frames as one backlog, then stream again"},
      {"frames corrupt P", "alter one byte after the CRC of each frame with probability P"},
      {"frames drop P", "skip each frame with probability P (the reader sees a sequence gap)"},
      {"gyro close|reopen|hold|release [SN]",
       "as pty ..., for the DUT with serial SN (default the first; pty ... SN works too)"},
      {"gyro corrupt|drop [SN] P",
       "as frames ..., for the DUT with serial SN (default the first; frames ... P SN too)"},
      {"probe stall top|side [SN]",
       "freeze the probe's register at its last value (SN: that DUT's own probe; default the "
       "station's)"},
      {"probe release top|side [SN]", "let a stalled probe read again (SN: that DUT's own)"},
      {"chamber alarm on|off", "raise or clear the chamber controller's alarm register"},
      {"table fault", "put the rate table's interlock in fault now (latched until :I:R)"},
      {"table hang", "the rate table answers no request (ACL or AERO); connections stay"},
      {"table disconnect",
       "close the table's ACL connections and refuse new ones, silence the AERO line"},
      {"table connect", "accept table connections again (after table disconnect)"},
      {"table clear", "end table hang and disconnect (a latched interlock fault stays)"},
      {"table status", "the rate table as JSON: mode, interlock, rate, position, demand, faults"},
      {"chamber units c|f",
       "serve the chamber's temperatures in °C or °F (and say so in its units register)"},
      {"chamber force TEMP_C",
       "runaway controller: drive the air to TEMP_C whatever the set point"},
      {"chamber release", "end 'chamber force': back to the requested set point"},
      {"status", "the simulator's state, faults in force and counters, as JSON"},
      {"help", "this list, as JSON"},
  };
  return commands;
}

Result<ControlCommand> parse_control_command(std::string_view line) {
  while (!line.empty() && (line.back() == '\r' || line.back() == '\n')) line.remove_suffix(1);
  const Words w(line);
  if (w.empty()) return bad("empty command; send 'help' for the list");
  const std::string_view first = w[0];
  if (first == "modbus") return parse_modbus(w);
  if (first == "pty") return parse_pty(w);
  if (first == "frames") return parse_frames(w);
  if (first == "gyro") return parse_gyro(w);
  if (first == "probe") return parse_probe(w);
  if (first == "chamber") return parse_chamber(w);
  if (first == "table") return parse_table(w);
  if (first == "status") return simple(w, 1, "status", Kind::kStatus);
  if (first == "help") return simple(w, 1, "help", Kind::kHelp);
  return bad(fmt::format("unknown command {}; send 'help' for the list", quoted(first)));
}

std::string status_json(const SimulatorStatus& s) {
  const SimulatorFaults& f = s.faults;
  nlohmann::ordered_json active = nlohmann::ordered_json::array();
  if (f.modbus_down) active.push_back("modbus_down");
  if (f.modbus_reply_delay_s > 0) active.push_back("modbus_delay");
  if (s.running && !f.pty_open) active.push_back("pty_closed");
  if (f.pty_held) active.push_back("pty_held");
  if (f.frame_corruption_rate > 0) active.push_back("frames_corrupt");
  if (f.frame_drop_rate > 0) active.push_back("frames_drop");
  if (f.top_stalled) active.push_back("probe_stall_top");
  if (f.side_stalled) active.push_back("probe_stall_side");
  if (f.chamber_alarm) active.push_back("chamber_alarm");
  if (f.chamber_forced_c) active.push_back("chamber_force");

  const GyroStreamStats& st = s.stream;
  const ModbusServerStats& mb = s.modbus;
  nlohmann::ordered_json j = {
      {"running", s.running},
      {"t_s", s.t_s},
      {"lag_s", s.lag_s},
      {"clock",
       {{"shared", !s.clock_file.empty()},
        {"file", s.clock_file},
        {"held_wall_s", s.clock_held_wall_s},
        {"line_wait_wall_s", s.clock_line_wait_wall_s}}},
      {"setpoint_c", s.setpoint_c},
      {"ramp_limit_c_per_min", s.ramp_limit_c_per_min},
      {"ramped_setpoint_c", s.truth.ramped_setpoint_c},
      {"air_c", s.truth.air_c},
      {"case_c", s.truth.case_c},
      {"case_rate_c_per_s", s.truth.case_rate_c_per_s},
      {"gradient_c", s.truth.gradient_c},
      {"top_c", s.truth.top_c},
      {"side_c", s.truth.side_c},
      {"readings", {{"top_c", s.readings.top_c}, {"side_c", s.readings.side_c}}},
      {"last_rate_dph", s.last_rate_dph},
      {"faults_active", active},
      {"faults",
       {{"modbus_down", f.modbus_down},
        {"modbus_reply_delay_s", f.modbus_reply_delay_s},
        {"pty_open", f.pty_open},
        {"pty_held", f.pty_held},
        {"frame_corruption_rate", f.frame_corruption_rate},
        {"frame_drop_rate", f.frame_drop_rate},
        {"probe_stalled", {{"top", f.top_stalled}, {"side", f.side_stalled}}},
        {"chamber_alarm", f.chamber_alarm},
        {"chamber_forced_c", optional_json(f.chamber_forced_c)},
        {"chamber_units", f.chamber_units == drivers::TemperatureUnit::kCelsius ? "C" : "F"}}},
      {"counters",
       {{"frames_generated", s.frames_generated},
        {"frames_fault_dropped", s.frames_fault_dropped},
        {"frames_fault_corrupted", s.frames_fault_corrupted},
        {"setpoint_writes", s.setpoint_writes},
        {"setpoint_writes_rejected", s.setpoint_writes_rejected},
        {"stream",
         {{"frames_queued", st.frames_queued},
          {"frames_dropped_full", st.frames_dropped_full},
          {"frames_dropped_closed", st.frames_dropped_closed},
          {"frames_dropped_no_reader", st.frames_dropped_no_reader},
          {"readers", st.readers},
          {"bytes_written", st.bytes_written},
          {"write_errors", st.write_errors},
          {"pending_bytes", st.pending_bytes}}},
        {"modbus",
         {{"connections", mb.connections},
          {"active_connections", mb.active_connections},
          {"requests", mb.requests},
          {"unknown_unit_requests", mb.unknown_unit_requests},
          {"refused_connections", mb.refused_connections}}}}},
  };
  nlohmann::ordered_json duts = nlohmann::ordered_json::array();
  for (const DutSimStatus& d : s.duts) {
    nlohmann::ordered_json active = nlohmann::ordered_json::array();
    if (s.running && !d.pty_open) active.push_back("pty_closed");
    if (d.pty_held) active.push_back("pty_held");
    if (d.frame_corruption_rate > 0) active.push_back("frames_corrupt");
    if (d.frame_drop_rate > 0) active.push_back("frames_drop");
    if (d.probe_top_stalled) active.push_back("probe_stall_top");
    if (d.probe_side_stalled) active.push_back("probe_stall_side");
    nlohmann::ordered_json rates;
    for (std::size_t i = 0; i < 3; ++i) rates[kAxisNames[i]] = d.last_rates_dph[i];
    const GyroStreamStats& ds = d.stream;
    nlohmann::ordered_json e = {
        {"serial", d.serial},
        {"device", d.device},
        {"case_c", d.shell.case_c},
        {"case_rate_c_per_s", d.shell.case_rate_c_per_s},
        {"gradient_c", d.shell.gradient_c},
        {"top_c", d.shell.top_c},
        {"side_c", d.shell.side_c},
        {"readings", d.probe_readings ? nlohmann::ordered_json{{"top_c", d.probe_readings->top_c},
                                                               {"side_c", d.probe_readings->side_c}}
                                      : nlohmann::ordered_json(nullptr)},
        {"last_rates_dph", rates},
        {"faults_active", active},
        {"faults",
         {{"pty_open", d.pty_open},
          {"pty_held", d.pty_held},
          {"frame_corruption_rate", d.frame_corruption_rate},
          {"frame_drop_rate", d.frame_drop_rate},
          {"probe_stalled", {{"top", d.probe_top_stalled}, {"side", d.probe_side_stalled}}}}},
        {"counters",
         {{"frames_generated", d.frames_generated},
          {"frames_fault_dropped", d.frames_fault_dropped},
          {"frames_fault_corrupted", d.frames_fault_corrupted},
          {"stream",
           {{"frames_queued", ds.frames_queued},
            {"frames_dropped_full", ds.frames_dropped_full},
            {"frames_dropped_closed", ds.frames_dropped_closed},
            {"frames_dropped_no_reader", ds.frames_dropped_no_reader},
            {"readers", ds.readers},
            {"bytes_written", ds.bytes_written},
            {"write_errors", ds.write_errors},
            {"pending_bytes", ds.pending_bytes}}}}},
    };
    duts.push_back(std::move(e));
  }
  j["duts"] = std::move(duts);
  if (s.table.served) j["table"] = table_json(s.table);
  return j.dump();
}

std::string table_status_json(const TableStatus& table) { return table_json(table).dump(); }

std::string execute_control_command(Simulator& sim, const ControlCommand& c) {
  // The DUT of a gyro-line command.
  std::size_t dut = 0;
  switch (c.kind) {
    case Kind::kPtyClose:
    case Kind::kPtyHold:
    case Kind::kPtyRelease:
    case Kind::kPtyReopen:
    case Kind::kFramesCorrupt:
    case Kind::kFramesDrop:
    case Kind::kProbeStall:
    case Kind::kProbeRelease:
      if (c.dut_given) {
        const auto found = sim.find_dut(c.dut);
        if (!found) {
          std::string serials;
          for (const auto& s : sim.dut_serials())
            serials += (serials.empty() ? "'" : ", '") + s + "'";
          return fmt::format("error no DUT with serial {}; the simulator serves {}",
                             sim::quoted(c.dut), serials);
        }
        dut = *found;
      }
      break;
    default:
      break;
  }
  switch (c.kind) {
    case Kind::kModbusDown:
      sim.set_modbus_down(true);
      return "ok";
    case Kind::kModbusUp:
      sim.set_modbus_down(false);
      return "ok";
    case Kind::kModbusDelay:
      sim.set_modbus_reply_delay_s(c.value);
      return "ok";
    case Kind::kPtyClose:
      sim.close_pty(dut);
      return "ok";
    case Kind::kPtyHold:
    case Kind::kPtyRelease:
      sim.hold_pty(c.kind == Kind::kPtyHold, dut);
      return "ok";
    case Kind::kPtyReopen: {
      if (Status s = sim.reopen_pty(dut); !s.ok()) {
        return "error cannot reopen the pty: " + s.error().message;
      }
      const auto ep = sim.endpoints();
      nlohmann::ordered_json j = {{"gyro_device", ep.gyro_device}};
      if (dut < ep.dut_devices.size()) {
        j["serial"] = ep.dut_devices[dut].first;
        j["device"] = ep.dut_devices[dut].second;
      }
      return ok_json(j);
    }
    case Kind::kFramesCorrupt:
      sim.set_frame_corruption_rate(c.value, dut);
      return "ok";
    case Kind::kFramesDrop:
      sim.set_frame_drop_rate(c.value, dut);
      return "ok";
    case Kind::kProbeStall:
    case Kind::kProbeRelease:
      if (c.dut_given) {
        if (Status s = sim.stall_dut_probe(dut, c.probe, c.kind == Kind::kProbeStall); !s.ok()) {
          return "error " + s.error().message;
        }
        return "ok";
      }
      sim.stall_probe(c.probe, c.kind == Kind::kProbeStall);
      return "ok";
    case Kind::kChamberAlarmOn:
    case Kind::kChamberAlarmOff:
      if (!sim.has_chamber_alarm()) {
        return "error the station config names no chamber alarm register; add a "
               "[chamber.alarm] table (address, function, type)";
      }
      sim.set_chamber_alarm(c.kind == Kind::kChamberAlarmOn);
      return "ok";
    case Kind::kChamberUnitsC:
    case Kind::kChamberUnitsF:
      if (!sim.has_chamber_units()) {
        return "error the chamber's profile has no units register (watlow-f4t has one); "
               "it serves °C";
      }
      sim.set_chamber_units(c.kind == Kind::kChamberUnitsC ? drivers::TemperatureUnit::kCelsius
                                                           : drivers::TemperatureUnit::kFahrenheit);
      return "ok";
    case Kind::kChamberForce:
      sim.force_chamber_c(c.value);
      return "ok";
    case Kind::kChamberRelease:
      sim.force_chamber_c(std::nullopt);
      return "ok";
    case Kind::kTableFault:
    case Kind::kTableHang:
    case Kind::kTableDisconnect:
    case Kind::kTableConnect:
    case Kind::kTableClear:
    case Kind::kTableStatus:
      if (!sim.has_table()) {
        return "error the simulator serves no table (add a [table] section to the station "
               "config or start gyrotherm-sim with --table)";
      }
      switch (c.kind) {
        case Kind::kTableFault:
          sim.table_fault();
          break;
        case Kind::kTableHang:
          sim.table_hang(true);
          break;
        case Kind::kTableDisconnect:
          sim.table_disconnect(true);
          break;
        case Kind::kTableConnect:
          sim.table_disconnect(false);
          break;
        case Kind::kTableClear:
          sim.table_clear();
          break;
        default:
          return "ok " + table_status_json(sim.status().table);
      }
      return "ok";
    case Kind::kStatus:
      return "ok " + status_json(sim.status());
    case Kind::kHelp: {
      nlohmann::ordered_json list = nlohmann::ordered_json::array();
      for (const auto& h : control_commands()) {
        list.push_back({{"command", h.usage}, {"does", h.description}});
      }
      return ok_json({{"commands", list}});
    }
  }
  return "error internal: unhandled command";
}

std::string handle_control_line(Simulator& sim, std::string_view line) {
  auto command = parse_control_command(line);
  if (!command.ok()) return "error " + command.error().message;
  return execute_control_command(sim, *command);
}

// --- ControlServer ---

struct ControlServer::Client {
  int fd = -1;
  std::string in;
  std::string out;
  bool closing = false;  // close once `out` is written
};

Result<std::unique_ptr<ControlServer>> ControlServer::open(Options options) {
  namespace fs = std::filesystem;
  const std::string path = options.path;  // options is moved into the server below
  if (path.empty()) return Error::Permanent("control socket: empty path");
  if (path.size() > kMaxControlSocketPath) {
    return Error::Permanent(
        fmt::format("control socket '{}' is {} bytes long; a Unix socket path holds at most {}",
                    path, path.size(), kMaxControlSocketPath));
  }
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::memcpy(addr.sun_path, path.data(), path.size());

  std::error_code ec;
  if (const fs::path parent = fs::path(path).parent_path(); !parent.empty()) {
    fs::create_directories(parent, ec);
  }
  struct stat st {};
  if (::lstat(path.c_str(), &st) == 0) {
    if (!S_ISSOCK(st.st_mode)) {
      return Error::Permanent(
          fmt::format("control socket '{}' exists and is not a socket; not replacing it", path));
    }
    const int probe = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (probe >= 0) {
      const bool live = ::connect(probe, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
      ::close(probe);
      if (live) {
        return Error::Transient(fmt::format(
            "control socket '{}' is in use by a running process (another gyrotherm-sim?)", path));
      }
    }
    ::unlink(path.c_str());  // stale: left behind by a process that died
  }

  std::unique_ptr<ControlServer> server(new ControlServer(std::move(options)));
  server->wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (server->wake_fd_ < 0) return Error::Permanent("eventfd: " + errno_text(errno));
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) return Error::Transient("control socket: socket(): " + errno_text(errno));
  server->listen_fd_ = fd;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    return Error::Transient(
        fmt::format("control socket: cannot bind '{}': {}", path, errno_text(errno)));
  }
  ::chmod(path.c_str(), 0600);
  if (::stat(path.c_str(), &st) == 0) {
    server->socket_dev_ = static_cast<uint64_t>(st.st_dev);
    server->socket_ino_ = static_cast<uint64_t>(st.st_ino);
  }
  if (::listen(fd, 16) != 0) {
    const std::string why = errno_text(errno);
    server->stop();  // removes the socket file
    return Error::Transient(fmt::format("control socket: cannot listen on '{}': {}", path, why));
  }
  return server;
}

ControlServer::ControlServer(Options options) : options_(std::move(options)) {}

ControlServer::~ControlServer() {
  stop();
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

void ControlServer::serve(Handler handler) {
  std::lock_guard lock(stop_mu_);
  if (thread_.joinable() || stopping_.load() || listen_fd_ < 0) return;
  handler_ = std::move(handler);
  thread_ = std::thread([this] { run(); });
}

void ControlServer::stop() {
  std::lock_guard lock(stop_mu_);
  if (stopping_.exchange(true)) return;
  wake();
  if (thread_.joinable()) thread_.join();
  for (Client& c : clients_) ::close(c.fd);
  clients_.clear();
  if (listen_fd_ >= 0) {
    ::close(listen_fd_);
    listen_fd_ = -1;
    // Only our own socket: a later simulator may have replaced it.
    struct stat st {};
    if (::stat(options_.path.c_str(), &st) == 0 &&
        static_cast<uint64_t>(st.st_dev) == socket_dev_ &&
        static_cast<uint64_t>(st.st_ino) == socket_ino_) {
      ::unlink(options_.path.c_str());
    }
  }
  std::lock_guard stats_lock(stats_mu_);
  stats_.active_connections = 0;
}

void ControlServer::wake() {
  if (wake_fd_ < 0) return;
  const uint64_t one = 1;
  [[maybe_unused]] ssize_t n = ::write(wake_fd_, &one, sizeof one);
}

ControlServerStats ControlServer::stats() const {
  std::lock_guard lock(stats_mu_);
  return stats_;
}

void ControlServer::accept_clients() {
  for (;;) {
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (fd < 0) return;  // EAGAIN (drained) or a transient accept error
    if (clients_.size() >= options_.max_clients) {
      const std::string reply =
          fmt::format("error too many control connections ({})\n", options_.max_clients);
      [[maybe_unused]] ssize_t n = ::send(fd, reply.data(), reply.size(), MSG_NOSIGNAL);
      ::close(fd);
      std::lock_guard lock(stats_mu_);
      ++stats_.refused_connections;
      continue;
    }
    Client client;
    client.fd = fd;
    clients_.push_back(std::move(client));
    std::lock_guard lock(stats_mu_);
    ++stats_.connections;
    stats_.active_connections = clients_.size();
  }
}

void ControlServer::answer(Client& client, std::string_view line) {
  std::string reply;
  try {
    reply = handler_(line);
  } catch (const std::exception& e) {
    reply = fmt::format("error internal: {}", e.what());
  }
  // One reply line, whatever the handler returned.
  std::replace(reply.begin(), reply.end(), '\n', ' ');
  client.out += reply;
  client.out += '\n';
  std::lock_guard lock(stats_mu_);
  ++stats_.lines;
}

bool ControlServer::read_client(Client& client) {
  char buf[4096];
  bool eof = false;
  for (;;) {
    const ssize_t n = ::recv(client.fd, buf, sizeof buf, 0);
    if (n > 0) {
      client.in.append(buf, static_cast<std::size_t>(n));
      if (client.in.size() > options_.max_line_bytes + 1) break;  // answer what is there
      continue;
    }
    if (n == 0) {
      eof = true;
      break;
    }
    if (errno == EINTR) continue;
    if (errno == EAGAIN || errno == EWOULDBLOCK) break;
    return false;  // reset by the peer
  }

  const std::size_t limit = options_.max_line_bytes;
  auto oversize = [&] {
    client.out += fmt::format("error line longer than {} bytes\n", limit);
    client.in.clear();
    client.closing = true;
    std::lock_guard lock(stats_mu_);
    ++stats_.oversize_lines;
  };
  std::size_t start = 0;
  while (!client.closing) {
    const std::size_t nl = client.in.find('\n', start);
    if (nl == std::string::npos) break;
    std::string_view line(client.in.data() + start, nl - start);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (line.size() > limit) {
      oversize();
      return true;
    }
    answer(client, line);
    start = nl + 1;
  }
  client.in.erase(0, start);
  if (client.closing) return true;
  if (client.in.size() > limit) {
    oversize();
  } else if (eof) {
    if (!client.in.empty()) answer(client, client.in);  // last line without a newline
    client.in.clear();
    client.closing = true;
  }
  return true;
}

bool ControlServer::flush_client(Client& client) {
  while (!client.out.empty()) {
    const ssize_t n = ::send(client.fd, client.out.data(), client.out.size(), MSG_NOSIGNAL);
    if (n > 0) {
      client.out.erase(0, static_cast<std::size_t>(n));
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) break;
    return false;
  }
  // A client that sends commands but never reads the replies.
  return client.out.size() <= options_.max_pending_reply_bytes;
}

void ControlServer::run() {
  std::vector<pollfd> fds;
  while (!stopping_.load()) {
    fds.clear();
    fds.push_back({wake_fd_, POLLIN, 0});
    fds.push_back({listen_fd_, POLLIN, 0});
    for (const Client& c : clients_) {
      short events = c.closing ? 0 : POLLIN;
      if (!c.out.empty()) events |= POLLOUT;
      fds.push_back({c.fd, events, 0});
    }
    const int n = ::poll(fds.data(), fds.size(), -1);
    if (n < 0 && errno != EINTR) break;
    if (n <= 0) continue;
    if (fds[0].revents & POLLIN) {
      uint64_t count;
      [[maybe_unused]] ssize_t r = ::read(wake_fd_, &count, sizeof count);
    }
    if (stopping_.load()) break;

    // Clients first (fds[2 + i] is clients_[i]), then new connections.
    std::vector<std::size_t> to_close;
    for (std::size_t i = 0; i < clients_.size(); ++i) {
      Client& c = clients_[i];
      const short revents = fds[2 + i].revents;
      bool keep = true;
      if (revents & (POLLIN | POLLHUP | POLLERR)) {
        keep = c.closing ? !(revents & (POLLHUP | POLLERR)) : read_client(c);
      }
      if (keep) keep = flush_client(c);
      if (keep && c.closing && c.out.empty()) keep = false;
      if (!keep) to_close.push_back(i);
    }
    for (auto it = to_close.rbegin(); it != to_close.rend(); ++it) {
      ::close(clients_[*it].fd);
      clients_.erase(clients_.begin() + static_cast<std::ptrdiff_t>(*it));
    }
    if (!to_close.empty()) {
      std::lock_guard lock(stats_mu_);
      stats_.active_connections = clients_.size();
    }
    if (fds[1].revents & POLLIN) accept_clients();
  }
}

// --- Client ---

Result<std::string> send_control_command(const std::string& socket_path, std::string_view command,
                                         std::chrono::milliseconds timeout) {
  if (command.find('\n') != std::string_view::npos) {
    return Error::Permanent("a control command is one line: it must not contain a newline");
  }
  if (socket_path.empty() || socket_path.size() > kMaxControlSocketPath) {
    return Error::Permanent(fmt::format("'{}' is not a usable Unix socket path", socket_path));
  }
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::memcpy(addr.sun_path, socket_path.data(), socket_path.size());
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return Error::Transient("socket(): " + errno_text(errno));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  // Bounds connect() (a full backlog) and send().
  timeval tv{};
  tv.tv_sec = static_cast<time_t>(timeout.count() / 1000);
  tv.tv_usec = static_cast<suseconds_t>((timeout.count() % 1000) * 1000);
  ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    return Error::Transient(
        fmt::format("cannot connect to the control socket '{}': {} (is gyrotherm-sim running with "
                    "[simulator] control_socket set?)",
                    socket_path, errno_text(errno)));
  }
  std::string request(command);
  request += '\n';
  for (std::size_t sent = 0; sent < request.size();) {
    const ssize_t n = ::send(fd, request.data() + sent, request.size() - sent, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      return Error::Transient(
          fmt::format("control socket '{}': send failed: {}", socket_path, errno_text(errno)));
    }
    sent += static_cast<std::size_t>(n);
  }

  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::string reply;
  char buf[4096];
  for (;;) {
    if (const auto nl = reply.find('\n'); nl != std::string::npos) return reply.substr(0, nl);
    const auto left =
        std::chrono::ceil<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) break;
    pollfd p{fd, POLLIN, 0};
    const int r = ::poll(&p, 1, static_cast<int>(left.count()));
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) break;
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      return Error::Transient(
          fmt::format("control socket '{}' closed before a full reply", socket_path));
    }
    reply.append(buf, static_cast<std::size_t>(n));
  }
  return Error::Transient(
      fmt::format("control socket '{}': no reply within {} ms", socket_path, timeout.count()));
}

}  // namespace gyrotherm::sim
