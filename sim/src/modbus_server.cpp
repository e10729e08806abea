#include "gyrotherm/sim/modbus_server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <set>

namespace gyrotherm::sim {
namespace {

using SteadyClock = std::chrono::steady_clock;

constexpr int kUnitIdOffset = 6;  // MBAP header: transaction, protocol, length, unit id
constexpr int kFunctionOffset = 7;

bool is_write_function(int function) {
  return function == MODBUS_FC_WRITE_SINGLE_REGISTER ||
         function == MODBUS_FC_WRITE_MULTIPLE_REGISTERS ||
         function == MODBUS_FC_WRITE_AND_READ_REGISTERS;
}

std::string errno_text() { return std::strerror(errno); }

}  // namespace

struct ModbusServer::DeviceImage {
  int unit_id = 0;
  Device device;  // the served registers and the write check
  modbus_mapping_t* mapping = nullptr;
  int holding_start = 0;
  int input_start = 0;

  ~DeviceImage() {
    if (mapping) modbus_mapping_free(mapping);
  }
  // Pointer to the registers of `spec`, or null when outside the image.
  uint16_t* words(const drivers::RegisterSpec& spec) const {
    const bool holding = spec.function == drivers::RegisterFunction::kHolding;
    const int start = holding ? holding_start : input_start;
    const int count = holding ? mapping->nb_registers : mapping->nb_input_registers;
    const int offset = spec.address - start;
    if (offset < 0 || offset + spec.word_count() > count) return nullptr;
    return (holding ? mapping->tab_registers : mapping->tab_input_registers) + offset;
  }
};

struct ModbusServer::Client {
  int fd = -1;
  bool has_pending = false;  // a request waiting for its delayed answer
  std::vector<uint8_t> pending;
  SteadyClock::time_point due{};
};

Result<std::unique_ptr<ModbusServer>> ModbusServer::start(Options options) {
  // Validate: distinct unit ids, no two registers of a device sharing a word.
  std::set<int> units;
  for (const Device& d : options.devices) {
    if (d.unit_id < 0 || d.unit_id > 255) {
      return Error::Permanent(fmt::format("Modbus unit id {} is out of range", d.unit_id));
    }
    if (!units.insert(d.unit_id).second) {
      return Error::Permanent(fmt::format(
          "two simulated devices share Modbus unit id {}; give the chamber and the probe "
          "module distinct unit_id values",
          d.unit_id));
    }
    for (std::size_t i = 0; i < d.registers.size(); ++i) {
      for (std::size_t j = i + 1; j < d.registers.size(); ++j) {
        const auto& a = d.registers[i];
        const auto& b = d.registers[j];
        if (a.function == b.function && a.address < b.address + b.word_count() &&
            b.address < a.address + a.word_count()) {
          return Error::Permanent(fmt::format("unit {}: registers at {} and {} overlap", d.unit_id,
                                              a.address, b.address));
        }
      }
    }
  }
  std::unique_ptr<ModbusServer> server(new ModbusServer(std::move(options)));
  for (const Device& d : server->options_.devices) {
    auto image = std::make_unique<DeviceImage>();
    image->unit_id = d.unit_id;
    image->device = d;
    int hr_lo = 65536, hr_hi = -1, ir_lo = 65536, ir_hi = -1;
    for (const auto& spec : d.registers) {
      if (spec.address < 0 || spec.address + spec.word_count() > 65536) {
        return Error::Permanent(fmt::format("register address {} out of range", spec.address));
      }
      const int last = spec.address + spec.word_count() - 1;
      if (spec.function == drivers::RegisterFunction::kHolding) {
        hr_lo = std::min(hr_lo, spec.address);
        hr_hi = std::max(hr_hi, last);
      } else {
        ir_lo = std::min(ir_lo, spec.address);
        ir_hi = std::max(ir_hi, last);
      }
    }
    image->holding_start = hr_hi >= 0 ? hr_lo : 0;
    image->input_start = ir_hi >= 0 ? ir_lo : 0;
    image->mapping =
        modbus_mapping_new_start_address(0, 0, 0, 0, static_cast<unsigned>(image->holding_start),
                                         static_cast<unsigned>(hr_hi >= 0 ? hr_hi - hr_lo + 1 : 0),
                                         static_cast<unsigned>(image->input_start),
                                         static_cast<unsigned>(ir_hi >= 0 ? ir_hi - ir_lo + 1 : 0));
    if (!image->mapping) {
      return Error::Permanent(
          fmt::format("cannot allocate the register image: {}", modbus_strerror(errno)));
    }
    server->devices_.push_back(std::move(image));
  }
  if (Status s = server->listen(); !s.ok()) return s.error();
  server->thread_ = std::thread([s = server.get()] { s->run(); });
  return server;
}

ModbusServer::ModbusServer(Options options) : options_(std::move(options)) {}

ModbusServer::~ModbusServer() {
  stop();
  if (ctx_) modbus_free(ctx_);
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

Status ModbusServer::listen() {
  ctx_ = modbus_new_tcp(options_.host.c_str(), options_.port);
  if (!ctx_) return Error::Permanent(fmt::format("modbus_new_tcp: {}", modbus_strerror(errno)));
  // A client that sends half a request must not hold the server for long.
  modbus_set_byte_timeout(ctx_, 0, 200'000);

  wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (wake_fd_ < 0) return Error::Permanent(fmt::format("eventfd: {}", errno_text()));

  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(options_.port));
  if (::inet_pton(AF_INET, options_.host.c_str(), &addr.sin_addr) != 1) {
    return Error::Permanent(
        fmt::format("Modbus server: '{}' is not an IPv4 address", options_.host));
  }
  listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (listen_fd_ < 0) return Error::Transient(fmt::format("socket: {}", errno_text()));
  const int one = 1;
  ::setsockopt(listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 ||
      ::listen(listen_fd_, 16) != 0) {
    const std::string why = errno_text();
    ::close(listen_fd_);
    listen_fd_ = -1;
    return Error::Transient(fmt::format("Modbus server: cannot listen on {}:{}: {}", options_.host,
                                        options_.port, why));
  }
  // Port 0 picked a free port: ask which (modbus_tcp_listen cannot tell).
  socklen_t len = sizeof addr;
  ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len);
  port_ = ntohs(addr.sin_port);
  return Status::Ok();
}

void ModbusServer::stop() {
  if (stopping_.exchange(true)) return;
  wake();
  if (thread_.joinable()) thread_.join();
  for (Client& c : clients_) ::close(c.fd);
  clients_.clear();
  if (listen_fd_ >= 0) ::close(listen_fd_);
  listen_fd_ = -1;
  std::lock_guard lock(stats_mu_);
  stats_.active_connections = 0;
}

void ModbusServer::wake() {
  if (wake_fd_ < 0) return;
  const uint64_t one = 1;
  [[maybe_unused]] ssize_t n = ::write(wake_fd_, &one, sizeof one);
}

void ModbusServer::set_down(bool down) {
  down_.store(down);
  wake();
}

void ModbusServer::set_reply_delay_s(double wall_s) {
  reply_delay_s_.store(std::isfinite(wall_s) && wall_s > 0 ? wall_s : 0.0);
  wake();
}

ModbusServerStats ModbusServer::stats() const {
  std::lock_guard lock(stats_mu_);
  return stats_;
}

ModbusServer::DeviceImage* ModbusServer::find(int unit_id) const {
  for (const auto& d : devices_) {
    if (d->unit_id == unit_id) return d.get();
  }
  return nullptr;
}

Status ModbusServer::set(int unit_id, const drivers::RegisterSpec& spec, double value) {
  DeviceImage* d = find(unit_id);
  if (!d) return Error::Permanent(fmt::format("no simulated device with unit id {}", unit_id));
  auto words = drivers::encode_register(spec, value);
  if (!words.ok()) return words.error();
  std::lock_guard lock(image_mu_);
  uint16_t* dst = d->words(spec);
  if (!dst) {
    return Error::Permanent(
        fmt::format("unit {}: register {} is outside the image", unit_id, spec.address));
  }
  std::copy(words->begin(), words->end(), dst);
  return Status::Ok();
}

Result<double> ModbusServer::get(int unit_id, const drivers::RegisterSpec& spec) const {
  DeviceImage* d = find(unit_id);
  if (!d) return Error::Permanent(fmt::format("no simulated device with unit id {}", unit_id));
  std::lock_guard lock(image_mu_);
  const uint16_t* src = d->words(spec);
  if (!src) {
    return Error::Permanent(
        fmt::format("unit {}: register {} is outside the image", unit_id, spec.address));
  }
  return drivers::decode_register(
      spec, std::span<const uint16_t>(src, static_cast<std::size_t>(spec.word_count())));
}

void ModbusServer::accept_clients() {
  for (;;) {
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (fd < 0) return;  // EAGAIN (drained) or a transient accept error
    if (down_.load() || clients_.size() >= options_.max_connections) {
      ::close(fd);
      std::lock_guard lock(stats_mu_);
      ++stats_.refused_connections;
      continue;
    }
    const int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    Client client;
    client.fd = fd;
    clients_.push_back(std::move(client));
    std::lock_guard lock(stats_mu_);
    ++stats_.connections;
    stats_.active_connections = clients_.size();
  }
}

void ModbusServer::close_client(std::size_t index) {
  ::close(clients_[index].fd);
  clients_.erase(clients_.begin() + static_cast<std::ptrdiff_t>(index));
  std::lock_guard lock(stats_mu_);
  stats_.active_connections = clients_.size();
}

// Answers one request on the client's socket. A failed send shows up as a
// hang-up on the next poll.
void ModbusServer::answer(Client& client, const std::vector<uint8_t>& request) {
  const int unit_id = request[kUnitIdOffset];
  const int function = request[kFunctionOffset];
  modbus_set_socket(ctx_, client.fd);
  DeviceImage* d = find(unit_id);
  if (!d) {
    {
      std::lock_guard lock(stats_mu_);
      ++stats_.unknown_unit_requests;
    }
    modbus_reply_exception(ctx_, request.data(), MODBUS_EXCEPTION_GATEWAY_TARGET);
    return;
  }
  if (const int code = check_request(*d, request); code != 0) {
    modbus_reply_exception(ctx_, request.data(), static_cast<unsigned>(code));
    return;
  }
  int rc;
  {
    std::lock_guard lock(image_mu_);
    rc = modbus_reply(ctx_, request.data(), static_cast<int>(request.size()), d->mapping);
  }
  if (rc >= 0 && is_write_function(function) && options_.on_write) options_.on_write(unit_id);
}

int ModbusServer::check_request(const DeviceImage& d, const std::vector<uint8_t>& request) const {
  using drivers::RegisterFunction;
  const std::size_t n = request.size();
  auto u16 = [&](std::size_t at) -> int {
    return at + 1 < n ? (request[at] << 8) | request[at + 1] : -1;
  };
  const auto& registers = d.device.registers;
  // Every address of [address, address + count) lies in a served register.
  auto covered = [&](RegisterFunction fn, int address, int count) {
    for (int a = address; a < address + count; ++a) {
      const bool in = std::any_of(registers.begin(), registers.end(), [&](const auto& r) {
        return r.function == fn && a >= r.address && a < r.address + r.word_count();
      });
      if (!in) return false;
    }
    return true;
  };
  // A write of `words` from `address`: 0 when every touched register may
  // take the value it would hold.
  auto check_write = [&](int address, const std::vector<uint16_t>& words) -> int {
    const int count = static_cast<int>(words.size());
    if (address < 0 || count <= 0 || !covered(RegisterFunction::kHolding, address, count)) {
      return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    }
    std::vector<std::pair<const drivers::RegisterSpec*, double>> values;
    for (const auto& r : registers) {
      if (r.function != RegisterFunction::kHolding || r.address >= address + count ||
          address >= r.address + r.word_count()) {
        continue;
      }
      if (r.read_only) return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
      std::vector<uint16_t> image(static_cast<std::size_t>(r.word_count()));
      {
        std::lock_guard lock(image_mu_);
        const uint16_t* src = d.words(r);
        if (src) std::copy(src, src + r.word_count(), image.begin());
      }
      for (int k = 0; k < r.word_count(); ++k) {
        const int a = r.address + k;
        if (a >= address && a < address + count) {
          image[static_cast<std::size_t>(k)] = words[static_cast<std::size_t>(a - address)];
        }
      }
      values.emplace_back(&r, drivers::decode_register(r, image));
    }
    if (d.device.accept_write) {
      for (const auto& [spec, value] : values) {
        if (!d.device.accept_write(*spec, value)) return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
      }
    }
    return 0;
  };
  auto words_at = [&](std::size_t at, int count) {
    std::vector<uint16_t> words;
    for (int k = 0; k < count; ++k) {
      const int w = u16(at + 2 * static_cast<std::size_t>(k));
      if (w < 0) return std::vector<uint16_t>{};
      words.push_back(static_cast<uint16_t>(w));
    }
    return words;
  };
  const int function = request[kFunctionOffset];
  const std::size_t data = kFunctionOffset + 1;
  switch (function) {
    case MODBUS_FC_READ_HOLDING_REGISTERS:
    case MODBUS_FC_READ_INPUT_REGISTERS: {
      const int address = u16(data), count = u16(data + 2);
      if (address < 0 || count < 1 || count > MODBUS_MAX_READ_REGISTERS) return 0;  // libmodbus
      const auto fn = function == MODBUS_FC_READ_HOLDING_REGISTERS ? RegisterFunction::kHolding
                                                                   : RegisterFunction::kInput;
      return covered(fn, address, count) ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    }
    case MODBUS_FC_WRITE_SINGLE_REGISTER:
      return check_write(u16(data), words_at(data + 2, 1));
    case MODBUS_FC_WRITE_MULTIPLE_REGISTERS: {
      const int count = u16(data + 2);
      if (count < 1 || count > MODBUS_MAX_WRITE_REGISTERS) return 0;  // libmodbus answers
      return check_write(u16(data), words_at(data + 5, count));
    }
    case MODBUS_FC_WRITE_AND_READ_REGISTERS: {
      const int read_address = u16(data), read_count = u16(data + 2);
      const int write_count = u16(data + 6);
      if (read_count < 1 || read_count > MODBUS_MAX_WR_READ_REGISTERS || write_count < 1 ||
          write_count > MODBUS_MAX_WR_WRITE_REGISTERS) {
        return 0;  // libmodbus answers
      }
      if (const int code = check_write(u16(data + 4), words_at(data + 9, write_count))) {
        return code;
      }
      return covered(RegisterFunction::kHolding, read_address, read_count)
                 ? 0
                 : MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    }
    case MODBUS_FC_MASK_WRITE_REGISTER:
      return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;  // not offered, as most controllers
    default:
      return 0;  // libmodbus answers (coils: none served, exception 0x02)
  }
}

void ModbusServer::run() {
  std::vector<pollfd> fds;
  std::vector<std::size_t> polled;  // client index of fds[2 + i]
  std::vector<uint8_t> buf(MODBUS_TCP_MAX_ADU_LENGTH);
  while (!stopping_.load()) {
    if (down_.load()) {
      while (!clients_.empty()) close_client(clients_.size() - 1);
    }
    fds.clear();
    polled.clear();
    fds.push_back({wake_fd_, POLLIN, 0});
    fds.push_back({listen_fd_, POLLIN, 0});
    int timeout_ms = -1;
    const auto now = SteadyClock::now();
    for (std::size_t i = 0; i < clients_.size(); ++i) {
      if (clients_[i].has_pending) {
        const auto wait = std::chrono::ceil<std::chrono::milliseconds>(clients_[i].due - now);
        const int ms = static_cast<int>(std::max<int64_t>(0, wait.count()));
        timeout_ms = timeout_ms < 0 ? ms : std::min(timeout_ms, ms);
        continue;  // one request at a time per connection, as a real device
      }
      fds.push_back({clients_[i].fd, POLLIN, 0});
      polled.push_back(i);
    }
    const int n = ::poll(fds.data(), fds.size(), timeout_ms);
    if (n < 0 && errno != EINTR) break;
    if (n > 0 && (fds[0].revents & POLLIN)) {
      uint64_t count;
      [[maybe_unused]] ssize_t r = ::read(wake_fd_, &count, sizeof count);
    }
    if (stopping_.load()) break;
    if (n > 0 && (fds[1].revents & POLLIN)) accept_clients();

    std::vector<std::size_t> to_close;
    for (std::size_t k = 0; n > 0 && k < polled.size(); ++k) {
      if (!(fds[2 + k].revents & (POLLIN | POLLHUP | POLLERR))) continue;
      Client& c = clients_[polled[k]];
      modbus_set_socket(ctx_, c.fd);
      const int len = modbus_receive(ctx_, buf.data());
      if (len < 0) {  // closed by the client, or a broken request
        to_close.push_back(polled[k]);
        continue;
      }
      if (len == 0) continue;
      {
        std::lock_guard lock(stats_mu_);
        ++stats_.requests;
      }
      std::vector<uint8_t> request(buf.begin(), buf.begin() + len);
      const double delay_s = reply_delay_s_.load();
      if (delay_s > 0) {
        c.has_pending = true;
        c.pending = std::move(request);
        c.due = SteadyClock::now() + std::chrono::duration_cast<SteadyClock::duration>(
                                         std::chrono::duration<double>(delay_s));
      } else {
        answer(c, request);
      }
    }
    const auto after = SteadyClock::now();
    for (Client& c : clients_) {
      if (c.has_pending && c.due <= after) {
        c.has_pending = false;
        answer(c, c.pending);
      }
    }
    std::sort(to_close.rbegin(), to_close.rend());
    for (std::size_t i : to_close) close_client(i);
  }
  modbus_set_socket(ctx_, -1);
}

}  // namespace gyrotherm::sim
