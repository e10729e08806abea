// The simulator's rate table over its real interfaces: ACL on TCP loopback
// with a raw socket client (each framing, chains, errors, hang,
// disconnect), the AERO grammar on the pty, and the control commands.
#include "gyrotherm/sim/table_server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "gyrotherm/sim/control_server.h"
#include "sim_test_util.h"

namespace gyrotherm::sim {
namespace {

using namespace test_util;

// Reads exactly `n` bytes (or fewer at EOF/deadline).
std::string read_n(int fd, std::size_t n, std::chrono::milliseconds timeout = 3000ms) {
  std::string out;
  const auto deadline = SteadyClock::now() + timeout;
  while (out.size() < n) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - SteadyClock::now());
    if (left.count() <= 0) break;
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) break;
    char buf[1];
    const ssize_t r = ::read(fd, buf, 1);
    if (r <= 0) break;
    out += buf[0];
  }
  return out;
}

// Reads until `end` (included).
std::string read_until(int fd, std::string_view end, std::chrono::milliseconds timeout = 3000ms) {
  std::string out;
  const auto deadline = SteadyClock::now() + timeout;
  while (out.size() < end.size() || out.compare(out.size() - end.size(), end.size(), end) != 0) {
    const std::string c = read_n(
        fd, 1,
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - SteadyClock::now()));
    if (c.empty()) break;
    out += c;
  }
  return out;
}

class AclClient {
 public:
  AclClient(int port, std::string framing) : framing_(std::move(framing)) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(static_cast<uint16_t>(port));
    ::inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
  }
  ~AclClient() { ::close(fd_); }
  bool connected() const { return connected_; }
  int fd() const { return fd_; }
  bool send(std::string_view line, std::string_view end = "\r\n") {
    std::string s(line);
    s += end;
    return ::send(fd_, s.data(), s.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(s.size());
  }
  // The reply, decoded by the framing; code -1 when none came.
  AclReply receive() {
    if (framing_ == "line") {
      const std::string l = read_until(fd_, "\n");
      if (l.empty()) return {-1, ""};
      const std::string payload = l.substr(0, l.size() - 1);
      if (payload.rfind("ERR ", 0) == 0) return {std::stoi(payload.substr(4)), ""};
      return {0, payload};
    }
    const std::string header = read_n(fd_, 8);
    if (header.size() != 8) return {-1, ""};
    int code, length;
    if (framing_ == "ascii") {
      code = std::stoi(header.substr(0, 4));
      length = std::stoi(header.substr(4, 4));
    } else {
      auto word = [&](int at) {
        uint32_t v = 0;
        for (int i = 0; i < 4; ++i) {
          const auto b = static_cast<uint8_t>(header[static_cast<std::size_t>(at + i)]);
          v |= static_cast<uint32_t>(b) << (framing_ == "binary-le" ? 8 * i : 8 * (3 - i));
        }
        return static_cast<int>(v);
      };
      code = word(0);
      length = word(4);
    }
    return {code, read_n(fd_, static_cast<std::size_t>(length))};
  }
  AclReply ask(std::string_view line) {
    if (!send(line)) return {-1, ""};
    return receive();
  }
  // True once the server has closed the connection (within the deadline).
  bool closed_by_peer() {
    return wait_for([&] {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 0) <= 0) return false;
      char c;
      return ::recv(fd_, &c, 1, MSG_DONTWAIT) == 0;
    });
  }

 private:
  std::string framing_;
  int fd_ = -1;
  bool connected_ = false;
};

class TableServerTest : public SimFixture, public ::testing::WithParamInterface<std::string> {
 protected:
  void start_table(const std::string& framing = "ascii") {
    config_.table = config::TableSection{};
    auto options = read_simulator_options(config_, {});
    ASSERT_TRUE(options.ok());
    options_.serve_table = options->serve_table;
    options_.table.reply_header = framing;
    start(&manual_clock_);
    ASSERT_TRUE(sim_->has_table());
  }
  // Moves station time and waits for the simulation to catch up.
  void advance(double dt_s) {
    manual_clock_.advance(dt_s);
    const double target = manual_clock_.now_s() - 1e-6;
    ASSERT_TRUE(wait_for([&] { return sim_->status().t_s >= target - 0.11; }));
  }
  std::string control(std::string_view command) {
    auto r = send_control_command(options_.control_socket, command);
    return r.ok() ? *r : "transport error: " + r.error().message;
  }
};

TEST_P(TableServerTest, FramingCarriesCodesAndPayloads) {
  start_table(GetParam());
  AclClient c(sim_->endpoints().table_port, GetParam());
  ASSERT_TRUE(c.connected());
  AclReply r = c.ask("*IDN?");
  EXPECT_EQ(r.code, 0);
  EXPECT_EQ(r.payload, "Gyrotherm,SIM-ACT3000,0001,1.0");
  r = c.ask(":U:L ON");
  EXPECT_EQ(r.code, 0);
  EXPECT_EQ(r.payload, "OK");
  r = c.ask(":D:R 2,10");
  EXPECT_EQ(r.code, kAclBadAxis);
  EXPECT_EQ(r.payload, "");
  r = c.ask(":Q:E? 2");
  EXPECT_EQ(r.payload, "No such axis");
}

INSTANTIATE_TEST_SUITE_P(Framings, TableServerTest,
                         ::testing::Values("ascii", "binary-le", "binary-be", "line"));

using TableAclTest = TableServerTest;

TEST_F(TableAclTest, ChainsRunInOneFrameAndKeepTheirSubsystem) {
  start_table();
  AclClient c(sim_->endpoints().table_port, "ascii");
  ASSERT_TRUE(c.connected());
  // Long, short and mixed-case forms; a sub-command after ';' without ':'
  // stays in the previous subsystem (TM-8004 §2.2.2).
  EXPECT_EQ(c.ask(":Demand:Rate 1,20;Position 1,30").payload, "OK");
  EXPECT_EQ(c.ask(":dem:rate? 1;:D:P? 1").payload, "20.000000;30.000000");
  EXPECT_EQ(c.ask(":Mode:Position 1;Rate 1").payload, "OK");
  EXPECT_EQ(c.ask(":I:O 1;C 1").payload, "OK");
  EXPECT_EQ(c.ask(":M? 1;:I? 1").payload, "Rate;Closed");
  // ALL is an axis for commands, not for queries.
  EXPECT_EQ(c.ask(":M:O ALL").payload, "OK");
  EXPECT_EQ(c.ask(":M? ALL").code, kAclBadArguments);
  // Requests may end in LF alone.
  ASSERT_TRUE(c.send(":M? 1", "\n"));
  EXPECT_EQ(c.receive().payload, "Off");
}

TEST_F(TableAclTest, ErrorsAnswerACodeAndExecuteNothing) {
  start_table();
  AclClient c(sim_->endpoints().table_port, "ascii");
  ASSERT_TRUE(c.connected());
  ASSERT_EQ(c.ask(":D:R 1,50").code, 0);
  const struct {
    const char* request;
    int code;
  } cases[] = {
      {":Demand:Posn 1,10", kAclUnknownCommand},  // TM-8004 §2.1: spelling
      {":Dem;Pos 1,10", kAclUnknownCommand},      // misuse of ';'
      {":D:P,1,10", kAclUnknownCommand},          // comma before the arguments
      {":D:R 3,10", kAclBadAxis},
      {":D:R 1,1000.5", kAclOutOfRange},  // beyond the rate limit
      {":D:R 1,x", kAclBadArguments},
      {":D:R 1", kAclBadArguments},
      {":L:R X,1,100", kAclOutOfRange},      // no such mode
      {":D:R 1,60;:D:R 2,70", kAclBadAxis},  // the good half is not executed
      {"*IDN", kAclUnknownCommand},          // a query without '?'
  };
  for (const auto& k : cases) {
    const AclReply r = c.ask(k.request);
    EXPECT_EQ(r.code, k.code) << k.request;
    EXPECT_EQ(r.payload, "") << k.request;
  }
  EXPECT_EQ(c.ask(":D:R? 1").payload, "50.000000");
  EXPECT_EQ(c.ask(":Q:E? 3").payload, "Parameter out of range");
}

TEST_F(TableAclTest, SpinsUpInStationTimeAndTripsAndResets) {
  start_table();
  AclClient c(sim_->endpoints().table_port, "ascii");
  ASSERT_TRUE(c.connected());
  EXPECT_EQ(c.ask(":L:R? R,1;:L:A? R,1;:L:V? R,1").payload, "1000.000000;1000.000000;1100.000000");
  ASSERT_EQ(c.ask(":U:L ON;:I:R;:D:R 1,100;:M:R 1;:I:C 1").payload, "OK");
  advance(2.0);  // 0.28 s to reach 100 °/s
  const double rate = std::stod(c.ask(":R:R? 1").payload);
  EXPECT_NEAR(rate, 100, 100 * 5e-4);  // 5 σ of the 1e-4 measurement noise
  EXPECT_EQ(c.ask("*STB?").payload, "0");
  // Over-speed: a trip below the rate faults the interlock.
  ASSERT_EQ(c.ask(":L:V R,1,50").payload, "OK");
  advance(0.2);
  EXPECT_EQ(c.ask(":I? 1;:M? 1;*STB?").payload, "Fault;Off;1");
  EXPECT_EQ(c.ask(":I:C 1").code, kAclRefused);
  advance(1.0);  // coasts to rest at 1000 °/s²
  EXPECT_EQ(c.ask(":R:R? 1").payload, "0.000000");
  EXPECT_EQ(c.ask(":I:R;:L:V R,1,1100;:I:C 1;:I? 1").payload, "Closed");
  const auto status = sim_->status().table;
  EXPECT_TRUE(status.served);
  EXPECT_EQ(status.state.interlock, drivers::TableInterlock::kClosed);
}

TEST_F(TableAclTest, HangKeepsTheConnectionAndDisconnectRefusesUntilConnect) {
  start_table();
  AclClient c(sim_->endpoints().table_port, "ascii");
  ASSERT_TRUE(c.connected());
  ASSERT_EQ(c.ask("*IDN?").code, 0);
  ASSERT_EQ(control("table hang"), "ok");
  ASSERT_TRUE(c.send("*IDN?"));
  // The server has read the request and dropped it: nothing came back.
  ASSERT_TRUE(wait_for([&] { return sim_->status().table.acl_unanswered == 1; }));
  char byte;
  EXPECT_EQ(::recv(c.fd(), &byte, 1, MSG_DONTWAIT), -1);
  ASSERT_EQ(control("table clear"), "ok");
  EXPECT_EQ(c.ask("*IDN?").code, 0);  // the same connection answers again

  ASSERT_EQ(control("table disconnect"), "ok");
  EXPECT_TRUE(c.closed_by_peer());
  AclClient refused(sim_->endpoints().table_port, "ascii");
  EXPECT_TRUE(refused.closed_by_peer());
  const nlohmann::json st = nlohmann::json::parse(control("table status").substr(3));
  EXPECT_EQ(st["faults"], nlohmann::json::array({"disconnect"}));
  ASSERT_EQ(control("table connect"), "ok");
  AclClient again(sim_->endpoints().table_port, "ascii");
  ASSERT_TRUE(again.connected());
  EXPECT_EQ(again.ask("*IDN?").code, 0);
}

TEST_F(TableAclTest, FaultCommandLatchesTheInterlockAndStatusShowsIt) {
  start_table();
  ASSERT_EQ(control("table fault"), "ok");
  AclClient c(sim_->endpoints().table_port, "ascii");
  EXPECT_EQ(c.ask(":I? 1").payload, "Fault");
  const nlohmann::json st = nlohmann::json::parse(control("status").substr(3));
  EXPECT_EQ(st["table"]["interlock"], "fault");
  EXPECT_EQ(st["table"]["faults"], nlohmann::json::array({"interlock_fault"}));
  EXPECT_EQ(st["table"]["port"], sim_->endpoints().table_port);
}

TEST_F(TableAclTest, WithoutATableTheControlCommandsSaySo) {
  start(&manual_clock_);
  EXPECT_FALSE(sim_->has_table());
  EXPECT_EQ(sim_->endpoints().table_port, 0);
  EXPECT_EQ(control("table status").rfind("error the simulator serves no table", 0), 0u);
}

// --- AERO on the pty ---

class AeroLine {
 public:
  explicit AeroLine(const std::string& path) {
    fd_ = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (fd_ >= 0) {
      termios t{};
      ::tcgetattr(fd_, &t);
      ::cfmakeraw(&t);
      ::tcsetattr(fd_, TCSANOW, &t);
    }
  }
  ~AeroLine() {
    if (fd_ >= 0) ::close(fd_);
  }
  bool open() const { return fd_ >= 0; }
  // The reply line (without "\r"), after checking the prompt follows.
  std::string ask(const std::string& request) {
    const std::string s = request + "\r\n";
    if (::write(fd_, s.data(), s.size()) != static_cast<ssize_t>(s.size())) return "<write>";
    const std::string got = read_until(fd_, ">\r");
    if (got.size() < 3 || got.compare(got.size() - 3, 3, "\r>\r") != 0) return "<no prompt>";
    return got.substr(0, got.size() - 3);
  }

 private:
  int fd_ = -1;
};

TEST_F(TableAclTest, AeroGrammarReachesTheSameTable) {
  start_table();
  AeroLine line(sim_->endpoints().table_device);
  ASSERT_TRUE(line.open()) << sim_->endpoints().table_device;
  EXPECT_EQ(line.ask("STA"), "2");  // healthy, not servoed
  EXPECT_EQ(line.ask("JOG-50"), "");
  advance(2.0);
  EXPECT_NEAR(std::stod(line.ask("PVE")), -50, 50 * 5e-4);
  EXPECT_EQ(line.ask("STA"), "0");
  AclClient c(sim_->endpoints().table_port, "ascii");
  EXPECT_EQ(c.ask(":M? 1").payload, "Rate");  // one table, two ways in
  EXPECT_EQ(line.ask("JOG5000"), "?");        // beyond the rate limit
  EXPECT_EQ(line.ask("XYZ"), "?");
  EXPECT_EQ(line.ask("PVE1"), "?");
  EXPECT_EQ(line.ask("STO"), "");
  advance(1.0);
  EXPECT_EQ(line.ask("MOV 90"), "");
  advance(20.0);
  EXPECT_NEAR(std::stod(line.ask("PPO")), 90, 1e-5);
  ASSERT_EQ(control("table fault"), "ok");
  EXPECT_EQ(line.ask("STA"), "3");
  EXPECT_EQ(line.ask("JOG10"), "?");  // latched
  EXPECT_EQ(line.ask("RST"), "");
  EXPECT_EQ(line.ask("STA"), "2");
}

}  // namespace
}  // namespace gyrotherm::sim
