// [[dut]] in the station config (docs/configuration.md, "[[dut]]"): every
// key into StationConfig::duts, every error naming file:line:key, the older
// [gyro] read as one DUT, and the simulator's DUT lines (dut_devices).
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>

#include "gyrotherm/config/config.h"
#include "gyrotherm/config/sim_endpoints.h"
#include "test_files.h"

namespace gyrotherm::config {
namespace {

using ::testing::AllOf;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::Not;
using ::testing::Pair;

// Lines 1-6; a [[dut]] appended to it starts on line 7.
constexpr const char* kStation = R"([station]
latitude_deg = 31.9
[chamber]
port = 1502
[probes]
port = 1502
)";

// One KVH 1750 with every key (lines 7-22) and one ASCII test set with
// every key (lines 23-43).
constexpr const char* kTwoDuts = R"([[dut]]
serial = "17-0042"
model = "KVH 1750"
device = "/dev/ttyUSB0"
baud = 921600
parity = "even"
protocol = "kvh1750"
unit = "deg"
output = "delta"
rate_hz = 1000
axes = ["x", "z"]
orientation = { z = "down", x = "up" }
primary_axis = "z"
table_axis = "x"
silent_timeout_s = 2.5
probes = { top_channel = 2, side_channel = 3 }
[[dut]]
serial = "TS-7"
model = "rate test set"
device = "/dev/ttyUSB1"
protocol = "ascii"
rate_hz = 100
silent_timeout_s = 4
[dut.ascii]
delimiter = ";"
prefix = "$GYR;"
checksum = "nmea"
seq_column = "n"
seq_modulo = 65536
columns = [
  { name = "n" },
  { name = "rate_x", kind = "rate", unit = "deg/s", axis = "x" },
  { name = "rate_y", kind = "rate", unit = "deg/s", axis = "y" },
  { name = "-" },
  { name = "temp", kind = "temperature", unit = "degC" },
  { name = "flags", kind = "status" },
]
valid_bits = { x = 1, y = 2 }
)";

Result<StationConfig> parse(const std::string& duts, const std::string& extra = "") {
  return parse_station_config(std::string(kStation) + duts + extra, "s.toml");
}

// The error message of a config that must not load.
std::string errors_of(const std::string& duts, const std::string& extra = "") {
  auto cfg = parse(duts, extra);
  EXPECT_FALSE(cfg.ok()) << "loaded:\n" << duts << extra;
  return cfg.ok() ? std::string() : cfg.error().message;
}

TEST(DutConfig, EveryKeyIsRead) {
  auto cfg = parse(kTwoDuts);
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  ASSERT_EQ(cfg->duts.size(), 2u);

  const DutSection& kvh = cfg->duts[0];
  EXPECT_EQ(kvh.serial, "17-0042");
  EXPECT_EQ(kvh.model, "KVH 1750");
  EXPECT_EQ(kvh.link.serial.device, "/dev/ttyUSB0");
  EXPECT_EQ(kvh.link.serial.baud, 921600);
  EXPECT_EQ(kvh.link.serial.parity, drivers::Parity::kEven);
  EXPECT_EQ(kvh.link.protocol, "kvh1750");
  EXPECT_EQ(kvh.link.unit, drivers::AngleUnit::kDeg);
  EXPECT_EQ(kvh.link.kind, drivers::OutputKind::kDeltaAngle);
  EXPECT_DOUBLE_EQ(kvh.link.rate_hz, 1000.0);
  EXPECT_THAT(kvh.axes, ElementsAre("x", "z"));
  EXPECT_THAT(kvh.orientation, ElementsAre(Pair("x", analysis::AxisOrientation::kUp),
                                           Pair("z", analysis::AxisOrientation::kDown)));
  EXPECT_EQ(kvh.primary_axis, "z");
  EXPECT_EQ(kvh.table_axis, "x");
  EXPECT_DOUBLE_EQ(kvh.silent_timeout_s, 2.5);
  ASSERT_TRUE(kvh.probes);
  EXPECT_EQ(kvh.probes->top_channel, 2);
  EXPECT_EQ(kvh.probes->side_channel, 3);

  const DutSection& ts = cfg->duts[1];
  EXPECT_EQ(ts.serial, "TS-7");
  EXPECT_EQ(ts.model, "rate test set");
  EXPECT_EQ(ts.link.protocol, "ascii");
  EXPECT_DOUBLE_EQ(ts.link.rate_hz, 100.0);
  const drivers::AsciiLineOptions& a = ts.link.ascii;
  EXPECT_EQ(a.delimiter, ";");
  EXPECT_EQ(a.prefix, "$GYR;");
  EXPECT_EQ(a.checksum, "nmea");
  EXPECT_EQ(a.seq_column, 0) << "the index of column \"n\"";
  EXPECT_EQ(a.seq_modulo, 65536u);
  ASSERT_EQ(a.columns.size(), 6u);
  EXPECT_EQ(a.columns[0].name, "n");
  EXPECT_EQ(a.columns[0].kind, ChannelKind::kOther) << "kind defaults to other";
  EXPECT_EQ(a.columns[1].name, "rate_x");
  EXPECT_EQ(a.columns[1].kind, ChannelKind::kRate);
  EXPECT_EQ(a.columns[1].unit, "deg/s");
  EXPECT_EQ(a.columns[1].axis, "x");
  EXPECT_EQ(a.columns[3].name, "-");
  EXPECT_EQ(a.columns[4].kind, ChannelKind::kTemperature);
  EXPECT_EQ(a.columns[4].unit, "degC");
  EXPECT_EQ(a.columns[5].kind, ChannelKind::kStatus);
  EXPECT_THAT(a.valid_bits, ElementsAre(Pair("x", 1u), Pair("y", 2u)));
  // Defaults from the line's rate channels: every rate axis, the last
  // primary, the primary up ([station] orientation), the others horizontal.
  EXPECT_THAT(ts.axes, ElementsAre("x", "y"));
  EXPECT_EQ(ts.primary_axis, "y");
  EXPECT_EQ(ts.table_axis, "y");
  EXPECT_THAT(ts.orientation, ElementsAre(Pair("x", analysis::AxisOrientation::kHorizontal),
                                          Pair("y", analysis::AxisOrientation::kUp)));
  EXPECT_FALSE(ts.probes);

  // "The gyro" for older code: the first DUT and its primary axis.
  EXPECT_EQ(cfg->gyro.serial_number, "17-0042");
  EXPECT_EQ(cfg->gyro.model, "KVH 1750");
  EXPECT_EQ(cfg->gyro.serial.device, "/dev/ttyUSB0");
  EXPECT_EQ(cfg->gyro.serial.baud, 921600);
  EXPECT_EQ(cfg->gyro.protocol, "kvh1750");
  EXPECT_EQ(cfg->gyro.format.axis, 2);
  EXPECT_EQ(cfg->gyro.format.unit, drivers::AngleUnit::kDeg);
  EXPECT_EQ(cfg->gyro.format.kind, drivers::OutputKind::kDeltaAngle);
  EXPECT_DOUBLE_EQ(cfg->gyro.format.rate_hz, 1000.0);
  EXPECT_DOUBLE_EQ(cfg->gyro.silent_timeout_s, 2.5);
  // The gyro_lost interlock: the quickest DUT's timeout.
  EXPECT_DOUBLE_EQ(cfg->interlocks.gyro_timeout_s, 2.5);

  ASSERT_NE(find_dut(cfg->duts, "TS-7"), nullptr);
  EXPECT_EQ(find_dut(cfg->duts, "TS-7")->model, "rate test set");
  EXPECT_EQ(find_dut(cfg->duts, "TS-8"), nullptr);
  EXPECT_EQ(axis_orientation(kvh, "z"), analysis::AxisOrientation::kDown);
  EXPECT_EQ(axis_orientation(kvh, "y"), std::nullopt) << "not analysed";
}

TEST(DutConfig, DefaultsOfAKvh1750) {
  auto cfg = parse(
      "[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB0\"\n"
      "[[dut]]\nserial = \"A2\"\ndevice = \"/dev/ttyUSB1\"\nsilent_timeout_s = 9\n",
      "[interlocks]\n");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  const DutSection& d = cfg->duts[0];
  EXPECT_EQ(d.model, "");
  EXPECT_EQ(d.link.protocol, "kvh1750");
  EXPECT_EQ(d.link.unit, drivers::AngleUnit::kRad);
  EXPECT_EQ(d.link.kind, drivers::OutputKind::kRate);
  EXPECT_DOUBLE_EQ(d.link.rate_hz, 10.0);
  EXPECT_EQ(d.link.serial.baud, drivers::SerialOptions{}.baud);
  EXPECT_THAT(d.axes, ElementsAre("x", "y", "z")) << "every gyro axis of the KVH 1750";
  EXPECT_EQ(d.primary_axis, "z");
  EXPECT_EQ(d.table_axis, "z");
  EXPECT_THAT(d.orientation, ElementsAre(Pair("x", analysis::AxisOrientation::kHorizontal),
                                         Pair("y", analysis::AxisOrientation::kHorizontal),
                                         Pair("z", analysis::AxisOrientation::kUp)));
  EXPECT_DOUBLE_EQ(d.silent_timeout_s, 5.0);
  EXPECT_FALSE(d.probes);
  EXPECT_DOUBLE_EQ(cfg->interlocks.gyro_timeout_s, 5.0) << "min(5, 9)";

  // The primary axis's default direction is [station] orientation.
  std::string down = kStation;
  down.insert(down.find("[chamber]"), "orientation = \"down\"\n");
  auto cfg_down = parse_station_config(
      down + "[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB0\"\nprimary_axis = \"x\"\n",
      "d.toml");
  ASSERT_TRUE(cfg_down.ok()) << cfg_down.error().message;
  EXPECT_EQ(axis_orientation(cfg_down->duts[0], "x"), analysis::AxisOrientation::kDown);
  EXPECT_EQ(axis_orientation(cfg_down->duts[0], "z"), analysis::AxisOrientation::kHorizontal);
  EXPECT_EQ(cfg_down->duts[0].table_axis, "x") << "table_axis defaults to primary_axis";
  EXPECT_EQ(cfg_down->gyro.format.axis, 0);
}

TEST(DutConfig, DeviceIsRequiredUnlessSimulated) {
  const std::string m = errors_of("[[dut]]\nserial = \"A1\"\n");
  EXPECT_THAT(m, HasSubstr("s.toml:7: dut[0].device: missing (required unless [simulator] "
                           "endpoints_file is set)"));
  auto sim = parse("[[dut]]\nserial = \"A1\"\n[[dut]]\nserial = \"A2\"\n",
                   "[simulator]\nendpoints_file = \"ep.toml\"\n");
  ASSERT_TRUE(sim.ok()) << sim.error().message;
  EXPECT_EQ(sim->duts.size(), 2u);
  EXPECT_EQ(sim->duts[1].link.serial.device, "");
}

TEST(DutConfig, SerialIsRequiredUniqueAndPrintable) {
  EXPECT_THAT(errors_of("[[dut]]\ndevice = \"/dev/ttyUSB0\"\n"),
              HasSubstr("s.toml:7: dut[0].serial: missing (required: the DUT's serial number)"));
  EXPECT_THAT(errors_of("[[dut]]\nserial = \"\"\ndevice = \"/dev/ttyUSB0\"\n"),
              HasSubstr("s.toml:8: dut[0].serial: must be 1 to 64 characters"));
  for (const char* bad : {"17/0042", "a,b", "tab\\there", "quo\\\"te", "back\\\\slash"}) {
    EXPECT_THAT(
        errors_of(fmt::format("[[dut]]\nserial = \"{}\"\ndevice = \"/dev/ttyUSB0\"\n", bad)),
        HasSubstr("s.toml:8: dut[0].serial: may hold printable ASCII characters"))
        << bad;
  }
  EXPECT_THAT(errors_of("[[dut]]\nserial = \" A1\"\ndevice = \"/dev/ttyUSB0\"\n"),
              HasSubstr("s.toml:8: dut[0].serial: must not start or end with a blank"));
  EXPECT_THAT(errors_of("[[dut]]\nserial = 42\ndevice = \"/dev/ttyUSB0\"\n"),
              HasSubstr("s.toml:8: dut[0].serial: expected a string, got integer"));
  // Serials with blanks and the usual punctuation are fine.
  auto ok = parse("[[dut]]\nserial = \"SN 17-0042.b#3\"\ndevice = \"/dev/ttyUSB0\"\n");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok->duts[0].serial, "SN 17-0042.b#3");

  const std::string dup = errors_of(
      "[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB0\"\n"
      "[[dut]]\nserial = \"A2\"\ndevice = \"/dev/ttyUSB1\"\n"
      "[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB0\"\n");
  EXPECT_THAT(dup, HasSubstr("s.toml:14: dut[2].serial: \"A1\" is also dut[0]'s serial (line 8): "
                             "each DUT has its own serial number"));
  EXPECT_THAT(dup, HasSubstr("s.toml:15: dut[2].device: \"/dev/ttyUSB0\" is also dut[0]'s device "
                             "(line 9): each DUT needs its own serial line"));
}

TEST(DutConfig, AtMostEightDuts) {
  std::string duts;
  for (int i = 0; i < 9; ++i)
    duts += fmt::format("[[dut]]\nserial = \"S{}\"\ndevice = \"/dev/ttyUSB{}\"\n", i, i);
  // The ninth starts on line 7 + 8 * 3.
  EXPECT_THAT(errors_of(duts),
              HasSubstr("s.toml:31: dut: 9 DUTs: a station reads at most 8 (one serial line"));
  duts.resize(duts.rfind("[[dut]]"));
  auto eight = parse(duts);
  ASSERT_TRUE(eight.ok()) << eight.error().message;
  EXPECT_EQ(eight->duts.size(), 8u);
}

TEST(DutConfig, LinkKeysAreChecked) {
  const std::string m = errors_of(R"([[dut]]
serial = "A1"
device = "/dev/ttyUSB0"
baud = -9600
parity = "mark"
protocol = "kvh1775"
rate_hz = 0
silent_timeout_s = 0
colour = "blue"
)");
  EXPECT_THAT(m, HasSubstr("s.toml:10: dut[0].baud: -9600 is not a baud rate"));
  EXPECT_THAT(m, HasSubstr("s.toml:11: dut[0].parity: \"mark\" is not one of: none, even, odd"));
  EXPECT_THAT(m,
              HasSubstr("s.toml:12: dut[0].protocol: \"kvh1775\" is not one of: kvh1750, ascii"));
  EXPECT_THAT(m, HasSubstr("s.toml:13: dut[0].rate_hz: 0 is out of range"));
  EXPECT_THAT(m, HasSubstr("s.toml:14: dut[0].silent_timeout_s: 0 is out of range"));
  EXPECT_THAT(m, HasSubstr("s.toml:15: dut[0].colour: unknown key"));

  const std::string kvh = errors_of(
      "[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB0\"\nunit = \"grad\"\n"
      "output = \"angle\"\n[dut.ascii]\ndelimiter = \",\"\n");
  EXPECT_THAT(kvh, HasSubstr("s.toml:10: dut[0].unit: \"grad\" is not one of: rad, deg"));
  EXPECT_THAT(kvh, HasSubstr("s.toml:11: dut[0].output: \"angle\" is not one of: rate, delta"));
  EXPECT_THAT(kvh, HasSubstr("s.toml:12: dut[0].ascii: only for protocol \"ascii\""));

  const std::string ascii = errors_of(
      "[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB0\"\nprotocol = \"ascii\"\nunit = \"rad\"\n"
      "output = \"rate\"\n");
  EXPECT_THAT(ascii, HasSubstr("s.toml:11: dut[0].unit: only for protocol kvh1750"));
  EXPECT_THAT(ascii, HasSubstr("s.toml:12: dut[0].output: only for protocol kvh1750"));
  EXPECT_THAT(ascii, HasSubstr("s.toml:7: dut[0].ascii: missing: protocol \"ascii\" needs a "
                               "[dut.ascii] table"));
}

TEST(DutConfig, AxesMustBeRateChannelsOfTheProtocol) {
  const std::string kvh = R"([[dut]]
serial = "A1"
device = "/dev/ttyUSB0"
)";
  EXPECT_THAT(errors_of(kvh + "axes = [\"z\", \"w\", \"z\", 3]\n"),
              AllOf(HasSubstr("s.toml:10: dut[0].axes[1]: must be \"x\", \"y\" or \"z\""),
                    HasSubstr("s.toml:10: dut[0].axes[2]: \"z\" is listed twice"),
                    HasSubstr("s.toml:10: dut[0].axes[3]: must be")));
  EXPECT_THAT(errors_of(kvh + "axes = []\n"),
              HasSubstr("s.toml:10: dut[0].axes: must list at least one axis"));
  EXPECT_THAT(errors_of(kvh + "axes = \"z\"\n"),
              HasSubstr("s.toml:10: dut[0].axes: expected an array, got string"));
  EXPECT_THAT(errors_of(kvh + "axes = [\"z\"]\nprimary_axis = \"x\"\ntable_axis = \"q\"\n"),
              AllOf(HasSubstr("s.toml:11: dut[0].primary_axis: \"x\" is not among axes (z)"),
                    HasSubstr("s.toml:12: dut[0].table_axis: \"q\" is not one of: x, y, z")));
  // An ASCII line with rate columns x and y only: z is not a rate channel.
  const std::string ascii = R"([[dut]]
serial = "TS-7"
device = "/dev/ttyUSB1"
protocol = "ascii"
axes = ["x", "z"]
[dut.ascii]
columns = [
  { name = "rate_x", kind = "rate", unit = "deg/h", axis = "x" },
  { name = "rate_y", kind = "rate", unit = "deg/h", axis = "y" },
  { name = "ax", kind = "accel", unit = "g", axis = "z" },
]
)";
  EXPECT_THAT(errors_of(ascii),
              HasSubstr("s.toml:11: dut[0].axes[1]: \"z\" is not among this DUT's rate channels "
                        "(axes x, y)"));
  // No rate column at all.
  EXPECT_THAT(errors_of(R"([[dut]]
serial = "TS-7"
device = "/dev/ttyUSB1"
protocol = "ascii"
[dut.ascii]
columns = [{ name = "temp", kind = "temperature", unit = "degC" }]
)"),
              HasSubstr("s.toml:11: dut[0].ascii: the line carries no rate channel"));
}

TEST(DutConfig, OrientationNamesAnalysedAxes) {
  const std::string m = errors_of(R"([[dut]]
serial = "A1"
device = "/dev/ttyUSB0"
axes = ["y", "z"]
orientation = { z = "sideways", x = "up", w = "down", y = 1 }
)");
  EXPECT_THAT(m, HasSubstr("s.toml:11: dut[0].orientation.z: \"sideways\" is not one of: up, "
                           "down, horizontal"));
  EXPECT_THAT(m, HasSubstr("s.toml:11: dut[0].orientation.x: \"x\" is not among axes (y, z)"));
  EXPECT_THAT(m, HasSubstr("s.toml:11: dut[0].orientation.w: is not an axis (x, y, z)"));
  EXPECT_THAT(m, HasSubstr("s.toml:11: dut[0].orientation.y: expected a string, got integer"));
  EXPECT_THAT(errors_of("[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB0\"\norientation = "
                        "\"up\"\n"),
              HasSubstr("s.toml:10: dut[0].orientation: expected a table, got string"));
}

// heading_deg: per horizontal axis, degrees from true north, clockwise.
TEST(DutConfig, HeadingDegGivesHorizontalAxesTheirAzimuth) {
  auto cfg = parse(R"([[dut]]
serial = "A1"
device = "/dev/ttyUSB0"
heading_deg = { x = 90.0, y = -45 }
)");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  const DutSection& d = cfg->duts[0];
  EXPECT_THAT(d.heading_deg, ElementsAre(Pair("x", 90.0), Pair("y", -45.0)));
  EXPECT_EQ(axis_heading_deg(d, "x"), 90.0);
  EXPECT_EQ(axis_heading_deg(d, "z"), std::nullopt) << "z is up: no heading";
  EXPECT_TRUE(cfg->warnings.empty()) << cfg->warnings.front();

  // A horizontal axis without one loads, as before headings, with a warning
  // naming the file, line, DUT key and axis.
  auto bare = parse(R"([[dut]]
serial = "A1"
device = "/dev/ttyUSB0"
orientation = { z = "up", x = "horizontal", y = "horizontal" }
heading_deg = { y = 180 }
)");
  ASSERT_TRUE(bare.ok()) << bare.error().message;
  ASSERT_EQ(bare->warnings.size(), 1u);
  EXPECT_THAT(bare->warnings[0],
              HasSubstr("s.toml:10: dut[0].heading_deg: axis x is horizontal without a heading: "
                        "its Earth-rate component is taken as 0 (as if it pointed east or west)"));
  EXPECT_THAT(bare->warnings[0], HasSubstr("heading_deg = { x = AZIMUTH }"));

  const std::string m = errors_of(R"([[dut]]
serial = "A1"
device = "/dev/ttyUSB0"
axes = ["x", "z"]
heading_deg = { z = 10.0, x = 400.0, w = 1.0, y = 5.0 }
[[dut]]
serial = "A2"
device = "/dev/ttyUSB1"
heading_deg = { x = "north" }
[[dut]]
serial = "A3"
device = "/dev/ttyUSB2"
heading_deg = 90.0
)");
  EXPECT_THAT(m, HasSubstr("s.toml:11: dut[0].heading_deg.z: axis z is \"up\" (orientation): "
                           "only a horizontal axis has a heading"));
  EXPECT_THAT(m, HasSubstr("s.toml:11: dut[0].heading_deg.x: 400 is out of range: must be in "
                           "[-360, 360] degrees"));
  EXPECT_THAT(m, HasSubstr("s.toml:11: dut[0].heading_deg.w: is not an axis (x, y, z)"));
  EXPECT_THAT(m, HasSubstr("s.toml:11: dut[0].heading_deg.y: \"y\" is not among axes (x, z)"));
  EXPECT_THAT(m, HasSubstr("s.toml:15: dut[1].heading_deg.x: expected a number, got string"));
  EXPECT_THAT(m, HasSubstr("s.toml:19: dut[2].heading_deg: expected a table, got float"));
}

TEST(DutConfig, OlderGyroSectionHorizontalIsWarnedAbout) {
  std::string horizontal = kStation;
  horizontal.insert(horizontal.find("[chamber]"), "orientation = \"horizontal\"\n");
  auto cfg = parse_station_config(horizontal + "[gyro]\ndevice = \"/dev/ttyUSB0\"\n", "g.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  ASSERT_EQ(cfg->warnings.size(), 1u);
  EXPECT_THAT(cfg->warnings[0], HasSubstr("g.toml:3: station.orientation: the gyro's axis is "
                                          "horizontal without a heading"));
  auto up = parse("[gyro]\ndevice = \"/dev/ttyUSB0\"\n");
  ASSERT_TRUE(up.ok());
  EXPECT_TRUE(up->warnings.empty());
}

TEST(DutConfig, ProbesAreChannelsOfTheProbesModule) {
  const std::string dut = "[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB0\"\n";
  EXPECT_THAT(errors_of(dut + "probes = { top_channel = 300, side_channel = -1 }\n"),
              AllOf(HasSubstr("s.toml:10: dut[0].probes.top_channel: 300 is not a "
                              "channel (0..255)"),
                    HasSubstr("s.toml:10: dut[0].probes.side_channel: -1 is not a channel")));
  EXPECT_THAT(errors_of(dut + "probes = { top_channel = 4 }\n"),
              HasSubstr("s.toml:10: dut[0].probes.side_channel: missing (required integer)"));
  EXPECT_THAT(errors_of(dut + "probes = { top_channel = 4, side_channel = 4, front = 5 }\n"),
              AllOf(HasSubstr("s.toml:10: dut[0].probes.side_channel: top_channel and "
                              "side_channel are the same channel"),
                    HasSubstr("s.toml:10: dut[0].probes.front: unknown key")));
  // With [probes.registers] there are no channel numbers to give.
  auto custom = parse_station_config(R"([station]
[chamber]
[probes]
registers.top = { address = 10 }
registers.side = { address = 11 }
[[dut]]
serial = "A1"
device = "/dev/ttyUSB0"
probes = { top_channel = 4, side_channel = 5 }
)",
                                     "c.toml");
  ASSERT_FALSE(custom.ok());
  EXPECT_THAT(custom.error().message,
              HasSubstr("c.toml:9: dut[0].probes.top_channel: per-DUT probes are channels of "
                        "the [probes] profile"));
}

TEST(DutConfig, AsciiOptionsAreChecked) {
  const std::string head = R"([[dut]]
serial = "TS-7"
device = "/dev/ttyUSB1"
protocol = "ascii"
[dut.ascii]
)";  // [dut.ascii] is line 11
  const std::string m = errors_of(head + R"(delimiter = "ab"
checksum = "md5"
prefix = 5
seq_column = "count"
seq_modulo = 1
valid_bits = { x = 0, w = 4 }
columns = [
  { name = "rate_x", kind = "rate", unit = "deg/s", axis = "x" },
  { kind = "rate", unit = "deg/s", axis = "y" },
  { name = "rate_z", kind = "spin", unit = "deg/s", axis = "z" },
  { name = "rate_q", kind = "rate", unit = "furlong/fortnight", axis = "z" },
  { name = "ax", kind = "accel", unit = "g" },
  { name = "temp", kind = "temperature", unit = "degC", axis = "x" },
  "seq",
  { name = "", colour = "red" },
]
)");
  EXPECT_THAT(m, HasSubstr("s.toml:12: dut[0].ascii.delimiter: \"ab\" is not a delimiter"));
  EXPECT_THAT(m, HasSubstr("s.toml:13: dut[0].ascii.checksum: \"md5\" is not one of: none, "
                           "nmea, crc16"));
  EXPECT_THAT(m, HasSubstr("s.toml:14: dut[0].ascii.prefix: expected a string, got integer"));
  EXPECT_THAT(m, HasSubstr("s.toml:15: dut[0].ascii.seq_column: \"count\" names no column"));
  EXPECT_THAT(m, HasSubstr("s.toml:16: dut[0].ascii.seq_modulo: 1 is out of range"));
  EXPECT_THAT(m, HasSubstr("s.toml:17: dut[0].ascii.valid_bits.x: 0 is not a bit mask"));
  EXPECT_THAT(m, HasSubstr("s.toml:17: dut[0].ascii.valid_bits.w: unknown key"));
  EXPECT_THAT(m, HasSubstr("s.toml:17: dut[0].ascii.valid_bits: needs one column of kind "
                           "status (the word the bits are in); columns has 0"));
  EXPECT_THAT(m, HasSubstr("s.toml:20: dut[0].ascii.columns[1].name: missing (required string)"));
  EXPECT_THAT(m, HasSubstr("s.toml:21: dut[0].ascii.columns[2].kind: \"spin\" is not one of: "
                           "rate, accel, temperature, status, other"));
  EXPECT_THAT(m, HasSubstr("s.toml:22: dut[0].ascii.columns[3].unit: "));
  EXPECT_THAT(m, HasSubstr("furlong/fortnight"));
  EXPECT_THAT(m, HasSubstr("s.toml:23: dut[0].ascii.columns[4].axis: missing (required for kind "
                           "accel)"));
  EXPECT_THAT(m, HasSubstr("s.toml:24: dut[0].ascii.columns[5].axis: only rate and accel "
                           "columns have an axis"));
  EXPECT_THAT(m, HasSubstr("s.toml:25: dut[0].ascii.columns[6]: expected a table {name, kind, "
                           "unit, axis}, got string"));
  EXPECT_THAT(m, HasSubstr("s.toml:26: dut[0].ascii.columns[7].name: must not be empty"));
  EXPECT_THAT(m, HasSubstr("s.toml:26: dut[0].ascii.columns[7].colour: unknown key"));

  EXPECT_THAT(errors_of(head + "delimiter = \",\"\n"),
              HasSubstr("s.toml:11: dut[0].ascii.columns: missing (required"));
  EXPECT_THAT(errors_of(head + "columns = []\n"),
              HasSubstr("s.toml:12: dut[0].ascii.columns: must list at least one column"));
  const std::string rate =
      "columns = [{ name = \"r\", kind = \"rate\", unit = \"deg/h\", axis = "
      "\"z\" }, { name = \"n\" }]\n";
  EXPECT_THAT(errors_of(head + rate + "seq_modulo = 256\n"),
              HasSubstr("s.toml:13: dut[0].ascii.seq_modulo: needs seq_column"));
  EXPECT_THAT(errors_of(head + rate + "seq_column = \"r\"\n"),
              HasSubstr("s.toml:13: dut[0].ascii.seq_column: \"r\" is a rate column"));
  EXPECT_THAT(errors_of(head + rate + "delimiter = \"5\"\n"),
              HasSubstr("s.toml:13: dut[0].ascii.delimiter: \"5\" is not a delimiter"));
  EXPECT_THAT(errors_of(head + rate + "prefix = \"$G*\"\n"),
              HasSubstr("s.toml:13: dut[0].ascii.prefix: must not hold a line end or *"));
  EXPECT_THAT(errors_of(head + rate + "valid_bits = { y = 2 }\n"),
              AllOf(HasSubstr("s.toml:13: dut[0].ascii.valid_bits.y: no rate column has axis y"),
                    HasSubstr("s.toml:13: dut[0].ascii.valid_bits: needs one column of kind "
                              "status")));
  // Names: a word each, once; one rate column per axis.
  const std::string names = errors_of(head + R"(columns = [
  { name = "rate z", kind = "rate", unit = "deg/h", axis = "z" },
  { name = "r", kind = "rate", unit = "deg/h", axis = "z" },
  { name = "r", kind = "other" },
  { name = "r2", kind = "rate", unit = "deg/h", axis = "z" },
]
)");
  EXPECT_THAT(names, HasSubstr("s.toml:13: dut[0].ascii.columns[0].name: \"rate z\": a channel "
                               "name is letters, digits and _"));
  EXPECT_THAT(names, HasSubstr("s.toml:15: dut[0].ascii.columns[2].name: \"r\" is also "
                               "columns[1]'s name"));
  EXPECT_THAT(names, HasSubstr("s.toml:16: dut[0].ascii.columns[3].axis: columns[1] is already "
                               "the rate column of axis z"));
  // A status column has no unit.
  EXPECT_THAT(
      errors_of(head + "columns = [{ name = \"r\", kind = \"rate\", unit = \"deg/h\", "
                       "axis = \"z\" }, { name = \"s\", kind = \"status\", unit = \"V\" }]\n"),
      HasSubstr("s.toml:12: dut[0].ascii.columns[1].unit: "));
  // Whitespace-delimited, a crc16, a 32-bit counter, a tab.
  auto ok = parse(head + rate + "delimiter = \"whitespace\"\nchecksum = \"crc16\"\n" +
                  "seq_column = \"n\"\nseq_modulo = 4294967296\n");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok->duts[0].link.ascii.delimiter, "whitespace");
  EXPECT_EQ(ok->duts[0].link.ascii.checksum, "crc16");
  EXPECT_EQ(ok->duts[0].link.ascii.seq_column, 1);
  EXPECT_EQ(ok->duts[0].link.ascii.seq_modulo, 0u) << "2^32: a counter that wraps by itself";
  auto tab = parse(head + rate + "delimiter = \"\\t\"\n");
  ASSERT_TRUE(tab.ok()) << tab.error().message;
  EXPECT_EQ(tab->duts[0].link.ascii.delimiter, "\t");
}

// What the protocol refuses of the line as a whole (more channels than a
// frame holds): its message, at [dut.ascii].
TEST(DutConfig, ProtocolRefusalsOfTheWholeLineNameTheAsciiTable) {
  std::string columns = "{ name = \"r\", kind = \"rate\", unit = \"deg/h\", axis = \"z\" }";
  for (std::size_t i = 1; i <= kMaxChannels; ++i)
    columns += fmt::format(", {{ name = \"c{}\" }}", i);
  const std::string m = errors_of(R"([[dut]]
serial = "TS-7"
device = "/dev/ttyUSB1"
protocol = "ascii"
[dut.ascii]
columns = [)" + columns + "]\n");
  EXPECT_THAT(m, HasSubstr(fmt::format("s.toml:11: dut[0].ascii: ascii columns: {} channels, at "
                                       "most {}",
                                       kMaxChannels + 1, kMaxChannels)));
}

TEST(DutConfig, EntriesThatAreNotTables) {
  // `dut = ...` on line 1, before the sections.
  const auto first_line = [](const std::string& line) {
    auto cfg = parse_station_config(line + "\n" + kStation, "s.toml");
    EXPECT_FALSE(cfg.ok()) << line;
    return cfg.ok() ? std::string() : cfg.error().message;
  };
  EXPECT_THAT(first_line("dut = 5"), HasSubstr("s.toml:1: dut: expected an array, got integer"));
  EXPECT_THAT(first_line("dut = []"), HasSubstr("s.toml:1: dut: must list at least one DUT"));
  EXPECT_THAT(first_line("dut = [1]"),
              HasSubstr("s.toml:1: dut[0]: expected a table ([[dut]]), got integer"));
  // The inline form of [[dut]] reads the same.
  auto inline_form = parse_station_config(
      "dut = [{serial = \"A1\", device = \"/dev/ttyUSB0\"}]\n" + std::string(kStation), "s.toml");
  ASSERT_TRUE(inline_form.ok()) << inline_form.error().message;
  EXPECT_EQ(inline_form->duts[0].serial, "A1");
}

// ---------------------------------------------------------------- the older [gyro]

TEST(DutConfig, GyroSectionReadsAsOneDut) {
  std::string station = kStation;
  station.insert(station.find("[chamber]"), "orientation = \"horizontal\"\n");
  auto cfg = parse_station_config(station + R"([gyro]
serial = "17-0042"
model = "KVH 1750"
device = "/dev/ttyUSB0"
baud = 460800
unit = "deg"
output = "delta"
axis = "y"
rate_hz = 500
silent_timeout_s = 3
)",
                                  "old.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  ASSERT_EQ(cfg->duts.size(), 1u);
  const DutSection& d = cfg->duts[0];
  EXPECT_EQ(d.serial, "17-0042");
  EXPECT_EQ(d.model, "KVH 1750");
  EXPECT_EQ(d.link.serial.device, "/dev/ttyUSB0");
  EXPECT_EQ(d.link.serial.baud, 460800);
  EXPECT_EQ(d.link.protocol, "kvh1750");
  EXPECT_EQ(d.link.unit, drivers::AngleUnit::kDeg);
  EXPECT_EQ(d.link.kind, drivers::OutputKind::kDeltaAngle);
  EXPECT_DOUBLE_EQ(d.link.rate_hz, 500.0);
  EXPECT_THAT(d.axes, ElementsAre("y"));
  EXPECT_EQ(d.primary_axis, "y");
  EXPECT_EQ(d.table_axis, "y");
  EXPECT_THAT(d.orientation, ElementsAre(Pair("y", analysis::AxisOrientation::kHorizontal)));
  EXPECT_DOUBLE_EQ(d.silent_timeout_s, 3.0);
  EXPECT_FALSE(d.probes);
  // `gyro` as it was.
  EXPECT_EQ(cfg->gyro.serial.device, "/dev/ttyUSB0");
  EXPECT_EQ(cfg->gyro.format.axis, 1);
  EXPECT_DOUBLE_EQ(cfg->gyro.format.rate_hz, 500.0);
  EXPECT_DOUBLE_EQ(cfg->interlocks.gyro_timeout_s, 3.0);

  // Without serial: the unnamed gyro.
  auto unnamed = parse("[gyro]\ndevice = \"/dev/ttyUSB0\"\n");
  ASSERT_TRUE(unnamed.ok()) << unnamed.error().message;
  ASSERT_EQ(unnamed->duts.size(), 1u);
  EXPECT_EQ(unnamed->duts[0].serial, "");
  EXPECT_EQ(unnamed->duts[0].model, "");
  EXPECT_THAT(unnamed->duts[0].axes, ElementsAre("z"));
  EXPECT_THAT(unnamed->duts[0].orientation, ElementsAre(Pair("z", analysis::AxisOrientation::kUp)));

  EXPECT_THAT(errors_of("[gyro]\nserial = \"a/b\"\ndevice = \"/dev/ttyUSB0\"\n"),
              HasSubstr("s.toml:8: gyro.serial: may hold printable ASCII"));
  EXPECT_THAT(errors_of("[gyro]\nbaud = 9600\n"),
              HasSubstr("s.toml:7: gyro.device: missing (required unless [simulator] "
                        "endpoints_file is set)"));
}

TEST(DutConfig, GyroAndDutTogetherOrNeither) {
  const std::string both = errors_of(
      "[gyro]\ndevice = \"/dev/ttyUSB0\"\n[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB1\"\n");
  EXPECT_THAT(both, HasSubstr("s.toml:9: dut: both [gyro] (line 7) and [[dut]] are given"));
  EXPECT_THAT(errors_of(""), HasSubstr("s.toml: dut: missing: give each device under test as a "
                                       "[[dut]] (or one gyro as the older [gyro] section)"));
}

TEST(DutConfig, ShippedStationConfigShowsAThreeImuExampleThatLoads) {
  // config/station.toml carries the [[dut]] example commented out; with the
  // comment signs removed (and its [gyro] dropped) it must load.
  const std::string text =
      testing::read_text(std::string(GYROTHERM_SOURCE_DIR) + "/config/station.toml");
  const auto begin = text.find("# [[dut]]");
  ASSERT_NE(begin, std::string::npos) << "station.toml shows [[dut]]";
  const auto end = text.find("\n\n", begin);
  std::string example;
  std::size_t pos = begin;
  while (pos < end) {
    std::size_t eol = text.find('\n', pos);
    std::string line = text.substr(pos, eol - pos);
    if (line.rfind("# ", 0) == 0) line = line.substr(2);
    if (line == "#") line.clear();
    example += line + "\n";
    pos = eol + 1;
  }
  std::string config = text;
  const auto gyro = config.find("[gyro]");
  ASSERT_NE(gyro, std::string::npos);
  config.erase(gyro, config.find("\n\n", gyro) - gyro);
  config += "\n" + example;
  auto cfg = parse_station_config(config, "station-duts.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message << "\n" << example;
  ASSERT_GE(cfg->duts.size(), 2u);
  EXPECT_EQ(cfg->duts[0].link.protocol, "kvh1750");
  EXPECT_TRUE(std::any_of(cfg->duts.begin(), cfg->duts.end(),
                          [](const DutSection& d) { return d.link.protocol == "ascii"; }));
}

// ---------------------------------------------------------------- simulator endpoints

class DutEndpoints : public ::testing::Test {
 protected:
  void TearDown() override { std::filesystem::remove_all(dir_); }
  const std::filesystem::path dir_ =
      std::filesystem::temp_directory_path() / ("gyrotherm-dut-ep-" + std::to_string(::getpid()));
  const std::string path_ = (dir_ / "ep.toml").string();
};

TEST_F(DutEndpoints, RoundTripAndApplyBySerial) {
  SimEndpoints ep{"127.0.0.1", 40123, "", 4242, "", 0};
  ep.dut_devices = {{"TS-7", "/dev/pts/8"}, {"17-0042", "/dev/pts/7"}, {"", "/dev/pts/9"}};
  ASSERT_TRUE(write_sim_endpoints(path_, ep).ok());
  const std::string text = testing::read_text(path_);
  EXPECT_THAT(text, HasSubstr("dut_devices = ["));
  EXPECT_THAT(text, HasSubstr("{ device = '/dev/pts/8', serial = 'TS-7' }"));
  EXPECT_THAT(text, HasSubstr("gyro_device = '/dev/pts/8'")) << "the first, for older daemons";
  auto back = read_sim_endpoints(path_);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->dut_devices, ep.dut_devices);
  EXPECT_EQ(back->gyro_device, "/dev/pts/8");

  auto cfg = parse(kTwoDuts);
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_EQ(sim_dut_devices_mismatch(*cfg, *back, path_), "");
  apply_sim_endpoints(*cfg, *back);
  EXPECT_EQ(cfg->duts[0].link.serial.device, "/dev/pts/7");
  EXPECT_EQ(cfg->duts[1].link.serial.device, "/dev/pts/8");
  EXPECT_EQ(cfg->gyro.serial.device, "/dev/pts/7") << "the first DUT's line";
  EXPECT_EQ(cfg->chamber.endpoint.port, 40123);

  // gyro_device may be left out when dut_devices is there.
  std::filesystem::create_directories(dir_);
  {
    std::ofstream out(path_);
    out << "modbus_host = \"127.0.0.1\"\nmodbus_port = 1\n"
           "dut_devices = [{serial = \"A\", device = \"/dev/pts/3\"}]\n";
  }
  auto no_gyro = read_sim_endpoints(path_);
  ASSERT_TRUE(no_gyro.ok()) << no_gyro.error().message;
  EXPECT_EQ(no_gyro->gyro_device, "/dev/pts/3");
}

// The rate each DUT is served at (gyrotherm-sim --rate-hz): written in its
// dut_devices entry, read back, and given to the DUT's link.
TEST_F(DutEndpoints, RatesRoundTripAndApplyBySerial) {
  SimEndpoints ep{"127.0.0.1", 40123, "", 4242, "", 0};
  ep.dut_devices = {{"17-0042", "/dev/pts/7"}, {"TS-7", "/dev/pts/8"}};
  ep.dut_rates_hz = {{"17-0042", 250.0}, {"TS-7", 20.0}};
  ASSERT_TRUE(write_sim_endpoints(path_, ep).ok());
  const std::string text = testing::read_text(path_);
  EXPECT_THAT(text, HasSubstr("{ device = '/dev/pts/8', rate_hz = 20.0, serial = 'TS-7' }"));
  auto back = read_sim_endpoints(path_);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->dut_rates_hz, ep.dut_rates_hz);
  auto cfg = parse(kTwoDuts);
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  ASSERT_EQ(cfg->duts[0].link.rate_hz, 1000.0);
  apply_sim_endpoints(*cfg, *back);
  EXPECT_EQ(cfg->duts[0].link.rate_hz, 250.0);
  EXPECT_EQ(cfg->duts[1].link.rate_hz, 20.0);
  EXPECT_EQ(cfg->gyro.format.rate_hz, 250.0) << "the first DUT's";

  // Older simulators state none: the config's rates stay.
  SimEndpoints old = ep;
  old.dut_rates_hz.clear();
  auto kept = parse(kTwoDuts);
  ASSERT_TRUE(kept.ok());
  apply_sim_endpoints(*kept, old);
  EXPECT_EQ(kept->duts[0].link.rate_hz, 1000.0);
  EXPECT_EQ(kept->duts[1].link.rate_hz, 100.0);

  std::filesystem::create_directories(dir_);
  {
    std::ofstream out(path_);
    out << "modbus_host = \"127.0.0.1\"\nmodbus_port = 1\n"
           "dut_devices = [{serial = \"A\", device = \"/dev/pts/3\", rate_hz = 0.0}]\n";
  }
  auto bad = read_sim_endpoints(path_);
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.error().message,
              HasSubstr(":3: dut_devices[0].rate_hz: 0 is out of range: must be in [0.1, 10000]"));
}

TEST_F(DutEndpoints, ADutTheSimulatorDoesNotServeIsNamed) {
  auto cfg = parse(kTwoDuts);
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  SimEndpoints ep{"127.0.0.1", 40123, "/dev/pts/7", 4242, "", 0};
  ep.dut_devices = {{"17-0042", "/dev/pts/7"}, {"XX-1", "/dev/pts/8"}};
  const std::string why = sim_dut_devices_mismatch(*cfg, ep, "ep.toml");
  EXPECT_THAT(why, HasSubstr("the simulator (ep.toml) serves no line for DUT \"TS-7\" (it serves "
                             "\"17-0042\", \"XX-1\")"));
  apply_sim_endpoints(*cfg, ep);
  EXPECT_EQ(cfg->duts[1].link.serial.device, "/dev/ttyUSB1") << "kept as configured";

  // An older simulator (gyro_device only) serves one gyro: enough for one DUT.
  SimEndpoints old{"127.0.0.1", 40123, "/dev/pts/7", 4242, "", 0};
  EXPECT_THAT(sim_dut_devices_mismatch(*cfg, old, "ep.toml"),
              HasSubstr("serves one gyro line (gyro_device, no dut_devices"));
  auto one = parse("[[dut]]\nserial = \"A1\"\ndevice = \"/dev/ttyUSB0\"\n");
  ASSERT_TRUE(one.ok());
  EXPECT_EQ(sim_dut_devices_mismatch(*one, old, "ep.toml"), "");
  apply_sim_endpoints(*one, old);
  EXPECT_EQ(one->duts[0].link.serial.device, "/dev/pts/7");
  EXPECT_EQ(one->gyro.serial.device, "/dev/pts/7");
  // The unnamed gyro of a [gyro] config is served as serial "".
  auto unnamed = parse("[gyro]\ndevice = \"/dev/ttyUSB0\"\n");
  ASSERT_TRUE(unnamed.ok());
  SimEndpoints named{"127.0.0.1", 1, "", 1, "", 0};
  named.dut_devices = {{"", "/dev/pts/4"}};
  EXPECT_EQ(sim_dut_devices_mismatch(*unnamed, named, "ep.toml"), "");
  apply_sim_endpoints(*unnamed, named);
  EXPECT_EQ(unnamed->duts[0].link.serial.device, "/dev/pts/4");
  EXPECT_EQ(unnamed->gyro.serial.device, "/dev/pts/4");
  named.dut_devices = {{"B", "/dev/pts/4"}};
  EXPECT_THAT(sim_dut_devices_mismatch(*unnamed, named, "ep.toml"),
              HasSubstr("no line for DUT (no serial)"));
}

TEST_F(DutEndpoints, BadDutDevicesAreNamed) {
  std::filesystem::create_directories(dir_);
  {
    std::ofstream out(path_);
    out << "modbus_host = \"127.0.0.1\"\nmodbus_port = 1\n"
           "dut_devices = [{serial = \"A\"}, 7, {serial = \"B\", device = \"\", port = 1}]\n";
  }
  auto bad = read_sim_endpoints(path_);
  ASSERT_FALSE(bad.ok());
  const std::string& m = bad.error().message;
  EXPECT_THAT(m, HasSubstr(":3: dut_devices[0].device: missing (required string)"));
  EXPECT_THAT(m, HasSubstr(":3: dut_devices[1]: expected a table {serial, device}, got integer"));
  EXPECT_THAT(m, HasSubstr(":3: dut_devices[2].device: must not be empty"));
  EXPECT_THAT(m, HasSubstr(":3: dut_devices[2].port: unknown key"));
  EXPECT_THAT(m, HasSubstr("gyro_device: missing")) << "no usable entry: gyro_device is needed";
}

}  // namespace
}  // namespace gyrotherm::config
