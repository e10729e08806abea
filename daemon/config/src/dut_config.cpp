// The devices under test (docs/configuration.md, "[[dut]]"): the [[dut]]
// reader, the older [gyro] section and the conversions between the two,
// and the lookups of a DutSection's axes.
#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <cctype>
#include <cmath>

#include "config_readers.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/core/toml_reader.h"

namespace gyrotherm::config {
namespace {

// A DUT's serial number as given at `key`: 1..64 printable ASCII characters,
// no blank at either end, none of / \ " , (it names the DUT in URLs, in
// file names and in comma-separated CLI lists). nullopt (reported) when not.
std::optional<std::string> read_serial_number(TableReader& t, std::string_view key) {
  auto s = t.string(key);
  if (!s) return std::nullopt;
  const auto bad = [](char c) {
    return c < 0x20 || c > 0x7E || c == '/' || c == '\\' || c == '"' || c == ',';
  };
  if (s->empty() || s->size() > 64) {
    t.error(key, "must be 1 to 64 characters");
  } else if (std::any_of(s->begin(), s->end(), bad)) {
    t.error(key,
            "may hold printable ASCII characters except / \\ \" and , (it names the DUT in "
            "URLs, file names and comma-separated lists)");
  } else if (s->front() == ' ' || s->back() == ' ') {
    t.error(key, "must not start or end with a blank");
  } else {
    return s;
  }
  return std::nullopt;
}

// ---------------------------------------------------------------- [[dut]]
// docs/configuration.md, "[[dut]]". Errors name the entry by its index in
// the file, from 0: dut[1].ascii.columns[3].unit.

bool is_axis_name(std::string_view s) { return s == "x" || s == "y" || s == "z"; }

// Messages reported so far (kept or dropped): a reader's "did this part
// add an error" without threading flags through every getter.
std::size_t error_count(const TomlErrors& errors) {
  return errors.messages().size() + errors.dropped();
}

// [dut.ascii] columns: one inline table {name, kind, unit, axis} per column,
// in line order.
void read_ascii_columns(TableReader& a, drivers::AsciiLineOptions& o) {
  TomlErrors& errors = a.errors();
  const toml::array* list = a.array("columns");
  if (!list) {
    if (!a.raw().contains("columns")) {
      a.error("columns", "missing (required: one {name, kind, unit, axis} per column)");
    }
    return;
  }
  if (list->empty()) {
    a.error("columns", "must list at least one column");
    return;
  }
  // A line of more columns than this is not a gyro's (kMaxChannels of them
  // are recorded; "-" columns are skipped).
  static constexpr std::size_t kMaxColumns = 64;
  if (list->size() > kMaxColumns) {
    a.error("columns", fmt::format("{} columns: at most {}", list->size(), kMaxColumns));
    return;
  }
  for (std::size_t i = 0; i < list->size(); ++i) {
    const toml::node& node = *list->get(i);
    const std::string path = a.key_path(fmt::format("columns[{}]", i));
    const toml::table* table = node.as_table();
    if (!table) {
      errors.add(
          node_line(node, a.line_of("columns")), path,
          fmt::format("expected a table {{name, kind, unit, axis}}, got {}", toml_type_name(node)));
      continue;
    }
    TableReader c(*table, path, errors);
    const std::size_t before = error_count(errors);
    drivers::AsciiColumn column;
    if (auto name = c.required_string("name")) {
      const bool word = !name->empty() && std::all_of(name->begin(), name->end(), [](char ch) {
        return std::isalnum(static_cast<unsigned char>(ch)) || ch == '_';
      });
      const auto same = [&](const drivers::AsciiColumn& other) { return other.name == *name; };
      if (name->empty()) {
        c.error("name", "must not be empty (\"-\" skips the column)");
      } else if (*name != "-" && !word) {
        c.error("name", fmt::format("\"{}\": a channel name is letters, digits and _ (\"-\" "
                                    "skips the column)",
                                    *name));
      } else if (*name != "-" && std::any_of(o.columns.begin(), o.columns.end(), same)) {
        c.error("name", fmt::format("\"{}\" is also columns[{}]'s name", *name,
                                    std::find_if(o.columns.begin(), o.columns.end(), same) -
                                        o.columns.begin()));
      } else {
        column.name = *name;
      }
    }
    if (auto kind = c.choice("kind", {"rate", "accel", "temperature", "status", "other"}, "other"))
      column.kind = *channel_kind_from_string(*kind);
    if (auto unit = c.string("unit")) column.unit = *unit;
    if (auto axis = c.choice("axis", {"x", "y", "z"}, std::nullopt)) column.axis = *axis;
    const bool has_axis = column.kind == ChannelKind::kRate || column.kind == ChannelKind::kAccel;
    if (column.name != "-" && has_axis && column.axis.empty() && !table->contains("axis")) {
      c.error("axis", fmt::format("missing (required for kind {})", to_string(column.kind)));
    } else if (!has_axis && !column.axis.empty()) {
      c.error("axis", "only rate and accel columns have an axis");
    } else if (has_axis && column.name != "-") {
      for (std::size_t j = 0; j < o.columns.size(); ++j) {
        const drivers::AsciiColumn& other = o.columns[j];
        // (A column whose name was refused is left out: its error is enough.)
        if (!other.name.empty() && other.name != "-" && other.kind == column.kind &&
            other.axis == column.axis) {
          c.error("axis", fmt::format("columns[{}] is already the {} column of axis {}", j,
                                      to_string(column.kind), column.axis));
          break;
        }
      }
    }
    c.finish();
    // The unit, on its own: a link of this one column makes the protocol
    // say whether it knows the unit for the kind, so the error can name
    // this column's unit key and line.
    if (error_count(errors) == before && column.name != "-") {
      drivers::DutLink single;
      single.protocol = "ascii";
      single.ascii.columns = {column};
      if (auto channels = drivers::dut_channels(single); !channels) {
        c.error("unit", channels.error().message);
      }
    }
    o.columns.push_back(std::move(column));
  }
}

// [dut.ascii]: what one text line holds (drivers::AsciiLineOptions).
void read_dut_ascii(TableReader a, drivers::AsciiLineOptions& o) {
  if (auto d = a.string("delimiter")) {
    const auto one_char_ok = [](char c) {
      const auto u = static_cast<unsigned char>(c);
      // Not a character of a number or of the checksum suffix.
      return c == '\t' || (u > 0x20 && u < 0x7F && !std::isalnum(u) && c != '.' && c != '+' &&
                           c != '-' && c != '*');
    };
    if (*d == "whitespace" || (d->size() == 1 && one_char_ok((*d)[0])))
      o.delimiter = *d;
    else
      a.error("delimiter",
              fmt::format("\"{}\" is not a delimiter: one character that is not part of a number "
                          "or of the checksum (not a letter, digit, blank, . + - *), or "
                          "\"whitespace\" (runs of blanks)",
                          *d));
  }
  if (auto p = a.string("prefix")) {
    if (p->size() > 64)
      a.error("prefix", "at most 64 characters");
    else if (p->find_first_of("\r\n*") != std::string::npos)
      a.error("prefix", "must not hold a line end or * (the checksum's mark)");
    else
      o.prefix = *p;
  }
  if (auto c = a.choice("checksum", {"none", "nmea", "crc16"}, std::nullopt)) o.checksum = *c;
  read_ascii_columns(a, o);
  if (auto name = a.string("seq_column")) {
    const auto it = std::find_if(o.columns.begin(), o.columns.end(),
                                 [&](const drivers::AsciiColumn& c) { return c.name == *name; });
    if (name->empty() || *name == "-" || it == o.columns.end()) {
      a.error("seq_column", fmt::format("\"{}\" names no column of columns", *name));
    } else if (it->kind == ChannelKind::kRate || it->kind == ChannelKind::kAccel ||
               it->kind == ChannelKind::kTemperature) {
      a.error("seq_column",
              fmt::format("\"{}\" is a {} column; the sequence counter is a column of kind "
                          "other (or status)",
                          *name, to_string(it->kind)));
    } else {
      o.seq_column = static_cast<int>(it - o.columns.begin());
    }
  }
  if (auto m = a.integer("seq_modulo")) {
    if (*m < 2 || *m > int64_t{1} << 32) {
      a.error("seq_modulo",
              fmt::format("{} is out of range: the counter counts 0..modulo-1, modulo in [2, "
                          "4294967296]",
                          *m));
    } else if (!a.raw().contains("seq_column")) {
      a.error("seq_modulo", "needs seq_column (the column holding the counter)");
    } else {
      // 2^32 is a 32-bit counter that wraps by itself: stored as 0.
      o.seq_modulo = static_cast<uint32_t>(*m == int64_t{1} << 32 ? 0 : *m);
    }
  }
  if (auto bits = a.table("valid_bits")) {
    for (const char* axis : {"x", "y", "z"}) {
      if (auto mask = bits->integer(axis)) {
        const bool rate_column =
            std::any_of(o.columns.begin(), o.columns.end(), [&](const drivers::AsciiColumn& c) {
              return c.name != "-" && c.kind == ChannelKind::kRate && c.axis == axis;
            });
        if (*mask < 1 || *mask > 0xFFFFFFFFLL)
          bits->error(axis, fmt::format("{} is not a bit mask (1..0xFFFFFFFF)", *mask));
        else if (!rate_column && !o.columns.empty())
          bits->error(axis, fmt::format("no rate column has axis {}", axis));
        else
          o.valid_bits.emplace_back(axis, static_cast<uint32_t>(*mask));
      }
    }
    bits->finish();
    const auto status_columns =
        std::count_if(o.columns.begin(), o.columns.end(), [](const drivers::AsciiColumn& c) {
          return c.kind == ChannelKind::kStatus && c.name != "-";
        });
    if (status_columns != 1 && !o.columns.empty()) {
      a.error("valid_bits", fmt::format("needs one column of kind status (the word the bits are "
                                        "in); columns has {}",
                                        status_columns));
    }
  }
  a.finish();
}

// [[dut]] probes = { top_channel = N, side_channel = M }: channels of the
// [probes] module, read as its profile reads top and side.
std::optional<DutProbes> read_dut_probes(TableReader p, const ProbesSection& station_probes) {
  DutProbes probes;
  bool ok = true;
  for (auto [key, field] : {std::pair{"top_channel", &probes.top_channel},
                            std::pair{"side_channel", &probes.side_channel}}) {
    auto v = p.integer(key);
    if (!v) {
      if (!p.raw().contains(key)) p.error(key, "missing (required integer)");
      ok = false;
    } else if (*v < 0 || *v > 255) {
      p.error(key, fmt::format("{} is not a channel (0..255)", *v));
      ok = false;
    } else if (station_probes.profile == "custom") {
      p.error(key,
              "per-DUT probes are channels of the [probes] profile; [probes.registers] names "
              "only the top and side registers (give [probes] a profile)");
      ok = false;
    } else if (auto spec =
                   drivers::probe_channel_spec(station_probes.profile, static_cast<int>(*v));
               !spec) {
      p.error(key, spec.error().message);
      ok = false;
    } else {
      *field = static_cast<int>(*v);
    }
  }
  if (ok && probes.top_channel == probes.side_channel)
    p.error("side_channel", "top_channel and side_channel are the same channel");
  p.finish();
  if (!ok) return std::nullopt;
  return probes;
}

// The rate axes `link`'s frames carry, in channel order (x, y, z for a KVH
// 1750; the rate columns' axes for an ASCII line).
std::vector<std::string> rate_axes(const std::vector<ChannelSpec>& channels) {
  std::vector<std::string> axes;
  for (const auto& c : channels) {
    if (c.kind == ChannelKind::kRate && !c.axis.empty() &&
        std::find(axes.begin(), axes.end(), c.axis) == axes.end()) {
      axes.push_back(c.axis);
    }
  }
  return axes;
}

// One [[dut]]. `station`: the primary axis's orientation when [[dut]]
// orientation does not give it. Returns the DUT when nothing was reported.
std::optional<DutSection> read_dut(TableReader& t, const StationSection& station,
                                   const ProbesSection& station_probes, bool simulated,
                                   TomlErrors& warnings) {
  TomlErrors& errors = t.errors();
  const std::size_t before = error_count(errors);
  DutSection d;
  drivers::DutLink& link = d.link;
  if (auto s = read_serial_number(t, "serial")) {
    d.serial = *s;
  } else if (!t.raw().contains("serial")) {
    t.error("serial", "missing (required: the DUT's serial number)");
  }
  if (auto m = t.string("model")) d.model = *m;
  if (auto dev = t.string("device")) link.serial.device = *dev;
  if (auto b = t.integer("baud")) {
    if (*b <= 0 || *b > 100'000'000)
      t.error("baud", fmt::format("{} is not a baud rate (positive)", *b));
    else
      link.serial.baud = static_cast<int>(*b);
  }
  if (auto p = t.choice("parity", {"none", "even", "odd"}, std::nullopt))
    link.serial.parity = *drivers::parse_parity(*p);
  if (link.serial.device.empty() && !simulated)
    t.error("device", "missing (required unless [simulator] endpoints_file is set)");
  bool protocol_ok = true;
  if (auto p = t.choice("protocol", {"kvh1750", "ascii"}, std::nullopt))
    link.protocol = *p;
  else if (t.raw().contains("protocol"))
    protocol_ok = false;  // reported; its channels are unknown
  if (link.protocol == "kvh1750") {
    if (auto u = t.choice("unit", {"rad", "deg"}, std::nullopt))
      link.unit = *u == "rad" ? drivers::AngleUnit::kRad : drivers::AngleUnit::kDeg;
    if (auto o = t.choice("output", {"rate", "delta"}, std::nullopt))
      link.kind = *o == "rate" ? drivers::OutputKind::kRate : drivers::OutputKind::kDeltaAngle;
    if (t.raw().contains("ascii"))
      t.error("ascii", "only for protocol \"ascii\" (this DUT's protocol is kvh1750)");
    t.skip("ascii");
  } else {
    for (const char* key : {"unit", "output"}) {
      if (t.raw().contains(key))
        t.error(key, "only for protocol kvh1750 (an ascii line's columns give their units)");
      t.skip(key);
    }
  }
  link.rate_hz = t.number_in("rate_hz", link.rate_hz, 0.1, 10000.0);
  d.silent_timeout_s = t.number_in("silent_timeout_s", d.silent_timeout_s, 0.1, 86400.0);
  if (auto r = t.boolean("required")) d.required = *r;
  if (auto p = t.table("probes")) d.probes = read_dut_probes(*p, station_probes);

  // The protocol's channels: the axes below must be among its rate channels.
  std::optional<std::vector<ChannelSpec>> channels;
  if (link.protocol == "ascii") {
    const std::size_t before_ascii = error_count(errors);
    if (auto a = t.table("ascii")) {
      read_dut_ascii(*a, link.ascii);
    } else if (!t.raw().contains("ascii")) {
      t.error("ascii",
              "missing: protocol \"ascii\" needs a [dut.ascii] table (delimiter, columns, ...)");
    }
    if (error_count(errors) == before_ascii && protocol_ok) {
      if (auto c = drivers::dut_channels(link))
        channels = std::move(*c);
      else
        t.error("ascii", c.error().message);
    }
  } else if (protocol_ok) {
    if (auto c = drivers::dut_channels(link))
      channels = std::move(*c);
    else
      t.error("protocol", c.error().message);
  }

  const std::vector<std::string> available =
      channels ? rate_axes(*channels) : std::vector<std::string>{};
  const std::string available_text =
      available.empty() ? std::string("none") : fmt::format("{}", fmt::join(available, ", "));
  if (channels && available.empty()) {
    t.error("ascii", "the line carries no rate channel (a column of kind rate with an axis)");
  }
  if (const toml::array* list = t.array("axes")) {
    if (list->empty()) t.error("axes", "must list at least one axis");
    for (std::size_t i = 0; i < list->size(); ++i) {
      const toml::node& node = *list->get(i);
      const int line = node_line(node, t.line_of("axes"));
      const std::string path = t.key_path(fmt::format("axes[{}]", i));
      auto axis = node.value_exact<std::string>();
      if (!axis || !is_axis_name(*axis)) {
        errors.add(line, path, "must be \"x\", \"y\" or \"z\"");
      } else if (std::find(d.axes.begin(), d.axes.end(), *axis) != d.axes.end()) {
        errors.add(line, path, fmt::format("\"{}\" is listed twice", *axis));
      } else if (channels &&
                 std::find(available.begin(), available.end(), *axis) == available.end()) {
        errors.add(line, path,
                   fmt::format("\"{}\" is not among this DUT's rate channels (axes {})", *axis,
                               available_text));
      } else {
        d.axes.push_back(*axis);
      }
    }
  } else if (!t.raw().contains("axes")) {
    d.axes = available;
  }
  // An axis key (primary_axis, table_axis) must name one of the axes.
  const auto axis_key = [&](std::string_view key) -> std::optional<std::string> {
    auto axis = t.string(key);
    if (!axis) return std::nullopt;
    if (!is_axis_name(*axis)) {
      t.error(key, fmt::format("\"{}\" is not one of: x, y, z", *axis));
      return std::nullopt;
    }
    if (std::find(d.axes.begin(), d.axes.end(), *axis) == d.axes.end()) {
      t.error(key, fmt::format("\"{}\" is not among axes ({})", *axis, fmt::join(d.axes, ", ")));
      return std::nullopt;
    }
    return axis;
  };
  if (auto p = axis_key("primary_axis"))
    d.primary_axis = *p;
  else if (!d.axes.empty())
    d.primary_axis = d.axes.back();
  if (auto a = axis_key("table_axis"))
    d.table_axis = *a;
  else
    d.table_axis = d.primary_axis;
  // orientation = { z = "up", x = "horizontal" }: given axes as given, the
  // primary axis otherwise as [station] orientation, the others horizontal.
  std::vector<std::pair<std::string, analysis::AxisOrientation>> given;
  if (auto o = t.table("orientation")) {
    for (const auto& entry : o->raw()) {
      const std::string axis(entry.first.str());
      if (!is_axis_name(axis)) {
        o->skip(axis);
        o->error(axis, "is not an axis (x, y, z)");
      } else if (std::find(d.axes.begin(), d.axes.end(), axis) == d.axes.end()) {
        o->skip(axis);
        o->error(axis, fmt::format("\"{}\" is not among axes ({})", axis, fmt::join(d.axes, ", ")));
      } else if (auto value = o->choice(axis, {"up", "down", "horizontal"}, std::nullopt)) {
        given.emplace_back(axis, *analysis::parse_orientation(*value));
      }
    }
    o->finish();
  }
  for (const auto& axis : d.axes) {
    const auto it =
        std::find_if(given.begin(), given.end(), [&](const auto& g) { return g.first == axis; });
    if (it != given.end())
      d.orientation.push_back(*it);
    else
      d.orientation.emplace_back(axis, axis == d.primary_axis
                                           ? station.orientation
                                           : analysis::AxisOrientation::kHorizontal);
  }
  // heading_deg = { x = 90.0, y = 0.0 }: where each horizontal axis's
  // positive direction points (azimuth from true north, clockwise seen from
  // above; at table position 0), for its Earth-rate component Ω cos φ cos h.
  if (auto h = t.table("heading_deg")) {
    for (const auto& entry : h->raw()) {
      const std::string axis(entry.first.str());
      const auto orientation = axis_orientation(d, axis);
      if (!is_axis_name(axis)) {
        h->skip(axis);
        h->error(axis, "is not an axis (x, y, z)");
      } else if (!orientation) {
        h->skip(axis);
        h->error(axis, fmt::format("\"{}\" is not among axes ({})", axis, fmt::join(d.axes, ", ")));
      } else if (*orientation != analysis::AxisOrientation::kHorizontal) {
        h->skip(axis);
        h->error(axis, fmt::format("axis {} is \"{}\" (orientation): only a horizontal axis has a "
                                   "heading",
                                   axis, analysis::to_string(*orientation)));
      } else if (auto v = h->number(axis)) {
        if (!std::isfinite(*v) || *v < -360.0 || *v > 360.0) {
          h->error(axis, fmt::format("{} is out of range: must be in [-360, 360] degrees", *v));
        } else {
          d.heading_deg.emplace_back(axis, *v);
        }
      }
    }
    h->finish();
  }
  // A horizontal axis without a heading keeps the meaning it had before
  // headings existed (east–west: no Earth rate); say so, it is rarely true.
  for (const auto& [axis, orientation] : d.orientation) {
    if (orientation != analysis::AxisOrientation::kHorizontal || axis_heading_deg(d, axis)) {
      continue;
    }
    warnings.add(t.line_of(t.raw().contains("orientation") ? "orientation" : "axes"),
                 t.key_path("heading_deg"),
                 fmt::format("axis {} is horizontal without a heading: its Earth-rate component "
                             "is taken as 0 (as if it pointed east or west); give "
                             "heading_deg = {{ {} = AZIMUTH }} (degrees from true north, "
                             "clockwise)",
                             axis, axis));
  }
  t.finish();
  if (error_count(errors) != before) return std::nullopt;
  return d;
}

}  // namespace

namespace internal {

void read_gyro(TableReader t, GyroSection& g) {
  if (t.raw().contains("serial")) {
    if (auto s = read_serial_number(t, "serial")) g.serial_number = *s;
  }
  if (auto m = t.string("model")) g.model = *m;
  if (auto d = t.string("device")) g.serial.device = *d;
  if (auto b = t.integer("baud")) {
    if (*b <= 0)
      t.error("baud", "must be positive");
    else
      g.serial.baud = static_cast<int>(*b);
  }
  if (auto p = t.choice("parity", {"none", "even", "odd"}, std::nullopt)) {
    g.serial.parity = *drivers::parse_parity(*p);
  }
  if (auto p = t.choice("protocol", {"kvh1750"}, std::nullopt)) g.protocol = *p;
  if (auto u = t.choice("unit", {"rad", "deg"}, std::nullopt)) {
    g.format.unit = *u == "rad" ? drivers::AngleUnit::kRad : drivers::AngleUnit::kDeg;
  }
  if (auto o = t.choice("output", {"rate", "delta"}, std::nullopt)) {
    g.format.kind = *o == "rate" ? drivers::OutputKind::kRate : drivers::OutputKind::kDeltaAngle;
  }
  if (auto a = t.choice("axis", {"x", "y", "z"}, std::nullopt)) g.format.axis = (*a)[0] - 'x';
  g.format.rate_hz = t.number_in("rate_hz", g.format.rate_hz, 0.1, 10000.0);
  g.silent_timeout_s = t.number_in("silent_timeout_s", g.silent_timeout_s, 0.1, 86400.0);
  t.finish();
}

// Every [[dut]], into `duts` (only those without errors); serials and lines
// unique, at most kMaxDuts.
void read_duts(TableReader& top, std::vector<DutSection>& duts, const StationSection& station,
               const ProbesSection& station_probes, bool simulated, TomlErrors& warnings) {
  TomlErrors& errors = top.errors();
  const toml::array* list = top.array("dut");
  if (!list) return;  // the reader reported the wrong type
  if (list->empty()) {
    top.error("dut", "must list at least one DUT");
    return;
  }
  if (list->size() > kMaxDuts) {
    errors.add(node_line(*list->get(kMaxDuts), top.line_of("dut")), "dut",
               fmt::format("{} DUTs: a station reads at most {} (one serial line and thread each)",
                           list->size(), kMaxDuts));
  }
  // Serial and device of each entry read so far, with its index and line.
  struct Seen {
    std::size_t index;
    int line;
  };
  std::vector<std::pair<std::string, Seen>> serials, devices;
  for (std::size_t i = 0; i < list->size(); ++i) {
    const toml::node& node = *list->get(i);
    const std::string path = fmt::format("dut[{}]", i);
    const toml::table* table = node.as_table();
    if (!table) {
      errors.add(node_line(node, top.line_of("dut")), path,
                 fmt::format("expected a table ([[dut]]), got {}", toml_type_name(node)));
      continue;
    }
    TableReader t(*table, path, errors);
    auto dut = read_dut(t, station, station_probes, simulated, warnings);
    // Duplicates, from the raw values: reported even when the entry has
    // other errors.
    const auto unique = [&](std::string_view key, auto& seen, std::string_view what) {
      auto value = (*table)[key].value_exact<std::string>();
      if (!value || value->empty()) return;
      const int line = t.line_of(key);
      for (const auto& [v, s] : seen) {
        if (v == *value) {
          errors.add(line, t.key_path(key),
                     fmt::format("\"{}\" is also dut[{}]'s {} (line {}): {}", *value, s.index, key,
                                 s.line, what));
          return;
        }
      }
      seen.emplace_back(*value, Seen{i, line});
    };
    unique("serial", serials, "each DUT has its own serial number");
    unique("device", devices, "each DUT needs its own serial line");
    if (dut) duts.push_back(std::move(*dut));
  }
}

// The older [gyro] as one DUT: its serial (optional), its one axis in the
// [station] orientation.
DutSection dut_from_gyro(const GyroSection& g, analysis::AxisOrientation orientation) {
  DutSection d;
  d.serial = g.serial_number;
  d.model = g.model;
  d.link.serial = g.serial;
  d.link.protocol = g.protocol;
  d.link.unit = g.format.unit;
  d.link.kind = g.format.kind;
  d.link.rate_hz = g.format.rate_hz;
  const std::string axis(1, static_cast<char>('x' + g.format.axis));
  d.axes = {axis};
  d.orientation = {{axis, orientation}};
  d.primary_axis = axis;
  d.table_axis = axis;
  d.silent_timeout_s = g.silent_timeout_s;
  return d;
}

// StationConfig::gyro for code that shows "the gyro": the first DUT, its
// primary axis.
GyroSection gyro_of(const DutSection& d) {
  GyroSection g;
  g.serial_number = d.serial;
  g.model = d.model;
  g.serial = d.link.serial;
  g.protocol = d.link.protocol;
  g.format.unit = d.link.unit;
  g.format.kind = d.link.kind;
  g.format.rate_hz = d.link.rate_hz;
  if (is_axis_name(d.primary_axis)) g.format.axis = d.primary_axis[0] - 'x';
  g.silent_timeout_s = d.silent_timeout_s;
  return g;
}

}  // namespace internal

const DutSection* find_dut(const std::vector<DutSection>& duts, std::string_view serial) {
  for (const auto& dut : duts) {
    if (dut.serial == serial) return &dut;
  }
  return nullptr;
}

std::optional<analysis::AxisOrientation> axis_orientation(const DutSection& dut,
                                                          std::string_view axis) {
  for (const auto& [name, orientation] : dut.orientation) {
    if (name == axis) return orientation;
  }
  return std::nullopt;
}

std::optional<double> axis_heading_deg(const DutSection& dut, std::string_view axis) {
  for (const auto& [name, heading] : dut.heading_deg) {
    if (name == axis) return heading;
  }
  return std::nullopt;
}

}  // namespace gyrotherm::config
