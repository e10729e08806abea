#include "gyrotherm/daemon/http_server.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/strand.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/version.hpp>
#include <nlohmann/json.hpp>

namespace gyrotherm::daemon {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;

HttpResponse json_response(const HttpRequest& req, http::status status, std::string body) {
  HttpResponse res{status, req.version()};
  res.set(http::field::server, "gyrothermd");
  res.set(http::field::content_type, "application/json");
  res.set(http::field::cache_control, "no-store");
  res.keep_alive(req.keep_alive());
  res.body() = std::move(body);
  res.prepare_payload();
  return res;
}

HttpResponse error_response(const HttpRequest& req, http::status status, std::string_view message) {
  nlohmann::json j = {{"error", message}, {"status", static_cast<int>(status)}};
  return json_response(req, status, j.dump());
}

namespace {

class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(tcp::socket&& socket, const HttpServerOptions& options, const HttpHandler& handler,
          std::atomic<int>& connections)
      : stream_(std::move(socket)),
        options_(options),
        handler_(handler),
        connections_(connections) {}
  ~Session() { --connections_; }

  void run() {
    asio::dispatch(stream_.get_executor(),
                   beast::bind_front_handler(&Session::do_read, shared_from_this()));
  }

 private:
  void do_read() {
    parser_.emplace();
    parser_->header_limit(static_cast<std::uint32_t>(options_.header_limit));
    parser_->body_limit(options_.body_limit);
    stream_.expires_after(options_.read_timeout);
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&Session::on_read, shared_from_this()));
  }

  void on_read(beast::error_code ec, std::size_t) {
    if (ec == http::error::end_of_stream || ec == beast::error::timeout ||
        ec == asio::error::connection_reset || ec == asio::error::operation_aborted) {
      return do_close();
    }
    if (ec) {
      // Malformed or oversized request: answer 4xx, then close.
      HttpRequest dummy;
      dummy.version(11);
      http::status status = http::status::bad_request;
      if (ec == http::error::body_limit) status = http::status::payload_too_large;
      if (ec == http::error::header_limit) status = http::status::request_header_fields_too_large;
      auto res = error_response(dummy, status, fmt::format("bad request: {}", ec.message()));
      res.keep_alive(false);
      return send(std::move(res));
    }
    HttpResponse res;
    const HttpRequest& req = parser_->get();
    try {
      res = handler_(req);
    } catch (const std::exception& e) {
      spdlog::error("HTTP handler for {}: {}", std::string(req.target()), e.what());
      res = error_response(req, http::status::internal_server_error, "internal error");
    }
    send(std::move(res));
  }

  void send(HttpResponse&& res) {
    auto sp = std::make_shared<HttpResponse>(std::move(res));
    stream_.expires_after(options_.read_timeout);
    http::async_write(stream_, *sp,
                      [self = shared_from_this(), sp](beast::error_code ec, std::size_t) {
                        self->on_write(sp->need_eof(), ec);
                      });
  }

  void on_write(bool close, beast::error_code ec) {
    if (ec || close) return do_close();
    do_read();
  }

  void do_close() {
    beast::error_code ec;
    stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
  }

  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  const HttpServerOptions& options_;
  const HttpHandler& handler_;
  std::atomic<int>& connections_;
};

}  // namespace

struct HttpServer::Impl {
  Impl(HttpServerOptions o, HttpHandler h)
      : options(std::move(o)), handler(std::move(h)), acceptor(ioc) {}

  void do_accept() {
    acceptor.async_accept(asio::make_strand(ioc), [this](beast::error_code ec, tcp::socket socket) {
      if (ec == asio::error::operation_aborted) return;
      if (!ec) {
        if (connections.load() >= options.max_connections) {
          beast::error_code ignored;
          socket.close(ignored);  // over the bound: refuse by closing
        } else {
          ++connections;
          std::make_shared<Session>(std::move(socket), options, handler, connections)->run();
        }
      }
      do_accept();
    });
  }

  // Declared before the io_context: sessions still queued in it refer to
  // these when the io_context is destroyed.
  HttpServerOptions options;
  HttpHandler handler;
  std::atomic<int> connections{0};
  asio::io_context ioc{1};
  tcp::acceptor acceptor;
};

Result<std::unique_ptr<HttpServer>> HttpServer::create(HttpServerOptions options,
                                                       HttpHandler handler) {
  std::unique_ptr<HttpServer> server(new HttpServer());
  server->impl_ = std::make_unique<Impl>(std::move(options), std::move(handler));
  Impl& impl = *server->impl_;
  beast::error_code ec;
  const auto address = asio::ip::make_address(impl.options.bind, ec);
  if (ec) {
    return Error::Permanent(
        fmt::format("api.bind: \"{}\" is not an IP address: {}", impl.options.bind, ec.message()));
  }
  const tcp::endpoint endpoint{address, static_cast<unsigned short>(impl.options.port)};
  impl.acceptor.open(endpoint.protocol(), ec);
  if (!ec) impl.acceptor.set_option(asio::socket_base::reuse_address(true), ec);
  if (!ec) impl.acceptor.bind(endpoint, ec);
  if (!ec) impl.acceptor.listen(asio::socket_base::max_listen_connections, ec);
  if (ec) {
    return Error::Permanent(fmt::format("cannot listen on {}:{}: {}", impl.options.bind,
                                        impl.options.port, ec.message()));
  }
  server->port_ = impl.acceptor.local_endpoint().port();
  return server;
}

HttpServer::~HttpServer() { stop(); }

void HttpServer::start() {
  impl_->do_accept();
  thread_ = std::thread([this] {
    for (;;) {
      try {
        impl_->ioc.run();
        return;
      } catch (const std::exception& e) {
        spdlog::error("HTTP server: {}", e.what());
      }
    }
  });
}

void HttpServer::stop() {
  if (!impl_) return;
  asio::post(impl_->ioc, [this] {
    beast::error_code ec;
    impl_->acceptor.close(ec);
  });
  impl_->ioc.stop();
  if (thread_.joinable()) thread_.join();
}

}  // namespace gyrotherm::daemon
