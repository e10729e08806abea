// Modbus register maps: how a value sits in 16-bit registers.
//
// A RegisterSpec says where a quantity lives (address, holding or input),
// how it is encoded (int16, uint16, float32 with a word order) and its scale
// (value = raw x scale) and whether a client may write it. Profiles bundle
// the specs of known controllers (docs/devices.md); a station with another controller writes
// its own map in the config.
//
// Watlow F4T: the addresses and enumerations below follow Watlow's F4T
// Modbus map as used by ESPEC North America's ChamberConnectLibrary
// (github.com/EspecNorthAmerica/ChamberConnectLibrary,
// chamberconnectlibrary/watlowf4t.py): loop 1 set point 2782 and process
// value 2820 (IEEE float, low word first), alarm n state 1356 + 100 (n - 1),
// the temperature units of values served over Modbus TCP 6730 (RTU: 14080),
// and Watlow's enumerated values (61 none, 62 off, 88 startup, 15 °C, 30 °F,
// 57 minutes, 39 hours...).
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"

namespace gyrotherm::drivers {

enum class RegisterFunction { kHolding, kInput };
enum class RegisterType { kInt16, kUint16, kFloat32 };
// For 32-bit values: which 16-bit word comes at the lower address.
enum class WordOrder { kLowFirst, kHighFirst };

struct RegisterSpec {
  int address = 0;
  RegisterFunction function = RegisterFunction::kHolding;
  RegisterType type = RegisterType::kFloat32;
  WordOrder word_order = WordOrder::kLowFirst;
  double scale = 1.0;  // value = raw x scale
  // The controller refuses writes (a process value, a state). Config maps
  // mark the process value read-only; the simulator answers a write to it
  // with exception 2.
  bool read_only = false;

  int word_count() const { return type == RegisterType::kFloat32 ? 2 : 1; }
};

// Decodes `words` (exactly word_count() registers, in address order).
double decode_register(const RegisterSpec& spec, std::span<const uint16_t> words);

// Encodes a physical value into registers in address order. Errors
// (permanent) when the value is not finite or does not fit the type after
// scaling (e.g. 4000 °C into int16 with scale 0.1).
Result<std::vector<uint16_t>> encode_register(const RegisterSpec& spec, double value);

// Parsing of the names used in config files.
Result<RegisterFunction> parse_register_function(std::string_view s);  // "holding", "input"
Result<RegisterType> parse_register_type(std::string_view s);  // "int16", "uint16", "float32"
Result<WordOrder> parse_word_order(std::string_view s);        // "low-first", "high-first"

// Watlow's enumerated values (F4T data map; ChamberConnectLibrary's
// watlow_val_dict, watlowf4t.py).
namespace watlow {
inline constexpr uint16_t kNone = 61;
inline constexpr uint16_t kOff = 62;
inline constexpr uint16_t kStartup = 88;
inline constexpr uint16_t kBoth = 13;
// Ramp action "Set Point Change": Watlow's enumeration (EZ-ZONE and F4T
// manuals); the library does not name it.
inline constexpr uint16_t kSetPointChange = 1647;
inline constexpr uint16_t kMinutes = 57;  // ramp scale
inline constexpr uint16_t kHours = 39;
inline constexpr uint16_t kCelsius = 15;  // temperature units
inline constexpr uint16_t kFahrenheit = 30;
// Alarm state (alarm n: register 1356 + 100 (n - 1)).
inline constexpr uint16_t kAlarmBlocked = 12;
inline constexpr uint16_t kAlarmHigh = 7;
inline constexpr uint16_t kAlarmLow = 8;
inline constexpr uint16_t kAlarmError = 28;
}  // namespace watlow

// An alarm state register and which of its values mean alarm. Either the
// values that mean "no alarm" (every other value is an alarm, the safe
// reading of an enumeration: the F4T's states None 61, Startup 88 and
// Blocked 12 are quiet, Alarm High 7, Alarm Low 8, Error 28 and anything
// unknown trip), or the values that mean alarm (every other is quiet).
struct ChamberAlarm {
  RegisterSpec reg;
  enum class Mode { kOkValues, kAlarmValues } mode = Mode::kOkValues;
  std::vector<double> values = {0.0};  // default: 0 = no alarm, anything else = alarm

  bool is_alarm(double value) const;
  // What a simulated controller serves: a quiet value and an alarm value.
  double quiet_value() const;
  double alarm_value() const;
};

enum class TemperatureUnit { kCelsius, kFahrenheit };

// A register saying which temperature unit the controller's set point and
// process value are in.
struct UnitsRegister {
  RegisterSpec reg;
  double celsius = watlow::kCelsius;
  double fahrenheit = watlow::kFahrenheit;

  // nullopt when the value is neither.
  std::optional<TemperatureUnit> decode(double value) const;
  double encode(TemperatureUnit unit) const;
};

double to_celsius(double value, TemperatureUnit unit);
double from_celsius(double celsius, TemperatureUnit unit);
const char* unit_symbol(TemperatureUnit unit);  // "°C", "°F"

// Temperature chamber controller: what the daemon reads and writes.
struct ChamberMap {
  RegisterSpec setpoint;       // °C, read/write
  RegisterSpec process_value;  // air temperature °C, read
  // Optional ramp registers (watlow-f4t: rate 2798, action 2794 with
  // Watlow's enumerations Off 62, Startup 88, Set Point Change 1647, Both
  // 13; scale 2796, Minutes 57 or Hours 39).
  std::optional<RegisterSpec> ramp_rate;
  std::optional<RegisterSpec> ramp_action;
  std::optional<RegisterSpec> ramp_scale;
  // Optional alarm state (the chamber_alarm interlock). Only when the config
  // asks for it ([chamber.alarm]); chamber_alarm_default() gives the
  // profile's register and values.
  std::optional<ChamberAlarm> alarm;
  // Where the profile knows it: the units the controller serves
  // temperatures in (watlow-f4t: 6730 over TCP, 14080 over RTU). Without it
  // the controller is taken to serve °C.
  std::optional<UnitsRegister> units;
};

// "watlow-f4t" (set point 2782, process value 2820, float32 low word
// first, holding; ramp registers; units 6730, or 14080 when `transport` is
// "rtu"), "watlow-f4" (process value 100, set point 300, int16, scale 0.1,
// holding), "generic" (set point holding 0, process value input 0, int16,
// scale 0.1). Process values are read-only. Unknown name: permanent error
// listing the known ones.
Result<ChamberMap> chamber_profile(std::string_view name, std::string_view transport = "tcp");

// The alarm a profile reads when the config asks for one without saying
// more: watlow-f4t alarm 1's state (holding 1356, uint16, read-only; quiet
// values None 61, Startup 88, Blocked 12); any other profile (and custom
// maps): nullopt, the config must name the register (0 = quiet).
std::optional<ChamberAlarm> chamber_alarm_default(std::string_view profile);

// Temperature input module. Profile "generic": channel N is input register N,
// int16, scale 0.1 (°C x 10, as most RTD input modules).
Result<RegisterSpec> probe_channel_spec(std::string_view profile, int channel);

}  // namespace gyrotherm::drivers
