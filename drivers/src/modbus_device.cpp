#include "gyrotherm/drivers/modbus_device.h"

#include <arpa/inet.h>
#include <fmt/format.h>
#include <modbus/modbus.h>
#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>
#include <vector>

#include "gyrotherm/core/clock.h"

namespace gyrotherm::drivers {
namespace {

using Steady = std::chrono::steady_clock;
constexpr std::chrono::milliseconds kMinReconnectBackoff{100};
constexpr std::chrono::milliseconds kMaxReconnectBackoff{5000};

const char* function_name(RegisterFunction f) {
  return f == RegisterFunction::kHolding ? "holding" : "input";
}

// Exception replies from the device: the link is fine, the request was not.
bool is_exception_reply(int err) { return err >= EMBXILFUN && err <= EMBXGTAR; }

// Exceptions where a retry may help (device busy, gateway trouble).
bool is_transient_exception(int err) {
  return err == EMBXACK || err == EMBXSBUSY || err == EMBXNACK || err == EMBXGPATH ||
         err == EMBXGTAR;
}

// The numeric addresses `host` resolves to (getaddrinfo: names, IPv4, IPv6),
// in the resolver's order, or the resolver's reason. libmodbus's own TCP
// back ends either take IPv4 literals only (modbus_new_tcp: "localhost"
// became 255.255.255.255, "Network is unreachable") or report a failed
// look-up as "Connection refused" (modbus_new_tcp_pi), so we resolve first
// and hand modbus_new_tcp_pi one numeric address at a time.
Result<std::vector<std::string>> resolve_host(const std::string& host, int port) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* list = nullptr;
  const std::string service = std::to_string(port);
  const int rc = ::getaddrinfo(host.c_str(), service.c_str(), &hints, &list);
  if (rc != 0) {
    return Error::Transient(
        fmt::format("cannot resolve host name \"{}\": {}", host,
                    rc == EAI_SYSTEM ? std::strerror(errno) : gai_strerror(rc)));
  }
  std::vector<std::string> out;
  for (const addrinfo* a = list; a != nullptr; a = a->ai_next) {
    char text[NI_MAXHOST];
    if (::getnameinfo(a->ai_addr, a->ai_addrlen, text, sizeof text, nullptr, 0, NI_NUMERICHOST) ==
            0 &&
        std::find(out.begin(), out.end(), text) == out.end()) {
      out.emplace_back(text);
    }
  }
  ::freeaddrinfo(list);
  if (out.empty()) {
    return Error::Transient(fmt::format("host name \"{}\" resolves to no address", host));
  }
  return out;
}

}  // namespace

std::string tcp_host_problem(std::string_view host) {
  if (host.empty()) return "empty (expected a host name or an IP address)";
  const std::string h(host);
  if (h.find(':') != std::string::npos) {
    in6_addr a6{};
    return ::inet_pton(AF_INET6, h.c_str(), &a6) == 1
               ? ""
               : fmt::format("\"{}\" is not a valid IPv6 address", h);
  }
  // All digits and dots: meant as an IPv4 address (a host name's last
  // label is never all digits).
  if (h.find_first_not_of("0123456789.") == std::string::npos) {
    in_addr a4{};
    return ::inet_pton(AF_INET, h.c_str(), &a4) == 1
               ? ""
               : fmt::format("\"{}\" is not a valid IPv4 address (four numbers 0..255)", h);
  }
  const std::string_view name = host.back() == '.' ? host.substr(0, host.size() - 1) : host;
  if (name.size() > 253) return fmt::format("host name \"{}\" is longer than 253 characters", h);
  std::size_t start = 0;
  for (;;) {
    const std::size_t dot = name.find('.', start);
    const std::string_view label =
        name.substr(start, dot == std::string_view::npos ? std::string_view::npos : dot - start);
    const bool ok = !label.empty() && label.size() <= 63 && label.front() != '-' &&
                    label.back() != '-' && std::all_of(label.begin(), label.end(), [](char c) {
                      return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') ||
                             (c >= '0' && c <= '9') || c == '-';
                    });
    if (!ok) {
      return fmt::format(
          "\"{}\" is not a host name or IP address (labels of letters, digits and '-', "
          "1..63 characters, separated by dots)",
          h);
    }
    if (dot == std::string_view::npos) break;
    start = dot + 1;
  }
  return "";
}

std::string ModbusEndpoint::describe() const {
  if (transport == "rtu") {
    return fmt::format("rtu {} {} {}{}{} unit {}", device, baud, data_bits, parity, stop_bits,
                       unit_id);
  }
  return fmt::format("{} {}:{} unit {}", transport, host, port, unit_id);
}

ModbusDevice::ModbusDevice(std::string name, ModbusEndpoint endpoint)
    : name_(std::move(name)), endpoint_(std::move(endpoint)) {}

ModbusDevice::~ModbusDevice() {
  std::lock_guard lock(mu_);
  disconnect_locked();
}

void ModbusDevice::disconnect_locked() {
  if (ctx_ != nullptr) {
    modbus_close(ctx_);
    modbus_free(ctx_);
    ctx_ = nullptr;
  }
  health_.connected = false;
}

void ModbusDevice::record_error_locked(const std::string& what) {
  ++health_.errors;
  health_.last_error = what;
}

Status ModbusDevice::connect() {
  std::lock_guard lock(mu_);
  return connect_locked("connect");
}

Status ModbusDevice::connect_locked(const std::string& op) {
  disconnect_locked();
  const std::string where = fmt::format("{} ({}): {}", name_, endpoint_.describe(), op);
  auto permanent = [this](std::string msg) -> Error {
    record_error_locked(msg);
    return Error::Permanent(std::move(msg));
  };

  // The device cannot be reached now: transient, next attempt after the backoff.
  auto unreachable = [this, &where](std::string cause) -> Error {
    connect_error_ = std::move(cause);
    const std::string msg = fmt::format("{}: {}", where, connect_error_);
    record_error_locked(msg);
    next_attempt_ = Steady::now() + backoff_;
    backoff_ = std::min(backoff_ * 2, kMaxReconnectBackoff);
    return Error::Transient(msg);
  };

  if (endpoint_.transport == "tcp") {
    if (endpoint_.port <= 0 || endpoint_.port > 65535) {
      return permanent(fmt::format("{}: invalid TCP port {}", where, endpoint_.port));
    }
    auto addresses = resolve_host(endpoint_.host, endpoint_.port);
    if (!addresses) return unreachable(addresses.error().message);
    // Each address in turn ("localhost" is ::1 and 127.0.0.1); the first
    // that accepts is used.
    std::string causes;
    for (const auto& address : *addresses) {
      modbus_t* ctx = modbus_new_tcp_pi(address.c_str(), std::to_string(endpoint_.port).c_str());
      if (ctx == nullptr) {
        return permanent(
            fmt::format("{}: cannot create Modbus context: {}", where, modbus_strerror(errno)));
      }
      if (Status s = setup_and_connect_locked(ctx, where); !s.ok()) {
        if (!s.error().transient) return s.error();
        if (!causes.empty()) causes += "; ";
        causes += addresses->size() == 1 || address == endpoint_.host
                      ? s.error().message
                      : fmt::format("{}: {}", address, s.error().message);
        continue;
      }
      return connected_locked(ctx);
    }
    return unreachable(fmt::format("cannot connect: {}", causes));
  }

  modbus_t* ctx = nullptr;
  if (endpoint_.transport == "rtu") {
    if (endpoint_.parity != 'N' && endpoint_.parity != 'E' && endpoint_.parity != 'O') {
      return permanent(
          fmt::format("{}: invalid parity '{}' (expected N, E or O)", where, endpoint_.parity));
    }
    ctx = modbus_new_rtu(endpoint_.device.c_str(), endpoint_.baud, endpoint_.parity,
                         endpoint_.data_bits, endpoint_.stop_bits);
  } else {
    return permanent(fmt::format("{}: unknown Modbus transport '{}' (expected tcp or rtu)", where,
                                 endpoint_.transport));
  }
  if (ctx == nullptr) {
    return permanent(
        fmt::format("{}: cannot create Modbus context: {}", where, modbus_strerror(errno)));
  }
  if (Status s = setup_and_connect_locked(ctx, where); !s.ok()) {
    if (!s.error().transient) return s.error();
    return unreachable(fmt::format("cannot connect: {}", s.error().message));
  }
  // Whatever waits in the serial line's input queue (the end of a reply the
  // previous user of the line gave up on) is not ours.
  modbus_flush(ctx);
  return connected_locked(ctx);
}

// Sets unit and timeout on `ctx` and connects. On failure frees `ctx`:
// permanent error (recorded) for a bad unit id, transient error with the bare
// cause (not recorded) when the device cannot be reached.
Status ModbusDevice::setup_and_connect_locked(modbus_t* ctx, const std::string& where) {
  if (modbus_set_slave(ctx, endpoint_.unit_id) != 0) {
    const std::string cause = modbus_strerror(errno);
    modbus_free(ctx);
    const std::string msg =
        fmt::format("{}: invalid unit id {}: {}", where, endpoint_.unit_id, cause);
    record_error_locked(msg);
    return Error::Permanent(msg);
  }
  const auto timeout_us = static_cast<uint64_t>(response_timeout_s() * 1e6);
  modbus_set_response_timeout(ctx, static_cast<uint32_t>(timeout_us / 1000000),
                              static_cast<uint32_t>(timeout_us % 1000000));
  if (modbus_connect(ctx) != 0) {
    const std::string cause = modbus_strerror(errno);
    modbus_free(ctx);
    return Error::Transient(cause);
  }
  return Status::Ok();
}

double ModbusDevice::response_timeout_s() const {
  return endpoint_.response_timeout_s > 0 ? endpoint_.response_timeout_s : 0.5;
}

Status ModbusDevice::connected_locked(modbus_t* ctx) {
  ctx_ = ctx;
  health_.connected = true;
  if (ever_connected_) ++health_.reconnects;
  ever_connected_ = true;
  backoff_ = kMinReconnectBackoff;
  next_attempt_ = {};
  return Status::Ok();
}

Status ModbusDevice::ensure_connected_locked(const std::string& op) {
  if (ctx_ != nullptr) return Status::Ok();
  const auto now = Steady::now();
  if (now < next_attempt_) {
    const auto wait_ms =
        std::chrono::duration_cast<std::chrono::milliseconds>(next_attempt_ - now).count();
    const std::string msg = fmt::format("{} ({}): {}: not connected ({}; next attempt in {} ms)",
                                        name_, endpoint_.describe(), op, connect_error_, wait_ms);
    record_error_locked(msg);
    return Error::Transient(msg);
  }
  return connect_locked(op);
}

Result<double> ModbusDevice::read(const RegisterSpec& spec) {
  std::lock_guard lock(mu_);
  ++health_.requests;
  const int count = spec.word_count();
  const std::string op =
      fmt::format("read {} register {}", function_name(spec.function), spec.address);
  if (Status s = ensure_connected_locked(op); !s.ok()) return s.error();

  std::array<uint16_t, 2> words{};
  const auto t0 = Steady::now();
  const int rc = spec.function == RegisterFunction::kHolding
                     ? modbus_read_registers(ctx_, spec.address, count, words.data())
                     : modbus_read_input_registers(ctx_, spec.address, count, words.data());
  const int err = errno;
  health_.last_latency_ms = std::chrono::duration<double, std::milli>(Steady::now() - t0).count();
  if (latency_observer_) latency_observer_(health_.last_latency_ms / 1000.0);
  if (rc != count) return request_failed_locked(op, count, rc, err, "got");
  health_.last_success_utc = wall_time_utc_iso();
  return decode_register(spec, std::span<const uint16_t>(words.data(), count));
}

Error ModbusDevice::request_failed_locked(const std::string& op, int count, int rc, int err,
                                          std::string_view verb) {
  std::string msg = fmt::format(
      "{} ({}): {} ({} word{}) failed: {}", name_, endpoint_.describe(), op, count,
      count == 1 ? "" : "s",
      rc < 0 ? std::string(modbus_strerror(err)) : fmt::format("{} {} words", verb, rc));
  // A short reply or a Modbus exception: the link is fine, the request not.
  if (rc >= 0 || is_exception_reply(err)) {
    record_error_locked(msg);
    return Error{msg, rc >= 0 || is_transient_exception(err)};
  }
  // A timeout or a garbled reply. An RTU frame carries no transaction id: a
  // reply still on its way would pass libmodbus's checks (unit, function,
  // byte count) as the answer to the next request of the same shape, so the
  // line is drained before anything else is sent. (Over TCP the transaction
  // id catches it, and the reconnect below drops the old connection.)
  if (endpoint_.transport == "rtu") {
    if (const std::size_t n = drain_line_locked(); n > 0) {
      msg += fmt::format(" ({} late byte{} discarded)", n, n == 1 ? "" : "s");
    }
  }
  record_error_locked(msg);
  disconnect_locked();  // the next call reconnects
  return Error::Transient(msg);
}

std::size_t ModbusDevice::drain_line_locked() {
  const int fd = modbus_get_socket(ctx_);
  if (fd < 0) return 0;
  // Silence for one response timeout ends the drain; a line that keeps
  // talking is given up on after four.
  const auto quiet = std::chrono::duration<double>(response_timeout_s());
  const auto give_up = Steady::now() + 4 * quiet;
  auto last_byte = Steady::now();
  std::size_t discarded = 0;
  std::array<uint8_t, 256> buf{};
  for (;;) {
    const auto now = Steady::now();
    const auto until = std::min(last_byte + quiet, give_up);
    if (now >= until) break;
    pollfd pfd{fd, POLLIN, 0};
    const int ms =
        static_cast<int>(std::chrono::ceil<std::chrono::milliseconds>(until - now).count());
    const int rc = ::poll(&pfd, 1, ms);
    if (rc < 0 && errno == EINTR) continue;
    if (rc <= 0 || !(pfd.revents & POLLIN)) break;
    const ssize_t n = ::read(fd, buf.data(), buf.size());
    if (n < 0 && (errno == EAGAIN || errno == EINTR)) continue;
    if (n <= 0) break;
    discarded += static_cast<std::size_t>(n);
    last_byte = Steady::now();
  }
  modbus_flush(ctx_);
  return discarded;
}

Status ModbusDevice::write(const RegisterSpec& spec, double value) {
  std::lock_guard lock(mu_);
  ++health_.requests;
  if (spec.function != RegisterFunction::kHolding) {
    const std::string msg =
        fmt::format("{} ({}): register {} is an input register and cannot be written", name_,
                    endpoint_.describe(), spec.address);
    record_error_locked(msg);
    return Error::Permanent(msg);
  }
  auto words = encode_register(spec, value);
  if (!words.ok()) {
    const std::string msg =
        fmt::format("{} ({}): {}", name_, endpoint_.describe(), words.error().message);
    record_error_locked(msg);
    return Error::Permanent(msg);
  }
  const std::string op = fmt::format("write {} to holding register {}", value, spec.address);
  if (Status s = ensure_connected_locked(op); !s.ok()) return s;

  const int count = static_cast<int>(words->size());
  const auto t0 = Steady::now();
  const int rc = count == 1 ? modbus_write_register(ctx_, spec.address, (*words)[0])
                            : modbus_write_registers(ctx_, spec.address, count, words->data());
  const int err = errno;
  health_.last_latency_ms = std::chrono::duration<double, std::milli>(Steady::now() - t0).count();
  if (latency_observer_) latency_observer_(health_.last_latency_ms / 1000.0);
  if (rc != count) return request_failed_locked(op, count, rc, err, "wrote");
  health_.last_success_utc = wall_time_utc_iso();
  return Status::Ok();
}

DeviceHealth ModbusDevice::health() const {
  std::lock_guard lock(mu_);
  return health_;
}

}  // namespace gyrotherm::drivers
