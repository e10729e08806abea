// The simulated station (gyrotherm-sim, docs/simulator.md), as a library so tests
// run it in-process.
//
// Wiring: a ThermalPlant and a GyroModel advanced in station time (the
// Clock) on one thread in fixed steps of min(0.1 s, 1 / rate_hz), emitting
// every gyro frame that falls due to a pty (GyroStream); a Modbus TCP server
// on loopback (ModbusServer) with the chamber controller (unit
// config.chamber.endpoint.unit_id, register map config.chamber.map; writing
// the set point register moves the plant's set point) and the probe module
// (unit config.probes.endpoint.unit_id, registers config.probes.top/side).
// The register image is refreshed from the plant every wall tick (~2 ms).
// A request for any other unit id is answered with exception 0x0B (gateway
// target device failed to respond).
//
// The chamber serves exactly its map's registers (ModbusServer: exception 2
// elsewhere and for writes to the read-only process value, alarm and units
// registers). Set point writes outside [-100, 200] °C or not finite are
// refused with exception 3. With the watlow-f4t ramp registers (Watlow's
// enumerations, as a real F4T: ramp action Off 62 at start, Startup 88,
// Set Point Change 1647, Both 13; ramp scale Minutes 57 or Hours 39; any
// other value is refused with exception 3), a ramp action of Set Point
// Change or Both makes the ramp rate register (per minute or per hour, by
// the ramp scale) limit the chamber's ramp, never beyond
// [simulator.thermal] max_ramp_c_per_min; Off and Startup (which ramps only
// at power-up) leave the plant's own limit.
//
// With a units register (watlow-f4t: 6730), the set point, process value
// and ramp rate are served in options.chamber_units (°C by default, °F on
// request or set_chamber_units()), and the register says which (Watlow's
// 15 °C, 30 °F). Without one, °C.
//
// With config.chamber.map.alarm set, the chamber also serves that register,
// read-only: its quiet value (watlow-f4t: None 61), or an alarm value (Alarm
// High 7) while set_chamber_alarm(true).
//
// The probe readings are quantised to the coarser of [simulator.thermal]
// probe_quantum_c and the probe registers' resolution (0.1 °C for int16 x
// 0.1), so the status shows what a client reads.
//
// With a rate table (config.table set, or options.serve_table), the
// simulator also serves one table (RateTableModel, stepped with the plant)
// two ways: ACL over TCP on loopback (TableServer, port options.table_port)
// and the AERO grammar on a second pty (AeroServer); and each on the other
// transport too, for [table] transport (ACL on a third pty, AERO over TCP
// on a port of its own); the gyro sees the table's true rate and position
// through its scale factor (GyroModel::enable_table).
//
// Devices under test (dut_model.h; docs/simulator.md "Several DUTs"): every
// [[dut]] of the config (simulated_duts()) gets its own pty, model, shell and
// faults; the first is "the gyro" of the older interface (gyro_link, the
// endpoints' gyro_device, last_rate_dph, the fault hooks' default). A DUT
// with probes (DutSection::probes) has its top and side channels served on
// the probe module, reading its own shell plus probe_offset_c; each can be
// stalled on its own (stall_dut_probe()).
//
// Fault hooks are plain methods, safe to call from any thread while running.
// With options.control_socket set, start() also opens a ControlServer
// (control_server.h) that calls them on command.
#pragma once

#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "gyrotherm/config/config.h"
#include "gyrotherm/config/sim_endpoints.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/core/shared_clock.h"
#include "gyrotherm/sim/dut_model.h"
#include "gyrotherm/sim/gyro_model.h"
#include "gyrotherm/sim/gyro_stream.h"
#include "gyrotherm/sim/modbus_server.h"
#include "gyrotherm/sim/options.h"
#include "gyrotherm/sim/rate_table_model.h"
#include "gyrotherm/sim/table_server.h"
#include "gyrotherm/sim/thermal_plant.h"

namespace gyrotherm::sim {

enum class ProbeRole { kTop, kSide };

class ControlServer;
class TableServer;
class AeroServer;

// The rate table as the status shows it.
struct TableStatus {
  bool served = false;
  TableModelState state;
  bool hung = false;          // table hang: requests go unanswered
  bool disconnected = false;  // table disconnect: ACL clients closed and refused
  int port = 0;               // ACL over TCP
  std::string device;         // AERO pty
  std::string acl_device;     // ACL on a pty
  int aero_port = 0;          // AERO over TCP
  uint64_t acl_requests = 0;
  uint64_t acl_unanswered = 0;  // dropped while hung
  uint64_t acl_refused_connections = 0;
  uint64_t aero_requests = 0;
  uint64_t acl_serial_requests = 0;  // ACL on the pty
  uint64_t aero_tcp_requests = 0;    // AERO over TCP
};

// The faults in force.
struct SimulatorFaults {
  bool modbus_down = false;
  double modbus_reply_delay_s = 0;  // wall seconds
  bool pty_open = false;            // false while closed by close_pty() (or not running)
  bool pty_held = false;            // hold_pty(true): frames queue, the line is quiet
  double frame_corruption_rate = 0;
  double frame_drop_rate = 0;
  bool top_stalled = false;
  bool side_stalled = false;
  bool chamber_alarm = false;
  std::optional<double> chamber_forced_c;  // force_chamber_c() target, °C
  drivers::TemperatureUnit chamber_units = drivers::TemperatureUnit::kCelsius;
};

// One DUT as the status shows it.
struct DutSimStatus {
  std::string serial;
  std::string device;                           // what the endpoints name (its link, or the pty)
  ThermalTruth shell;                           // its case (the plant's unless it has its own)
  std::optional<ProbeReadings> probe_readings;  // its own probes' registers, if served
  bool has_probe_top = false;                   // its own top probe is served
  bool has_probe_side = false;
  bool probe_top_stalled = false;  // stall_dut_probe()
  bool probe_side_stalled = false;
  std::array<double, 3> last_rates_dph{};  // last sample per axis x, y, z, noise included
  uint64_t frames_generated = 0;
  uint64_t frames_fault_dropped = 0;
  uint64_t frames_fault_corrupted = 0;
  GyroStreamStats stream;
  bool pty_open = false;
  bool pty_held = false;
  double frame_corruption_rate = 0;
  double frame_drop_rate = 0;
};

struct SimulatorStatus {
  bool running = false;
  double t_s = 0;    // station seconds simulated since start()
  double lag_s = 0;  // how far the simulation trails the clock (0 when keeping up)
  // On the shared clock (SimulatorOptions::shared_clock): its file, and the
  // wall seconds it has waited for the daemon (held) or for a DUT line to
  // take its frames.
  std::string clock_file;
  double clock_held_wall_s = 0;
  double clock_line_wait_wall_s = 0;
  double setpoint_c = 0;  // requested set point (Modbus or set_setpoint_c)
  // The controller's ramp limit from its ramp registers, as the plant takes
  // it at its next step (0: the plant's own max_ramp_c_per_min).
  double ramp_limit_c_per_min = 0;
  ThermalTruth truth;        // the plant's state at t_s
  ProbeReadings readings;    // what the probe registers hold (unless stalled)
  double last_rate_dph = 0;  // the last gyro sample of the sensitive axis, noise included
  uint64_t frames_generated = 0;
  uint64_t frames_fault_dropped = 0;    // set_frame_drop_rate
  uint64_t frames_fault_corrupted = 0;  // set_frame_corruption_rate
  GyroStreamStats stream;
  ModbusServerStats modbus;
  uint64_t setpoint_writes = 0;
  uint64_t setpoint_writes_rejected = 0;
  SimulatorFaults faults;
  TableStatus table;
  std::vector<DutSimStatus> duts;  // in [[dut]] order; the fields above are duts[0]'s
};

class Simulator {
 public:
  // Builds the plant, gyro model and device maps. `clock` (station time;
  // must outlive the simulator) defaults to an own ScaledClock with
  // options.time_scale. Permanent error on an inconsistent config (e.g.
  // chamber and probes with the same unit id).
  static Result<std::unique_ptr<Simulator>> create(const config::StationConfig& config,
                                                   const SimulatorOptions& options,
                                                   const Clock* clock = nullptr);
  ~Simulator();  // stop()
  Simulator(const Simulator&) = delete;
  Simulator& operator=(const Simulator&) = delete;

  // Listens (Modbus and, if set, the control socket), opens the pty, writes
  // the truth file, starts the simulation and, once all of that is up,
  // writes the endpoints file (with this process's pid). On error
  // everything started is stopped again.
  Status start();
  // Stops the threads, closes the servers and the pty, removes the endpoints
  // file it wrote and the control socket. Idempotent. The truth file stays.
  void stop();

  // What a client connects to (valid after start()).
  config::SimEndpoints endpoints() const;
  const std::string& truth_file() const { return options_.truth_file; }
  const std::string& endpoints_file() const { return options_.endpoints_file; }
  std::string truth_json() const { return truth_json_; }
  SimulatorStatus status() const;
  const SimulatorOptions& options() const { return options_; }

  // The DUTs, in [[dut]] order (at least one).
  std::size_t dut_count() const { return duts_.size(); }
  std::vector<std::string> dut_serials() const;
  // The index of the DUT with `serial`; nullopt when none has it.
  std::optional<std::size_t> find_dut(std::string_view serial) const;

  // --- Fault injection and test hooks ---
  // The gyro-line hooks take the DUT's index (default the first); an index
  // beyond dut_count() is ignored (reopen_pty: an error).
  // Moves the requested set point as a Modbus write would (register too).
  void set_setpoint_c(double setpoint_c);
  // Probability (0..1) that a frame gets one byte altered after its CRC.
  void set_frame_corruption_rate(double p, std::size_t dut = 0);
  // Probability (0..1) that a frame is not sent (its sequence number is used,
  // so the reader sees a gap).
  void set_frame_drop_rate(double p, std::size_t dut = 0);
  // Modbus link down: connections closed and refused until set false.
  void set_modbus_down(bool down);
  // Every Modbus answer comes `wall_s` wall seconds late (0 = none).
  void set_modbus_reply_delay_s(double wall_s);
  // Hang-up of the gyro line; frames due while closed are dropped.
  void close_pty(std::size_t dut = 0);
  // Opens a new pty (a new path: endpoints() and the endpoints file follow).
  Status reopen_pty(std::size_t dut = 0);
  // Holds the gyro frames back (true): they queue in the simulator, up to
  // its pending limit, and the line stays quiet; released (false), they go
  // out as one backlog, as from a reader that was descheduled.
  void hold_pty(bool held, std::size_t dut = 0);
  // A stalled probe's register keeps its last value (the station's pair).
  void stall_probe(ProbeRole role, bool stalled);
  // The same for DUT `dut`'s own probe (DutSection::probes). Error naming
  // the DUT when there is no such DUT, or it serves no such probe of its
  // own (no probes, or its channel is another probe's).
  Status stall_dut_probe(std::size_t dut, ProbeRole role, bool stalled);
  // Raises (true) or clears the chamber alarm. Without an alarm register in
  // the config (has_chamber_alarm() false) only the status shows it.
  void set_chamber_alarm(bool raised);
  bool has_chamber_alarm() const { return config_.chamber.map.alarm.has_value(); }
  // The unit the chamber serves temperatures in (only with a units register;
  // has_chamber_units()). The set point stays; its register is rewritten.
  void set_chamber_units(drivers::TemperatureUnit unit);
  bool has_chamber_units() const { return config_.chamber.map.units.has_value(); }
  // Runaway controller (ThermalPlant::force_air_c): while set, the chamber
  // air heads to target_c (clamped to [-100, 200] °C) at the plant's max ramp
  // rate whatever the requested set point; the set point register keeps what
  // the client wrote. nullopt (or a non-finite target) releases it.
  void force_chamber_c(std::optional<double> target_c);

  // --- The rate table (has_table()); each a no-op without one ---
  bool has_table() const { return table_.has_value(); }
  // Interlock to fault now (latched until :I:R), mode off; the axis coasts.
  void table_fault();
  // Hang: the table answers no request (ACL or AERO); connections stay.
  void table_hang(bool hung);
  // Disconnect: TCP clients (ACL, and AERO over TCP) are closed and new
  // ones refused (accepted and closed), the serial lines (AERO, and ACL on
  // a pty) go silent, until false (`table connect`).
  void table_disconnect(bool disconnected);
  // Ends hang and disconnect. A latched interlock fault stays (:I:R).
  void table_clear();
  // One ACL request line handled as the TCP server would (code + payload).
  AclReply table_acl(std::string_view line);

 private:
  // The hang and disconnect faults onto every table server. life_mu_ held.
  void apply_table_link_faults();

  // One DUT's moving parts.
  struct Dut {
    Dut(DutModel m, DutShell sh, std::size_t nominal_frame_bytes, std::size_t pending_limit)
        : model(std::move(m)), shell(std::move(sh)), stream(nominal_frame_bytes, pending_limit) {}
    DutModel model;  // these four guarded by sim_mu_
    DutShell shell;
    uint64_t next_frame = 1;
    std::mt19937_64 fault_rng;
    uint64_t frames_generated = 0;
    uint64_t frames_fault_dropped = 0;
    uint64_t frames_fault_corrupted = 0;
    std::atomic<double> corruption_rate{0.0};
    std::atomic<double> drop_rate{0.0};
    GyroStream stream;  // guarded by stream_mu_
    std::string link;   // its symlink ("" = none: the endpoints name the pty)
    std::optional<drivers::RegisterSpec> probe_top, probe_side;  // served on the probe module
    // What its probe registers hold: the shell's readings, each kept while
    // that probe is stalled (guarded by sim_mu_).
    ProbeReadings probe_readings;
    std::atomic<bool> probe_stalled[2] = {false, false};  // top, side
    // Frames of one tick, waiting for the stream (simulation thread only).
    std::vector<uint8_t> batch;
    std::vector<std::size_t> batch_sizes;
  };

  Simulator(config::StationConfig config, SimulatorOptions options, const Clock* clock,
            std::vector<std::unique_ptr<Dut>> duts);
  void run();
  void run_paced();
  // Writes every DUT's batch to its line; true when every line that is open
  // and not held took all of its frames (nothing pending).
  bool write_batches();
  void advance_to(double target_s);
  void publish_registers();
  void on_modbus_write(int unit_id);
  // Stops the Modbus server's thread (no on_modbus_write() after it), then
  // destroys the server.
  void release_modbus_server();
  Status write_endpoints_file();
  // Points DUT `i`'s link (if any) at its current pty. Needs stream_mu_.
  Status point_gyro_link_locked(std::size_t i);
  std::string device_locked(std::size_t i) const;  // needs stream_mu_

  config::StationConfig config_;
  SimulatorOptions options_;
  std::unique_ptr<Clock> own_clock_;
  const Clock* clock_;
  // The shared clock, when this simulator owns station time (options'
  // shared_clock with an endpoints file and its own clock); the run loop
  // then paces itself (run_paced()).
  std::unique_ptr<SharedClockOwner> shared_clock_;
  // run_paced(): free running (no daemon holds the clock) since when, and
  // how far behind scaled wall time that started.
  bool free_running_ = false;
  double free_offset_s_ = 0;
  std::string truth_json_;
  int chamber_unit_;
  int probes_unit_;

  // Simulation state, guarded by sim_mu_ (the simulation thread holds it
  // while it advances one tick).
  mutable std::mutex sim_mu_;
  ThermalPlant plant_;
  std::vector<std::unique_ptr<Dut>> duts_;  // fixed after construction
  double step_s_ = 0.1;
  double t0_s_ = 0;
  int64_t steps_ = 0;
  SimulatorStatus status_;
  std::optional<RateTableModel> table_;  // guarded by sim_mu_
  AclControllerState acl_state_;         // guarded by sim_mu_

  std::atomic<double> setpoint_c_;
  std::atomic<double> ramp_limit_c_per_min_{0.0};  // <= 0: the plant's own limit
  std::atomic<bool> stalled_[2] = {false, false};
  std::atomic<bool> chamber_alarm_{false};
  std::mutex alarm_mu_;  // orders the alarm register's writes with its changes
  // Chamber units (atomic for status()); units_mu_ orders a change with the
  // temperature registers' writes and the reading of a client's write.
  std::atomic<drivers::TemperatureUnit> chamber_units_;
  std::mutex units_mu_;
  std::atomic<double> forced_chamber_c_;  // NaN = not forced

  mutable std::mutex stream_mu_;  // every Dut::stream

  mutable std::mutex life_mu_;  // start/stop against the hooks that reach server_
  std::unique_ptr<ModbusServer> server_;
  std::unique_ptr<ControlServer> control_;
  std::unique_ptr<TableServer> table_server_;      // ACL over TCP
  std::unique_ptr<AeroServer> aero_server_;        // AERO on a pty
  std::unique_ptr<AeroServer> acl_serial_server_;  // ACL on a pty (a line server)
  std::unique_ptr<TableServer> aero_tcp_server_;   // AERO over TCP (a line server)
  std::atomic<bool> table_hung_{false};
  std::atomic<bool> table_disconnected_{false};
  std::atomic<int> modbus_port_{0};
  std::thread thread_;
  std::mutex wake_mu_;
  std::condition_variable wake_cv_;
  bool stopping_ = false;  // guarded by wake_mu_
  bool wrote_endpoints_ = false;
};

}  // namespace gyrotherm::sim
