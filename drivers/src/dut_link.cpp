// dut_channels(): the channel list of each protocol; the ASCII options'
// validation and the line encoder.
#include "gyrotherm/drivers/dut_link.h"

#include <fmt/format.h>

#include <array>
#include <boost/crc.hpp>
#include <cmath>
#include <set>
#include <stdexcept>

#include "gyrotherm/core/units.h"
#include "gyrotherm/drivers/ascii_line.h"

namespace gyrotherm::drivers {
namespace {

constexpr double kStandardGravity = 9.80665;  // m/s^2 per g

std::string column_label(std::size_t index, const AsciiColumn& c) {
  return fmt::format("ascii column {} '{}'", index, c.name);
}

bool valid_name(const std::string& name) {
  if (name.empty()) return false;
  for (char ch : name) {
    const bool ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') ||
                    (ch >= '0' && ch <= '9') || ch == '_';
    if (!ok) return false;
  }
  return true;
}

bool valid_axis(const std::string& axis) { return axis == "x" || axis == "y" || axis == "z"; }

// The unit a column of `kind` is sent in -> (physical unit, scale). nullopt:
// not a unit for that kind. `rate_hz` turns per-sample angles into rates.
std::optional<std::pair<std::string, double>> column_scale(ChannelKind kind,
                                                           const std::string& unit,
                                                           double rate_hz) {
  constexpr double kRadToDph = units::kDegPerRad * units::kSecondsPerHour;
  switch (kind) {
    case ChannelKind::kRate:
      if (unit == "deg/h") return std::pair<std::string, double>{"deg/h", 1.0};
      if (unit == "deg/s") return std::pair<std::string, double>{"deg/h", units::kSecondsPerHour};
      if (unit == "rad/s") return std::pair<std::string, double>{"deg/h", kRadToDph};
      if (unit == "deg") {
        return std::pair<std::string, double>{"deg/h", units::kSecondsPerHour * rate_hz};
      }
      if (unit == "rad") return std::pair<std::string, double>{"deg/h", kRadToDph * rate_hz};
      return std::nullopt;
    case ChannelKind::kAccel:
      if (unit == "g") return std::pair<std::string, double>{"g", 1.0};
      if (unit == "mg") return std::pair<std::string, double>{"g", 1e-3};
      if (unit == "m/s^2") return std::pair<std::string, double>{"g", 1.0 / kStandardGravity};
      return std::nullopt;
    case ChannelKind::kTemperature:
      if (unit == "degC") return std::pair<std::string, double>{"degC", 1.0};
      return std::nullopt;
    case ChannelKind::kStatus:
      if (unit.empty()) return std::pair<std::string, double>{"", 1.0};
      return std::nullopt;
    case ChannelKind::kOther:
      return std::pair<std::string, double>{unit, 1.0};
  }
  return std::nullopt;
}

std::string_view expected_units(ChannelKind kind) {
  switch (kind) {
    case ChannelKind::kRate:
      return "deg/h, deg/s, rad/s, or per sample deg, rad";
    case ChannelKind::kAccel:
      return "g, mg, m/s^2";
    case ChannelKind::kTemperature:
      return "degC";
    case ChannelKind::kStatus:
      return "\"\" (none)";
    case ChannelKind::kOther:
      return "any";
  }
  return "";
}

bool is_channel_column(const AsciiLineOptions& o, std::size_t i) {
  return o.columns[i].name != "-" &&
         !(o.seq_column && static_cast<std::size_t>(*o.seq_column) == i);
}

Result<std::vector<ChannelSpec>> ascii_channels(const AsciiLineOptions& o, double rate_hz) {
  if (Status s = validate_ascii_options(o); !s.ok()) return s.error();
  std::vector<ChannelSpec> out;
  for (std::size_t i = 0; i < o.columns.size(); ++i) {
    if (!is_channel_column(o, i)) continue;
    const AsciiColumn& c = o.columns[i];
    const auto scale = column_scale(c.kind, c.unit, rate_hz);  // validated
    out.push_back(ChannelSpec{c.name, scale->first, c.kind, c.axis, scale->second});
  }
  return out;
}

std::vector<ChannelSpec> kvh1750_channels(const DutLink& link) {
  double gyro_scale = units::kSecondsPerHour;
  if (link.unit == AngleUnit::kRad) gyro_scale *= units::kDegPerRad;
  if (link.kind == OutputKind::kDeltaAngle) gyro_scale *= link.rate_hz;
  return {
      {"gyro_x", "deg/h", ChannelKind::kRate, "x", gyro_scale},
      {"gyro_y", "deg/h", ChannelKind::kRate, "y", gyro_scale},
      {"gyro_z", "deg/h", ChannelKind::kRate, "z", gyro_scale},
      {"accel_x", "g", ChannelKind::kAccel, "x", 1.0},
      {"accel_y", "g", ChannelKind::kAccel, "y", 1.0},
      {"accel_z", "g", ChannelKind::kAccel, "z", 1.0},
      {"status", "", ChannelKind::kStatus, "", 1.0},
      {"temp_c", "degC", ChannelKind::kTemperature, "", 1.0},
  };
}

std::string hex_upper(uint32_t v, int digits) { return fmt::format("{:0{}X}", v, digits); }

}  // namespace

uint16_t crc16_ccitt_false(std::string_view bytes) {
  boost::crc_optimal<16, 0x1021, 0xFFFF, 0, false, false> crc;
  crc.process_bytes(bytes.data(), bytes.size());
  return crc.checksum();
}

uint8_t nmea_xor(std::string_view bytes) {
  uint8_t x = 0;
  for (char ch : bytes) x ^= static_cast<uint8_t>(ch);
  return x;
}

Status validate_ascii_options(const AsciiLineOptions& o) {
  const std::string& d = o.delimiter;
  if (d != "whitespace") {
    if (d.size() != 1) {
      return Error::Permanent(
          fmt::format("ascii delimiter '{}': must be one character or \"whitespace\"", d));
    }
    const char ch = d[0];
    const bool bad = ch == '\r' || ch == '\n' || ch == '*' || ch == '.' || ch == '+' || ch == '-' ||
                     (ch >= '0' && ch <= '9') || (ch >= 'a' && ch <= 'z') ||
                     (ch >= 'A' && ch <= 'Z') ||
                     (static_cast<unsigned char>(ch) < 0x20 && ch != '\t');
    if (bad) {
      return Error::Permanent(fmt::format(
          "ascii delimiter '{}': cannot separate numbers (not a letter, digit, '.', '+', '-', "
          "'*' or a line end)",
          d));
    }
  }
  if (o.checksum != "none" && o.checksum != "nmea" && o.checksum != "crc16") {
    return Error::Permanent(
        fmt::format("ascii checksum '{}': expected none, nmea or crc16", o.checksum));
  }
  if (o.prefix.find_first_of("\r\n*") != std::string::npos) {
    return Error::Permanent(
        fmt::format("ascii prefix '{}': must not hold a line end or '*'", o.prefix));
  }
  if (o.columns.empty()) return Error::Permanent("ascii columns: none given");
  if (o.seq_column) {
    if (*o.seq_column < 0 || static_cast<std::size_t>(*o.seq_column) >= o.columns.size()) {
      return Error::Permanent(fmt::format("ascii seq_column {}: no such column (0..{})",
                                          *o.seq_column, o.columns.size() - 1));
    }
    if (o.seq_modulo == 1) {
      return Error::Permanent(
          "ascii seq_modulo 1: a counter needs at least 2 values (0: wraps at 2^32)");
    }
  } else if (o.seq_modulo != 0) {
    return Error::Permanent(
        fmt::format("ascii seq_modulo {}: given without a seq_column", o.seq_modulo));
  }
  std::set<std::string> names;
  std::set<std::pair<ChannelKind, std::string>> axes;
  std::set<std::string> rate_axes;
  std::size_t channels = 0;
  std::size_t status_columns = 0;
  for (std::size_t i = 0; i < o.columns.size(); ++i) {
    const AsciiColumn& c = o.columns[i];
    if (!is_channel_column(o, i)) continue;
    const std::string label = column_label(i, c);
    if (!valid_name(c.name)) {
      return Error::Permanent(
          fmt::format("{}: a name is letters, digits and '_' (\"-\" skips the column)", label));
    }
    if (!names.insert(c.name).second) {
      return Error::Permanent(fmt::format("{}: name repeated", label));
    }
    if (!column_scale(c.kind, c.unit, 1.0)) {
      return Error::Permanent(
          fmt::format("{}: unit '{}' is not a unit for a {} column (expected {})", label, c.unit,
                      to_string(c.kind), expected_units(c.kind)));
    }
    if (c.kind == ChannelKind::kRate || c.kind == ChannelKind::kAccel) {
      if (!valid_axis(c.axis)) {
        return Error::Permanent(fmt::format("{}: axis '{}' (a {} column needs x, y or z)", label,
                                            c.axis, to_string(c.kind)));
      }
      if (!axes.insert({c.kind, c.axis}).second) {
        return Error::Permanent(
            fmt::format("{}: a second {} column for axis {}", label, to_string(c.kind), c.axis));
      }
      if (c.kind == ChannelKind::kRate) rate_axes.insert(c.axis);
    } else if (!c.axis.empty()) {
      return Error::Permanent(fmt::format(
          "{}: axis '{}' given, but only rate and accel columns have one", label, c.axis));
    }
    if (c.kind == ChannelKind::kStatus) ++status_columns;
    ++channels;
  }
  if (channels == 0) {
    return Error::Permanent("ascii columns: no channel (every column is \"-\" or the seq column)");
  }
  if (channels > kMaxChannels) {
    return Error::Permanent(
        fmt::format("ascii columns: {} channels, at most {}", channels, kMaxChannels));
  }
  if (!o.valid_bits.empty()) {
    if (status_columns != 1) {
      return Error::Permanent(fmt::format(
          "ascii valid_bits: need exactly one status column to read them from, found {}",
          status_columns));
    }
    std::set<std::string> seen;
    for (const auto& [axis, mask] : o.valid_bits) {
      if (!valid_axis(axis) || !rate_axes.count(axis)) {
        return Error::Permanent(
            fmt::format("ascii valid_bits: axis '{}' is not the axis of a rate column", axis));
      }
      if (mask == 0) {
        return Error::Permanent(fmt::format("ascii valid_bits: axis {}: mask 0 (no bit)", axis));
      }
      if (!seen.insert(axis).second) {
        return Error::Permanent(fmt::format("ascii valid_bits: axis {} given twice", axis));
      }
    }
  }
  return Status::Ok();
}

Result<std::vector<ChannelSpec>> dut_channels(const DutLink& link) {
  if (!(link.rate_hz > 0) || !std::isfinite(link.rate_hz)) {
    return Error::Permanent(fmt::format("rate_hz {}: must be > 0", link.rate_hz));
  }
  if (link.protocol == "kvh1750") return kvh1750_channels(link);
  if (link.protocol == "ascii") return ascii_channels(link.ascii, link.rate_hz);
  return Error::Permanent(
      fmt::format("unknown gyro protocol '{}' (supported: kvh1750, ascii)", link.protocol));
}

std::string encode_ascii_line(const AsciiLineOptions& o, std::span<const double> values,
                              uint32_t seq) {
  std::size_t channels = 0;
  std::size_t named = 0;
  for (std::size_t i = 0; i < o.columns.size(); ++i) {
    if (o.columns[i].name != "-") ++named;
    if (is_channel_column(o, i)) ++channels;
  }
  bool with_seq_entry = false;
  if (values.size() == named && named != channels) {
    with_seq_entry = true;
  } else if (values.size() != channels) {
    throw std::invalid_argument(
        fmt::format("encode_ascii_line: {} values for {} channels", values.size(), channels));
  }
  const std::string delim = o.delimiter == "whitespace" ? std::string(" ") : o.delimiter;
  std::string line = o.prefix;
  std::size_t v = 0;
  for (std::size_t i = 0; i < o.columns.size(); ++i) {
    const AsciiColumn& c = o.columns[i];
    if (i > 0) line += delim;
    if (o.seq_column && static_cast<std::size_t>(*o.seq_column) == i) {
      line += fmt::format("{}", o.seq_modulo ? seq % o.seq_modulo : seq);
      if (with_seq_entry && c.name != "-") ++v;
      continue;
    }
    if (c.name == "-") {
      line += "0";
      continue;
    }
    const double x = values[v++];
    if (std::isnan(x)) {
      line += "nan";
    } else if (c.kind == ChannelKind::kStatus) {
      line += fmt::format("{:.0f}", x);
    } else {
      line += fmt::format("{}", x);
    }
  }
  if (o.checksum == "nmea") {
    std::string_view body(line);
    if (!body.empty() && body.front() == '$') body.remove_prefix(1);
    const std::string sum = hex_upper(nmea_xor(body), 2);
    line.push_back('*');
    line.append(sum);
  } else if (o.checksum == "crc16") {
    const std::string sum = hex_upper(crc16_ccitt_false(line), 4);
    line.push_back('*');
    line.append(sum);
  }
  line += "\r\n";
  return line;
}

}  // namespace gyrotherm::drivers
