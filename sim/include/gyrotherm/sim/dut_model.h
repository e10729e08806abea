// One simulated device under test ([[dut]], docs/simulator.md "Several
// DUTs"): three gyro axes and three accelerometers, its shell temperature and
// probes, and the bytes its line carries (KVH 1750 frames or ASCII lines).
//
// Each gyro axis is a GyroModel (gyro_model.h) with its own parameters, seed
// and Earth-rate component: the axis's orientation and heading in the DUT's
// config (up: +Ω sin φ, down: −Ω sin φ, horizontal with heading h:
// Ω cos φ cos h, horizontal without one: 0, as analysis::
// earth_rate_component_dph). With a table served every DUT is on it: its
// table_axis sees the rate table through the scale factor
// (GyroModel::enable_table; a radial one from its own heading when it has
// one); its other axes are taken perpendicular to the spin axis, see no
// table rate, and a horizontal one with a heading turns with the table
// (GyroModel::turn_with_table: Ω cos φ cos(h + position)). Each
// accelerometer reads gravity along its axis (up +1 g, down −1 g, horizontal
// 0) plus white noise. Status: every channel valid. Internal temperature:
// the shell ("case") temperature plus internal_temp_offset_c.
//
// The shell follows the station's plant (its case, gradient and probes) unless
// the DUT overrides a case parameter ([simulator.dut.SN] case_tau_s, ...):
// then it has its own case, lagging the chamber air with the same
// discretisation as ThermalPlant. The DUT's own probes (DutSection::probes)
// read its top/side plus probe_offset_c, with the plant's probe noise and
// quantum. Deterministic given the seeds. Not thread-safe.
#pragma once

#include <array>
#include <cstdint>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/sim/gyro_model.h"
#include "gyrotherm/sim/thermal_plant.h"

namespace gyrotherm::sim {

inline constexpr std::array<const char*, 3> kAxisNames = {"x", "y", "z"};
// Index of "x", "y", "z"; -1 otherwise.
int axis_index(std::string_view axis);

// Default bias offsets that tell DUTs and axes apart when the config gives no
// bias_dph of its own: position × kDefaultDutBiasStepDph, plus
// kDefaultAxisBiasStepDph × k for the k-th axis other than the primary (in x,
// y, z order; the primary axis k = 0). The first DUT's primary axis is thus
// exactly [simulator.gyro].
inline constexpr double kDefaultDutBiasStepDph = 1.0;
inline constexpr double kDefaultAxisBiasStepDph = 0.25;

// A DUT's own case ([simulator.dut.SN] keys of the same names as
// [simulator.thermal]); unset = the plant's value. Any set: the DUT has its
// own case; none set: it shares the plant's.
struct DutCaseParams {
  std::optional<double> case_tau_s;
  std::optional<double> gradient_c_per_c_per_min;
  std::optional<double> gradient_offset_c;
  std::optional<double> gradient_tau_s;
  bool own() const {
    return case_tau_s || gradient_c_per_c_per_min || gradient_offset_c || gradient_tau_s;
  }
};

// One DUT's simulation parameters, resolved from [simulator.gyro],
// [simulator.dut.SN] and its per-axis tables [simulator.dut.SN.x] (in that
// order of precedence, the last winning).
struct DutSimParams {
  std::string serial;
  std::array<GyroParams, 3> axes;           // x, y, z
  std::array<bool, 3> bias_given{};         // bias_dph set for this DUT or axis (no default offset)
  std::array<double, 3> bias_offset_dph{};  // the default offset added (0 when given)
  double accel_noise_g = 1e-4;
  double internal_temp_offset_c = 0.0;  // internal temperature − shell temperature
  double probe_offset_c = 0.0;          // the DUT's probes read top/side + this
  DutCaseParams case_params;
};

// The DUT's shell: shared with the plant, or its own case following the air.
class DutShell {
 public:
  DutShell(const ThermalParams& plant, const DutCaseParams& own, double probe_offset_c,
           uint64_t seed);
  // After the plant stepped by dt_s: follows it (own case: lags its air).
  void step(double dt_s, const ThermalTruth& plant);
  const ThermalTruth& truth() const { return truth_; }
  bool own() const { return own_; }
  // The DUT's probe readings (top/side + offset, noise, quantum) at the last step.
  const ProbeReadings& readings() const { return readings_; }
  const ThermalParams& params() const { return params_; }

 private:
  double read_probe(double true_c);

  ThermalParams params_;  // the plant's with the DUT's overrides
  bool own_;
  double probe_offset_c_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  ThermalTruth truth_;
  ProbeReadings readings_;
};

// What one frame carried, physical units.
struct DutSample {
  std::array<double, 3> rate_dph{};
  std::array<double, 3> accel_g{};
  double temp_c = 0;  // internal temperature (KVH: rounded to whole °C on the line)
  uint32_t seq = 0;
};

struct AxisSetup {
  analysis::AxisOrientation orientation = analysis::AxisOrientation::kHorizontal;
  std::optional<double> heading_deg;  // a horizontal axis's [[dut]] heading_deg
  double earth_rate_dph = 0;          // at table position 0
  double gravity_g = 0;
  bool on_table = false;          // the table_axis, with a table served
  bool turns_with_table = false;  // a horizontal axis with a heading, with a table served
};

class DutModel {
 public:
  // `dut` the config's entry at `position`; `table` the mount when a table is
  // served (the DUT's table_axis goes on it). `axis_seeds` one per axis.
  // Permanent error: an unknown protocol or ASCII layout (dut_channels), a
  // primary or table axis that is not x, y or z.
  static Result<DutModel> create(const config::DutSection& dut, int position,
                                 const DutSimParams& params, const config::StationSection& station,
                                 const std::optional<TableMount>& table,
                                 const ScaleFactorParams& scale_factor,
                                 const std::array<uint64_t, 3>& axis_seeds, uint64_t accel_seed);

  // One frame: advances every axis by one sample period and returns what it
  // carried; `bytes` gets the encoded frame (a KVH 1750 frame or an ASCII
  // line with its "\r\n").
  DutSample next_frame(const ThermalTruth& shell, const TableInput& table,
                       std::vector<uint8_t>& bytes);

  double sample_period_s() const { return 1.0 / dut_.link.rate_hz; }
  const config::DutSection& dut() const { return dut_; }
  int position() const { return position_; }
  int primary_axis() const { return primary_; }
  bool ascii() const { return dut_.link.protocol == "ascii"; }
  const GyroModel& axis_model(int axis) const { return axes_[static_cast<std::size_t>(axis)]; }
  const AxisSetup& axis_setup(int axis) const { return setup_[static_cast<std::size_t>(axis)]; }
  const std::vector<ChannelSpec>& channels() const { return channels_; }
  const DutSimParams& params() const { return params_; }
  const DutSample& last() const { return last_; }

  // The DUT's truth (docs/simulator.md): per axis its parameters, Earth
  // rate, gravity and the static means Table I should recover at
  // `static_temps_c` (shell gradient = its steady offset, dT/dt = 0).
  nlohmann::json truth(const DutShell& shell, const std::vector<double>& static_temps_c,
                       bool table_served) const;

 private:
  DutModel(config::DutSection dut, int position, DutSimParams params, std::vector<GyroModel> axes,
           std::array<AxisSetup, 3> setup, int primary, std::vector<ChannelSpec> channels,
           uint64_t accel_seed);

  config::DutSection dut_;
  int position_;
  DutSimParams params_;
  std::vector<GyroModel> axes_;  // x, y, z
  std::array<AxisSetup, 3> setup_;
  int primary_;
  std::vector<ChannelSpec> channels_;  // dut_channels(link)
  std::mt19937_64 accel_rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  uint32_t seq_ = 0;
  DutSample last_;
};

// The DUTs the simulator serves: config.duts, or (a config loaded before
// [[dut]] existed) one unnamed DUT made from [gyro] and [station].
std::vector<config::DutSection> simulated_duts(const config::StationConfig& config);

// The index of `dut`'s primary axis: primary_axis, else the last of axes,
// else z; -1 when that names no axis x, y or z.
int primary_axis_index(const config::DutSection& dut);

// The orientation of `axis` (0..2) on `dut`: its orientation entry; else
// `station_orientation` for the primary axis, horizontal for the others.
analysis::AxisOrientation axis_orientation(const config::DutSection& dut, int axis,
                                           analysis::AxisOrientation station_orientation);

}  // namespace gyrotherm::sim
