#include "gyrotherm/drivers/modbus_devices.h"

#include <fmt/format.h>

namespace gyrotherm::drivers {

ModbusChamber::ModbusChamber(ModbusEndpoint endpoint, ChamberMap map)
    : device_("chamber", std::move(endpoint)), map_(std::move(map)) {}

Result<UnitsReading> ModbusChamber::units() {
  if (!map_.units) return UnitsReading{TemperatureUnit::kCelsius, "", 0};
  const UnitsRegister& units = *map_.units;
  auto v = device_.read(units.reg);
  if (!v) return v.error();
  UnitsReading r;
  r.code = *v;
  r.unit = units.decode(*v);
  r.note = r.unit ? fmt::format("units register {} = {}", units.reg.address, *v)
                  : fmt::format("units register {} holds {}, neither °C ({}) nor °F ({})",
                                units.reg.address, *v, units.celsius, units.fahrenheit);
  return r;
}

Result<bool> ModbusChamber::alarm() {
  if (!map_.alarm) return Error::Permanent("chamber: no alarm register in its map");
  auto v = device_.read(map_.alarm->reg);
  if (!v) return v.error();
  return map_.alarm->is_alarm(*v);
}

ModbusProbes::ModbusProbes(ModbusEndpoint endpoint, RegisterSpec top, RegisterSpec side)
    : device_("probes", std::move(endpoint)), top_(top), side_(side) {}

}  // namespace gyrotherm::drivers
