// The REST API (docs/api.md) as a pure function from request
// to response.
//
// One table of routes (api_routes() lists it; daemon/api/openapi.json describes
// it and a test keeps the two equal): status, the queue, operator controls,
// run records and decimated samples, fits, /metrics, /healthz, the OpenAPI
// document and the dashboard's files. GET /api/v1/stream is answered by the
// HTTP server's EventStream (http_server.h).
//
// Access (docs/api.md, "Access"): every POST, PATCH and DELETE needs
// "Authorization: Bearer TOKEN" with a control token ([api] tokens): missing
// or unknown -> 401 with WWW-Authenticate, a read token ([api] read_tokens)
// -> 403, no control token configured -> 403; nothing reaches the station.
// With reads_need_token, every GET under /api/v1 and /metrics needs a read or
// control token too (401 otherwise); /healthz and the dashboard's files stay
// open. Tokens are compared in constant time and never logged or echoed. A
// peer that presented too many unknown tokens gets 429 with Retry-After on
// whatever needs a token (AuthLimiter). Bad JSON, unknown fields and wrong types -> 400 naming the
// field. Unknown paths -> 404, known paths with another method -> 405.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/api/auth_limiter.h"
#include "gyrotherm/api/body_cache.h"
#include "gyrotherm/api/http_server.h"
#include "gyrotherm/api/web_assets.h"
#include "gyrotherm/station/control.h"
#include "gyrotherm/station/status.h"

namespace gyrotherm::api {

struct ApiContext {
  std::function<station::StatusSnapshot()> status;
  station::StationControl* control = nullptr;  // nullptr: control and record routes answer 503
  std::vector<std::string> tokens;             // [api] tokens: may read and change
  std::vector<std::string> read_tokens;        // [api] read_tokens: may read only
  bool reads_need_token = false;               // [api] read_access = "token"
  AuthLimiter* auth_limiter = nullptr;         // not owned; nullptr: no throttling
  std::function<std::string()> metrics;        // Prometheus text; nullptr: /metrics answers 503
  const WebAssets* web = nullptr;              // the dashboard; nullptr: / answers 404
  // Not owned. When set, /api/v1/status (/metrics) serves this cache's body
  // instead of rendering `status` (`metrics`) for every request; every
  // control request invalidates the status's.
  BodyCache* status_body = nullptr;
  BodyCache* metrics_body = nullptr;
};

// `peer` is the client's address (as HttpServer passes it): the key of the
// failed-authentication throttling.
HttpResponse handle_api_request(const HttpRequest& req, const ApiContext& ctx,
                                std::string_view peer = {});

// The access check alone, for routes answered outside handle_api_request
// (the event stream): the refusal (401, 403, 429), or nullopt when `req` may
// go on. Unknown paths pass (they get their 404 elsewhere).
std::optional<HttpResponse> check_access(const HttpRequest& req, const ApiContext& ctx,
                                         std::string_view peer = {});

// Every (method, path template) served, e.g. {"GET", "/api/v1/runs/{id}"};
// HEAD is served wherever GET is and not listed. docs: daemon/api/openapi.json.
struct RouteInfo {
  std::string method;
  std::string path;
};
std::vector<RouteInfo> api_routes();

// The OpenAPI 3 document (daemon/api/openapi.json, embedded at build time).
std::string_view openapi_document();

// What a presented token may do: kControl when it equals one of
// `control_tokens`, kRead when one of `read_tokens`, else kNone. Compares it
// with every token of both lists, every byte of it each time: the time taken
// depends on the presented token's length and the lists, not on which token
// (if any) matches or how much of one it shares.
enum class TokenRole { kNone, kRead, kControl };
TokenRole token_role(std::string_view presented, const std::vector<std::string>& control_tokens,
                     const std::vector<std::string>& read_tokens);

// True when `presented` equals one of `tokens` (token_role with no read tokens).
bool token_matches(std::string_view presented, const std::vector<std::string>& tokens);

}  // namespace gyrotherm::api
