#include "gyrotherm/api/api.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <nlohmann/json.hpp>
#include <optional>

#include "gyrotherm/api/http_message.h"

namespace gyrotherm::api {

namespace http = boost::beast::http;

namespace {

constexpr double kMaxPoints = 20000;  // samples route: points per request

std::optional<int64_t> parse_id(std::string_view s) {
  int64_t v = 0;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || ptr != s.data() + s.size() || v <= 0) return std::nullopt;
  return v;
}

HttpResponse reply_response(const HttpRequest& req, const station::Reply& reply,
                            http::status ok_status = http::status::ok) {
  if (!reply.refusal) return json_response(req, ok_status, json_text(reply.body));
  const station::Refusal& r = *reply.refusal;
  http::status status = http::status::unprocessable_entity;
  switch (r.kind) {
    case station::Refusal::Kind::kNotFound:
      status = http::status::not_found;
      break;
    case station::Refusal::Kind::kConflict:
      status = http::status::conflict;
      break;
    case station::Refusal::Kind::kInvalid:
      status = http::status::unprocessable_entity;
      break;
    case station::Refusal::Kind::kUnavailable:
      status = http::status::service_unavailable;
      break;
    case station::Refusal::Kind::kBadRequest:
      status = http::status::bad_request;
      break;
  }
  nlohmann::json body = {{"error", r.message}, {"status", static_cast<int>(status)}};
  if (!r.details.empty()) body["errors"] = r.details;
  return json_response(req, status, json_text(body));
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
  } catch (const nlohmann::json::exception& e) {  // parse_error; out_of_range for 1e999
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

// Characters (UTF-8 code points) of `s`; the JSON parser has checked it is
// valid UTF-8.
std::size_t utf8_chars(std::string_view s) {
  return static_cast<std::size_t>(std::count_if(
      s.begin(), s.end(), [](char c) { return (static_cast<unsigned char>(c) & 0xC0) != 0x80; }));
}

// The first control character of `s` (tab and newline allowed when
// `multiline`), or nullopt.
std::optional<unsigned> control_character(std::string_view s, bool multiline) {
  for (char ch : s) {
    const auto c = static_cast<unsigned char>(ch);
    if (multiline && (c == '\n' || c == '\t')) continue;
    if (c < 0x20 || c == 0x7F) return c;
  }
  return std::nullopt;
}

// A string of at most `max_chars` characters without control characters,
// or a 400 naming `where`.
std::optional<std::string> bounded_text(Body& b, const HttpRequest& req, const nlohmann::json& v,
                                        const std::string& where, std::size_t max_chars,
                                        bool multiline) {
  if (b.error) return std::nullopt;
  if (!v.is_string()) {
    b.error = error_response(req, http::status::bad_request,
                             fmt::format("field {} must be a string", where));
    return std::nullopt;
  }
  std::string text = v.get<std::string>();
  if (const std::size_t n = utf8_chars(text); n > max_chars) {
    b.error = error_response(
        req, http::status::bad_request,
        fmt::format("field {} is {} characters long (at most {})", where, n, max_chars));
    return std::nullopt;
  }
  if (auto c = control_character(text, multiline)) {
    b.error = error_response(req, http::status::bad_request,
                             fmt::format("field {} contains the control character U+{:04X}{}",
                                         where, *c, multiline ? "" : " (one line only)"));
    return std::nullopt;
  }
  return text;
}

// An array of at most `max_items` distinct, non-empty strings of at most
// `max_chars` characters each, or a 400 naming the field and the element.
std::optional<std::vector<std::string>> bounded_list(Body& b, const HttpRequest& req,
                                                     const char* key, std::size_t max_items,
                                                     std::size_t max_chars, const char* what) {
  if (b.error || !b.json.contains(key)) return std::nullopt;
  const auto& v = b.json[key];
  if (!v.is_array()) {
    b.error = error_response(req, http::status::bad_request,
                             fmt::format("field '{}' must be an array of {}", key, what));
    return std::nullopt;
  }
  if (v.size() > max_items) {
    b.error = error_response(
        req, http::status::bad_request,
        fmt::format("field '{}' has {} {} (at most {})", key, v.size(), what, max_items));
    return std::nullopt;
  }
  std::vector<std::string> out;
  for (std::size_t i = 0; i < v.size(); ++i) {
    const std::string where = fmt::format("'{}'[{}]", key, i);
    auto item = bounded_text(b, req, v[i], where, max_chars, false);
    if (!item) return std::nullopt;
    if (item->empty()) {
      b.error =
          error_response(req, http::status::bad_request, fmt::format("field {} is empty", where));
      return std::nullopt;
    }
    if (std::find(out.begin(), out.end(), *item) != out.end()) {
      b.error = error_response(req, http::status::bad_request,
                               fmt::format("field {}: \"{}\" is listed twice", where, *item));
      return std::nullopt;
    }
    out.push_back(std::move(*item));
  }
  return out;
}

// The run metadata fields of a body (POST /queue, PATCH /runs/{id}): each
// optional, checked against the limits of control.h.
station::MetadataEdit metadata_fields(Body& b, const HttpRequest& req) {
  station::MetadataEdit m;
  if (b.error) return m;
  if (b.json.contains("operator")) {
    m.operator_name =
        bounded_text(b, req, b.json["operator"], "'operator'", station::kMaxOperatorChars, false);
  }
  if (b.json.contains("comment")) {
    m.comment =
        bounded_text(b, req, b.json["comment"], "'comment'", station::kMaxCommentChars, true);
  }
  m.tags = bounded_list(b, req, "tags", station::kMaxTags, station::kMaxTagChars, "tags (strings)");
  m.dut_serials = bounded_list(b, req, "duts", station::kMaxDutSerials, station::kMaxSerialChars,
                               "DUT serials (strings)");
  return m;
}

HttpResponse method_not_allowed(const HttpRequest& req, std::string_view allowed) {
  HttpResponse res =
      error_response(req, http::status::method_not_allowed, fmt::format("use {}", allowed));
  res.set(http::field::allow, boost::beast::string_view(allowed.data(), allowed.size()));
  return res;
}

}  // namespace

namespace {

// Every byte of `presented` is looked at, whatever the outcome.
bool equal_in_constant_time(std::string_view presented, std::string_view token) {
  unsigned diff = presented.size() == token.size() ? 0u : 1u;
  for (std::size_t i = 0; i < presented.size(); ++i) {
    const unsigned char t = token.empty() ? 0 : static_cast<unsigned char>(token[i % token.size()]);
    diff |= static_cast<unsigned>(static_cast<unsigned char>(presented[i]) ^ t);
  }
  return diff == 0;
}

}  // namespace

TokenRole token_role(std::string_view presented, const std::vector<std::string>& control_tokens,
                     const std::vector<std::string>& read_tokens) {
  bool control = false;
  bool read = false;
  for (const auto& token : control_tokens) control |= equal_in_constant_time(presented, token);
  for (const auto& token : read_tokens) read |= equal_in_constant_time(presented, token);
  if (control) return TokenRole::kControl;
  return read ? TokenRole::kRead : TokenRole::kNone;
}

bool token_matches(std::string_view presented, const std::vector<std::string>& tokens) {
  return token_role(presented, tokens, {}) == TokenRole::kControl;
}

namespace {

using Params = std::vector<std::string_view>;  // the {…} segments of the path, in order
using Handler = HttpResponse (*)(const HttpRequest&, const ApiContext&, const Params&);

// Who may use a route. kRead routes are open unless ctx.reads_need_token.
enum class Access { kOpen, kRead, kControl };

struct Route {
  http::verb method;
  std::string_view path;  // template: "{name}" matches one segment
  Access access;
  bool station;  // needs ctx.control (503 without)
  Handler handle;
};

HttpResponse no_station(const HttpRequest& req) {
  return error_response(req, http::status::service_unavailable, "no station attached");
}

// Percent-decodes a query component ('+' is a space) or, with
// `plus_is_space` false, a path segment; nullopt when malformed.
std::optional<std::string> url_decode(std::string_view s, bool plus_is_space = true) {
  std::string out;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '+' && plus_is_space) {
      out += ' ';
    } else if (s[i] == '%') {
      if (i + 2 >= s.size()) return std::nullopt;
      int v = 0;
      const auto [p, ec] = std::from_chars(s.data() + i + 1, s.data() + i + 3, v, 16);
      if (ec != std::errc() || p != s.data() + i + 3) return std::nullopt;
      out += static_cast<char>(v);
      i += 2;
    } else {
      out += s[i];
    }
  }
  return out;
}

// The query parameters, or a 400 naming the first unknown or malformed one.
struct Query {
  std::vector<std::pair<std::string, std::string>> params;
  std::optional<HttpResponse> error;
  const std::string* find(std::string_view key) const {
    for (const auto& [k, v] : params) {
      if (k == key) return &v;
    }
    return nullptr;
  }
};

Query parse_query(const HttpRequest& req, std::initializer_list<std::string_view> allowed) {
  Query q;
  std::string_view target(req.target().data(), req.target().size());
  const auto mark = target.find('?');
  if (mark == std::string_view::npos) return q;
  std::string_view rest = target.substr(mark + 1);
  while (!rest.empty()) {
    const auto amp = rest.find('&');
    const std::string_view item = rest.substr(0, amp);
    rest = amp == std::string_view::npos ? std::string_view() : rest.substr(amp + 1);
    if (item.empty()) continue;
    const auto eq = item.find('=');
    auto key = url_decode(item.substr(0, eq));
    auto value =
        url_decode(eq == std::string_view::npos ? std::string_view() : item.substr(eq + 1));
    if (!key || !value) {
      q.error = error_response(req, http::status::bad_request,
                               fmt::format("malformed query parameter '{}'", item));
      return q;
    }
    if (std::find(allowed.begin(), allowed.end(), *key) == allowed.end()) {
      std::string known;
      for (auto a : allowed) known += fmt::format("{}{}", known.empty() ? "" : ", ", a);
      q.error = error_response(req, http::status::bad_request,
                               fmt::format("unknown query parameter '{}' (expected: {})", *key,
                                           known.empty() ? "none" : known));
      return q;
    }
    q.params.emplace_back(std::move(*key), std::move(*value));
  }
  return q;
}

// A finite number in [lo, hi], or a 400 naming the parameter.
std::optional<double> number_param(const Query& q, std::optional<HttpResponse>& error,
                                   const HttpRequest& req, std::string_view key, double lo,
                                   double hi) {
  const std::string* v = q.find(key);
  if (!v || error) return std::nullopt;
  double x = 0;
  const auto [p, ec] = std::from_chars(v->data(), v->data() + v->size(), x);
  if (ec != std::errc() || p != v->data() + v->size() || !std::isfinite(x) || x < lo || x > hi) {
    error = error_response(
        req, http::status::bad_request,
        fmt::format("query parameter '{}': \"{}\" is not a number in [{}, {}]", key, *v, lo, hi));
    return std::nullopt;
  }
  return x;
}

HttpResponse text_response(const HttpRequest& req, std::string content_type, std::string body,
                           std::string_view cache = "no-store") {
  HttpResponse res{http::status::ok, req.version()};
  res.set(http::field::server, "gyrothermd");
  res.set(http::field::content_type, content_type);
  res.set(http::field::cache_control, boost::beast::string_view(cache.data(), cache.size()));
  res.keep_alive(req.keep_alive());
  res.body() = std::move(body);
  res.prepare_payload();
  return res;
}

HttpResponse serve_web_file(const HttpRequest& req, const ApiContext& ctx, std::string_view name) {
  const WebAssets::File* f = ctx.web ? ctx.web->find(name) : nullptr;
  if (!f) {
    if (!ctx.web) {
      return error_response(req, http::status::not_found,
                            "the dashboard's files were not found at start-up (see the daemon's "
                            "log; build the gyrotherm_web target or set [api] web_root)");
    }
    return error_response(req, http::status::not_found, fmt::format("no web file '{}'", name));
  }
  HttpResponse res = text_response(req, f->content_type, f->body, "no-cache");
  res.set("X-Content-Type-Options", "nosniff");
  return res;
}

constexpr Route kRoutes[] = {
    {http::verb::get, "/", Access::kOpen, false,
     [](const HttpRequest& req, const ApiContext& ctx, const Params&) {
       return serve_web_file(req, ctx, "index.html");
     }},
    {http::verb::get, "/web/{file}", Access::kOpen, false,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       return serve_web_file(req, ctx, p[0]);
     }},
    {http::verb::get, "/healthz", Access::kOpen, false,
     [](const HttpRequest& req, const ApiContext&, const Params&) {
       return json_response(req, http::status::ok, R"({"ok":true})");
     }},
    {http::verb::get, "/metrics", Access::kRead, false,
     [](const HttpRequest& req, const ApiContext& ctx, const Params&) {
       if (!ctx.metrics && !ctx.metrics_body) {
         return error_response(req, http::status::service_unavailable, "no metrics attached");
       }
       return text_response(req, "text/plain; version=0.0.4; charset=utf-8",
                            ctx.metrics_body ? *ctx.metrics_body->get() : ctx.metrics());
     }},
    {http::verb::get, "/api/v1/openapi.json", Access::kRead, false,
     [](const HttpRequest& req, const ApiContext&, const Params&) {
       return json_response(req, http::status::ok, std::string(openapi_document()));
     }},
    {http::verb::get, "/api/v1/status", Access::kRead, false,
     [](const HttpRequest& req, const ApiContext& ctx, const Params&) {
       if (ctx.status_body) return json_response(req, http::status::ok, *ctx.status_body->get());
       return json_response(req, http::status::ok, json_text(to_json(ctx.status())));
     }},
    // Served by the HTTP server's event stream; reached here only when none
    // is attached.
    {http::verb::get, "/api/v1/stream", Access::kRead, false,
     [](const HttpRequest& req, const ApiContext&, const Params&) {
       return error_response(req, http::status::service_unavailable, "no event stream attached");
     }},
    {http::verb::get, "/api/v1/queue", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params&) {
       return reply_response(req, ctx.control->queue_list());
     }},
    {http::verb::post, "/api/v1/queue", Access::kControl, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params&) {
       Body body = parse_body(req, {"schedule_toml", "source", "ignore_failures", "operator",
                                    "comment", "tags", "duts"});
       auto toml = field<std::string>(body, req, "schedule_toml", "a string (the schedule file)");
       auto source = field<std::string>(body, req, "source", "a string");
       auto ignore = field<bool>(body, req, "ignore_failures", "true or false");
       const station::MetadataEdit metadata = metadata_fields(body, req);
       if (body.error) return *body.error;
       if (!toml) {
         return error_response(req, http::status::bad_request,
                               "field 'schedule_toml' is required (the schedule file's text)");
       }
       station::QueueRequest q;
       q.toml_text = std::move(*toml);
       q.source = source.value_or("");
       q.ignore_failures = ignore.value_or(false);
       q.metadata.operator_name = metadata.operator_name.value_or("");
       q.metadata.comment = metadata.comment.value_or("");
       q.metadata.tags = metadata.tags.value_or(std::vector<std::string>{});
       q.metadata.dut_serials = metadata.dut_serials.value_or(std::vector<std::string>{});
       return reply_response(req, ctx.control->enqueue(q), http::status::created);
     }},
    {http::verb::delete_, "/api/v1/queue/{id}", Access::kControl, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       return reply_response(req, ctx.control->queue_remove(*parse_id(p[0])));
     }},
    {http::verb::post, "/api/v1/queue/{id}/move", Access::kControl, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       Body body = parse_body(req, {"position"});
       auto pos = field<int64_t>(body, req, "position", "an integer (0 = next)");
       if (body.error) return *body.error;
       if (!pos)
         return error_response(req, http::status::bad_request, "field 'position' is required");
       if (*pos < 0) {
         return error_response(req, http::status::bad_request, "field 'position' must be >= 0");
       }
       return reply_response(
           req, ctx.control->queue_move(*parse_id(p[0]),
                                        static_cast<int>(std::min<int64_t>(*pos, 1 << 20))));
     }},
    {http::verb::post, "/api/v1/control/{action}", Access::kControl, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       Body body = parse_body(req, {"reason"});
       auto reason = field<std::string>(body, req, "reason", "a string");
       if (body.error) return *body.error;
       return reply_response(req, ctx.control->control(p[0], reason.value_or("")));
     }},
    {http::verb::get, "/api/v1/runs", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params&) {
       return reply_response(req, ctx.control->runs());
     }},
    {http::verb::get, "/api/v1/runs/{id}", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       return reply_response(req, ctx.control->run_with_duts(*parse_id(p[0])));
     }},
    {http::verb::patch, "/api/v1/runs/{id}", Access::kControl, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       Body body = parse_body(req, {"operator", "comment", "tags", "duts"});
       const station::MetadataEdit edit = metadata_fields(body, req);
       if (body.error) return *body.error;
       if (!edit.operator_name && !edit.comment && !edit.tags && !edit.dut_serials) {
         return error_response(req, http::status::bad_request,
                               "nothing to change: give one or more of operator, comment, tags, "
                               "duts");
       }
       // Tokens carry no names: the audit event says the change came over
       // the API.
       return reply_response(req, ctx.control->edit_run(*parse_id(p[0]), edit, "api"));
     }},
    {http::verb::get, "/api/v1/runs/{id}/events", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       return reply_response(req, ctx.control->run_events(*parse_id(p[0])));
     }},
    {http::verb::get, "/api/v1/runs/{id}/stats", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       const Query q = parse_query(req, {"dut", "axis"});
       if (q.error) return *q.error;
       station::StatsQuery sq;
       if (const std::string* dut = q.find("dut")) sq.dut = *dut;
       if (const std::string* axis = q.find("axis")) sq.axis = *axis;
       return reply_response(req, ctx.control->run_stats_filtered(*parse_id(p[0]), sq));
     }},
    {http::verb::get, "/api/v1/runs/{id}/fits", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       return reply_response(req, ctx.control->run_fits(*parse_id(p[0])));
     }},
    {http::verb::get, "/api/v1/runs/{id}/allan", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       return reply_response(req, ctx.control->run_allan(*parse_id(p[0])));
     }},
    {http::verb::get, "/api/v1/runs/{id}/scale-factor", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       return reply_response(req, ctx.control->run_scale_factor(*parse_id(p[0])));
     }},
    {http::verb::get, "/api/v1/exports", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params&) {
       return reply_response(req, ctx.control->exports());
     }},
    {http::verb::get, "/api/v1/runs/{id}/samples", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       const Query q = parse_query(req, {"from", "to", "max_points", "dut", "channel"});
       if (q.error) return *q.error;
       std::optional<HttpResponse> error;
       constexpr double kMaxS = 1e9;
       station::SamplesQuery sq;
       sq.from_s = number_param(q, error, req, "from", -kMaxS, kMaxS).value_or(0.0);
       sq.to_s = number_param(q, error, req, "to", -kMaxS, kMaxS);
       if (auto m = number_param(q, error, req, "max_points", 1, kMaxPoints)) {
         if (*m != std::floor(*m)) {
           error = error_response(req, http::status::bad_request,
                                  "query parameter 'max_points' must be an integer");
         }
         sq.max_points = static_cast<int>(*m);
       }
       if (const std::string* dut = q.find("dut")) sq.dut = *dut;
       if (const std::string* channel = q.find("channel")) sq.channel = *channel;
       if (error) return *error;
       if (sq.to_s && *sq.to_s < sq.from_s) {
         return error_response(
             req, http::status::bad_request,
             fmt::format("query parameters: from ({}) is after to ({})", sq.from_s, *sq.to_s));
       }
       return reply_response(req, ctx.control->run_channel_samples(*parse_id(p[0]), sq));
     }},
    {http::verb::get, "/api/v1/duts", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params&) {
       return reply_response(req, ctx.control->duts());
     }},
    {http::verb::get, "/api/v1/duts/{serial}", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       // check_params has decoded and bounded it.
       return reply_response(req, ctx.control->dut_history(*url_decode(p[0], false)));
     }},
    {http::verb::get, "/api/v1/fits/{id}", Access::kRead, true,
     [](const HttpRequest& req, const ApiContext& ctx, const Params& p) {
       return reply_response(req, ctx.control->fit(*parse_id(p[0])));
     }},
};

// Matches `path` against a route template, collecting the {…} segments.
bool match(std::string_view pattern, std::string_view path, Params& params) {
  params.clear();
  while (!pattern.empty() || !path.empty()) {
    if (pattern.empty() || path.empty() || pattern[0] != '/' || path[0] != '/') return false;
    pattern.remove_prefix(1);
    path.remove_prefix(1);
    const auto pe = pattern.find('/');
    const auto se = path.find('/');
    const std::string_view pseg = pattern.substr(0, pe);
    const std::string_view seg = path.substr(0, se);
    if (!pseg.empty() && pseg.front() == '{') {
      if (seg.empty()) return false;
      params.push_back(seg);
    } else if (pseg != seg) {
      return false;
    }
    pattern = pe == std::string_view::npos ? std::string_view() : pattern.substr(pe);
    path = se == std::string_view::npos ? std::string_view() : path.substr(se);
  }
  return true;
}

// Path parameters every route checks the same way: ids are positive
// integers, control actions are known.
std::optional<HttpResponse> check_params(const HttpRequest& req, std::string_view pattern,
                                         const Params& params) {
  std::size_t i = 0;
  for (std::string_view rest = pattern; !rest.empty();) {
    const auto open = rest.find('{');
    if (open == std::string_view::npos) break;
    const auto close = rest.find('}', open);
    const std::string_view name = rest.substr(open + 1, close - open - 1);
    rest = rest.substr(close + 1);
    const std::string_view value = params[i++];
    if (name == "id" && !parse_id(value)) {
      return error_response(req, http::status::not_found,
                            fmt::format("ids are positive integers, not '{}'", value));
    }
    if (name == "serial") {
      const auto serial = url_decode(value, false);
      if (!serial || serial->empty() || utf8_chars(*serial) > station::kMaxSerialChars) {
        return error_response(
            req, http::status::not_found,
            fmt::format("'{}' is not a DUT serial (percent-encoded, 1 to {} "
                        "characters)",
                        value.substr(0, 2 * station::kMaxSerialChars), station::kMaxSerialChars));
      }
    }
    if (name == "action" && value != "pause" && value != "resume" && value != "abort" &&
        value != "stop" && value != "table-reset") {
      return error_response(
          req, http::status::not_found,
          fmt::format("no control action '{}' (pause, resume, abort, stop, table-reset)", value));
    }
  }
  return std::nullopt;
}

std::string_view method_name(http::verb v) {
  const auto s = http::to_string(v);
  return {s.data(), s.size()};
}

}  // namespace

std::vector<RouteInfo> api_routes() {
  std::vector<RouteInfo> out;
  for (const Route& r : kRoutes)
    out.push_back({std::string(method_name(r.method)), std::string(r.path)});
  return out;
}

namespace {

struct Found {
  const Route* route = nullptr;
  Params params;
  std::string allowed;  // the methods of the path, when none is req's
};

Found find_route(const HttpRequest& req) {
  std::string_view target(req.target().data(), req.target().size());
  if (const auto q = target.find('?'); q != std::string_view::npos) target = target.substr(0, q);
  const http::verb method = req.method() == http::verb::head ? http::verb::get : req.method();
  Found f;
  for (const Route& r : kRoutes) {
    if (!match(r.path, target, f.params)) continue;
    if (r.method == method) {
      f.route = &r;
      return f;
    }
    f.allowed += fmt::format("{}{}", f.allowed.empty() ? "" : ", ", method_name(r.method));
  }
  f.params.clear();
  return f;
}

// The token of an "Authorization: Bearer TOKEN" value, "" when the value is
// not of that form. RFC 9110 §11.1: the scheme is case-insensitive and one
// or more spaces separate it from the credentials.
std::string_view bearer_token(std::string_view value) {
  constexpr std::string_view kBearer = "bearer";
  if (value.size() <= kBearer.size() || value[kBearer.size()] != ' ') return {};
  for (std::size_t i = 0; i < kBearer.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(value[i])) != kBearer[i]) return {};
  }
  value.remove_prefix(kBearer.size());
  while (!value.empty() && value.front() == ' ') value.remove_prefix(1);
  return value;
}

// The refusal of a request to a route with `access`, or nullopt.
std::optional<HttpResponse> authorize(const HttpRequest& req, const ApiContext& ctx,
                                      std::string_view peer, Access access) {
  if (access == Access::kOpen || (access == Access::kRead && !ctx.reads_need_token)) {
    return std::nullopt;
  }
  if (access == Access::kControl && ctx.tokens.empty()) {
    return error_response(req, http::status::forbidden,
                          "changes are disabled: no token in [api] tokens of the station config");
  }
  if (ctx.auth_limiter) {
    if (const int wait_s = ctx.auth_limiter->retry_after_s(peer); wait_s > 0) {
      HttpResponse res = error_response(
          req, http::status::too_many_requests,
          fmt::format("too many unknown tokens from this address: try again in {} s", wait_s));
      res.set(http::field::retry_after, std::to_string(wait_s));
      return res;
    }
  }
  const auto it = req.find(http::field::authorization);
  std::string_view presented;
  if (it != req.end())
    presented = bearer_token(std::string_view(it->value().data(), it->value().size()));
  const TokenRole role =
      presented.empty() ? TokenRole::kNone : token_role(presented, ctx.tokens, ctx.read_tokens);
  if (role == TokenRole::kNone) {
    // Credentials that are not a token of the station count against the
    // peer; a request without any does not.
    if (it != req.end() && ctx.auth_limiter && ctx.auth_limiter->record_failure(peer)) {
      const auto& o = ctx.auth_limiter->options();
      spdlog::warn(
          "API: {} unknown tokens from {} within {:g} s; its requests that need a token get "
          "429 for {:g} s",
          o.max_failures, peer.empty() ? "?" : peer, o.window_s, o.window_s);
    }
    HttpResponse res =
        error_response(req, http::status::unauthorized,
                       presented.empty() ? "this request needs Authorization: Bearer TOKEN"
                                         : "the token is not one of the station's tokens");
    res.set(http::field::www_authenticate, "Bearer");
    return res;
  }
  if (access == Access::kControl && role == TokenRole::kRead) {
    return error_response(req, http::status::forbidden,
                          "the token is read-only ([api] read_tokens): it may read but not "
                          "change anything; changes need one of [api] tokens");
  }
  return std::nullopt;
}

}  // namespace

std::optional<HttpResponse> check_access(const HttpRequest& req, const ApiContext& ctx,
                                         std::string_view peer) {
  const Found f = find_route(req);
  if (!f.route) return std::nullopt;
  return authorize(req, ctx, peer, f.route->access);
}

HttpResponse handle_api_request(const HttpRequest& req, const ApiContext& ctx,
                                std::string_view peer) {
  const Found f = find_route(req);
  if (!f.route) {
    if (!f.allowed.empty()) return method_not_allowed(req, f.allowed);
    std::string_view target(req.target().data(), req.target().size());
    target = target.substr(0, target.find('?'));
    return error_response(req, http::status::not_found,
                          fmt::format("no such resource: {}", target));
  }
  if (auto bad = check_params(req, f.route->path, f.params)) return *bad;
  if (auto denied = authorize(req, ctx, peer, f.route->access)) return *denied;
  if (f.route->station && !ctx.control) return no_station(req);
  HttpResponse response = f.route->handle(req, ctx, f.params);
  // Whatever a control request changed, the next status shows it.
  if (f.route->access == Access::kControl && ctx.status_body) ctx.status_body->invalidate();
  return response;
}

}  // namespace gyrotherm::api
