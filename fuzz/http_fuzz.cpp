// Fuzzes HTTP request handling: Beast's request parser with the daemon's
// limits (as daemon/api/src/http_server.cpp reads a request), then the REST API
// (daemon/api.h, handle_api_request) with a fake station, and the response
// serialised as the server would send it.
//
// The input is an HTTP request as it comes off the wire. The same bytes are
// also split by hand into method, target, header lines and body and handed
// to the API without Beast's checks, so the API sees targets and header
// values the parser would refuse (NUL, spaces, bare bytes >= 0x80).
// Each request goes to the API twice: reads open, and reads that need a token
// ([api] read_access = "token"), with a control and a read token configured.
// Checked: no exception escapes the API (the server would answer 500), every
// response has a 1xx-5xx status, a JSON body where the content type says so,
// and never echoes a token, nor any answer carries one in a header.
#include <boost/beast/core/buffers_to_string.hpp>
#include <boost/beast/http.hpp>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <string_view>

#include "fuzz_check.h"
#include "gyrotherm/api/api.h"

using namespace gyrotherm::api;
namespace station = gyrotherm::station;
namespace http = boost::beast::http;

namespace {

constexpr std::string_view kToken = "fuzz-token-0123456789abcdef";
constexpr std::string_view kReadToken = "fuzz-read-token-0123456789";
constexpr std::size_t kHeaderLimit = 8 * 1024;  // [api] defaults (config.h)
constexpr std::size_t kBodyLimit = 64 * 1024;

// Small fixed replies; a few refusals so every status mapping is reached.
class FakeControl : public station::StationControl {
 public:
  station::Reply queue_list() override {
    return station::Reply::ok({{"held", false}, {"entries", {}}});
  }
  station::Reply queue_add(const std::string& toml, const std::string&, bool) override {
    if (toml.empty())
      return station::Reply::refused(station::Refusal::Kind::kInvalid, "empty", {"fuzz.toml: x"});
    return station::Reply::ok({{"id", 1}});
  }
  station::Reply queue_remove(int64_t id) override {
    if (id == 9) return station::Reply::refused(station::Refusal::Kind::kConflict, "running");
    return station::Reply::ok({{"removed", id}});
  }
  station::Reply queue_move(int64_t id, int position) override {
    if (position > 100)
      return station::Reply::refused(station::Refusal::Kind::kInvalid, "bad position");
    return station::Reply::ok({{"id", id}, {"position", position}});
  }
  station::Reply control(std::string_view action, const std::string&) override {
    if (action == "pause")
      return station::Reply::refused(station::Refusal::Kind::kConflict, "no run to pause");
    return station::Reply::ok({{"ok", true}});
  }
  station::Reply runs() override { return station::Reply::ok(nlohmann::json::array()); }
  station::Reply run(int64_t id) override {
    if (id == 8) return station::Reply::refused(station::Refusal::Kind::kNotFound, "no run 8");
    return station::Reply::ok({{"id", id}});
  }
  station::Reply run_events(int64_t) override {
    return station::Reply::ok(nlohmann::json::array());
  }
  station::Reply run_stats(int64_t) override {
    return station::Reply::refused(station::Refusal::Kind::kUnavailable, "database failed");
  }
  station::Reply run_samples(int64_t id, const station::SamplesQuery& q) override {
    return station::Reply::ok({{"run_id", id}, {"from_s", q.from_s}, {"max_points", q.max_points}});
  }
  station::Reply run_fits(int64_t) override { return station::Reply::ok(nlohmann::json::array()); }
  station::Reply run_allan(int64_t) override { return station::Reply::ok(nlohmann::json::array()); }
  station::Reply run_scale_factor(int64_t) override {
    return station::Reply::ok(nlohmann::json::object());
  }
  station::Reply fit(int64_t id) override { return station::Reply::ok({{"id", id}}); }
  station::Reply exports() override { return station::Reply::ok(nlohmann::json::array()); }
  station::Reply enqueue(const station::QueueRequest& q) override {
    if (q.metadata.dut_serials.size() > 1) {
      return station::Reply::refused(station::Refusal::Kind::kBadRequest,
                                     "field 'duts': no DUT with serial 'x'");
    }
    return queue_add(q.toml_text, q.source, q.ignore_failures);
  }
  station::Reply run_with_duts(int64_t id) override { return run(id); }
  station::Reply edit_run(int64_t id, const station::MetadataEdit&, const std::string&) override {
    return run(id);
  }
  station::Reply run_stats_filtered(int64_t id, const station::StatsQuery&) override {
    return run_stats(id);
  }
  station::Reply run_channel_samples(int64_t id, const station::SamplesQuery& q) override {
    if (!q.channel.empty())
      return station::Reply::refused(station::Refusal::Kind::kNotFound, "no channel");
    return run_samples(id, q);
  }
  station::Reply duts() override { return station::Reply::ok(nlohmann::json::array()); }
  station::Reply dut_history(const std::string& serial) override {
    return station::Reply::refused(station::Refusal::Kind::kNotFound,
                                   "no DUT with serial '" + serial + "'");
  }
};

const WebAssets* web_assets() {
  static const auto loaded = WebAssets::load(GYROTHERM_FUZZ_WEB_DIR);
  return loaded.ok() ? &*loaded : nullptr;
}

ApiContext& context(bool reads_need_token) {
  static FakeControl control;
  static ApiContext ctx = [] {
    ApiContext c;
    c.status = [] {
      station::StatusSnapshot s;
      s.station_name = "fuzz";
      s.run_id = 3;
      s.chamber_c = 20.5;
      return s;
    };
    c.control = &control;
    c.tokens = {std::string(kToken), "second-token"};
    c.read_tokens = {std::string(kReadToken)};
    c.metrics = [] { return std::string("gyrotherm_up 1\n"); };
    c.web = web_assets();
    return c;
  }();
  static ApiContext token_mode = [] {
    ApiContext c = ctx;
    c.reads_need_token = true;
    return c;
  }();
  return reads_need_token ? token_mode : ctx;
}

boost::beast::string_view bsv(std::string_view s) { return {s.data(), s.size()}; }

void check_response(const HttpRequest& req, const HttpResponse& res) {
  const int status = static_cast<int>(res.result_int());
  FUZZ_CHECK(status >= 100 && status <= 599);
  const auto type = res[http::field::content_type];
  if (type == "application/json" && req.method() != http::verb::head) {
    FUZZ_CHECK(nlohmann::json::accept(res.body()));
  }
  // A token is echoed only if the client put it where echoes come from.
  const std::string_view target(req.target().data(), req.target().size());
  for (const std::string_view token : {kToken, kReadToken}) {
    if (target.find(token) == std::string_view::npos &&
        req.body().find(token) == std::string::npos) {
      FUZZ_CHECK(res.body().find(token) == std::string::npos);
      for (const auto& field : res) {
        FUZZ_CHECK(std::string_view(field.value().data(), field.value().size()).find(token) ==
                   std::string_view::npos);
      }
    }
  }
  std::ostringstream wire;
  wire << res;  // what async_write sends
  FUZZ_CHECK(!wire.str().empty());
}

void handle(const HttpRequest& req) {
  for (const bool reads_need_token : {false, true}) {
    const HttpResponse res = handle_api_request(req, context(reads_need_token), "192.0.2.1");
    check_response(req, res);
  }
}

// Beast's parser, fed the bytes as one buffer the way async_read would.
void via_beast(std::string_view bytes) {
  http::request_parser<http::string_body> parser;
  parser.header_limit(static_cast<std::uint32_t>(kHeaderLimit));
  parser.body_limit(kBodyLimit);
  parser.eager(true);
  boost::beast::error_code ec;
  std::size_t used = 0;
  while (!parser.is_done() && used < bytes.size()) {
    const std::size_t n =
        parser.put(boost::asio::buffer(bytes.data() + used, bytes.size() - used), ec);
    if (ec == http::error::need_more && n == 0) break;
    if (ec && ec != http::error::need_more) return;  // the server answers 4xx
    used += n;
    ec = {};
  }
  if (!parser.is_done()) {
    if (!parser.got_some()) return;  // the server sees end_of_stream
    parser.put_eof(ec);
    if (ec || !parser.is_done()) return;
  }
  handle(parser.get());
}

// The same bytes as a request without Beast's validation.
void by_hand(std::string_view bytes) {
  auto line = [&bytes]() {
    const auto nl = bytes.find('\n');
    std::string_view l = bytes.substr(0, nl);
    bytes = nl == std::string_view::npos ? std::string_view() : bytes.substr(nl + 1);
    if (!l.empty() && l.back() == '\r') l.remove_suffix(1);
    return l;
  };
  std::string_view first = line();
  const auto sp = first.find(' ');
  const std::string_view method = first.substr(0, sp);
  std::string_view target = sp == std::string_view::npos ? "" : first.substr(sp + 1);
  if (const auto v = target.rfind(" HTTP/"); v != std::string_view::npos)
    target = target.substr(0, v);

  HttpRequest req;
  req.version(11);
  const http::verb verb = http::string_to_verb(bsv(method));
  if (verb != http::verb::unknown) {
    req.method(verb);
  } else {
    req.method_string(bsv(method));
  }
  req.target(bsv(target));
  while (!bytes.empty()) {
    const std::string_view l = line();
    if (l.empty()) break;
    const auto colon = l.find(':');
    if (colon == std::string_view::npos) continue;
    std::string_view value = l.substr(colon + 1);
    while (!value.empty() && value.front() == ' ') value.remove_prefix(1);
    req.insert(bsv(l.substr(0, colon)), bsv(value));
  }
  req.body() = std::string(bytes);
  handle(req);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  via_beast(bytes);
  by_hand(bytes);
  return 0;
}
