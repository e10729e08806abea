// How the station reads one device under test: its serial line, its frame
// protocol and the protocol's options. The seam between [[dut]] in the
// config, the drivers, the simulator and the station.
//
// Protocols (docs/devices.md):
// - "kvh1750": KVH 1750 "Format A" binary frames. Channels, in raw[] order:
//   gyro_x, gyro_y, gyro_z (rate, deg/h after scale; raw as sent, rad or deg,
//   per second or per sample), accel_x, accel_y, accel_z (g), status,
//   temp_c. Sequence counter 0..127; status bits 0-2 gyro X/Y/Z valid,
//   4-6 accel valid (a clear bit makes that channel's value NaN).
// - "ascii": one text line per sample; AsciiLineOptions say what is in it.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/drivers/devices.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/drivers/serial_port.h"

namespace gyrotherm::drivers {

// One column of an ASCII line. Its value is parsed as a decimal number
// (status columns also as 0x-prefixed hex); physical = value * scale, where
// scale comes from `unit`: rate columns deg/h, deg/s, rad/s (per second) or
// deg, rad (per sample: delta angles, times rate_hz); accel g or m/s^2;
// temperature degC; status and other columns as declared (scale 1).
struct AsciiColumn {
  std::string name;  // channel name; "-" skips the column
  ChannelKind kind = ChannelKind::kOther;
  std::string unit;  // as sent
  std::string axis;  // x, y, z for rate and accel columns
};

struct AsciiLineOptions {
  std::string delimiter = ",";  // one character, or "whitespace" (runs of blanks)
  std::vector<AsciiColumn> columns;
  // Column holding a sequence counter (its index among `columns`), with its
  // modulo; nullopt: none (gaps are then found from the sample clock only).
  std::optional<int> seq_column;
  uint32_t seq_modulo = 0;
  // Line integrity: "none"; "nmea" (line ends in *HH, the XOR of the bytes
  // between an optional leading '$' and '*', two hex digits); "crc16"
  // (line ends in *HHHH, CRC-16/CCITT-FALSE of the bytes before '*').
  std::string checksum = "none";
  std::string prefix;  // lines must start with it (e.g. "$GYR,"); "" = any
  // Status column: the bits that mean "valid" for each rate axis (x, y, z);
  // a value whose bit is clear is NaN. Empty = no validity bits.
  std::vector<std::pair<std::string, uint32_t>> valid_bits;  // axis -> mask
};

struct DutLink {
  SerialOptions serial;
  std::string protocol = "kvh1750";  // kvh1750, ascii
  AngleUnit unit = AngleUnit::kRad;  // kvh1750: the gyro's angle unit
  OutputKind kind = OutputKind::kRate;
  double rate_hz = 10.0;   // the device's output rate (station time)
  AsciiLineOptions ascii;  // protocol "ascii" only
};

// The channels a DUT on `link` records, in raw[] order. Error: unknown
// protocol, an ASCII column list that is empty, repeats a name, has an
// unknown unit for its kind, or more than kMaxChannels columns (named).
Result<std::vector<ChannelSpec>> dut_channels(const DutLink& link);

// A DutSource reading `link` on its own thread, timestamped on `clock` (the
// GyroReader's sample-clock rule, per DUT). Permanent error as dut_channels.
Result<std::unique_ptr<DutSource>> make_dut_source(const DutLink& link, const Clock& clock);

}  // namespace gyrotherm::drivers
