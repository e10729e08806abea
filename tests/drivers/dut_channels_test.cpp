// dut_channels() for each protocol and the ASCII line encoder.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <vector>

#include "gyrotherm/drivers/ascii_line.h"
#include "gyrotherm/drivers/dut_link.h"

namespace gyrotherm::drivers {
namespace {

AsciiColumn channel_col(std::string name, ChannelKind kind, std::string unit,
                        std::string axis = "") {
  return AsciiColumn{std::move(name), kind, std::move(unit), std::move(axis)};
}

// $GYR,<seq>,<gyro_z deg/s>,<accel_z m/s^2>,<temp degC>,<status>
AsciiLineOptions gyr_options() {
  AsciiLineOptions o;
  o.prefix = "$GYR,";
  o.columns = {channel_col("seq", ChannelKind::kOther, ""),
               channel_col("gyro_z", ChannelKind::kRate, "deg/s", "z"),
               channel_col("accel_z", ChannelKind::kAccel, "m/s^2", "z"),
               channel_col("temp_c", ChannelKind::kTemperature, "degC"),
               channel_col("status", ChannelKind::kStatus, "")};
  o.seq_column = 0;
  o.seq_modulo = 256;
  return o;
}

DutLink ascii_link(AsciiLineOptions o) {
  DutLink link;
  link.protocol = "ascii";
  link.rate_hz = 100.0;
  link.ascii = std::move(o);
  return link;
}

TEST(DutChannels, Kvh1750ListAndScales) {
  DutLink link;
  link.rate_hz = 1000.0;
  auto ch = dut_channels(link);
  ASSERT_TRUE(ch.ok()) << ch.error().message;
  const std::vector<std::string> names{"gyro_x",  "gyro_y",  "gyro_z", "accel_x",
                                       "accel_y", "accel_z", "status", "temp_c"};
  ASSERT_EQ(ch->size(), names.size());
  for (std::size_t i = 0; i < names.size(); ++i) EXPECT_EQ((*ch)[i].name, names[i]);
  const double rad_to_dph = 180.0 / M_PI * 3600.0;  // 206264.806...
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ((*ch)[i].kind, ChannelKind::kRate);
    EXPECT_EQ((*ch)[i].unit, "deg/h");
    EXPECT_EQ((*ch)[i].axis, std::string(1, static_cast<char>('x' + i)));
    EXPECT_NEAR((*ch)[i].scale, rad_to_dph, 1e-9);
    EXPECT_EQ((*ch)[3 + i].kind, ChannelKind::kAccel);
    EXPECT_EQ((*ch)[3 + i].unit, "g");
    EXPECT_EQ((*ch)[3 + i].scale, 1.0);
  }
  EXPECT_EQ((*ch)[6].kind, ChannelKind::kStatus);
  EXPECT_EQ((*ch)[6].unit, "");
  EXPECT_EQ((*ch)[7].kind, ChannelKind::kTemperature);
  EXPECT_EQ((*ch)[7].unit, "degC");

  link.unit = AngleUnit::kDeg;
  link.kind = OutputKind::kDeltaAngle;
  ch = dut_channels(link);
  ASSERT_TRUE(ch.ok());
  EXPECT_NEAR((*ch)[0].scale, 3600.0 * 1000.0, 1e-6);  // deg per sample at 1 kHz
}

TEST(DutChannels, AsciiColumnsWithUnitScales) {
  auto link = ascii_link(gyr_options());
  auto ch = dut_channels(link);
  ASSERT_TRUE(ch.ok()) << ch.error().message;
  ASSERT_EQ(ch->size(), 4u);  // the seq column is the frame's seq, not a channel
  EXPECT_EQ((*ch)[0].name, "gyro_z");
  EXPECT_EQ((*ch)[0].unit, "deg/h");
  EXPECT_EQ((*ch)[0].axis, "z");
  EXPECT_DOUBLE_EQ((*ch)[0].scale, 3600.0);
  EXPECT_EQ((*ch)[1].unit, "g");
  EXPECT_DOUBLE_EQ((*ch)[1].scale, 1.0 / 9.80665);
  EXPECT_EQ((*ch)[2].unit, "degC");
  EXPECT_EQ((*ch)[3].kind, ChannelKind::kStatus);

  // Per-sample angles become rates at rate_hz; mg to g.
  AsciiLineOptions o;
  o.delimiter = "whitespace";
  o.columns = {channel_col("gx", ChannelKind::kRate, "rad", "x"),
               channel_col("-", ChannelKind::kOther, ""),
               channel_col("gy", ChannelKind::kRate, "deg", "y"),
               channel_col("gz", ChannelKind::kRate, "rad/s", "z"),
               channel_col("ax", ChannelKind::kAccel, "mg", "x"),
               channel_col("v", ChannelKind::kOther, "V")};
  ch = dut_channels(ascii_link(o));
  ASSERT_TRUE(ch.ok()) << ch.error().message;
  ASSERT_EQ(ch->size(), 5u);
  EXPECT_NEAR((*ch)[0].scale, 180.0 / M_PI * 3600.0 * 100.0, 1e-6);
  EXPECT_DOUBLE_EQ((*ch)[1].scale, 3600.0 * 100.0);
  EXPECT_NEAR((*ch)[2].scale, 180.0 / M_PI * 3600.0, 1e-9);
  EXPECT_DOUBLE_EQ((*ch)[3].scale, 1e-3);
  EXPECT_EQ((*ch)[4].unit, "V");
  EXPECT_EQ((*ch)[4].scale, 1.0);
}

// Each bad option is refused with a message naming the column (index and
// name) or the option.
TEST(DutChannels, AsciiErrorsNameTheColumn) {
  struct Case {
    std::function<void(AsciiLineOptions&)> change;
    std::string expected;
  };
  const std::vector<Case> cases{
      {[](auto& o) { o.columns[1].unit = "deg/min"; }, "ascii column 1 'gyro_z': unit 'deg/min'"},
      {[](auto& o) { o.columns[2].name = "gyro_z"; }, "ascii column 2 'gyro_z': name repeated"},
      {[](auto& o) { o.columns[1].axis = "w"; }, "ascii column 1 'gyro_z': axis 'w'"},
      {[](auto& o) { o.columns[3].axis = "x"; }, "ascii column 3 'temp_c': axis 'x'"},
      {[](auto& o) { o.columns[4].unit = "bits"; }, "ascii column 4 'status': unit 'bits'"},
      {[](auto& o) { o.columns[2].name = "a z"; }, "ascii column 2 'a z'"},
      {[](auto& o) { o.columns.clear(); }, "ascii columns: none given"},
      {[](auto& o) { o.delimiter = ";;"; }, "ascii delimiter ';;'"},
      {[](auto& o) { o.delimiter = "."; }, "ascii delimiter '.'"},
      {[](auto& o) { o.checksum = "crc32"; }, "ascii checksum 'crc32'"},
      {[](auto& o) { o.seq_column = 9; }, "ascii seq_column 9"},
      {[](auto& o) { o.seq_column.reset(); }, "ascii seq_modulo 256"},
      {[](auto& o) {
         o.valid_bits = {{"x", 1}};
       },
       "ascii valid_bits: axis 'x'"},
      {[](auto& o) {
         o.valid_bits = {{"z", 0}};
       },
       "mask 0"},
      {[](auto& o) { o.prefix = "$A*"; }, "ascii prefix"},
      {[](auto& o) {
         o.columns.clear();
         for (int i = 0; i < 17; ++i)
           o.columns.push_back(channel_col(fmt::format("c{}", i), ChannelKind::kOther, ""));
         o.seq_column.reset();
         o.seq_modulo = 0;
       },
       "17 channels, at most 16"},
  };
  for (const Case& c : cases) {
    AsciiLineOptions o = gyr_options();
    c.change(o);
    auto ch = dut_channels(ascii_link(o));
    ASSERT_FALSE(ch.ok()) << c.expected;
    EXPECT_NE(ch.error().message.find(c.expected), std::string::npos)
        << ch.error().message << " (expected: " << c.expected << ")";
  }
  DutLink unknown;
  unknown.protocol = "nmea0183";
  auto ch = dut_channels(unknown);
  ASSERT_FALSE(ch.ok());
  EXPECT_NE(ch.error().message.find("'nmea0183'"), std::string::npos);
}

// Checksums precomputed independently with Python:
//   binascii.crc_hqx(b"$GYR,12,1.5,-2,0.25,7", 0xFFFF) == 0xA880 (CRC-16/CCITT-FALSE)
//   functools.reduce(operator.xor, b"GYR,12,1.5,-2,0.25,7") == 0x78 (NMEA, '$' excluded)
TEST(AsciiEncoder, WritesPrefixSeqAndChecksums) {
  EXPECT_EQ(crc16_ccitt_false("123456789"), 0x29B1);  // the catalogue's check value
  AsciiLineOptions o;
  o.prefix = "$GYR,";
  o.columns = {channel_col("seq", ChannelKind::kOther, ""),
               channel_col("gyro_z", ChannelKind::kRate, "deg/h", "z"),
               channel_col("-", ChannelKind::kOther, ""),
               channel_col("accel_z", ChannelKind::kAccel, "g", "z"),
               channel_col("status", ChannelKind::kStatus, "")};
  o.seq_column = 0;
  o.seq_modulo = 100;
  const std::vector<double> v{1.5, 0.25, 7};
  EXPECT_EQ(encode_ascii_line(o, v, 112), "$GYR,12,1.5,0,0.25,7\r\n");
  o.columns[2] = channel_col("x", ChannelKind::kOther, "");  // now a channel: -2
  const std::vector<double> v2{1.5, -2, 0.25, 7};
  o.checksum = "crc16";
  EXPECT_EQ(encode_ascii_line(o, v2, 12), "$GYR,12,1.5,-2,0.25,7*A880\r\n");
  o.checksum = "nmea";
  EXPECT_EQ(encode_ascii_line(o, v2, 12), "$GYR,12,1.5,-2,0.25,7*78\r\n");
  // One value per named column: the seq column's entry is ignored.
  const std::vector<double> v3{999, 1.5, -2, 0.25, 7};
  EXPECT_EQ(encode_ascii_line(o, v3, 12), "$GYR,12,1.5,-2,0.25,7*78\r\n");
  EXPECT_THROW(encode_ascii_line(o, std::vector<double>{1.0}, 0), std::invalid_argument);
}

}  // namespace
}  // namespace gyrotherm::drivers
