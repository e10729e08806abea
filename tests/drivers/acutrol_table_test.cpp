// AcutrolTable against a small fake controller on loopback TCP, written
// here (unit level: it answers canned frames, drops the connection,
// answers with an error code, stalls). The real simulator peer is tested
// with the simulator.
#include "gyrotherm/drivers/acutrol_table.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/rate_tables.h"
#include "test_time.h"

namespace gyrotherm::drivers {
namespace {

using namespace std::chrono_literals;

std::string ascii_frame(unsigned code, const std::string& payload) {
  char head[16];
  std::snprintf(head, sizeof head, "%04u%04zu", code, payload.size());
  return head + payload;
}

// What the fake does with one command line.
struct Response {
  enum Kind { kReply, kDrop, kStall } kind = kReply;
  std::string bytes;
};
Response reply(const std::string& payload, unsigned code = 0) {
  return {Response::kReply, ascii_frame(code, payload)};
}

// A controller on 127.0.0.1, port chosen by the system. `handler` answers
// each command line (without "\r\n"); it runs on the server's thread.
class FakeController {
 public:
  using Handler = std::function<Response(const std::string&)>;
  explicit FakeController(Handler handler) : handler_(std::move(handler)) {
    listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = 0;
    if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
        ::listen(listen_fd_, 4) != 0) {
      ADD_FAILURE() << "cannot listen on loopback";
    }
    socklen_t len = sizeof a;
    ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
    thread_ = std::thread([this] { run(); });
  }
  ~FakeController() {
    stop_ = true;
    thread_.join();
    if (client_fd_ >= 0) ::close(client_fd_);
    ::close(listen_fd_);
  }
  int port() const { return port_; }
  int accepts() const { return accepts_.load(); }
  std::vector<std::string> commands() const {
    std::lock_guard lock(mu_);
    return commands_;
  }
  // Commands after the connections' first contact (`*IDN?`).
  std::vector<std::string> commands_after_handshake() const {
    std::vector<std::string> out;
    for (const auto& c : commands())
      if (c != "*IDN?") out.push_back(c);
    return out;
  }

 private:
  void run() {
    std::string buf;
    while (!stop_) {
      pollfd fds[2] = {{listen_fd_, POLLIN, 0}, {client_fd_, POLLIN, 0}};
      if (::poll(fds, client_fd_ >= 0 ? 2 : 1, 10) <= 0) continue;
      if (fds[0].revents & POLLIN) {
        const int fd = ::accept(listen_fd_, nullptr, nullptr);
        if (fd >= 0) {
          if (client_fd_ >= 0) ::close(client_fd_);
          client_fd_ = fd;
          buf.clear();
          ++accepts_;
        }
        continue;
      }
      if (client_fd_ < 0 || !(fds[1].revents & (POLLIN | POLLHUP))) continue;
      char tmp[512];
      const ssize_t n = ::recv(client_fd_, tmp, sizeof tmp, 0);
      if (n <= 0) {
        ::close(client_fd_);
        client_fd_ = -1;
        continue;
      }
      buf.append(tmp, static_cast<std::size_t>(n));
      for (auto end = buf.find("\r\n"); end != std::string::npos; end = buf.find("\r\n")) {
        const std::string command = buf.substr(0, end);
        buf.erase(0, end + 2);
        {
          std::lock_guard lock(mu_);
          commands_.push_back(command);
        }
        const Response r = handler_(command);
        if (r.kind == Response::kDrop) {
          ::close(client_fd_);
          client_fd_ = -1;
          break;
        }
        if (r.kind == Response::kReply) {
          ::send(client_fd_, r.bytes.data(), r.bytes.size(), MSG_NOSIGNAL);
        }
      }
    }
  }

  Handler handler_;
  int listen_fd_ = -1;
  int client_fd_ = -1;  // the server thread's only
  int port_ = 0;
  std::atomic<int> accepts_{0};
  std::atomic<bool> stop_{false};
  mutable std::mutex mu_;
  std::vector<std::string> commands_;
  std::thread thread_;
};

// A healthy controller: axis 1, interlock as `interlock`, limits 500 °/s,
// 1000 °/s², trip 550 °/s.
Response healthy(const std::string& c, std::string* interlock) {
  if (c == ":M? 1;:I? 1;:R:R? 1;:R:P? 1") return reply("Rate;" + *interlock + ";10.0001;123.4");
  if (c == ":L:R? R,1;:L:A? R,1;:L:V? R,1") return reply("500.0;1000.0;550.0");
  if (c == ":I? 1") return reply(*interlock);
  if (c == ":I:C 1") {
    *interlock = "Closed";
    return reply("OK");
  }
  return reply("OK");
}

TableConnection connection_to(const FakeController& fake, double timeout_s = 1.0) {
  TableConnection c;
  c.profile = "acutrol";
  c.host = "127.0.0.1";
  c.port = fake.port();
  c.timeout_s = timeout_s;
  return c;
}

TEST(AcutrolTable, ReadIsOneChainedExchangeAfterIdentifying) {
  std::string interlock = "Closed";
  FakeController fake([&](const std::string& c) { return healthy(c, &interlock); });
  AcutrolTable table(connection_to(fake), "turntable");
  ASSERT_TRUE(table.connect().ok());
  auto s = table.read();
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(s->mode, TableMode::kRate);
  EXPECT_EQ(s->interlock, TableInterlock::kClosed);
  EXPECT_DOUBLE_EQ(s->rate_dps, 10.0001);
  EXPECT_DOUBLE_EQ(s->position_deg, 123.4);
  // No remote lockout for reading (`:U:L ON` comes with the first motion).
  const std::vector<std::string> expected = {"*IDN?", ":M? 1;:I? 1;:R:R? 1;:R:P? 1"};
  EXPECT_EQ(fake.commands(), expected);
  const auto h = table.health();
  EXPECT_TRUE(h.connected);
  EXPECT_EQ(h.requests, 2u);
  EXPECT_EQ(h.errors, 0u);
  EXPECT_FALSE(h.last_success_utc.empty());
}

TEST(AcutrolTable, SetRateClosesTheInterlockFirstThenDemandsTheRate) {
  std::string interlock = "Open";
  FakeController fake([&](const std::string& c) { return healthy(c, &interlock); });
  AcutrolTable table(connection_to(fake));
  const Status st = table.set_rate(-10.5);
  ASSERT_TRUE(st.ok()) << st.error().message;
  const std::vector<std::string> expected = {":L:R? R,1;:L:A? R,1;:L:V? R,1", ":U:L ON", ":I? 1",
                                             ":I:C 1", ":D:R 1,-10.5;:M:R 1"};
  EXPECT_EQ(fake.commands_after_handshake(), expected);
  // Remote held, interlock now closed, limits cached: only the query and
  // the demand.
  ASSERT_TRUE(table.set_rate(20).ok());
  const auto all = fake.commands_after_handshake();
  ASSERT_EQ(all.size(), 7u);
  EXPECT_EQ(all[5], ":I? 1");
  EXPECT_EQ(all[6], ":D:R 1,20;:M:R 1");
}

TEST(AcutrolTable, RefusesARateBeyondTheLimitsBeforeSending) {
  std::string interlock = "Closed";
  FakeController fake([&](const std::string& c) { return healthy(c, &interlock); });
  AcutrolTable table(connection_to(fake), "turntable");
  const Status st = table.set_rate(500.5);
  ASSERT_FALSE(st.ok());
  EXPECT_FALSE(st.error().transient);
  EXPECT_NE(st.error().message.find("turntable"), std::string::npos);
  EXPECT_NE(st.error().message.find("beyond the rate limit 500"), std::string::npos);
  for (const auto& c : fake.commands()) EXPECT_EQ(c.find(":D:R"), std::string::npos) << c;
  EXPECT_TRUE(table.set_rate(-500).ok());  // at the limit
  auto limits = table.limits();
  ASSERT_TRUE(limits.ok());
  EXPECT_DOUBLE_EQ(limits->max_accel_dps2, 1000.0);
  EXPECT_DOUBLE_EQ(*limits->trip_rate_dps, 550.0);
  EXPECT_EQ(table.health().errors, 1u);
}

TEST(AcutrolTable, PositionStopServoOffResetSendTheirCommands) {
  std::string interlock = "Closed";
  FakeController fake([&](const std::string& c) { return healthy(c, &interlock); });
  AcutrolTable table(connection_to(fake));
  ASSERT_TRUE(table.set_position(90.25).ok());
  ASSERT_TRUE(table.stop().ok());
  ASSERT_TRUE(table.servo_off().ok());
  ASSERT_TRUE(table.reset_faults().ok());
  const std::vector<std::string> expected = {":U:L ON", ":I? 1",  ":D:P 1,90.25;:M:P 1",
                                             ":M:O 1",  ":I:O 1", ":I:R"};
  EXPECT_EQ(fake.commands_after_handshake(), expected);
}

TEST(AcutrolTable, AFaultedInterlockIsNotClosedBySetRate) {
  std::string interlock = "Fault";
  FakeController fake([&](const std::string& c) { return healthy(c, &interlock); });
  AcutrolTable table(connection_to(fake));
  const Status st = table.set_rate(1);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("fault"), std::string::npos);
  for (const auto& c : fake.commands()) {
    EXPECT_NE(c, ":I:C 1");
    EXPECT_EQ(c.find(":D:R"), std::string::npos);
  }
}

TEST(AcutrolTable, AnErrorCodeNamesTheCommandAndAsksForItsText) {
  std::string interlock = "Closed";
  FakeController fake([&](const std::string& c) {
    if (c.rfind(":D:P", 0) == 0) return reply("", 12);
    if (c == ":Q:E? 12") return reply("Parameter out of range");
    return healthy(c, &interlock);
  });
  AcutrolTable table(connection_to(fake), "turntable");
  const Status st = table.set_position(400);
  ASSERT_FALSE(st.ok());
  const std::string& m = st.error().message;
  EXPECT_NE(m.find("turntable"), std::string::npos) << m;
  EXPECT_NE(m.find(":D:P 1,400;:M:P 1"), std::string::npos) << m;
  EXPECT_NE(m.find("error code 12"), std::string::npos) << m;
  EXPECT_NE(m.find("Parameter out of range"), std::string::npos) << m;
  EXPECT_FALSE(st.error().transient);
  // The link stays up: the next call uses the same connection.
  ASSERT_TRUE(table.read().ok());
  EXPECT_EQ(fake.accepts(), 1);
  EXPECT_EQ(table.health().last_error, m);
}

TEST(AcutrolTable, ReconnectsAfterADropNoSoonerThanTheDoublingBackoff) {
  std::string interlock = "Closed";
  std::atomic<bool> drop_reads{true};
  FakeController fake([&](const std::string& c) {
    if (drop_reads && c.rfind(":M?", 0) == 0) return Response{Response::kDrop, ""};
    return healthy(c, &interlock);
  });
  ManualWallClock clock(1000.0);
  AcutrolTable table(connection_to(fake), "turntable", clock);
  auto r = table.read();  // connects, handshake, query dropped
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.error().transient);
  EXPECT_NE(r.error().message.find("closed by the controller"), std::string::npos)
      << r.error().message;
  EXPECT_EQ(fake.accepts(), 1);

  clock.advance(0.4);  // backoff 0.5 s not over: no attempt
  r = table.read();
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.error().transient);
  EXPECT_NE(r.error().message.find("next attempt in"), std::string::npos) << r.error().message;
  EXPECT_EQ(fake.accepts(), 1);

  clock.advance(0.2);  // 0.6 s: reconnects, is dropped again; backoff now 1 s
  EXPECT_FALSE(table.read().ok());
  ASSERT_TRUE(testing::wait_for_condition([&] { return fake.accepts() == 2; }, 2000ms));
  clock.advance(0.9);
  EXPECT_FALSE(table.read().ok());
  EXPECT_EQ(fake.accepts(), 2);

  drop_reads = false;
  clock.advance(0.2);  // 1.1 s
  r = table.read();
  ASSERT_TRUE(r.ok()) << r.error().message;
  ASSERT_TRUE(testing::wait_for_condition([&] { return fake.accepts() == 3; }, 2000ms));
  const auto h = table.health();
  EXPECT_TRUE(h.connected);
  EXPECT_EQ(h.reconnects, 2u);
  EXPECT_EQ(h.errors, 2u);  // the two drops; waiting out a backoff is not counted
  EXPECT_NE(h.last_error.find("turntable"), std::string::npos);
}

TEST(AcutrolTable, AStallPastTheTimeoutDropsTheConnection) {
  std::string interlock = "Closed";
  FakeController fake([&](const std::string& c) {
    if (c.rfind(":M?", 0) == 0) return Response{Response::kStall, ""};
    return healthy(c, &interlock);
  });
  AcutrolTable table(connection_to(fake, 0.2), "turntable");
  ASSERT_TRUE(table.connect().ok());
  const auto t0 = std::chrono::steady_clock::now();
  auto r = table.read();
  const double waited_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.error().transient);
  EXPECT_NE(r.error().message.find("no reply within 0.2 s"), std::string::npos)
      << r.error().message;
  EXPECT_GE(waited_s, 0.19);
  EXPECT_LT(waited_s, 0.2 + testing::time_factor() * 1.0);
  EXPECT_FALSE(table.health().connected);
}

TEST(AcutrolTable, GarbageAndOversizeRepliesResynchronise) {
  std::string interlock = "Closed";
  std::atomic<int> reads{0};
  FakeController fake([&](const std::string& c) {
    if (c.rfind(":M?", 0) == 0) {
      const int n = reads++;
      if (n == 0) return Response{Response::kReply, "garbage!\r\n"};
      if (n == 1) return Response{Response::kReply, "00009999" + std::string(64, 'x')};
      if (n == 2) return reply("Rate;Ajar;1;2");  // framed, content wrong
    }
    return healthy(c, &interlock);
  });
  ManualWallClock clock(0);
  AcutrolTable table(connection_to(fake), "turntable", clock);
  for (const char* expected : {"malformed", "payload length 9999", "Ajar"}) {
    auto r = table.read();
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find(expected), std::string::npos) << r.error().message;
    EXPECT_TRUE(r.error().transient);
    clock.advance(20);  // past any backoff
  }
  auto r = table.read();
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(fake.accepts(), 4);  // every bad reply cost the connection
}

TEST(AcutrolTable, BinaryFramingEndToEnd) {
  FakeController fake([&](const std::string& c) {
    std::string payload = c.rfind(":M?", 0) == 0 ? "Position;Open;0;359.5" : "OK";
    std::string out;
    for (uint32_t v : {0u, static_cast<uint32_t>(payload.size())})
      for (int i = 3; i >= 0; --i) out += static_cast<char>((v >> (8 * i)) & 0xff);
    return Response{Response::kReply, out + payload};
  });
  auto conn = connection_to(fake);
  conn.reply_header = "binary-be";
  AcutrolTable table(conn);
  auto s = table.read();
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(s->mode, TableMode::kPosition);
  EXPECT_EQ(s->interlock, TableInterlock::kOpen);
  EXPECT_DOUBLE_EQ(s->position_deg, 359.5);
}

TEST(AcutrolTable, UnreachableAndMisconfigured) {
  int port = 0;
  {
    FakeController gone([](const std::string&) { return reply("OK"); });
    port = gone.port();
  }  // closed: nothing listens there now
  TableConnection c;
  c.host = "127.0.0.1";
  c.port = port;
  AcutrolTable table(c, "turntable");
  const Status st = table.connect();
  ASSERT_FALSE(st.ok());
  EXPECT_TRUE(st.error().transient);
  EXPECT_NE(st.error().message.find(fmt::format("127.0.0.1:{}", port)), std::string::npos)
      << st.error().message;

  c.reply_header = "hex";
  AcutrolTable bad(c, "turntable");
  const Status b = bad.connect();
  ASSERT_FALSE(b.ok());
  EXPECT_FALSE(b.error().transient);
  EXPECT_NE(b.error().message.find("hex"), std::string::npos);
}

TEST(RateTables, FactoryChoosesByProfile) {
  TableConnection c;
  TableLimits declared{300, 100, std::nullopt};
  auto acutrol = make_rate_table(c, declared, "t1");
  ASSERT_TRUE(acutrol.ok());
  EXPECT_NE(dynamic_cast<AcutrolTable*>(acutrol->get()), nullptr);
  EXPECT_EQ((*acutrol)->name(), "t1");
  c.profile = "aero";
  auto aero = make_rate_table(c, declared);
  ASSERT_TRUE(aero.ok());
  auto limits = (*aero)->limits();
  ASSERT_TRUE(limits.ok());
  EXPECT_DOUBLE_EQ(limits->max_rate_dps, 300);
  c.profile = "contraves";
  auto bad = make_rate_table(c, declared);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("contraves"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm::drivers
