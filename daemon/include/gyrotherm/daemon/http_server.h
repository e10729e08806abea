// A small HTTP/1.1 server on Boost.Beast (async, one io_context thread).
//
// Request handling is a pure function from request to response (see api.h),
// kept apart from sessions and the listener, as in Beast's async example
// server. Every read has a timeout, headers and bodies are size-limited and
// the number of connections is bounded; a bad request gets a 4xx and the
// server keeps serving. Exceptions thrown by the handler become 500s.
#pragma once

#include <atomic>
#include <boost/asio/io_context.hpp>
#include <boost/beast/http.hpp>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <thread>

#include "gyrotherm/core/result.h"

namespace gyrotherm::daemon {

using HttpRequest = boost::beast::http::request<boost::beast::http::string_body>;
using HttpResponse = boost::beast::http::response<boost::beast::http::string_body>;
using HttpHandler = std::function<HttpResponse(const HttpRequest&)>;

struct HttpServerOptions {
  std::string bind = "127.0.0.1";
  int port = 8750;  // 0: any free port; see HttpServer::port()
  std::chrono::seconds read_timeout{10};
  std::size_t header_limit = 8 * 1024;
  std::size_t body_limit = 64 * 1024;
  int max_connections = 64;
};

class HttpServer {
 public:
  // Binds and listens; error (permanent) when the address is unusable or the
  // port is taken. Serving starts with start().
  static Result<std::unique_ptr<HttpServer>> create(HttpServerOptions options, HttpHandler handler);
  ~HttpServer();  // stop()

  void start();  // runs the io_context on its own thread
  void stop();   // idempotent
  int port() const { return port_; }

  struct Impl;

 private:
  HttpServer() = default;
  std::unique_ptr<Impl> impl_;
  int port_ = 0;
  std::thread thread_;
};

// Helpers for handlers.
HttpResponse json_response(const HttpRequest& req, boost::beast::http::status status,
                           std::string body);
HttpResponse error_response(const HttpRequest& req, boost::beast::http::status status,
                            std::string_view message);

}  // namespace gyrotherm::daemon
