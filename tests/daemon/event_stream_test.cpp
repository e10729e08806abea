// The Server-Sent Events fan-out: unit tests of EventStream, then the real
// HTTP server on loopback with raw sockets (several readers, a stalled
// reader that must be dropped without holding up the publisher or the
// others).
#include <arpa/inet.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "gyrotherm/api/http_message.h"
#include "gyrotherm/api/http_server.h"
#include "test_time.h"

namespace gyrotherm::api {
namespace {

using namespace std::chrono_literals;
using Steady = std::chrono::steady_clock;

std::string drain(StreamClient& c) {
  std::lock_guard lock(c.mu);
  std::string out;
  for (const auto& m : c.queue) out += *m;
  c.queue.clear();
  c.queued_bytes = 0;
  c.writing = false;
  return out;
}

TEST(EventStream, SubscriberGetsRetryStatusThenPublishedMessagesInOrder) {
  EventStream stream({.queue_bytes = 1 << 20, .max_clients = 4, .tick = 1000ms, .status_json = [] {
                        return std::string(R"({"state":"idle"})");
                      }});
  int wakes = 0;
  auto client = stream.subscribe([&] { ++wakes; });
  ASSERT_TRUE(client);
  EXPECT_EQ(stream.clients(), 1);
  EXPECT_EQ(drain(*client), "retry: 3000\n\nid: 1\nevent: status\ndata: {\"state\":\"idle\"}\n\n");
  stream.publish("event", R"({"message":"a"})");
  stream.publish("state", R"({"to":"acquiring"})");
  EXPECT_EQ(wakes, 1) << "one wake per idle period, not per message";
  EXPECT_EQ(drain(*client),
            "id: 2\nevent: event\ndata: {\"message\":\"a\"}\n\n"
            "id: 3\nevent: state\ndata: {\"to\":\"acquiring\"}\n\n");
  stream.tick();
  EXPECT_NE(drain(*client).find("event: status"), std::string::npos);
}

TEST(EventStream, ClientTooFarBehindIsDroppedAndTheOthersGoOn) {
  EventStream stream({.queue_bytes = 4096, .max_clients = 4, .tick = 1000ms, .status_json = {}});
  auto slow = stream.subscribe([] {});
  auto fast = stream.subscribe([] {});
  drain(*fast);
  const std::string data(100, 'x');
  std::string received;
  for (int i = 0; i < 100; ++i) {
    stream.publish("event", data);
    received += drain(*fast);
  }
  EXPECT_EQ(stream.dropped(), 1u);
  EXPECT_EQ(stream.clients(), 1);
  {
    std::lock_guard lock(slow->mu);
    EXPECT_TRUE(slow->closed);
    EXPECT_TRUE(slow->queue.empty());
  }
  std::size_t count = 0;
  for (std::size_t p = 0; (p = received.find("event: event", p)) != std::string::npos; ++p) ++count;
  EXPECT_EQ(count, 100u);
}

TEST(EventStream, MaxClientsIsEnforcedAndFreedSlotsAreReused) {
  EventStream stream({.queue_bytes = 4096, .max_clients = 2, .tick = 1000ms, .status_json = {}});
  auto a = stream.subscribe([] {});
  auto b = stream.subscribe([] {});
  EXPECT_TRUE(a && b);
  EXPECT_FALSE(stream.subscribe([] {}));
  a.reset();  // the session went away
  EXPECT_TRUE(stream.subscribe([] {}));
}

TEST(EventStream, PublishFromManyThreadsDeliversEveryMessageOnce) {
  EventStream stream(
      {.queue_bytes = 64 << 20, .max_clients = 4, .tick = 1000ms, .status_json = {}});
  auto client = stream.subscribe([] {});
  drain(*client);
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < 1000; ++i) stream.publish("event", fmt::format("{}-{}", t, i));
    });
  }
  for (auto& t : threads) t.join();
  const std::string all = drain(*client);
  std::size_t count = 0;
  for (std::size_t p = 0; (p = all.find("event: event", p)) != std::string::npos; ++p) ++count;
  EXPECT_EQ(count, 4000u);
}

// --- over real HTTP ---------------------------------------------------------

int connect_to(int port, int rcvbuf_bytes = 0) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (rcvbuf_bytes > 0) setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf_bytes, sizeof rcvbuf_bytes);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    ::close(fd);
    return -1;
  }
  const std::string req = "GET /api/v1/stream HTTP/1.1\r\nHost: x\r\n\r\n";
  if (::send(fd, req.data(), req.size(), MSG_NOSIGNAL) != static_cast<ssize_t>(req.size())) {
    ::close(fd);
    return -1;
  }
  return fd;
}

// Reads until `done(text)` or `timeout` (stretched by
// GYROTHERM_TEST_TIME_FACTOR) passes; returns what was read. Sets
// `closed` when the server closed the connection.
template <class Done>
std::string read_until(int fd, Done done, std::chrono::milliseconds timeout,
                       bool* closed = nullptr) {
  std::string text;
  const auto deadline = Steady::now() + testing::scaled(timeout);
  char buf[65536];
  while (!done(text) && Steady::now() < deadline) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 50) <= 0) continue;
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n <= 0) {
      if (closed) *closed = true;
      break;
    }
    text.append(buf, static_cast<std::size_t>(n));
  }
  return text;
}

std::size_t count_of(const std::string& text, const std::string& what) {
  std::size_t n = 0;
  for (std::size_t p = 0; (p = text.find(what, p)) != std::string::npos; p += what.size()) ++n;
  return n;
}

TEST(EventStreamHttp, ClientsReceiveTicksAndEventsAStalledClientIsDropped) {
  EventStream stream({.queue_bytes = 4 << 20, .max_clients = 8, .tick = 100ms, .status_json = [] {
                        return std::string(R"({"state":"acquiring"})");
                      }});
  HttpServerOptions options;
  options.port = 0;
  options.stream = &stream;
  options.write_timeout = 60s;  // the drop must come from the queue bound, not a timeout
  auto server = HttpServer::create(options, [](const HttpRequest& req) {
    return error_response(req, boost::beast::http::status::not_found, "no");
  });
  ASSERT_TRUE(server.ok()) << server.error().message;
  (*server)->start();
  const int port = (*server)->port();

  std::vector<int> readers;
  for (int i = 0; i < 3; ++i) readers.push_back(connect_to(port));
  const int stalled = connect_to(port, 1024);
  for (int fd : readers) ASSERT_GE(fd, 0);
  ASSERT_GE(stalled, 0);

  // Headers, the retry line and two status ticks reach every reader.
  for (int fd : readers) {
    const std::string head = read_until(
        fd, [](const std::string& t) { return count_of(t, "event: status") >= 2; }, 5s);
    EXPECT_NE(head.find("HTTP/1.1 200 OK"), std::string::npos) << head;
    EXPECT_NE(head.find("Content-Type: text/event-stream"), std::string::npos) << head;
    EXPECT_NE(head.find("retry: 3000"), std::string::npos);
    EXPECT_GE(count_of(head, "event: status"), 2u);
  }
  const auto deadline = Steady::now() + testing::scaled(5s);
  while (stream.clients() < 4 && Steady::now() < deadline) std::this_thread::sleep_for(10ms);
  ASSERT_EQ(stream.clients(), 4);

  // 32 MB of events: far more than the stalled client's socket buffers and
  // queue hold. The readers keep reading as it is published.
  const std::string payload(4 * 1024, 'p');
  constexpr int kEvents = 8192;
  std::vector<std::string> got(readers.size());
  // Bytes each reader has received so far.
  auto received = std::make_unique<std::atomic<std::size_t>[]>(readers.size());
  std::vector<std::thread> reading;
  for (std::size_t i = 0; i < readers.size(); ++i) {
    reading.emplace_back([&, i] {
      // Only the text new since the last look is searched: 32 MB searched
      // whole at every read kept a reader on a loaded machine so busy it
      // fell a queue behind and was dropped.
      std::size_t searched = 0;
      got[i] = read_until(
          readers[i],
          [&, i, searched](const std::string& t) mutable {
            received[i].store(t.size());
            const std::size_t from = searched > 16 ? searched - 16 : 0;
            searched = t.size();
            return t.find("event: last", from) != std::string::npos;
          },
          30s);
    });
  }
  // A reader that reads is never a queue's worth behind: after each burst
  // of 64 KB the publisher waits, a bounded time, until every reader has
  // taken all but 1 MB of what was published (a loaded machine may
  // deschedule a reader for a while; the stalled client never reads).
  const auto readers_keep_up = [&](std::size_t published) {
    const auto until = Steady::now() + testing::scaled(10s);
    for (;;) {
      bool all = true;
      for (std::size_t r = 0; r < readers.size(); ++r) {
        all = all && received[r].load() + (1u << 20) >= published;
      }
      if (all || Steady::now() >= until) return;
      std::this_thread::sleep_for(1ms);
    }
  };
  const auto t0 = Steady::now();
  double slowest_publish_ms = 0;
  for (int i = 0; i < kEvents; ++i) {
    const auto p0 = Steady::now();
    stream.publish("bulk", payload);
    slowest_publish_ms = std::max(
        slowest_publish_ms, std::chrono::duration<double, std::milli>(Steady::now() - p0).count());
    if (i % 16 == 15) readers_keep_up(static_cast<std::size_t>(i + 1) * payload.size());
  }
  stream.publish("last", "{}");
  for (auto& t : reading) t.join();
  const double total_ms = std::chrono::duration<double, std::milli>(Steady::now() - t0).count();

  EXPECT_EQ(stream.dropped(), 1u) << "the stalled client is dropped";
  // Waiting on the stalled client would block a publish until the 60 s write
  // timeout; a few seconds tell that apart from a loaded machine's
  // scheduling delays (throughput is measured in bench/, not here).
  EXPECT_LT(slowest_publish_ms, static_cast<double>(testing::scaled(5s).count()))
      << "publish never waits on a client";
  EXPECT_LT(total_ms, static_cast<double>(testing::scaled(30s).count()));
  for (std::size_t i = 0; i < readers.size(); ++i) {
    EXPECT_EQ(count_of(got[i], "event: bulk"), static_cast<std::size_t>(kEvents)) << "reader " << i;
    EXPECT_NE(got[i].find("event: last"), std::string::npos);
  }
  // The stalled client finds its connection closed once it reads again.
  bool closed = false;
  read_until(
      stalled, [](const std::string&) { return false; }, 10s, &closed);
  EXPECT_TRUE(closed);

  for (int fd : readers) ::close(fd);
  ::close(stalled);
  (*server)->stop();
}

TEST(EventStreamOptions, Validity) {
  std::string why;
  EXPECT_TRUE(EventStreamOptions{}.is_valid(&why)) << why;
  EventStreamOptions o;
  o.max_clients = 0;
  EXPECT_TRUE(o.is_valid(&why)) << "0: no streams; " << why;
  o = {};
  o.queue_bytes = 0;
  EXPECT_FALSE(o.is_valid(&why));
  EXPECT_NE(why.find("queue_bytes = 0 must be >= 1"), std::string::npos) << why;
  o = {};
  o.max_clients = -1;
  EXPECT_FALSE(o.is_valid(&why));
  EXPECT_NE(why.find("max_clients"), std::string::npos) << why;
  o = {};
  o.tick = 0ms;
  EXPECT_FALSE(o.is_valid(&why));
  EXPECT_NE(why.find("tick = 0 ms"), std::string::npos) << why;
  EXPECT_FALSE(o.is_valid(nullptr));
}

TEST(HttpServerOptions, Validity) {
  std::string why;
  EXPECT_TRUE(HttpServerOptions{}.is_valid(&why)) << why;
  const std::vector<std::pair<std::function<void(HttpServerOptions&)>, std::string>> bad = {
      {[](HttpServerOptions& o) { o.bind = "localhost"; }, "bind = \"localhost\""},
      {[](HttpServerOptions& o) { o.port = 65536; }, "port = 65536"},
      {[](HttpServerOptions& o) { o.port = -1; }, "port"},
      {[](HttpServerOptions& o) { o.read_timeout = 0ms; }, "read_timeout = 0 ms must be > 0"},
      {[](HttpServerOptions& o) { o.write_timeout = -5ms; }, "write_timeout"},
      {[](HttpServerOptions& o) { o.header_limit = 0; }, "header_limit"},
      {[](HttpServerOptions& o) { o.body_limit = 0; }, "body_limit"},
      {[](HttpServerOptions& o) { o.max_connections = 0; }, "max_connections"},
      {[](HttpServerOptions& o) { o.threads = 0; }, "threads"},
      {[](HttpServerOptions& o) { o.stream_path = "api/v1/stream"; }, "stream_path"},
  };
  for (const auto& [spoil, field] : bad) {
    HttpServerOptions o;
    spoil(o);
    why.clear();
    EXPECT_FALSE(o.is_valid(&why)) << field;
    EXPECT_NE(why.find(field), std::string::npos) << field << ": " << why;
    EXPECT_FALSE(o.is_valid(nullptr)) << field;
  }
  // The stream it serves is checked with it; create() refuses either.
  EventStreamOptions stalled;
  stalled.tick = 0ms;
  EventStream stream(stalled);
  HttpServerOptions o;
  o.port = 0;
  o.stream = &stream;
  EXPECT_FALSE(o.is_valid(&why));
  EXPECT_NE(why.find("stream.tick"), std::string::npos) << why;
  auto server = HttpServer::create(o, [](const HttpRequest& req) {
    return error_response(req, boost::beast::http::status::not_found, "no");
  });
  ASSERT_FALSE(server.ok());
  EXPECT_NE(server.error().message.find("invalid HTTP server options: stream.tick"),
            std::string::npos)
      << server.error().message;
}

}  // namespace
}  // namespace gyrotherm::api
