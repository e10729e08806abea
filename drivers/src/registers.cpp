#include "gyrotherm/drivers/registers.h"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>

namespace gyrotherm::drivers {
namespace {

const char* type_name(RegisterType t) {
  switch (t) {
    case RegisterType::kInt16:
      return "int16";
    case RegisterType::kUint16:
      return "uint16";
    case RegisterType::kFloat32:
      return "float32";
  }
  return "?";
}

RegisterSpec spec(int address, RegisterFunction fn, RegisterType type, WordOrder order,
                  double scale) {
  RegisterSpec s;
  s.address = address;
  s.function = fn;
  s.type = type;
  s.word_order = order;
  s.scale = scale;
  return s;
}

Error out_of_range(const RegisterSpec& spec, double value, double raw, const char* range) {
  return Error::Permanent(
      fmt::format("value {} does not fit register {} ({} with scale {}): raw {} outside {}", value,
                  spec.address, type_name(spec.type), spec.scale, raw, range));
}

}  // namespace

double decode_register(const RegisterSpec& spec, std::span<const uint16_t> words) {
  switch (spec.type) {
    case RegisterType::kInt16:
      return static_cast<int16_t>(words[0]) * spec.scale;
    case RegisterType::kUint16:
      return words[0] * spec.scale;
    case RegisterType::kFloat32: {
      const uint32_t hi = spec.word_order == WordOrder::kLowFirst ? words[1] : words[0];
      const uint32_t lo = spec.word_order == WordOrder::kLowFirst ? words[0] : words[1];
      return static_cast<double>(std::bit_cast<float>((hi << 16) | lo)) * spec.scale;
    }
  }
  return 0;
}

Result<std::vector<uint16_t>> encode_register(const RegisterSpec& spec, double value) {
  if (!std::isfinite(value)) {
    return Error::Permanent(
        fmt::format("value {} for register {} is not finite", value, spec.address));
  }
  if (spec.scale == 0 || !std::isfinite(spec.scale)) {
    return Error::Permanent(
        fmt::format("register {} has an invalid scale {}", spec.address, spec.scale));
  }
  const double raw = value / spec.scale;
  switch (spec.type) {
    case RegisterType::kInt16: {
      const double r = std::round(raw);
      if (r < -32768 || r > 32767) return out_of_range(spec, value, r, "-32768..32767");
      return std::vector<uint16_t>{static_cast<uint16_t>(static_cast<int16_t>(r))};
    }
    case RegisterType::kUint16: {
      const double r = std::round(raw);
      if (r < 0 || r > 65535) return out_of_range(spec, value, r, "0..65535");
      return std::vector<uint16_t>{static_cast<uint16_t>(r)};
    }
    case RegisterType::kFloat32: {
      if (std::abs(raw) > std::numeric_limits<float>::max()) {
        return out_of_range(spec, value, raw, "the float32 range");
      }
      const auto bits = std::bit_cast<uint32_t>(static_cast<float>(raw));
      const auto hi = static_cast<uint16_t>(bits >> 16);
      const auto lo = static_cast<uint16_t>(bits & 0xFFFF);
      if (spec.word_order == WordOrder::kLowFirst) return std::vector<uint16_t>{lo, hi};
      return std::vector<uint16_t>{hi, lo};
    }
  }
  return Error::Permanent(fmt::format("register {} has an unknown type", spec.address));
}

Result<RegisterFunction> parse_register_function(std::string_view s) {
  if (s == "holding") return RegisterFunction::kHolding;
  if (s == "input") return RegisterFunction::kInput;
  return Error::Permanent(
      fmt::format("unknown register function '{}' (expected one of: holding, input)", s));
}

Result<RegisterType> parse_register_type(std::string_view s) {
  if (s == "int16") return RegisterType::kInt16;
  if (s == "uint16") return RegisterType::kUint16;
  if (s == "float32") return RegisterType::kFloat32;
  return Error::Permanent(
      fmt::format("unknown register type '{}' (expected one of: int16, uint16, float32)", s));
}

Result<WordOrder> parse_word_order(std::string_view s) {
  if (s == "low-first") return WordOrder::kLowFirst;
  if (s == "high-first") return WordOrder::kHighFirst;
  return Error::Permanent(
      fmt::format("unknown word order '{}' (expected one of: low-first, high-first)", s));
}

bool ChamberAlarm::is_alarm(double value) const {
  const bool listed = std::find(values.begin(), values.end(), value) != values.end();
  return mode == Mode::kOkValues ? !listed : listed;
}

namespace {
// The smallest of `preferred`, 0, 1, 2, ... that is not in `values`.
double first_not_in(const std::vector<double>& values, double preferred) {
  auto in = [&](double v) { return std::find(values.begin(), values.end(), v) != values.end(); };
  if (!in(preferred)) return preferred;
  double v = 0;
  while (in(v)) v += 1;
  return v;
}
}  // namespace

double ChamberAlarm::quiet_value() const {
  if (mode == Mode::kOkValues && !values.empty()) return values.front();
  return first_not_in(values, 0.0);
}

double ChamberAlarm::alarm_value() const {
  if (mode == Mode::kAlarmValues && !values.empty()) return values.front();
  return first_not_in(values, watlow::kAlarmHigh);
}

std::optional<TemperatureUnit> UnitsRegister::decode(double value) const {
  if (value == celsius) return TemperatureUnit::kCelsius;
  if (value == fahrenheit) return TemperatureUnit::kFahrenheit;
  return std::nullopt;
}

double UnitsRegister::encode(TemperatureUnit unit) const {
  return unit == TemperatureUnit::kCelsius ? celsius : fahrenheit;
}

double to_celsius(double value, TemperatureUnit unit) {
  return unit == TemperatureUnit::kCelsius ? value : (value - 32.0) / 1.8;
}

double from_celsius(double celsius, TemperatureUnit unit) {
  return unit == TemperatureUnit::kCelsius ? celsius : celsius * 1.8 + 32.0;
}

const char* unit_symbol(TemperatureUnit unit) {
  return unit == TemperatureUnit::kCelsius ? "°C" : "°F";
}

Result<ChamberMap> chamber_profile(std::string_view name, std::string_view transport) {
  using F = RegisterFunction;
  using T = RegisterType;
  constexpr auto kLow = WordOrder::kLowFirst;
  ChamberMap map;
  if (name == "watlow-f4t") {
    // ChamberConnectLibrary watlowf4t.py: set_loop_sp / get_loop_pv (2782,
    // 2820 for loop 1), __profile_units (6730 over TCP, 14080 over RTU).
    map.setpoint = spec(2782, F::kHolding, T::kFloat32, kLow, 1.0);
    map.process_value = spec(2820, F::kHolding, T::kFloat32, kLow, 1.0);
    map.process_value.read_only = true;
    map.ramp_rate = spec(2798, F::kHolding, T::kFloat32, kLow, 1.0);
    map.ramp_action = spec(2794, F::kHolding, T::kUint16, kLow, 1.0);
    map.ramp_scale = spec(2796, F::kHolding, T::kUint16, kLow, 1.0);
    UnitsRegister units;
    units.reg = spec(transport == "rtu" ? 14080 : 6730, F::kHolding, T::kUint16, kLow, 1.0);
    map.units = units;
    return map;
  }
  if (name == "watlow-f4") {
    map.setpoint = spec(300, F::kHolding, T::kInt16, kLow, 0.1);
    map.process_value = spec(100, F::kHolding, T::kInt16, kLow, 0.1);
    map.process_value.read_only = true;
    return map;
  }
  if (name == "generic") {
    map.setpoint = spec(0, F::kHolding, T::kInt16, kLow, 0.1);
    map.process_value = spec(0, F::kInput, T::kInt16, kLow, 0.1);
    map.process_value.read_only = true;
    return map;
  }
  return Error::Permanent(fmt::format(
      "unknown chamber profile '{}' (expected one of: watlow-f4t, watlow-f4, generic)", name));
}

std::optional<ChamberAlarm> chamber_alarm_default(std::string_view profile) {
  if (profile != "watlow-f4t") return std::nullopt;
  // ChamberConnectLibrary watlowf4t.py get_alarm_status: alarm i (from 0)
  // at 1356 + 100 i is inactive when it reads 88, 61 or 12.
  ChamberAlarm alarm;
  alarm.reg =
      spec(1356, RegisterFunction::kHolding, RegisterType::kUint16, WordOrder::kLowFirst, 1.0);
  alarm.reg.read_only = true;
  alarm.mode = ChamberAlarm::Mode::kOkValues;
  alarm.values = {watlow::kNone, watlow::kStartup, watlow::kAlarmBlocked};
  return alarm;
}

Result<RegisterSpec> probe_channel_spec(std::string_view profile, int channel) {
  if (profile != "generic") {
    return Error::Permanent(
        fmt::format("unknown probe module profile '{}' (expected one of: generic)", profile));
  }
  if (channel < 0 || channel > 65535) {
    return Error::Permanent(
        fmt::format("probe channel {} out of range (expected 0..65535)", channel));
  }
  RegisterSpec s =
      spec(channel, RegisterFunction::kInput, RegisterType::kInt16, WordOrder::kLowFirst, 0.1);
  s.read_only = true;
  return s;
}

}  // namespace gyrotherm::drivers
