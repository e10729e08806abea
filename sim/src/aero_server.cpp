#include "gyrotherm/sim/aero_server.h"

#include <fmt/format.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>

namespace gyrotherm::sim {
namespace {

std::string framed(std::string_view reply) { return std::string(reply) + "\r>\r"; }

std::optional<double> parse_number(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  double v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (s.empty() || ec != std::errc() || end != s.data() + s.size() || !std::isfinite(v)) {
    return std::nullopt;
  }
  return v;
}

// nullopt = error ("?"); otherwise the reply line.
std::optional<std::string> run(RateTableModel& t, std::string_view mnemonic,
                               std::string_view rest) {
  using drivers::TableMode;
  const bool has_number = rest.find_first_not_of(" \t") != std::string_view::npos;
  const auto value = parse_number(rest);
  auto ok = [](TableCommandResult r) { return r == TableCommandResult::kOk; };
  if (mnemonic == "PVE" || mnemonic == "PPO" || mnemonic == "STA" || mnemonic == "STO" ||
      mnemonic == "HOM" || mnemonic == "RST") {
    if (has_number) return std::nullopt;
    if (mnemonic == "PVE") return fmt::format("{:.6f}", t.measured_rate_dps());
    if (mnemonic == "PPO") return fmt::format("{:.6f}", t.position_deg());
    if (mnemonic == "STA") {
      const auto s = t.state();
      int status = 0;
      if (s.interlock == drivers::TableInterlock::kFault) status |= 1;
      if (s.interlock != drivers::TableInterlock::kClosed) status |= 2;
      return std::to_string(status);
    }
    if (mnemonic == "STO")
      return ok(t.set_mode(TableMode::kOff)) ? std::optional<std::string>("") : std::nullopt;
    if (mnemonic == "RST") {
      t.reset_faults();
      return "";
    }
    // HOM
    if (!ok(t.close_interlock()) || !ok(t.set_position_demand(0)) ||
        !ok(t.set_mode(TableMode::kPosition))) {
      return std::nullopt;
    }
    return "";
  }
  if (mnemonic == "JOG" || mnemonic == "MOV" || mnemonic == "ACL" || mnemonic == "VEL") {
    if (!value) return std::nullopt;
    bool done = false;
    if (mnemonic == "JOG") {
      done = ok(t.set_rate_demand(*value)) && ok(t.close_interlock()) &&
             ok(t.set_mode(TableMode::kRate));
    } else if (mnemonic == "MOV") {
      done = ok(t.set_position_demand(*value)) && ok(t.close_interlock()) &&
             ok(t.set_mode(TableMode::kPosition));
    } else if (mnemonic == "ACL") {
      done = ok(t.set_accel_limit(*value));
    } else {
      done = ok(t.set_rate_limit(*value));
    }
    return done ? std::optional<std::string>("") : std::nullopt;
  }
  return std::nullopt;
}

}  // namespace

std::string handle_aero_line(RateTableModel& table, std::string_view line) {
  while (!line.empty() && (line.front() == ' ' || line.front() == '\t')) line.remove_prefix(1);
  if (line.size() < 3) return framed("?");
  std::string mnemonic;
  for (char c : line.substr(0, 3))
    mnemonic += static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  RateTableModel t = table;  // all or none
  const auto reply = run(t, mnemonic, line.substr(3));
  if (!reply) return framed("?");
  table = std::move(t);
  return framed(*reply);
}

Result<std::unique_ptr<AeroServer>> AeroServer::start(Handler handler) {
  auto pty = drivers::Pty::open(/*nonblocking_master=*/true);
  if (!pty.ok()) return pty.error();
  std::unique_ptr<AeroServer> server(new AeroServer(std::move(pty).value(), std::move(handler)));
  server->wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (server->wake_fd_ < 0)
    return Error::Permanent(std::string("eventfd: ") + std::strerror(errno));
  AeroServer* raw = server.get();
  server->thread_ = std::thread([raw] { raw->run(); });
  return server;
}

AeroServer::AeroServer(drivers::Pty pty, Handler handler)
    : pty_(std::move(pty)), handler_(std::move(handler)) {}

AeroServer::~AeroServer() {
  stop();
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

void AeroServer::stop() {
  std::lock_guard lock(stop_mu_);
  if (stopping_.exchange(true)) return;
  if (wake_fd_ >= 0) {
    const uint64_t one = 1;
    [[maybe_unused]] ssize_t n = ::write(wake_fd_, &one, sizeof one);
  }
  if (thread_.joinable()) thread_.join();
  pty_.close_master();
}

void AeroServer::run() {
  std::string in;
  char buf[1024];
  while (!stopping_.load()) {
    pollfd fds[2] = {{wake_fd_, POLLIN, 0}, {pty_.master_fd(), POLLIN, 0}};
    const int n = ::poll(fds, 2, -1);
    if (n < 0 && errno != EINTR) break;
    if (stopping_.load()) break;
    if (n <= 0 || !(fds[1].revents & POLLIN)) continue;
    const ssize_t r = ::read(pty_.master_fd(), buf, sizeof buf);
    if (r <= 0) continue;
    in.append(buf, static_cast<std::size_t>(r));
    std::size_t start = 0;
    for (;;) {
      const std::size_t end = in.find_first_of("\r\n", start);
      if (end == std::string::npos) break;
      const std::string_view line(in.data() + start, end - start);
      start = end + 1;
      if (line.empty()) continue;  // the "\n" of "\r\n"
      if (silent_.load()) continue;
      ++requests_;
      const std::string reply = handler_(line);
      (void)pty_.write_master(
          std::span(reinterpret_cast<const uint8_t*>(reply.data()), reply.size()));
    }
    in.erase(0, start);
    if (in.size() > 4096) in.clear();  // a line that never ends
  }
}

}  // namespace gyrotherm::sim
