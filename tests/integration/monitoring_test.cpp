// Monitoring end to end on the simulated station: the live stream carries
// status ticks and the run's state changes and events, /metrics follows the
// acquisition, the decimated samples agree with the SQLite file, and the
// OpenAPI document is served.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sqlite3.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdlib>
#include <map>
#include <regex>
#include <sstream>

#include "gyrotherm/storage/database.h"
#include "station_fixture.h"

namespace gyrotherm::testing {
namespace {

using namespace std::chrono_literals;

// The value of one sample line of a Prometheus text exposition, e.g.
// metric(text, "gyrotherm_state{state=\"acquiring\"}").
std::optional<double> metric(const std::string& text, const std::string& series) {
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    if (line.rfind(series + " ", 0) == 0) return std::stod(line.substr(series.size() + 1));
  }
  return std::nullopt;
}

class MonitoringTest : public StationTest {
 protected:
  void SetUp() override {
    StationTest::SetUp();
    write(dir_ / "schedule.toml", kSchedule);
    start_sim();
    start_daemon();
    ASSERT_TRUE(wait_until([&] { return status().has_value(); }, 20s)) << daemon_->log();
  }

  // Opens /api/v1/stream on a raw socket.
  int open_stream() {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(static_cast<uint16_t>(api_port_));
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) return -1;
    const std::string req =
        "GET /api/v1/stream HTTP/1.1\r\nHost: t\r\nAccept: text/event-stream\r\n\r\n";
    ::send(fd, req.data(), req.size(), MSG_NOSIGNAL);
    return fd;
  }
  // Appends what the stream sends to `text` until `done(text)` or timeout.
  template <class Done>
  bool read_stream(int fd, std::string& text, Done done, std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    char buf[8192];
    while (!done(text)) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      pollfd p{fd, POLLIN, 0};
      if (::poll(&p, 1, 100) <= 0) continue;
      const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
      if (n <= 0) return false;
      text.append(buf, static_cast<std::size_t>(n));
    }
    return true;
  }
};

TEST_F(MonitoringTest, StreamCarriesStatusTicksStateChangesAndEvents) {
  const int fd = open_stream();
  ASSERT_GE(fd, 0);
  std::string text;
  // The run reaches acquisition: a state event says so, with the events
  // that go with it, and status ticks keep coming (about one a wall second).
  const bool got = read_stream(
      fd, text,
      [](const std::string& t) {
        return std::regex_search(t,
                                 std::regex(R"(event: state\ndata: \{[^\n]*"to":"acquiring")")) &&
               t.find("event: event\n") != std::string::npos;
      },
      60s);
  ASSERT_TRUE(got) << text.substr(0, 4000) << "\n" << daemon_->log();
  std::size_t status_events = 0;
  for (std::size_t p = 0; (p = text.find("event: status\n", p)) != std::string::npos; ++p) {
    ++status_events;
  }
  std::string more;
  ASSERT_TRUE(read_stream(
      fd, more,
      [](const std::string& t) {
        std::size_t n = 0;
        for (std::size_t p = 0; (p = t.find("event: status\n", p)) != std::string::npos; ++p) ++n;
        return n >= 2;
      },
      10s));
  EXPECT_NE(text.find("retry: 3000"), std::string::npos);
  EXPECT_GE(status_events, 1u);
  // Every data line is one JSON object.
  std::istringstream lines(text + more);
  int data_lines = 0;
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("data: ", 0) != 0) continue;
    ++data_lines;
    const auto j = nlohmann::json::parse(line.substr(6), nullptr, false);
    EXPECT_TRUE(j.is_object()) << line.substr(0, 200);
  }
  EXPECT_GE(data_lines, 3);
  ::close(fd);
}

TEST_F(MonitoringTest, MetricsFollowTheAcquisition) {
  ASSERT_TRUE(wait_until(
      [&] {
        auto s = status();
        return s && (*s)["state"] == "acquiring";
      },
      60s))
      << daemon_->log();
  auto scrape = [&] {
    auto r = call("GET", "/metrics", "", "");
    return r && r->status == 200 ? r->body : std::string();
  };
  const std::string first = scrape();
  ASSERT_FALSE(first.empty());
  EXPECT_EQ(metric(first, "gyrotherm_up"), 1.0);
  EXPECT_EQ(metric(first, "gyrotherm_state{state=\"acquiring\"}"), 1.0);
  EXPECT_EQ(metric(first, "gyrotherm_state{state=\"idle\"}"), 0.0);
  EXPECT_TRUE(metric(first, "gyrotherm_temperature_celsius{sensor=\"chamber\"}").has_value());
  EXPECT_TRUE(metric(first, "gyrotherm_gyro_rate_dph").has_value());
  EXPECT_GT(metric(first, "gyrotherm_modbus_request_seconds_count{device=\"chamber\"}").value_or(0),
            0);
  EXPECT_GT(metric(first, "gyrotherm_db_commit_seconds_count").value_or(0), 0);
  EXPECT_EQ(metric(first, "gyrotherm_gyro_crc_failures_total"), 0.0);
  EXPECT_EQ(metric(first, "gyrotherm_gyro_sequence_gaps_total"), 0.0);
  EXPECT_NE(first.find("# TYPE gyrotherm_gyro_samples_total counter"), std::string::npos);
  EXPECT_NE(first.find("# TYPE gyrotherm_modbus_request_seconds histogram"), std::string::npos);
  const double samples0 = metric(first, "gyrotherm_gyro_samples_total").value_or(-1);
  ASSERT_TRUE(wait_until(
      [&] { return metric(scrape(), "gyrotherm_gyro_samples_total").value_or(0) > samples0 + 20; },
      10s));
  auto health = call("GET", "/healthz", "", "");
  ASSERT_TRUE(health);
  EXPECT_EQ(health->status, 200);
}

TEST_F(MonitoringTest, DecimatedSamplesAgreeWithTheDatabase) {
  ASSERT_TRUE(wait_until(
      [&] {
        auto s = status();
        return s && (*s)["state"] == "acquiring" && (*s)["t_run_s"].get<double>() > 300;
      },
      60s))
      << daemon_->log();
  const auto run_id = (*status())["run_id"].get<int64_t>();
  // The samples of [0, 300] committed (the status's clock runs ahead of
  // the writer's commits, far ahead on a slow build): then both reads see them.
  ASSERT_TRUE(wait_until(
      [&] {
        auto db = storage::Database::open_read_only((dir_ / "station.db").string());
        if (!db.ok()) return false;
        auto last = db->last_gyro_sample_t_s(run_id);
        return last.ok() && last->has_value() && **last > 300.5;
      },
      60s))
      << daemon_->log();
  const std::string base = fmt::format("/api/v1/runs/{}/samples", run_id);
  const auto j = get_json(base + "?from=0&to=300&max_points=100");
  ASSERT_TRUE(j.is_object());
  const auto& g = j["gyro"];
  ASSERT_LE(g["t_s"].size(), 100u);
  ASSERT_GE(g["t_s"].size(), 50u);
  EXPECT_EQ(g["mean_dph"].size(), g["t_s"].size());
  EXPECT_EQ(j["source"], "rollup");  // 10 Hz x 300 s = 3000 samples > 100 points
  int64_t n_sum = 0;
  for (const auto& n : g["n"]) n_sum += n.get<int64_t>();
  for (std::size_t i = 0; i < g["t_s"].size(); ++i) {
    EXPECT_LE(g["min_dph"][i].get<double>(), g["mean_dph"][i].get<double>());
    EXPECT_GE(g["max_dph"][i].get<double>(), g["mean_dph"][i].get<double>());
    if (i > 0) {
      EXPECT_GT(g["t_s"][i].get<double>(), g["t_s"][i - 1].get<double>());
    }
  }
  // The same count from the file (its chunks), over the range the answer covers.
  auto file = storage::Database::open_read_only((dir_ / "station.db").string());
  ASSERT_TRUE(file.ok()) << file.error().message;
  auto raw = file->gyro_samples(run_id, j["from_s"].get<double>(), j["to_s"].get<double>());
  ASSERT_TRUE(raw.ok()) << raw.error().message;
  // Exact but for a sample on a block edge at either end: the rollup places
  // a sample by the time it was written with, a read by the chunk's implicit
  // clock (within 1e-6 of a period), and on the simulator's clock 10 Hz
  // samples fall on the 0.1 s grid, so one at an edge can land on either side.
  EXPECT_LE(std::abs(n_sum - static_cast<int64_t>(raw->size())), 2);
  double raw_sum = 0;
  for (const GyroSample& r : *raw) raw_sum += r.rate_dph;
  double weighted = 0;
  for (std::size_t i = 0; i < g["t_s"].size(); ++i) {
    weighted += g["mean_dph"][i].get<double>() * g["n"][i].get<double>();
  }
  // (two edge samples of ~3000 at ~8 °/h with 1 °/h of noise: < 0.005 °/h)
  EXPECT_NEAR(weighted / static_cast<double>(n_sum), raw_sum / static_cast<double>(raw->size()),
              0.005);
  EXPECT_FALSE(j["temperature"]["t_s"].empty());

  // Bad parameters name themselves.
  auto bad = call("GET", base + "?from=abc", "", "");
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->status, 400);
  EXPECT_NE(bad->body.find("'from'"), std::string::npos) << bad->body;
  bad = call("GET", base + "?max_points=0", "", "");
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->status, 400);
  bad = call("GET", base + "?from=10&to=5", "", "");
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->status, 400);
  bad = call("GET", base + "?colour=red", "", "");
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->status, 400);
  EXPECT_NE(bad->body.find("colour"), std::string::npos);
  auto missing = call("GET", "/api/v1/runs/999/samples", "", "");
  ASSERT_TRUE(missing);
  EXPECT_EQ(missing->status, 404);

  // The contract is served, and names this route.
  const auto doc = get_json("/api/v1/openapi.json");
  ASSERT_TRUE(doc.is_object());
  EXPECT_TRUE(doc["paths"].contains("/api/v1/runs/{id}/samples"));
}

}  // namespace
}  // namespace gyrotherm::testing
