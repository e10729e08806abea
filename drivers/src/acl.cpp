#include "gyrotherm/drivers/acl.h"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <cmath>

namespace gyrotherm::drivers::acl {

namespace {

bool iequals(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           auto lower = [](char c) {
             return (c >= 'A' && c <= 'Z') ? static_cast<char>(c + 32) : c;
           };
           return lower(x) == lower(y);
         });
}

std::string_view trim(std::string_view s) {
  auto blank = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; };
  while (!s.empty() && blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && blank(s.back())) s.remove_suffix(1);
  return s;
}

// Printable form of bytes for an error message: at most 32 of them, the
// others escaped.
std::string printable(std::string_view bytes) {
  std::string out;
  for (std::size_t i = 0; i < bytes.size() && i < 32; ++i) {
    const auto c = static_cast<unsigned char>(bytes[i]);
    if (c >= 0x20 && c < 0x7f)
      out += static_cast<char>(c);
    else
      out += fmt::format("\\x{:02x}", c);
  }
  if (bytes.size() > 32) out += "...";
  return out;
}

std::string strip_line_end(std::string_view payload) {
  while (!payload.empty() && (payload.back() == '\r' || payload.back() == '\n'))
    payload.remove_suffix(1);
  return std::string(payload);
}

uint32_t read_u32(std::string_view b, bool little_endian) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) {
    const auto byte = static_cast<uint8_t>(b[static_cast<std::size_t>(little_endian ? 3 - i : i)]);
    v = (v << 8) | byte;
  }
  return v;
}

}  // namespace

Result<ReplyFraming> parse_reply_framing(std::string_view name) {
  if (name == "ascii") return ReplyFraming::kAscii;
  if (name == "binary-le") return ReplyFraming::kBinaryLe;
  if (name == "binary-be") return ReplyFraming::kBinaryBe;
  if (name == "line") return ReplyFraming::kLine;
  return Error::Permanent(
      fmt::format("reply_header \"{}\" is none of ascii, binary-le, binary-be, line", name));
}

std::string_view to_string(ReplyFraming framing) {
  switch (framing) {
    case ReplyFraming::kAscii:
      return "ascii";
    case ReplyFraming::kBinaryLe:
      return "binary-le";
    case ReplyFraming::kBinaryBe:
      return "binary-be";
    case ReplyFraming::kLine:
      return "line";
  }
  return "?";
}

std::string format_number(double value) {
  if (!std::isfinite(value)) return "nan";  // callers refuse non-finite values first
  std::string s = fmt::format("{:.6f}", value);
  while (!s.empty() && s.back() == '0') s.pop_back();
  if (!s.empty() && s.back() == '.') s.pop_back();
  if (s == "-0") s = "0";
  return s;
}

std::string command_line(std::string_view commands) { return fmt::format("{}\r\n", commands); }

std::string identify() { return "*IDN?"; }
std::string take_remote() { return ":U:L ON"; }
std::string release_remote() { return ":U:L OFF"; }
std::string demand_rate(int axis, double rate_dps) {
  return fmt::format(":D:R {0},{1};:M:R {0}", axis, format_number(rate_dps));
}
std::string demand_position(int axis, double position_deg) {
  return fmt::format(":D:P {0},{1};:M:P {0}", axis, format_number(position_deg));
}
std::string mode_off(int axis) { return fmt::format(":M:O {}", axis); }
std::string interlock_close(int axis) { return fmt::format(":I:C {}", axis); }
std::string interlock_open(int axis) { return fmt::format(":I:O {}", axis); }
std::string interlock_reset() { return ":I:R"; }
std::string interlock_query(int axis) { return fmt::format(":I? {}", axis); }
std::string state_query(int axis) {
  return fmt::format(":M? {0};:I? {0};:R:R? {0};:R:P? {0}", axis);
}
std::string limits_query(int axis) {
  return fmt::format(":L:R? R,{0};:L:A? R,{0};:L:V? R,{0}", axis);
}
std::string error_text_query(uint32_t code) { return fmt::format(":Q:E? {}", code); }

Result<std::optional<Reply>> ReplyDecoder::next() {
  auto garbage = [this](std::string what) -> Error {
    std::string msg = fmt::format("malformed reply ({} framing): {}", to_string(framing_), what);
    buf_.clear();
    return Error::Transient(std::move(msg));
  };
  switch (framing_) {
    case ReplyFraming::kLine: {
      const auto lf = buf_.find('\n');
      if (lf == std::string::npos) {
        if (buf_.size() > kMaxPayloadBytes) {
          return garbage(fmt::format("no line end within {} bytes", kMaxPayloadBytes));
        }
        return std::optional<Reply>{};
      }
      if (lf > kMaxPayloadBytes) {
        return garbage(fmt::format("a line of {} bytes (more than {})", lf, kMaxPayloadBytes));
      }
      Reply r{0, strip_line_end(std::string_view(buf_).substr(0, lf))};
      buf_.erase(0, lf + 1);
      return std::optional<Reply>(std::move(r));
    }
    case ReplyFraming::kAscii: {
      // A CR/LF the controller may send after a payload it did not count
      // belongs to no header: skip it between replies.
      const auto start = buf_.find_first_not_of("\r\n");
      buf_.erase(0, start == std::string::npos ? buf_.size() : start);
      const std::size_t have = std::min<std::size_t>(buf_.size(), 8);
      for (std::size_t i = 0; i < have; ++i) {
        if (buf_[i] < '0' || buf_[i] > '9') {
          return garbage(fmt::format("header \"{}\" is not 8 decimal digits",
                                     printable(std::string_view(buf_).substr(0, have))));
        }
      }
      if (buf_.size() < 8) return std::optional<Reply>{};
      const auto code = static_cast<uint32_t>(std::stoul(buf_.substr(0, 4)));
      const auto length = static_cast<std::size_t>(std::stoul(buf_.substr(4, 4)));
      if (length > kMaxPayloadBytes) {
        return garbage(fmt::format("payload length {} beyond {}", length, kMaxPayloadBytes));
      }
      if (buf_.size() < 8 + length) return std::optional<Reply>{};
      Reply r{code, strip_line_end(std::string_view(buf_).substr(8, length))};
      buf_.erase(0, 8 + length);
      return std::optional<Reply>(std::move(r));
    }
    case ReplyFraming::kBinaryLe:
    case ReplyFraming::kBinaryBe: {
      if (buf_.size() < 8) return std::optional<Reply>{};
      const bool le = framing_ == ReplyFraming::kBinaryLe;
      const uint32_t code = read_u32(std::string_view(buf_).substr(0, 4), le);
      const uint32_t length = read_u32(std::string_view(buf_).substr(4, 4), le);
      if (length > kMaxPayloadBytes) {
        return garbage(fmt::format("payload length {} beyond {} (header {})", length,
                                   kMaxPayloadBytes,
                                   printable(std::string_view(buf_).substr(0, 8))));
      }
      if (buf_.size() < 8 + length) return std::optional<Reply>{};
      Reply r{code, strip_line_end(std::string_view(buf_).substr(8, length))};
      buf_.erase(0, 8 + length);
      return std::optional<Reply>(std::move(r));
    }
  }
  return garbage("unknown framing");
}

std::string describe_bytes(std::string_view bytes, std::size_t max) {
  std::string out = "\"";
  for (std::size_t i = 0; i < bytes.size() && i < max; ++i) {
    const auto c = static_cast<unsigned char>(bytes[i]);
    if (c == '\\' || c == '"')
      out += fmt::format("\\{}", static_cast<char>(c));
    else if (c >= 0x20 && c < 0x7f)
      out += static_cast<char>(c);
    else
      out += fmt::format("\\x{:02x}", c);
  }
  if (bytes.size() > max) out += "...";
  return fmt::format("{}\" ({} byte{})", out, bytes.size(), bytes.size() == 1 ? "" : "s");
}

namespace {

bool is_text_byte(char ch) {
  const auto c = static_cast<unsigned char>(ch);
  return (c >= 0x20 && c < 0x7f) || c == '\t';
}

// Printable text, CR/LF allowed only at its end.
bool is_reply_text(std::string_view s) {
  while (!s.empty() && (s.back() == '\r' || s.back() == '\n')) s.remove_suffix(1);
  return std::all_of(s.begin(), s.end(), is_text_byte);
}

bool all_digits(std::string_view s) {
  return std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

}  // namespace

Result<std::optional<FirstReply>> detect_first_reply(std::string_view bytes) {
  const std::string_view all = bytes;
  const std::size_t skipped = std::min(bytes.find_first_not_of("\r\n"), bytes.size());
  bytes.remove_prefix(skipped);
  const auto none = [&](std::string_view why) -> Error {
    return Error::Transient(fmt::format(
        "the first reply fits no known framing (ascii, binary-le, binary-be, line): {}; "
        "received {}",
        why, describe_bytes(all)));
  };
  const auto done = [&](ReplyFraming framing, uint32_t code, std::size_t header,
                        std::size_t length) -> std::optional<FirstReply> {
    return FirstReply{framing, Reply{code, strip_line_end(bytes.substr(header, length))},
                      skipped + header + length};
  };
  if (bytes.empty()) return std::optional<FirstReply>{};
  const std::size_t head = std::min<std::size_t>(bytes.size(), 8);
  if (all_digits(bytes.substr(0, head))) {
    if (bytes.size() < 8) return std::optional<FirstReply>{};
    const auto code = static_cast<uint32_t>(std::stoul(std::string(bytes.substr(0, 4))));
    const auto length = static_cast<std::size_t>(std::stoul(std::string(bytes.substr(4, 4))));
    if (bytes.size() < 8 + length) return std::optional<FirstReply>{};
    if (!is_reply_text(bytes.substr(8, length))) {
      return none(fmt::format("an ascii header for {} bytes, but they are not text", length));
    }
    return done(ReplyFraming::kAscii, code, 8, length);
  }
  if (is_text_byte(bytes.front())) {
    const std::size_t lf = bytes.find('\n');
    const std::string_view line = bytes.substr(0, lf);
    if (!is_reply_text(line)) return none("text that holds non-printable bytes");
    if (lf == std::string_view::npos) {
      if (line.size() > kMaxPayloadBytes) {
        return none(fmt::format("no line end within {} bytes", kMaxPayloadBytes));
      }
      return std::optional<FirstReply>{};
    }
    return done(ReplyFraming::kLine, 0, 0, lf + 1);
  }
  if (bytes.size() < 8) return std::optional<FirstReply>{};
  for (const bool le : {true, false}) {
    const uint32_t length = read_u32(bytes.substr(4, 4), le);
    if (length == 0 || length > kMaxPayloadBytes) continue;
    if (bytes.size() < 8 + length) return std::optional<FirstReply>{};
    if (!is_reply_text(bytes.substr(8, length))) continue;
    return done(le ? ReplyFraming::kBinaryLe : ReplyFraming::kBinaryBe,
                read_u32(bytes.substr(0, 4), le), 8, length);
  }
  return none("a binary header whose length (either byte order) is no text that follows");
}

std::vector<std::string_view> split_fields(std::string_view payload) {
  std::vector<std::string_view> fields;
  payload = trim(payload);
  if (payload.empty()) return fields;
  for (;;) {
    const auto semi = payload.find(';');
    fields.push_back(trim(payload.substr(0, semi)));
    if (semi == std::string_view::npos) break;
    payload.remove_prefix(semi + 1);
  }
  return fields;
}

Result<double> parse_number(std::string_view field) {
  const std::string_view f = trim(field);
  // <NR1> | <NR2> | <NR3>: [sign] digits [. digits] [E [sign] digits]
  // (TM-8004 §2.6.1). Checked by hand: from_chars alone would take "inf",
  // "nan" and hexadecimal forms.
  std::size_t i = 0;
  if (i < f.size() && (f[i] == '+' || f[i] == '-')) ++i;
  std::size_t digits = 0;
  while (i < f.size() && f[i] >= '0' && f[i] <= '9') ++i, ++digits;
  if (i < f.size() && f[i] == '.') {
    ++i;
    while (i < f.size() && f[i] >= '0' && f[i] <= '9') ++i, ++digits;
  }
  bool ok = digits > 0;
  if (ok && i < f.size() && (f[i] == 'E' || f[i] == 'e')) {
    ++i;
    if (i < f.size() && (f[i] == '+' || f[i] == '-')) ++i;
    std::size_t exp_digits = 0;
    while (i < f.size() && f[i] >= '0' && f[i] <= '9') ++i, ++exp_digits;
    ok = exp_digits > 0;
  }
  if (!ok || i != f.size()) {
    return Error::Permanent(fmt::format("\"{}\" is not a number", printable(field)));
  }
  const char* first = f.data();
  if (*first == '+') ++first;  // from_chars takes no '+'
  double v = 0;
  const auto [end, ec] = std::from_chars(first, f.data() + f.size(), v);
  if (ec != std::errc() || end != f.data() + f.size() || !std::isfinite(v)) {
    return Error::Permanent(fmt::format("\"{}\" is not a finite number", printable(field)));
  }
  return v;
}

ParsedMode parse_mode(std::string_view field) {
  const std::string_view f = trim(field);
  ParsedMode m{TableMode::kUnknown, std::string(f)};
  if (iequals(f, "P") || iequals(f, "Position")) m.mode = TableMode::kPosition;
  if (iequals(f, "R") || iequals(f, "Rate")) m.mode = TableMode::kRate;
  if (iequals(f, "O") || iequals(f, "Off")) m.mode = TableMode::kOff;
  return m;
}

Result<TableInterlock> parse_interlock(std::string_view field) {
  const std::string_view f = trim(field);
  if (iequals(f, "Open")) return TableInterlock::kOpen;
  if (iequals(f, "Close") || iequals(f, "Closed")) return TableInterlock::kClosed;
  if (iequals(f, "Fault")) return TableInterlock::kFault;
  return Error::Permanent(
      fmt::format("interlock \"{}\" is none of Open, Close (Closed), Fault", printable(f)));
}

Result<TableState> parse_state(std::string_view payload) {
  const auto fields = split_fields(payload);
  if (fields.size() != 4) {
    return Error::Permanent(
        fmt::format("expected mode;interlock;rate;position, got {} field{} in \"{}\"",
                    fields.size(), fields.size() == 1 ? "" : "s", printable(payload)));
  }
  TableState s;
  auto mode = parse_mode(fields[0]);
  s.mode = mode.mode;
  s.mode_text = std::move(mode.text);
  auto interlock = parse_interlock(fields[1]);
  if (!interlock) return interlock.error();
  s.interlock = *interlock;
  auto rate = parse_number(fields[2]);
  if (!rate) return Error::Permanent("rate: " + rate.error().message);
  auto position = parse_number(fields[3]);
  if (!position) return Error::Permanent("position: " + position.error().message);
  s.rate_dps = *rate;
  s.position_deg = *position;
  if (s.interlock == TableInterlock::kFault) s.fault = "interlock fault";
  return s;
}

Result<TableLimits> parse_limits(std::string_view payload) {
  const auto fields = split_fields(payload);
  if (fields.size() != 3) {
    return Error::Permanent(fmt::format(
        "expected rate limit;acceleration limit;velocity trip, got {} field{} in \"{}\"",
        fields.size(), fields.size() == 1 ? "" : "s", printable(payload)));
  }
  static constexpr const char* kNames[] = {"rate limit", "acceleration limit", "velocity trip"};
  double v[3] = {};
  for (std::size_t i = 0; i < 3; ++i) {
    auto n = parse_number(fields[i]);
    if (!n) return Error::Permanent(fmt::format("{}: {}", kNames[i], n.error().message));
    if (*n <= 0) {
      return Error::Permanent(fmt::format("{} {} is not positive", kNames[i], fields[i]));
    }
    v[i] = *n;
  }
  return TableLimits{v[0], v[1], v[2]};
}

}  // namespace gyrotherm::drivers::acl
