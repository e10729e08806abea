// End-to-end: the daemon's HTTP server against hostile clients (garbage,
// malformed and oversized requests, slow senders, too many connections)
// over raw sockets, while the simulated station acquires. Every bad client
// gets its exact 4xx or is closed, the API keeps answering, and not one gyro
// sample is lost.
#include <arpa/inet.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <iterator>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "station_fixture.h"
#include "test_files.h"

namespace gyrotherm {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;
using testing::StationTest;
using testing::wait_until;
using json = nlohmann::json;

constexpr double kReadTimeoutS = 2.0;
constexpr int kMaxConnections = 8;
constexpr std::size_t kMaxHeaderBytes = 4096;  // half the defaults: the keys are read
constexpr std::size_t kMaxBodyBytes = 16384;

// One blocking TCP connection to 127.0.0.1 with deadlines on every read.
class RawClient {
 public:
  explicit RawClient(int port) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(static_cast<uint16_t>(port));
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    timeval send_timeout{5, 0};
    ::setsockopt(fd_, SOL_SOCKET, SO_SNDTIMEO, &send_timeout, sizeof send_timeout);
    if (::connect(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
      ::close(fd_);
      fd_ = -1;
    }
  }
  ~RawClient() {
    if (fd_ >= 0) ::close(fd_);
  }
  RawClient(const RawClient&) = delete;
  RawClient& operator=(const RawClient&) = delete;

  bool connected() const { return fd_ >= 0; }
  bool closed() const { return closed_; }

  // False when the peer is gone (EPIPE, ECONNRESET) or the send timed out.
  bool send(std::string_view data) {
    while (!data.empty()) {
      const ssize_t n = ::send(fd_, data.data(), data.size(), MSG_NOSIGNAL);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) return false;
      data.remove_prefix(static_cast<std::size_t>(n));
    }
    return true;
  }

  // Waits up to `timeout` for bytes; appends them to received(). Returns
  // false once the peer has closed (EOF or reset) or the time is up.
  bool read_some(milliseconds timeout) {
    if (closed_) return false;
    pollfd p{fd_, POLLIN, 0};
    const int r = ::poll(&p, 1, static_cast<int>(timeout.count()));
    if (r <= 0) return false;
    char buf[16384];
    const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
    if (n <= 0) {  // 0: FIN; < 0: ECONNRESET after a close with unread data
      closed_ = true;
      closed_at_ = Clock::now();
      return false;
    }
    received_.append(buf, static_cast<std::size_t>(n));
    return true;
  }

  // Reads until the peer closes; true if it did within `timeout`.
  bool wait_closed(milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    while (!closed_) {
      const auto left = std::chrono::duration_cast<milliseconds>(deadline - Clock::now());
      if (left.count() <= 0) return false;
      read_some(left);
    }
    return true;
  }

  // Reads one response with a Content-Length body (keep-alive); its status
  // code, 0 if the peer closed or `timeout` passed first.
  int read_response(milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      const auto end = received_.find("\r\n\r\n");
      if (end != std::string::npos) {
        std::size_t length = 0;
        const std::string head = lower(received_.substr(0, end));
        if (const auto cl = head.find("\r\ncontent-length:"); cl != std::string::npos) {
          length = std::stoul(head.substr(cl + 17));
        }
        if (received_.size() >= end + 4 + length) {
          const int status = status_code(received_);
          received_.erase(0, end + 4 + length);
          return status;
        }
      }
      const auto left = std::chrono::duration_cast<milliseconds>(deadline - Clock::now());
      if (left.count() <= 0 || !read_some(left)) return 0;
    }
  }

  const std::string& received() const { return received_; }
  std::string head() const { return received_.substr(0, received_.find("\r\n")); }
  Clock::time_point closed_at() const { return closed_at_; }

  // "HTTP/1.1 431 ..." -> 431; 0 when `text` is no status line.
  static int status_code(const std::string& text) {
    int code = 0;
    if (std::sscanf(text.c_str(), "HTTP/1.%*1d %3d", &code) != 1) return 0;
    return code;
  }

 private:
  static std::string lower(std::string s) {
    for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
  }

  int fd_ = -1;
  std::string received_;
  bool closed_ = false;
  Clock::time_point closed_at_{};
};

std::string get_status_request(bool keep_alive) {
  return fmt::format("GET /api/v1/status HTTP/1.1\r\nHost: 127.0.0.1\r\n{}\r\n",
                     keep_alive ? "" : "Connection: close\r\n");
}

class HttpHardeningTest : public StationTest {
 protected:
  void SetUp() override {
    StationTest::SetUp();
    if (HasFatalFailure()) return;
    // The fixture's config with tight server limits (read back and edited
    // here so the other station tests keep theirs).
    std::string config = testing::read_text(dir_ / "station.toml");
    const auto api = config.find("[api]\n");
    ASSERT_NE(api, std::string::npos);
    config.insert(api + 6,
                  fmt::format("read_timeout_s = {}\nmax_connections = {}\n"
                              "max_header_bytes = {}\nmax_body_bytes = {}\n",
                              kReadTimeoutS, kMaxConnections, kMaxHeaderBytes, kMaxBodyBytes));
    write(dir_ / "station.toml", config);
    // One long soak: acquiring for the whole test.
    write(dir_ / "schedule.toml", R"(name = "hardening"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
acquire_min = 600
)");
  }

  // The station acquiring and the gyro stream flowing.
  void start_acquiring() {
    start_sim();
    start_daemon();
    std::optional<json> s;
    ASSERT_TRUE(wait_until(
        [&] {
          s = status();
          return s && s->value("state", "") == "acquiring" &&
                 (*s)["storage"]["gyro_rows"].get<int64_t>() > 0;
        },
        std::chrono::seconds(30)))
        << daemon_->log();
    samples_ = (*s)["devices"]["gyro"]["samples"].get<int64_t>();
    rows_ = (*s)["storage"]["gyro_rows"].get<int64_t>();
    queue_length_ = (*s)["queue_length"].get<int64_t>();
  }

  // After each hostile client: the API answers, gyro samples keep coming and
  // are stored, and none was lost on the way.
  void expect_station_healthy(const std::string& after) {
    SCOPED_TRACE("after " + after);
    std::optional<json> s;
    ASSERT_TRUE(wait_until(
        [&] {
          s = status();
          return s && (*s)["devices"]["gyro"]["samples"].get<int64_t>() > samples_ &&
                 (*s)["storage"]["gyro_rows"].get<int64_t>() > rows_;
        },
        std::chrono::seconds(5)))
        << "status: " << (s ? s->dump() : "no answer") << "\n"
        << daemon_->log();
    const json& gyro = (*s)["devices"]["gyro"];
    EXPECT_EQ((*s)["state"], "acquiring");
    EXPECT_EQ(gyro["sequence_gaps"], 0) << gyro.dump();
    EXPECT_EQ(gyro["frames_missed"], 0) << gyro.dump();
    EXPECT_EQ(gyro["crc_failures"], 0) << gyro.dump();
    EXPECT_EQ((*s)["storage"]["dropped"], 0) << (*s)["storage"].dump();
    EXPECT_EQ((*s)["storage"]["commit_failures"], 0) << (*s)["storage"].dump();
    EXPECT_EQ((*s)["queue_length"], queue_length_) << "a refused request changed the queue";
    samples_ = gyro["samples"].get<int64_t>();
    rows_ = (*s)["storage"]["gyro_rows"].get<int64_t>();
  }

  // Sends `request` on a fresh connection; the status code of the answer,
  // which must be followed by the server closing the connection.
  int answer_then_close(const std::string& request) {
    RawClient c(api_port_);
    EXPECT_TRUE(c.connected());
    c.send(request);  // may fail half-way once the server has answered
    EXPECT_TRUE(c.wait_closed(milliseconds(3000)))
        << "the server kept the connection open after: " << c.head();
    return RawClient::status_code(c.received());
  }

  int64_t samples_ = 0;
  int64_t rows_ = 0;
  int64_t queue_length_ = 0;
};

TEST_F(HttpHardeningTest, MalformedAndOversizedRequestsGetTheir4xxAndAcquisitionGoesOn) {
  ASSERT_NO_FATAL_FAILURE(start_acquiring());

  // Garbage: a TLS ClientHello-like prefix and binary bytes.
  std::string garbage("\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03\xff\xfe\x00\x7f", 15);
  EXPECT_EQ(answer_then_close(garbage + "\r\n\r\n"), 400);
  expect_station_healthy("garbage bytes");
  EXPECT_EQ(answer_then_close("\r\n\r\n\r\n\r\n"), 400);
  expect_station_healthy("blank lines");

  // Bad request lines: a method that is no token, versions that are not
  // HTTP/d.d, no target.
  EXPECT_EQ(answer_then_close("G@T /api/v1/status HTTP/1.1\r\nHost: x\r\n\r\n"), 400);
  EXPECT_EQ(answer_then_close("GET /api/v1/status HTTP/x.1\r\nHost: x\r\n\r\n"), 400);
  EXPECT_EQ(answer_then_close("GET /api/v1/status HTTP/1.10\r\nHost: x\r\n\r\n"), 400);
  EXPECT_EQ(answer_then_close("GET /api/v1/status SPDY/3\r\nHost: x\r\n\r\n"), 400);
  EXPECT_EQ(answer_then_close("GET HTTP/1.1\r\nHost: x\r\n\r\n"), 400);
  EXPECT_EQ(answer_then_close("GET /api/v1/status HTTP/1.1\r\nno colon here\r\n\r\n"), 400);
  expect_station_healthy("bad request lines");
  {
    // A well-formed but unknown method on a known path: the router's 405.
    RawClient c(api_port_);
    ASSERT_TRUE(c.send("BREW /api/v1/status HTTP/1.1\r\nHost: x\r\n\r\n"));
    EXPECT_EQ(c.read_response(milliseconds(3000)), 405) << c.head();
  }
  expect_station_healthy("unknown method");

  // Headers over max_header_bytes: one long field, many small ones, a long
  // target.
  EXPECT_EQ(answer_then_close(fmt::format("GET /api/v1/status HTTP/1.1\r\nHost: x\r\nX-Fill: "
                                          "{}\r\n\r\n",
                                          std::string(kMaxHeaderBytes + 1000, 'a'))),
            431);
  // Many small fields: Beast 1.74 applies its limit per read, so the server
  // also checks the whole header's size; just over the limit is a 431 too.
  const auto many_fields = [](std::size_t total) {
    std::string r = "GET /api/v1/status HTTP/1.1\r\nHost: x\r\nConnection: close\r\n";
    for (int i = 0; r.size() + 12 < total; ++i) r += fmt::format("X-F{:05}: v\r\n", i);
    return r + "\r\n";
  };
  EXPECT_EQ(answer_then_close(many_fields(2 * kMaxHeaderBytes)), 431);
  EXPECT_EQ(answer_then_close(many_fields(kMaxHeaderBytes + 100)), 431) << "just over the limit";
  EXPECT_EQ(answer_then_close(many_fields(kMaxHeaderBytes - 200)), 200) << "within the limit";
  EXPECT_EQ(answer_then_close(fmt::format("GET /api/v1/{} HTTP/1.1\r\nHost: x\r\n\r\n",
                                          std::string(kMaxHeaderBytes + 1000, 'x'))),
            431);
  expect_station_healthy("oversized headers");

  // A body over max_body_bytes: refused on its Content-Length before it is
  // read, and as a chunked body once it passes the limit.
  const std::string auth = fmt::format("Authorization: Bearer {}\r\n", kToken);
  EXPECT_EQ(answer_then_close(fmt::format("POST /api/v1/queue HTTP/1.1\r\nHost: x\r\n{}"
                                          "Content-Type: application/json\r\n"
                                          "Content-Length: {}\r\n\r\n{{\"schedule_toml\":",
                                          auth, kMaxBodyBytes + 1)),
            413);
  std::string chunked = fmt::format(
      "POST /api/v1/queue HTTP/1.1\r\nHost: x\r\n{}Content-Type: application/json\r\n"
      "Transfer-Encoding: chunked\r\n\r\n",
      auth);
  for (std::size_t sent = 0; sent <= kMaxBodyBytes; sent += 4096)
    chunked += "1000\r\n" + std::string(4096, ' ') + "\r\n";
  chunked += "0\r\n\r\n";
  EXPECT_EQ(answer_then_close(chunked), 413);
  expect_station_healthy("oversized bodies");

  // Content-Length that is no length, or two that disagree, or beside chunked.
  for (const char* length : {"abc", "-1", "12x", "99999999999999999999999", "5, 6"}) {
    SCOPED_TRACE(fmt::format("Content-Length: {}", length));
    EXPECT_EQ(answer_then_close(fmt::format("POST /api/v1/queue HTTP/1.1\r\nHost: x\r\n{}"
                                            "Content-Length: {}\r\n\r\n{{}}",
                                            auth, length)),
              400);
  }
  EXPECT_EQ(answer_then_close(fmt::format("POST /api/v1/queue HTTP/1.1\r\nHost: x\r\n{}"
                                          "Content-Length: 2\r\nContent-Length: 3\r\n\r\n{{}}",
                                          auth)),
            400);
  EXPECT_EQ(answer_then_close(fmt::format("POST /api/v1/queue HTTP/1.1\r\nHost: x\r\n{}"
                                          "Content-Length: 5\r\nTransfer-Encoding: chunked\r\n"
                                          "\r\n0\r\n\r\n",
                                          auth)),
            400);
  expect_station_healthy("invalid Content-Length");

  // Good requests still work, two on one kept-alive connection.
  RawClient c(api_port_);
  ASSERT_TRUE(c.send(get_status_request(true)));
  EXPECT_EQ(c.read_response(milliseconds(3000)), 200);
  ASSERT_TRUE(c.send(get_status_request(true)));
  EXPECT_EQ(c.read_response(milliseconds(3000)), 200);
  expect_station_healthy("keep-alive requests");
}

TEST_F(HttpHardeningTest, SlowClientsAreCutOffAfterTheReadTimeout) {
  ASSERT_NO_FATAL_FAILURE(start_acquiring());
  const auto timeout = milliseconds(static_cast<int>(kReadTimeoutS * 1000));
  // Closed after read_timeout_s (not long before: it is the timeout that
  // does it), with a margin for a loaded machine.
  const auto expect_cut_off_in_time = [&](RawClient& c, Clock::time_point start) {
    ASSERT_TRUE(c.wait_closed(timeout * 3)) << "still open after 3 × read_timeout_s";
    const auto took = std::chrono::duration_cast<milliseconds>(c.closed_at() - start);
    EXPECT_GE(took.count(), timeout.count() * 3 / 4);
    EXPECT_LE(took.count(), timeout.count() * 2);
  };

  // The three run side by side, so the test waits one timeout, not three.
  // Headers that never end (slowloris: a few bytes, then nothing).
  RawClient stalled(api_port_);
  const auto stalled_start = Clock::now();
  ASSERT_TRUE(stalled.send("GET /api/v1/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: "));
  // Headers trickling in one byte every 300 ms: the timeout covers the whole
  // request, not each read.
  RawClient trickle(api_port_);
  const auto trickle_start = Clock::now();
  // A body that stops half-way.
  RawClient half_body(api_port_);
  const auto half_body_start = Clock::now();
  ASSERT_TRUE(half_body.send(
      fmt::format("POST /api/v1/queue HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {}\r\n"
                  "Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{{\"schedule",
                  kToken)));

  const std::string slow = "GET /api/v1/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: abcdefghij";
  for (std::size_t i = 0; i < slow.size() && !trickle.closed(); ++i) {
    if (!trickle.send(slow.substr(i, 1))) break;
    // The 300 ms between bytes: waiting for the server to answer or close.
    if (trickle.read_some(milliseconds(300))) break;
  }
  expect_cut_off_in_time(trickle, trickle_start);
  EXPECT_TRUE(trickle.received().empty()) << "answered an unfinished request: " << trickle.head();
  expect_cut_off_in_time(stalled, stalled_start);
  EXPECT_TRUE(stalled.received().empty()) << stalled.head();
  expect_cut_off_in_time(half_body, half_body_start);
  EXPECT_TRUE(half_body.received().empty()) << half_body.head();
  expect_station_healthy("slow clients");

  // An idle keep-alive connection is closed after the same time.
  RawClient idle(api_port_);
  ASSERT_TRUE(idle.send(get_status_request(true)));
  EXPECT_EQ(idle.read_response(milliseconds(3000)), 200);
  const auto idle_start = Clock::now();
  expect_cut_off_in_time(idle, idle_start);
  expect_station_healthy("an idle keep-alive connection");
}

TEST_F(HttpHardeningTest, ConnectionsBeyondMaxConnectionsAreClosedAndServiceReturns) {
  ASSERT_NO_FATAL_FAILURE(start_acquiring());

  // max_connections hogs, each shown to hold its slot by one answered
  // request on a kept-alive connection.
  const auto open_hogs = [&] {
    // The server releases the slots of connections that just closed when
    // their sessions see the close; on a loaded machine that can lag, so a
    // hog that finds no slot yet tries again, within a deadline.
    std::vector<std::unique_ptr<RawClient>> hogs;
    for (int i = 0; i < kMaxConnections; ++i) {
      const auto deadline = Clock::now() + std::chrono::seconds(10);
      int answer = 0;
      std::unique_ptr<RawClient> c;
      while (answer != 200 && Clock::now() < deadline) {
        c = std::make_unique<RawClient>(api_port_);
        if (!c->connected() || !c->send(get_status_request(true))) continue;
        answer = c->read_response(milliseconds(3000));
      }
      EXPECT_EQ(answer, 200) << "hog " << i;
      hogs.push_back(std::move(c));
    }
    return hogs;
  };
  // A client over the limit: closed at once, no answer.
  const auto expect_refused = [&](const std::string& what) {
    SCOPED_TRACE(what);
    RawClient extra(api_port_);
    ASSERT_TRUE(extra.connected());  // the kernel accepts; the server closes
    extra.send(get_status_request(true));
    EXPECT_TRUE(extra.wait_closed(milliseconds(3000)));
    EXPECT_TRUE(extra.received().empty()) << "served over the limit: " << extra.head();
  };

  // Round 1: the hogs leave by closing.
  {
    auto hogs = open_hogs();
    for (int i = 0; i < 3; ++i) expect_refused(fmt::format("extra client {}", i));
    EXPECT_FALSE(status().has_value()) << "a status request over the limit was served";
    // The hogs are still served meanwhile.
    ASSERT_TRUE(hogs[0]->send(get_status_request(true)));
    EXPECT_EQ(hogs[0]->read_response(milliseconds(3000)), 200);
  }
  expect_station_healthy("hogs closed");

  // Round 2: the hogs stay silent until the server times them out.
  {
    auto hogs = open_hogs();
    expect_refused("extra client while hogs idle");
    for (auto& h : hogs) EXPECT_TRUE(h->wait_closed(milliseconds(3 * 2000)));
    expect_station_healthy("hogs timed out");
  }

  // And the full count can connect again.
  auto hogs = open_hogs();
  hogs.clear();
  expect_station_healthy("a second set of clients");
}

}  // namespace
}  // namespace gyrotherm
