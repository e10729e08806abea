// The station's Modbus devices (devices.h) over libmodbus: a chamber
// controller through its register map (ChamberMap: the vendor's map, see
// registers.h) and a probe module through two channel registers. Used by
// the daemon's station and by the CLI's `devices` and `chamber setpoint`.
#pragma once

#include <functional>
#include <string>

#include "gyrotherm/drivers/devices.h"
#include "gyrotherm/drivers/modbus_device.h"
#include "gyrotherm/drivers/registers.h"

namespace gyrotherm::drivers {

class ModbusChamber final : public Chamber {
 public:
  ModbusChamber(ModbusEndpoint endpoint, ChamberMap map);

  const std::string& name() const override { return device_.name(); }
  Status connect() override { return device_.connect(); }
  DeviceHealth health() const override { return device_.health(); }
  // A map without a units register: °C, nothing read.
  Result<UnitsReading> units() override;
  Result<double> process_value() override { return device_.read(map_.process_value); }
  Result<double> setpoint() override { return device_.read(map_.setpoint); }
  Status write_setpoint(double value) override { return device_.write(map_.setpoint, value); }
  bool has_alarm() const override { return map_.alarm.has_value(); }
  // Error when the map has no alarm.
  Result<bool> alarm() override;

  // Wall seconds of every request (the latency histogram); set before use.
  void set_latency_observer(std::function<void(double seconds)> observer) {
    device_.set_latency_observer(std::move(observer));
  }

 private:
  ModbusDevice device_;
  ChamberMap map_;
};

class ModbusProbes final : public ShellProbes {
 public:
  ModbusProbes(ModbusEndpoint endpoint, RegisterSpec top, RegisterSpec side);

  const std::string& name() const override { return device_.name(); }
  Status connect() override { return device_.connect(); }
  DeviceHealth health() const override { return device_.health(); }
  Result<double> top_c() override { return device_.read(top_); }
  Result<double> side_c() override { return device_.read(side_); }

  void set_latency_observer(std::function<void(double seconds)> observer) {
    device_.set_latency_observer(std::move(observer));
  }

 private:
  ModbusDevice device_;
  RegisterSpec top_, side_;
};

}  // namespace gyrotherm::drivers
