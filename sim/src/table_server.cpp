#include "gyrotherm/sim/table_server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <optional>

namespace gyrotherm::sim {
namespace {

// --- The command tree (TM-8004 §4: the subset the station uses) ---

enum class Sub { kRoot, kDemand, kInterlock, kMode, kRead, kLimit, kQuery, kUtility };

struct Mnemonic {
  const char* name;  // long form; any leading part of it matches
  int id;            // Sub (root level) or AclOp (leaf)
};

// Root subsystems. The first match wins, as short forms are tried in order.
constexpr Mnemonic kSubsystems[] = {
    {"DEMAND", static_cast<int>(Sub::kDemand)},   {"INTERLOCK", static_cast<int>(Sub::kInterlock)},
    {"MODE", static_cast<int>(Sub::kMode)},       {"READ", static_cast<int>(Sub::kRead)},
    {"LIMIT", static_cast<int>(Sub::kLimit)},     {"QUERY", static_cast<int>(Sub::kQuery)},
    {"UTILITY", static_cast<int>(Sub::kUtility)},
};

std::vector<Mnemonic> leaves_of(Sub sub) {
  auto op = [](AclOp o) { return static_cast<int>(o); };
  switch (sub) {
    case Sub::kDemand:
      return {{"RATE", op(AclOp::kDemandRate)}, {"POSITION", op(AclOp::kDemandPosition)}};
    case Sub::kInterlock:
      return {{"RESET", op(AclOp::kInterlockReset)},
              {"CLOSE", op(AclOp::kInterlockClose)},
              {"OPEN", op(AclOp::kInterlockOpen)}};
    case Sub::kMode:
      return {{"RATE", op(AclOp::kModeRate)},
              {"POSITION", op(AclOp::kModePosition)},
              {"OFF", op(AclOp::kModeOff)}};
    case Sub::kRead:
      return {{"POSITION", op(AclOp::kReadPosition)},
              {"RATE", op(AclOp::kReadRate)},
              {"ACCELERATION", op(AclOp::kReadAcceleration)}};
    case Sub::kLimit:
      return {{"RATE", op(AclOp::kLimitRate)},
              {"ACCELERATION", op(AclOp::kLimitAcceleration)},
              {"VELOCITYTRIP", op(AclOp::kLimitVelocityTrip)},
              {"VTRIP", op(AclOp::kLimitVelocityTrip)}};
    case Sub::kQuery:
      return {{"ERROR", op(AclOp::kQueryError)}};
    case Sub::kUtility:
      return {{"LOCKOUTMODE", op(AclOp::kLockout)}};
    case Sub::kRoot:
      break;
  }
  return {};
}

bool matches(std::string_view token, const char* name) {
  const std::string_view n(name);
  if (token.empty() || token.size() > n.size()) return false;
  for (std::size_t i = 0; i < token.size(); ++i) {
    if (std::toupper(static_cast<unsigned char>(token[i])) != n[i]) return false;
  }
  return true;
}

template <class Range>
std::optional<int> find_mnemonic(std::string_view token, const Range& list) {
  for (const Mnemonic& m : list) {
    if (matches(token, m.name)) return m.id;
  }
  return std::nullopt;
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r'))
    s.remove_suffix(1);
  return s;
}

bool iequals(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return std::toupper(static_cast<unsigned char>(x)) ==
                  std::toupper(static_cast<unsigned char>(y));
         });
}

// Where an op sits: its subsystem (for the next relative header), whether it
// may be a query, a command, and how many arguments each takes.
struct OpShape {
  Sub sub;
  bool query_ok;
  bool command_ok;
  int query_args_min, query_args_max;
  int command_args_min, command_args_max;
};

OpShape shape_of(AclOp op) {
  switch (op) {
    case AclOp::kIdn:
    case AclOp::kStb:
      return {Sub::kRoot, true, false, 0, 0, 0, 0};
    case AclOp::kLockout:
      return {Sub::kUtility, true, true, 0, 0, 1, 1};
    case AclOp::kInterlockQuery:
      return {Sub::kRoot, true, false, 1, 1, 0, 0};
    case AclOp::kInterlockReset:
      return {Sub::kInterlock, false, true, 0, 0, 0, 1};
    case AclOp::kInterlockClose:
    case AclOp::kInterlockOpen:
      return {Sub::kInterlock, false, true, 0, 0, 1, 1};
    case AclOp::kModeQuery:
      return {Sub::kRoot, true, false, 1, 1, 0, 0};
    case AclOp::kModeRate:
    case AclOp::kModePosition:
    case AclOp::kModeOff:
      return {Sub::kMode, false, true, 0, 0, 1, 1};
    case AclOp::kDemandRate:
    case AclOp::kDemandPosition:
      return {Sub::kDemand, true, true, 1, 1, 2, 2};
    case AclOp::kReadPosition:
    case AclOp::kReadRate:
    case AclOp::kReadAcceleration:
      return {Sub::kRead, true, false, 1, 1, 0, 0};
    case AclOp::kLimitRate:
    case AclOp::kLimitAcceleration:
      return {Sub::kLimit, true, true, 2, 2, 3, 3};
    case AclOp::kLimitVelocityTrip:
      // TM-8004 §4.6.9 also shows the query with the axis only (":L:V? 2").
      return {Sub::kLimit, true, true, 1, 2, 3, 3};
    case AclOp::kQueryError:
      return {Sub::kQuery, true, false, 1, 1, 0, 0};
  }
  return {Sub::kRoot, false, false, 0, 0, 0, 0};
}

AclReply error(int code) { return AclReply{code, ""}; }

std::optional<double> number(std::string_view s) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  double v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || end != s.data() + s.size() || !std::isfinite(v)) return std::nullopt;
  return v;
}

// The axis argument: 0 when good, else the error code.
int check_axis(std::string_view arg, bool query) {
  if (!query && iequals(arg, "ALL")) return kAclOk;
  const auto v = number(arg);
  if (!v || *v != std::floor(*v)) return kAclBadArguments;
  return *v == 1 ? kAclOk : kAclBadAxis;
}

// The mode letter of the limit commands (TM-8004 §4.6.2: <mode>,<axis>).
// The simulator keeps one set of limits for rate and position mode.
bool limit_mode_ok(std::string_view arg) {
  return matches(arg, "RATE") || matches(arg, "POSITION");
}

std::string fixed(double v) { return fmt::format("{:.6f}", v); }

int code_of(TableCommandResult r) {
  switch (r) {
    case TableCommandResult::kOk:
      return kAclOk;
    case TableCommandResult::kOutOfRange:
      return kAclOutOfRange;
    case TableCommandResult::kRefused:
      return kAclRefused;
  }
  return kAclRefused;
}

std::string_view interlock_word(drivers::TableInterlock i) {
  switch (i) {
    case drivers::TableInterlock::kOpen:
      return "Open";
    case drivers::TableInterlock::kClosed:
      return "Closed";
    case drivers::TableInterlock::kFault:
      return "Fault";
  }
  return "Fault";
}

// Field firmware answers the mode's name (TM-8004 §4.7 shows "P"/"R").
std::string_view mode_word(drivers::TableMode m) {
  switch (m) {
    case drivers::TableMode::kRate:
      return "Rate";
    case drivers::TableMode::kPosition:
      return "Position";
    default:
      return "Off";
  }
}

// One command on the table; a value for queries.
struct Outcome {
  int code = kAclOk;
  std::optional<std::string> value;
};

Outcome run(const AclCommand& c, RateTableModel& t, AclControllerState& controller) {
  const auto& a = c.args;
  auto axis_then = [&](std::size_t axis_index) -> int {
    return a.size() > axis_index ? check_axis(a[axis_index], c.query) : kAclOk;
  };
  switch (c.op) {
    case AclOp::kIdn:
      return {kAclOk, std::string(kAclIdentity)};
    case AclOp::kStb: {
      // Bit 0: the system interlocks summary (TM-8004 §3.10): set while the
      // interlock is latched in fault.
      const int stb = t.state().interlock == drivers::TableInterlock::kFault ? 1 : 0;
      return {kAclOk, std::to_string(stb)};
    }
    case AclOp::kLockout:
      if (c.query) return {kAclOk, std::string(controller.lockout ? "ON" : "OFF")};
      if (iequals(a[0], "ON")) {
        controller.lockout = true;
      } else if (iequals(a[0], "OFF")) {
        controller.lockout = false;
      } else {
        return {kAclOutOfRange, {}};
      }
      return {};
    case AclOp::kInterlockQuery:
      if (int e = axis_then(0)) return {e, {}};
      return {kAclOk, std::string(interlock_word(t.state().interlock))};
    case AclOp::kInterlockReset:
      if (int e = axis_then(0)) return {e, {}};
      t.reset_faults();
      return {};
    case AclOp::kInterlockClose:
      if (int e = axis_then(0)) return {e, {}};
      return {code_of(t.close_interlock()), {}};
    case AclOp::kInterlockOpen:
      if (int e = axis_then(0)) return {e, {}};
      t.open_interlock();
      return {};
    case AclOp::kModeQuery:
      if (int e = axis_then(0)) return {e, {}};
      return {kAclOk, std::string(mode_word(t.state().mode))};
    case AclOp::kModeRate:
    case AclOp::kModePosition:
    case AclOp::kModeOff: {
      if (int e = axis_then(0)) return {e, {}};
      const auto mode = c.op == AclOp::kModeRate       ? drivers::TableMode::kRate
                        : c.op == AclOp::kModePosition ? drivers::TableMode::kPosition
                                                       : drivers::TableMode::kOff;
      return {code_of(t.set_mode(mode)), {}};
    }
    case AclOp::kDemandRate:
    case AclOp::kDemandPosition: {
      if (int e = axis_then(0)) return {e, {}};
      const bool rate = c.op == AclOp::kDemandRate;
      if (c.query) {
        const auto s = t.state();
        return {kAclOk, fixed(rate ? s.rate_demand_dps : s.position_demand_deg)};
      }
      const auto v = number(a[1]);
      if (!v) return {kAclBadArguments, {}};
      return {code_of(rate ? t.set_rate_demand(*v) : t.set_position_demand(*v)), {}};
    }
    case AclOp::kReadPosition:
    case AclOp::kReadRate:
    case AclOp::kReadAcceleration: {
      if (int e = axis_then(0)) return {e, {}};
      const double v = c.op == AclOp::kReadPosition ? t.position_deg()
                       : c.op == AclOp::kReadRate   ? t.measured_rate_dps()
                                                    : t.accel_dps2();
      return {kAclOk, fixed(v)};
    }
    case AclOp::kLimitRate:
    case AclOp::kLimitAcceleration:
    case AclOp::kLimitVelocityTrip: {
      std::size_t axis_index = 1;
      if (c.query && a.size() == 1) {
        axis_index = 0;  // ":L:V? a"
      } else if (!limit_mode_ok(a[0])) {
        return {kAclOutOfRange, {}};
      }
      if (int e = axis_then(axis_index)) return {e, {}};
      const auto s = t.state();
      if (c.query) {
        const double v = c.op == AclOp::kLimitRate           ? s.rate_limit_dps
                         : c.op == AclOp::kLimitAcceleration ? s.accel_limit_dps2
                                                             : s.trip_rate_dps;
        return {kAclOk, fixed(v)};
      }
      const auto v = number(a[2]);
      if (!v) return {kAclBadArguments, {}};
      const auto r = c.op == AclOp::kLimitRate           ? t.set_rate_limit(*v)
                     : c.op == AclOp::kLimitAcceleration ? t.set_accel_limit(*v)
                                                         : t.set_trip_rate(*v);
      return {code_of(r), {}};
    }
    case AclOp::kQueryError: {
      const auto v = number(a[0]);
      if (!v || *v != std::floor(*v)) return {kAclBadArguments, {}};
      return {kAclOk, acl_error_text(static_cast<int>(*v))};
    }
  }
  return {kAclUnknownCommand, {}};
}

}  // namespace

std::string acl_error_text(int code) {
  switch (code) {
    case kAclOk:
      return "No error";
    case kAclUnknownCommand:
      return "Unknown command or bad syntax";
    case kAclBadAxis:
      return "No such axis";
    case kAclOutOfRange:
      return "Parameter out of range";
    case kAclRefused:
      return "Refused in the present state (interlock fault: reset first)";
    case kAclBadArguments:
      return "Wrong number of arguments or an argument that is not a number";
    default:
      return fmt::format("Unknown error code {}", code);
  }
}

std::variant<std::vector<AclCommand>, AclReply> parse_acl(std::string_view line) {
  std::vector<AclCommand> commands;
  Sub current = Sub::kRoot;
  std::size_t start = 0;
  for (;;) {
    const std::size_t semi = line.find(';', start);
    const std::string_view segment = trim(
        line.substr(start, semi == std::string_view::npos ? std::string_view::npos : semi - start));
    if (segment.empty()) return error(kAclUnknownCommand);  // ";;", a trailing ';'
    const std::size_t blank = segment.find_first_of(" \t");
    std::string_view header = segment.substr(0, blank);
    const std::string_view rest =
        blank == std::string_view::npos ? std::string_view() : trim(segment.substr(blank));

    AclCommand c;
    if (!header.empty() && header.back() == '?') {
      c.query = true;
      header.remove_suffix(1);
    }
    if (header.find_first_of(",?") != std::string_view::npos) return error(kAclUnknownCommand);
    std::optional<AclOp> op;
    if (!header.empty() && header.front() == '*') {
      if (iequals(header, "*IDN")) op = AclOp::kIdn;
      if (iequals(header, "*STB")) op = AclOp::kStb;
    } else {
      Sub sub = current;
      if (!header.empty() && header.front() == ':') {
        sub = Sub::kRoot;
        header.remove_prefix(1);
      }
      std::vector<std::string_view> tokens;
      for (std::size_t p = 0;;) {
        const std::size_t colon = header.find(':', p);
        tokens.push_back(header.substr(p, colon == std::string_view::npos ? colon : colon - p));
        if (colon == std::string_view::npos) break;
        p = colon + 1;
      }
      std::size_t i = 0;
      if (sub == Sub::kRoot) {
        const auto s = find_mnemonic(tokens[0], kSubsystems);
        if (!s) return error(kAclUnknownCommand);
        sub = static_cast<Sub>(*s);
        i = 1;
        if (tokens.size() == 1) {
          if (sub == Sub::kInterlock) op = AclOp::kInterlockQuery;
          if (sub == Sub::kMode) op = AclOp::kModeQuery;
        }
      }
      if (!op) {
        if (tokens.size() != i + 1) return error(kAclUnknownCommand);
        const auto leaf = find_mnemonic(tokens[i], leaves_of(sub));
        if (!leaf) return error(kAclUnknownCommand);
        op = static_cast<AclOp>(*leaf);
      }
    }
    if (!op) return error(kAclUnknownCommand);
    c.op = *op;
    const OpShape shape = shape_of(c.op);
    if (c.query ? !shape.query_ok : !shape.command_ok) return error(kAclUnknownCommand);
    if (!rest.empty()) {
      for (std::size_t p = 0;;) {
        const std::size_t comma = rest.find(',', p);
        const auto arg = trim(rest.substr(p, comma == std::string_view::npos ? comma : comma - p));
        if (arg.empty()) return error(kAclBadArguments);
        c.args.emplace_back(arg);
        if (comma == std::string_view::npos) break;
        p = comma + 1;
      }
    }
    const int n = static_cast<int>(c.args.size());
    const int lo = c.query ? shape.query_args_min : shape.command_args_min;
    const int hi = c.query ? shape.query_args_max : shape.command_args_max;
    if (n < lo || n > hi) return error(kAclBadArguments);
    commands.push_back(std::move(c));
    current = shape.sub;
    if (semi == std::string_view::npos) break;
    start = semi + 1;
  }
  return commands;
}

AclReply execute_acl(RateTableModel& table, AclControllerState& controller,
                     const std::vector<AclCommand>& commands) {
  // One frame, all or none: run on copies, keep them only if every command
  // succeeded.
  RateTableModel t = table;
  AclControllerState c = controller;
  std::string payload;
  bool any_value = false;
  for (const AclCommand& command : commands) {
    const Outcome o = run(command, t, c);
    if (o.code != kAclOk) return error(o.code);
    if (o.value) {
      if (any_value) payload += ';';
      payload += *o.value;
      any_value = true;
    }
  }
  table = std::move(t);
  controller = c;
  return AclReply{kAclOk, any_value ? payload : std::string("OK")};
}

AclReply handle_acl_line(RateTableModel& table, AclControllerState& controller,
                         std::string_view line) {
  auto parsed = parse_acl(line);
  if (auto* e = std::get_if<AclReply>(&parsed)) return *e;
  return execute_acl(table, controller, std::get<std::vector<AclCommand>>(parsed));
}

std::string frame_acl_reply(const AclReply& reply, std::string_view header) {
  const std::string& p = reply.payload;
  if (header == "line") {
    return (reply.code == kAclOk ? p : fmt::format("ERR {}", reply.code)) + "\n";
  }
  if (header == "binary-le" || header == "binary-be") {
    std::string out;
    auto put = [&](uint32_t v) {
      for (int i = 0; i < 4; ++i) {
        const int shift = header == "binary-le" ? 8 * i : 8 * (3 - i);
        out += static_cast<char>((v >> shift) & 0xff);
      }
    };
    put(static_cast<uint32_t>(reply.code));
    put(static_cast<uint32_t>(p.size()));
    return out + p;
  }
  // "ascii": payloads here are far below 10000 bytes.
  return fmt::format("{:04d}{:04d}", reply.code % 10000, p.size() % 10000) + p;
}

// --- TableServer ---

struct TableServer::Client {
  int fd = -1;
  std::string in;
  std::string out;
};

Result<std::unique_ptr<TableServer>> TableServer::start(Options options) {
  if (!options.handler) return Error::Permanent("table server: no handler");
  if (options.port < 0 || options.port > 65535) {
    return Error::Permanent(fmt::format("table server: port {} is not a TCP port", options.port));
  }
  std::unique_ptr<TableServer> server(new TableServer(std::move(options)));
  const auto& o = server->options_;
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(o.port));
  if (::inet_pton(AF_INET, o.host.c_str(), &addr.sin_addr) != 1) {
    return Error::Permanent(fmt::format("table server: '{}' is not an IPv4 address", o.host));
  }
  server->wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (server->wake_fd_ < 0)
    return Error::Permanent(std::string("eventfd: ") + std::strerror(errno));
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0)
    return Error::Transient(std::string("table server: socket(): ") + std::strerror(errno));
  server->listen_fd_ = fd;
  const int one = 1;
  ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 || ::listen(fd, 16) != 0) {
    return Error::Transient(fmt::format("table server: cannot listen on {}:{}: {}", o.host, o.port,
                                        std::strerror(errno)));
  }
  socklen_t len = sizeof addr;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  server->port_ = ntohs(addr.sin_port);
  TableServer* raw = server.get();
  server->thread_ = std::thread([raw] { raw->run(); });
  return server;
}

TableServer::TableServer(Options options) : options_(std::move(options)) {}

TableServer::~TableServer() {
  stop();
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

void TableServer::stop() {
  std::lock_guard lock(stop_mu_);
  if (stopping_.exchange(true)) return;
  wake();
  if (thread_.joinable()) thread_.join();
  if (listen_fd_ >= 0) ::close(listen_fd_);
  listen_fd_ = -1;
}

void TableServer::wake() {
  if (wake_fd_ < 0) return;
  const uint64_t one = 1;
  [[maybe_unused]] ssize_t n = ::write(wake_fd_, &one, sizeof one);
}

void TableServer::set_disconnected(bool disconnected) {
  disconnected_.store(disconnected);
  wake();  // the thread closes the clients
}

TableServerStats TableServer::stats() const {
  std::lock_guard lock(stats_mu_);
  return stats_;
}

void TableServer::run() {
  std::vector<Client> clients;
  std::vector<pollfd> fds;
  auto drop_all = [&] {
    for (Client& c : clients) ::close(c.fd);
    clients.clear();
  };
  while (!stopping_.load()) {
    if (disconnected_.load()) drop_all();
    fds.clear();
    fds.push_back({wake_fd_, POLLIN, 0});
    fds.push_back({listen_fd_, POLLIN, 0});
    for (const Client& c : clients) {
      fds.push_back({c.fd, static_cast<short>(POLLIN | (c.out.empty() ? 0 : POLLOUT)), 0});
    }
    const int n = ::poll(fds.data(), fds.size(), -1);
    if (n < 0 && errno != EINTR) break;
    if (n <= 0) continue;
    if (fds[0].revents & POLLIN) {
      uint64_t count;
      [[maybe_unused]] ssize_t r = ::read(wake_fd_, &count, sizeof count);
    }
    if (stopping_.load()) break;
    if (disconnected_.load()) {
      drop_all();
    } else {
      std::vector<std::size_t> to_close;
      for (std::size_t i = 0; i < clients.size(); ++i) {
        Client& c = clients[i];
        const short revents = fds[2 + i].revents;
        bool keep = true;
        if (revents & (POLLIN | POLLHUP | POLLERR)) {
          char buf[4096];
          const ssize_t r = ::recv(c.fd, buf, sizeof buf, 0);
          if (r > 0) {
            c.in.append(buf, static_cast<std::size_t>(r));
          } else if (r == 0 || (errno != EINTR && errno != EAGAIN && errno != EWOULDBLOCK)) {
            keep = false;
          }
        }
        std::size_t start = 0;
        while (keep) {
          const std::size_t nl = c.in.find('\n', start);
          if (nl == std::string::npos) break;
          std::string_view line(c.in.data() + start, nl - start);
          if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
          start = nl + 1;
          if (line.empty()) continue;
          if (hung_.load()) {
            std::lock_guard lock(stats_mu_);
            ++stats_.unanswered;
            continue;
          }
          try {
            c.out += options_.handler(line);
          } catch (const std::exception&) {
            c.out += frame_acl_reply(AclReply{kAclRefused, ""}, "ascii");
          }
          std::lock_guard lock(stats_mu_);
          ++stats_.requests;
        }
        c.in.erase(0, start);
        if (c.in.size() > options_.max_line_bytes) keep = false;
        while (keep && !c.out.empty()) {
          const ssize_t w = ::send(c.fd, c.out.data(), c.out.size(), MSG_NOSIGNAL);
          if (w > 0) {
            c.out.erase(0, static_cast<std::size_t>(w));
          } else if (w < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            break;
          } else if (!(w < 0 && errno == EINTR)) {
            keep = false;
          }
        }
        if (c.out.size() > (1u << 20)) keep = false;  // a client that never reads
        if (!keep) to_close.push_back(i);
      }
      for (auto it = to_close.rbegin(); it != to_close.rend(); ++it) {
        ::close(clients[*it].fd);
        clients.erase(clients.begin() + static_cast<std::ptrdiff_t>(*it));
      }
    }
    if (fds[1].revents & POLLIN) {
      for (;;) {
        const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0) break;
        if (disconnected_.load() || clients.size() >= options_.max_clients) {
          ::close(fd);  // refused: the client sees the connection closed
          std::lock_guard lock(stats_mu_);
          ++stats_.refused_connections;
          continue;
        }
        clients.push_back(Client{fd, {}, {}});
        std::lock_guard lock(stats_mu_);
        ++stats_.connections;
      }
    }
  }
  drop_all();
}

}  // namespace gyrotherm::sim
