#include "gyrotherm/drivers/dut_reader.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include "gyrotherm/core/paced_clock.h"
#include "gyrotherm/drivers/dut_link.h"
#include "gyrotherm/drivers/gyro_reader.h"

namespace gyrotherm::drivers {
namespace {

constexpr std::chrono::milliseconds kMinReopenBackoff{100};
constexpr std::chrono::milliseconds kMaxReopenBackoff{5000};
constexpr std::chrono::milliseconds kReadTimeout{50};
constexpr std::size_t kMaxUnanchored = 65536;
constexpr std::chrono::milliseconds kPublishWait{5};

bool has_nan(const DutFrame& f, std::size_t channels) {
  for (std::size_t i = 0; i < channels && i < kMaxChannels; ++i) {
    if (std::isnan(f.raw[i])) return true;
  }
  return false;
}

}  // namespace

DutReader::DutReader(SerialOptions serial, double rate_hz, std::unique_ptr<DutProtocol> protocol,
                     const Clock& clock, Sink sink, std::string config_error)
    : serial_(std::move(serial)),
      rate_hz_(rate_hz),
      protocol_(std::move(protocol)),
      clock_(clock),
      sink_(std::move(sink)),
      config_error_(std::move(config_error)) {}

DutReader::~DutReader() { stop(); }

void DutReader::start() {
  if (thread_.joinable()) return;
  {
    std::lock_guard lock(mu_);
    stop_ = false;
  }
  thread_ = std::thread([this] { run(); });
}

void DutReader::stop() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
  }
  stop_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

GyroReaderHealth DutReader::health() const {
  std::lock_guard lock(mu_);
  return health_;
}

bool DutReader::wait_unless_stopped(std::chrono::milliseconds wall) {
  std::unique_lock lock(mu_);
  stop_cv_.wait_for(lock, wall, [this] { return stop_.load(); });
  return !stop_;
}

// One opened line and the stamping of its stream; the reader thread's own.
// It lives until the backoff after the line hung up is over; its clock slot
// is let go when the line hangs up (run()).
struct DutReader::Line {
  SerialPort port;
  const PacedClock* paced;  // the clock's paced side, or null
  double tolerance_s;
  SampleClock sample_clock;
  std::unique_ptr<ClockConsumer> slot;  // paced only
  // Paced: frames read before the line was first emptied wait here, to be
  // stamped back from the moment it was (at most kMaxUnanchored).
  std::vector<DutFrame> unanchored{};
  bool settled;
  // Scaled clock: the frames of a read that emptied the line lagging the
  // clock beyond the tolerance wait here for the next read. If that one
  // lags less, the sender is still working off a backlog (a reader that
  // was stopped): the frames keep their counter slots. If it lags as much,
  // or nothing comes within hold_max, the line really jumped (frames lost
  // that the counter cannot tell): they move forward with the clock.
  // Before, the first piece of a backlog realigned the clock and the rest
  // came "ahead" of it, squeezed 1 us apart.
  std::vector<DutFrame> held{};
  double held_lag_s = 0;
  std::chrono::steady_clock::time_point held_at{};
  std::chrono::steady_clock::duration hold_max;
  double marked_s = -std::numeric_limits<double>::infinity();  // last marked consumed
};

void DutReader::run() {
  if (!check_config()) return;
  // How far the sample clock may drift from the station clock before it is
  // re-anchored: 2 s; on a scaled clock, one wall second at high time scales
  // (where a descheduled reader or simulator is late by many station
  // seconds).
  const double tolerance_s = as_paced(clock_) ? 2.0 : std::max(2.0, 1.0 * clock_.time_scale());

  std::array<uint8_t, 4096> buf{};
  std::vector<DutFrame> frames;
  auto backoff = kMinReopenBackoff;
  bool opened_before = false;

  while (!stop_) {
    std::optional<Line> line = open_line(opened_before, tolerance_s);
    if (!line) {
      if (!wait_unless_stopped(backoff)) break;
      backoff = std::min(backoff * 2, kMaxReopenBackoff);
      continue;
    }
    opened_before = true;
    if (read_until_hangup(*line, buf, frames)) {
      backoff = kMinReopenBackoff;  // the port delivers data: a later hang-up starts afresh
    }
    publish_held(*line);
    // The line is gone: its slot on a simulator's clock goes now, so the
    // simulated station's time runs on through the outage as a real one's
    // would (the backoff and the reopen are a gap in station time too).
    // Held through the backoff, the slot stopped the clock for as long as
    // the reader waited: how much of an outage the samples showed depended
    // on wall-clock timing. The port stays open until the backoff is over:
    // closed at once, its pseudo-terminal's number was free for another
    // process to take, and the reopen found that one's line at the path.
    line->slot.reset();
    if (stop_) break;
    if (!wait_unless_stopped(backoff)) break;
    backoff = std::min(backoff * 2, kMaxReopenBackoff);
  }
  std::lock_guard lock(mu_);
  health_.connected = false;
}

bool DutReader::check_config() {
  if (config_error_.empty() && (!(rate_hz_ > 0) || !std::isfinite(rate_hz_))) {
    config_error_ =
        fmt::format("DUT reader on {}: rate {} Hz (must be > 0)", serial_.device, rate_hz_);
  }
  if (!config_error_.empty()) {
    std::lock_guard lock(mu_);
    health_.last_error = config_error_;
    return false;
  }
  return true;
}

std::optional<DutReader::Line> DutReader::open_line(bool reopened, double tolerance_s) {
  auto port = SerialPort::open(serial_);
  if (!port.ok()) {
    std::lock_guard lock(mu_);
    health_.connected = false;
    health_.last_error = port.error().message;
    return std::nullopt;
  }
  protocol_->reset();
  {
    std::lock_guard lock(mu_);
    health_.connected = true;
    if (reopened) ++health_.reopens;
    health_.parser = protocol_->counters();
  }
  // On a simulator's clock (paced) this reader marks how far it has read,
  // and the simulator never runs more than its lead ahead: the stream is
  // never more than that behind the clock, and the sample clock anchors
  // where the line was first emptied.
  const PacedClock* paced = as_paced(clock_);
  return Line{
      .port = std::move(port).value(),
      .paced = paced,
      .tolerance_s = tolerance_s,
      .sample_clock = SampleClock(rate_hz_, tolerance_s, protocol_->seq_modulo()),
      .slot = paced ? paced->consumer("dut " + serial_.device) : nullptr,
      .settled = paced == nullptr,
      .hold_max = std::max<std::chrono::steady_clock::duration>(
          std::chrono::milliseconds(500),
          std::chrono::duration_cast<std::chrono::steady_clock::duration>(
              std::chrono::duration<double>(3.0 / rate_hz_ / std::max(clock_.time_scale(), 1e-3)))),
  };
}

bool DutReader::read_until_hangup(Line& line, std::span<uint8_t> buf,
                                  std::vector<DutFrame>& frames) {
  bool got_bytes = false;
  while (!stop_) {
    auto got = line.port.read(buf, kReadTimeout);
    if (!got.ok()) {
      note_read_error(got.error().message);
      break;
    }
    if (*got == 0) {
      on_quiet_read(line);
      continue;
    }
    // Nothing left on the line: this read's last frame arrived just now.
    const bool drained = line.port.pending_bytes() == 0;
    got_bytes = true;

    frames.clear();
    protocol_->feed(std::span<const uint8_t>(buf.data(), *got), frames);
    const double now_s = clock_.now_s();
    const uint64_t invalid = stamp_frames(line, now_s, frames);
    anchor_frames(line, drained, now_s, frames);

    {
      std::lock_guard lock(mu_);
      health_.invalid_samples += invalid;
      health_.parser = protocol_->counters();
    }
    publish(frames);
    if (drained && line.slot) {
      // The simulator publishes a time just after it wrote that time's
      // frames: a reader this quick waits a moment for it rather than a
      // whole read timeout.
      if (clock_.now_s() <= line.marked_s) {
        (void)line.paced->wait_until(line.marked_s + 1e-9, kPublishWait);
      }
      mark_if_empty(line);
    }
  }
  return got_bytes;
}

void DutReader::note_read_error(const std::string& message) {
  std::lock_guard lock(mu_);
  health_.connected = false;
  ++health_.read_errors;
  health_.last_error = message;
}

void DutReader::on_quiet_read(Line& line) {
  if (!line.held.empty() && std::chrono::steady_clock::now() - line.held_at >= line.hold_max) {
    std::vector<DutFrame> none;
    release_as_jump(line, clock_.now_s(), none);
    publish(none);
  }
  mark_if_empty(line);
}

uint64_t DutReader::stamp_frames(Line& line, double now_s, std::vector<DutFrame>& frames) {
  const std::size_t channels = protocol_->channels().size();
  uint64_t invalid = 0;
  for (DutFrame& f : frames) {
    f.t_s = line.sample_clock.stamp(f.seq, now_s);
    if (has_nan(f, channels)) ++invalid;
  }
  return invalid;
}

void DutReader::anchor_frames(Line& line, bool drained, double now_s,
                              std::vector<DutFrame>& frames) {
  if (!line.settled) {
    line.unanchored.insert(line.unanchored.end(), frames.begin(), frames.end());
    frames.clear();
    if (drained || line.unanchored.size() >= kMaxUnanchored) {
      if (drained) {
        const double shift_s = line.sample_clock.settle(now_s);
        for (auto& f : line.unanchored) f.t_s += shift_s;
      }
      frames.swap(line.unanchored);
      line.settled = true;
    }
  } else if (line.paced) {
    if (drained) {
      if (const double shift_s = line.sample_clock.realign(now_s); shift_s > 0) {
        for (auto& f : frames) f.t_s += shift_s;
      }
    }
  } else {
    if (!line.held.empty()) {
      if (line.sample_clock.lag_s(now_s) > line.held_lag_s - 0.5 * line.tolerance_s) {
        release_as_jump(line, now_s, frames);  // not catching up
      } else {
        frames.insert(frames.begin(), line.held.begin(), line.held.end());  // a backlog
        line.held.clear();
      }
    }
    if (drained && line.sample_clock.lag_s(now_s) > line.tolerance_s) {
      line.held_lag_s = line.sample_clock.lag_s(now_s);
      line.held_at = std::chrono::steady_clock::now();
      line.held.insert(line.held.end(), frames.begin(), frames.end());
      frames.clear();
    }
  }
}

// The held frames move with the clock (a jump) and go out.
void DutReader::release_as_jump(Line& line, double now_s, std::vector<DutFrame>& also) {
  const double shift_s = line.sample_clock.realign(now_s);
  for (auto& f : line.held) f.t_s += shift_s;
  for (auto& f : also) f.t_s += shift_s;
  also.insert(also.begin(), line.held.begin(), line.held.end());
  line.held.clear();
}

// Paced: everything the simulator made up to a station time is on the
// line before it publishes that time; read the clock, then find the line
// empty, and all of it has been read.
void DutReader::mark_if_empty(Line& line) {
  if (!line.slot) return;
  const double t_s = clock_.now_s();
  if (line.port.pending_bytes() == 0 && t_s > line.marked_s) {
    line.slot->consumed(t_s);
    line.marked_s = t_s;
  }
}

void DutReader::publish(std::span<const DutFrame> frames) {
  {
    std::lock_guard lock(mu_);
    health_.samples += frames.size();
    if (!frames.empty()) health_.last_sample_station_s = frames.back().t_s;
  }
  if (!frames.empty() && sink_) {
    try {
      sink_(frames);
    } catch (const std::exception& e) {
      std::lock_guard lock(mu_);
      health_.last_error = fmt::format("frame sink failed: {}", e.what());
    }
  }
}

void DutReader::publish_held(Line& line) {
  // Nothing read is dropped with the line: held frames go out as stamped.
  if (!line.held.empty()) {
    std::vector<DutFrame> rest;
    rest.swap(line.held);
    publish(rest);
  }
}

SerialDut::SerialDut(SerialOptions serial, double rate_hz, std::unique_ptr<DutProtocol> protocol,
                     const Clock& clock)
    : reader_(std::move(serial), rate_hz, std::move(protocol), clock,
              [this](std::span<const DutFrame> frames) { sink_(frames); }) {}

void SerialDut::start(Sink sink) {
  sink_ = std::move(sink);
  reader_.start();
}

Result<std::unique_ptr<DutSource>> make_dut_source(const DutLink& link, const Clock& clock) {
  auto protocol = make_dut_protocol(link);
  if (!protocol.ok()) return protocol.error();
  return std::unique_ptr<DutSource>(
      new SerialDut(link.serial, link.rate_hz, std::move(protocol).value(), clock));
}

}  // namespace gyrotherm::drivers
