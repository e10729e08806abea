#include "gyrotherm/daemon/api.h"

#include <fmt/format.h>

#include <charconv>
#include <optional>

namespace gyrotherm::daemon {

namespace http = boost::beast::http;

namespace {

constexpr std::string_view kPrefix = "/api/v1/";

// Splits "/api/v1/a/b/c" into {"a", "b", "c"}.
std::vector<std::string_view> path_parts(std::string_view path) {
  std::vector<std::string_view> parts;
  path.remove_prefix(kPrefix.size());
  while (!path.empty()) {
    const auto slash = path.find('/');
    parts.push_back(path.substr(0, slash));
    if (slash == std::string_view::npos) break;
    path.remove_prefix(slash + 1);
  }
  return parts;
}

std::optional<int64_t> parse_id(std::string_view s) {
  int64_t v = 0;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || ptr != s.data() + s.size() || v <= 0) return std::nullopt;
  return v;
}

HttpResponse reply_response(const HttpRequest& req, const Reply& reply,
                            http::status ok_status = http::status::ok) {
  if (!reply.refusal) return json_response(req, ok_status, reply.body.dump());
  const Refusal& r = *reply.refusal;
  http::status status = http::status::unprocessable_entity;
  switch (r.kind) {
    case Refusal::Kind::kNotFound:
      status = http::status::not_found;
      break;
    case Refusal::Kind::kConflict:
      status = http::status::conflict;
      break;
    case Refusal::Kind::kInvalid:
      status = http::status::unprocessable_entity;
      break;
    case Refusal::Kind::kUnavailable:
      status = http::status::service_unavailable;
      break;
  }
  nlohmann::json body = {{"error", r.message}};
  if (!r.details.empty()) body["errors"] = r.details;
  return json_response(req, status, body.dump());
}

// The request body as a JSON object with only `allowed` fields, or a 400.
struct Body {
  nlohmann::json json = nlohmann::json::object();
  std::optional<HttpResponse> error;
};

Body parse_body(const HttpRequest& req, std::initializer_list<std::string_view> allowed) {
  Body b;
  if (req.body().empty()) return b;
  try {
    b.json = nlohmann::json::parse(req.body());
  } catch (const nlohmann::json::parse_error& e) {
    b.error = error_response(req, http::status::bad_request,
                             fmt::format("body is not JSON: {}", e.what()));
    return b;
  }
  if (!b.json.is_object()) {
    b.error = error_response(req, http::status::bad_request, "body must be a JSON object");
    return b;
  }
  for (const auto& [key, value] : b.json.items()) {
    if (std::find(allowed.begin(), allowed.end(), key) == allowed.end()) {
      std::string known;
      for (auto a : allowed) known += fmt::format("{}{}", known.empty() ? "" : ", ", a);
      b.error = error_response(req, http::status::bad_request,
                               fmt::format("unknown field '{}' (expected: {})", key, known));
      return b;
    }
  }
  return b;
}

// Field `key` of type T if present; a 400 naming the field when mistyped.
template <class T>
std::optional<T> field(Body& b, const HttpRequest& req, const char* key, const char* type) {
  if (b.error || !b.json.contains(key)) return std::nullopt;
  const auto& v = b.json[key];
  const bool ok = [&] {
    if constexpr (std::is_same_v<T, bool>) return v.is_boolean();
    if constexpr (std::is_same_v<T, std::string>) return v.is_string();
    if constexpr (std::is_integral_v<T>) return v.is_number_integer();
    return false;
  }();
  if (!ok) {
    b.error = error_response(req, http::status::bad_request,
                             fmt::format("field '{}' must be {}", key, type));
    return std::nullopt;
  }
  return v.get<T>();
}

// 401/403 unless the request carries a configured token.
std::optional<HttpResponse> check_token(const HttpRequest& req, const ApiContext& ctx) {
  if (ctx.tokens.empty()) {
    return error_response(req, http::status::forbidden,
                          "changes are disabled: no token in [api] tokens of the station config");
  }
  const auto it = req.find(http::field::authorization);
  std::string_view presented;
  if (it != req.end()) {
    std::string_view value(it->value().data(), it->value().size());
    constexpr std::string_view kBearer = "Bearer ";
    if (value.size() > kBearer.size() && value.substr(0, kBearer.size()) == kBearer) {
      presented = value.substr(kBearer.size());
    }
  }
  if (presented.empty() || !token_matches(presented, ctx.tokens)) {
    HttpResponse res =
        error_response(req, http::status::unauthorized,
                       presented.empty() ? "this request needs Authorization: Bearer TOKEN"
                                         : "the token is not one of the station's tokens");
    res.set(http::field::www_authenticate, "Bearer");
    return res;
  }
  return std::nullopt;
}

HttpResponse method_not_allowed(const HttpRequest& req, std::string_view allowed) {
  HttpResponse res =
      error_response(req, http::status::method_not_allowed, fmt::format("use {}", allowed));
  res.set(http::field::allow, boost::beast::string_view(allowed.data(), allowed.size()));
  return res;
}

}  // namespace

bool token_matches(std::string_view presented, const std::vector<std::string>& tokens) {
  bool any = false;
  for (const auto& token : tokens) {
    // Every byte of the presented token is compared, whatever the outcome.
    unsigned diff = presented.size() == token.size() ? 0u : 1u;
    for (std::size_t i = 0; i < presented.size(); ++i) {
      const unsigned char t =
          token.empty() ? 0 : static_cast<unsigned char>(token[i % token.size()]);
      diff |= static_cast<unsigned>(static_cast<unsigned char>(presented[i]) ^ t);
    }
    any |= diff == 0;
  }
  return any;
}

HttpResponse handle_api_request(const HttpRequest& req, const ApiContext& ctx) {
  std::string_view target(req.target().data(), req.target().size());
  if (const auto q = target.find('?'); q != std::string_view::npos) target = target.substr(0, q);
  const auto method = req.method();
  const bool get = method == http::verb::get || method == http::verb::head;
  const bool post = method == http::verb::post;
  const bool del = method == http::verb::delete_;

  if (target == "/healthz") {
    if (!get) return method_not_allowed(req, "GET");
    return json_response(req, http::status::ok, R"({"ok":true})");
  }
  if (target == "/api/v1/status") {
    if (!get) return method_not_allowed(req, "GET");
    return json_response(req, http::status::ok, to_json(ctx.status()).dump());
  }
  if (target.substr(0, kPrefix.size()) != kPrefix) {
    return error_response(req, http::status::not_found, "no such resource: " + std::string(target));
  }
  const auto parts = path_parts(target);
  auto not_found = [&] {
    return error_response(req, http::status::not_found, "no such resource: " + std::string(target));
  };
  if (parts.empty()) return not_found();
  auto need_control = [&]() -> std::optional<HttpResponse> {
    if (ctx.control) return std::nullopt;
    return error_response(req, http::status::service_unavailable, "no station attached");
  };

  // /queue, /queue/{id}, /queue/{id}/move
  if (parts[0] == "queue") {
    if (parts.size() == 1) {
      if (get) {
        if (auto e = need_control()) return *e;
        return reply_response(req, ctx.control->queue_list());
      }
      if (!post) return method_not_allowed(req, "GET, POST");
      if (auto denied = check_token(req, ctx)) return *denied;
      if (auto e = need_control()) return *e;
      Body body = parse_body(req, {"schedule_toml", "source", "ignore_failures"});
      auto toml = field<std::string>(body, req, "schedule_toml", "a string (the schedule file)");
      auto source = field<std::string>(body, req, "source", "a string");
      auto ignore = field<bool>(body, req, "ignore_failures", "true or false");
      if (body.error) return *body.error;
      if (!toml) {
        return error_response(req, http::status::bad_request,
                              "field 'schedule_toml' is required (the schedule file's text)");
      }
      return reply_response(
          req, ctx.control->queue_add(*toml, source.value_or(""), ignore.value_or(false)),
          http::status::created);
    }
    const auto id = parse_id(parts[1]);
    if (!id) return error_response(req, http::status::not_found, "queue ids are positive integers");
    if (parts.size() == 2) {
      if (!del) return method_not_allowed(req, "DELETE");
      if (auto denied = check_token(req, ctx)) return *denied;
      if (auto e = need_control()) return *e;
      return reply_response(req, ctx.control->queue_remove(*id));
    }
    if (parts.size() == 3 && parts[2] == "move") {
      if (!post) return method_not_allowed(req, "POST");
      if (auto denied = check_token(req, ctx)) return *denied;
      if (auto e = need_control()) return *e;
      Body body = parse_body(req, {"position"});
      auto pos = field<int64_t>(body, req, "position", "an integer (0 = next)");
      if (body.error) return *body.error;
      if (!pos)
        return error_response(req, http::status::bad_request, "field 'position' is required");
      if (*pos < 0) {
        return error_response(req, http::status::bad_request, "field 'position' must be >= 0");
      }
      return reply_response(
          req, ctx.control->queue_move(*id, static_cast<int>(std::min<int64_t>(*pos, 1 << 20))));
    }
    return not_found();
  }

  // /control/{action}
  if (parts[0] == "control" && parts.size() == 2) {
    const std::string_view action = parts[1];
    if (action != "pause" && action != "resume" && action != "abort" && action != "stop") {
      return not_found();
    }
    if (!post) return method_not_allowed(req, "POST");
    if (auto denied = check_token(req, ctx)) return *denied;
    if (auto e = need_control()) return *e;
    Body body = parse_body(req, {"reason"});
    auto reason = field<std::string>(body, req, "reason", "a string");
    if (body.error) return *body.error;
    return reply_response(req, ctx.control->control(action, reason.value_or("")));
  }

  // /runs, /runs/{id}, /runs/{id}/events, /runs/{id}/stats
  if (parts[0] == "runs") {
    if (!get) return method_not_allowed(req, "GET");
    if (auto e = need_control()) return *e;
    if (parts.size() == 1) return reply_response(req, ctx.control->runs());
    const auto id = parse_id(parts[1]);
    if (!id) return error_response(req, http::status::not_found, "run ids are positive integers");
    if (parts.size() == 2) return reply_response(req, ctx.control->run(*id));
    if (parts.size() == 3 && parts[2] == "events") {
      return reply_response(req, ctx.control->run_events(*id));
    }
    if (parts.size() == 3 && parts[2] == "stats") {
      return reply_response(req, ctx.control->run_stats(*id));
    }
  }
  return not_found();
}

}  // namespace gyrotherm::daemon
