// The ASCII line protocol (docs/devices.md, "ASCII lines"): one text line per
// sample, its columns, units, sequence counter and checksum as
// AsciiLineOptions (dut_link.h) say.
//
// encode_ascii_line() writes the line a device configured so would print; the
// simulator and the tests use it. The parser (AsciiLineProtocol, protocol.h)
// accepts every line it writes.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/dut_link.h"

namespace gyrotherm::drivers {

// Longest line the parser keeps, terminator excluded. A longer line is
// dropped (counted as skipped bytes) without growing the buffer.
inline constexpr std::size_t kAsciiMaxLineBytes = 4096;

// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0),
// computed with Boost.CRC. Check value: "123456789" -> 0x29B1.
uint16_t crc16_ccitt_false(std::string_view bytes);
// NMEA checksum: XOR of every byte.
uint8_t nmea_xor(std::string_view bytes);

// Checks `options` as dut_channels() does (delimiter, columns, units, axes,
// sequence column and modulo, checksum, status bits). Errors name the option
// or the column (index from 0 and name).
Status validate_ascii_options(const AsciiLineOptions& options);

// One line, terminated by "\r\n", as a device configured by `options` prints
// it: the prefix, one field per column joined by the delimiter (a space for
// "whitespace"), then "*HH" or "*HHHH" (upper-case hex) for a checksum.
// `values` are the values as sent (raw: in each column's unit), one per
// channel in dut_channels() order, i.e. the columns in order minus "-"
// columns and the sequence column. (Also accepted: one per column that is not
// "-", the sequence column's entry then being ignored.) `seq` fills the
// sequence column (reduced modulo seq_modulo when set); "-" columns print
// "0". Numbers print with the shortest digits that read back exactly; status
// columns as decimal integers; NaN as "nan". Precondition:
// validate_ascii_options(options) passed and values.size() is one of the two
// counts above (otherwise a std::invalid_argument).
std::string encode_ascii_line(const AsciiLineOptions& options, std::span<const double> values,
                              uint32_t seq);

}  // namespace gyrotherm::drivers
