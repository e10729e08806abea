// A blocking HTTP/1.1 client for the CLI and tests (Boost.Beast).
#pragma once

#include <chrono>
#include <string>

#include "gyrotherm/core/result.h"

namespace gyrotherm::cli {

struct HttpResult {
  int status = 0;
  std::string body;
  std::string content_type;
};

// `url` like "http://127.0.0.1:8750/api/v1/status" (http only). A token, if
// not empty, is sent as "Authorization: Bearer TOKEN". Errors (transient):
// bad URL, connection refused, timeout (wall).
Result<HttpResult> http_request(const std::string& method, const std::string& url,
                                const std::string& body = "", const std::string& token = "",
                                std::chrono::milliseconds timeout = std::chrono::seconds(5));

}  // namespace gyrotherm::cli
