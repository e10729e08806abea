// The control socket: the command parser on its own (a table of good and bad
// lines), the server with a trivial handler (stale and live socket files),
// and the simulator driven through a real Unix socket, its effects checked
// through status() and libmodbus.
#include "gyrotherm/sim/control_server.h"

#include <gtest/gtest.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "sim_test_util.h"

namespace gyrotherm::sim {
namespace {

using namespace test_util;
using Kind = ControlCommand::Kind;

// --- Parser ---

struct GoodLine {
  const char* line;
  Kind kind;
  double value = 0;
  ProbeRole probe = ProbeRole::kTop;
};

TEST(ParseControlCommand, AcceptsEveryCommand) {
  const GoodLine good[] = {
      {"modbus down", Kind::kModbusDown},
      {"  modbus\tup \r", Kind::kModbusUp},
      {"modbus delay 0.25", Kind::kModbusDelay, 0.25},
      {"modbus delay 0", Kind::kModbusDelay, 0},
      {"modbus delay 600", Kind::kModbusDelay, 600},
      {"pty close", Kind::kPtyClose},
      {"pty reopen", Kind::kPtyReopen},
      {"pty hold", Kind::kPtyHold},
      {"pty release", Kind::kPtyRelease},
      {"frames corrupt 1", Kind::kFramesCorrupt, 1},
      {"frames drop 0.5", Kind::kFramesDrop, 0.5},
      {"frames drop 1e-3", Kind::kFramesDrop, 1e-3},
      {"probe stall top", Kind::kProbeStall, 0, ProbeRole::kTop},
      {"probe stall side", Kind::kProbeStall, 0, ProbeRole::kSide},
      {"probe release side", Kind::kProbeRelease, 0, ProbeRole::kSide},
      {"chamber alarm on", Kind::kChamberAlarmOn},
      {"chamber alarm off", Kind::kChamberAlarmOff},
      {"chamber force 80", Kind::kChamberForce, 80},
      {"chamber force -20.5", Kind::kChamberForce, -20.5},
      {"chamber release", Kind::kChamberRelease},
      {"status", Kind::kStatus},
      {"help\n", Kind::kHelp},
  };
  for (const auto& g : good) {
    auto c = parse_control_command(g.line);
    ASSERT_TRUE(c.ok()) << g.line << ": " << c.error().message;
    EXPECT_EQ(c->kind, g.kind) << g.line;
    EXPECT_DOUBLE_EQ(c->value, g.value) << g.line;
    EXPECT_EQ(c->probe, g.probe) << g.line;
    EXPECT_FALSE(c->dut_given) << g.line;
  }
}

// A DUT's own probe: the serial after top|side; without one, the station's.
TEST(ParseControlCommand, ProbeCommandsTakeADutSerial) {
  auto stall = parse_control_command("probe stall side 17-0043");
  ASSERT_TRUE(stall.ok()) << stall.error().message;
  EXPECT_EQ(stall->kind, Kind::kProbeStall);
  EXPECT_EQ(stall->probe, ProbeRole::kSide);
  EXPECT_TRUE(stall->dut_given);
  EXPECT_EQ(stall->dut, "17-0043");
  auto release = parse_control_command("probe release top TS-7");
  ASSERT_TRUE(release.ok()) << release.error().message;
  EXPECT_EQ(release->kind, Kind::kProbeRelease);
  EXPECT_EQ(release->probe, ProbeRole::kTop);
  EXPECT_EQ(release->dut, "TS-7");
  auto station = parse_control_command("probe stall top");
  ASSERT_TRUE(station.ok());
  EXPECT_FALSE(station->dut_given);
}

TEST(ParseControlCommand, RejectsWithAMessageNamingTheProblem) {
  const std::pair<std::string, std::string> bad[] = {
      {"", "empty command; send 'help'"},
      {" \t ", "empty command"},
      {"reboot", "unknown command 'reboot'; send 'help' for the list"},
      {"MODBUS down", "unknown command 'MODBUS'"},
      {"modbus", "'modbus' needs one of: down, up, delay WALL_S"},
      {"modbus sideways", "unknown 'modbus' subcommand 'sideways'"},
      {"modbus down now", "unexpected 'now' after 'modbus down'"},
      {"modbus delay", "'modbus delay' needs a value: WALL_S"},
      {"modbus delay soon", "'modbus delay': 'soon' is not a number"},
      {"modbus delay 0.5s", "'0.5s' is not a number"},
      {"modbus delay nan", "'nan' is not a number"},
      {"modbus delay -1", "'modbus delay': -1 is outside [0, 600]"},
      {"modbus delay 1e9", "is outside [0, 600]"},
      {"modbus delay 1 2", "unexpected '2' after 'modbus delay 1'"},
      {"pty", "'pty' needs one of: close, reopen"},
      {"pty open", "unknown 'pty' subcommand 'open'"},
      {"frames", "'frames' needs one of"},
      {"frames corrupt 1.5", "'frames corrupt': 1.5 is outside [0, 1]"},
      {"frames drop", "'frames drop' needs a value: P"},
      {"frames flip 0.1", "unknown 'frames' subcommand 'flip'"},
      {"probe stall", "'probe stall' needs a probe: top or side"},
      {"probe stall bottom", "'probe stall': unknown probe 'bottom'"},
      // An optional serial (a DUT's own probe), then nothing.
      {"probe release top SN now", "unexpected 'now' after 'probe release top SN'"},
      {"probe freeze top", "unknown 'probe' subcommand 'freeze'"},
      {"chamber", "'chamber' needs one of"},
      {"chamber alarm", "'chamber alarm' needs on or off"},
      {"chamber alarm maybe", "expected on or off, got 'maybe'"},
      {"chamber force", "'chamber force' needs a value: TEMP_C"},
      {"chamber force hot", "'hot' is not a number"},
      {"chamber force 300", "'chamber force': 300 is outside [-100, 200]"},
      {"chamber release now", "unexpected 'now' after 'chamber release'"},
      {"chamber explode", "unknown 'chamber' subcommand 'explode'"},
      {"status please", "unexpected 'please' after 'status'"},
      {"help me", "unexpected 'me' after 'help'"},
      {"\x01\xff garbage",
       "unknown command '?"
       "?'"},  // unprintable bytes shown as '?'
  };
  for (const auto& [line, expected] : bad) {
    auto c = parse_control_command(line);
    ASSERT_FALSE(c.ok()) << "accepted: " << line;
    EXPECT_NE(c.error().message.find(expected), std::string::npos)
        << line << " -> " << c.error().message;
    EXPECT_FALSE(c.error().transient);
  }
  // A long word is quoted shortened.
  auto c = parse_control_command(std::string(500, 'x'));
  ASSERT_FALSE(c.ok());
  EXPECT_LT(c.error().message.size(), 100u) << c.error().message;
  EXPECT_NE(c.error().message.find("xxx...'"), std::string::npos) << c.error().message;
}

TEST(ControlCommands, HelpListsEveryCommand) {
  std::string all;
  for (const auto& h : control_commands()) all += std::string(h.usage) + "\n";
  for (const char* usage :
       {"modbus down", "modbus up", "modbus delay WALL_S", "pty close", "pty reopen", "pty hold",
        "pty release", "frames corrupt P", "frames drop P", "probe stall top|side [SN]",
        "probe release top|side [SN]", "chamber alarm on|off", "chamber force TEMP_C",
        "chamber release", "status", "help"}) {
    EXPECT_NE(all.find(std::string(usage) + "\n"), std::string::npos) << usage;
  }
}

TEST(StatusJson, HasTheStateFaultsAndCounters) {
  SimulatorStatus s;
  s.running = true;
  s.t_s = 12.5;
  s.setpoint_c = 40;
  s.truth.air_c = 30.5;
  s.truth.case_c = 25;
  s.readings.top_c = 25.1;
  s.frames_generated = 125;
  s.modbus.refused_connections = 3;
  s.faults.modbus_down = true;
  s.faults.pty_open = true;
  s.faults.chamber_forced_c = 80.0;
  const auto j = nlohmann::json::parse(status_json(s));
  EXPECT_EQ(j["t_s"], 12.5);
  EXPECT_EQ(j["setpoint_c"], 40.0);
  EXPECT_EQ(j["air_c"], 30.5);
  EXPECT_EQ(j["case_c"], 25.0);
  EXPECT_EQ(j["readings"]["top_c"], 25.1);
  EXPECT_EQ(j["faults"]["modbus_down"], true);
  EXPECT_EQ(j["faults"]["chamber_forced_c"], 80.0);
  EXPECT_TRUE(j["faults"]["chamber_alarm"].is_boolean());
  EXPECT_EQ(j["faults_active"], (nlohmann::json{"modbus_down", "chamber_force"}));
  EXPECT_EQ(j["counters"]["frames_generated"], 125);
  EXPECT_EQ(j["counters"]["modbus"]["refused_connections"], 3);

  s.faults = {};
  const auto released = nlohmann::json::parse(status_json(s));
  EXPECT_TRUE(released["faults"]["chamber_forced_c"].is_null());
  EXPECT_EQ(released["faults_active"], (nlohmann::json{"pty_closed"}));
}

// --- A raw socket client, to send what gyrotherm-sim ctl never would ---

class RawClient {
 public:
  explicit RawClient(const std::string& path) {
    fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, path.c_str(), sizeof addr.sun_path - 1);
    if (::connect(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
      ::close(fd_);
      fd_ = -1;
    }
  }
  ~RawClient() {
    if (fd_ >= 0) ::close(fd_);
  }
  bool ok() const { return fd_ >= 0; }
  bool send(const std::string& bytes) {
    return ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL) ==
           static_cast<ssize_t>(bytes.size());
  }
  void shutdown_write() { ::shutdown(fd_, SHUT_WR); }

  // The next reply line, or nullopt on EOF or after `timeout`.
  std::optional<std::string> line(std::chrono::milliseconds timeout = 3000ms) {
    const auto deadline = SteadyClock::now() + timeout;
    for (;;) {
      if (const auto nl = buf_.find('\n'); nl != std::string::npos) {
        std::string l = buf_.substr(0, nl);
        buf_.erase(0, nl + 1);
        return l;
      }
      if (eof_ || !read_some(deadline)) return std::nullopt;
    }
  }
  // True once the server has closed the connection (all replies read).
  bool closed_by_server(std::chrono::milliseconds timeout = 3000ms) {
    const auto deadline = SteadyClock::now() + timeout;
    while (!eof_ && read_some(deadline)) {
    }
    return eof_;
  }

 private:
  bool read_some(SteadyClock::time_point deadline) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - SteadyClock::now());
    if (left.count() <= 0) return false;
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) return false;
    char b[4096];
    const ssize_t n = ::recv(fd_, b, sizeof b, 0);
    if (n <= 0) {
      eof_ = true;
      return false;
    }
    buf_.append(b, static_cast<std::size_t>(n));
    return true;
  }

  int fd_ = -1;
  std::string buf_;
  bool eof_ = false;
};

// --- The server alone ---

class ControlServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char dir_template[] = "/tmp/gyrotherm-ctl-test-XXXXXX";
    ASSERT_NE(::mkdtemp(dir_template), nullptr);
    dir_ = dir_template;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  static std::string reply_or_error(const std::string& path, const std::string& line) {
    auto reply = send_control_command(path, line);
    return reply.ok() ? *reply : "(client) " + reply.error().message;
  }
  static ControlServer::Handler echo() {
    return [](std::string_view line) { return "ok " + std::string(line); };
  }
  std::string dir_;
};

TEST_F(ControlServerTest, ReplacesAStaleSocketButNotALiveOneOrAFile) {
  const std::string path = dir_ + "/sub/ctl.sock";  // the parent is created
  {
    // A socket file nobody listens on any more, as a killed simulator leaves.
    auto first = ControlServer::open({path});
    ASSERT_TRUE(first.ok()) << first.error().message;
    const std::string kept = dir_ + "/kept.sock";
    std::filesystem::rename(path, kept);
    (*first)->stop();
    std::filesystem::rename(kept, path);
  }
  ASSERT_TRUE(std::filesystem::is_socket(path));
  auto server = ControlServer::open({path});
  ASSERT_TRUE(server.ok()) << server.error().message;
  (*server)->serve(echo());
  EXPECT_EQ(reply_or_error(path, "hello"), "ok hello");

  auto second = ControlServer::open({path});
  ASSERT_FALSE(second.ok());
  EXPECT_TRUE(second.error().transient);
  EXPECT_NE(second.error().message.find("in use"), std::string::npos) << second.error().message;
  EXPECT_EQ(reply_or_error(path, "still"), "ok still");  // untouched

  (*server)->stop();
  EXPECT_FALSE(std::filesystem::exists(path));

  const std::string file = dir_ + "/not-a-socket";
  std::ofstream(file) << "data";
  auto refused = ControlServer::open({file});
  ASSERT_FALSE(refused.ok());
  EXPECT_FALSE(refused.error().transient);
  EXPECT_NE(refused.error().message.find("is not a socket"), std::string::npos);
  EXPECT_TRUE(std::filesystem::exists(file));
}

TEST_F(ControlServerTest, ClientReportsAMissingSocket) {
  auto reply = send_control_command(dir_ + "/nobody.sock", "status");
  ASSERT_FALSE(reply.ok());
  EXPECT_TRUE(reply.error().transient);
  EXPECT_NE(reply.error().message.find("cannot connect"), std::string::npos);
  EXPECT_FALSE(send_control_command(dir_ + "/x.sock", "two\nlines").ok());
}

TEST_F(ControlServerTest, ManyClientsPipelinedLinesAndTheLimitOnClients) {
  const std::string path = dir_ + "/ctl.sock";
  ControlServer::Options options{path};
  options.max_clients = 3;
  auto server = ControlServer::open(options);
  ASSERT_TRUE(server.ok()) << server.error().message;
  (*server)->serve(echo());

  RawClient a(path), b(path), c(path);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  ASSERT_TRUE(a.send("one\r\ntwo\nthr"));
  EXPECT_EQ(a.line(), "ok one");
  EXPECT_EQ(a.line(), "ok two");
  ASSERT_TRUE(b.send("bee\n"));
  EXPECT_EQ(b.line(), "ok bee");
  ASSERT_TRUE(a.send("ee\n"));
  EXPECT_EQ(a.line(), "ok three");

  RawClient d(path);  // the fourth
  EXPECT_EQ(d.line(), "error too many control connections (3)");
  EXPECT_TRUE(d.closed_by_server());
  EXPECT_TRUE(wait_for([&] { return (*server)->stats().refused_connections == 1; }));

  // The last line without a newline is answered when the client shuts down.
  ASSERT_TRUE(c.send("last"));
  c.shutdown_write();
  EXPECT_EQ(c.line(), "ok last");
  EXPECT_TRUE(c.closed_by_server());
  EXPECT_TRUE(wait_for([&] { return (*server)->stats().active_connections == 2; }));
}

// --- The simulator through its control socket ---

class ControlSocketTest : public SimFixture {
 protected:
  // One command through a fresh connection, as gyrotherm-sim ctl sends it.
  std::string command(const std::string& line) {
    auto reply = send_control_command(options_.control_socket, line);
    EXPECT_TRUE(reply.ok()) << line << ": " << reply.error().message;
    return reply.ok() ? *reply : std::string();
  }
  nlohmann::json status_reply() {
    const std::string reply = command("status");
    EXPECT_EQ(reply.rfind("ok {", 0), 0u) << reply;
    return nlohmann::json::parse(reply.size() > 3 ? reply.substr(3) : "{}");
  }
};

TEST_F(ControlSocketTest, ChamberAlarmReadsThroughModbus) {
  ASSERT_NO_FATAL_FAILURE(start());
  ASSERT_TRUE(config_.chamber.map.alarm);
  // The F4T's alarm 1 state (demo.toml): Watlow's enumerations.
  const drivers::RegisterSpec alarm = config_.chamber.map.alarm->reg;
  EXPECT_EQ(alarm.address, 1356);
  ModbusClient client(port(), chamber_unit());
  EXPECT_EQ(client.read(alarm), 61.0);  // None

  EXPECT_EQ(command("chamber alarm on"), "ok");
  EXPECT_EQ(client.read(alarm), 7.0);  // Alarm High, at once, not at the next tick
  EXPECT_TRUE(sim_->status().faults.chamber_alarm);
  EXPECT_EQ(status_reply()["faults_active"], (nlohmann::json{"chamber_alarm"}));

  EXPECT_EQ(command("chamber alarm off"), "ok");
  EXPECT_EQ(client.read(alarm), 61.0);
  // A client cannot clear or raise it: the state is read-only (exception 2).
  ASSERT_FALSE(client.write(alarm, 7));
  EXPECT_EQ(errno, EMBXILADD) << modbus_strerror(errno);
  EXPECT_EQ(client.read(alarm), 61.0);
}

// "chamber units f": the F4T's units register says °F and the temperature
// registers follow; the set point stays where it was.
TEST_F(ControlSocketTest, ChamberUnitsSwitchTheServedTemperatures) {
  ManualClock& clock = manual_clock_;
  ASSERT_NO_FATAL_FAILURE(start(&clock));
  const auto& map = config_.chamber.map;
  ASSERT_TRUE(map.units);
  ModbusClient client(port(), chamber_unit());
  EXPECT_EQ(client.read(map.units->reg), 15.0);
  EXPECT_EQ(client.read(map.setpoint), 23.0);
  const double air_c = sim_->status().truth.air_c;
  EXPECT_NEAR(client.read(map.process_value).value_or(-999), air_c, 1e-4);

  EXPECT_EQ(command("chamber units f"), "ok");
  EXPECT_EQ(client.read(map.units->reg), 30.0);
  EXPECT_NEAR(client.read(map.setpoint).value_or(-999), 73.4, 1e-4);
  EXPECT_NEAR(client.read(map.process_value).value_or(-999), air_c * 1.8 + 32, 1e-4);
  EXPECT_EQ(status_reply()["faults"]["chamber_units"], "F");
  // A set point written in °F: 104 °F = 40 °C.
  ASSERT_TRUE(client.write(map.setpoint, 104.0));
  EXPECT_TRUE(wait_for([&] { return std::abs(sim_->status().setpoint_c - 40.0) < 1e-4; }));
  // °F beyond 200 °C is refused: 400 °C = 752 °F.
  EXPECT_FALSE(client.write(map.setpoint, 752.0));

  EXPECT_EQ(command("chamber units c"), "ok");
  EXPECT_EQ(client.read(map.units->reg), 15.0);
  EXPECT_NEAR(client.read(map.setpoint).value_or(-999), 40.0, 1e-4);
}

TEST_F(ControlSocketTest, AlarmWithoutARegisterIsAnError) {
  config_.chamber.map.alarm.reset();
  ASSERT_NO_FATAL_FAILURE(start());
  const std::string reply = command("chamber alarm on");
  EXPECT_EQ(reply.rfind("error ", 0), 0u) << reply;
  EXPECT_NE(reply.find("[chamber.alarm]"), std::string::npos) << reply;
}

TEST_F(ControlSocketTest, ChamberForceDrivesTheAirOutOfLimitsAndReleaseBringsItBack) {
  ManualClock& clock = manual_clock_;
  ASSERT_NO_FATAL_FAILURE(start(&clock));
  ModbusClient client(port(), chamber_unit());
  const auto& map = config_.chamber.map;

  EXPECT_EQ(command("chamber force 80"), "ok");
  // 5 °C/min from 23 °C with a 120 s lag: past 60 °C after ~565 s, near 78
  // °C at 900 s (control noise std 0.25 °C).
  clock.advance(900);
  ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= 900 - 1e-6; }));
  const auto forced = sim_->status();
  EXPECT_GT(forced.truth.air_c, 70.0);
  // The registers are published just after the step.
  EXPECT_TRUE(wait_for([&] { return client.read(map.process_value).value_or(0) > 70.0; }));
  // The client's set point stands, in the register and the status.
  EXPECT_EQ(client.read(map.setpoint).value_or(0), 23.0);
  EXPECT_EQ(forced.setpoint_c, 23.0);
  EXPECT_EQ(forced.faults.chamber_forced_c, 80.0);
  EXPECT_EQ(status_reply()["faults"]["chamber_forced_c"], 80.0);

  EXPECT_EQ(command("chamber release"), "ok");
  clock.advance(1500);  // back at 5 °C/min: ramp done after ~690 s, then 6.7 lags
  ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= 2400 - 1e-6; }));
  EXPECT_NEAR(sim_->status().truth.air_c, 23.0, 1.5);
  EXPECT_FALSE(sim_->status().faults.chamber_forced_c);
  EXPECT_TRUE(status_reply()["faults"]["chamber_forced_c"].is_null());
}

TEST_F(ControlSocketTest, ModbusDownRefusesConnectionsUntilUp) {
  ASSERT_NO_FATAL_FAILURE(start());
  ModbusClient client(port(), chamber_unit(), 0.2);
  ASSERT_TRUE(client.read(config_.chamber.map.process_value));

  EXPECT_EQ(command("modbus down"), "ok");
  EXPECT_TRUE(wait_for([&] {
    client.connect();
    return !client.read(config_.chamber.map.process_value);
  }));
  EXPECT_TRUE(wait_for([&] { return sim_->status().modbus.refused_connections >= 1; }));
  EXPECT_EQ(status_reply()["faults"]["modbus_down"], true);

  EXPECT_EQ(command("modbus up"), "ok");
  EXPECT_TRUE(wait_for([&] {
    client.connect();
    return client.read(config_.chamber.map.process_value).has_value();
  }));
}

TEST_F(ControlSocketTest, EveryFaultCommandReachesItsHook) {
  ASSERT_NO_FATAL_FAILURE(start());
  EXPECT_EQ(command("modbus delay 0.05"), "ok");
  EXPECT_EQ(command("frames corrupt 0.25"), "ok");
  EXPECT_EQ(command("frames drop 0.5"), "ok");
  EXPECT_EQ(command("probe stall side"), "ok");
  EXPECT_EQ(command("pty hold"), "ok");
  EXPECT_TRUE(sim_->status().faults.pty_held);
  EXPECT_EQ(command("pty close"), "ok");
  SimulatorFaults f = sim_->status().faults;
  EXPECT_DOUBLE_EQ(f.modbus_reply_delay_s, 0.05);
  EXPECT_DOUBLE_EQ(f.frame_corruption_rate, 0.25);
  EXPECT_DOUBLE_EQ(f.frame_drop_rate, 0.5);
  EXPECT_TRUE(f.side_stalled);
  EXPECT_FALSE(f.top_stalled);
  EXPECT_FALSE(f.pty_open);
  EXPECT_EQ(status_reply()["faults_active"],
            (nlohmann::json{"modbus_delay", "pty_closed", "pty_held", "frames_corrupt",
                            "frames_drop", "probe_stall_side"}));

  const std::string reopened = command("pty reopen");
  ASSERT_EQ(reopened.rfind("ok {", 0), 0u) << reopened;
  EXPECT_EQ(nlohmann::json::parse(reopened.substr(3))["gyro_device"], options_.gyro_link);
  EXPECT_EQ(command("modbus delay 0"), "ok");
  EXPECT_EQ(command("frames corrupt 0"), "ok");
  EXPECT_EQ(command("frames drop 0"), "ok");
  EXPECT_EQ(command("probe release side"), "ok");
  EXPECT_EQ(command("pty release"), "ok");
  f = sim_->status().faults;
  EXPECT_TRUE(f.pty_open);
  EXPECT_FALSE(f.pty_held);
  EXPECT_EQ(status_reply()["faults_active"], nlohmann::json::array());

  const std::string help = command("help");
  ASSERT_EQ(help.rfind("ok {", 0), 0u) << help;
  EXPECT_EQ(nlohmann::json::parse(help.substr(3))["commands"].size(), control_commands().size());
}

// A DUT's own probe stalled over the socket: its register keeps its value
// while the station's pair and its other probe read on; released, it
// follows its shell again. The demo's DUTs get probes here: 17-0043 on
// channels 4 and 5, TS-7 on channel 0 (the station's top: not its own).
TEST_F(ControlSocketTest, DutProbeStallFreezesThatDutsRegisterOnly) {
  config_.duts[1].probes = config::DutProbes{4, 5};
  config_.duts[2].probes = config::DutProbes{0, 6};
  options_.thermal.probe_noise_c = 0.5;  // every reading moves at every step
  ASSERT_NO_FATAL_FAILURE(start(&manual_clock_));
  ModbusClient client(port(), probes_unit());
  const auto top4 = drivers::probe_channel_spec("generic", 4);
  const auto side5 = drivers::probe_channel_spec("generic", 5);
  ASSERT_TRUE(top4.ok() && side5.ok());
  const auto advance = [&](double dt_s) {
    manual_clock_.advance(dt_s);
    const double target_s = manual_clock_.now_s() - 1e-6;
    ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= target_s; }));
  };
  // The registers as published after the last step.
  const auto published = [&](const DutSimStatus& d) {
    return wait_for([&] {
      return client.read(*top4) == d.probe_readings->top_c &&
             client.read(*side5) == d.probe_readings->side_c;
    });
  };
  ASSERT_NO_FATAL_FAILURE(advance(1.0));

  EXPECT_EQ(command("probe stall top 17-0043"), "ok");
  const SimulatorStatus at_stall = sim_->status();
  ASSERT_TRUE(at_stall.duts[1].probe_readings);
  const double frozen_c = at_stall.duts[1].probe_readings->top_c;
  ASSERT_TRUE(published(at_stall.duts[1]));
  int side_moves = 0, station_moves = 0;
  double side_c = at_stall.duts[1].probe_readings->side_c;
  double station_top_c = at_stall.readings.top_c;
  for (int k = 0; k < 5; ++k) {
    ASSERT_NO_FATAL_FAILURE(advance(3.0));
    const SimulatorStatus st = sim_->status();
    ASSERT_TRUE(published(st.duts[1]));
    EXPECT_EQ(client.read(*top4), frozen_c) << "step " << k;
    EXPECT_EQ(st.duts[1].probe_readings->top_c, frozen_c);
    side_moves += st.duts[1].probe_readings->side_c != side_c;
    station_moves += st.readings.top_c != station_top_c;
    side_c = st.duts[1].probe_readings->side_c;
    station_top_c = st.readings.top_c;
  }
  EXPECT_GE(side_moves, 3);  // 0.5 °C of noise read at 0.1 °C: the others move
  EXPECT_GE(station_moves, 3);
  const auto j = status_reply();
  EXPECT_EQ(j["duts"][1]["faults_active"], (nlohmann::json{"probe_stall_top"}));
  EXPECT_EQ(j["duts"][1]["faults"]["probe_stalled"]["top"], true);
  EXPECT_EQ(j["duts"][1]["faults"]["probe_stalled"]["side"], false);
  EXPECT_EQ(j["faults_active"], nlohmann::json::array());  // the station's pair reads on
  EXPECT_EQ(j["faults"]["probe_stalled"]["top"], false);

  EXPECT_EQ(command("probe release top 17-0043"), "ok");
  int top_moves = 0;
  for (int k = 0; k < 5; ++k) {
    ASSERT_NO_FATAL_FAILURE(advance(3.0));
    const SimulatorStatus st = sim_->status();
    ASSERT_TRUE(published(st.duts[1]));
    top_moves += st.duts[1].probe_readings->top_c != frozen_c;
  }
  EXPECT_GE(top_moves, 3);
  EXPECT_FALSE(sim_->status().duts[1].probe_top_stalled);

  // What cannot be stalled says why, and changes nothing.
  EXPECT_EQ(command("probe stall side NOPE"),
            "error no DUT with serial 'NOPE'; the simulator serves '17-0042', '17-0043', 'TS-7'");
  const std::string no_probes = command("probe stall top 17-0042");
  EXPECT_EQ(no_probes.rfind("error DUT '17-0042' has no probes of its own", 0), 0u) << no_probes;
  const std::string shared = command("probe stall top TS-7");
  EXPECT_EQ(shared.rfind("error the top probe of DUT 'TS-7' is channel 0, which another probe", 0),
            0u)
      << shared;
  EXPECT_EQ(command("probe stall side TS-7"), "ok");  // channel 6: its own
  const SimulatorStatus st = sim_->status();
  EXPECT_FALSE(st.faults.top_stalled);
  EXPECT_FALSE(st.duts[2].probe_top_stalled);
  EXPECT_TRUE(st.duts[2].probe_side_stalled);
  EXPECT_FALSE(st.duts[1].probe_side_stalled);
}

TEST_F(ControlSocketTest, GarbageAndOversizeLinesGetErrorsAndTheServerKeepsAnswering) {
  ASSERT_NO_FATAL_FAILURE(start());
  RawClient bystander(options_.control_socket);
  RawClient rude(options_.control_socket);
  ASSERT_TRUE(bystander.ok() && rude.ok());

  ASSERT_TRUE(rude.send(std::string("\x01\x02\xff\xfe garbage\n", 13)));
  const auto garbage = rude.line();
  ASSERT_TRUE(garbage);
  EXPECT_EQ(garbage->rfind("error unknown command", 0), 0u) << *garbage;
  ASSERT_TRUE(rude.send("\n"));
  EXPECT_EQ(rude.line().value_or("").rfind("error empty command", 0), 0u);
  ASSERT_TRUE(rude.send("chamber force 9000\nstatus\n"));  // still connected
  EXPECT_EQ(rude.line().value_or("").rfind("error 'chamber force': 9000 is outside", 0), 0u);
  EXPECT_EQ(rude.line().value_or("").rfind("ok {", 0), 0u);

  // Oversize, in pieces and without a newline: an error, then hung up.
  const std::string huge(5000, 'a');
  ASSERT_TRUE(rude.send(huge.substr(0, 3000)));
  ASSERT_TRUE(rude.send(huge.substr(3000)));
  EXPECT_EQ(rude.line(), "error line longer than 4096 bytes");
  EXPECT_TRUE(rude.closed_by_server());

  // Oversize with a newline.
  RawClient rude2(options_.control_socket);
  ASSERT_TRUE(rude2.send(std::string(4097, 'b') + "\nstatus\n"));
  EXPECT_EQ(rude2.line(), "error line longer than 4096 bytes");
  EXPECT_TRUE(rude2.closed_by_server());

  ASSERT_TRUE(bystander.send("status\n"));
  const auto status = bystander.line();
  ASSERT_TRUE(status);
  EXPECT_EQ(status->rfind("ok {", 0), 0u) << *status;
  EXPECT_EQ(command("modbus up"), "ok");
  EXPECT_TRUE(sim_->status().running);
}

}  // namespace
}  // namespace gyrotherm::sim
