// `gyrotherm devices` and `gyrotherm decode` with [[dut]] entries: the real
// CLI binary, real ptys playing a KVH 1750 and an ASCII test set, capture
// files decoded by the DUT's protocol.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>
#include <vector>

#include "gyrotherm/config/config.h"
#include "gyrotherm/drivers/ascii_line.h"
#include "gyrotherm/drivers/kvh1750.h"
#include "gyrotherm/drivers/pty.h"
#include "temp_dir_test.h"
#include "test_files.h"

namespace gyrotherm {
namespace {

using ::testing::HasSubstr;

class DutCliTest : public testing::TempDirTest {
 protected:
  DutCliTest() : TempDirTest("gyrotherm-dut-cli") {}
  struct Run {
    int code;
    std::string out, err;
  };
  // Runs the CLI to completion (killed after 60 s); `stdin_path`: its input.
  Run cli(const std::vector<std::string>& args, const std::string& stdin_path = "") {
    const std::string out = (dir_ / "out.txt").string(), err = (dir_ / "err.txt").string();
    std::string cmd = "timeout -s KILL 60 " + std::string(GYROTHERM_BIN_DIR) + "/gyrotherm";
    for (const auto& a : args) cmd += " '" + a + "'";
    if (!stdin_path.empty()) cmd += " <'" + stdin_path + "'";
    cmd += " >" + out + " 2>" + err;
    const int st = std::system(cmd.c_str());
    return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, testing::read_text(out), testing::read_text(err)};
  }

  // A station whose chamber and probes nobody serves, with `duts`.
  std::string write_config(const std::string& duts) {
    const std::string path = (dir_ / "station.toml").string();
    std::ofstream(path) << fmt::format(R"([station]
[chamber]
host = "127.0.0.1"
port = 1
response_timeout_s = 0.1
[probes]
host = "127.0.0.1"
port = 1
response_timeout_s = 0.1
[storage]
db = "{}"
{})",
                                       (dir_ / "station.db").string(), duts);
    return path;
  }
};

// The test set of docs/configuration.md, less the "-" column.
constexpr const char* kTestSet = R"([[dut]]
serial = "TS-7"
model = "rate test set"
device = "{}"
protocol = "ascii"
rate_hz = 100
[dut.ascii]
prefix = "$GYR,"
checksum = "nmea"
seq_column = "n"
seq_modulo = 65536
columns = [
  {{ name = "n" }},
  {{ name = "rate_x", kind = "rate", unit = "deg/s", axis = "x" }},
  {{ name = "rate_y", kind = "rate", unit = "deg/s", axis = "y" }},
  {{ name = "temp_c", kind = "temperature", unit = "degC" }},
  {{ name = "status", kind = "status" }},
]
valid_bits = {{ x = 1, y = 2 }}
)";

// The options kTestSet gives, as the config reads them.
drivers::AsciiLineOptions test_set_options(const std::string& config_path) {
  auto cfg = config::load_station_config(config_path);
  EXPECT_TRUE(cfg.ok()) << cfg.error().message;
  return cfg.ok() ? cfg->duts.back().link.ascii : drivers::AsciiLineOptions{};
}

// Frame n of the test set: rate_x, rate_y (deg/s), temp_c, status.
std::vector<double> test_set_values(uint32_t n) {
  return {0.0042 + 1e-4 * n, -0.0013, 24.5 + 0.25 * (n % 4), n == 3 ? 2.0 : 3.0};
}

TEST_F(DutCliTest, DecodeAnAsciiCaptureByItsDut) {
  const std::string config = write_config(fmt::format(kTestSet, "/dev/null"));
  const drivers::AsciiLineOptions options = test_set_options(config);
  std::string capture = "noise before the first line\r\n";
  // The last line confirms the jump over the corrupted one (docs/devices.md,
  // "Sequence counters").
  for (uint32_t n = 0; n < 7; ++n) {
    const auto values = test_set_values(n);
    std::string line = drivers::encode_ascii_line(options, values, 65534 + n);
    if (n == 4) {  // its checksum no longer matches
      char& digit = line[line.find('*') + 1];
      digit = digit == '0' ? '1' : '0';
    }
    capture += line;
  }
  const std::string path = (dir_ / "capture.txt").string();
  std::ofstream(path, std::ios::binary) << capture;

  const Run r = cli({"decode", "--protocol", "ascii", "--config", config, "--dut", "TS-7", path});
  ASSERT_EQ(r.code, 0) << r.err;
  std::istringstream lines(r.out);
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line, "seq,rate_x,rate_y,temp_c,status");
  std::vector<uint32_t> seqs;
  while (std::getline(lines, line)) {
    uint32_t seq = 0;
    double rx = 0, ry = 0, temp = 0, status = 0;
    char rx_text[64] = {};
    ASSERT_EQ(
        std::sscanf(line.c_str(), "%u,%63[^,],%lf,%lf,%lf", &seq, rx_text, &ry, &temp, &status), 5)
        << line;
    const uint32_t n = (seq + 2) % 65536;  // seq 65534 is frame 0
    const auto want = test_set_values(n);
    if (n == 3) {
      EXPECT_STREQ(rx_text, "nan") << "status 1: y valid, x not";
    } else {
      rx = std::strtod(rx_text, nullptr);
      EXPECT_EQ(rx, want[0]) << "exact: shortest digits both ways";
    }
    EXPECT_EQ(ry, want[1]);
    EXPECT_EQ(temp, want[2]);
    EXPECT_EQ(status, want[3]);
    seqs.push_back(seq);
  }
  EXPECT_THAT(seqs, ::testing::ElementsAre(65534u, 65535u, 0u, 1u, 3u, 4u)) << "the counter wraps";
  EXPECT_THAT(r.err, HasSubstr("6 valid frames, 1 CRC failures"));

  // From standard input, with the summary as JSON.
  const Run piped =
      cli({"decode", "--protocol", "ascii", "--config", config, "--dut", "TS-7", "--json"}, path);
  ASSERT_EQ(piped.code, 0) << piped.err;
  EXPECT_EQ(piped.out, r.out);
  const auto summary = nlohmann::json::parse(piped.err);
  EXPECT_EQ(summary["frames_ok"], 6);
  EXPECT_EQ(summary["crc_failures"], 1);
}

TEST_F(DutCliTest, DecodeRefusalsNameWhatIsMissing) {
  const std::string config = write_config(fmt::format(kTestSet, "/dev/null"));
  const std::string path = (dir_ / "empty.txt").string();
  std::ofstream(path) << "";
  const Run bare = cli({"decode", "--protocol", "ascii", path});
  EXPECT_EQ(bare.code, 2);
  EXPECT_THAT(bare.err, HasSubstr("--protocol ascii needs --config FILE and --dut SERIAL"));
  const Run unknown =
      cli({"decode", "--protocol", "ascii", "--config", config, "--dut", "TS-8", path});
  EXPECT_EQ(unknown.code, 2);
  EXPECT_THAT(unknown.err, HasSubstr("no [[dut]] with serial \"TS-8\" (serials: \"TS-7\")"));
  const Run wrong =
      cli({"decode", "--protocol", "kvh1750", "--config", config, "--dut", "TS-7", path});
  EXPECT_EQ(wrong.code, 2);
  EXPECT_THAT(wrong.err, HasSubstr("DUT \"TS-7\" speaks ascii, not kvh1750"));
}

// Two DUTs on two ptys: one reading each, every channel in physical units.
TEST_F(DutCliTest, DevicesReadsEveryDut) {
  auto kvh_pty = drivers::Pty::open(true);
  auto ascii_pty = drivers::Pty::open(true);
  ASSERT_TRUE(kvh_pty.ok() && ascii_pty.ok());
  const std::string config = write_config(
      fmt::format(R"([[dut]]
serial = "17-0042"
model = "KVH 1750"
device = "{}"
rate_hz = 1000
axes = ["x", "z"]
{})",
                  kvh_pty->slave_path(), fmt::format(kTestSet, ascii_pty->slave_path())));
  const drivers::AsciiLineOptions options = test_set_options(config);
  drivers::GyroFrame frame;
  frame.gyro = {1.0e-5f, -2.0e-5f, 3.9e-5f};  // rad/s
  frame.accel = {0.001f, -0.002f, 1.0f};
  frame.status = 0x77;
  frame.temp_c = 31;
  std::atomic<bool> stop{false};
  std::thread devices([&] {
    for (uint32_t n = 0; !stop; ++n) {
      frame.seq = static_cast<uint8_t>(n % 128);
      const auto bytes = drivers::encode_kvh1750(frame);
      (void)kvh_pty->write_master(bytes, 50);
      const std::string line = drivers::encode_ascii_line(options, test_set_values(0), n);
      (void)ascii_pty->write_master(
          std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(line.data()), line.size()), 50);
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  });
  const Run r = cli({"--json", "devices", "--config", config});
  const Run text = cli({"devices", "--config", config});
  stop = true;
  devices.join();
  EXPECT_EQ(r.code, 1) << "nobody serves the chamber\n" << r.out << r.err;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["duts"].size(), 2u) << j.dump(2);
  const auto& kvh = j["duts"][0];
  EXPECT_EQ(kvh["serial"], "17-0042");
  EXPECT_EQ(kvh["model"], "KVH 1750");
  EXPECT_EQ(kvh["primary_axis"], "z");
  ASSERT_FALSE(kvh.contains("error")) << kvh.dump(2);
  const auto channel = [](const nlohmann::json& dut, const std::string& name) {
    for (const auto& c : dut["channels"]) {
      if (c["name"] == name) return c;
    }
    ADD_FAILURE() << name << " not in " << dut.dump();
    return nlohmann::json();
  };
  // rad/s as float32 -> °/h: × 180/π × 3600; the float's own value.
  constexpr double kRadToDph = 180.0 / M_PI * 3600.0;
  EXPECT_NEAR(channel(kvh, "gyro_z")["value"].get<double>(), double(3.9e-5f) * kRadToDph, 1e-9);
  EXPECT_EQ(channel(kvh, "gyro_z")["unit"], "deg/h");
  EXPECT_NEAR(channel(kvh, "accel_z")["value"].get<double>(), 1.0, 1e-7);
  EXPECT_EQ(channel(kvh, "status")["value"], 0x77);
  EXPECT_EQ(channel(kvh, "temp_c")["value"], 31.0);
  // "gyro": the first DUT's primary axis, as before [[dut]].
  EXPECT_NEAR(j["gyro"]["rate_dph"].get<double>(), double(3.9e-5f) * kRadToDph, 1e-9);
  EXPECT_EQ(j["gyro"]["crc_failures"], 0);

  const auto& ts = j["duts"][1];
  EXPECT_EQ(ts["serial"], "TS-7");
  ASSERT_FALSE(ts.contains("error")) << ts.dump(2);
  EXPECT_NEAR(channel(ts, "rate_x")["value"].get<double>(), 0.0042 * 3600.0, 1e-9);
  EXPECT_NEAR(channel(ts, "rate_y")["value"].get<double>(), -0.0013 * 3600.0, 1e-9);
  EXPECT_EQ(channel(ts, "temp_c")["value"], 24.5);
  EXPECT_TRUE(j["chamber"]["process_value_c"].contains("error"));

  // Text: one block per DUT.
  EXPECT_THAT(text.out,
              HasSubstr("dut      17-0042 (KVH 1750) on " + kvh_pty->slave_path() + " (kvh1750)"));
  EXPECT_THAT(text.out, HasSubstr(fmt::format("  gyro_z           {:.3f} deg/h  (primary axis)",
                                              double(3.9e-5f) * kRadToDph)));
  EXPECT_THAT(text.out, HasSubstr("  status           0x77"));
  EXPECT_THAT(text.out, HasSubstr("dut      TS-7 (rate test set) on " + ascii_pty->slave_path() +
                                  " (ascii)"));
  EXPECT_THAT(text.out, HasSubstr("  rate_x           15.120 deg/h"));
}

}  // namespace
}  // namespace gyrotherm
