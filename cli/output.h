// What the CLI's commands print besides their data: errors on stderr, and
// text tables whose columns are measured in terminal cells.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace gyrotherm::cli {

// Exit statuses of the offline commands: 1 the command ran and failed (or
// found what it checks for), 2 bad input (arguments, a file it cannot read).
inline constexpr int kExitFailed = 1;
inline constexpr int kExitInput = 2;

// Prints "<who>: <message>" on stderr, with a newline unless the message ends
// in one; returns `code`, the exit status to return. `who` names the command.
int fail(const std::string& message, int code = 1, std::string_view who = "gyrotherm");

// Columns `s` takes on a terminal: UTF-8 continuation bytes take none.
std::size_t cells(std::string_view s);

enum class Align { kLeft, kRight };

// A header row and data rows, columns two spaces apart, each aligned as
// `align` says (one per column), every line after `indent`; no trailing blanks.
std::string table(const std::vector<std::string>& header, const std::vector<Align>& align,
                  const std::vector<std::vector<std::string>>& rows, std::string_view indent = "");

// The same with the first `left` columns left-aligned, the others right-aligned.
std::string table(const std::vector<std::string>& header,
                  const std::vector<std::vector<std::string>>& rows, std::size_t left = 0,
                  std::string_view indent = "");

}  // namespace gyrotherm::cli
