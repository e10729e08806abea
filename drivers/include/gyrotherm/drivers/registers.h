// Modbus register maps: how a value sits in 16-bit registers.
//
// A RegisterSpec says where a quantity lives (address, holding or input),
// how it is encoded (int16, uint16, float32 with a word order) and its scale
// (value = raw x scale). Profiles bundle the specs of known controllers
// (docs/devices.md); a station with another controller writes its own map in the
// config.
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

// Temperature chamber controller: what the daemon reads and writes.
struct ChamberMap {
  RegisterSpec setpoint;       // °C, read/write
  RegisterSpec process_value;  // air temperature °C, read
  // Optional ramp registers (watlow-f4t: rate 2798, action 2794, scale 2796).
  std::optional<RegisterSpec> ramp_rate;
  std::optional<RegisterSpec> ramp_action;
  std::optional<RegisterSpec> ramp_scale;
  // Optional alarm flag (nonzero = the controller reports an alarm). No
  // profile has one: alarm registers depend on how the controller's alarm
  // instances are set up, so the config names it ([chamber.alarm]).
  std::optional<RegisterSpec> alarm;
};

// "watlow-f4t" (Data Map 1: set point 2782, process value 2820, float32 low
// word first, holding), "watlow-f4" (process value 100, set point 300, int16,
// scale 0.1, holding), "generic" (set point holding 0, process value input 0,
// int16, scale 0.1). Unknown name: permanent error listing the known ones.
Result<ChamberMap> chamber_profile(std::string_view name);

// Temperature input module. Profile "generic": channel N is input register N,
// int16, scale 0.1 (°C x 10, as most RTD input modules).
Result<RegisterSpec> probe_channel_spec(std::string_view profile, int channel);

}  // namespace gyrotherm::drivers
