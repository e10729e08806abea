// ModbusDevice against a real libmodbus TCP server on 127.0.0.1, port 0.
#include "gyrotherm/drivers/modbus_device.h"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <thread>

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

}  // namespace
}  // namespace gyrotherm::drivers
