// The parts of reading TOML files that need no toml++ (toml_reader.h has the
// rest): the messages collected for a file, the escaping of control
// characters in them, and the largest file read. For the code that reports
// errors or reads a TOML file's text without walking its tables.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <unordered_set>
#include <utility>
#include <vector>

namespace gyrotherm {

// The messages of one file. Each is one line: control characters in a key
// or a message (a quoted key may hold any) are escaped as \xNN, so nothing
// from the file reaches a terminal as a control sequence. A message equal to
// one already there is not added again (a hash set: linear in the count).
// At most kMaxStored distinct messages are kept; the rest are only counted
// (dropped()), which bounds memory whatever the file holds.
class TomlErrors {
 public:
  static constexpr std::size_t kMaxStored = 10000;

  explicit TomlErrors(std::string file) : file_(std::move(file)) {}
  void add(int line, std::string_view key_path, std::string_view message);
  bool empty() const { return messages_.empty(); }
  const std::vector<std::string>& messages() const { return messages_; }
  // Messages not kept because kMaxStored were already there.
  std::size_t dropped() const { return dropped_; }
  const std::string& file() const { return file_; }
  // The messages, one per line, at most `max_lines` of them and then
  // "... and N more errors".
  std::string joined(std::size_t max_lines = kMaxReported) const;

  // How many messages joined() (and the schedule reader) show by default.
  static constexpr std::size_t kMaxReported = 50;

 private:
  std::string file_;
  std::vector<std::string> messages_;
  std::unordered_set<std::string> seen_;
  std::size_t dropped_ = 0;
};

// "... and N more errors" for messages not shown; "" when n is 0.
std::string more_errors_line(std::size_t n);

// `text` with ASCII control characters (and DEL, and the C1 controls
// U+0080..U+009F) written as \xNN / \u{NN}: safe to print on a terminal.
std::string escape_control_characters(std::string_view text);

// True when `text` holds any character escape_control_characters escapes.
bool has_control_characters(std::string_view text);

// The largest file parse_toml_file reads (a station config or a schedule
// is a few KiB; a 10000-step schedule written out is under 1 MiB).
inline constexpr std::size_t kMaxTomlFileBytes = 1 << 20;

}  // namespace gyrotherm
