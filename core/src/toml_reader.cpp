#include "gyrotherm/core/toml_reader.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "gyrotherm/core/files.h"

namespace gyrotherm {

namespace {

// The length of the control character at text[i] (1 for C0/DEL, 2 for a C1
// control in UTF-8), 0 when there is none.
std::size_t control_at(std::string_view text, std::size_t i) {
  const auto c = static_cast<unsigned char>(text[i]);
  if (c < 0x20 || c == 0x7F) return 1;
  if (c == 0xC2 && i + 1 < text.size()) {
    const auto next = static_cast<unsigned char>(text[i + 1]);
    if (next >= 0x80 && next <= 0x9F) return 2;
  }
  return 0;
}

}  // namespace

std::string escape_control_characters(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (std::size_t i = 0; i < text.size();) {
    const std::size_t n = control_at(text, i);
    if (n == 0) {
      out += text[i++];
    } else if (n == 1) {
      out += fmt::format("\\x{:02X}", static_cast<unsigned char>(text[i]));
      i += 1;
    } else {
      out += fmt::format("\\u{{{:02X}}}", static_cast<unsigned char>(text[i + 1]));
      i += 2;
    }
  }
  return out;
}

bool has_control_characters(std::string_view text) {
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (control_at(text, i) > 0) return true;
  }
  return false;
}

std::string more_errors_line(std::size_t n) {
  if (n == 0) return "";
  return fmt::format("... and {} more error{}", n, n == 1 ? "" : "s");
}

void TomlErrors::add(int line, std::string_view key_path, std::string_view message) {
  if (messages_.size() >= kMaxStored) {
    ++dropped_;
    return;
  }
  std::string where = line > 0 ? fmt::format("{}:{}", file_, line) : file_;
  std::string m = key_path.empty() ? fmt::format("{}: {}", where, message)
                                   : fmt::format("{}: {}: {}", where, key_path, message);
  if (has_control_characters(m)) m = escape_control_characters(m);
  if (!seen_.insert(m).second) return;
  messages_.push_back(std::move(m));
}

std::string TomlErrors::joined(std::size_t max_lines) const {
  std::string out;
  const std::size_t shown = std::min(max_lines, messages_.size());
  for (std::size_t i = 0; i < shown; ++i) {
    out += messages_[i];
    out += '\n';
  }
  if (const std::size_t more = messages_.size() - shown + dropped_; more > 0) {
    out += more_errors_line(more) + "\n";
  }
  return out;
}

std::optional<toml::table> parse_toml_string(std::string_view text, TomlErrors& errors) {
  try {
    return toml::parse(text, std::string_view(errors.file()));
  } catch (const toml::parse_error& e) {
    errors.add(static_cast<int>(e.source().begin.line), "",
               fmt::format("TOML syntax error: {}", e.description()));
    return std::nullopt;
  }
}

std::optional<toml::table> parse_toml_file(const std::string& path, TomlErrors& errors,
                                           std::size_t max_bytes) {
  auto text = read_bounded_file(path, max_bytes);
  if (!text) {
    // The message starts with the path, which every message here gets anyway.
    std::string_view reason = text.error().message;
    if (reason.substr(0, path.size() + 2) == path + ": ") reason.remove_prefix(path.size() + 2);
    errors.add(0, "", reason);
    return std::nullopt;
  }
  return parse_toml_string(*text, errors);
}

std::string_view toml_type_name(const toml::node& node) {
  switch (node.type()) {
    case toml::node_type::table:
      return "table";
    case toml::node_type::array:
      return "array";
    case toml::node_type::string:
      return "string";
    case toml::node_type::integer:
      return "integer";
    case toml::node_type::floating_point:
      return "float";
    case toml::node_type::boolean:
      return "boolean";
    case toml::node_type::date:
      return "date";
    case toml::node_type::time:
      return "time";
    case toml::node_type::date_time:
      return "date-time";
    default:
      return "nothing";
  }
}

int node_line(const toml::node& node, int fallback) {
  const int line = static_cast<int>(node.source().begin.line);
  return line > 0 ? line : fallback;
}

TableReader::TableReader(const toml::table& table, std::string path, TomlErrors& errors)
    : table_(&table), path_(std::move(path)), errors_(&errors) {}

std::string TableReader::key_path(std::string_view key) const {
  if (path_.empty()) return std::string(key);
  if (key.empty()) return path_;
  return fmt::format("{}.{}", path_, key);
}

int TableReader::line_of(std::string_view key) const {
  if (const toml::node* n = table_->get(key)) {
    return static_cast<int>(n->source().begin.line);
  }
  return static_cast<int>(table_->source().begin.line);
}

void TableReader::error(std::string_view key, std::string_view message) {
  errors_->add(line_of(key), key_path(key), message);
}

const toml::node* TableReader::get(std::string_view key) {
  used_.emplace(key);
  return table_->get(key);
}

void TableReader::skip(std::string_view key) { used_.emplace(key); }

std::optional<double> TableReader::number(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return std::nullopt;
  if (auto v = n->value_exact<int64_t>()) return static_cast<double>(*v);
  if (auto v = n->value_exact<double>()) {
    if (!std::isfinite(*v)) {
      error(key, "must be a finite number");
      return std::nullopt;
    }
    return *v;
  }
  error(key, fmt::format("expected a number, got {}", toml_type_name(*n)));
  return std::nullopt;
}

std::optional<int64_t> TableReader::integer(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return std::nullopt;
  if (auto v = n->value_exact<int64_t>()) return *v;
  error(key, fmt::format("expected an integer, got {}", toml_type_name(*n)));
  return std::nullopt;
}

std::optional<std::string> TableReader::string(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return std::nullopt;
  if (auto v = n->value_exact<std::string>()) return *v;
  error(key, fmt::format("expected a string, got {}", toml_type_name(*n)));
  return std::nullopt;
}

std::optional<bool> TableReader::boolean(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return std::nullopt;
  if (auto v = n->value_exact<bool>()) return *v;
  error(key, fmt::format("expected true or false, got {}", toml_type_name(*n)));
  return std::nullopt;
}

std::optional<TableReader> TableReader::table(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return std::nullopt;
  if (const toml::table* t = n->as_table()) return TableReader(*t, key_path(key), *errors_);
  error(key, fmt::format("expected a table, got {}", toml_type_name(*n)));
  return std::nullopt;
}

const toml::array* TableReader::array(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return nullptr;
  if (const toml::array* a = n->as_array()) return a;
  error(key, fmt::format("expected an array, got {}", toml_type_name(*n)));
  return nullptr;
}

double TableReader::number_in(std::string_view key, double default_value, double lo, double hi) {
  const auto v = number(key);
  if (!v) return default_value;
  if (*v < lo || *v > hi) {
    error(key, fmt::format("{} is out of range: must be in [{}, {}]", *v, lo, hi));
    return default_value;
  }
  return *v;
}

std::optional<double> TableReader::required_number(std::string_view key) {
  if (!table_->contains(key)) {
    used_.emplace(key);
    error(key, "missing (required number)");
    return std::nullopt;
  }
  return number(key);
}

std::optional<std::string> TableReader::required_string(std::string_view key) {
  if (!table_->contains(key)) {
    used_.emplace(key);
    error(key, "missing (required string)");
    return std::nullopt;
  }
  return string(key);
}

std::optional<std::string> TableReader::choice(std::string_view key,
                                               const std::vector<std::string>& allowed,
                                               std::optional<std::string> default_value) {
  auto v = string(key);
  if (!v) return default_value;
  for (const auto& a : allowed) {
    if (*v == a) return v;
  }
  error(key, fmt::format("\"{}\" is not one of: {}", *v, fmt::join(allowed, ", ")));
  return std::nullopt;
}

void TableReader::finish() {
  for (const auto& [k, node] : *table_) {
    if (used_.find(k.str()) == used_.end()) {
      errors_->add(static_cast<int>(node.source().begin.line), key_path(k.str()), "unknown key");
    }
  }
}

}  // namespace gyrotherm
