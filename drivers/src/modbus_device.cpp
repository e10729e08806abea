#include "gyrotherm/drivers/modbus_device.h"

#include <fmt/format.h>
#include <modbus/modbus.h>

#include <algorithm>
#include <array>
#include <cerrno>

#include "gyrotherm/core/clock.h"

namespace gyrotherm::drivers {
namespace {

using Steady = std::chrono::steady_clock;
constexpr std::chrono::milliseconds kMinBackoff{100};
constexpr std::chrono::milliseconds kMaxBackoff{5000};

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

}  // namespace

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

  modbus_t* ctx = nullptr;
  if (endpoint_.transport == "tcp") {
    if (endpoint_.port <= 0 || endpoint_.port > 65535) {
      return permanent(fmt::format("{}: invalid TCP port {}", where, endpoint_.port));
    }
    ctx = modbus_new_tcp(endpoint_.host.c_str(), endpoint_.port);
  } else if (endpoint_.transport == "rtu") {
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
  if (modbus_set_slave(ctx, endpoint_.unit_id) != 0) {
    const std::string cause = modbus_strerror(errno);
    modbus_free(ctx);
    return permanent(fmt::format("{}: invalid unit id {}: {}", where, endpoint_.unit_id, cause));
  }
  const double timeout_s = endpoint_.response_timeout_s > 0 ? endpoint_.response_timeout_s : 0.5;
  const auto timeout_us = static_cast<uint64_t>(timeout_s * 1e6);
  modbus_set_response_timeout(ctx, static_cast<uint32_t>(timeout_us / 1000000),
                              static_cast<uint32_t>(timeout_us % 1000000));

  if (modbus_connect(ctx) != 0) {
    connect_error_ = fmt::format("cannot connect: {}", modbus_strerror(errno));
    const std::string msg = fmt::format("{}: {}", where, connect_error_);
    modbus_free(ctx);
    record_error_locked(msg);
    next_attempt_ = Steady::now() + backoff_;
    backoff_ = std::min(backoff_ * 2, kMaxBackoff);
    return Error::Transient(msg);
  }
  ctx_ = ctx;
  health_.connected = true;
  if (ever_connected_) ++health_.reconnects;
  ever_connected_ = true;
  backoff_ = kMinBackoff;
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
  const std::string msg = fmt::format(
      "{} ({}): {} ({} word{}) failed: {}", name_, endpoint_.describe(), op, count,
      count == 1 ? "" : "s",
      rc < 0 ? std::string(modbus_strerror(err)) : fmt::format("{} {} words", verb, rc));
  record_error_locked(msg);
  // A short reply or a Modbus exception: the link is fine, the request not.
  if (rc >= 0 || is_exception_reply(err)) return Error{msg, rc >= 0 || is_transient_exception(err)};
  disconnect_locked();  // the next call reconnects
  return Error::Transient(msg);
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
