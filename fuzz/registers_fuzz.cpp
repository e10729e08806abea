// Fuzzes Modbus register decoding and encoding (drivers/registers.h).
//
// Every profile's specs (chamber_profile, probe_channel_spec) and a spec
// made of fuzz bytes decode fuzz register words. Checked: integer types give
// raw x scale exactly and survive a round trip through encode_register;
// float32 with scale 1 gives back the same words for every finite value;
// encode_register never accepts a value it cannot represent. The name
// parsers get fuzz strings.
#include <fuzzer/FuzzedDataProvider.h>

#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "fuzz_check.h"
#include "gyrotherm/drivers/registers.h"

using namespace gyrotherm::drivers;

namespace {

void check_spec(const RegisterSpec& spec, FuzzedDataProvider& in) {
  std::vector<uint16_t> words;
  for (int i = 0; i < spec.word_count(); ++i) words.push_back(in.ConsumeIntegral<uint16_t>());
  const double v = decode_register(spec, words);

  if (spec.type != RegisterType::kFloat32) {
    const double raw = spec.type == RegisterType::kInt16 ? static_cast<int16_t>(words[0])
                                                         : static_cast<double>(words[0]);
    FUZZ_CHECK(v == raw * spec.scale);
    // Scales far from 1 lose the raw value to rounding: no round trip then.
    const double mag = std::abs(spec.scale);
    if (mag >= 1e-6 && mag <= 1e6) {
      const auto back = encode_register(spec, v);
      FUZZ_CHECK(back.ok());
      FUZZ_CHECK(*back == words);
    }
  } else if (spec.scale == 1.0 && std::isfinite(v)) {
    const auto back = encode_register(spec, v);
    FUZZ_CHECK(back.ok());
    FUZZ_CHECK(*back == words);
  }

  // Encoding an arbitrary value: refused, or decodes back close to it.
  const double value = in.ConsumeFloatingPoint<double>();
  const auto enc = encode_register(spec, value);
  if (!std::isfinite(value)) FUZZ_CHECK(!enc.ok());
  if (enc.ok()) {
    FUZZ_CHECK(enc->size() == static_cast<std::size_t>(spec.word_count()));
    const double dec = decode_register(spec, *enc);
    FUZZ_CHECK(std::isfinite(dec) || std::abs(value) > 1e30);
    const double mag = std::abs(spec.scale);
    if (spec.type != RegisterType::kFloat32 && mag >= 1e-6 && mag <= 1e6) {
      const bool close =
          std::abs(dec - value) <= std::abs(spec.scale) * 0.5000001 + 1e-9 * std::abs(value);
      if (!close)
        std::fprintf(stderr, "scale %.17g value %.17g decoded %.17g\n", spec.scale, value, dec);
      FUZZ_CHECK(close);
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider in(data, size);

  for (const char* name : {"watlow-f4t", "watlow-f4", "generic"}) {
    const auto map = chamber_profile(name);
    FUZZ_CHECK(map.ok());
    check_spec(map->setpoint, in);
    check_spec(map->process_value, in);
    for (const auto& opt : {map->ramp_rate, map->ramp_action, map->ramp_scale}) {
      if (opt) check_spec(*opt, in);
    }
    if (map->alarm) check_spec(map->alarm->reg, in);
    if (map->units) check_spec(map->units->reg, in);
  }
  const int channel = in.ConsumeIntegral<int>();
  const auto probe = probe_channel_spec("generic", channel);
  FUZZ_CHECK(probe.ok() == (channel >= 0 && channel <= 65535));
  if (probe.ok()) check_spec(*probe, in);

  RegisterSpec spec;
  spec.address = in.ConsumeIntegralInRange<int>(0, 65535);
  spec.function = in.ConsumeBool() ? RegisterFunction::kHolding : RegisterFunction::kInput;
  spec.type =
      in.PickValueInArray({RegisterType::kInt16, RegisterType::kUint16, RegisterType::kFloat32});
  spec.word_order = in.ConsumeBool() ? WordOrder::kLowFirst : WordOrder::kHighFirst;
  constexpr std::array<double, 6> kScales{1.0, 0.1, 0.01, 10.0, -0.5, 0.0};
  spec.scale = in.ConsumeBool() ? in.PickValueInArray(kScales) : in.ConsumeFloatingPoint<double>();
  check_spec(spec, in);

  const std::string name = in.ConsumeRandomLengthString(32);
  const auto fn = parse_register_function(name);
  FUZZ_CHECK(fn.ok() == (name == "holding" || name == "input"));
  const auto type = parse_register_type(name);
  FUZZ_CHECK(type.ok() == (name == "int16" || name == "uint16" || name == "float32"));
  const auto order = parse_word_order(name);
  FUZZ_CHECK(order.ok() == (name == "low-first" || name == "high-first"));
  const auto profile = chamber_profile(name);
  FUZZ_CHECK(profile.ok() == (name == "watlow-f4t" || name == "watlow-f4" || name == "generic"));
  return 0;
}
