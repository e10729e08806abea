#include "gyrotherm/drivers/registers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

namespace gyrotherm::drivers {
namespace {

RegisterSpec make(RegisterType type, WordOrder order = WordOrder::kLowFirst, double scale = 1.0) {
  RegisterSpec s;
  s.address = 100;
  s.type = type;
  s.word_order = order;
  s.scale = scale;
  return s;
}

std::vector<uint16_t> encode_ok(const RegisterSpec& spec, double value) {
  auto r = encode_register(spec, value);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message);
  return r.ok() ? *r : std::vector<uint16_t>{};
}

TEST(Registers, Float32LowWordFirst) {
  const auto spec = make(RegisterType::kFloat32, WordOrder::kLowFirst);
  EXPECT_EQ(spec.word_count(), 2);
  // 23.5f = 0x41BC0000
  EXPECT_EQ(encode_ok(spec, 23.5), (std::vector<uint16_t>{0x0000, 0x41BC}));
  const std::vector<uint16_t> words{0x0000, 0x41BC};
  EXPECT_EQ(decode_register(spec, words), 23.5);
  // -20.25f = 0xC1A20000
  EXPECT_EQ(encode_ok(spec, -20.25), (std::vector<uint16_t>{0x0000, 0xC1A2}));
  // 0.1f = 0x3DCCCCCD: both words non-zero
  EXPECT_EQ(encode_ok(spec, 0.1), (std::vector<uint16_t>{0xCCCD, 0x3DCC}));
}

TEST(Registers, Float32HighWordFirst) {
  const auto spec = make(RegisterType::kFloat32, WordOrder::kHighFirst);
  EXPECT_EQ(encode_ok(spec, 23.5), (std::vector<uint16_t>{0x41BC, 0x0000}));
  EXPECT_EQ(encode_ok(spec, 0.1), (std::vector<uint16_t>{0x3DCC, 0xCCCD}));
  const std::vector<uint16_t> words{0x3DCC, 0xCCCD};
  EXPECT_EQ(decode_register(spec, words), static_cast<double>(0.1f));
}

TEST(Registers, Float32WithScale) {
  const auto spec = make(RegisterType::kFloat32, WordOrder::kLowFirst, 0.5);
  // raw 47 = 0x423C0000
  EXPECT_EQ(encode_ok(spec, 23.5), (std::vector<uint16_t>{0x0000, 0x423C}));
  EXPECT_EQ(decode_register(spec, std::vector<uint16_t>{0x0000, 0x423C}), 23.5);
}

TEST(Registers, Int16NegativeWithImpliedDecimal) {
  const auto spec = make(RegisterType::kInt16, WordOrder::kLowFirst, 0.1);
  EXPECT_EQ(spec.word_count(), 1);
  EXPECT_EQ(encode_ok(spec, -20.5), (std::vector<uint16_t>{0xFF33}));
  EXPECT_NEAR(decode_register(spec, std::vector<uint16_t>{0xFF33}), -20.5, 1e-12);
  EXPECT_EQ(encode_ok(spec, 60.3), (std::vector<uint16_t>{603}));
  EXPECT_NEAR(decode_register(spec, std::vector<uint16_t>{603}), 60.3, 1e-12);
  EXPECT_EQ(encode_ok(spec, 3276.7), (std::vector<uint16_t>{0x7FFF}));
  EXPECT_EQ(encode_ok(spec, -3276.8), (std::vector<uint16_t>{0x8000}));
  EXPECT_NEAR(decode_register(spec, std::vector<uint16_t>{0x8000}), -3276.8, 1e-9);
}

TEST(Registers, Uint16) {
  const auto spec = make(RegisterType::kUint16);
  EXPECT_EQ(encode_ok(spec, 57), (std::vector<uint16_t>{57}));
  EXPECT_EQ(encode_ok(spec, 65535), (std::vector<uint16_t>{0xFFFF}));
  EXPECT_EQ(decode_register(spec, std::vector<uint16_t>{0xFFFF}), 65535.0);
  const auto scaled = make(RegisterType::kUint16, WordOrder::kLowFirst, 0.01);
  EXPECT_EQ(encode_ok(scaled, 1.5), (std::vector<uint16_t>{150}));
}

TEST(Registers, OutOfRangeValuesAreErrors) {
  const auto i16 = make(RegisterType::kInt16, WordOrder::kLowFirst, 0.1);
  auto r = encode_register(i16, 4000.0);
  ASSERT_FALSE(r.ok());
  EXPECT_FALSE(r.error().transient);
  EXPECT_NE(r.error().message.find("4000"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("int16"), std::string::npos) << r.error().message;
  EXPECT_FALSE(encode_register(i16, -3276.9).ok());

  const auto u16 = make(RegisterType::kUint16);
  EXPECT_FALSE(encode_register(u16, -1.0).ok());
  EXPECT_FALSE(encode_register(u16, 65536.0).ok());

  const auto f32 = make(RegisterType::kFloat32);
  EXPECT_FALSE(encode_register(f32, 1e39).ok());
  EXPECT_FALSE(encode_register(f32, std::numeric_limits<double>::quiet_NaN()).ok());
  EXPECT_FALSE(encode_register(i16, std::numeric_limits<double>::infinity()).ok());

  const auto zero_scale = make(RegisterType::kInt16, WordOrder::kLowFirst, 0.0);
  EXPECT_FALSE(encode_register(zero_scale, 1.0).ok());
}

TEST(Registers, ParseNames) {
  EXPECT_EQ(*parse_register_function("holding"), RegisterFunction::kHolding);
  EXPECT_EQ(*parse_register_function("input"), RegisterFunction::kInput);
  EXPECT_EQ(*parse_register_type("int16"), RegisterType::kInt16);
  EXPECT_EQ(*parse_register_type("uint16"), RegisterType::kUint16);
  EXPECT_EQ(*parse_register_type("float32"), RegisterType::kFloat32);
  EXPECT_EQ(*parse_word_order("low-first"), WordOrder::kLowFirst);
  EXPECT_EQ(*parse_word_order("high-first"), WordOrder::kHighFirst);

  auto t = parse_register_type("int32");
  ASSERT_FALSE(t.ok());
  EXPECT_FALSE(t.error().transient);
  EXPECT_NE(t.error().message.find("'int32'"), std::string::npos);
  EXPECT_NE(t.error().message.find("int16, uint16, float32"), std::string::npos);
  auto f = parse_register_function("coil");
  ASSERT_FALSE(f.ok());
  EXPECT_NE(f.error().message.find("holding, input"), std::string::npos);
  auto o = parse_word_order("little");
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("low-first, high-first"), std::string::npos);
}

TEST(Registers, WatlowF4tProfile) {
  auto p = chamber_profile("watlow-f4t");
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(p->setpoint.address, 2782);
  EXPECT_EQ(p->setpoint.type, RegisterType::kFloat32);
  EXPECT_EQ(p->setpoint.word_order, WordOrder::kLowFirst);
  EXPECT_EQ(p->setpoint.function, RegisterFunction::kHolding);
  EXPECT_EQ(p->process_value.address, 2820);
  EXPECT_EQ(p->process_value.type, RegisterType::kFloat32);
  ASSERT_TRUE(p->ramp_rate && p->ramp_action && p->ramp_scale);
  EXPECT_EQ(p->ramp_rate->address, 2798);
  EXPECT_EQ(p->ramp_action->address, 2794);
  EXPECT_EQ(p->ramp_scale->address, 2796);
}

// ChamberConnectLibrary (watlowf4t.py): the PV is read, never written; the
// units register is 6730 over TCP and 14080 over RTU.
TEST(Registers, WatlowF4tProcessValueIsReadOnlyAndUnitsFollowTheTransport) {
  auto tcp = chamber_profile("watlow-f4t");
  ASSERT_TRUE(tcp.ok());
  EXPECT_TRUE(tcp->process_value.read_only);
  EXPECT_FALSE(tcp->setpoint.read_only);
  ASSERT_TRUE(tcp->units);
  EXPECT_EQ(tcp->units->reg.address, 6730);
  EXPECT_EQ(tcp->units->reg.type, RegisterType::kUint16);
  EXPECT_EQ(tcp->units->decode(15), TemperatureUnit::kCelsius);
  EXPECT_EQ(tcp->units->decode(30), TemperatureUnit::kFahrenheit);
  EXPECT_EQ(tcp->units->decode(0), std::nullopt);
  auto rtu = chamber_profile("watlow-f4t", "rtu");
  ASSERT_TRUE(rtu.ok() && rtu->units);
  EXPECT_EQ(rtu->units->reg.address, 14080);
  EXPECT_FALSE(chamber_profile("watlow-f4")->units.has_value());
}

TEST(Registers, FahrenheitConversions) {
  EXPECT_DOUBLE_EQ(to_celsius(77.0, TemperatureUnit::kFahrenheit), 25.0);
  EXPECT_DOUBLE_EQ(to_celsius(-4.0, TemperatureUnit::kFahrenheit), -20.0);
  EXPECT_DOUBLE_EQ(from_celsius(-40.0, TemperatureUnit::kFahrenheit), -40.0);
  EXPECT_DOUBLE_EQ(from_celsius(100.0, TemperatureUnit::kFahrenheit), 212.0);
  EXPECT_DOUBLE_EQ(to_celsius(23.5, TemperatureUnit::kCelsius), 23.5);
}

// The F4T's alarm state enumerations (ChamberConnectLibrary
// get_alarm_status: 88, 61, 12 are inactive; Watlow: Alarm High 7, Alarm
// Low 8, Error 28).
TEST(Registers, F4tAlarmStatesAreEnumerations) {
  auto alarm = chamber_alarm_default("watlow-f4t");
  ASSERT_TRUE(alarm);
  EXPECT_EQ(alarm->reg.address, 1356);
  EXPECT_TRUE(alarm->reg.read_only);
  for (double quiet : {61.0, 88.0, 12.0}) EXPECT_FALSE(alarm->is_alarm(quiet)) << quiet;
  for (double active : {7.0, 8.0, 28.0, 0.0, 1.0}) EXPECT_TRUE(alarm->is_alarm(active)) << active;
  EXPECT_EQ(alarm->quiet_value(), 61.0);
  EXPECT_EQ(alarm->alarm_value(), 7.0);
  EXPECT_FALSE(chamber_alarm_default("generic"));

  ChamberAlarm flag;  // no profile: 0 quiet, anything else an alarm
  EXPECT_FALSE(flag.is_alarm(0));
  EXPECT_TRUE(flag.is_alarm(1));
  EXPECT_TRUE(flag.is_alarm(61));
  EXPECT_EQ(flag.quiet_value(), 0.0);
  EXPECT_TRUE(flag.is_alarm(flag.alarm_value()));

  ChamberAlarm listed;
  listed.mode = ChamberAlarm::Mode::kAlarmValues;
  listed.values = {0, 3};  // only these are alarms
  EXPECT_TRUE(listed.is_alarm(0));
  EXPECT_TRUE(listed.is_alarm(3));
  EXPECT_FALSE(listed.is_alarm(1));
  EXPECT_FALSE(listed.is_alarm(listed.quiet_value()));
  EXPECT_EQ(listed.alarm_value(), 0.0);
}

TEST(Registers, WatlowF4Profile) {
  auto p = chamber_profile("watlow-f4");
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(p->process_value.address, 100);
  EXPECT_EQ(p->setpoint.address, 300);
  EXPECT_EQ(p->setpoint.type, RegisterType::kInt16);
  EXPECT_DOUBLE_EQ(p->setpoint.scale, 0.1);
  EXPECT_DOUBLE_EQ(p->process_value.scale, 0.1);
  EXPECT_FALSE(p->ramp_rate.has_value());
}

TEST(Registers, GenericProfilesAndUnknownNames) {
  auto g = chamber_profile("generic");
  ASSERT_TRUE(g.ok());
  EXPECT_EQ(g->setpoint.function, RegisterFunction::kHolding);
  EXPECT_EQ(g->process_value.function, RegisterFunction::kInput);
  EXPECT_EQ(g->process_value.type, RegisterType::kInt16);

  auto bad = chamber_profile("eurotherm");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("eurotherm"), std::string::npos);
  EXPECT_NE(bad.error().message.find("watlow-f4t, watlow-f4, generic"), std::string::npos);

  auto ch = probe_channel_spec("generic", 3);
  ASSERT_TRUE(ch.ok());
  EXPECT_EQ(ch->address, 3);
  EXPECT_EQ(ch->function, RegisterFunction::kInput);
  EXPECT_EQ(ch->type, RegisterType::kInt16);
  EXPECT_DOUBLE_EQ(ch->scale, 0.1);
  EXPECT_FALSE(probe_channel_spec("generic", -1).ok());
  auto unknown = probe_channel_spec("adam-4015", 0);
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.error().message.find("adam-4015"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm::drivers
