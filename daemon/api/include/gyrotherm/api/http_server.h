// A small HTTP/1.1 server on Boost.Beast (async, a few io_context threads)
// with a Server-Sent Events fan-out.
//
// Request handling is a pure function from request to response (see api.h),
// kept apart from sessions and the listener, as in Beast's async example
// server. Every read has a timeout, headers and bodies are size-limited and
// the number of connections is bounded; a bad request gets a 4xx and the
// server keeps serving. An HTTP/1.1 request without exactly one valid Host
// gets 400 (RFC 9112 §3.2). Exceptions thrown by the handler become 500s. Log
// lines name the method and path, never a header or the query.
//
// A GET of options.stream_path turns the connection into an event stream
// (text/event-stream, chunked) fed by an EventStream: publish() formats a
// message once and queues it for every client without touching a socket,
// so no publisher (the acquisition side) ever waits on a client; a client
// further behind than queue_bytes, or whose write stalls past write_timeout,
// is disconnected, and the others go on.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "gyrotherm/core/result.h"

// Boost.Beast's message types, declared only: <boost/beast/http.hpp>
// preprocesses to about 190000 lines, and most users of this header (and of
// api.h) only pass requests and responses on. Beast 1.74 has no
// forward-declaration headers; a declaration that no longer matches Beast's
// fails to compile where both are seen, and http_server.cpp checks that the
// aliases below are Beast's request and response. A file that builds or reads
// a request or response includes gyrotherm/api/http_message.h.
namespace boost::beast::http {
template <bool isRequest, class Body, class Fields>
class message;
template <class CharT, class Traits, class Allocator>
struct basic_string_body;
template <class Allocator>
class basic_fields;
enum class status : unsigned;
}  // namespace boost::beast::http

namespace gyrotherm::api {

// boost::beast::http::request<string_body> and response<string_body>.
using HttpRequest = boost::beast::http::message<
    true, boost::beast::http::basic_string_body<char, std::char_traits<char>, std::allocator<char>>,
    boost::beast::http::basic_fields<std::allocator<char>>>;
using HttpResponse = boost::beast::http::message<
    false,
    boost::beast::http::basic_string_body<char, std::char_traits<char>, std::allocator<char>>,
    boost::beast::http::basic_fields<std::allocator<char>>>;
using HttpHandler = std::function<HttpResponse(const HttpRequest&)>;
// A handler that is also told the client's address ("127.0.0.1", "::1").
using HttpPeerHandler = std::function<HttpResponse(const HttpRequest&, std::string_view peer)>;

// One stream client's queue (shared by the EventStream and the session).
struct StreamClient {
  std::mutex mu;
  std::deque<std::shared_ptr<const std::string>> queue;
  std::size_t queued_bytes = 0;
  bool writing = false;  // a pump is scheduled or a write is in flight
  bool closed = false;
  std::function<void()> wake;  // schedules a pump on the session's strand
};

struct EventStreamOptions {
  std::size_t queue_bytes = 256 * 1024;  // per client, before it is dropped
  int max_clients = 32;
  std::chrono::milliseconds tick{1000};  // wall time between status ticks
  // The `status` event's data (JSON), sent on connect and at every tick.
  std::function<std::string()> status_json;

  // False with a message naming the field when queue_bytes is 0,
  // max_clients is negative (0: no streams) or tick is not positive.
  bool is_valid(std::string* why) const;
};

class EventStream {
 public:
  // The server that serves the stream checks its options (HttpServer::create).
  explicit EventStream(EventStreamOptions options) : options_(std::move(options)) {}

  // Thread-safe, never blocks on a client. `data` must be one line (JSON).
  void publish(std::string_view event, std::string_view data);
  // Publishes a status event when anyone listens (the server's tick).
  void tick();

  int clients() const;
  uint64_t dropped() const { return dropped_.load(); }
  const EventStreamOptions& options() const { return options_; }

  // For the server: registers a client with its first messages (retry and
  // a status); nullptr when max_clients are connected.
  std::shared_ptr<StreamClient> subscribe(std::function<void()> wake);

 private:
  std::string format(std::string_view event, std::string_view data);
  void push(StreamClient& client, const std::shared_ptr<const std::string>& message);

  EventStreamOptions options_;
  mutable std::mutex mu_;
  std::vector<std::weak_ptr<StreamClient>> clients_;
  std::atomic<uint64_t> next_id_{1};
  std::atomic<uint64_t> dropped_{0};
};

struct HttpServerOptions {
  std::string bind = "127.0.0.1";
  int port = 8750;                                 // 0: any free port; see HttpServer::port()
  std::chrono::milliseconds read_timeout{10'000};  // a whole request; idle keep-alive
  std::chrono::milliseconds write_timeout{10'000};
  std::size_t header_limit = 8 * 1024;
  std::size_t body_limit = 64 * 1024;
  int max_connections = 64;
  int threads = 2;  // io_context threads: a slow database read does not stall the rest
  EventStream* stream = nullptr;  // not owned; outlives the server
  std::string stream_path = "/api/v1/stream";
  // Asked before a stream starts: a response refuses the stream (it is sent
  // instead); nullopt or no gate lets it start.
  std::function<std::optional<HttpResponse>(const HttpRequest&, std::string_view peer)> stream_gate;

  // False with a message naming the field when a value is out of range:
  // bind not an IP address, port not 0..65535, a timeout not positive, a
  // limit, max_connections or threads below 1, a stream_path not starting
  // with /, or the stream's options (EventStreamOptions::is_valid, prefixed
  // "stream.").
  bool is_valid(std::string* why) const;
};

struct HttpServerStats {
  uint64_t requests = 0;
  uint64_t refused_connections = 0;  // over max_connections
  uint64_t bad_requests = 0;         // malformed, oversized
  int connections = 0;
};

class HttpServer {
 public:
  // Binds and listens; error (permanent) when the options are not valid
  // (is_valid), the address is unusable or the port is taken. Serving starts
  // with start().
  static Result<std::unique_ptr<HttpServer>> create(HttpServerOptions options,
                                                    HttpPeerHandler handler);
  static Result<std::unique_ptr<HttpServer>> create(HttpServerOptions options, HttpHandler handler);
  ~HttpServer();  // stop()

  void start();  // runs the io_context on its own threads
  void stop();   // idempotent
  int port() const { return port_; }
  HttpServerStats stats() const;

  struct Impl;

 private:
  HttpServer() = default;
  std::unique_ptr<Impl> impl_;
  int port_ = 0;
  std::vector<std::thread> threads_;
};

// What breaks RFC 9112 §3.2 in `req`'s Host: none on an HTTP/1.1 request,
// more than one, or a value that is no uri-host[:port]; nullopt when it is
// fine (HTTP/1.0 may leave Host out). The server answers such a request 400
// before any handler sees it.
std::optional<std::string> host_problem(const HttpRequest& req);

// Helpers for handlers.
// `j` as compact JSON text; bytes in its strings that are not UTF-8 (a
// serial or path segment quoted from the request) become U+FFFD instead of
// throwing: what every reply, status and stream event is written with.
std::string json_text(const nlohmann::json& j);
HttpResponse json_response(const HttpRequest& req, boost::beast::http::status status,
                           std::string body);
HttpResponse error_response(const HttpRequest& req, boost::beast::http::status status,
                            std::string_view message);

}  // namespace gyrotherm::api
