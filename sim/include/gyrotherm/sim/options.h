// Options of gyrotherm-sim: the [simulator] section of the station config
// (with [simulator.thermal] and [simulator.gyro]) plus command-line
// overrides.
//
//   [simulator]
//   endpoints_file = "demo/sim-endpoints.toml"  # where the opened endpoints go ("" = none)
//   truth_file = "demo/sim-truth.json"          # the gyro model's truth ("" = none)
//   gyro_link = "demo/gyro-pty"                 # a stable symlink to the current pty ("" = none)
//   control_socket = "demo/sim.sock"            # fault-injection commands ("" = none)
//   modbus_port = 0                             # 0: any free port
//   seed = 1
//   initial_temp_c = 23.0
//   chamber_units = "C"                         # C or F: what a chamber with a
//                                               # units register serves (watlow-f4t)
//   pending_frames_limit = 0                    # see SimulatorOptions
//   table_port = 0                              # the rate table's ACL port; 0: any free port
//   [simulator.thermal]  -> ThermalParams (thermal_plant.h), same key names
//   [simulator.gyro]     -> GyroParams (gyro_model.h), same key names
//   [simulator.table]    -> TableParams (rate_table_model.h), same key names
//   [simulator.scale_factor] -> ScaleFactorParams (gyro_model.h), same key names
//   [simulator.randomize] -> RandomizeRanges: [lo, hi] ranges each DUT axis's
//                           noise (white_noise_dph, bias_instability_dph,
//                           rate_random_walk_dph_per_sqrt_h) and each DUT's
//                           case_tau_s are drawn from, by the seed; they win
//                           over every other table; the truth file lists
//                           the values drawn
//   [simulator.dut.SN]   -> DutOverrides (or [[simulator.dut]] with serial = "SN"):
//                           GyroParams keys for every axis of DUT SN, accel_noise_g,
//                           internal_temp_offset_c, probe_offset_c, case_tau_s,
//                           gradient_c_per_c_per_min, gradient_offset_c,
//                           gradient_tau_s; per axis [simulator.dut.SN.x] (.y, .z)
//                           with GyroParams keys
//
// The table is served when the station config has a [table] section or
// with `--table` (serve_table).
//
// The gyro output format (unit, rate/delta, axis, rate_hz) comes from [gyro]
// (each DUT's from its [[dut]]); `--rate-hz HZ` sets every DUT's rate,
// `--rate-hz SERIAL=HZ` one DUT's (that wins over HZ).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/config/config.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/sim/dut_model.h"
#include "gyrotherm/sim/gyro_model.h"
#include "gyrotherm/sim/rate_table_model.h"
#include "gyrotherm/sim/thermal_plant.h"

namespace gyrotherm::sim {

// What a [simulator.dut.SN] table (or its per-axis table .x, .y, .z) sets of
// GyroParams: unset keys keep the value from the level above.
struct GyroOverrides {
  std::optional<double> bias_dph;
  std::optional<std::vector<double>> temp_coeffs;
  std::optional<std::vector<double>> rate_coeffs;
  std::optional<std::vector<double>> gradient_coeffs;
  std::optional<double> white_noise_dph;
  std::optional<double> bias_instability_dph;
  std::optional<double> bias_instability_tau_s;
  std::optional<double> rate_random_walk_dph_per_sqrt_h;
  void apply(GyroParams& p) const;
};

// One DUT's [simulator.dut.SN] (or [[simulator.dut]] with serial = SN).
struct DutOverrides {
  std::string serial;
  GyroOverrides all;                  // every axis
  std::array<GyroOverrides, 3> axis;  // [simulator.dut.SN.x], .y, .z
  std::optional<double> accel_noise_g;
  std::optional<double> internal_temp_offset_c;
  std::optional<double> probe_offset_c;
  DutCaseParams case_params;
};

// A [lo, hi] range a parameter is drawn from: log-uniform when lo > 0 (a
// noise spans decades), uniform when lo = 0; lo = hi fixes it.
struct DrawRange {
  double lo = 0;
  double hi = 0;
  double draw(std::mt19937_64& rng) const;
};

// [simulator.randomize]: the station's gyros and cases drawn by the seed, so
// a test (or a bench over many seeds) is blind to the parameters it checks
// the analysis against; the truth file says what was drawn. Each DUT draws
// from its own stream (the seed and its position among the DUTs), axis x,
// y, z in turn (white noise, bias instability, rate random walk), then its
// case time constant: adding a DUT changes none of the others.
struct RandomizeRanges {
  std::optional<DrawRange> white_noise_dph;
  std::optional<DrawRange> bias_instability_dph;
  std::optional<DrawRange> rate_random_walk_dph_per_sqrt_h;
  std::optional<DrawRange> case_tau_s;
  // The chamber's, from a stream of their own (kChamberRandomizeStream),
  // two draws in this order: the air's lag and the control noise.
  std::optional<DrawRange> air_tau_s;
  std::optional<DrawRange> control_noise_c;
};

// The seed of one of the simulator's random streams (SplitMix64, Steele,
// Lea & Flood 2014): streams 1-4 the plant, chamber noise and table, 16 + 4
// per DUT its axes and accelerometers, 1000 + p a DUT's shell probes,
// kRandomizeStream + p a DUT's [simulator.randomize] draws.
uint64_t derive_seed(uint64_t seed, uint64_t stream);
inline constexpr uint64_t kRandomizeStream = 5000;
inline constexpr uint64_t kChamberRandomizeStream = 4999;

// sizeof(sockaddr_un::sun_path) - 1 on Linux.
inline constexpr std::size_t kMaxControlSocketPath = 107;

struct SimulatorOptions {
  std::string endpoints_file;  // "" = do not write one
  std::string truth_file;      // "" = do not write one
  // A symlink kept pointing at the current pty, like /dev/serial/by-id/...:
  // after reopen_pty() the daemon finds the new pty through it. When set,
  // it is the gyro device the endpoints name. "" = none.
  std::string gyro_link;
  // Unix-domain socket for fault-injection commands (control_server.h); at
  // most 107 bytes. "" = none.
  std::string control_socket;
  std::string modbus_host = "127.0.0.1";
  int modbus_port = 0;  // 0 = any free port
  uint64_t seed = 1;
  // The temperature unit the chamber serves its set point, process value and
  // ramp rate in, when its map has a units register (watlow-f4t: 6730).
  // Without one it serves °C.
  drivers::TemperatureUnit chamber_units = drivers::TemperatureUnit::kCelsius;
  double time_scale = 1.0;  // station seconds per wall second
  // With an endpoints file and no injected clock: publish station time in
  // a shared clock file (`<endpoints_file>.clock`, named in the endpoints)
  // that gyrothermd reads, and run no further than it keeps up
  // (core/shared_clock.h). false (--scaled-clock): scale wall time alone.
  bool shared_clock = true;
  ThermalParams thermal;
  GyroParams gyro;
  drivers::GyroFormat gyro_format;  // from [gyro]; its rate_hz is the first DUT's as served
  // --rate-hz: every DUT's output rate (nullopt: each its [[dut]] rate_hz),
  // and per DUT by serial (winning over rate_hz); see dut_rate_hz().
  std::optional<double> rate_hz;
  std::vector<std::pair<std::string, double>> dut_rate_hz;
  // Per-DUT overrides, by serial ([simulator.dut.SN]); DUTs without one get
  // [simulator.gyro] with the default bias offsets (dut_model.h).
  std::vector<DutOverrides> dut_overrides;
  RandomizeRanges randomize;  // [simulator.randomize]; applied last
  // Frames kept while the pty's reader is slow ([simulator]
  // pending_frames_limit); beyond that new frames are dropped (and counted).
  // 0 = five wall seconds of frames, at least 256.
  std::size_t pending_frames_limit = 0;
  // The rate table: served when the station config has [table] or when
  // serve_table is set (--table).
  bool serve_table = false;
  int table_port = 0;  // ACL over TCP on modbus_host; 0 = any free port
  TableParams table;
  ScaleFactorParams scale_factor;

  bool is_valid(std::string* why) const;
};

// Command-line overrides (`gyrotherm-sim --time-scale ... --seed ...`).
struct SimulatorOverrides {
  std::optional<double> time_scale;
  std::optional<std::string> endpoints_file;
  std::optional<std::string> truth_file;
  std::optional<std::string> control_socket;
  std::optional<uint64_t> seed;
  std::optional<double> rate_hz;                                 // --rate-hz HZ: every DUT
  std::vector<std::pair<std::string, double>> dut_rate_hz = {};  // --rate-hz SERIAL=HZ
  std::optional<int> table_port;
  bool serve_table = false;   // --table
  bool scaled_clock = false;  // --scaled-clock: no shared clock file
};

// The output rates a DUT may be served at, Hz (as [[dut]] rate_hz).
inline constexpr double kMinRateHz = 0.1;
inline constexpr double kMaxRateHz = 10000.0;

// `--rate-hz` values, each "HZ" (every DUT) or "SERIAL=HZ" (the DUT with
// that serial; split at the last '='), into `overrides` (rate_hz,
// dut_rate_hz). Error naming the value: not a number, outside [kMinRateHz,
// kMaxRateHz], no serial before '=', HZ or one serial given twice.
Status parse_rate_hz_options(const std::vector<std::string>& values, SimulatorOverrides& overrides);

// "" when every serial of `per_dut` names one of `duts`, else the error
// naming the first that does not, and the station's serials.
std::string unknown_rate_hz_serial(const std::vector<std::pair<std::string, double>>& per_dut,
                                   const std::vector<config::DutSection>& duts);

// The rate `dut` is served at: its --rate-hz SERIAL=HZ, else --rate-hz HZ,
// else its [[dut]] rate_hz.
double dut_rate_hz(const SimulatorOptions& options, const config::DutSection& dut);

// The parameters of `dut` (at `position` in the station's DUT list):
// options.gyro, then its overrides (if any) for every axis, then per axis;
// an axis whose bias_dph no level above [simulator.gyro] set gets the
// default offset (position × 1 °/h + 0.25 °/h × k, k = 0 for the primary
// axis, 1 and 2 for the others in x, y, z order).
// The chamber's plant: [simulator.thermal] with what [simulator.randomize]
// draws for it by the seed (air_tau_s, control_noise_c).
ThermalParams resolve_thermal_params(const SimulatorOptions& options);

DutSimParams resolve_dut_params(const SimulatorOptions& options, const config::DutSection& dut,
                                int position);

// Reads config.simulator_table strictly (unknown keys and out-of-range values
// are errors "file:line: simulator.key: ..."), takes the gyro format from
// config.gyro, then applies the overrides and validates. The error message
// lists every problem, one per line. No [simulator] section: all defaults.
Result<SimulatorOptions> read_simulator_options(const config::StationConfig& config,
                                                const SimulatorOverrides& overrides = {});

}  // namespace gyrotherm::sim
