// The simulator's endpoints file: what gyrotherm-sim writes when it has
// opened its servers and ptys, and what gyrothermd takes from it when
// [simulator] endpoints_file is set (config.h, SimulatorSection).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "gyrotherm/config/config.h"
#include "gyrotherm/core/result.h"

namespace gyrotherm::config {

// What gyrotherm-sim writes for the daemon (TOML):
//   modbus_host = "127.0.0.1"; modbus_port = N; gyro_device = "/dev/pts/N"; pid = N;
//   control_socket = "PATH" (optional); time_scale = X (station seconds per
//   wall second the simulator runs at; absent from older simulators);
//   dut_devices = [{serial = "...", device = "...", rate_hz = HZ}, ...]
struct SimEndpoints {
  std::string modbus_host = "127.0.0.1";
  int modbus_port = 0;
  std::string gyro_device;
  long pid = 0;
  std::string control_socket;  // fault-injection command socket ("" = none)
  double time_scale = 0;       // 0 = not stated
  // The simulator's shared station clock (core/shared_clock.h); "" = none
  // (an older simulator, or one started with --scaled-clock).
  std::string clock_file{};
  // The rate table the simulator serves (0 / "" = none): ACL over TCP, and
  // the AERO grammar on a pty; and for [table] transport, each on the other
  // transport (absent from older simulators).
  int table_port = 0;
  std::string table_device{};
  std::string table_acl_device{};  // ACL on a pty
  int table_aero_port = 0;         // AERO over TCP, on modbus_host
  // Every simulated DUT's pty, by the DUT's serial number, in [[dut]]
  // order (gyro_device is the first's). Written as `dut_devices = [{serial =
  // "...", device = "..."}, ...]`.
  std::vector<std::pair<std::string, std::string>> dut_devices{};
  // Each DUT's output rate as served, Hz, by serial (gyrotherm-sim
  // --rate-hz may differ from the config's rate_hz): `rate_hz` in its
  // dut_devices entry. Empty from older simulators. apply_sim_endpoints()
  // gives each DUT its served rate.
  std::vector<std::pair<std::string, double>> dut_rates_hz{};
};
// "" when a daemon at `daemon_time_scale` may run against the simulator
// that wrote `ep`, else why not (the two clocks would disagree: the
// daemon's set points, rates and acquisition windows would be wrong).
std::string sim_time_scale_mismatch(const SimEndpoints& ep, double daemon_time_scale,
                                    const std::string& endpoints_file);
Result<SimEndpoints> read_sim_endpoints(const std::string& path);
Status write_sim_endpoints(const std::string& path, const SimEndpoints& endpoints);
// Applies endpoints to the chamber, probes, table and every DUT's line and
// output rate (by serial; a DUT the simulator does not serve is an error at
// start-up).
void apply_sim_endpoints(StationConfig& config, const SimEndpoints& endpoints);
// "" when the simulator that wrote `ep` serves every DUT of `config`, else
// which it does not serve (the daemon refuses to start: its line would be
// missing). An older simulator's file (no dut_devices) serves one gyro, on
// gyro_device: enough for a config with one DUT, whatever its serial.
std::string sim_dut_devices_mismatch(const StationConfig& config, const SimEndpoints& ep,
                                     const std::string& endpoints_file);

}  // namespace gyrotherm::config
