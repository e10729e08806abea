// Three devices under test for end-to-end tests: two KVH 1750 on their own
// ptys (one with its own probes) and one ASCII test set, each with its own
// truth ([simulator.dut.*]); they replace the fixture's [gyro].
#pragma once

#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <string>

namespace gyrotherm::testing {

// The three DUTs replace the fixture's [gyro]. Biases are far enough apart
// (≥ 0.6 °/h) that a row stored under the wrong DUT or axis cannot pass.
inline constexpr const char* kDuts = R"([[dut]]
serial = "17-0042"
model = "KVH 1750"
protocol = "kvh1750"
unit = "rad"
output = "rate"
rate_hz = 10.0
silent_timeout_s = 60.0
orientation = { z = "up", x = "horizontal", y = "horizontal" }
primary_axis = "z"

[[dut]]
serial = "17-0043"
model = "KVH 1750"
protocol = "kvh1750"
unit = "deg"
output = "delta"
rate_hz = 10.0
silent_timeout_s = 60.0
axes = ["x", "z"]
orientation = { z = "down", x = "horizontal" }
primary_axis = "z"
probes = { top_channel = 2, side_channel = 3 }

[[dut]]
serial = "TS-7"
model = "rate test set"
protocol = "ascii"
rate_hz = 10.0
silent_timeout_s = 60.0
orientation = { y = "up", x = "horizontal" }
primary_axis = "y"
[dut.ascii]
delimiter = ","
prefix = "$GYR,"
checksum = "nmea"
seq_column = "n"
seq_modulo = 65536
columns = [
  { name = "n" },
  { name = "rate_x", kind = "rate", unit = "deg/s", axis = "x" },
  { name = "rate_y", kind = "rate", unit = "deg/s", axis = "y" },
  { name = "temp_c", kind = "temperature", unit = "degC" },
  { name = "status", kind = "status" },
]
valid_bits = { x = 1, y = 2 }
)";

inline constexpr const char* kDutTruth = R"(
[simulator.dut.17-0042.x]
bias_dph = 1.2
[simulator.dut.17-0042.y]
bias_dph = -0.9
[simulator.dut.17-0043]
bias_dph = 2.5
[simulator.dut.17-0043.x]
bias_dph = 3.4
[simulator.dut.TS-7]
bias_dph = -1.8
[simulator.dut.TS-7.x]
bias_dph = -3.0
)";

// The fixture's station config with the three DUTs instead of its [gyro],
// and their truth; false when the config has no [gyro] ... [storage].
inline bool with_three_duts(std::string& station_toml) {
  const auto from = station_toml.find("[gyro]");
  const auto to = station_toml.find("[storage]");
  if (from == std::string::npos || to == std::string::npos) return false;
  station_toml.replace(from, to - from, std::string(kDuts) + "\n");
  station_toml += kDutTruth;
  return true;
}

// The truth's Table I bias (Earth rate removed) of a DUT axis at temp_c,
// interpolated between its static points (every 5 °C).
inline double three_duts_truth_bias_dph(const nlohmann::json& truth, const std::string& serial,
                                        const std::string& axis, double temp_c) {
  for (const auto& d : truth["duts"]) {
    if (d["serial"] != serial) continue;
    const auto& pts = d["axes"][axis]["static"];
    for (std::size_t i = 0; i + 1 < pts.size(); ++i) {
      const double t0 = pts[i]["temp_c"], t1 = pts[i + 1]["temp_c"];
      if (temp_c < t0 || temp_c > t1) continue;
      const double b0 = pts[i]["bias_earth_removed_dph"], b1 = pts[i + 1]["bias_earth_removed_dph"];
      return b0 + (b1 - b0) * (temp_c - t0) / (t1 - t0);
    }
  }
  ADD_FAILURE() << "no truth for " << serial << " " << axis << " at " << temp_c;
  return NAN;
}

}  // namespace gyrotherm::testing
