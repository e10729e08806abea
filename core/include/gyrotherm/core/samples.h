// Sample records shared by drivers, storage, analysis and the daemon.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace gyrotherm {

// One gyro sample of the configured axis.
struct GyroSample {
  // Station seconds. As produced by the reader: the station clock; once
  // stored: seconds since the run's start.
  double t_s = 0;
  double rate_dph = 0;  // rate about the configured axis, °/h
  uint8_t seq = 0;      // the frame's sequence counter (0..127 for KVH 1750)
  uint8_t status = 0;   // the frame's status byte as sent
  int16_t temp_c = 0;   // gyro's internal temperature as sent, °C
};

// One control-loop reading of the station's temperatures, °C.
struct TemperatureSample {
  double t_s = 0;  // same convention as GyroSample::t_s
  double setpoint_c = 0;
  double chamber_c = 0;
  double top_c = 0;
  double side_c = 0;
};

// One reading of the rate table (turntable) with the demand in force.
// Angles are degrees, rates °/s (the table's own units; gyro rates are °/h).
struct TableSample {
  double t_s = 0;                               // same convention as GyroSample::t_s
  std::string demand_mode{};                    // none, static, rate: the step's demand
  double demand_rate_dps = 0;                   // demanded rate (rate demands; 0 otherwise)
  std::optional<double> demand_position_deg{};  // demanded position; nullopt: none
  double rate_dps = 0;                          // measured rate
  double position_deg = 0;                      // measured position, [0, 360) on a continuous axis
  std::string mode{};                           // servo mode reported: off, rate, position, unknown
  std::string interlock{};                      // open, closed, fault
};

// ---------------------------------------------------------------- devices under test
// A station tests one or more DUTs ([[dut]] in the config), each on its own
// serial line. Every channel a DUT's frame carries is recorded.

// What a channel measures.
enum class ChannelKind {
  kRate,         // an angular rate; physical unit deg/h
  kAccel,        // a specific force; physical unit g
  kTemperature,  // degC
  kStatus,       // a status word, as sent (bit meanings per protocol)
  kOther,        // anything else a line carries (unit as declared)
};
std::string_view to_string(ChannelKind kind);  // rate, accel, temperature, status, other
std::optional<ChannelKind> channel_kind_from_string(std::string_view s);

// One channel of a DUT's frames. A frame carries raw values as sent (a
// KVH 1750's float32 in rad/s, say); physical = raw * scale, in `unit`.
// Storage keeps the raw value (exactly: float32 when the device sent
// float32), so an exported sample equals what the station computed live.
struct ChannelSpec {
  std::string name;  // unique within the DUT: gyro_x, accel_z, status, temp_c, or a column name
  std::string unit;  // physical unit: deg/h, g, degC, "" for status
  ChannelKind kind = ChannelKind::kOther;
  std::string axis;  // "x", "y", "z" for rate and accel channels; "" otherwise
  double scale = 1.0;
};

inline constexpr std::size_t kMaxChannels = 16;

// One frame of one DUT, timestamped on the station clock (seconds; once
// stored, seconds since the run's start). raw[i] belongs to channel i of the
// DUT's channel list; a value the frame flags invalid (a KVH status bit
// clear) is NaN. Channels beyond the DUT's count are unused.
struct DutFrame {
  double t_s = 0;
  uint32_t seq = 0;  // the frame's sequence counter as sent (0 when the protocol has none)
  std::array<double, kMaxChannels> raw{};
};

}  // namespace gyrotherm
