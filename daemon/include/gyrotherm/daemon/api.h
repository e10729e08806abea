// The REST API (DESIGN.md §9, docs/api.md) as a pure function from request
// to response.
//
// Served: GET /api/v1/status, GET /healthz; the queue (GET/POST
// /api/v1/queue, DELETE /api/v1/queue/{id}, POST /api/v1/queue/{id}/move);
// POST /api/v1/control/{pause|resume|abort|stop}; GET /api/v1/runs,
// /api/v1/runs/{id}, /api/v1/runs/{id}/events, /api/v1/runs/{id}/stats.
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

namespace gyrotherm::daemon {

struct ApiContext {
  std::function<StatusSnapshot()> status;
  StationControl* control = nullptr;  // nullptr: control and record routes answer 503
  std::vector<std::string> tokens;    // [api] tokens
};

HttpResponse handle_api_request(const HttpRequest& req, const ApiContext& ctx);

// True when `presented` equals one of `tokens`. Takes the same time for any
// presented token of a given length, whichever token (if any) matches.
bool token_matches(std::string_view presented, const std::vector<std::string>& tokens);

}  // namespace gyrotherm::daemon
