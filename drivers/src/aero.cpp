#include "gyrotherm/drivers/aero.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>

#include "gyrotherm/drivers/acl.h"

namespace gyrotherm::drivers::aero {

namespace {

std::string_view trim(std::string_view s) {
  auto blank = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; };
  while (!s.empty() && blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && blank(s.back())) s.remove_suffix(1);
  return s;
}

}  // namespace

std::string command_line(std::string_view mnemonic, std::optional<double> number) {
  if (!number) return fmt::format("{}\r\n", mnemonic);
  return fmt::format("{}{}\r\n", mnemonic, acl::format_number(*number));
}

Result<int64_t> whole_argument(std::string_view mnemonic, double value, std::string_view unit) {
  constexpr double kLargest = 1e9;  // beyond any rate or angle a table takes
  const double whole = std::round(value);
  if (!std::isfinite(value) || std::fabs(value) > kLargest) {
    return Error::Permanent(
        fmt::format("{} {} is not a number {} can send", value, unit, mnemonic));
  }
  if (std::fabs(value - whole) > 1e-9) {
    return Error::Permanent(
        fmt::format("{:g} {} is not a whole number, and {} takes whole numbers (the public driver "
                    "RateSweepGUI.py sends '{}%d')",
                    value, unit, mnemonic, mnemonic));
  }
  return static_cast<int64_t>(whole);
}

std::string_view strip_echo(std::string_view reply, std::string_view command) {
  const auto end = reply.find('\n');
  const std::string_view first = trim(reply.substr(0, end));
  const std::string_view c = trim(command);
  const bool same = first.size() == c.size() &&
                    std::equal(first.begin(), first.end(), c.begin(), [](char a, char b) {
                      return std::toupper(static_cast<unsigned char>(a)) ==
                             std::toupper(static_cast<unsigned char>(b));
                    });
  if (!same) return reply;
  return end == std::string_view::npos ? std::string_view() : reply.substr(end + 1);
}

Result<std::optional<std::string>> ReplyDecoder::next() {
  for (;;) {
    // Skip line ends between lines.
    const auto start = buf_.find_first_not_of("\r\n");
    buf_.erase(0, start == std::string::npos ? buf_.size() : start);
    if (buf_.empty()) return std::optional<std::string>{};
    if (buf_.front() == '>') {
      // The prompt: it closes the reply whether or not a line end follows.
      buf_.erase(0, 1);
      std::string reply = std::move(lines_);
      lines_.clear();
      return std::optional<std::string>(std::move(reply));
    }
    const auto end = buf_.find_first_of("\r\n");
    if (end == std::string::npos) {
      if (buf_.size() > kMaxLineBytes) {
        const std::size_t n = buf_.size();
        reset();
        return Error::Transient(fmt::format(
            "malformed reply: {} bytes without a line end (more than {})", n, kMaxLineBytes));
      }
      return std::optional<std::string>{};
    }
    if (end > kMaxLineBytes) {
      reset();
      return Error::Transient(
          fmt::format("malformed reply: a line of {} bytes (more than {})", end, kMaxLineBytes));
    }
    if (lines_.size() + end > kMaxLineBytes) {
      reset();
      return Error::Transient(
          fmt::format("malformed reply: more than {} bytes before a prompt", kMaxLineBytes));
    }
    if (!lines_.empty()) lines_ += '\n';
    lines_.append(trim(std::string_view(buf_).substr(0, end)));
    buf_.erase(0, end);
  }
}

bool is_refusal(std::string_view reply) { return reply.find('?') != std::string_view::npos; }

Result<double> parse_number(std::string_view reply) { return acl::parse_number(reply); }

Result<int64_t> parse_status(std::string_view reply) {
  const std::string_view t = trim(reply);
  int64_t v = 0;
  const char* first = t.data();
  if (!t.empty() && *first == '+') ++first;
  const auto [end, ec] = std::from_chars(first, t.data() + t.size(), v);
  if (t.empty() || ec != std::errc() || end != t.data() + t.size()) {
    return Error::Permanent(fmt::format("status \"{}\" is not an integer", t));
  }
  return v;
}

}  // namespace gyrotherm::drivers::aero
