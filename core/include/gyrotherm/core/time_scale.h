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

// A daemon that scales wall time on its own (--clock scaled) against a
// simulator that does the same: two clocks, and reader latency in wall
// seconds times the scale becomes station seconds of misplaced samples.
// Measured on a loaded 2-core machine: x10 held, x100 put a scale factor's
// samples 100 s late. Above this `--clock scaled` is refused (a
// simulator without a clock file gets a warning); the simulator's shared
// clock (--clock sim) holds at any scale, running slower when it must.
inline constexpr double kMaxScaledSimTimeScale = 10.0;

}  // namespace gyrotherm
