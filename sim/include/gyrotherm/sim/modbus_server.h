// Modbus TCP server of the simulated station, on libmodbus's server API
// (modbus_receive / modbus_reply, as libmodbus's own test servers).
//
// Serves several devices, told apart by the request's unit id, each with its
// own register image: exactly the RegisterSpecs it was given, as a real
// controller serves its data map. Several clients at once: one thread polls
// the listening socket and every connection. Answers, as a Watlow
// controller does (Watlow's communications guides: exception 02 for a
// parameter that cannot be accessed, 03 for a value out of range):
//   - a unit id nobody serves: exception 0x0B (gateway target device failed
//     to respond), so a client fails at once instead of waiting for its
//     timeout;
//   - a read or write touching any address no register covers: exception
//     0x02 (illegal data address), even between two served registers;
//   - a write touching a read-only register (RegisterSpec::read_only):
//     exception 0x02 too: for a write, that address is not an allowable
//     one; the request is valid in form, so not 0x03;
//   - a write whose value the device's `accept_write` refuses (a set point
//     out of range, an unknown enumeration): exception 0x03 (illegal data
//     value), nothing written.
// Coils and discrete inputs are not served (exception 0x02).
//
// Thread-safe: the image is read and written under one mutex by the server
// thread and by set()/get().
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/registers.h"

typedef struct _modbus modbus_t;

namespace gyrotherm::sim {

struct ModbusServerStats {
  uint64_t connections = 0;  // accepted (and kept) connections, total
  uint64_t active_connections = 0;
  uint64_t requests = 0;  // requests received
  uint64_t unknown_unit_requests = 0;
  uint64_t refused_connections = 0;  // closed at once while down or over the limit
};

class ModbusServer {
 public:
  struct Device {
    int unit_id = 1;
    std::vector<drivers::RegisterSpec> registers;  // what the image must hold
    // Called on the server thread, without the image lock, for each register
    // a write request touches, with the value it would hold; false refuses
    // the whole request with exception 0x03. Unset: every value is taken.
    std::function<bool(const drivers::RegisterSpec& spec, double value)> accept_write;
  };
  struct Options {
    std::string host = "127.0.0.1";  // IPv4 address to bind
    int port = 0;                    // 0 = any free port
    std::vector<Device> devices;     // distinct unit ids
    // Called on the server thread, after a write request (function 0x06,
    // 0x10 or 0x17) to `unit_id` was applied to the image and answered. It
    // may call set()/get().
    std::function<void(int unit_id)> on_write;
    std::size_t max_connections = 32;
  };

  // Binds, listens and starts the server thread. Permanent error on bad
  // options (duplicate unit ids, overlapping registers), transient when the
  // port cannot be bound.
  static Result<std::unique_ptr<ModbusServer>> start(Options options);
  ~ModbusServer();  // stop()
  ModbusServer(const ModbusServer&) = delete;
  ModbusServer& operator=(const ModbusServer&) = delete;

  void stop();  // idempotent: closes every connection and the listening socket
  int port() const { return port_; }

  // Writes / reads one value of a device's image. Errors: unknown unit,
  // register outside the image, value that does not fit the register.
  Status set(int unit_id, const drivers::RegisterSpec& spec, double value);
  Result<double> get(int unit_id, const drivers::RegisterSpec& spec) const;

  // Fault injection. Down: every connection is closed and new ones are
  // accepted and closed at once. Delay: each request is answered `wall_s`
  // wall seconds after it arrived (other connections are still served).
  void set_down(bool down);
  void set_reply_delay_s(double wall_s);
  bool down() const { return down_.load(); }
  double reply_delay_s() const { return reply_delay_s_.load(); }

  ModbusServerStats stats() const;

 private:
  struct DeviceImage;
  struct Client;

  explicit ModbusServer(Options options);
  Status listen();
  void run();
  void accept_clients();
  void close_client(std::size_t index);
  void answer(Client& client, const std::vector<uint8_t>& request);
  // The exception code a request must get before libmodbus sees it, or 0.
  int check_request(const DeviceImage& device, const std::vector<uint8_t>& request) const;
  void wake();
  DeviceImage* find(int unit_id) const;

  Options options_;
  std::vector<std::unique_ptr<DeviceImage>> devices_;
  int listen_fd_ = -1;
  int wake_fd_ = -1;  // eventfd
  int port_ = 0;
  modbus_t* ctx_ = nullptr;      // framing only; socket set per request
  std::vector<Client> clients_;  // server thread only
  std::thread thread_;
  std::atomic<bool> stopping_{false};
  std::atomic<bool> down_{false};
  std::atomic<double> reply_delay_s_{0.0};
  mutable std::mutex image_mu_;
  mutable std::mutex stats_mu_;
  ModbusServerStats stats_;
};

}  // namespace gyrotherm::sim
