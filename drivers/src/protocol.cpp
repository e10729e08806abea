#include "gyrotherm/drivers/protocol.h"

#include <fmt/format.h>

#include <charconv>
#include <cmath>
#include <limits>

#include "gyrotherm/drivers/ascii_line.h"
#include "gyrotherm/drivers/kvh1750.h"

namespace gyrotherm::drivers {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr uint64_t kCounter32Modulo = uint64_t{1} << 32;

bool is_blank(char ch) { return ch == ' ' || ch == '\t'; }

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_blank(s.back())) s.remove_suffix(1);
  return s;
}

// Splits `s` at `delim` (a char), or at runs of blanks (delim == 0), into
// `out`. Single-character fields are trimmed of blanks.
void split_fields(std::string_view s, char delim, std::vector<std::string_view>& out) {
  out.clear();
  if (delim == 0) {
    std::size_t i = 0;
    while (i < s.size()) {
      while (i < s.size() && is_blank(s[i])) ++i;
      if (i == s.size()) break;
      const std::size_t start = i;
      while (i < s.size() && !is_blank(s[i])) ++i;
      out.push_back(s.substr(start, i - start));
    }
    return;
  }
  std::size_t start = 0;
  while (true) {
    const std::size_t end = s.find(delim, start);
    const std::string_view field =
        s.substr(start, end == std::string_view::npos ? end : end - start);
    out.push_back(is_blank(delim) ? field : trim(field));
    if (end == std::string_view::npos) break;
    start = end + 1;
  }
}

std::optional<double> parse_number(std::string_view s) {
  if (s.size() > 1 && s.front() == '+' && s[1] != '-' && s[1] != '+') s.remove_prefix(1);
  if (s.empty()) return std::nullopt;
  double v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  // Out of range: from_chars leaves v; a device value beyond double is not a reading.
  if (ec != std::errc() || end != s.data() + s.size()) return std::nullopt;
  return std::isfinite(v) ? v : kNaN;
}

// Decimal, or hex with 0x/0X; 0..2^32-1.
std::optional<uint32_t> parse_unsigned(std::string_view s, bool allow_hex) {
  int base = 10;
  if (allow_hex && s.size() > 2 && s[0] == '0' && (s[1] == 'x' || s[1] == 'X')) {
    s.remove_prefix(2);
    base = 16;
  }
  if (s.empty()) return std::nullopt;
  uint32_t v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v, base);
  if (ec != std::errc() || end != s.data() + s.size()) return std::nullopt;
  return v;
}

std::optional<uint32_t> parse_hex_digits(std::string_view s, std::size_t digits) {
  if (s.size() != digits) return std::nullopt;
  for (char ch : s) {
    if (!std::isxdigit(static_cast<unsigned char>(ch))) return std::nullopt;
  }
  return parse_unsigned(std::string("0x").append(s), true);
}

// A field quoted in a reason: printable, and short.
std::string quoted(std::string_view s) {
  std::string out;
  for (char ch : s.substr(0, 32)) {
    const auto u = static_cast<unsigned char>(ch);
    out += (u >= 0x20 && u < 0x7F) ? std::string(1, ch) : fmt::format("\\x{:02X}", u);
  }
  if (s.size() > 32) out += "...";
  return "'" + out + "'";
}

}  // namespace

// ------------------------------------------------------------ GyroFrameProtocol

DutFrame to_dut_frame(const GyroFrame& f) {
  DutFrame d;
  d.raw.fill(0.0);
  d.seq = f.seq;
  for (std::size_t i = 0; i < 3; ++i) {
    d.raw[i] = (f.status & (1u << i)) ? static_cast<double>(f.gyro[i]) : kNaN;
    d.raw[3 + i] = (f.status & (1u << (4 + i))) ? static_cast<double>(f.accel[i]) : kNaN;
  }
  d.raw[6] = f.status;
  d.raw[7] = f.temp_c;
  return d;
}

GyroFrameProtocol::GyroFrameProtocol(std::unique_ptr<FrameParser> parser,
                                     std::vector<ChannelSpec> channels)
    : parser_(std::move(parser)), channels_(std::move(channels)) {}

uint64_t GyroFrameProtocol::seq_modulo() const { return kKvh1750SeqModulo; }

void GyroFrameProtocol::feed(std::span<const uint8_t> bytes, std::vector<DutFrame>& out) {
  frames_.clear();
  parser_->feed(bytes, frames_);
  for (const GyroFrame& f : frames_) out.push_back(to_dut_frame(f));
}

// ------------------------------------------------------------ AsciiLineProtocol

Result<std::unique_ptr<AsciiLineProtocol>> AsciiLineProtocol::create(
    const AsciiLineOptions& options, double rate_hz) {
  DutLink link;
  link.protocol = "ascii";
  link.rate_hz = rate_hz;
  link.ascii = options;
  auto channels = dut_channels(link);
  if (!channels.ok()) return channels.error();
  return std::unique_ptr<AsciiLineProtocol>(
      new AsciiLineProtocol(options, std::move(channels).value()));
}

AsciiLineProtocol::AsciiLineProtocol(AsciiLineOptions options, std::vector<ChannelSpec> channels)
    : options_(std::move(options)), channels_(std::move(channels)) {
  if (options_.seq_column) {
    seq_modulo_ = options_.seq_modulo != 0 ? options_.seq_modulo : kCounter32Modulo;
    guard_.emplace(seq_modulo_);
  }
  // Channels are the columns in order minus "-" and the sequence column
  // (dut_channels()), so the n-th such column fills channel n.
  int next = 0;
  for (std::size_t i = 0; i < options_.columns.size(); ++i) {
    const AsciiColumn& c = options_.columns[i];
    const bool seq = options_.seq_column && static_cast<std::size_t>(*options_.seq_column) == i;
    column_channel_.push_back(c.name == "-" || seq ? -1 : next++);
    if (!seq && c.name != "-" && c.kind == ChannelKind::kStatus) status_column_ = i;
  }
  for (const auto& [axis, mask] : options_.valid_bits) {
    for (std::size_t ch = 0; ch < channels_.size(); ++ch) {
      if (channels_[ch].kind == ChannelKind::kRate && channels_[ch].axis == axis) {
        valid_checks_.emplace_back(ch, mask);
      }
    }
  }
  line_.reserve(kAsciiMaxLineBytes);
}

void AsciiLineProtocol::reject(std::size_t bytes, std::string reason) {
  counters_.bytes_skipped += bytes;
  counters_.last_reject = std::move(reason);
}

void AsciiLineProtocol::feed(std::span<const uint8_t> bytes, std::vector<DutFrame>& out) {
  for (const uint8_t b : bytes) {
    if (b == '\r' || b == '\n') {
      if (overlong_) {
        overlong_ = false;  // its bytes were counted as they came
      } else if (!line_.empty()) {
        line_done(out);
        line_.clear();
      }
      continue;
    }
    if (overlong_) {
      ++counters_.bytes_skipped;
      continue;
    }
    if (line_.size() == kAsciiMaxLineBytes) {
      reject(line_.size() + 1,
             fmt::format("line longer than {} bytes (discarded to its end)", kAsciiMaxLineBytes));
      line_.clear();
      overlong_ = true;
      continue;
    }
    line_.push_back(static_cast<char>(b));
  }
}

void AsciiLineProtocol::line_done(std::vector<DutFrame>& out) {
  const std::string_view line(line_);
  const std::size_t n = line.size();
  if (!line.starts_with(options_.prefix)) {
    reject(n, fmt::format("line {} does not start with the prefix '{}'", quoted(line),
                          options_.prefix));
    return;
  }
  std::string_view body = line;
  if (options_.checksum != "none") {
    const bool nmea = options_.checksum == "nmea";
    const std::size_t digits = nmea ? 2 : 4;
    const std::size_t star = line.rfind('*');
    if (star == std::string_view::npos || star < options_.prefix.size()) {
      reject(n, fmt::format("line {} has no checksum (*{})", quoted(line), nmea ? "HH" : "HHHH"));
      return;
    }
    body = line.substr(0, star);
    const auto sent = parse_hex_digits(trim(line.substr(star + 1)), digits);
    if (!sent) {
      reject(n, fmt::format("line {}: checksum {} is not {} hex digits", quoted(line),
                            quoted(line.substr(star + 1)), digits));
      return;
    }
    uint32_t computed = 0;
    if (nmea) {
      std::string_view covered = body;
      if (!covered.empty() && covered.front() == '$') covered.remove_prefix(1);
      computed = nmea_xor(covered);
    } else {
      computed = crc16_ccitt_false(body);
    }
    if (computed != *sent) {
      ++counters_.crc_failures;
      reject(n, fmt::format("line {}: checksum *{:0{}X} does not match the line's {:0{}X}",
                            quoted(line), *sent, digits, computed, digits));
      return;
    }
  }
  body.remove_prefix(options_.prefix.size());
  const char delim = options_.delimiter == "whitespace" ? '\0' : options_.delimiter[0];
  split_fields(body, delim, fields_);
  if (fields_.size() != options_.columns.size()) {
    reject(n, fmt::format("line {}: {} fields, expected {}", quoted(line), fields_.size(),
                          options_.columns.size()));
    return;
  }
  DutFrame frame;
  frame.raw.fill(0.0);
  uint32_t status = 0;
  for (std::size_t i = 0; i < fields_.size(); ++i) {
    const AsciiColumn& c = options_.columns[i];
    const std::string_view f = fields_[i];
    if (options_.seq_column && static_cast<std::size_t>(*options_.seq_column) == i) {
      const auto seq = parse_unsigned(f, false);
      if (!seq || *seq >= seq_modulo_) {
        reject(n, fmt::format("line {}: column {} '{}' (sequence): {} is not a counter 0..{}",
                              quoted(line), i, c.name, quoted(f), seq_modulo_ - 1));
        return;
      }
      frame.seq = *seq;
      continue;
    }
    const int ch = column_channel_[i];
    if (ch < 0) continue;
    if (c.kind == ChannelKind::kStatus) {
      const auto v = parse_unsigned(f, true);
      if (!v) {
        reject(n,
               fmt::format("line {}: column {} '{}': {} is not a status word (decimal or 0x hex)",
                           quoted(line), i, c.name, quoted(f)));
        return;
      }
      frame.raw[static_cast<std::size_t>(ch)] = *v;
      if (i == status_column_) status = *v;
      continue;
    }
    const auto v = parse_number(f);
    if (!v) {
      reject(n, fmt::format("line {}: column {} '{}': {} is not a number", quoted(line), i, c.name,
                            quoted(f)));
      return;
    }
    frame.raw[static_cast<std::size_t>(ch)] = *v;
  }
  for (const auto& [ch, mask] : valid_checks_) {
    if ((status & mask) != mask) frame.raw[ch] = kNaN;
  }
  if (guard_) {
    guard_->push(
        frame, frame.seq, n, [&] { return "line " + quoted(line); }, out, counters_);
    return;
  }
  ++counters_.frames_ok;
  out.push_back(frame);
}

void AsciiLineProtocol::reset() {
  counters_.bytes_skipped += line_.size();  // a partial line is discarded too
  line_.clear();
  overlong_ = false;
  if (guard_) guard_->reset(counters_);
}

// ------------------------------------------------------------ factory

Result<std::unique_ptr<DutProtocol>> make_dut_protocol(const DutLink& link) {
  auto channels = dut_channels(link);
  if (!channels.ok()) return channels.error();
  if (link.protocol == "kvh1750") {
    return std::unique_ptr<DutProtocol>(
        new GyroFrameProtocol(std::make_unique<Kvh1750Parser>(), std::move(channels).value()));
  }
  auto ascii = AsciiLineProtocol::create(link.ascii, link.rate_hz);
  if (!ascii.ok()) return ascii.error();
  return std::unique_ptr<DutProtocol>(std::move(ascii).value());
}

}  // namespace gyrotherm::drivers
