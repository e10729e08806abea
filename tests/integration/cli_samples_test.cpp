// gyrotherm samples: a real database written through SampleWriter (a
// KVH-1750-like DUT, a gap), exported by the real binary; every value read
// back from the CSV text equals what was stored, bit for bit.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;

struct CliRun {
  int code;
  std::string out, err;
};

std::string read_all(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

class CliSamples : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / fmt::format("gyrotherm-cli-samples-{}", ::getpid());
    fs::create_directories(dir_);
    db_path_ = (dir_ / "station.db").string();
    auto db = storage::Database::open(db_path_);
    ASSERT_TRUE(db.ok()) << db.error().message;
    storage::RunRecord run;
    run.schedule_name = "soak";
    run.state = "completed";
    auto run_id = db->create_run(run);
    ASSERT_TRUE(run_id.ok()) << run_id.error().message;
    storage::RunDutRecord d;
    d.run_id = *run_id;
    d.dut.serial = "17-0042";
    d.dut.model = "KVH 1750";
    d.primary_axis = "z";
    d.axes = {"x", "y", "z"};
    d.rate_hz = 1000;
    d.seq_modulo = 128;
    const double rad_to_dph = 180.0 / M_PI * 3600.0;
    const ChannelSpec specs[] = {{"gyro_x", "deg/h", ChannelKind::kRate, "x", rad_to_dph},
                                 {"gyro_y", "deg/h", ChannelKind::kRate, "y", rad_to_dph},
                                 {"gyro_z", "deg/h", ChannelKind::kRate, "z", rad_to_dph},
                                 {"accel_x", "g", ChannelKind::kAccel, "x", 1},
                                 {"accel_y", "g", ChannelKind::kAccel, "y", 1},
                                 {"accel_z", "g", ChannelKind::kAccel, "z", 1},
                                 {"status", "", ChannelKind::kStatus, "", 1},
                                 {"temp_c", "degC", ChannelKind::kTemperature, "", 1}};
    int idx = 0;
    for (const ChannelSpec& s : specs) d.channels.push_back({0, d.run_id, 0, idx++, s});
    auto reg = db->add_run_dut(*run_id, d);
    ASSERT_TRUE(reg.ok()) << reg.error().message;
    dut_ = *reg;
    for (int i = 0; i < 9000; ++i) {
      DutFrame f;
      f.t_s = 10.0 + i * 0.001 + (i >= 5000 ? 3.0 : 0.0);  // a gap at 5000
      f.seq = static_cast<uint32_t>(i % 128);
      for (int c = 0; c < 6; ++c) f.raw[c] = static_cast<float>(1e-5 * std::sin(i * 0.013 + c));
      f.raw[6] = i % 777 == 0 ? 0x70 : 0x77;
      f.raw[7] = 21;
      if (i % 777 == 0) f.raw[0] = std::nan("");
      frames_.push_back(f);
    }
    auto writer = storage::SampleWriter::start(db_path_);
    ASSERT_TRUE(writer.ok()) << writer.error().message;
    (*writer)->push_frames(dut_, frames_);
    ASSERT_TRUE((*writer)->flush().ok());
  }
  void TearDown() override {
    if (!::testing::Test::HasFailure()) fs::remove_all(dir_);
  }

  CliRun cli(const std::vector<std::string>& args) {
    const fs::path out = dir_ / "out.csv", err = dir_ / "err.txt";
    std::string cmd = std::string(GYROTHERM_BIN_DIR) + "/gyrotherm samples";
    for (const auto& a : args) cmd += " '" + a + "'";
    cmd += " >" + out.string() + " 2>" + err.string();
    const int st = std::system(cmd.c_str());
    return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, read_all(out), read_all(err)};
  }

  fs::path dir_;
  std::string db_path_;
  storage::RunDutRecord dut_;
  std::vector<DutFrame> frames_;
};

std::vector<std::vector<std::string>> parse_csv(const std::string& text) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::size_t at = 0;
    for (;;) {
      const auto comma = line.find(',', at);
      f.push_back(line.substr(at, comma == std::string::npos ? std::string::npos : comma - at));
      if (comma == std::string::npos) break;
      at = comma + 1;
    }
    rows.push_back(std::move(f));
  }
  return rows;
}

TEST_F(CliSamples, EveryChannelExactlyWithUnitsInTheHeader) {
  const CliRun r = cli({"--db", db_path_, "--run", std::to_string(dut_.run_id)});
  ASSERT_EQ(r.code, 0) << r.err;
  const auto rows = parse_csv(r.out);
  ASSERT_EQ(rows.size(), frames_.size() + 1);
  EXPECT_EQ(rows[0], (std::vector<std::string>{"t_s", "gyro_x (deg/h)", "gyro_y (deg/h)",
                                               "gyro_z (deg/h)", "accel_x (g)", "accel_y (g)",
                                               "accel_z (g)", "status", "temp_c (degC)"}));
  for (std::size_t i = 0; i < frames_.size(); ++i) {
    const auto& row = rows[i + 1];
    ASSERT_EQ(row.size(), 9u) << i;
    EXPECT_NEAR(std::strtod(row[0].c_str(), nullptr), frames_[i].t_s, 1e-9) << i;
    for (int c = 0; c < 8; ++c) {
      const double want = frames_[i].raw[c] * dut_.channels[c].spec.scale;
      if (std::isnan(want)) {
        EXPECT_EQ(row[c + 1], "") << i << " " << c;
      } else {
        // Shortest round-trip digits: the text reads back as the same double.
        ASSERT_EQ(std::strtod(row[c + 1].c_str(), nullptr), want)
            << i << " " << c << " " << row[c + 1];
      }
    }
  }
}

TEST_F(CliSamples, OneChannelAndARange) {
  const CliRun r = cli({"--db", db_path_, "--run", std::to_string(dut_.run_id), "--dut", "17-0042",
                        "--channel", "accel_z", "--from", "14.5", "--to", "18.0005"});
  ASSERT_EQ(r.code, 0) << r.err;
  const auto rows = parse_csv(r.out);
  ASSERT_FALSE(rows.empty());
  EXPECT_EQ(rows[0], (std::vector<std::string>{"t_s", "accel_z (g)"}));
  std::size_t want = 0;
  for (const DutFrame& f : frames_) want += f.t_s >= 14.5 - 1e-12 && f.t_s < 18.0005 ? 1 : 0;
  EXPECT_EQ(rows.size() - 1, want);
  EXPECT_EQ(std::strtod(rows[1][0].c_str(), nullptr), 14.5);
}

TEST_F(CliSamples, ErrorsNameTheUnknownRunDutOrChannel) {
  CliRun r = cli({"--db", db_path_, "--run", "99"});
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("99"), std::string::npos) << r.err;
  r = cli({"--db", db_path_, "--run", std::to_string(dut_.run_id), "--dut", "SN-NOPE"});
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("'SN-NOPE'"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("'17-0042'"), std::string::npos) << r.err;
  r = cli({"--db", db_path_, "--run", std::to_string(dut_.run_id), "--channel", "gyro_q"});
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("'gyro_q'"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("accel_y"), std::string::npos) << r.err;
  r = cli({"--db", (dir_ / "missing.db").string(), "--run", "1"});
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("missing.db"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace gyrotherm
