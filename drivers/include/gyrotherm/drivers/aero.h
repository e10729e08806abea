// The Ideal Aerosmith AERO-series serial grammar as bytes: command lines and
// the reply decoder. No I/O here (AeroTable, aero_table.h, does the serial
// line).
//
// No manual was found; the grammar is that of the public driver in
// actigraph/RateTableSweepGUI (`RateSweepGUI.py`, class IdealAerosmithTable):
// a command is a three-letter mnemonic and an optional number, sent with
// "\r\n" (`JOG-100`, `MOV90`, `PPO`); the controller answers a line ending
// in CR, then a prompt line `>`; a `?` in the answer means the command was
// refused. docs/table.md lists what must be checked on a real controller.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"

namespace gyrotherm::drivers::aero {

// Lines longer than this without a line end are refused as garbage.
inline constexpr std::size_t kMaxLineBytes = 256;

// `mnemonic` followed by `number` when given (fixed point, at most 6
// decimals, trailing zeros dropped: `JOG-12`, `MOV90`), then "\r\n".
std::string command_line(std::string_view mnemonic, std::optional<double> number = std::nullopt);

// JOG and MOV take whole numbers. The one public driver
// (actigraph/RateTableSweepGUI, RateSweepGUI.py) formats them with %d
// (`'JOG%d' % degreesPerSecond`, `'MOV%d' % position`, and RMO, VEL, ACL,
// ZER alike) while it sends HOF, AMP and FRQ with %f: whether the
// controller takes decimals after JOG or MOV is nowhere written, and one
// that truncated them would spoil a scale factor silently. So a value is
// sent only when it is a whole number (within 1e-9, then rounded): the
// whole number to send, or an error naming the value and the mnemonic.
Result<int64_t> whole_argument(std::string_view mnemonic, double value, std::string_view unit);

// The reply without an echo of `command`: a first line equal to the
// command (blanks and case aside) is what a controller echoing its input
// sends before the answer, and is dropped.
std::string_view strip_echo(std::string_view reply, std::string_view command);

// Incremental decoder of the controller's answers. Lines end in CR or LF
// (empty lines are skipped); a `>` at the start of a line is the prompt that
// closes a reply. The reply is the text of the lines before the prompt
// (joined by '\n', usually one line; "" when the prompt came alone). A line
// longer than kMaxLineBytes is an error from next(); the decoder has then
// dropped what it held and the caller should reopen the line.
class ReplyDecoder {
 public:
  void feed(std::string_view bytes) { buf_.append(bytes); }
  // A complete reply, nullopt while incomplete, or an error.
  Result<std::optional<std::string>> next();
  void reset() {
    buf_.clear();
    lines_.clear();
  }

 private:
  std::string buf_;    // bytes not yet split into lines
  std::string lines_;  // reply lines seen since the last prompt
};

// A `?` anywhere in the reply: the controller refused the command.
bool is_refusal(std::string_view reply);
// The answer to PPO / PVE: one decimal number ([sign] digits [. digits]
// [E [sign] digits]), nothing else. Error names the text.
Result<double> parse_number(std::string_view reply);
// The answer to STA: a decimal integer.
Result<int64_t> parse_status(std::string_view reply);

}  // namespace gyrotherm::drivers::aero
