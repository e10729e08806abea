// ModbusDevice against a real libmodbus TCP server on 127.0.0.1, port 0,
// and over RTU against a pymodbus server (an independent implementation) on
// a pair of pseudo-terminals joined back to back.
#include "gyrotherm/drivers/modbus_device.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/drivers/pty.h"

extern char** environ;

#include "test_time.h"

namespace gyrotherm::drivers {
namespace {

using namespace std::chrono_literals;

// Binds 127.0.0.1:0 and returns the listening socket; `port` gets the port.
int listen_on_free_port(int& port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = 0;
  if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 ||
      ::listen(fd, 4) != 0) {
    return -1;
  }
  socklen_t len = sizeof addr;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  port = ntohs(addr.sin_port);
  return fd;
}

// One-client-at-a-time Modbus TCP server: libmodbus frames the requests and
// replies from a register mapping; we own the sockets.
class TestServer {
 public:
  static constexpr int kRegisters = 4000;

  TestServer() {
    mapping_ = modbus_mapping_new(0, 0, kRegisters, kRegisters);
    listen_fd_ = listen_on_free_port(port_);
    ctx_ = modbus_new_tcp("127.0.0.1", port_);
    thread_ = std::thread([this] { serve(); });
  }
  ~TestServer() {
    stop_ = true;
    thread_.join();
    if (client_fd_ >= 0) ::close(client_fd_);
    ::close(listen_fd_);
    modbus_free(ctx_);
    modbus_mapping_free(mapping_);
  }

  bool ok() const { return mapping_ != nullptr && listen_fd_ >= 0 && ctx_ != nullptr; }
  int port() const { return port_; }
  int accepted() const { return accepted_; }

  void set_holding(int address, uint16_t v) {
    std::lock_guard lock(mu_);
    mapping_->tab_registers[address] = v;
  }
  uint16_t holding(int address) {
    std::lock_guard lock(mu_);
    return mapping_->tab_registers[address];
  }
  void set_input(int address, uint16_t v) {
    std::lock_guard lock(mu_);
    mapping_->tab_input_registers[address] = v;
  }
  // Closes the client's connection from the server side (as a controller
  // that reboots, or a gateway that drops idle links).
  void drop_client() {
    std::lock_guard lock(mu_);
    if (client_fd_ >= 0) ::shutdown(client_fd_, SHUT_RDWR);
  }

 private:
  void serve() {
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    while (!stop_) {
      int client;
      {
        std::lock_guard lock(mu_);
        client = client_fd_;
      }
      pollfd fds[2] = {{listen_fd_, POLLIN, 0}, {client, POLLIN, 0}};
      if (::poll(fds, client >= 0 ? 2 : 1, 20) <= 0) continue;
      if (fds[0].revents & POLLIN) {
        const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
        if (fd >= 0) {
          std::lock_guard lock(mu_);
          if (client_fd_ >= 0) ::close(client_fd_);
          client_fd_ = fd;
          ++accepted_;
        }
        continue;
      }
      if (client >= 0 && fds[1].revents) {
        modbus_set_socket(ctx_, client);
        const int rc = modbus_receive(ctx_, query);
        std::lock_guard lock(mu_);
        if (rc > 0) {
          modbus_reply(ctx_, query, rc, mapping_);
        } else if (rc < 0) {
          ::close(client_fd_);
          client_fd_ = -1;
        }
      }
    }
  }

  std::mutex mu_;
  modbus_mapping_t* mapping_ = nullptr;
  modbus_t* ctx_ = nullptr;
  int listen_fd_ = -1;
  int port_ = 0;
  int client_fd_ = -1;
  std::atomic<int> accepted_{0};
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

ModbusEndpoint endpoint_for(int port) {
  ModbusEndpoint ep;
  ep.transport = "tcp";
  ep.host = "127.0.0.1";
  ep.port = port;
  ep.unit_id = 1;
  ep.response_timeout_s = 0.5;
  return ep;
}

RegisterSpec spec(int address, RegisterType type, WordOrder order = WordOrder::kLowFirst,
                  double scale = 1.0, RegisterFunction fn = RegisterFunction::kHolding) {
  RegisterSpec s;
  s.address = address;
  s.type = type;
  s.word_order = order;
  s.scale = scale;
  s.function = fn;
  return s;
}

TEST(ModbusDevice, DescribeEndpoint) {
  EXPECT_EQ(endpoint_for(1502).describe(), "tcp 127.0.0.1:1502 unit 1");
}

TEST(ModbusDevice, ReadsAndWritesEachType) {
  TestServer server;
  ASSERT_TRUE(server.ok());
  ModbusDevice dev("chamber", endpoint_for(server.port()));
  ASSERT_TRUE(dev.connect().ok());

  // float32, low word first (watlow-f4t set point): 23.5 = 0x41BC0000.
  const auto sp = spec(2782, RegisterType::kFloat32, WordOrder::kLowFirst);
  server.set_holding(2782, 0x0000);
  server.set_holding(2783, 0x41BC);
  auto v = dev.read(sp);
  ASSERT_TRUE(v.ok()) << v.error().message;
  EXPECT_EQ(*v, 23.5);
  ASSERT_TRUE(dev.write(sp, -20.25).ok());  // 0xC1A20000
  EXPECT_EQ(server.holding(2782), 0x0000);
  EXPECT_EQ(server.holding(2783), 0xC1A2);

  // float32, high word first: 0.1f = 0x3DCCCCCD.
  const auto hf = spec(10, RegisterType::kFloat32, WordOrder::kHighFirst);
  ASSERT_TRUE(dev.write(hf, 0.1).ok());
  EXPECT_EQ(server.holding(10), 0x3DCC);
  EXPECT_EQ(server.holding(11), 0xCCCD);
  v = dev.read(hf);
  ASSERT_TRUE(v.ok());
  EXPECT_EQ(*v, static_cast<double>(0.1f));

  // int16 with one implied decimal (watlow-f4).
  const auto pv = spec(100, RegisterType::kInt16, WordOrder::kLowFirst, 0.1);
  server.set_holding(100, 0xFF33);
  v = dev.read(pv);
  ASSERT_TRUE(v.ok());
  EXPECT_NEAR(*v, -20.5, 1e-9);
  ASSERT_TRUE(dev.write(spec(300, RegisterType::kInt16, WordOrder::kLowFirst, 0.1), 45.5).ok());
  EXPECT_EQ(server.holding(300), 455);

  // uint16 (ramp scale).
  ASSERT_TRUE(dev.write(spec(2796, RegisterType::kUint16), 57).ok());
  EXPECT_EQ(server.holding(2796), 57);
  v = dev.read(spec(2796, RegisterType::kUint16));
  ASSERT_TRUE(v.ok());
  EXPECT_EQ(*v, 57.0);

  // Input register (probe channel): readable, not writable.
  auto probe = probe_channel_spec("generic", 5);
  ASSERT_TRUE(probe.ok());
  server.set_input(5, 235);
  v = dev.read(*probe);
  ASSERT_TRUE(v.ok());
  EXPECT_NEAR(*v, 23.5, 1e-9);
  const Status w = dev.write(*probe, 1.0);
  ASSERT_FALSE(w.ok());
  EXPECT_FALSE(w.error().transient);

  // A value that does not fit is refused before anything is sent.
  const Status big = dev.write(spec(300, RegisterType::kInt16, WordOrder::kLowFirst, 0.1), 4000);
  ASSERT_FALSE(big.ok());
  EXPECT_FALSE(big.error().transient);
  EXPECT_NE(big.error().message.find("chamber"), std::string::npos);

  const DeviceHealth h = dev.health();
  EXPECT_TRUE(h.connected);
  EXPECT_EQ(h.requests, 11u);
  EXPECT_EQ(h.errors, 2u);
  EXPECT_EQ(h.reconnects, 0u);
  EXPECT_FALSE(h.last_success_utc.empty());
  EXPECT_GE(h.last_latency_ms, 0.0);
}

TEST(ModbusDevice, ExceptionReplyIsPermanentAndKeepsTheConnection) {
  TestServer server;
  ASSERT_TRUE(server.ok());
  ModbusDevice dev("probes", endpoint_for(server.port()));
  // Illegal data address: beyond the server's map.
  auto v = dev.read(spec(TestServer::kRegisters + 10, RegisterType::kInt16));
  ASSERT_FALSE(v.ok());
  EXPECT_FALSE(v.error().transient);
  const std::string& msg = v.error().message;
  EXPECT_NE(msg.find("probes"), std::string::npos) << msg;
  EXPECT_NE(msg.find("127.0.0.1:" + std::to_string(server.port())), std::string::npos) << msg;
  EXPECT_NE(msg.find(std::to_string(TestServer::kRegisters + 10)), std::string::npos) << msg;
  EXPECT_NE(msg.find(modbus_strerror(EMBXILADD)), std::string::npos) << msg;

  EXPECT_TRUE(dev.health().connected);
  ASSERT_TRUE(dev.read(spec(0, RegisterType::kInt16)).ok());
  EXPECT_EQ(server.accepted(), 1);
  EXPECT_EQ(dev.health().reconnects, 0u);
}

TEST(ModbusDevice, UnreachableDeviceIsATransientError) {
  int port = 0;
  const int fd = listen_on_free_port(port);
  ASSERT_GE(fd, 0);
  ::close(fd);  // nothing listens there any more

  ModbusDevice dev("chamber", endpoint_for(port));
  auto v = dev.read(spec(0, RegisterType::kInt16));
  ASSERT_FALSE(v.ok());
  EXPECT_TRUE(v.error().transient);
  EXPECT_NE(v.error().message.find("chamber"), std::string::npos) << v.error().message;
  EXPECT_NE(v.error().message.find(std::to_string(port)), std::string::npos);
  EXPECT_NE(v.error().message.find("holding register 0"), std::string::npos);

  // Within the backoff interval the next call fails at once, without a new attempt.
  const auto t0 = std::chrono::steady_clock::now();
  auto again = dev.read(spec(0, RegisterType::kInt16));
  ASSERT_FALSE(again.ok());
  EXPECT_TRUE(again.error().transient);
  EXPECT_LT(std::chrono::steady_clock::now() - t0, testing::scaled(50ms));

  const DeviceHealth h = dev.health();
  EXPECT_FALSE(h.connected);
  EXPECT_EQ(h.requests, 2u);
  EXPECT_EQ(h.errors, 2u);
  EXPECT_TRUE(h.last_success_utc.empty());
  EXPECT_FALSE(h.last_error.empty());

  EXPECT_TRUE(dev.connect().error().transient);
}

// Issue 15 item 18: host names are resolved ("localhost" used to become
// 255.255.255.255, "Network is unreachable"); a name that does not resolve
// is reported as such, not as a network fault.
TEST(ModbusDevice, HostNamesAreResolved) {
  TestServer server;
  ASSERT_TRUE(server.ok());
  server.set_holding(9, 4242);
  ModbusEndpoint ep = endpoint_for(server.port());
  ep.host = "localhost";
  ModbusDevice dev("chamber", ep);
  auto v = dev.read(spec(9, RegisterType::kUint16));
  ASSERT_TRUE(v.ok()) << v.error().message;
  EXPECT_EQ(*v, 4242.0);

  ep.host = "chamber.invalid";  // RFC 2606: never resolves
  ModbusDevice nowhere("chamber", ep);
  const Status s = nowhere.connect();
  ASSERT_FALSE(s.ok());
  EXPECT_TRUE(s.error().transient);
  EXPECT_NE(s.error().message.find("cannot resolve host name \"chamber.invalid\""),
            std::string::npos)
      << s.error().message;
  EXPECT_EQ(s.error().message.find("unreachable"), std::string::npos) << s.error().message;
}

TEST(ModbusDevice, HostSpelling) {
  for (const char* good : {"127.0.0.1", "localhost", "a-b.c9.example", "::1", "2001:db8::5"}) {
    EXPECT_EQ(tcp_host_problem(good), "") << good;
  }
  for (const char* bad : {"300.1.2.3", "1.2.3.4.5", "a_b", "a..b", "-a", "a-", "", "1::2::3"}) {
    EXPECT_NE(tcp_host_problem(bad), "") << bad;
  }
}

TEST(ModbusDevice, BadEndpointIsPermanent) {
  ModbusEndpoint ep = endpoint_for(502);
  ep.transport = "udp";
  ModbusDevice dev("chamber", ep);
  const Status s = dev.connect();
  ASSERT_FALSE(s.ok());
  EXPECT_FALSE(s.error().transient);
  EXPECT_NE(s.error().message.find("udp"), std::string::npos);
}

TEST(ModbusDevice, ReconnectsAfterTheServerDropsTheConnection) {
  TestServer server;
  ASSERT_TRUE(server.ok());
  ModbusDevice dev("chamber", endpoint_for(server.port()));
  server.set_holding(7, 123);
  const auto reg = spec(7, RegisterType::kUint16);
  ASSERT_TRUE(dev.read(reg).ok());

  server.drop_client();
  auto failed = dev.read(reg);
  ASSERT_FALSE(failed.ok());
  EXPECT_TRUE(failed.error().transient);
  EXPECT_FALSE(dev.health().connected);

  Result<double> v = Error::Transient("not tried");
  const auto deadline = std::chrono::steady_clock::now() + testing::scaled(5s);
  while (std::chrono::steady_clock::now() < deadline) {
    v = dev.read(reg);
    if (v.ok()) break;
    std::this_thread::sleep_for(10ms);
  }
  ASSERT_TRUE(v.ok()) << v.error().message;
  EXPECT_EQ(*v, 123.0);
  const DeviceHealth h = dev.health();
  EXPECT_TRUE(h.connected);
  EXPECT_EQ(h.reconnects, 1u);
  EXPECT_EQ(server.accepted(), 2);
}

// ---------------------------------------------------------------- Modbus RTU

// Two pseudo-terminals joined back to back (a null-modem cable): bytes
// written to one slave come out of the other. The peer opens one slave path,
// the device under test the other.
class PtyCable {
 public:
  PtyCable() {
    auto a = Pty::open(true);
    auto b = Pty::open(true);
    if (!a || !b) return;
    a_.emplace(std::move(*a));
    b_.emplace(std::move(*b));
    thread_ = std::thread([this] { relay(); });
  }
  ~PtyCable() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  bool ok() const { return a_.has_value() && b_.has_value(); }
  const std::string& end_a() const { return a_->slave_path(); }
  const std::string& end_b() const { return b_->slave_path(); }

 private:
  void relay() {
    uint8_t buf[512];
    while (!stop_) {
      pollfd fds[2] = {{a_->master_fd(), POLLIN, 0}, {b_->master_fd(), POLLIN, 0}};
      if (::poll(fds, 2, 20) <= 0) continue;
      for (int i = 0; i < 2; ++i) {
        if (!(fds[i].revents & POLLIN)) continue;
        const ssize_t n = ::read(fds[i].fd, buf, sizeof buf);
        if (n <= 0) continue;
        (void)(i == 0 ? *b_ : *a_).write_master(std::span<const uint8_t>(buf, n));
      }
    }
  }
  std::optional<Pty> a_, b_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

// tests/drivers/peers/slow_rtu_peer.py on `device`: holding registers of
// units 1 and 2, the one at `delayed_address` answered `delay_s` late.
class SlowRtuPeer {
 public:
  SlowRtuPeer(const std::string& device, int delayed_address, double delay_s,
              const std::vector<std::string>& registers) {
    int out[2];
    if (::pipe2(out, O_CLOEXEC) != 0) return;
    std::vector<std::string> args = {
        "/usr/bin/python3", GYROTHERM_SOURCE_DIR "/tests/drivers/peers/slow_rtu_peer.py", device,
        std::to_string(delayed_address), std::to_string(delay_s)};
    args.insert(args.end(), registers.begin(), registers.end());
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, out[1], STDOUT_FILENO);
    if (::posix_spawn(&pid_, argv[0], &actions, nullptr, argv.data(), environ) != 0) pid_ = -1;
    posix_spawn_file_actions_destroy(&actions);
    ::close(out[1]);
    // Wait (wall, up to 20 s: Python starts slowly on a loaded machine) for "ready".
    std::string said;
    const auto deadline = std::chrono::steady_clock::now() + 20s;
    while (pid_ > 0 && said.find("ready") == std::string::npos &&
           std::chrono::steady_clock::now() < deadline) {
      pollfd pfd{out[0], POLLIN, 0};
      if (::poll(&pfd, 1, 100) <= 0) continue;
      char buf[256];
      const ssize_t n = ::read(out[0], buf, sizeof buf);
      if (n <= 0) break;
      said.append(buf, static_cast<std::size_t>(n));
    }
    // The pipe stays open while the peer runs: an unbuffered Python writes
    // "ready" and "\n" separately, and the second write must not fail.
    out_ = out[0];
    ready_ = said.find("ready") != std::string::npos;
  }
  ~SlowRtuPeer() {
    if (pid_ > 0) {
      ::kill(pid_, SIGTERM);
      ::waitpid(pid_, nullptr, 0);
    }
    if (out_ >= 0) ::close(out_);
  }
  // False when the peer did not start (python3-pymodbus, python3-serial-asyncio
  // missing: scripts/install-deps installs them).
  bool ready() const { return ready_; }

 private:
  pid_t pid_ = -1;
  int out_ = -1;  // the read end of the peer's stdout
  bool ready_ = false;
};

ModbusEndpoint rtu_endpoint(const std::string& device, int unit, double timeout_s) {
  ModbusEndpoint ep;
  ep.transport = "rtu";
  ep.device = device;
  ep.baud = 19200;
  ep.parity = 'N';
  ep.unit_id = unit;
  ep.response_timeout_s = timeout_s;
  return ep;
}

// Issue 15 item 17: a reply that comes after the response timeout must not be
// taken as the answer to the next request. The chamber (unit 1) answers its
// process value 1.5 s late with a 1.0 s timeout; the reads that follow, as in
// `gyrotherm devices`, must each get their own register's value.
TEST(ModbusDeviceRtu, LateReplyIsNotTakenAsTheNextAnswer) {
  constexpr int kPv = 100, kSp = 300, kAlarm = 310, kTop = 200, kSide = 201;
  PtyCable cable;
  ASSERT_TRUE(cable.ok());
  SlowRtuPeer peer(cable.end_a(), kPv, 1.5,
                   {"1=100:413", "1=300:250", "1=310:7", "2=200:222", "2=201:223"});
  ASSERT_TRUE(peer.ready()) << "the pymodbus RTU peer did not start (python3-pymodbus and "
                               "python3-serial-asyncio installed?)";
  const auto u16 = spec(0, RegisterType::kUint16);
  auto at = [&](int address) {
    RegisterSpec s = u16;
    s.address = address;
    return s;
  };
  {
    ModbusDevice chamber("chamber", rtu_endpoint(cable.end_b(), 1, 1.0));
    ModbusDevice probes("probes", rtu_endpoint(cable.end_b(), 2, 1.0));
    auto pv = chamber.read(at(kPv));
    ASSERT_FALSE(pv.ok()) << "the process value came within the timeout: " << *pv;
    EXPECT_TRUE(pv.error().transient);

    auto sp = chamber.read(at(kSp));
    ASSERT_TRUE(sp.ok()) << sp.error().message;
    EXPECT_EQ(*sp, 250.0) << "the set point read returned another register's value";
    auto top = probes.read(at(kTop));
    ASSERT_TRUE(top.ok()) << top.error().message;
    EXPECT_EQ(*top, 222.0);
    auto side = probes.read(at(kSide));
    ASSERT_TRUE(side.ok()) << side.error().message;
    EXPECT_EQ(*side, 223.0);
    // The daemon's poll: a late process value must not land as the alarm word.
    EXPECT_FALSE(chamber.read(at(kPv)).ok());
    auto alarm = chamber.read(at(kAlarm));
    ASSERT_TRUE(alarm.ok()) << alarm.error().message;
    EXPECT_EQ(*alarm, 7.0);
    // The last request timed out again; its reply is still on the way when
    // this process's devices close the line.
    EXPECT_FALSE(chamber.read(at(kPv)).ok());
  }
  // The next process (a fresh device on the same line) must not see it either.
  ModbusDevice next("chamber", rtu_endpoint(cable.end_b(), 1, 1.0));
  auto sp = next.read(at(kSp));
  ASSERT_TRUE(sp.ok()) << sp.error().message;
  EXPECT_EQ(*sp, 250.0) << "stale bytes from the previous user of the line";
}

}  // namespace
}  // namespace gyrotherm::drivers
