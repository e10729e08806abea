// Unit conversions and physical constants used across modules.
// Gyro rates are stored and analysed in degrees per hour (°/h).
#pragma once

#include <cmath>
#include <numbers>

namespace gyrotherm::units {

inline constexpr double kDegPerRad = 180.0 / std::numbers::pi;
inline constexpr double kSecondsPerHour = 3600.0;
// Earth's sidereal rotation rate, °/h.
inline constexpr double kEarthRateDph = 15.041067;

constexpr double dps_to_dph(double dps) { return dps * kSecondsPerHour; }
constexpr double dph_to_dps(double dph) { return dph / kSecondsPerHour; }
constexpr double rad_to_deg(double rad) { return rad * kDegPerRad; }
constexpr double deg_to_rad(double deg) { return deg / kDegPerRad; }

}  // namespace gyrotherm::units
