#include "gyrotherm/api/api.h"

#include <arpa/inet.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>

#include "gyrotherm/api/auth_limiter.h"
#include "gyrotherm/api/http_message.h"
#include "gyrotherm/api/http_server.h"
#include "gyrotherm/cli/http_client.h"
#include "gyrotherm/core/clock.h"

namespace gyrotherm::api {
namespace {

namespace http = boost::beast::http;
using cli::http_request;

HttpRequest get(std::string target, http::verb verb = http::verb::get) {
  HttpRequest req{verb, target, 11};
  return req;
}

constexpr const char* kToken = "test-token-0123456789abcdef";

// Records what the API asked for and answers per the contract.
class FakeControl : public station::StationControl {
 public:
  std::vector<std::string> calls;
  station::Reply queue_list() override {
    calls.push_back("queue_list");
    return station::Reply::ok({{"held", false}, {"entries", nlohmann::json::array()}});
  }
  station::Reply queue_add(const std::string& toml, const std::string& source,
                           bool ignore) override {
    calls.push_back(fmt::format("queue_add {} {} {}", toml, source, ignore));
    if (toml == "bad") {
      return station::Reply::refused(station::Refusal::Kind::kInvalid,
                                     "schedule refused, nothing queued",
                                     {"s.toml:3: step.setpoint_c: 70 °C is above 60 °C"});
    }
    return station::Reply::ok({{"id", 1}});
  }
  station::Reply queue_remove(int64_t id) override {
    calls.push_back(fmt::format("queue_remove {}", id));
    if (id == 9)
      return station::Reply::refused(station::Refusal::Kind::kConflict, "entry 9 is running");
    if (id == 8)
      return station::Reply::refused(station::Refusal::Kind::kNotFound, "no queued entry 8");
    return station::Reply::ok({{"removed", id}});
  }
  station::Reply queue_move(int64_t id, int position) override {
    calls.push_back(fmt::format("queue_move {} {}", id, position));
    return station::Reply::ok({{"held", false}});
  }
  station::Reply control(std::string_view action, const std::string& reason) override {
    calls.push_back(fmt::format("control {} {}", action, reason));
    if (action == "pause")
      return station::Reply::refused(station::Refusal::Kind::kConflict, "no run to pause");
    return station::Reply::ok({{"ok", true}});
  }
  station::Reply runs() override {
    calls.push_back("runs");
    return station::Reply::ok(nlohmann::json::array());
  }
  station::Reply run(int64_t id) override {
    calls.push_back(fmt::format("run {}", id));
    return station::Reply::ok({{"id", id}});
  }
  station::Reply run_events(int64_t id) override {
    calls.push_back(fmt::format("events {}", id));
    return station::Reply::ok(nlohmann::json::array());
  }
  station::Reply run_stats(int64_t id) override {
    calls.push_back(fmt::format("stats {}", id));
    return station::Reply::ok(nlohmann::json::array());
  }
  station::Reply run_samples(int64_t id, const station::SamplesQuery& q) override {
    calls.push_back(fmt::format("samples {} {} {} {}", id, q.from_s,
                                q.to_s ? fmt::format("{}", *q.to_s) : "last", q.max_points));
    return station::Reply::ok({{"run_id", id}});
  }
  station::Reply run_fits(int64_t id) override {
    calls.push_back(fmt::format("fits {}", id));
    return station::Reply::ok(nlohmann::json::array());
  }
  station::Reply run_allan(int64_t id) override {
    calls.push_back(fmt::format("allan {}", id));
    return station::Reply::ok(nlohmann::json::array());
  }
  station::Reply run_scale_factor(int64_t id) override {
    calls.push_back(fmt::format("scale-factor {}", id));
    return station::Reply::ok({{"points", nlohmann::json::array()}});
  }
  station::Reply fit(int64_t id) override {
    calls.push_back(fmt::format("fit {}", id));
    if (id == 5) return station::Reply::refused(station::Refusal::Kind::kNotFound, "no fit 5");
    return station::Reply::ok({{"id", id}});
  }
  station::Reply exports() override {
    calls.push_back("exports");
    return station::Reply::ok(nlohmann::json::array());
  }
  static std::string listed(const std::vector<std::string>& items) {
    return fmt::format("[{}]", fmt::join(items, "|"));
  }
  station::Reply enqueue(const station::QueueRequest& q) override {
    const auto& m = q.metadata;
    for (const auto& serial : m.dut_serials) {
      if (serial == "nope") {
        return station::Reply::refused(
            station::Refusal::Kind::kBadRequest,
            "field 'duts': no DUT with serial 'nope' (configured [[dut]] "
            "serials: '17-0042')");
      }
    }
    calls.push_back(fmt::format("enqueue {} {} {} op={} comment={} tags={} duts={}", q.toml_text,
                                q.source, q.ignore_failures, m.operator_name, m.comment,
                                listed(m.tags), listed(m.dut_serials)));
    if (q.toml_text == "bad") {
      return station::Reply::refused(station::Refusal::Kind::kInvalid,
                                     "schedule refused, nothing queued",
                                     {"s.toml:3: step.setpoint_c: 70 °C is above 60 °C"});
    }
    return station::Reply::ok({{"id", 1}});
  }
  station::Reply run_with_duts(int64_t id) override {
    calls.push_back(fmt::format("run {}", id));
    return station::Reply::ok({{"id", id}, {"duts", nlohmann::json::array()}});
  }
  station::Reply edit_run(int64_t id, const station::MetadataEdit& e,
                          const std::string& changed_by) override {
    calls.push_back(fmt::format("edit_run {} op={} comment={} tags={} duts={} by {}", id,
                                e.operator_name.value_or("(same)"), e.comment.value_or("(same)"),
                                e.tags ? listed(*e.tags) : "(same)",
                                e.dut_serials ? listed(*e.dut_serials) : "(same)", changed_by));
    if (id == 8) return station::Reply::refused(station::Refusal::Kind::kNotFound, "no run 8");
    return station::Reply::ok({{"id", id}});
  }
  station::Reply run_stats_filtered(int64_t id, const station::StatsQuery& q) override {
    calls.push_back(fmt::format("stats {} dut={} axis={}", id, q.dut, q.axis));
    if (q.dut == "17-0099") {
      return station::Reply::refused(station::Refusal::Kind::kNotFound,
                                     "run 12 has no DUT '17-0099' (its DUTs: '17-0042')");
    }
    return station::Reply::ok(nlohmann::json::array());
  }
  station::Reply run_channel_samples(int64_t id, const station::SamplesQuery& q) override {
    calls.push_back(fmt::format("samples {} {} {} {}{}", id, q.from_s,
                                q.to_s ? fmt::format("{}", *q.to_s) : "last", q.max_points,
                                q.dut.empty() && q.channel.empty()
                                    ? std::string()
                                    : fmt::format(" dut={} channel={}", q.dut, q.channel)));
    if (q.channel == "nope") {
      return station::Reply::refused(
          station::Refusal::Kind::kNotFound,
          "DUT '17-0042' of run 4 has no channel 'nope' (its channels: ...)");
    }
    return station::Reply::ok({{"run_id", id}});
  }
  station::Reply duts() override {
    calls.push_back("duts");
    return station::Reply::ok(nlohmann::json::array());
  }
  station::Reply dut_history(const std::string& serial) override {
    calls.push_back("dut " + serial);
    if (serial == "17-0043") {
      return station::Reply::refused(station::Refusal::Kind::kNotFound,
                                     "no DUT with serial '17-0043'");
    }
    return station::Reply::ok({{"serial", serial}});
  }
};

ApiContext fake_context(station::StationControl* control = nullptr) {
  ApiContext ctx;
  ctx.status = [] {
    station::StatusSnapshot s;
    s.station_name = "test";
    s.state = "acquiring";
    s.run_id = 7;
    s.chamber_c = 20.25;
    s.gyro_rate_dph = 7.95;
    s.gyro.parser.crc_failures = 3;
    return s;
  };
  ctx.control = control;
  ctx.tokens = {kToken};
  return ctx;
}

HttpRequest request(http::verb verb, std::string target, std::string body = "",
                    std::string authorization = std::string("Bearer ") + kToken) {
  HttpRequest req{verb, target, 11};
  if (!authorization.empty()) req.set(http::field::authorization, authorization);
  req.body() = std::move(body);
  req.prepare_payload();
  return req;
}

TEST(Api, StatusIsJsonWithStateTemperaturesAndHealth) {
  const auto res = handle_api_request(get("/api/v1/status"), fake_context());
  EXPECT_EQ(res.result(), http::status::ok);
  EXPECT_EQ(res[http::field::content_type], "application/json");
  const auto j = nlohmann::json::parse(res.body());
  EXPECT_EQ(j["state"], "acquiring");
  EXPECT_EQ(j["run_id"], 7);
  EXPECT_DOUBLE_EQ(j["chamber_c"].get<double>(), 20.25);
  EXPECT_TRUE(j["top_c"].is_null());
  EXPECT_DOUBLE_EQ(j["gyro_rate_dph"].get<double>(), 7.95);
  EXPECT_EQ(j["devices"]["gyro"]["crc_failures"], 3);
  EXPECT_TRUE(j["devices"].contains("chamber"));
  EXPECT_TRUE(j["devices"].contains("probes"));
}

TEST(Api, UnknownPathIs404AndWrongMethod405) {
  EXPECT_EQ(handle_api_request(get("/api/v1/nope"), fake_context()).result(),
            http::status::not_found);
  EXPECT_EQ(handle_api_request(get("/api/v1/status", http::verb::post), fake_context()).result(),
            http::status::method_not_allowed);
  EXPECT_EQ(handle_api_request(get("/healthz"), fake_context()).result(), http::status::ok);
}

// The real server on an ephemeral loopback port, with the real client.
TEST(HttpServer, ServesOverLoopbackAndSurvivesGarbage) {
  const ApiContext ctx = fake_context();
  HttpServerOptions options;
  options.bind = "127.0.0.1";
  options.port = 0;
  auto server = HttpServer::create(
      options, [&ctx](const HttpRequest& r) { return handle_api_request(r, ctx); });
  ASSERT_TRUE(server.ok()) << server.error().message;
  (*server)->start();
  const std::string base = "http://127.0.0.1:" + std::to_string((*server)->port());

  auto ok = http_request("GET", base + "/api/v1/status");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok->status, 200);
  EXPECT_EQ(nlohmann::json::parse(ok->body)["station"], "test");

  // An oversized body is refused with 413 (or the connection is closed while
  // the client is still sending it), and the server keeps serving.
  auto big = http_request("POST", base + "/api/v1/status", std::string(100 * 1024, 'x'));
  if (big.ok()) {
    EXPECT_EQ(big->status, 413);
  }
  auto again = http_request("GET", base + "/healthz");
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_EQ(again->status, 200);
  (*server)->stop();
}

TEST(HttpServer, RefusesAnAddressInUse) {
  HttpServerOptions options;
  options.port = 0;
  auto first = HttpServer::create(options, [](const HttpRequest& r) {
    return error_response(r, http::status::not_found, "x");
  });
  ASSERT_TRUE(first.ok());
  options.port = (*first)->port();
  auto second = HttpServer::create(options, [](const HttpRequest& r) {
    return error_response(r, http::status::not_found, "x");
  });
  ASSERT_FALSE(second.ok());
  EXPECT_NE(second.error().message.find("cannot listen on 127.0.0.1:"), std::string::npos);
}

TEST(Api, MutationsNeedAValidBearerToken) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  const std::vector<std::pair<http::verb, std::string>> mutations = {
      {http::verb::post, "/api/v1/queue"},          {http::verb::delete_, "/api/v1/queue/3"},
      {http::verb::post, "/api/v1/queue/3/move"},   {http::verb::post, "/api/v1/control/pause"},
      {http::verb::post, "/api/v1/control/resume"}, {http::verb::post, "/api/v1/control/abort"},
      {http::verb::post, "/api/v1/control/stop"},   {http::verb::patch, "/api/v1/runs/3"}};
  for (const auto& [verb, target] : mutations) {
    for (const std::string& auth : {std::string(""), std::string("Bearer wrong-token-0123456789ab"),
                                    std::string("Basic ") + kToken, std::string("Bearer ")}) {
      const auto res = handle_api_request(request(verb, target, "{}", auth), ctx);
      EXPECT_EQ(res.result(), http::status::unauthorized) << target << " with '" << auth << "'";
      EXPECT_EQ(res[http::field::www_authenticate], "Bearer");
      EXPECT_EQ(res.body().find(kToken), std::string::npos) << "tokens are never echoed";
    }
  }
  EXPECT_TRUE(control.calls.empty()) << "nothing reached the station without a token";
  // Reads are open.
  EXPECT_EQ(handle_api_request(request(http::verb::get, "/api/v1/queue", "", ""), ctx).result(),
            http::status::ok);
  // No token configured: every mutation is refused.
  ApiContext no_tokens = ctx;
  no_tokens.tokens.clear();
  EXPECT_EQ(
      handle_api_request(request(http::verb::post, "/api/v1/control/stop"), no_tokens).result(),
      http::status::forbidden);
}

// Found by the HTTP fuzz target: both threw out of handle_api_request.
TEST(Api, ANumberOutOfRangeAndANonUtf8TargetAreClientErrors) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  const auto huge = handle_api_request(
      request(http::verb::post, "/api/v1/control/pause", R"({"reason": 1e999})"), ctx);
  EXPECT_EQ(huge.result(), http::status::bad_request);
  EXPECT_NE(huge.body().find("body is not JSON"), std::string::npos) << huge.body();
  const auto bytes = handle_api_request(get("/api/v1/\xce\xce"), ctx);
  EXPECT_EQ(bytes.result(), http::status::not_found);
  EXPECT_FALSE(nlohmann::json::parse(bytes.body(), nullptr, false).is_discarded()) << bytes.body();
}

TEST(Api, TokenComparison) {
  const std::vector<std::string> tokens = {"first-token-0123456789", "second-token-abcdefghij"};
  EXPECT_TRUE(token_matches("first-token-0123456789", tokens));
  EXPECT_TRUE(token_matches("second-token-abcdefghij", tokens));
  EXPECT_FALSE(token_matches("first-token-012345678", tokens)) << "a prefix";
  EXPECT_FALSE(token_matches("first-token-01234567890", tokens)) << "longer";
  EXPECT_FALSE(token_matches("First-token-0123456789", tokens));
  EXPECT_FALSE(token_matches("", tokens));
  EXPECT_FALSE(token_matches("x", {}));
}

TEST(Api, RoutesReachTheStationWithTheirArguments) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  auto call = [&](http::verb v, const char* target, const char* body = "") {
    return handle_api_request(request(v, target, body), ctx);
  };
  EXPECT_EQ(call(http::verb::post, "/api/v1/queue",
                 R"({"schedule_toml":"x","source":"a.toml","ignore_failures":true})")
                .result(),
            http::status::created);
  EXPECT_EQ(call(http::verb::delete_, "/api/v1/queue/3").result(), http::status::ok);
  EXPECT_EQ(call(http::verb::post, "/api/v1/queue/3/move", R"({"position":0})").result(),
            http::status::ok);
  EXPECT_EQ(call(http::verb::post, "/api/v1/control/abort", R"({"reason":"leak"})").result(),
            http::status::ok);
  EXPECT_EQ(call(http::verb::post, "/api/v1/control/stop").result(), http::status::ok);
  EXPECT_EQ(call(http::verb::get, "/api/v1/runs").result(), http::status::ok);
  EXPECT_EQ(call(http::verb::get, "/api/v1/runs/12").result(), http::status::ok);
  EXPECT_EQ(call(http::verb::get, "/api/v1/runs/12/events").result(), http::status::ok);
  EXPECT_EQ(call(http::verb::get, "/api/v1/runs/12/stats").result(), http::status::ok);
  EXPECT_EQ(control.calls,
            (std::vector<std::string>{"enqueue x a.toml true op= comment= tags=[] duts=[]",
                                      "queue_remove 3", "queue_move 3 0", "control abort leak",
                                      "control stop ", "runs", "run 12", "events 12",
                                      "stats 12 dut= axis="}));
}

TEST(Api, SamplesQueryReachesTheStationDecodedWithDefaults) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  for (const char* target :
       {"/api/v1/runs/4/samples", "/api/v1/runs/4/samples?from=10&to=20.5&max_points=300",
        "/api/v1/runs/4/samples?from=%2D5&max_points=20000"}) {
    EXPECT_EQ(handle_api_request(get(target), ctx).result(), http::status::ok) << target;
  }
  EXPECT_EQ(control.calls,
            (std::vector<std::string>{"samples 4 0 last 2000", "samples 4 10 20.5 300",
                                      "samples 4 -5 last 20000"}));
  // Garbage never reaches the station.
  control.calls.clear();
  for (const char* target :
       {"/api/v1/runs/4/samples?from=1e999", "/api/v1/runs/4/samples?to=nan",
        "/api/v1/runs/4/samples?max_points=20001", "/api/v1/runs/4/samples?max_points=2.5",
        "/api/v1/runs/4/samples?from=%zz", "/api/v1/runs/4/samples?from=1&from_s=2"}) {
    EXPECT_EQ(handle_api_request(get(target), ctx).result(), http::status::bad_request) << target;
  }
  EXPECT_TRUE(control.calls.empty());
}

TEST(Api, AnalysisRoutesReachTheStationWithTheRunId) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  for (const char* target : {"/api/v1/runs/7/allan", "/api/v1/runs/7/fits", "/api/v1/fits/9"}) {
    EXPECT_EQ(handle_api_request(get(target), ctx).result(), http::status::ok) << target;
  }
  EXPECT_EQ(control.calls, (std::vector<std::string>{"allan 7", "fits 7", "fit 9"}));
  control.calls.clear();
  EXPECT_EQ(handle_api_request(get("/api/v1/runs/x/allan"), ctx).result(), http::status::not_found)
      << "no route takes a non-numeric run id";
  EXPECT_TRUE(control.calls.empty());
}

TEST(Api, WebFilesAreOnlyThoseReadAtStartUp) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("gyrotherm-web-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir / "sub");
  std::ofstream(dir / "index.html") << "<html>dashboard</html>";
  std::ofstream(dir / "app.js") << "let x = 1;";
  std::ofstream(dir / "notes.txt") << "not a web file type";
  std::ofstream(dir / "sub" / "deep.js") << "nested";
  auto web = WebAssets::load(dir.string());
  ASSERT_TRUE(web.ok()) << web.error().message;
  ApiContext ctx = fake_context();
  ctx.web = &*web;
  const auto index = handle_api_request(get("/"), ctx);
  EXPECT_EQ(index.result(), http::status::ok);
  EXPECT_EQ(index.body(), "<html>dashboard</html>");
  EXPECT_EQ(index[http::field::content_type], "text/html; charset=utf-8");
  EXPECT_EQ(handle_api_request(get("/web/app.js"), ctx).result(), http::status::ok);
  for (const char* target : {"/web/notes.txt", "/web/sub/deep.js", "/web/../index.html",
                             "/web/..%2Fetc%2Fpasswd", "/web/%2e%2e", "/web/", "/web/nope.js"}) {
    EXPECT_EQ(handle_api_request(get(target), ctx).result(), http::status::not_found) << target;
  }
  std::filesystem::remove_all(dir);
  EXPECT_FALSE(WebAssets::load(dir.string()).ok()) << "a missing web root is an error";
}

TEST(Api, AWebFileOverTheLimitIsAnErrorNamingIt) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("gyrotherm-web-big-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "index.html") << "<html>dashboard</html>";
  std::ofstream(dir / "big.js") << std::string(kMaxWebFileBytes + 1, 'x');
  auto web = WebAssets::load(dir.string());
  std::filesystem::remove_all(dir);
  ASSERT_FALSE(web.ok());
  EXPECT_NE(web.error().message.find("web files: " + (dir / "big.js").string()), std::string::npos)
      << web.error().message;
}

TEST(Api, RefusalsMapToStatusesWithTheirMessages) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  auto res = handle_api_request(
      request(http::verb::post, "/api/v1/queue", R"({"schedule_toml":"bad"})"), ctx);
  EXPECT_EQ(res.result(), http::status::unprocessable_entity);
  auto j = nlohmann::json::parse(res.body());
  EXPECT_EQ(j["error"], "schedule refused, nothing queued");
  ASSERT_EQ(j["errors"].size(), 1u);
  EXPECT_EQ(j["errors"][0], "s.toml:3: step.setpoint_c: 70 °C is above 60 °C");
  EXPECT_EQ(handle_api_request(request(http::verb::delete_, "/api/v1/queue/9"), ctx).result(),
            http::status::conflict);
  EXPECT_EQ(handle_api_request(request(http::verb::delete_, "/api/v1/queue/8"), ctx).result(),
            http::status::not_found);
  EXPECT_EQ(handle_api_request(request(http::verb::post, "/api/v1/control/pause"), ctx).result(),
            http::status::conflict);
}

// The rate table's fault reset is a control action like pause: routed to
// the station's control() with its reason (`gyrotherm table reset` on a
// station the daemon runs).
TEST(Api, TableResetIsAControlActionOfTheStation) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  const auto res = handle_api_request(
      request(http::verb::post, "/api/v1/control/table-reset", R"({"reason":"e-stop checked"})"),
      ctx);
  EXPECT_EQ(res.result(), http::status::ok) << res.body();
  EXPECT_EQ(control.calls, (std::vector<std::string>{"control table-reset e-stop checked"}));
  const auto unknown =
      handle_api_request(request(http::verb::post, "/api/v1/control/table-rest"), ctx);
  EXPECT_EQ(unknown.result(), http::status::not_found);
  EXPECT_NE(unknown.body().find("table-reset"), std::string::npos) << "the actions are listed";
}

// With a body cache attached, the status is rendered once for many reads,
// and a control request (whatever its answer) makes the next one new.
TEST(Api, TheStatusIsServedFromItsCacheAndAControlRequestRendersItAnew) {
  class StillWall final : public WallClock {
   public:
    double unix_now_s() const override { return 1000.0; }
  } wall;
  FakeControl control;
  ApiContext ctx = fake_context(&control);
  std::atomic<int> snapshots{0};
  ctx.status = [&] {
    station::StatusSnapshot s;
    s.station_name = "cached";
    s.state = snapshots++ == 0 ? "idle" : "paused";
    return s;
  };
  BodyCache status_body([&] { return json_text(to_json(ctx.status())); }, 3600, wall);
  ctx.status_body = &status_body;
  for (int i = 0; i < 5; ++i) {
    const auto res = handle_api_request(get("/api/v1/status"), ctx);
    ASSERT_EQ(res.result(), http::status::ok);
    EXPECT_EQ(nlohmann::json::parse(res.body())["state"], "idle") << res.body();
  }
  EXPECT_EQ(snapshots.load(), 1);
  // A read of something else leaves it.
  EXPECT_EQ(handle_api_request(get("/api/v1/queue"), ctx).result(), http::status::ok);
  EXPECT_EQ(handle_api_request(get("/api/v1/status"), ctx).result(), http::status::ok);
  EXPECT_EQ(snapshots.load(), 1);
  // The fake refuses the pause (409); the status is rendered anew all the same.
  EXPECT_EQ(handle_api_request(
                request(http::verb::post, "/api/v1/control/pause", R"({"reason":"x"})"), ctx)
                .result(),
            http::status::conflict);
  const auto res = handle_api_request(get("/api/v1/status"), ctx);
  EXPECT_EQ(nlohmann::json::parse(res.body())["state"], "paused") << res.body();
  EXPECT_EQ(snapshots.load(), 2);
}

TEST(Api, BadBodiesAre400NamingTheProblem) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  struct Case {
    const char* target;
    const char* body;
    const char* message;
  };
  for (const Case& c : {
           Case{"/api/v1/queue", "{not json", "body is not JSON"},
           Case{"/api/v1/queue", "[1,2]", "body must be a JSON object"},
           Case{"/api/v1/queue", R"({"schedule":"x"})", "unknown field 'schedule'"},
           Case{"/api/v1/queue", R"({"schedule_toml":5})",
                "field 'schedule_toml' must be a string"},
           Case{"/api/v1/queue", R"({"source":"a"})", "field 'schedule_toml' is required"},
           Case{"/api/v1/queue", R"({"schedule_toml":"x","ignore_failures":"yes"})",
                "field 'ignore_failures' must be true or false"},
           Case{"/api/v1/queue/3/move", R"({"position":"first"})",
                "field 'position' must be an integer"},
           Case{"/api/v1/queue/3/move", R"({"position":-1})", "must be >= 0"},
           Case{"/api/v1/queue/3/move", "{}", "field 'position' is required"},
           Case{"/api/v1/control/pause", R"({"why":"x"})",
                "unknown field 'why' (expected: reason)"},
       }) {
    const auto res = handle_api_request(request(http::verb::post, c.target, c.body), ctx);
    EXPECT_EQ(res.result(), http::status::bad_request) << c.target << " " << c.body;
    EXPECT_NE(res.body().find(c.message), std::string::npos) << res.body();
  }
  EXPECT_TRUE(control.calls.empty());
  EXPECT_EQ(handle_api_request(request(http::verb::delete_, "/api/v1/queue/abc"), ctx).result(),
            http::status::not_found);
  EXPECT_EQ(handle_api_request(request(http::verb::get, "/api/v1/control/pause"), ctx).result(),
            http::status::method_not_allowed);
  EXPECT_EQ(handle_api_request(request(http::verb::post, "/api/v1/control/explode"), ctx).result(),
            http::status::not_found);
}

// ---------------------------------------------------------------- access

constexpr const char* kReadToken = "read-token-0123456789abcdef";
// Shares all but its last character with kToken.
constexpr const char* kNearToken = "test-token-0123456789abcdeF";

const std::vector<std::pair<http::verb, std::string>>& mutations() {
  static const std::vector<std::pair<http::verb, std::string>> list = {
      {http::verb::post, "/api/v1/queue"},          {http::verb::delete_, "/api/v1/queue/3"},
      {http::verb::post, "/api/v1/queue/3/move"},   {http::verb::post, "/api/v1/control/pause"},
      {http::verb::post, "/api/v1/control/resume"}, {http::verb::post, "/api/v1/control/abort"},
      {http::verb::post, "/api/v1/control/stop"},   {http::verb::patch, "/api/v1/runs/3"}};
  return list;
}

// Every GET route that carries station data (all of /api/v1 and /metrics).
const std::vector<std::string>& data_reads() {
  static const std::vector<std::string> list = {
      "/api/v1/status",       "/api/v1/queue",         "/api/v1/runs",
      "/api/v1/runs/4",       "/api/v1/runs/4/events", "/api/v1/runs/4/stats",
      "/api/v1/runs/4/fits",  "/api/v1/runs/4/allan",  "/api/v1/runs/4/samples?max_points=10",
      "/api/v1/fits/4",       "/api/v1/exports",       "/api/v1/duts",
      "/api/v1/duts/17-0042", "/api/v1/openapi.json",  "/metrics"};
  return list;
}

std::string bearer(const char* token) { return fmt::format("Bearer {}", token); }

ApiContext two_role_context(FakeControl* control) {
  ApiContext ctx = fake_context(control);
  ctx.read_tokens = {kReadToken};
  ctx.metrics = [] { return std::string("gyrotherm_up 1\n"); };
  return ctx;
}

TEST(Api, ReadTokensMayReadButNeverChange) {
  FakeControl control;
  const ApiContext ctx = two_role_context(&control);
  for (const auto& [verb, target] : mutations()) {
    const auto res = handle_api_request(request(verb, target, "{}", bearer(kReadToken)), ctx);
    EXPECT_EQ(res.result(), http::status::forbidden) << target;
    const auto body = nlohmann::json::parse(res.body());
    EXPECT_NE(body["error"].get<std::string>().find("read-only"), std::string::npos) << res.body();
    EXPECT_EQ(res.body().find(kReadToken), std::string::npos) << "tokens are never echoed";
    EXPECT_EQ(res.body().find(kToken), std::string::npos);
  }
  EXPECT_TRUE(control.calls.empty()) << "nothing reached the station with a read token";
  // Unknown and missing tokens stay 401, however much of a real one they share.
  for (const std::string& auth : {std::string(""), bearer(kNearToken), bearer("read-token-0123")}) {
    EXPECT_EQ(handle_api_request(request(http::verb::post, "/api/v1/control/stop", "", auth), ctx)
                  .result(),
              http::status::unauthorized)
        << auth;
  }
  EXPECT_TRUE(control.calls.empty());
  // The control token changes; the read token reads.
  EXPECT_EQ(handle_api_request(request(http::verb::post, "/api/v1/control/stop"), ctx).result(),
            http::status::ok);
  EXPECT_EQ(
      handle_api_request(request(http::verb::get, "/api/v1/runs", "", bearer(kReadToken)), ctx)
          .result(),
      http::status::ok);
  // Read tokens only, no control token: changes are disabled (403), not a 401.
  ApiContext read_only = ctx;
  read_only.tokens.clear();
  EXPECT_EQ(
      handle_api_request(request(http::verb::post, "/api/v1/control/stop", "", bearer(kReadToken)),
                         read_only)
          .result(),
      http::status::forbidden);
}

TEST(Api, InTokenModeReadsNeedAReadOrControlToken) {
  FakeControl control;
  ApiContext ctx = two_role_context(&control);
  ctx.reads_need_token = true;
  for (const std::string& target : data_reads()) {
    for (const std::string& auth : {std::string(""), bearer(kNearToken), std::string("Basic x")}) {
      const auto res = handle_api_request(request(http::verb::get, target, "", auth), ctx);
      EXPECT_EQ(res.result(), http::status::unauthorized) << target << " with '" << auth << "'";
      EXPECT_EQ(res[http::field::www_authenticate], "Bearer") << target;
      EXPECT_EQ(res.body().find(kToken), std::string::npos);
      EXPECT_EQ(handle_api_request(request(http::verb::head, target, "", auth), ctx).result(),
                http::status::unauthorized)
          << "HEAD " << target;
    }
    for (const char* token : {kReadToken, kToken}) {
      EXPECT_EQ(
          handle_api_request(request(http::verb::get, target, "", bearer(token)), ctx).result(),
          http::status::ok)
          << target;
    }
  }
  // The event stream is answered by the server, which asks check_access.
  const auto stream = check_access(request(http::verb::get, "/api/v1/stream", "", ""), ctx);
  ASSERT_TRUE(stream.has_value());
  EXPECT_EQ(stream->result(), http::status::unauthorized);
  EXPECT_FALSE(
      check_access(request(http::verb::get, "/api/v1/stream", "", bearer(kReadToken)), ctx));
  // Liveness and the dashboard's files hold no station data: open.
  EXPECT_EQ(handle_api_request(request(http::verb::get, "/healthz", "", ""), ctx).result(),
            http::status::ok);
  for (const char* target : {"/", "/web/app.js"}) {
    EXPECT_NE(handle_api_request(request(http::verb::get, target, "", ""), ctx).result(),
              http::status::unauthorized)
        << target;
    EXPECT_FALSE(check_access(request(http::verb::get, target, "", ""), ctx)) << target;
  }
  // Open mode (the default): no token needed to read, and a wrong one is ignored.
  ctx.reads_need_token = false;
  for (const std::string& target : data_reads()) {
    for (const std::string& auth : {std::string(""), bearer(kNearToken)}) {
      EXPECT_EQ(handle_api_request(request(http::verb::get, target, "", auth), ctx).result(),
                http::status::ok)
          << target;
    }
  }
  EXPECT_FALSE(check_access(request(http::verb::get, "/api/v1/stream", "", ""), ctx));
}

TEST(Api, TokenRoles) {
  const std::vector<std::string> control = {"control-token-0123456789", "control-token-abcdefghij"};
  const std::vector<std::string> read = {"read-token-0123456789ab"};
  EXPECT_EQ(token_role("control-token-0123456789", control, read), TokenRole::kControl);
  EXPECT_EQ(token_role("control-token-abcdefghij", control, read), TokenRole::kControl);
  EXPECT_EQ(token_role("read-token-0123456789ab", control, read), TokenRole::kRead);
  EXPECT_EQ(token_role("read-token-0123456789aB", control, read), TokenRole::kNone);
  EXPECT_EQ(token_role("read-token-0123456789a", control, read), TokenRole::kNone) << "a prefix";
  EXPECT_EQ(token_role("control-token-0123456789x", control, read), TokenRole::kNone);
  EXPECT_EQ(token_role("", control, read), TokenRole::kNone);
  EXPECT_EQ(token_role("read-token-0123456789ab", {}, read), TokenRole::kRead);
  EXPECT_EQ(token_role("read-token-0123456789ab", control, {}), TokenRole::kNone);
  EXPECT_FALSE(token_matches("read-token-0123456789ab", control));
}

TEST(AuthLimiter, LocksAPeerOutAfterMaxFailuresWithinTheWindow) {
  ManualClock wall(1000.0);
  auto made = AuthLimiter::create({.max_failures = 3, .window_s = 60.0}, &wall);
  ASSERT_TRUE(made.ok()) << made.error().message;
  AuthLimiter& limiter = **made;
  EXPECT_EQ(limiter.retry_after_s("10.0.0.1"), 0);
  // Failures further apart than the window never add up.
  for (int i = 0; i < 5; ++i) {
    EXPECT_FALSE(limiter.record_failure("10.0.0.1"));
    wall.advance(31.0);
  }
  EXPECT_EQ(limiter.retry_after_s("10.0.0.1"), 0);
  // Three within 60 s lock the peer out for 60 s from the third.
  EXPECT_FALSE(limiter.record_failure("10.0.0.1"));  // with the one 31 s ago: 2
  wall.advance(20.0);
  EXPECT_TRUE(limiter.record_failure("10.0.0.1"));
  EXPECT_EQ(limiter.retry_after_s("10.0.0.1"), 60);
  EXPECT_EQ(limiter.retry_after_s("10.0.0.2"), 0) << "other peers are not affected";
  wall.advance(59.5);
  EXPECT_EQ(limiter.retry_after_s("10.0.0.1"), 1) << "rounded up";
  wall.advance(0.5);
  EXPECT_EQ(limiter.retry_after_s("10.0.0.1"), 0);
  // A clean count afterwards.
  EXPECT_FALSE(limiter.record_failure("10.0.0.1"));
  EXPECT_FALSE(limiter.record_failure("10.0.0.1"));
  EXPECT_EQ(limiter.retry_after_s("10.0.0.1"), 0);
}

TEST(AuthLimiterOptions, Validity) {
  std::string why;
  EXPECT_TRUE(AuthLimiterOptions{}.is_valid(&why)) << why;
  EXPECT_FALSE(AuthLimiterOptions{.max_failures = 0}.is_valid(&why));
  EXPECT_NE(why.find("max_failures = 0 must be >= 1"), std::string::npos) << why;
  EXPECT_FALSE(AuthLimiterOptions{.window_s = 0}.is_valid(&why));
  EXPECT_NE(why.find("window_s"), std::string::npos) << why;
  EXPECT_FALSE(AuthLimiterOptions{.window_s = std::nan("")}.is_valid(nullptr));
  EXPECT_FALSE(AuthLimiterOptions{.max_peers = 0}.is_valid(&why));
  EXPECT_NE(why.find("max_peers"), std::string::npos) << why;
  // create() refuses them with the message.
  auto made = AuthLimiter::create({.max_peers = 0});
  ASSERT_FALSE(made.ok());
  EXPECT_NE(made.error().message.find("max_peers"), std::string::npos) << made.error().message;
}

TEST(AuthLimiter, ThePeerTableIsBounded) {
  ManualClock wall(0.0);
  auto made = AuthLimiter::create({.max_failures = 2, .window_s = 60.0, .max_peers = 8}, &wall);
  ASSERT_TRUE(made.ok()) << made.error().message;
  AuthLimiter& limiter = **made;
  limiter.record_failure("attacker");
  EXPECT_TRUE(limiter.record_failure("attacker"));
  for (int i = 0; i < 100; ++i) {
    wall.advance(0.01);
    limiter.record_failure(fmt::format("10.0.0.{}", i));
  }
  EXPECT_LE(limiter.peers(), 8u);
}

TEST(Api, UnknownTokensAreThrottledPerPeer) {
  FakeControl control;
  ManualClock wall(0.0);
  auto made = AuthLimiter::create({.max_failures = 3, .window_s = 60.0}, &wall);
  ASSERT_TRUE(made.ok()) << made.error().message;
  AuthLimiter& limiter = **made;
  ApiContext ctx = two_role_context(&control);
  ctx.auth_limiter = &limiter;
  const auto stop = [&](const std::string& auth, std::string_view peer) {
    return handle_api_request(request(http::verb::post, "/api/v1/control/stop", "", auth), ctx,
                              peer);
  };
  // No token at all and a read token on a mutation are not failures.
  for (int i = 0; i < 10; ++i) {
    EXPECT_EQ(stop("", "10.0.0.1").result(), http::status::unauthorized);
    EXPECT_EQ(stop(bearer(kReadToken), "10.0.0.1").result(), http::status::forbidden);
  }
  EXPECT_EQ(stop(bearer(kToken), "10.0.0.1").result(), http::status::ok);
  // Three unknown tokens lock 10.0.0.1 out; even the right token gets 429.
  for (const char* bad : {kNearToken, "x", kNearToken}) {
    EXPECT_EQ(stop(bearer(bad), "10.0.0.1").result(), http::status::unauthorized);
  }
  const auto locked = stop(bearer(kToken), "10.0.0.1");
  EXPECT_EQ(locked.result(), http::status::too_many_requests);
  EXPECT_EQ(locked[http::field::retry_after], "60");
  EXPECT_EQ(locked.body().find(kToken), std::string::npos);
  wall.advance(45.0);
  EXPECT_EQ(stop(bearer(kToken), "10.0.0.1")[http::field::retry_after], "15");
  EXPECT_EQ(control.calls.size(), 1u) << "only the one good request reached the station";
  // Others are not affected, nor open reads of the locked-out peer.
  EXPECT_EQ(stop(bearer(kToken), "10.0.0.2").result(), http::status::ok);
  EXPECT_EQ(handle_api_request(request(http::verb::get, "/api/v1/status", "", ""), ctx, "10.0.0.1")
                .result(),
            http::status::ok);
  // In token mode its reads need a token, so they are throttled too.
  ctx.reads_need_token = true;
  EXPECT_EQ(handle_api_request(request(http::verb::get, "/api/v1/status", "", bearer(kReadToken)),
                               ctx, "10.0.0.1")
                .result(),
            http::status::too_many_requests);
  EXPECT_EQ(
      handle_api_request(request(http::verb::get, "/healthz", "", ""), ctx, "10.0.0.1").result(),
      http::status::ok);
  wall.advance(15.0);
  EXPECT_EQ(stop(bearer(kToken), "10.0.0.1").result(), http::status::ok) << "the window passed";
}

// The server hands each handler the client's address, and asks the stream
// gate before a stream starts.
TEST(HttpServer, PassesThePeerAddressAndGatesTheStream) {
  EventStream stream({});
  std::mutex mu;
  std::vector<std::string> peers;
  HttpServerOptions options;
  options.port = 0;
  options.stream = &stream;
  options.stream_gate = [&](const HttpRequest& req,
                            std::string_view peer) -> std::optional<HttpResponse> {
    std::lock_guard lock(mu);
    peers.push_back(fmt::format("gate {}", peer));
    return error_response(req, http::status::unauthorized, "no");
  };
  auto server = HttpServer::create(options, [&](const HttpRequest& req, std::string_view peer) {
    std::lock_guard lock(mu);
    peers.push_back(std::string(peer));
    return json_response(req, http::status::ok, "{}");
  });
  ASSERT_TRUE(server.ok()) << server.error().message;
  (*server)->start();
  const std::string base = fmt::format("http://127.0.0.1:{}", (*server)->port());
  auto ok = http_request("GET", base + "/api/v1/status");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  auto refused = http_request("GET", base + "/api/v1/stream");
  ASSERT_TRUE(refused.ok()) << refused.error().message;
  EXPECT_EQ(refused->status, 401);
  (*server)->stop();
  std::lock_guard lock(mu);
  EXPECT_EQ(peers, (std::vector<std::string>{"127.0.0.1", "gate 127.0.0.1"}));
  EXPECT_EQ(stream.clients(), 0);
}

// RFC 9110 §11.1: the authentication scheme is case-insensitive, and one or
// more spaces separate it from the credentials. "bearer TOKEN" was refused.
TEST(Api, TheBearerSchemeIsCaseInsensitive) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  for (const char* scheme : {"Bearer ", "bearer ", "BEARER ", "bEaReR ", "Bearer   "}) {
    const auto res = handle_api_request(
        request(http::verb::post, "/api/v1/control/stop", "", std::string(scheme) + kToken), ctx);
    EXPECT_EQ(res.result(), http::status::ok) << "'" << scheme << "': " << res.body();
  }
  EXPECT_EQ(control.calls.size(), 5u);
  // Still refused: another scheme, a scheme glued to the token, no token.
  for (const std::string& auth :
       {std::string("Basic ") + kToken, std::string("bearer") + kToken,
        std::string("xbearer ") + kToken, std::string("bearer "), std::string("bearer")}) {
    const auto res =
        handle_api_request(request(http::verb::post, "/api/v1/control/stop", "", auth), ctx);
    EXPECT_EQ(res.result(), http::status::unauthorized) << "'" << auth << "'";
  }
  EXPECT_EQ(control.calls.size(), 5u);
}

// One request over a fresh loopback connection; the status code of the
// answer, 0 when none came within 5 s.
int status_of_raw_request(int port, const std::string& request) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0 ||
      ::send(fd, request.data(), request.size(), MSG_NOSIGNAL) !=
          static_cast<ssize_t>(request.size())) {
    ::close(fd);
    return 0;
  }
  std::string text;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (text.find("\r\n") == std::string::npos && std::chrono::steady_clock::now() < deadline) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 50) <= 0) continue;
    char buf[4096];
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n <= 0) break;
    text.append(buf, static_cast<std::size_t>(n));
  }
  ::close(fd);
  int status = 0;
  std::sscanf(text.c_str(), "HTTP/1.%*1d %3d", &status);
  return status;
}

// RFC 9112 §3.2: an HTTP/1.1 request without Host, with two, or with one
// that is not a valid host gets 400, and the handler never sees it. An
// HTTP/1.0 request may leave Host out. Every request used to get 200.
TEST(HttpServer, HostIsRequiredOnHttp11) {
  HttpServerOptions options;
  options.port = 0;
  std::atomic<int> handled{0};
  auto server = HttpServer::create(options, [&](const HttpRequest& req) {
    ++handled;
    return json_response(req, http::status::ok, "{}");
  });
  ASSERT_TRUE(server.ok()) << server.error().message;
  (*server)->start();
  const int port = (*server)->port();
  auto status = [&](const std::string& head) {
    return status_of_raw_request(port, head + "Connection: close\r\n\r\n");
  };
  EXPECT_EQ(status("GET /api/v1/status HTTP/1.1\r\nHost: 127.0.0.1:8080\r\n"), 200);
  EXPECT_EQ(status("GET /api/v1/status HTTP/1.1\r\nhost: [::1]:8080\r\n"), 200);
  EXPECT_EQ(status("GET /api/v1/status HTTP/1.0\r\n"), 200);
  EXPECT_EQ(handled.load(), 3);
  EXPECT_EQ(status("GET /api/v1/status HTTP/1.1\r\n"), 400);
  EXPECT_EQ(status("GET /api/v1/status HTTP/1.1\r\nHost: a\r\nHost: b\r\n"), 400);
  EXPECT_EQ(status("GET /api/v1/status HTTP/1.1\r\nHost: a b\r\n"), 400);
  EXPECT_EQ(status("GET /api/v1/status HTTP/1.1\r\nHost: a/b\r\n"), 400);
  EXPECT_EQ(status("GET /api/v1/stream HTTP/1.1\r\n"), 400);
  EXPECT_EQ(handled.load(), 3) << "the handler saw a request without a valid Host";
}

// The CLI's and the dashboard's client sends Host (it is what the server
// now requires).
TEST(HttpServer, TheClientSendsHost) {
  HttpServerOptions options;
  options.port = 0;
  std::mutex mu;
  std::string host;
  auto server = HttpServer::create(options, [&](const HttpRequest& req) {
    std::lock_guard lock(mu);
    host = std::string(req[http::field::host]);
    return json_response(req, http::status::ok, "{}");
  });
  ASSERT_TRUE(server.ok()) << server.error().message;
  (*server)->start();
  const auto res = http_request(
      "GET", fmt::format("http://127.0.0.1:{}/api/v1/status", (*server)->port()), "", "");
  ASSERT_TRUE(res.ok()) << res.error().message;
  EXPECT_EQ(res->status, 200);
  std::lock_guard lock(mu);
  EXPECT_EQ(host, fmt::format("127.0.0.1:{}", (*server)->port()));
}

// ---------------------------------------------------------------- run metadata and DUTs

TEST(Api, QueueMetadataReachesTheStation) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  const auto res = handle_api_request(
      request(http::verb::post, "/api/v1/queue",
              R"({"schedule_toml":"x","operator":"Ana Müller","comment":"re-spliced\nfibre",)"
              R"("tags":["campaign-7","week 1"],"duts":["17-0042","17-0050"]})"),
      ctx);
  EXPECT_EQ(res.result(), http::status::created) << res.body();
  ASSERT_EQ(control.calls.size(), 1u);
  EXPECT_EQ(control.calls[0],
            "enqueue x  false op=Ana Müller comment=re-spliced\nfibre tags=[campaign-7|week 1] "
            "duts=[17-0042|17-0050]");
  // A serial the station has not configured: 400 naming it, nothing queued.
  const auto unknown = handle_api_request(
      request(http::verb::post, "/api/v1/queue", R"({"schedule_toml":"x","duts":["nope"]})"), ctx);
  EXPECT_EQ(unknown.result(), http::status::bad_request);
  EXPECT_NE(unknown.body().find("no DUT with serial 'nope'"), std::string::npos) << unknown.body();
  EXPECT_NE(unknown.body().find("field 'duts'"), std::string::npos) << unknown.body();
}

// The `error` of an error response ("" when there is none).
std::string error_of(const HttpResponse& res) {
  const auto j = nlohmann::json::parse(res.body(), nullptr, false);
  return j.is_object() && j.contains("error") && j["error"].is_string()
             ? j["error"].get<std::string>()
             : std::string();
}

// The limits of control.h, on both routes that take metadata; nothing
// reaches the station.
TEST(Api, MetadataFieldsAre400NamingTheFieldAndTheItem) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  const auto quoted = [](const std::string& s) { return nlohmann::json(s).dump(); };
  const auto list = [](std::size_t n, std::size_t chars) {
    nlohmann::json a = nlohmann::json::array();
    for (std::size_t i = 0; i < n; ++i) a.push_back(fmt::format("{:0>{}}", i, chars));
    return a.dump();
  };
  struct Case {
    std::string fields;  // JSON members, without braces
    std::string message;
  };
  const std::vector<Case> cases = {
      {R"("operator":5)", "field 'operator' must be a string"},
      {R"("operator":)" + quoted(std::string(129, 'a')),
       "field 'operator' is 129 characters long (at most 128)"},
      {R"("operator":"two\nlines")", "field 'operator' contains the control character U+000A"},
      {R"("comment":)" + quoted(std::string(4097, 'c')),
       "field 'comment' is 4097 characters long (at most 4096)"},
      {R"("comment":"bell\u0007")", "field 'comment' contains the control character U+0007"},
      {R"("tags":"a,b")", "field 'tags' must be an array of tags"},
      {R"("tags":)" + list(33, 2), "field 'tags' has 33 tags (strings) (at most 32)"},
      {R"("tags":)" + list(1, 65), "field 'tags'[0] is 65 characters long (at most 64)"},
      {R"("tags":["ok",7])", "field 'tags'[1] must be a string"},
      {R"("tags":["a","b","a"])", "field 'tags'[2]: \"a\" is listed twice"},
      {R"("tags":[""])", "field 'tags'[0] is empty"},
      {R"("duts":["17-0042",3])", "field 'duts'[1] must be a string"},
      {R"("duts":)" + list(17, 3), "field 'duts' has 17 DUT serials (strings) (at most 16)"},
      {R"("duts":[)" + quoted(std::string(65, 's')) + "]",
       "field 'duts'[0] is 65 characters long (at most 64)"},
      {R"("operators":"ana")", "unknown field 'operators'"},
  };
  for (const Case& c : cases) {
    const auto post = handle_api_request(
        request(http::verb::post, "/api/v1/queue", R"({"schedule_toml":"x",)" + c.fields + "}"),
        ctx);
    EXPECT_EQ(post.result(), http::status::bad_request) << c.fields;
    EXPECT_NE(error_of(post).find(c.message), std::string::npos)
        << c.fields << " -> " << post.body();
    const auto patch =
        handle_api_request(request(http::verb::patch, "/api/v1/runs/3", "{" + c.fields + "}"), ctx);
    EXPECT_EQ(patch.result(), http::status::bad_request) << c.fields;
    EXPECT_NE(error_of(patch).find(c.message), std::string::npos)
        << c.fields << " -> " << patch.body();
  }
  EXPECT_TRUE(control.calls.empty());
  // At the limits, counted in characters (é is two bytes): accepted.
  std::string e128;
  for (int i = 0; i < 128; ++i) e128 += "é";
  const auto limits = handle_api_request(
      request(http::verb::post, "/api/v1/queue",
              R"({"schedule_toml":"x","operator":)" + quoted(e128) + R"(,"tags":)" + list(32, 64) +
                  R"(,"comment":"tab\there\nand a new line"})"),
      ctx);
  EXPECT_EQ(limits.result(), http::status::created) << limits.body();
}

TEST(Api, RunMetadataEditNeedsTheControlTokenAndAField) {
  FakeControl control;
  const ApiContext ctx = two_role_context(&control);
  const std::string body = R"({"operator":"bo","tags":["a"],"duts":[]})";
  EXPECT_EQ(
      handle_api_request(request(http::verb::patch, "/api/v1/runs/3", body, ""), ctx).result(),
      http::status::unauthorized);
  EXPECT_EQ(handle_api_request(
                request(http::verb::patch, "/api/v1/runs/3", body, bearer(kReadToken)), ctx)
                .result(),
            http::status::forbidden);
  EXPECT_TRUE(control.calls.empty());
  const auto empty = handle_api_request(request(http::verb::patch, "/api/v1/runs/3", "{}"), ctx);
  EXPECT_EQ(empty.result(), http::status::bad_request);
  EXPECT_NE(empty.body().find("nothing to change"), std::string::npos) << empty.body();
  EXPECT_TRUE(control.calls.empty());

  EXPECT_EQ(handle_api_request(request(http::verb::patch, "/api/v1/runs/3", body), ctx).result(),
            http::status::ok);
  EXPECT_EQ(
      handle_api_request(request(http::verb::patch, "/api/v1/runs/8", R"({"comment":""})"), ctx)
          .result(),
      http::status::not_found);
  EXPECT_EQ(control.calls, (std::vector<std::string>{
                               "edit_run 3 op=bo comment=(same) tags=[a] duts=[] by api",
                               "edit_run 8 op=(same) comment= tags=(same) duts=(same) by api"}));
  EXPECT_EQ(handle_api_request(request(http::verb::put, "/api/v1/runs/3", body), ctx).result(),
            http::status::method_not_allowed);
}

TEST(Api, DutRoutesDecodeTheSerialAndName404s) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  EXPECT_EQ(handle_api_request(get("/api/v1/duts"), ctx).result(), http::status::ok);
  EXPECT_EQ(handle_api_request(get("/api/v1/duts/17-0042"), ctx).result(), http::status::ok);
  EXPECT_EQ(handle_api_request(get("/api/v1/duts/SN%2017%2F42"), ctx).result(), http::status::ok);
  EXPECT_EQ(handle_api_request(get("/api/v1/duts/a+b"), ctx).result(), http::status::ok);
  const auto unknown = handle_api_request(get("/api/v1/duts/17-0043"), ctx);
  EXPECT_EQ(unknown.result(), http::status::not_found);
  EXPECT_NE(unknown.body().find("no DUT with serial '17-0043'"), std::string::npos);
  EXPECT_EQ(control.calls, (std::vector<std::string>{"duts", "dut 17-0042", "dut SN 17/42",
                                                     "dut a+b", "dut 17-0043"}));
  control.calls.clear();
  for (const std::string& target :
       {"/api/v1/duts/" + std::string(65, 's'), std::string("/api/v1/duts/%zz")}) {
    EXPECT_EQ(handle_api_request(get(target), ctx).result(), http::status::not_found) << target;
  }
  EXPECT_TRUE(control.calls.empty());

  // A serial that is not UTF-8 (found by the http fuzz target: the reply
  // quoting it threw from the JSON writer and ended the process): answered
  // in valid JSON, the bad byte shown as U+FFFD.
  const auto bad = handle_api_request(get("/api/v1/duts/SN%201\x92"
                                          "7-0042"),
                                      ctx);
  EXPECT_EQ(bad.result(), http::status::ok);
  const auto body = nlohmann::json::parse(bad.body(), nullptr, false);
  ASSERT_FALSE(body.is_discarded()) << bad.body();
  EXPECT_EQ(body.value("serial", ""),
            "SN 1\xEF\xBF\xBD"
            "7-0042")
      << bad.body();
}

TEST(Api, StatsAndSamplesTakeTheDutAndItsAxisOrChannel) {
  FakeControl control;
  const ApiContext ctx = fake_context(&control);
  EXPECT_EQ(handle_api_request(get("/api/v1/runs/12/stats?dut=17-0042&axis=z"), ctx).result(),
            http::status::ok);
  EXPECT_EQ(handle_api_request(get("/api/v1/runs/12/stats?axis=x"), ctx).result(),
            http::status::ok);
  const auto no_dut = handle_api_request(get("/api/v1/runs/12/stats?dut=17-0099"), ctx);
  EXPECT_EQ(no_dut.result(), http::status::not_found);
  EXPECT_NE(no_dut.body().find("no DUT '17-0099'"), std::string::npos) << no_dut.body();
  EXPECT_EQ(handle_api_request(
                get("/api/v1/runs/4/samples?dut=SN%2017&channel=accel_x&max_points=10"), ctx)
                .result(),
            http::status::ok);
  const auto no_channel = handle_api_request(get("/api/v1/runs/4/samples?channel=nope"), ctx);
  EXPECT_EQ(no_channel.result(), http::status::not_found);
  EXPECT_NE(no_channel.body().find("no channel 'nope'"), std::string::npos);
  EXPECT_EQ(control.calls,
            (std::vector<std::string>{"stats 12 dut=17-0042 axis=z", "stats 12 dut= axis=x",
                                      "stats 12 dut=17-0099 axis=",
                                      "samples 4 0 last 10 dut=SN 17 "
                                      "channel=accel_x",
                                      "samples 4 0 last 2000 dut= channel=nope"}));
  control.calls.clear();
  const auto bad = handle_api_request(get("/api/v1/runs/12/stats?axes=z"), ctx);
  EXPECT_EQ(bad.result(), http::status::bad_request);
  EXPECT_NE(bad.body().find("unknown query parameter 'axes' (expected: dut, axis)"),
            std::string::npos)
      << bad.body();
  EXPECT_TRUE(control.calls.empty());
}

}  // namespace
}  // namespace gyrotherm::api
