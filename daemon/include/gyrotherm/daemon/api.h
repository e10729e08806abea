// The REST API (DESIGN.md §9, docs/api.md) as a pure function from request
// to response.
//
// One table of routes (api_routes() lists it; daemon/openapi.json describes
// it and a test keeps the two equal): status, the queue, operator controls,
// run records and decimated samples, fits, /metrics, /healthz, the OpenAPI
// document and the dashboard's files. GET /api/v1/stream is answered by the
// HTTP server's EventStream (http_server.h).
//
// Every POST and DELETE needs "Authorization: Bearer TOKEN" with one of the
// configured tokens (compared in constant time; never logged or echoed):
// missing or wrong -> 401 and nothing changes; no token configured -> 403.
// Bad JSON, unknown fields and wrong types -> 400 naming the field. Unknown
// paths -> 404, known paths with another method -> 405.
#pragma once

#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/daemon/control.h"
#include "gyrotherm/daemon/http_server.h"
#include "gyrotherm/daemon/status.h"
#include "gyrotherm/daemon/web_assets.h"

namespace gyrotherm::daemon {

struct ApiContext {
  std::function<StatusSnapshot()> status;
  StationControl* control = nullptr;     // nullptr: control and record routes answer 503
  std::vector<std::string> tokens;       // [api] tokens
  std::function<std::string()> metrics;  // Prometheus text; nullptr: /metrics answers 503
  const WebAssets* web = nullptr;        // the dashboard; nullptr: / answers 404
};

HttpResponse handle_api_request(const HttpRequest& req, const ApiContext& ctx);

// Every (method, path template) served, e.g. {"GET", "/api/v1/runs/{id}"};
// HEAD is served wherever GET is and not listed. docs: daemon/openapi.json.
struct RouteInfo {
  std::string method;
  std::string path;
};
std::vector<RouteInfo> api_routes();

// The OpenAPI 3 document (daemon/openapi.json, embedded at build time).
std::string_view openapi_document();

// True when `presented` equals one of `tokens`. Takes the same time for any
// presented token of a given length, whichever token (if any) matches.
bool token_matches(std::string_view presented, const std::vector<std::string>& tokens);

}  // namespace gyrotherm::daemon
