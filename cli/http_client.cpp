#include "gyrotherm/cli/http_client.h"

#include <fmt/format.h>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <regex>

namespace gyrotherm::cli {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;

Result<HttpResult> http_request(const std::string& method, const std::string& url,
                                const std::string& body, const std::string& token,
                                std::chrono::milliseconds timeout) {
  static const std::regex kUrl(R"(^http://([^/:]+)(?::(\d+))?(/.*)?$)");
  std::smatch m;
  if (!std::regex_match(url, m, kUrl)) {
    return Error::Permanent(fmt::format("\"{}\" is not an http:// URL", url));
  }
  const std::string host = m[1];
  const std::string port = m[2].matched ? std::string(m[2]) : "80";
  const std::string target = m[3].matched ? std::string(m[3]) : "/";

  asio::io_context ioc;
  beast::tcp_stream stream(ioc);
  tcp::resolver resolver(ioc);
  beast::flat_buffer buffer;
  http::request<http::string_body> req{http::string_to_verb(method), target, 11};
  // RFC 9110 §7.2: the port goes with the host unless it is the default.
  req.set(http::field::host, m[2].matched && port != "80" ? host + ":" + port : host);
  req.set(http::field::user_agent, "gyrotherm");
  if (!token.empty()) req.set(http::field::authorization, "Bearer " + token);
  if (!body.empty()) {
    req.set(http::field::content_type, "application/json");
    req.body() = body;
  }
  req.prepare_payload();
  http::response<http::string_body> res;
  beast::error_code result_ec;
  bool done = false;

  stream.expires_after(timeout);
  resolver.async_resolve(host, port, [&](beast::error_code ec, tcp::resolver::results_type r) {
    if (ec) {
      result_ec = ec;
      return;
    }
    stream.async_connect(r, [&](beast::error_code ec, const tcp::endpoint&) {
      if (ec) {
        result_ec = ec;
        return;
      }
      http::async_write(stream, req, [&](beast::error_code ec, std::size_t) {
        if (ec) {
          result_ec = ec;
          return;
        }
        http::async_read(stream, buffer, res, [&](beast::error_code ec, std::size_t) {
          result_ec = ec;
          done = !ec;
        });
      });
    });
  });
  ioc.run();
  if (!done) {
    return Error::Transient(
        fmt::format("{} {}: {}", method, url, result_ec ? result_ec.message() : "no response"));
  }
  beast::error_code ignored;
  stream.socket().shutdown(tcp::socket::shutdown_both, ignored);
  HttpResult out;
  out.status = static_cast<int>(res.result_int());
  out.body = std::move(res.body());
  out.content_type = std::string(res[http::field::content_type]);
  return out;
}

}  // namespace gyrotherm::cli
