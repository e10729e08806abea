// GyroReader: serial line -> frame parser -> timestamped samples of one
// axis, on its own thread. It is a DutReader (dut_reader.h) over the
// FrameParser's frames, reduced to the configured axis; the rules below
// (SampleClock, reopening) are the DutReader's.
//
// Timestamps come from the gyro's own sample clock: t = anchor + n / rate_hz,
// where n counts frames since the anchor including frames missed according to
// the sequence counter. The anchor is the station clock at the first frame.
// It is re-taken, with tolerance max(2 s, 1 wall s x time_scale): forward,
// when the last frame of a read that emptied the line (so it arrived just
// now) lags the clock by more than that: the stream stalled, or more frames
// were lost than the counter can count (the KVH 1750's wraps at 128). The whole read moves
// with it. A read that leaves bytes on the line is a backlog, late by design:
// however long the reader was descheduled or stopped, its frames keep their
// counter's slots and never re-anchor forward. And back to the clock when the
// estimate runs ahead of it, never earlier than the previous sample.
// Timestamps therefore always increase.
// Frames whose configured axis is flagged invalid in the status byte are
// counted and not emitted. The port is reopened with backoff (100 ms doubling
// to 5 s wall) after a hang-up or when it cannot be opened; nothing of this
// stops the thread.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/drivers/devices.h"
#include "gyrotherm/drivers/frame_parser.h"
#include "gyrotherm/drivers/serial_port.h"

namespace gyrotherm::drivers {

class DutReader;  // dut_reader.h

enum class AngleUnit { kRad, kDeg };
enum class OutputKind { kRate, kDeltaAngle };  // rate: unit/s; delta: unit per sample

struct GyroFormat {
  AngleUnit unit = AngleUnit::kRad;
  OutputKind kind = OutputKind::kRate;
  int axis = 2;           // 0 = X, 1 = Y, 2 = Z
  double rate_hz = 10.0;  // the device's output rate (station time)
};

// Converts one axis value as sent into °/h.
double to_rate_dph(float value, const GyroFormat& format);

// The timestamping rule above, on its own (the reader uses one per opening
// of the port). Pure: tests feed it counters and clock readings.
class SampleClock {
 public:
  // `seq_modulo`: what the frames' counter wraps at (128 for the KVH 1750);
  // 0: frames carry no counter, each takes the next slot.
  SampleClock(double rate_hz, double tolerance_s, uint64_t seq_modulo = 128);
  // `seq`: the frame's counter; `now_s`: the station clock when the frame was
  // read. Returns the frame's station time.
  double stamp(uint64_t seq, double now_s);
  // After the frames of a read that emptied the line were stamped: when the
  // last one lags `now_s` by more than the tolerance, the anchor moves
  // forward so that it is stamped `now_s`. Returns how far (s, 0 if not): the
  // caller adds it to that read's stamps.
  double realign(double now_s);
  // Like realign, in both directions and whatever the tolerance: the last
  // frame stamped is taken to be at `now_s` (the line was just emptied on a
  // simulator's clock, where the stream never trails the clock by more than
  // a step). Returns the shift (s) the caller adds to the stamps so far.
  double settle(double now_s);
  // How far the last frame stamped lags `now_s` (0 before any).
  double lag_s(double now_s) const { return anchored_ ? now_s - last_t_s_ : 0.0; }
  void reset();  // the next frame anchors on the clock

 private:
  double period_s_;
  double tolerance_s_;
  uint64_t seq_modulo_;
  bool anchored_ = false;
  double anchor_s_ = 0;
  uint64_t n_ = 0;
  uint64_t last_seq_ = 0;
  double last_t_s_ = 0;
};

class GyroReader {
 public:
  using Sink = std::function<void(std::span<const GyroSample>)>;

  // `sink` is called on the reader thread with each batch of samples (t_s in
  // station seconds); it must not block for long.
  GyroReader(SerialOptions serial, GyroFormat format, std::unique_ptr<FrameParser> parser,
             const Clock& clock, Sink sink);
  ~GyroReader();  // stops the thread

  void start();
  void stop();  // idempotent; joins the thread
  GyroReaderHealth health() const;

 private:
  // The DutReader's frames -> samples of the configured axis.
  void on_frames(std::span<const DutFrame> frames);

  GyroFormat format_;
  Sink sink_;
  mutable std::mutex mu_;
  uint64_t samples_ = 0;
  uint64_t invalid_samples_ = 0;
  double last_sample_station_s_ = -1;
  std::vector<GyroSample> batch_;  // reused, reader thread only
  // Behind a pointer: dut_reader.h includes this header (via dut_link.h).
  std::unique_ptr<DutReader> reader_;
};

}  // namespace gyrotherm::drivers
