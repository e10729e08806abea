#include "gyrotherm/core/toml_reader.h"

#include <fmt/format.h>

#include <cmath>
#include <fstream>
#include <sstream>

namespace gyrotherm {

void TomlErrors::add(int line, std::string_view key_path, std::string_view message) {
  std::string where = line > 0 ? fmt::format("{}:{}", file_, line) : file_;
  if (key_path.empty()) {
    messages_.push_back(fmt::format("{}: {}", where, message));
  } else {
    messages_.push_back(fmt::format("{}: {}: {}", where, key_path, message));
  }
}

std::string TomlErrors::joined() const {
  std::string out;
  for (const auto& m : messages_) {
    out += m;
    out += '\n';
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

std::optional<toml::table> parse_toml_file(const std::string& path, TomlErrors& errors) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    errors.add(0, "", "cannot open file");
    return std::nullopt;
  }
  std::ostringstream ss;
  ss << in.rdbuf();
  return parse_toml_string(ss.str(), errors);
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
