#include "gyrotherm/analysis/csv_window.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <optional>
#include <system_error>

namespace gyrotherm::analysis {
namespace {

constexpr std::array<std::string_view, 4> kRequired = {"t_s", "rate_dph", "top_c", "side_c"};
constexpr int kIgnored = -1;
constexpr std::size_t kMaxShownField = 40;

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

bool is_blank(std::string_view line) { return trim(line).empty(); }

// A field as shown in a message: long ones cut short.
std::string shown(std::string_view field) {
  if (field.size() <= kMaxShownField) return std::string(field);
  return std::string(field.substr(0, kMaxShownField)) + "...";
}

// Splits `text` into lines without their LF / CRLF ending, with 1-based numbers.
class LineReader {
 public:
  explicit LineReader(std::string_view text) : rest_(text) {}

  bool next(std::string_view* line) {
    if (done_) return false;
    const std::size_t nl = rest_.find('\n');
    if (nl == std::string_view::npos) {
      *line = rest_;
      done_ = true;
      if (line->empty()) return false;  // no final partial line
    } else {
      *line = rest_.substr(0, nl);
      rest_.remove_prefix(nl + 1);
    }
    if (!line->empty() && line->back() == '\r') line->remove_suffix(1);
    ++number_;
    return true;
  }
  std::size_t number() const { return number_; }

 private:
  std::string_view rest_;
  std::size_t number_ = 0;
  bool done_ = false;
};

// Collects errors, keeping the first kMaxCsvErrors messages and counting the rest.
class ErrorList {
 public:
  explicit ErrorList(const std::string& source) : source_(source) {}

  template <class... Args>
  void add(std::size_t line, fmt::format_string<Args...> f, Args&&... args) {
    ++count_;
    if (count_ > kMaxCsvErrors) return;
    if (!text_.empty()) text_ += '\n';
    text_ += fmt::format("{}:{}: ", source_, line);
    text_ += fmt::format(f, std::forward<Args>(args)...);
  }
  bool empty() const { return count_ == 0; }
  Error error() const {
    std::string msg = text_;
    if (count_ > kMaxCsvErrors)
      msg += fmt::format("\n... and {} more errors", count_ - kMaxCsvErrors);
    return Error::Permanent(std::move(msg));
  }

 private:
  const std::string& source_;
  std::string text_;
  std::size_t count_ = 0;
};

// Role (index into kRequired, or kIgnored) of each header column.
Result<std::vector<int>> parse_header(std::string_view line, std::size_t line_no,
                                      const std::string& source) {
  if (line.find('"') != std::string_view::npos) {
    return Error::Permanent(fmt::format(
        "{}:{}: quoted fields are not supported (found '\"' in the header)", source, line_no));
  }
  std::vector<int> roles;
  std::vector<std::string_view> names;
  std::array<std::size_t, kRequired.size()> column_of{};  // 1-based, 0 = absent
  for (std::size_t start = 0;;) {
    const std::size_t comma = line.find(',', start);
    const std::string_view name =
        trim(line.substr(start, comma == std::string_view::npos ? line.npos : comma - start));
    int role = kIgnored;
    for (std::size_t r = 0; r < kRequired.size(); ++r) {
      if (name != kRequired[r]) continue;
      if (column_of[r] != 0) {
        return Error::Permanent(
            fmt::format("{}:{}: column {} appears twice in the header "
                        "(columns {} and {})",
                        source, line_no, name, column_of[r], names.size() + 1));
      }
      column_of[r] = names.size() + 1;
      role = static_cast<int>(r);
    }
    roles.push_back(role);
    names.push_back(name);
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  std::string missing;
  for (std::size_t r = 0; r < kRequired.size(); ++r) {
    if (column_of[r] != 0) continue;
    if (!missing.empty()) missing += ", ";
    missing += kRequired[r];
  }
  if (!missing.empty()) {
    std::string found;
    for (std::string_view n : names) {
      if (!found.empty()) found += ", ";
      found += fmt::format("'{}'", shown(n));
    }
    return Error::Permanent(fmt::format(
        "{}:{}: header lacks column(s) {} (found {}; required t_s, rate_dph, top_c, side_c)",
        source, line_no, missing, found));
  }
  return roles;
}

// Parses one required field into *out; on failure adds the error and returns false.
bool parse_value(std::string_view raw, std::size_t line_no, std::string_view column,
                 ErrorList* errors, double* out) {
  std::string_view field = trim(raw);
  if (field.empty()) {
    errors->add(line_no, "column {}: empty value", column);
    return false;
  }
  std::string_view digits = field;
  if (digits.size() > 1 && digits[0] == '+' && digits[1] != '-' && digits[1] != '+') {
    digits.remove_prefix(1);
  }
  double v = 0;
  const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), v);
  if (ec == std::errc::result_out_of_range) {
    errors->add(line_no, "column {}: '{}' is out of range for a double", column, shown(field));
    return false;
  }
  if (ec != std::errc() || ptr != digits.data() + digits.size()) {
    errors->add(line_no, "column {}: '{}' is not a number", column, shown(field));
    return false;
  }
  if (!std::isfinite(v)) {
    errors->add(line_no, "column {}: {} is not finite", column, shown(field));
    return false;
  }
  *out = v;
  return true;
}

// Column asked for (index into `columns`, or kIgnored) of each header column.
Result<std::vector<int>> parse_column_header(std::string_view line, std::size_t line_no,
                                             const std::string& source,
                                             std::span<const CsvColumn> columns) {
  if (line.find('"') != std::string_view::npos) {
    return Error::Permanent(fmt::format(
        "{}:{}: quoted fields are not supported (found '\"' in the header)", source, line_no));
  }
  std::vector<int> roles;
  std::vector<std::string_view> names;
  std::vector<std::size_t> column_of(columns.size(), 0);  // 1-based, 0 = absent
  for (std::size_t start = 0;;) {
    const std::size_t comma = line.find(',', start);
    const std::string_view name =
        trim(line.substr(start, comma == std::string_view::npos ? line.npos : comma - start));
    int role = kIgnored;
    for (std::size_t r = 0; r < columns.size(); ++r) {
      if (name != columns[r].name) continue;
      if (column_of[r] != 0) {
        return Error::Permanent(
            fmt::format("{}:{}: column {} appears twice in the header (columns {} and {})", source,
                        line_no, name, column_of[r], names.size() + 1));
      }
      column_of[r] = names.size() + 1;
      role = static_cast<int>(r);
    }
    roles.push_back(role);
    names.push_back(name);
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  std::string missing, required;
  for (std::size_t r = 0; r < columns.size(); ++r) {
    if (!columns[r].required) continue;
    required += fmt::format("{}{}", required.empty() ? "" : ", ", columns[r].name);
    if (column_of[r] == 0)
      missing += fmt::format("{}{}", missing.empty() ? "" : ", ", columns[r].name);
  }
  if (!missing.empty()) {
    std::string found;
    for (std::string_view n : names) {
      if (!found.empty()) found += ", ";
      found += fmt::format("'{}'", shown(n));
    }
    return Error::Permanent(fmt::format("{}:{}: header lacks column(s) {} (found {}; required {})",
                                        source, line_no, missing, found, required));
  }
  return roles;
}

// The whole file's bytes.
Result<std::string> read_whole_file(const std::string& path) {
  struct Closer {
    void operator()(std::FILE* f) const { std::fclose(f); }
  };
  std::unique_ptr<std::FILE, Closer> f(std::fopen(path.c_str(), "rb"));
  if (!f) {
    return Error::Permanent(
        fmt::format("cannot open CSV file '{}': {}", path, std::strerror(errno)));
  }
  std::string text;
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  std::size_t capacity = ec ? std::size_t{1} << 20 : static_cast<std::size_t>(size) + 1;
  std::size_t used = 0;
  for (;;) {
    text.resize(capacity);
    const std::size_t got = std::fread(text.data() + used, 1, capacity - used, f.get());
    used += got;
    if (used < capacity) {
      if (std::ferror(f.get())) {
        return Error::Permanent(
            fmt::format("cannot read CSV file '{}': {}", path, std::strerror(errno)));
      }
      break;  // end of file
    }
    capacity *= 2;
  }
  text.resize(used);
  return text;
}

// Skips a UTF-8 byte-order mark and blank lines: the header row goes into
// `line`. False when the text has none.
bool read_header_line(std::string_view& text, std::optional<LineReader>& lines,
                      std::string_view* line) {
  static constexpr std::string_view kBom = "\xEF\xBB\xBF";
  if (text.substr(0, kBom.size()) == kBom) text.remove_prefix(kBom.size());
  lines.emplace(text);
  while (lines->next(line)) {
    if (!is_blank(*line)) return true;
  }
  return false;
}

// One data row split by the header's column roles: `on_field(role, raw)` for
// each column that is not ignored. A quoted row or one whose field count
// differs from the header's is an error naming the line. Whether every field
// of the row was taken.
template <class OnField>
bool parse_row(std::string_view line, std::size_t line_no, const std::vector<int>& roles,
               ErrorList& errors, OnField&& on_field) {
  if (std::memchr(line.data(), '"', line.size()) != nullptr) {
    errors.add(line_no, "quoted fields are not supported (found '\"')");
    return false;
  }
  const std::size_t n_columns = roles.size();
  std::size_t n_fields = 1;
  for (char c : line) n_fields += c == ',';
  if (n_fields != n_columns) {
    errors.add(line_no, "{} value (row has {} fields, header has {})",
               n_fields < n_columns ? "missing" : "extra", n_fields, n_columns);
    return false;
  }
  bool row_ok = true;
  std::size_t start = 0;
  for (std::size_t c = 0; c < n_columns; ++c) {
    const std::size_t comma = c + 1 < n_columns ? line.find(',', start) : line.size();
    if (roles[c] != kIgnored) row_ok &= on_field(roles[c], line.substr(start, comma - start));
    start = comma + 1;
  }
  return row_ok;
}

}  // namespace

Result<CsvWindow> parse_csv_window(std::string_view text, const std::string& source_name) {
  std::optional<LineReader> lines;
  std::string_view line;
  if (!read_header_line(text, lines, &line)) {
    return Error::Permanent(fmt::format(
        "{}: no header row (expected a header naming t_s, rate_dph, top_c, side_c)", source_name));
  }
  const std::size_t header_line = lines->number();
  Result<std::vector<int>> roles = parse_header(line, header_line, source_name);
  if (!roles.ok()) return roles.error();

  CsvWindow w;
  w.source = source_name;
  const std::size_t rows_hint = static_cast<std::size_t>(
      std::count(text.begin(), text.end(), '\n'));  // an upper bound, give or take one
  for (auto* v : {&w.t_s, &w.rate_dph, &w.top_c, &w.side_c}) v->reserve(rows_hint + 1);
  std::array<std::vector<double>*, kRequired.size()> column = {&w.t_s, &w.rate_dph, &w.top_c,
                                                               &w.side_c};

  ErrorList errors(source_name);
  double last_t_s = std::numeric_limits<double>::quiet_NaN();
  std::size_t last_t_line = 0;
  while (lines->next(&line)) {
    if (is_blank(line)) continue;
    const std::size_t line_no = lines->number();
    std::array<double, kRequired.size()> values{};
    if (!parse_row(line, line_no, *roles, errors, [&](int role, std::string_view raw) {
          return parse_value(raw, line_no, kRequired[role], &errors, &values[role]);
        })) {
      continue;
    }
    const double t = values[0];
    if (last_t_line != 0 && !(t > last_t_s)) {
      errors.add(line_no,
                 "column t_s: {} does not increase (line {} has {}; t_s must be strictly "
                 "increasing)",
                 t, last_t_line, last_t_s);
    }
    last_t_s = t;
    last_t_line = line_no;
    if (!errors.empty()) continue;  // no data will be returned; stop growing it
    for (std::size_t r = 0; r < kRequired.size(); ++r) column[r]->push_back(values[r]);
  }
  if (!errors.empty()) return errors.error();
  if (w.t_s.empty()) {
    return Error::Permanent(
        fmt::format("{}: no data rows (only the header, line {})", source_name, header_line));
  }
  w.row_count = w.t_s.size();
  return w;
}

Result<CsvWindow> read_csv_window(const std::string& path) {
  auto text = read_whole_file(path);
  if (!text) return text.error();
  return parse_csv_window(*text, path);
}

CsvSamples csv_window_samples(const CsvWindow& window) {
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  const std::size_t n = window.t_s.size();
  CsvSamples out;
  out.gyro.resize(n);
  out.temps.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    out.gyro[i].t_s = window.t_s[i];
    out.gyro[i].rate_dph = window.rate_dph[i];
    TemperatureSample& t = out.temps[i];
    t.t_s = window.t_s[i];
    t.setpoint_c = kNaN;
    t.chamber_c = kNaN;
    t.top_c = window.top_c[i];
    t.side_c = window.side_c[i];
  }
  return out;
}

Result<AnalysisSeries> csv_analysis_series(const CsvWindow& window, double bin_s) {
  const CsvSamples samples = csv_window_samples(window);
  return make_analysis_series(samples.gyro, samples.temps, bin_s);
}

Result<CsvColumns> parse_csv_columns(std::string_view text, const std::string& source_name,
                                     std::span<const CsvColumn> columns) {
  std::optional<LineReader> lines;
  std::string_view line;
  if (!read_header_line(text, lines, &line)) {
    std::string names;
    for (const CsvColumn& c : columns)
      names += fmt::format("{}{}", names.empty() ? "" : ", ", c.name);
    return Error::Permanent(
        fmt::format("{}: no header row (expected a header naming {})", source_name, names));
  }
  const std::size_t header_line = lines->number();
  Result<std::vector<int>> roles = parse_column_header(line, header_line, source_name, columns);
  if (!roles.ok()) return roles.error();

  CsvColumns out;
  out.source = source_name;
  out.present.assign(columns.size(), false);
  out.values.resize(columns.size());
  for (int role : *roles) {
    if (role != kIgnored) out.present[static_cast<std::size_t>(role)] = true;
  }

  ErrorList errors(source_name);
  std::vector<double> values(columns.size());
  while (lines->next(&line)) {
    if (is_blank(line)) continue;
    const std::size_t line_no = lines->number();
    const bool row_ok =
        parse_row(line, line_no, *roles, errors, [&](int role, std::string_view raw) {
          const auto r = static_cast<std::size_t>(role);
          return parse_value(raw, line_no, columns[r].name, &errors, &values[r]);
        });
    if (!row_ok || !errors.empty()) continue;  // no data will be returned
    out.line.push_back(line_no);
    for (std::size_t r = 0; r < columns.size(); ++r) {
      if (out.present[r]) out.values[r].push_back(values[r]);
    }
  }
  if (!errors.empty()) return errors.error();
  if (out.line.empty()) {
    return Error::Permanent(
        fmt::format("{}: no data rows (only the header, line {})", source_name, header_line));
  }
  out.row_count = out.line.size();
  return out;
}

Result<CsvColumns> read_csv_columns(const std::string& path, std::span<const CsvColumn> columns) {
  auto text = read_whole_file(path);
  if (!text) return text.error();
  return parse_csv_columns(*text, path, columns);
}

}  // namespace gyrotherm::analysis
