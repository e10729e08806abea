// The REST API (DESIGN.md §9) as a pure function from request to response.
//
// Served now: GET /api/v1/status, GET /healthz. Unknown paths get 404 with a
// JSON error, known paths with another method 405.
#pragma once

#include <functional>

#include "gyrotherm/daemon/http_server.h"
#include "gyrotherm/daemon/status.h"

namespace gyrotherm::daemon {

struct ApiContext {
  std::function<StatusSnapshot()> status;
};

HttpResponse handle_api_request(const HttpRequest& req, const ApiContext& ctx);

}  // namespace gyrotherm::daemon
