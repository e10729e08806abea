// The station's devices as the run controller sees them: the chamber's
// temperature controller, the probe module on the gyro's shell, and each
// DUT's stream of timestamped frames.
//
// The Station takes its devices as these interfaces (StationDevices). The
// real ones are ModbusChamber and ModbusProbes (modbus_devices.h: a vendor's
// register map over libmodbus) and the DUT readers (dut_reader.h: a protocol
// on a serial line, one DutSource per [[dut]]); the station's unit tests hand
// it fakes. A new kind of device (a rate table) is one more interface here,
// one implementation beside the others and one more member of
// StationDevices.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/drivers/frame_parser.h"
#include "gyrotherm/drivers/registers.h"

namespace gyrotherm::drivers {

// How a request/reply device has been doing, for the status report.
struct DeviceHealth {
  bool connected = false;
  std::string last_success_utc;  // wall time of the last successful request, "" if none
  uint64_t requests = 0;
  uint64_t errors = 0;
  uint64_t reconnects = 0;
  std::string last_error;
  double last_latency_ms = 0;
};

// A device the station polls. Errors name the device and the cause; losing
// the link is a transient error and the next call tries again. Calls may
// come from more than one thread (the control loop, the status report).
class PolledDevice {
 public:
  virtual ~PolledDevice() = default;
  virtual const std::string& name() const = 0;
  // Connects now. Unreachable: transient (later calls reconnect by
  // themselves); a bad address: permanent.
  virtual Status connect() = 0;
  virtual DeviceHealth health() const = 0;
};

// What a chamber says about the unit it serves temperatures in.
struct UnitsReading {
  // nullopt: the controller names neither °C nor °F (`note` says what).
  std::optional<TemperatureUnit> unit;
  // Where the unit came from, for the log: "units register 6730 = 15", or
  // "units register 6730 holds 5, neither °C (15) nor °F (30)". Empty for a
  // controller without a units register (it serves °C).
  std::string note;
  double code = 0;  // what the register held
};

// The chamber's temperature controller. Temperatures are in the unit the
// controller serves (units()); the station converts.
class Chamber : public PolledDevice {
 public:
  // Read at each call: the unit can be changed at the controller. Error: no
  // answer.
  virtual Result<UnitsReading> units() = 0;
  virtual Result<double> process_value() = 0;  // air temperature
  virtual Result<double> setpoint() = 0;
  virtual Status write_setpoint(double value) = 0;
  // Whether an alarm state is read (the chamber_alarm interlock) and, then,
  // whether the controller is in alarm.
  virtual bool has_alarm() const = 0;
  virtual Result<bool> alarm() = 0;
};

// The two temperature probes on the gyro's shell, in °C.
class ShellProbes : public PolledDevice {
 public:
  virtual Result<double> top_c() = 0;
  virtual Result<double> side_c() = 0;
};

// How a gyro stream has been doing, for the status report.
struct GyroReaderHealth {
  bool connected = false;
  uint64_t samples = 0;          // samples emitted
  uint64_t invalid_samples = 0;  // frames whose axis-valid bit was clear
  ParserCounters parser;         // frames, CRC failures, skipped bytes, gaps
  uint64_t reopens = 0;          // times the port was (re)opened after the first
  uint64_t read_errors = 0;
  double last_sample_station_s = -1;  // station time of the last sample, -1 if none
  std::string last_error;
};

// One device under test's frames (every channel), timestamped in station
// seconds, in batches (a DUT per [[dut]] entry); health() counts frames as
// `samples`.
class DutSource {
 public:
  using Sink = std::function<void(std::span<const DutFrame>)>;
  virtual ~DutSource() = default;
  // The channels of every frame, in raw[] order; fixed for the source's life.
  virtual const std::vector<ChannelSpec>& channels() const = 0;
  // Starts delivering: `sink` is called with each batch, on the source's
  // thread (or the caller's, for a fake); it must not block for long.
  virtual void start(Sink sink) = 0;
  virtual void stop() = 0;  // idempotent; no batch after it returns
  virtual GyroReaderHealth health() const = 0;
};

}  // namespace gyrotherm::drivers
