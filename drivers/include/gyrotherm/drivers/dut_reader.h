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
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>

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
  void run();
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
