#include "gyrotherm/api/http_server.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <array>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/version.hpp>
#include <cctype>
#include <nlohmann/json.hpp>
#include <type_traits>

namespace gyrotherm::api {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;

// http_server.h declares Beast's types itself (see there).
static_assert(std::is_same_v<HttpRequest, http::request<http::string_body>>);
static_assert(std::is_same_v<HttpResponse, http::response<http::string_body>>);

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

std::string json_text(const nlohmann::json& j) {
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

HttpResponse error_response(const HttpRequest& req, http::status status, std::string_view message) {
  // Messages quote the request (its target, a query value): json_text.
  return json_response(req, status,
                       json_text({{"error", message}, {"status", static_cast<int>(status)}}));
}

std::optional<std::string> host_problem(const HttpRequest& req) {
  const auto count = req.count(http::field::host);
  if (count == 0) {
    if (req.version() >= 11) return std::string("an HTTP/1.1 request needs a Host header");
    return std::nullopt;
  }
  if (count > 1) return std::string("more than one Host header");
  const auto v = req[http::field::host];
  const std::string_view value(v.data(), v.size());
  // uri-host [":" port] (RFC 3986): an IP literal in brackets, or reg-name
  // characters; the port digits only.
  std::string_view host = value;
  std::string_view port;
  if (!host.empty() && host.front() == '[') {
    const auto close = host.find(']');
    if (close == std::string_view::npos) return std::string("Host: an unclosed [");
    port = host.substr(close + 1);
    host = host.substr(1, close - 1);
    for (const char c : host) {
      if (!(std::isxdigit(static_cast<unsigned char>(c)) || c == ':' || c == '.')) {
        return std::string("Host: not a valid IP literal");
      }
    }
  } else {
    const auto colon = host.rfind(':');
    if (colon != std::string_view::npos) {
      port = host.substr(colon);
      host = host.substr(0, colon);
    }
    constexpr std::string_view kRegName = "-._~%!$&'()*+,;=";
    for (const char c : host) {
      if (!std::isalnum(static_cast<unsigned char>(c)) &&
          kRegName.find(c) == std::string_view::npos) {
        return std::string("Host: not a valid host name");
      }
    }
  }
  if (!port.empty()) {
    if (port.front() != ':') return std::string("Host: not a valid host name");
    port.remove_prefix(1);
    for (const char c : port) {
      if (!std::isdigit(static_cast<unsigned char>(c)))
        return std::string("Host: not a valid port");
    }
  }
  return std::nullopt;
}

// --- EventStream ---------------------------------------------------------

std::string EventStream::format(std::string_view event, std::string_view data) {
  return fmt::format("id: {}\nevent: {}\ndata: {}\n\n", next_id_.fetch_add(1), event, data);
}

void EventStream::push(StreamClient& client, const std::shared_ptr<const std::string>& message) {
  bool wake = false;
  {
    std::lock_guard lock(client.mu);
    if (client.closed) return;
    if (client.queued_bytes + message->size() > options_.queue_bytes) {
      // Too far behind: drop the client rather than hold anything up.
      client.closed = true;
      client.queue.clear();
      client.queued_bytes = 0;
      ++dropped_;
      wake = true;
    } else {
      client.queue.push_back(message);
      client.queued_bytes += message->size();
      wake = !client.writing;
      client.writing = true;
    }
  }
  if (wake && client.wake) client.wake();
}

void EventStream::publish(std::string_view event, std::string_view data) {
  std::vector<std::shared_ptr<StreamClient>> targets;
  {
    std::lock_guard lock(mu_);
    std::erase_if(clients_, [&](const std::weak_ptr<StreamClient>& w) {
      auto c = w.lock();
      if (!c) return true;
      targets.push_back(std::move(c));
      return false;
    });
  }
  if (targets.empty()) return;
  const auto message = std::make_shared<const std::string>(format(event, data));
  for (const auto& c : targets) push(*c, message);
}

void EventStream::tick() {
  if (clients() == 0 || !options_.status_json) return;
  publish("status", options_.status_json());
}

int EventStream::clients() const {
  std::lock_guard lock(mu_);
  int n = 0;
  for (const auto& w : clients_) {
    if (auto c = w.lock()) {
      std::lock_guard client_lock(c->mu);
      n += c->closed ? 0 : 1;
    }
  }
  return n;
}

std::shared_ptr<StreamClient> EventStream::subscribe(std::function<void()> wake) {
  auto client = std::make_shared<StreamClient>();
  client->wake = std::move(wake);
  {
    std::lock_guard lock(mu_);
    std::erase_if(clients_, [](const std::weak_ptr<StreamClient>& w) { return w.expired(); });
    if (static_cast<int>(clients_.size()) >= options_.max_clients) return nullptr;
    clients_.push_back(client);
  }
  // The first messages wait for the response header: `writing` stays set
  // until the session's first pump.
  std::lock_guard lock(client->mu);
  client->writing = true;
  auto first = std::make_shared<const std::string>("retry: 3000\n\n");
  client->queue.push_back(first);
  client->queued_bytes += first->size();
  if (options_.status_json) {
    auto status = std::make_shared<const std::string>(format("status", options_.status_json()));
    client->queue.push_back(status);
    client->queued_bytes += status->size();
  }
  return client;
}

// --- Server ----------------------------------------------------------------

struct HttpServer::Impl {
  Impl(HttpServerOptions o, HttpPeerHandler h)
      : options(std::move(o)), handler(std::move(h)), acceptor(ioc), tick_timer(ioc) {}

  void do_accept();
  void schedule_tick();

  // Declared before the io_context: sessions still queued in it refer to
  // these when the io_context is destroyed.
  HttpServerOptions options;
  HttpPeerHandler handler;
  std::atomic<int> connections{0};
  std::atomic<uint64_t> requests{0};
  std::atomic<uint64_t> refused{0};
  std::atomic<uint64_t> bad_requests{0};
  asio::io_context ioc;
  tcp::acceptor acceptor;
  asio::steady_timer tick_timer;
};

namespace {

bool is_stream_request(const HttpRequest& req, const std::string& stream_path) {
  std::string_view target(req.target().data(), req.target().size());
  if (const auto q = target.find('?'); q != std::string_view::npos) target = target.substr(0, q);
  return req.method() == http::verb::get && target == stream_path;
}

// The target without its query, cut to 200 bytes: what a log line may show.
std::string path_for_log(const HttpRequest& req) {
  std::string_view target(req.target().data(), req.target().size());
  target = target.substr(0, std::min(target.find('?'), std::size_t{200}));
  return std::string(target);
}

class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(tcp::socket&& socket, HttpServer::Impl& server)
      : stream_(std::move(socket)), server_(server) {
    beast::error_code ec;
    const tcp::endpoint remote = stream_.socket().remote_endpoint(ec);
    if (!ec) {
      const auto address = remote.address();
      // An IPv4 client of a dual-stack socket is one peer, however it came.
      peer_ = address.is_v6() && address.to_v6().is_v4_mapped()
                  ? asio::ip::make_address_v4(asio::ip::v4_mapped, address.to_v6()).to_string()
                  : address.to_string();
    }
  }
  ~Session() {
    if (client_) {
      std::lock_guard lock(client_->mu);
      client_->closed = true;
    }
    --server_.connections;
  }

  void run() {
    asio::dispatch(stream_.get_executor(),
                   beast::bind_front_handler(&Session::do_read, shared_from_this()));
  }

 private:
  const HttpServerOptions& options() const { return server_.options; }

  void do_read() {
    parser_.emplace();
    parser_->header_limit(static_cast<std::uint32_t>(options().header_limit));
    parser_->body_limit(options().body_limit);
    stream_.expires_after(options().read_timeout);
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
      ++server_.bad_requests;
      HttpRequest dummy;
      dummy.version(11);
      http::status status = http::status::bad_request;
      if (ec == http::error::body_limit) status = http::status::payload_too_large;
      if (ec == http::error::header_limit) status = http::status::request_header_fields_too_large;
      auto res = error_response(dummy, status, fmt::format("bad request: {}", ec.message()));
      res.keep_alive(false);
      return send(std::move(res));
    }
    ++server_.requests;
    const HttpRequest& req = parser_->get();
    // Beast applies header_limit per read, not to the whole header: check
    // the total here so "larger than max_header_bytes" is always a 431.
    std::size_t header_bytes = req.method_string().size() + req.target().size() + 12;
    for (const auto& f : req) header_bytes += f.name_string().size() + f.value().size() + 4;
    if (header_bytes > options().header_limit) {
      ++server_.bad_requests;
      auto res = error_response(req, http::status::request_header_fields_too_large,
                                fmt::format("bad request: the header is {} bytes, over the limit "
                                            "of {} ([api] max_header_bytes)",
                                            header_bytes, options().header_limit));
      res.keep_alive(false);
      return send(std::move(res));
    }
    if (const auto problem = host_problem(req)) {
      ++server_.bad_requests;
      auto res = error_response(req, http::status::bad_request,
                                fmt::format("bad request: {} (RFC 9112 §3.2)", *problem));
      res.keep_alive(false);
      return send(std::move(res));
    }
    HttpResponse res;
    try {
      if (options().stream && is_stream_request(req, options().stream_path)) {
        std::optional<HttpResponse> refused;
        if (options().stream_gate) refused = options().stream_gate(req, peer_);
        if (!refused) return start_stream(req);
        res = std::move(*refused);
      } else {
        res = server_.handler(req, peer_);
      }
    } catch (const std::exception& e) {
      spdlog::error("HTTP handler for {} {}: {}", std::string(req.method_string()),
                    path_for_log(req), e.what());
      res = error_response(req, http::status::internal_server_error, "internal error");
    }
    send(std::move(res));
  }

  void send(HttpResponse&& res) {
    auto sp = std::make_shared<HttpResponse>(std::move(res));
    stream_.expires_after(options().write_timeout);
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

  // --- event stream ---

  void start_stream(const HttpRequest& req) {
    std::weak_ptr<Session> weak = shared_from_this();
    auto executor = stream_.get_executor();
    client_ = options().stream->subscribe([weak, executor] {
      asio::post(executor, [weak] {
        if (auto self = weak.lock()) self->pump();
      });
    });
    if (!client_) {
      auto res = error_response(req, http::status::service_unavailable,
                                fmt::format("too many stream clients (max_stream_clients = {})",
                                            options().stream->options().max_clients));
      res.keep_alive(false);
      return send(std::move(res));
    }
    header_ = std::make_unique<http::response<http::empty_body>>(http::status::ok, req.version());
    header_->set(http::field::server, "gyrothermd");
    header_->set(http::field::content_type, "text/event-stream");
    header_->set(http::field::cache_control, "no-store");
    header_->chunked(true);
    serializer_ = std::make_unique<http::response_serializer<http::empty_body>>(*header_);
    stream_.expires_after(options().write_timeout);
    http::async_write_header(stream_, *serializer_,
                             [self = shared_from_this()](beast::error_code ec, std::size_t) {
                               if (ec) return self->close_stream();
                               self->stream_.expires_never();
                               self->watch_client();
                               self->pump();
                             });
  }

  // A read kept pending for the stream's life: it holds the session while
  // no write is in flight and sees the client hang up at once. Anything the
  // client sends is ignored.
  void watch_client() {
    stream_.socket().async_read_some(
        asio::buffer(drain_), [self = shared_from_this()](beast::error_code ec, std::size_t) {
          if (ec) return self->close_stream();
          self->watch_client();
        });
  }

  // Writes the client's queue one message at a time; runs on the strand.
  void pump() {
    std::shared_ptr<const std::string> message;
    {
      std::lock_guard lock(client_->mu);
      if (!client_->closed) {
        if (client_->queue.empty()) {
          client_->writing = false;
          return;
        }
        message = client_->queue.front();
      }
    }
    if (!message) return close_stream();
    stream_.expires_after(options().write_timeout);
    asio::async_write(
        stream_, http::make_chunk(asio::buffer(*message)),
        [self = shared_from_this(), message](beast::error_code ec, std::size_t) {
          if (ec) return self->close_stream();
          self->stream_.expires_never();
          {
            std::lock_guard lock(self->client_->mu);
            if (!self->client_->queue.empty() && self->client_->queue.front() == message) {
              self->client_->queue.pop_front();
              self->client_->queued_bytes -= message->size();
            }
          }
          self->pump();
        });
  }

  void close_stream() {
    {
      std::lock_guard lock(client_->mu);
      client_->closed = true;
      client_->queue.clear();
      client_->queued_bytes = 0;
    }
    beast::error_code ec;
    stream_.socket().shutdown(tcp::socket::shutdown_both, ec);
    stream_.socket().close(ec);
  }

  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  HttpServer::Impl& server_;
  std::string peer_;  // the client's address; "" when the socket could not say
  std::shared_ptr<StreamClient> client_;
  std::array<char, 256> drain_{};
  std::unique_ptr<http::response<http::empty_body>> header_;
  std::unique_ptr<http::response_serializer<http::empty_body>> serializer_;
};

}  // namespace

void HttpServer::Impl::do_accept() {
  acceptor.async_accept(asio::make_strand(ioc), [this](beast::error_code ec, tcp::socket socket) {
    if (ec == asio::error::operation_aborted) return;
    if (!ec) {
      if (connections.load() >= options.max_connections) {
        ++refused;
        beast::error_code ignored;
        socket.close(ignored);  // over the bound: refuse by closing
      } else {
        ++connections;
        std::make_shared<Session>(std::move(socket), *this)->run();
      }
    }
    do_accept();
  });
}

void HttpServer::Impl::schedule_tick() {
  tick_timer.expires_after(options.stream->options().tick);
  tick_timer.async_wait([this](beast::error_code ec) {
    if (ec) return;
    options.stream->tick();
    schedule_tick();
  });
}

Result<std::unique_ptr<HttpServer>> HttpServer::create(HttpServerOptions options,
                                                       HttpHandler handler) {
  return create(std::move(options),
                [handler = std::move(handler)](const HttpRequest& req, std::string_view) {
                  return handler(req);
                });
}

bool EventStreamOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  // A queue of 0 bytes drops every client at its first event.
  if (queue_bytes == 0) return fail("queue_bytes = 0 must be >= 1");
  if (max_clients < 0) return fail(fmt::format("max_clients = {} must be >= 0", max_clients));
  if (tick <= std::chrono::milliseconds::zero()) {
    return fail(fmt::format("tick = {} ms must be > 0", tick.count()));
  }
  return true;
}

bool HttpServerOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  beast::error_code ec;
  (void)asio::ip::make_address(bind, ec);
  if (ec) return fail(fmt::format("bind = \"{}\" is not an IP address: {}", bind, ec.message()));
  if (port < 0 || port > 65535) {
    return fail(fmt::format("port = {} is not a TCP port (0..65535)", port));
  }
  for (const auto& [name, timeout] :
       {std::pair{"read_timeout", read_timeout}, std::pair{"write_timeout", write_timeout}}) {
    if (timeout <= std::chrono::milliseconds::zero()) {
      return fail(fmt::format("{} = {} ms must be > 0", name, timeout.count()));
    }
  }
  if (header_limit == 0) return fail("header_limit = 0 must be >= 1");
  if (body_limit == 0) return fail("body_limit = 0 must be >= 1");
  for (const auto& [name, count] :
       {std::pair{"max_connections", max_connections}, std::pair{"threads", threads}}) {
    if (count < 1) return fail(fmt::format("{} = {} must be >= 1", name, count));
  }
  if (!stream_path.starts_with('/')) {
    return fail(fmt::format("stream_path = \"{}\" must start with /", stream_path));
  }
  if (std::string sub_why; stream && !stream->options().is_valid(&sub_why)) {
    return fail("stream." + sub_why);
  }
  return true;
}

Result<std::unique_ptr<HttpServer>> HttpServer::create(HttpServerOptions options,
                                                       HttpPeerHandler handler) {
  if (std::string why; !options.is_valid(&why)) {
    return Error::Permanent("invalid HTTP server options: " + why);
  }
  std::unique_ptr<HttpServer> server(new HttpServer());
  server->impl_ = std::make_unique<Impl>(std::move(options), std::move(handler));
  Impl& impl = *server->impl_;
  beast::error_code ec;
  const auto address = asio::ip::make_address(impl.options.bind, ec);  // valid: is_valid
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
  if (impl_->options.stream) impl_->schedule_tick();
  const int n = impl_->options.threads;  // >= 1: is_valid
  for (int i = 0; i < n; ++i) {
    threads_.emplace_back([this] {
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
}

void HttpServer::stop() {
  if (!impl_) return;
  asio::post(impl_->ioc, [this] {
    beast::error_code ec;
    impl_->acceptor.close(ec);
    impl_->tick_timer.cancel();
  });
  impl_->ioc.stop();
  for (auto& t : threads_) {
    if (t.joinable()) t.join();
  }
  threads_.clear();
}

HttpServerStats HttpServer::stats() const {
  return {impl_->requests.load(), impl_->refused.load(), impl_->bad_requests.load(),
          impl_->connections.load()};
}

}  // namespace gyrotherm::api
