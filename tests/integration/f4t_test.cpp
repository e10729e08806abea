// End-to-end against Watlow F4T behaviour, with independent peers:
//   - mbpoll (a Modbus master that is not ours) against gyrotherm-sim: the
//     simulator serves only an F4T's registers, refuses writes to read-only
//     ones and unknown enumerations, and speaks Watlow's enumerations;
//   - a pymodbus 3.0 server (f4t_peer.py) playing an F4T with the register
//     map and enumerations of ESPEC's ChamberConnectLibrary (alarm state
//     None = 61, temperatures in °F) against the real gyrothermd;
//   - gyrotherm-sim told to serve °F, against gyrothermd.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <csignal>
#include <cstdio>
#include <string>

#include "gyrotherm/config/sim_endpoints.h"
#include "station_fixture.h"

namespace gyrotherm::testing {
namespace {

using ::testing::HasSubstr;
using json = nlohmann::json;

struct CommandResult {
  int code = -1;
  std::string output;  // stdout and stderr
};

CommandResult run_command(const std::string& command) {
  CommandResult r;
  FILE* p = ::popen((command + " 2>&1").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  std::size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) r.output.append(buf, n);
  const int status = ::pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

class F4tTest : public StationTest {
 protected:
  int sim_port() {
    auto ep = config::read_sim_endpoints((dir_ / "endpoints.toml").string());
    EXPECT_TRUE(ep.ok()) << (ep.ok() ? "" : ep.error().message);
    return ep.ok() ? ep->modbus_port : 0;
  }
  // mbpoll, once, PDU addressing (-0), against `port` on loopback; `values`
  // (after the host) makes it a write.
  CommandResult mbpoll(int port, const std::string& args, const std::string& values = "") {
    return run_command(fmt::format("mbpoll -0 -1 -o 2 -p {} {} 127.0.0.1 {}", port, args, values));
  }
  bool wait_status(const std::function<bool(const json&)>& pred,
                   std::chrono::milliseconds timeout = std::chrono::seconds(60)) {
    return wait_until(
        [&] {
          auto s = status();
          return s && !s->is_discarded() && pred(*s);
        },
        timeout);
  }
  std::string diag() {
    auto s = status();
    return fmt::format("status: {}\ndaemon log:\n{}", s ? s->dump() : "none",
                       daemon_ ? daemon_->log() : "");
  }
};

TEST_F(F4tTest, SimulatorAnswersMbpollAsAnF4t) {
  ASSERT_NO_FATAL_FAILURE(start_sim());
  const int port = sim_port();
  if (find_program("mbpoll").empty()) GTEST_SKIP() << "mbpoll is not installed";

  // An address no F4T register covers, inside the span of served ones.
  auto unmapped = mbpoll(port, "-a 1 -t 4 -r 2000");
  EXPECT_NE(unmapped.code, 0) << unmapped.output;
  EXPECT_THAT(unmapped.output, HasSubstr("Illegal data address"));

  // The process value is read-only: exception 2 for a write.
  auto pv_write = mbpoll(port, "-a 1 -t 4:float -r 2820", "30");
  EXPECT_NE(pv_write.code, 0) << pv_write.output;
  EXPECT_THAT(pv_write.output, HasSubstr("Illegal data address"));

  // Watlow's enumerations: ramp action Off (62), ramp scale Minutes (57),
  // units °C (15).
  auto action = mbpoll(port, "-a 1 -t 4 -r 2794");
  EXPECT_EQ(action.code, 0) << action.output;
  EXPECT_THAT(action.output, HasSubstr("[2794]: \t62"));
  auto scale = mbpoll(port, "-a 1 -t 4 -r 2796");
  EXPECT_THAT(scale.output, HasSubstr("[2796]: \t57"));
  auto units = mbpoll(port, "-a 1 -t 4 -r 6730");
  EXPECT_EQ(units.code, 0) << units.output;
  EXPECT_THAT(units.output, HasSubstr("[6730]: \t15"));

  // An enumeration Watlow does not define for the ramp action: exception 3.
  auto bad_action = mbpoll(port, "-a 1 -t 4 -r 2794", "1");
  EXPECT_NE(bad_action.code, 0) << bad_action.output;
  EXPECT_THAT(bad_action.output, HasSubstr("Illegal data value"));
  auto good_action = mbpoll(port, "-a 1 -t 4 -r 2794", "1647");  // Set Point Change
  EXPECT_EQ(good_action.code, 0) << good_action.output;

  // A set point beyond the controller's range: exception 3, not taken.
  auto far = mbpoll(port, "-a 1 -t 4:float -r 2782", "500");
  EXPECT_NE(far.code, 0) << far.output;
  EXPECT_THAT(far.output, HasSubstr("Illegal data value"));
  auto sp = mbpoll(port, "-a 1 -t 4:float -r 2782");
  EXPECT_THAT(sp.output, HasSubstr("[2782]: \t23"));
}

// The fixture's station (the F4T's alarm 1) with `sim_extra` in [simulator].
std::string f4t_station(const fs::path& dir, int api_port, const std::string& sim_extra) {
  std::string text = station_config(dir, api_port);
  const std::string sim = "[simulator]\n";
  if (auto at = text.find(sim); at != std::string::npos) {
    text.insert(at + sim.size(), sim_extra);
  }
  return text;
}

TEST_F(F4tTest, DaemonRunsASimulatedF4tServingFahrenheit) {
  write(dir_ / "station.toml", f4t_station(dir_, api_port_, "chamber_units = \"F\"\n"));
  write(dir_ / "schedule.toml", soak_schedule("fahrenheit", 25, 600));
  ASSERT_NO_FATAL_FAILURE(start_sim());
  start_daemon();
  // 25 °C = 77 °F at the controller; the daemon shows and controls in °C.
  ASSERT_TRUE(wait_status([](const json& s) {
    return s["state"] == "acquiring" && s["chamber_c"].is_number() &&
           std::abs(s["chamber_c"].get<double>() - 25.0) < 2.0;
  })) << diag();
  auto sp = mbpoll(sim_port(), "-a 1 -t 4:float -r 2782");
  EXPECT_THAT(sp.output, HasSubstr("[2782]: \t77")) << sp.output;
  // The alarm register holds the F4T's None (61): no chamber_alarm.
  auto s = status();
  ASSERT_TRUE(s);
  EXPECT_EQ((*s)["interlocks"].dump().find("chamber_alarm"), std::string::npos) << s->dump();

  // Raised: Alarm High (7) in the register, the interlock trips.
  ASSERT_TRUE(sim_ctl("chamber alarm on"));
  auto alarm = mbpoll(sim_port(), "-a 1 -t 4 -r 1356");
  EXPECT_THAT(alarm.output, HasSubstr("[1356]: \t7"));
  EXPECT_TRUE(wait_status([](const json& st) {
    return st["interlocks"].dump().find("chamber_alarm") != std::string::npos;
  })) << diag();
}

// An F4T that is not ours: pymodbus with ChamberConnectLibrary's map.
TEST_F(F4tTest, DaemonAgainstAPymodbusF4tInFahrenheit) {
  const std::string python = "/usr/bin/python3";
  if (run_command(python + " -c 'import pymodbus'").code != 0) {
    GTEST_SKIP() << "python3-pymodbus is not installed";
  }
  const int modbus_port = free_tcp_port();
  // The peer writes the endpoints; no simulator runs.
  std::string text = station_config(dir_, api_port_);
  const std::string gyro = "[gyro]\nsilent_timeout_s = 60.0";
  text.replace(text.find(gyro), gyro.size(), "[gyro]\nsilent_timeout_s = 86400.0");
  write(dir_ / "station.toml", text);
  write(dir_ / "schedule.toml", soak_schedule("peer", 25, 600));
  ChildProcess peer({python, std::string(GYROTHERM_SOURCE_DIR) + "/tests/integration/f4t_peer.py",
                     std::to_string(modbus_port), (dir_ / "endpoints.toml").string(), "--units",
                     "F", "--pv-c", "25", "--probe-c", "25"},
                    (dir_ / "peer.log").string());
  ASSERT_TRUE(
      wait_until([&] { return fs::exists(dir_ / "endpoints.toml"); }, std::chrono::seconds(20)))
      << peer.log();
  start_daemon();

  // The PV register holds 77 (°F): the daemon reports 25 °C.
  ASSERT_TRUE(wait_status([](const json& s) {
    return s["chamber_c"].is_number() && s["state"] != "idle" && !s["state"].is_null();
  })) << diag();
  auto s = status();
  ASSERT_TRUE(s);
  EXPECT_NEAR((*s)["chamber_c"].get<double>(), 25.0, 1e-4) << s->dump();
  // The set point goes out in °F: 25 °C = 77 °F.
  EXPECT_TRUE(wait_until(
      [&] {
        return mbpoll(modbus_port, "-a 1 -t 4:float -r 2782").output.find("[2782]: \t77") !=
               std::string::npos;
      },
      std::chrono::seconds(30)))
      << mbpoll(modbus_port, "-a 1 -t 4:float -r 2782").output << diag();
  // Alarm 1 state None (61) is no alarm.
  s = status();
  ASSERT_TRUE(s);
  EXPECT_EQ((*s)["interlocks"].dump().find("chamber_alarm"), std::string::npos) << s->dump();

  // Alarm High (7): the interlock trips.
  peer.signal(SIGUSR1);
  EXPECT_TRUE(wait_status([](const json& st) {
    return st["interlocks"].dump().find("chamber_alarm") != std::string::npos;
  })) << diag();
}

}  // namespace
}  // namespace gyrotherm::testing
