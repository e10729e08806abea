// Sample records shared by drivers, storage, analysis and the daemon.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

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

}  // namespace gyrotherm
