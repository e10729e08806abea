// DutReader: serial line -> DUT protocol -> timestamped frames of every
// channel, on its own thread.
//
// Timestamps follow the SampleClock rule (gyro_reader.h) with the
// protocol's counter wrap (DutProtocol::seq_modulo()); a protocol without a
// counter gets one slot per frame, its gaps found from the station clock
// only (a stalled line re-anchors at the read that empties it). Every frame
// is delivered, values flagged invalid as NaN; health() counts frames as
// `samples` and frames with any NaN value as `invalid_samples`. The port is
// reopened with backoff (100 ms doubling to 5 s wall) after a hang-up or
// when it cannot be opened; the protocol is reset then (a new stream's first
// counter is no gap). Nothing of this stops the thread.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/drivers/devices.h"
#include "gyrotherm/drivers/protocol.h"
#include "gyrotherm/drivers/serial_port.h"

namespace gyrotherm::drivers {

class DutReader {
 public:
  using Sink = std::function<void(std::span<const DutFrame>)>;

  // `sink` is called on the reader thread with each batch (t_s in station
  // seconds); it must not block for long. A non-empty `config_error` (a
  // caller's own check of its settings) makes start() report it in
  // health().last_error and read nothing.
  DutReader(SerialOptions serial, double rate_hz, std::unique_ptr<DutProtocol> protocol,
            const Clock& clock, Sink sink, std::string config_error = {});
  ~DutReader();  // stops the thread

  const std::vector<ChannelSpec>& channels() const { return protocol_->channels(); }
  void start();
  void stop();  // idempotent; joins the thread; no batch after it returns
  GyroReaderHealth health() const;

 private:
  // One opened line and the stamping of its stream (dut_reader.cpp).
  struct Line;

  // The thread: opens the line, reads it until it hangs up, waits the
  // backoff, and again, until stop().
  void run();
  // The rate checked; false (the error in health().last_error) when the
  // settings forbid reading.
  bool check_config();
  // Opens the port and starts a new stream on it (the protocol reset, a new
  // sample clock, the paced clock's slot), noted in health; nullopt when the
  // port cannot be opened (the error in health).
  std::optional<Line> open_line(bool reopened, double tolerance_s);
  // Reads, stamps and publishes frames until a read fails (a hang-up, noted
  // in health) or stop(); true when any read brought bytes. `buf` and
  // `frames` are the thread's buffers.
  bool read_until_hangup(Line& line, std::span<uint8_t> buf, std::vector<DutFrame>& frames);
  void note_read_error(const std::string& message);
  // A read that brought nothing: held frames that waited hold_max go out as a
  // jump; the clock is marked if the line is empty.
  void on_quiet_read(Line& line);
  // Stamps one read's frames (read at station time `now_s`); returns how
  // many carry a NaN value.
  uint64_t stamp_frames(Line& line, double now_s, std::vector<DutFrame>& frames);
  // Sets the stamps of one read's frames against the clock: kept until the
  // line is first emptied (paced), moved forward when it is emptied (paced),
  // held while the line lags (scaled clock). Leaves in `frames` what goes out
  // now.
  void anchor_frames(Line& line, bool drained, double now_s, std::vector<DutFrame>& frames);
  void release_as_jump(Line& line, double now_s, std::vector<DutFrame>& also);
  void mark_if_empty(Line& line);
  // Counts `frames` in health and hands them to the sink (its exception
  // noted in health).
  void publish(std::span<const DutFrame> frames);
  void publish_held(Line& line);
  // Waits `wall` or until stop(); returns false when stopping.
  bool wait_unless_stopped(std::chrono::milliseconds wall);

  SerialOptions serial_;
  double rate_hz_;
  std::unique_ptr<DutProtocol> protocol_;
  const Clock& clock_;
  Sink sink_;
  std::string config_error_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  mutable std::mutex mu_;
  std::condition_variable stop_cv_;  // wakes the backoff wait on stop()
  GyroReaderHealth health_;
};

// The DutSource of a DUT on a serial line (make_dut_source()).
class SerialDut final : public DutSource {
 public:
  SerialDut(SerialOptions serial, double rate_hz, std::unique_ptr<DutProtocol> protocol,
            const Clock& clock);
  const std::vector<ChannelSpec>& channels() const override { return reader_.channels(); }
  void start(Sink sink) override;
  void stop() override { reader_.stop(); }
  GyroReaderHealth health() const override { return reader_.health(); }

 private:
  Sink sink_;  // set before the reader's thread starts
  DutReader reader_;
};

}  // namespace gyrotherm::drivers
