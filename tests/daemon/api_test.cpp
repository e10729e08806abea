#include "gyrotherm/daemon/api.h"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "gyrotherm/daemon/http_client.h"
#include "gyrotherm/daemon/http_server.h"

namespace gyrotherm::daemon {
namespace {

namespace http = boost::beast::http;

HttpRequest get(std::string target, http::verb verb = http::verb::get) {
  HttpRequest req{verb, target, 11};
  return req;
}

ApiContext fake_context() {
  return ApiContext{[] {
    StatusSnapshot s;
    s.station_name = "test";
    s.state = "acquiring";
    s.run_id = 7;
    s.chamber_c = 20.25;
    s.gyro_rate_dph = 7.95;
    s.gyro.parser.crc_failures = 3;
    return s;
  }};
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

}  // namespace
}  // namespace gyrotherm::daemon
