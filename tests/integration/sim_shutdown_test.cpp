// gyrotherm-sim's shutdown: the real binary started, served (Modbus clients
// writing the set point on several connections, as a daemon does), and
// stopped with SIGTERM, many times over. Every stop must be a clean exit 0:
// a write being answered while the simulator stopped used to reach a
// Modbus server that was already released (a segfault, 2 in 10 stops on a
// busy machine).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <signal.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <thread>
#include <vector>

#include "gyrotherm/config/config.h"
#include "gyrotherm/config/sim_endpoints.h"
#include "gyrotherm/drivers/modbus_device.h"
#include "process.h"
#include "temp_dir_test.h"
#include "test_files.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using testing::ChildProcess;

class SimShutdownTest : public testing::TempDirTest {
 protected:
  SimShutdownTest() : TempDirTest("gyrotherm-sim-shutdown") {}

  // demo.toml with every file of the simulator in this test's folder.
  std::string write_config() {
    std::string cfg = testing::read_text(std::string(GYROTHERM_SOURCE_DIR) + "/config/demo.toml");
    // fmt, not "\"" + string: gcc 12 warns -Wrestrict on that (a false positive).
    auto quoted = [](const std::filesystem::path& p) { return fmt::format("\"{}\"", p.string()); };
    auto replace = [&](const std::string& from, const std::string& to) {
      const auto pos = cfg.find(from);
      EXPECT_NE(pos, std::string::npos) << from;
      if (pos != std::string::npos) cfg.replace(pos, from.size(), to);
    };
    replace("\"demo/sim-endpoints.toml\"", quoted(dir_ / "ep.toml"));
    replace("\"demo/sim-truth.json\"", quoted(dir_ / "truth.json"));
    replace("\"demo/gyro-pty\"", quoted(dir_ / "gyro-pty"));
    replace("\"demo/sim.sock\"", quoted(dir_ / "sim.sock"));
    const std::string path = (dir_ / "station.toml").string();
    std::ofstream(path) << cfg;
    return path;
  }
};

TEST_F(SimShutdownTest, SigtermWhileServingExitsCleanlyEveryTime) {
  const std::string cfg_path = write_config();
  auto cfg = config::load_station_config(cfg_path);
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  constexpr int kRounds = 20;
  constexpr int kWriters = 4;
  for (int round = 0; round < kRounds; ++round) {
    SCOPED_TRACE(fmt::format("round {}", round));
    const std::string log = (dir_ / fmt::format("sim-{}.log", round)).string();
    ChildProcess sim({std::string(GYROTHERM_BIN_DIR) + "/gyrotherm-sim", "--config", cfg_path,
                      "--time-scale", "10"},
                     log);
    ASSERT_TRUE(
        testing::wait_until([&] { return fs::exists(dir_ / "ep.toml"); }, std::chrono::seconds(20)))
        << sim.log();
    auto ep = config::read_sim_endpoints((dir_ / "ep.toml").string());
    ASSERT_TRUE(ep.ok()) << ep.error().message;
    config::StationConfig station = *cfg;
    config::apply_sim_endpoints(station, *ep);

    // Writers on their own connections, each write answered then handed
    // to the simulator's on-write hook; they run until the simulator is gone.
    std::atomic<bool> done{false};
    std::atomic<int> writes{0};
    std::vector<std::thread> writers;
    for (int w = 0; w < kWriters; ++w) {
      writers.emplace_back([&, w] {
        drivers::ModbusDevice chamber(fmt::format("chamber-{}", w), station.chamber.endpoint);
        for (int i = 0; !done.load(); ++i) {
          if (chamber.write(station.chamber.map.setpoint, 20.0 + (i % 10) * 0.5).ok()) ++writes;
        }
      });
    }
    const bool served = testing::wait_until([&] { return writes.load() >= 50 * kWriters; },
                                            std::chrono::seconds(20));
    sim.signal(SIGTERM);
    const auto status = sim.wait(std::chrono::seconds(30));
    done = true;
    for (auto& t : writers) t.join();
    ASSERT_TRUE(served) << writes.load() << " writes\n" << sim.log();
    ASSERT_TRUE(status.has_value()) << "no exit within 30 s of SIGTERM\n" << sim.log();
    ASSERT_EQ(*status, 0) << (*status > 128 ? fmt::format("killed by signal {}", *status - 128)
                                            : std::string("exit status"))
                          << "\n"
                          << sim.log();
    EXPECT_FALSE(fs::exists(dir_ / "ep.toml")) << "the endpoints file is removed on the way out";
  }
}

}  // namespace
}  // namespace gyrotherm
