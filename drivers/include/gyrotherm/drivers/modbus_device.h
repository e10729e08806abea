// A Modbus device (chamber controller, probe module) reached through libmodbus.
//
// Reads and writes physical values through RegisterSpecs. Connection loss is
// transient: the next call reconnects, at most once per backoff interval
// (doubling from 100 ms to 5 s of wall time), so a dead device costs the
// control loop a timeout, not a hang. Every request and error is counted for
// the health report. Thread-safe: calls are serialised by an internal mutex.
//
// TCP hosts may be names or IPv4/IPv6 literals (resolved at each connect). A
// Modbus RTU frame has no transaction id, so after a timeout or a garbled
// reply the line is drained until it has been silent for one response
// timeout, and flushed on every connect: a late reply is never taken as the
// answer to the next request (libmodbus checks each reply's unit, function
// and byte count; that cannot tell two replies of the same shape apart).
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/devices.h"
#include "gyrotherm/drivers/registers.h"

typedef struct _modbus modbus_t;  // libmodbus handle

namespace gyrotherm::drivers {

struct ModbusEndpoint {
  std::string transport = "tcp";   // "tcp" or "rtu"
  std::string host = "127.0.0.1";  // tcp
  int port = 502;                  // tcp
  std::string device;              // rtu: serial device path
  int baud = 19200;                // rtu
  char parity = 'N';               // rtu: 'N', 'E', 'O'
  int data_bits = 8;               // rtu
  int stop_bits = 1;               // rtu
  int unit_id = 1;
  double response_timeout_s = 0.5;  // wall seconds per request

  std::string describe() const;  // "tcp 127.0.0.1:502 unit 1"
};

// Checks the spelling of a TCP host: an IPv4 literal (four numbers 0..255),
// an IPv6 literal, or a host name (RFC 1123 labels: letters, digits, '-',
// 1..63 characters each, 253 in all). Returns what is wrong, or "" when it
// is well formed; whether a name resolves is only known at connect.
std::string tcp_host_problem(std::string_view host);

class ModbusDevice {
 public:
  ModbusDevice(std::string name, ModbusEndpoint endpoint);
  ~ModbusDevice();
  ModbusDevice(const ModbusDevice&) = delete;
  ModbusDevice& operator=(const ModbusDevice&) = delete;

  // Connects now (reconnecting if connected). Transient error when the
  // device is unreachable, permanent on a bad endpoint (unknown transport...).
  Status connect();
  // Reads one value. Errors name the device, the register and the cause.
  Result<double> read(const RegisterSpec& spec);
  // Writes one value (holding registers only; an input register is a
  // permanent error).
  Status write(const RegisterSpec& spec, double value);

  DeviceHealth health() const;
  const std::string& name() const { return name_; }

  // Called with the wall duration of every request that reached the device
  // (for the latency histogram); set before use from other threads.
  void set_latency_observer(std::function<void(double seconds)> observer) {
    latency_observer_ = std::move(observer);
  }
  const ModbusEndpoint& endpoint() const { return endpoint_; }

 private:
  // `op` ("read holding register 2782") goes into the error message.
  Status connect_locked(const std::string& op);
  Status setup_and_connect_locked(modbus_t* ctx, const std::string& where);
  Status connected_locked(modbus_t* ctx);  // takes `ctx` as the connection
  double response_timeout_s() const;
  // RTU, after a timeout or a garbled reply: reads and discards until the
  // line has been silent for one response timeout (at most four in all),
  // then flushes. Returns the bytes discarded.
  std::size_t drain_line_locked();
  Status ensure_connected_locked(const std::string& op);
  void disconnect_locked();
  void record_error_locked(const std::string& what);
  // Records a failed request (rc from libmodbus, err its errno) and returns
  // the error: permanent for most exception replies, transient otherwise.
  Error request_failed_locked(const std::string& op, int count, int rc, int err,
                              std::string_view verb);

  std::string name_;
  std::function<void(double)> latency_observer_;
  ModbusEndpoint endpoint_;
  mutable std::mutex mu_;
  modbus_t* ctx_ = nullptr;  // owned; freed in disconnect_locked()
  DeviceHealth health_;
  std::chrono::steady_clock::time_point next_attempt_{};
  std::chrono::milliseconds backoff_{100};
  bool ever_connected_ = false;  // for counting reconnects
  std::string connect_error_;    // cause of the last failed connect
};

}  // namespace gyrotherm::drivers
