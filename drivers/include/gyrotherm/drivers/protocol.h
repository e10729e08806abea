// DUT protocols: bytes in, frames of every channel out.
//
// A protocol owns everything that differs between devices: framing and
// integrity checks, the channel list, what the status bits mean (a value
// flagged invalid becomes NaN) and the sequence counter's wrap, which the
// reader's sample clock needs (seq_modulo). The DutReader (dut_reader.h) only
// reads bytes, feeds them here and timestamps what comes out. Like
// FrameParser, a protocol takes bytes, never devices: tests feed it from
// memory, and it never emits a frame that failed its integrity check.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/drivers/dut_link.h"
#include "gyrotherm/drivers/frame_parser.h"
#include "gyrotherm/drivers/sequence_guard.h"

namespace gyrotherm::drivers {

class DutProtocol {
 public:
  virtual ~DutProtocol() = default;
  // The channels of every frame, in raw[] order (dut_channels()).
  virtual const std::vector<ChannelSpec>& channels() const = 0;
  // What the frames' sequence counter wraps at; 0: the protocol has none
  // (the sample clock then counts one slot per frame and finds gaps from
  // the station clock only).
  virtual uint64_t seq_modulo() const = 0;
  // Consumes `bytes` (any split: a partial frame or line is kept for the
  // next call) and appends every complete, valid frame to `out` in stream
  // order, t_s = 0 (the reader stamps it), raw values as sent, NaN for a
  // value flagged invalid.
  virtual void feed(std::span<const uint8_t> bytes, std::vector<DutFrame>& out) = 0;
  // Forgets buffered partial input and the last sequence number (after the
  // port was reopened). Keeps counters.
  virtual void reset() = 0;
  // frames_ok, crc_failures (checksum mismatches), bytes_skipped (bytes of
  // everything discarded), sequence gaps; last_reject says why the last
  // input was discarded.
  virtual const ParserCounters& counters() const = 0;
};

// A FrameParser's GyroFrames (KVH 1750 layout) as DutFrames with the
// channels of dut_channels() for kvh1750: raw[0..2] gyro X/Y/Z, raw[3..5]
// accel X/Y/Z (NaN when status bit 0-2 / 4-6 is clear), raw[6] the status
// byte, raw[7] the temperature. Counter wraps at 128.
class GyroFrameProtocol final : public DutProtocol {
 public:
  GyroFrameProtocol(std::unique_ptr<FrameParser> parser, std::vector<ChannelSpec> channels);
  const std::vector<ChannelSpec>& channels() const override { return channels_; }
  uint64_t seq_modulo() const override;
  void feed(std::span<const uint8_t> bytes, std::vector<DutFrame>& out) override;
  void reset() override { parser_->reset(); }
  const ParserCounters& counters() const override { return parser_->counters(); }

 private:
  std::unique_ptr<FrameParser> parser_;
  std::vector<ChannelSpec> channels_;
  std::vector<GyroFrame> frames_;  // reused between feeds
};

// A KVH 1750 frame's values in raw[] order, invalid ones NaN (as above).
DutFrame to_dut_frame(const GyroFrame& frame);

// Lines of text as AsciiLineOptions say (docs/devices.md, "ASCII lines").
// A line ends at CR, LF or CRLF; empty lines are ignored. A line is
// discarded (every byte counted in bytes_skipped, the reason in
// last_reject) when it lacks the prefix, has the wrong number of fields, a
// field that is not a number (status: decimal or 0x hex integer; sequence:
// decimal integer below the modulo), or a bad checksum (also counted in
// crc_failures). A line longer than kAsciiMaxLineBytes is discarded up to
// its end without being buffered. Fields are trimmed of blanks; a number
// that is not finite (nan, inf) is NaN. A rate value whose valid bits
// (valid_bits) are not all set in the status column is NaN. With a
// sequence column, the counter is judged by SequenceGuard: a line whose
// counter jumps is emitted once the next line confirms the jump, and
// dropped (sequence_rejects, its bytes skipped) when it does not.
class AsciiLineProtocol final : public DutProtocol {
 public:
  // Error: the options fail validate_ascii_options (named).
  static Result<std::unique_ptr<AsciiLineProtocol>> create(const AsciiLineOptions& options,
                                                           double rate_hz);
  const std::vector<ChannelSpec>& channels() const override { return channels_; }
  uint64_t seq_modulo() const override { return seq_modulo_; }
  void feed(std::span<const uint8_t> bytes, std::vector<DutFrame>& out) override;
  void reset() override;
  const ParserCounters& counters() const override { return counters_; }

 private:
  AsciiLineProtocol(AsciiLineOptions options, std::vector<ChannelSpec> channels);
  void line_done(std::vector<DutFrame>& out);
  void reject(std::size_t bytes, std::string reason);

  AsciiLineOptions options_;
  std::vector<ChannelSpec> channels_;
  uint64_t seq_modulo_ = 0;  // 0: no counter
  // Per column: the channel it fills (-1: none).
  std::vector<int> column_channel_;
  std::size_t status_column_ = SIZE_MAX;
  // (channel index, mask) for each valid_bits entry.
  std::vector<std::pair<std::size_t, uint32_t>> valid_checks_;
  std::string line_;
  bool overlong_ = false;                         // discarding the rest of a too-long line
  std::optional<SequenceGuard<DutFrame>> guard_;  // with a sequence column
  std::vector<std::string_view> fields_;          // reused between lines
  ParserCounters counters_;
};

// The protocol of `link`. Error: as dut_channels().
Result<std::unique_ptr<DutProtocol>> make_dut_protocol(const DutLink& link);

}  // namespace gyrotherm::drivers
