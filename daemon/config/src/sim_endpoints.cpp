#include "gyrotherm/config/sim_endpoints.h"

#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <cmath>
#include <sstream>

#include "gyrotherm/core/files.h"
#include "gyrotherm/core/toml_reader.h"
#include "gyrotherm/drivers/rate_table.h"

namespace gyrotherm::config {

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
  // dut_devices = [{serial = "...", device = "..."}, ...]: every simulated
  // DUT's pty; gyro_device (the first's) may then be left out.
  if (const toml::array* list = t.array("dut_devices")) {
    for (std::size_t i = 0; i < list->size(); ++i) {
      const toml::node& node = *list->get(i);
      const std::string path = fmt::format("dut_devices[{}]", i);
      const toml::table* entry = node.as_table();
      if (!entry) {
        errors.add(
            node_line(node, t.line_of("dut_devices")), path,
            fmt::format("expected a table {{serial, device}}, got {}", toml_type_name(node)));
        continue;
      }
      TableReader e(*entry, path, errors);
      auto serial = e.required_string("serial");  // "" = the unnamed gyro
      auto device = e.required_string("device");
      if (device && device->empty()) e.error("device", "must not be empty");
      // The rate the DUT is served at (absent from older simulators).
      double rate_hz = 0;  // 0 = not stated
      if (auto r = e.number("rate_hz")) {
        if (*r >= 0.1 && *r <= 10000.0)
          rate_hz = *r;
        else
          e.error("rate_hz", fmt::format("{} is out of range: must be in [0.1, 10000]", *r));
      }
      e.finish();
      if (serial && device && !device->empty()) ep.dut_devices.emplace_back(*serial, *device);
      if (serial && rate_hz > 0) ep.dut_rates_hz.emplace_back(*serial, rate_hz);
    }
  }
  if (ep.dut_devices.empty() || t.raw().contains("gyro_device")) {
    if (auto d = t.required_string("gyro_device")) ep.gyro_device = *d;
  } else {
    ep.gyro_device = ep.dut_devices.front().second;
  }
  if (auto p = t.integer("pid")) ep.pid = static_cast<long>(*p);
  if (auto c = t.string("control_socket")) ep.control_socket = *c;
  if (auto p = t.integer("table_port")) {
    if (*p < 0 || *p > 65535)
      t.error("table_port", fmt::format("{} is not a TCP port", *p));
    else
      ep.table_port = static_cast<int>(*p);
  }
  if (auto d = t.string("table_device")) ep.table_device = *d;
  if (auto d = t.string("table_acl_device")) ep.table_acl_device = *d;
  if (auto p = t.integer("table_aero_port")) {
    if (*p < 0 || *p > 65535)
      t.error("table_aero_port", fmt::format("{} is not a TCP port", *p));
    else
      ep.table_aero_port = static_cast<int>(*p);
  }
  if (auto c = t.string("clock_file")) ep.clock_file = *c;
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
  // gyro_device stays for older daemons: the first DUT's line.
  const std::string& gyro_device = ep.gyro_device.empty() && !ep.dut_devices.empty()
                                       ? ep.dut_devices.front().second
                                       : ep.gyro_device;
  toml::table t{{"modbus_host", ep.modbus_host},
                {"modbus_port", ep.modbus_port},
                {"gyro_device", gyro_device},
                {"pid", static_cast<int64_t>(ep.pid)}};
  if (!ep.control_socket.empty()) t.insert("control_socket", ep.control_socket);
  if (ep.time_scale > 0) t.insert("time_scale", ep.time_scale);
  if (!ep.clock_file.empty()) t.insert("clock_file", ep.clock_file);
  if (ep.table_port > 0) t.insert("table_port", ep.table_port);
  if (!ep.table_device.empty()) t.insert("table_device", ep.table_device);
  if (!ep.table_acl_device.empty()) t.insert("table_acl_device", ep.table_acl_device);
  if (ep.table_aero_port > 0) t.insert("table_aero_port", ep.table_aero_port);
  if (!ep.dut_devices.empty()) {
    toml::array list;
    for (const auto& [serial, device] : ep.dut_devices) {
      toml::table entry{{"serial", serial}, {"device", device}};
      for (const auto& [s, hz] : ep.dut_rates_hz) {
        if (s == serial) entry.insert("rate_hz", hz);
      }
      entry.is_inline(true);
      list.push_back(std::move(entry));
    }
    t.insert("dut_devices", std::move(list));
  }
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
  // Every DUT's line, by serial; an older simulator (no dut_devices) serves
  // one gyro, on gyro_device. A DUT the simulator does not serve keeps its
  // configured line: sim_dut_devices_mismatch() names it.
  if (ep.dut_devices.empty()) {
    if (!config.duts.empty()) config.duts.front().link.serial.device = ep.gyro_device;
  } else {
    for (auto& dut : config.duts) {
      for (const auto& [serial, device] : ep.dut_devices) {
        if (serial == dut.serial) dut.link.serial.device = device;
      }
    }
  }
  // The rate each DUT is served at (gyrotherm-sim --rate-hz): what its
  // frames come at, and for a delta-angle output what turns them into rates.
  for (auto& dut : config.duts) {
    for (const auto& [serial, hz] : ep.dut_rates_hz) {
      if (serial == dut.serial) dut.link.rate_hz = hz;
    }
  }
  config.gyro.serial.device =
      config.duts.empty() ? ep.gyro_device : config.duts.front().link.serial.device;
  if (!config.duts.empty()) config.gyro.format.rate_hz = config.duts.front().link.rate_hz;
  // The simulator's table, for a station that has one, by protocol and
  // transport: ACL on loopback TCP or a pty, the AERO grammar on a pty or
  // loopback TCP. What an older simulator does not serve stays as
  // configured.
  if (config.table) {
    drivers::TableConnection& c = config.table->connection;
    const bool serial = drivers::table_transport(c) == "serial";
    const bool acl = c.profile == "acutrol";
    const std::string& device = acl ? ep.table_acl_device : ep.table_device;
    const int port = acl ? ep.table_port : ep.table_aero_port;
    if (serial && !device.empty()) {
      c.device = device;
    } else if (!serial && port > 0) {
      c.host = ep.modbus_host;
      c.port = port;
    }
  }
}

std::string sim_dut_devices_mismatch(const StationConfig& config, const SimEndpoints& ep,
                                     const std::string& endpoints_file) {
  const auto named = [](const std::string& serial) {
    return serial.empty() ? std::string("(no serial)") : fmt::format("\"{}\"", serial);
  };
  if (ep.dut_devices.empty()) {
    if (config.duts.size() <= 1) return "";
    return fmt::format(
        "the simulator ({}) serves one gyro line (gyro_device, no dut_devices: an older "
        "gyrotherm-sim) but the config has {} DUTs: start a gyrotherm-sim that serves every "
        "[[dut]]",
        endpoints_file, config.duts.size());
  }
  std::vector<std::string> missing, served;
  for (const auto& dut : config.duts) {
    const bool found = std::any_of(ep.dut_devices.begin(), ep.dut_devices.end(),
                                   [&](const auto& d) { return d.first == dut.serial; });
    if (!found) missing.push_back(named(dut.serial));
  }
  if (missing.empty()) return "";
  for (const auto& d : ep.dut_devices) served.push_back(named(d.first));
  return fmt::format(
      "the simulator ({}) serves no line for DUT{} {} (it serves {}): start gyrotherm-sim with "
      "the same station config",
      endpoints_file, missing.size() == 1 ? "" : "s", fmt::join(missing, ", "),
      fmt::join(served, ", "));
}

}  // namespace gyrotherm::config
