// The time scales (station seconds per wall second) that the daemon and the
// simulator accept with --time-scale.
//
// Measured (docs/simulator.md, "Time"): with a 10 Hz gyro, a soak stores
// every sample up to kMaxTimeScale; above it the pty stream and the sample
// writer fall behind, so higher scales are refused rather than run badly.
#pragma once

namespace gyrotherm {

inline constexpr double kMinTimeScale = 1e-3;
inline constexpr double kMaxTimeScale = 1e4;

}  // namespace gyrotherm
