// The Acutronic Command Language (ACL) as bytes: building command lines and
// decoding the controller's replies. No I/O here: AcutrolTable
// (acutrol_table.h) does the TCP side, the fuzz target and the tests feed
// the decoder from memory.
//
// Sources: Acutronic TM-8004 "ACUTROL3000 Command Language" (§2.1 short
// forms, §2.6 numeric response formats, §4.5 interlock, §4.6 limits, §4.7
// modes, §4.10 read), TM-9384C (TCP/IP interface) and the public drivers
// AcutronicRobotics/acutrol (`acutrol.py`: commands end in "\r\n", the first
// 8 bytes of each reply are skipped) and IEAv-EFO/acutrol3000
// (`acutrol3000.py`, GPIB). The reply header's layout is not settled by
// them, hence ReplyFraming (docs/table.md, "Framing").
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/rate_table.h"

namespace gyrotherm::drivers::acl {

// How each reply is framed (TableConnection::reply_header).
enum class ReplyFraming {
  kAscii,     // "0000" error code, "0012" payload length (ASCII decimal), payload
  kBinaryLe,  // uint32 code, uint32 length, little-endian, then the payload
  kBinaryBe,  // the same, big-endian
  kLine,      // no header: the payload up to LF; no error code
};
// "ascii", "binary-le", "binary-be", "line"; anything else: permanent error
// naming it.
Result<ReplyFraming> parse_reply_framing(std::string_view name);
std::string_view to_string(ReplyFraming framing);

// Replies longer than this are refused as garbage (the longest answer we ask
// for, four numbers, is well under 100 bytes; *IDN? is at most 72).
inline constexpr std::size_t kMaxPayloadBytes = 4096;

// ---------------------------------------------------------------- commands
// A number as a command argument: fixed point, at most 6 decimals, trailing
// zeros dropped ("10.5", "-3", "0.000125"). Finite values only.
std::string format_number(double value);
// `commands` (one, or several joined by ';') terminated by "\r\n".
std::string command_line(std::string_view commands);

// Short forms (TM-8004 §2.1: `:D:P 3,10.5` = `:Demand:Position 3,10.5`).
std::string identify();                                      // *IDN? (§3.4)
std::string take_remote();                                   // :U:L ON (§4.14.2)
std::string release_remote();                                // :U:L OFF
std::string demand_rate(int axis, double rate_dps);          // :D:R a,r;:M:R a
std::string demand_position(int axis, double position_deg);  // :D:P a,p;:M:P a
std::string mode_off(int axis);                              // :M:O a
std::string interlock_close(int axis);                       // :I:C a
std::string interlock_open(int axis);                        // :I:O a
std::string interlock_reset();                               // :I:R
std::string interlock_query(int axis);                       // :I? a
// Mode, interlock, rate, position in one controller frame.
std::string state_query(int axis);  // :M? a;:I? a;:R:R? a;:R:P? a
// Rate-mode limits: rate, acceleration, velocity trip (§4.6.8, §4.6.2, §4.6.9).
std::string limits_query(int axis);           // :L:R? R,a;:L:A? R,a;:L:V? R,a
std::string error_text_query(uint32_t code);  // :Q:E? code

// ---------------------------------------------------------------- replies
struct Reply {
  uint32_t code = 0;    // the controller's error code; 0 = success
  std::string payload;  // without the header and without trailing CR/LF
};

// Incremental decoder: feed() bytes as they arrive, next() hands out whole
// replies. A malformed header (a non-digit in an ASCII header, a length
// beyond kMaxPayloadBytes, a line longer than that) is an error from next();
// the decoder has then dropped what it held, and the caller must drop the
// connection too (what follows on it cannot be trusted to be aligned).
class ReplyDecoder {
 public:
  explicit ReplyDecoder(ReplyFraming framing) : framing_(framing) {}
  void feed(std::string_view bytes) { buf_.append(bytes); }
  // A complete reply, nullopt while one is incomplete, or an error.
  Result<std::optional<Reply>> next();
  void reset() { buf_.clear(); }
  std::size_t buffered() const { return buf_.size(); }
  ReplyFraming framing() const { return framing_; }

 private:
  ReplyFraming framing_;
  std::string buf_;
};

// The first reply of a connection, to identify() (*IDN?: printable text,
// at most 72 characters, TM-8004 §3.4), with the framing it came in. The
// manual says only that replies carry an error code and a message length
// (TM-8004 §2); a public driver skips 8 bytes (acutrol.py); the release
// notes speak of a byte-swapped binary error word and of commands without
// data answering CR/LF (TM-9389, build 1848/1859). So the framing is read
// off this reply:
//   ascii      8 decimal digits (code, length), then `length` bytes of text
//   binary-le  8 bytes not all printable; the 32-bit length at offset 4,
//   binary-be  read little- or big-endian, is 1..kMaxPayloadBytes; then
//              that many bytes of text
//   line       text up to LF, no header
// Leading CR/LF are skipped. Text: printable ASCII or tab, CR/LF at its end.
struct FirstReply {
  ReplyFraming framing = ReplyFraming::kAscii;
  Reply reply;
  std::size_t consumed = 0;  // bytes of `bytes` this reply took
};
// nullopt while more bytes are needed; an error (naming the bytes received,
// printable, non-printable ones escaped) when they fit none of the framings.
Result<std::optional<FirstReply>> detect_first_reply(std::string_view bytes);
// `bytes` for a message: printable ASCII as is, the rest as \xNN, at most
// `max` bytes then "...", and the count.
std::string describe_bytes(std::string_view bytes, std::size_t max = 64);

// The ';'-separated fields of a payload, each without surrounding blanks
// (a chained query answers one field per query: `P;R;P`, TM-8004 §4.7).
std::vector<std::string_view> split_fields(std::string_view payload);
// An <NR1>, <NR2> or <NR3> number (TM-8004 §2.6: `12.3`, `-0.012E+3`); the
// whole field must be the number. Error names the field.
Result<double> parse_number(std::string_view field);

struct ParsedMode {
  TableMode mode = TableMode::kUnknown;
  std::string text;  // as received
};
// `P`/`R`/`O` (TM-8004 §4.7) or `Position`/`Rate`/`Off` (field firmware),
// case-insensitive; anything else is kUnknown, with its text.
ParsedMode parse_mode(std::string_view field);
// `Open`, `Close` or `Closed`, `Fault`, case-insensitive: the manual's
// interlock state is {Close|Open|Fault} (TM-8004 §4.5.3), field firmware
// answers `Closed`; acutrol3000.py compares the answer of `:interlock? 1`
// with "Fault\n". Anything else is an error.
Result<TableInterlock> parse_interlock(std::string_view field);

// The answer to state_query(): four fields.
Result<TableState> parse_state(std::string_view payload);
// The answer to limits_query(): three fields, all positive.
Result<TableLimits> parse_limits(std::string_view payload);

}  // namespace gyrotherm::drivers::acl
