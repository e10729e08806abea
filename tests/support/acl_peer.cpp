#include "acl_peer.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cstdio>

namespace gyrotherm::testing {
namespace {

std::string trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
  return std::string(s);
}

std::string upper(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return out;
}

// TM-8004 §2.1: a mnemonic may be shortened; the manual's own examples use
// one letter (`:I:C 1`, `:U:L ON`). The first name in `names` that the token
// begins is taken, so the order settles `C` (Close, before anything else).
std::optional<std::string> resolve(std::string_view token,
                                   std::initializer_list<const char*> names) {
  const std::string t = upper(token);
  if (t.empty()) return std::nullopt;
  for (const char* n : names) {
    if (std::string_view(n).substr(0, t.size()) == t) return std::string(n);
  }
  return std::nullopt;
}

std::vector<std::string> split(std::string_view s, char sep) {
  std::vector<std::string> out;
  for (;;) {
    const auto at = s.find(sep);
    out.push_back(trim(s.substr(0, at)));
    if (at == std::string_view::npos) break;
    s.remove_prefix(at + 1);
  }
  return out;
}

std::optional<double> number(const std::string& s) {
  double v = 0;
  const char* first = s.data();
  if (!s.empty() && *first == '+') ++first;
  const auto [end, ec] = std::from_chars(first, s.data() + s.size(), v);
  if (s.empty() || ec != std::errc() || end != s.data() + s.size()) return std::nullopt;
  return v;
}

std::string format(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.6f", v);
  return buf;
}

}  // namespace

AclPeer::AclPeer() : AclPeer(Options{}) {}

AclPeer::AclPeer(Options options)
    : options_(std::move(options)), end_(std::make_unique<PeerEnd>(options_.transport)) {
  thread_ = std::thread([this] { run(); });
}

AclPeer::~AclPeer() {
  stop_ = true;
  thread_.join();
}

std::vector<AclPeer::Entry> AclPeer::log() const {
  std::lock_guard lock(mu_);
  return log_;
}

std::vector<std::string> AclPeer::commands() const {
  std::vector<std::string> out;
  for (const Entry& e : log()) out.push_back(e.command);
  return out;
}

std::vector<std::string> AclPeer::commands_of(int connection) const {
  std::vector<std::string> out;
  for (const Entry& e : log()) {
    if (e.connection == connection) out.push_back(e.command);
  }
  return out;
}

void AclPeer::clear_log() {
  std::lock_guard lock(mu_);
  log_.clear();
}

AclPeer::State AclPeer::state() const {
  std::lock_guard lock(mu_);
  return state_;
}

void AclPeer::set_state(const State& state) {
  std::lock_guard lock(mu_);
  state_ = state;
}

void AclPeer::refuse(std::string prefix, uint32_t code, std::string text) {
  std::lock_guard lock(mu_);
  refusals_.push_back({upper(prefix), code, std::move(text)});
}

void AclPeer::run() {
  std::string buf;
  while (!stop_) {
    PeerEnd::Received in = end_->receive(10);
    if (in.new_connection) buf.clear();
    buf += in.bytes;
    // TM-8004 §2.4: a message ends at LF (CR LF accepted).
    for (auto lf = buf.find('\n'); lf != std::string::npos; lf = buf.find('\n')) {
      std::string line = buf.substr(0, lf);
      buf.erase(0, lf + 1);
      if (!line.empty() && line.back() == '\r') line.pop_back();
      if (auto out = answer_line(line, end_->connections())) end_->send(*out);
    }
  }
}

std::string AclPeer::frame(uint32_t code, const std::string& payload) const {
  switch (options_.framing) {
    case Framing::kAscii: {
      char head[16];
      std::snprintf(head, sizeof head, "%04u%04zu", code % 10000, payload.size() % 10000);
      return head + payload;
    }
    case Framing::kBinaryLe:
    case Framing::kBinaryBe: {
      std::string out;
      for (uint32_t v : {code, static_cast<uint32_t>(payload.size())}) {
        for (int i = 0; i < 4; ++i) {
          const int shift = options_.framing == Framing::kBinaryLe ? 8 * i : 8 * (3 - i);
          out += static_cast<char>((v >> shift) & 0xff);
        }
      }
      return out + payload;
    }
    case Framing::kLine:
      return payload.ends_with("\n") ? payload : payload + "\r\n";
  }
  return payload;
}

std::optional<std::string> AclPeer::answer_line(const std::string& line, int connection) {
  const auto now = std::chrono::steady_clock::now();
  const std::vector<std::string> segments = split(line, ';');
  {
    std::lock_guard lock(mu_);
    for (const std::string& s : segments) log_.push_back({s, connection, now});
  }
  std::vector<std::string> values;
  std::vector<std::string> current;  // the subsystem path a relative segment continues
  for (const std::string& segment : segments) {
    const auto blank = segment.find_first_of(" \t");
    std::string header = segment.substr(0, blank);
    const std::string rest = blank == std::string::npos ? "" : trim(segment.substr(blank));
    std::vector<std::string> args;
    if (!rest.empty()) args = split(rest, ',');
    const bool query = !header.empty() && header.back() == '?';
    if (query) header.pop_back();

    std::optional<uint32_t> refused;
    std::string path;
    {
      std::lock_guard lock(mu_);
      for (const Refusal& r : refusals_) {
        if (upper(segment).starts_with(r.prefix)) refused = r.code;
      }
    }
    if (!refused && !header.empty() && header.front() == '*') {
      path = upper(header);
    } else if (!refused) {
      std::vector<std::string> tokens;
      const bool absolute = !header.empty() && header.front() == ':';
      if (!absolute) tokens = current;
      for (const std::string& t : split(absolute ? header.substr(1) : header, ':')) {
        tokens.push_back(t);
      }
      std::vector<std::string> names;
      for (std::size_t i = 0; i < tokens.size(); ++i) {
        std::optional<std::string> n;
        const std::string& t = tokens[i];
        if (i == 0) {
          n = resolve(t, {"DEMAND", "INTERLOCK", "LIMIT", "MODE", "QUERY", "READ", "UTILITY"});
        } else if (names[0] == "DEMAND") {
          n = resolve(t, {"POSITION", "RATE"});
        } else if (names[0] == "INTERLOCK") {
          n = resolve(t, {"CLOSE", "OPEN", "RESET"});
        } else if (names[0] == "LIMIT") {
          n = resolve(t, {"RATE", "ACCELERATION", "VELOCITY"});
        } else if (names[0] == "MODE") {
          n = resolve(t, {"OFF", "RATE", "POSITION"});
        } else if (names[0] == "QUERY") {
          n = resolve(t, {"ERROR"});
        } else if (names[0] == "READ") {
          n = resolve(t, {"POSITION", "RATE", "ACCELERATION"});
        } else if (names[0] == "UTILITY") {
          n = resolve(t, {"LOCKOUT"});
        }
        if (!n || i > 1) {
          names.clear();
          break;
        }
        names.push_back(*n);
      }
      if (!names.empty()) {
        current.assign(names.begin(), names.end() - (names.size() > 1 ? 1 : 0));
        for (const std::string& n : names) path += ":" + n;
      }
    }
    if (path == ":QUERY:ERROR" && !options_.answer_error_query) return std::nullopt;
    if (path == "*IDN" && query && options_.idn_reply_bytes) return *options_.idn_reply_bytes;
    const Outcome o = refused ? Outcome{*refused, std::nullopt} : execute(path, query, args);
    if (o.code != 0) return frame(o.code, "");
    if (o.value) values.push_back(*o.value);
  }
  if (!values.empty()) {
    std::string payload;
    for (const std::string& v : values) payload += (payload.empty() ? "" : ";") + v;
    return frame(0, payload);
  }
  switch (options_.command_answer) {
    case CommandAnswer::kCrLf:
      return frame(0, "\r\n");
    case CommandAnswer::kOk:
      return frame(0, "OK");
    case CommandAnswer::kEmpty:
      return frame(0, "");
  }
  return frame(0, "");
}

AclPeer::Outcome AclPeer::execute(const std::string& path, bool query,
                                  const std::vector<std::string>& args) {
  std::lock_guard lock(mu_);
  State& s = state_;
  const auto axis_at = [&](std::size_t i) -> bool {
    if (args.size() <= i) return false;
    const auto a = number(args[i]);
    return a && *a >= 1 && *a <= options_.axes && *a == static_cast<int>(*a);
  };
  const Outcome unknown{kUnknownCommand, std::nullopt};
  const Outcome ok{0, std::nullopt};
  const auto value = [](std::string v) { return Outcome{0, std::move(v)}; };

  if (path == "*IDN") return query ? value(options_.idn) : unknown;
  if (path == "*STB") {
    return query ? value(s.interlock == Interlock::kFault ? "1" : "0") : unknown;
  }
  if (path == ":UTILITY:LOCKOUT") {
    if (query) return value(s.lockout ? "ON" : "OFF");
    if (args.size() != 1) return unknown;
    const std::string a = upper(args[0]);
    if (a != "ON" && a != "OFF") return unknown;
    s.lockout = a == "ON";
    return ok;
  }
  if (path == ":QUERY:ERROR") {
    if (!query || args.size() != 1) return unknown;
    for (const Refusal& r : refusals_) {
      if (args[0] == std::to_string(r.code)) return value(r.text);
    }
    return value("Unknown error");
  }
  if (path == ":INTERLOCK:RESET") {
    if (query) return unknown;
    if (s.interlock == Interlock::kFault) s.interlock = Interlock::kOpen;
    return ok;
  }
  if (path.starts_with(":LIMIT:")) {
    // :L:R? <mode>,<axis> (TM-8004 §4.6): the same limits for every mode here.
    if (!query) return unknown;
    if (!axis_at(1)) return Outcome{kBadAxis, std::nullopt};
    if (path == ":LIMIT:RATE") return value(format(options_.rate_limit_dps));
    if (path == ":LIMIT:ACCELERATION") return value(format(options_.accel_limit_dps2));
    return value(format(options_.trip_rate_dps));
  }
  if (!axis_at(0)) return path.empty() ? unknown : Outcome{kBadAxis, std::nullopt};
  if (path == ":INTERLOCK") {
    if (!query) return unknown;
    switch (s.interlock) {
      case Interlock::kOpen:
        return value("Open");
      case Interlock::kClosed:
        return value(options_.closed_word);
      case Interlock::kFault:
        return value("Fault");
    }
  }
  if (path == ":INTERLOCK:CLOSE") {
    if (query) return unknown;
    if (s.interlock == Interlock::kFault) return Outcome{kFaulted, std::nullopt};
    s.interlock = Interlock::kClosed;
    return ok;
  }
  if (path == ":INTERLOCK:OPEN") {
    if (query) return unknown;
    if (s.interlock == Interlock::kClosed) s.interlock = Interlock::kOpen;
    s.mode = Mode::kOff;
    s.rate_dps = 0;
    return ok;
  }
  if (path == ":MODE") {
    if (!query) return unknown;
    const bool l = options_.long_mode_words;
    switch (s.mode) {
      case Mode::kOff:
        return value(l ? "Off" : "O");
      case Mode::kRate:
        return value(l ? "Rate" : "R");
      case Mode::kPosition:
        return value(l ? "Position" : "P");
    }
  }
  if (path == ":MODE:OFF" || path == ":MODE:RATE" || path == ":MODE:POSITION") {
    if (query) return unknown;
    s.mode = path == ":MODE:OFF"    ? Mode::kOff
             : path == ":MODE:RATE" ? Mode::kRate
                                    : Mode::kPosition;
    const bool servoed = s.interlock == Interlock::kClosed;
    s.rate_dps = servoed && s.mode == Mode::kRate ? s.demand_rate_dps : 0;
    if (servoed && s.mode == Mode::kPosition) s.position_deg = s.demand_position_deg;
    return ok;
  }
  if (path == ":DEMAND:RATE" || path == ":DEMAND:POSITION") {
    if (query || args.size() != 2) return unknown;
    const auto v = number(args[1]);
    if (!v) return unknown;
    const bool servoed = s.interlock == Interlock::kClosed;
    if (path == ":DEMAND:RATE") {
      s.demand_rate_dps = *v;
      if (servoed && s.mode == Mode::kRate) s.rate_dps = *v;
    } else {
      s.demand_position_deg = *v;
      if (servoed && s.mode == Mode::kPosition) s.position_deg = *v;
    }
    return ok;
  }
  if (path == ":READ:RATE") return query ? value(format(s.rate_dps)) : unknown;
  if (path == ":READ:POSITION") return query ? value(format(s.position_deg)) : unknown;
  if (path == ":READ:ACCELERATION") return query ? value(format(0)) : unknown;
  return unknown;
}

}  // namespace gyrotherm::testing
