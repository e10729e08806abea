#include "gyrotherm/daemon/api.h"

namespace gyrotherm::daemon {

namespace http = boost::beast::http;

HttpResponse handle_api_request(const HttpRequest& req, const ApiContext& ctx) {
  std::string_view target(req.target().data(), req.target().size());
  if (const auto q = target.find('?'); q != std::string_view::npos) target = target.substr(0, q);
  const bool get = req.method() == http::verb::get || req.method() == http::verb::head;

  if (target == "/api/v1/status") {
    if (!get) return error_response(req, http::status::method_not_allowed, "use GET");
    return json_response(req, http::status::ok, to_json(ctx.status()).dump());
  }
  if (target == "/healthz") {
    if (!get) return error_response(req, http::status::method_not_allowed, "use GET");
    return json_response(req, http::status::ok, R"({"ok":true})");
  }
  return error_response(req, http::status::not_found, "no such resource: " + std::string(target));
}

}  // namespace gyrotherm::daemon
