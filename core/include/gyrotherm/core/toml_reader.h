// Strict reading of TOML files (station config, schedules, simulator).
//
// A TableReader hands out the keys of one table with type checks, remembers
// which keys were read, and on finish() reports every key nobody asked for.
// Problems are collected, not thrown: a technician sees every error of a file
// at once, each as "file:line: key.path: what is wrong".
//
// This header is for the code that walks TOML tables and includes toml++.
// The error collection, the escaping of control characters and the file size
// limit need no toml++: toml_errors.h.
#pragma once

#include <toml++/toml.h>

#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/core/toml_errors.h"

namespace gyrotherm {

// Parses a whole file. A syntax error is reported (file:line) into `errors`
// and yields nullopt, as is a file that cannot be read, is not a regular
// file (a directory, /dev/zero, a FIFO) or is larger than `max_bytes`.
std::optional<toml::table> parse_toml_file(const std::string& path, TomlErrors& errors,
                                           std::size_t max_bytes = kMaxTomlFileBytes);
std::optional<toml::table> parse_toml_string(std::string_view text, TomlErrors& errors);

class TableReader {
 public:
  // `path` is the dotted name of this table ("" for the root).
  TableReader(const toml::table& table, std::string path, TomlErrors& errors);

  // Each getter: nullopt if absent; an error (and nullopt) if of the wrong type.
  std::optional<double> number(std::string_view key);  // integer or float
  std::optional<int64_t> integer(std::string_view key);
  std::optional<std::string> string(std::string_view key);
  std::optional<bool> boolean(std::string_view key);
  std::optional<TableReader> table(std::string_view key);
  const toml::array* array(std::string_view key);
  // Marks a key as known without reading it (sections read elsewhere).
  void skip(std::string_view key);

  // Range-checked number with a default. Reports "must be in [lo, hi]".
  double number_in(std::string_view key, double default_value, double lo, double hi);
  // A required number/string: reports "missing" when absent.
  std::optional<double> required_number(std::string_view key);
  std::optional<std::string> required_string(std::string_view key);
  // A string that must be one of `allowed`.
  std::optional<std::string> choice(std::string_view key, const std::vector<std::string>& allowed,
                                    std::optional<std::string> default_value);

  // Reports an error located at `key` (or at the table when absent).
  void error(std::string_view key, std::string_view message);
  // Reports every key that was not read, skipped or expected.
  void finish();

  std::string key_path(std::string_view key) const;
  int line_of(std::string_view key) const;
  const toml::table& raw() const { return *table_; }
  TomlErrors& errors() const { return *errors_; }

 private:
  const toml::node* get(std::string_view key);

  const toml::table* table_;
  std::string path_;
  TomlErrors* errors_;
  std::set<std::string, std::less<>> used_;
};

// "integer", "string", "table", ... for error messages.
std::string_view toml_type_name(const toml::node& node);

// The line of an array entry; `fallback` (the array's key line) when toml++
// kept none.
int node_line(const toml::node& node, int fallback);

}  // namespace gyrotherm
