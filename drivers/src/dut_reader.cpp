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

constexpr std::chrono::milliseconds kMinBackoff{100};
constexpr std::chrono::milliseconds kMaxBackoff{5000};
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

void DutReader::run() {
  if (config_error_.empty() && (!(rate_hz_ > 0) || !std::isfinite(rate_hz_))) {
    config_error_ =
        fmt::format("DUT reader on {}: rate {} Hz (must be > 0)", serial_.device, rate_hz_);
  }
  if (!config_error_.empty()) {
    std::lock_guard lock(mu_);
    health_.last_error = config_error_;
    return;
  }
  // On a simulator's clock (paced) this reader marks how far it has read,
  // and the simulator never runs more than its lead ahead: the stream is
  // never more than that behind the clock, and the sample clock anchors
  // where the line was first emptied.
  const PacedClock* paced = as_paced(clock_);
  // How far the sample clock may drift from the station clock before it is
  // re-anchored: 2 s; on a scaled clock, one wall second at high time scales
  // (where a descheduled reader or simulator is late by many station
  // seconds).
  const double tolerance_s = paced ? 2.0 : std::max(2.0, 1.0 * clock_.time_scale());
  const std::size_t channels = protocol_->channels().size();

  std::array<uint8_t, 4096> buf{};
  std::vector<DutFrame> frames;
  auto backoff = kMinBackoff;
  bool opened_before = false;

  while (!stop_) {
    auto port = SerialPort::open(serial_);
    if (!port.ok()) {
      {
        std::lock_guard lock(mu_);
        health_.connected = false;
        health_.last_error = port.error().message;
      }
      if (!wait_unless_stopped(backoff)) break;
      backoff = std::min(backoff * 2, kMaxBackoff);
      continue;
    }
    protocol_->reset();
    {
      std::lock_guard lock(mu_);
      health_.connected = true;
      if (opened_before) ++health_.reopens;
      health_.parser = protocol_->counters();
    }
    opened_before = true;

    SampleClock sample_clock(rate_hz_, tolerance_s, protocol_->seq_modulo());
    std::unique_ptr<ClockConsumer> slot;
    if (paced) slot = paced->consumer("dut " + serial_.device);
    // Paced: frames read before the line was first emptied wait here, to be
    // stamped back from the moment it was (at most kMaxUnanchored).
    std::vector<DutFrame> unanchored;
    bool settled = paced == nullptr;
    // Scaled clock: the frames of a read that emptied the line lagging the
    // clock beyond the tolerance wait here for the next read. If that one
    // lags less, the sender is still working off a backlog (a reader that
    // was stopped): the frames keep their counter slots. If it lags as much,
    // or nothing comes within hold_max, the line really jumped (frames lost
    // that the counter cannot tell): they move forward with the clock.
    // Before, the first piece of a backlog realigned the clock and the rest
    // came "ahead" of it, squeezed 1 us apart.
    std::vector<DutFrame> held;
    double held_lag_s = 0;
    std::chrono::steady_clock::time_point held_at{};
    const auto hold_max = std::max<std::chrono::steady_clock::duration>(
        std::chrono::milliseconds(500),
        std::chrono::duration_cast<std::chrono::steady_clock::duration>(
            std::chrono::duration<double>(3.0 / rate_hz_ / std::max(clock_.time_scale(), 1e-3))));
    const auto deliver = [&](std::vector<DutFrame>& out) {
      {
        std::lock_guard lock(mu_);
        health_.samples += out.size();
        if (!out.empty()) health_.last_sample_station_s = out.back().t_s;
      }
      if (!out.empty() && sink_) {
        try {
          sink_(out);
        } catch (const std::exception& e) {
          std::lock_guard lock(mu_);
          health_.last_error = fmt::format("frame sink failed: {}", e.what());
        }
      }
    };
    // The held frames move with the clock (a jump) and go out.
    const auto release_as_jump = [&](double now_s, std::vector<DutFrame>& also) {
      const double shift_s = sample_clock.realign(now_s);
      for (auto& f : held) f.t_s += shift_s;
      for (auto& f : also) f.t_s += shift_s;
      also.insert(also.begin(), held.begin(), held.end());
      held.clear();
    };

    // Paced: everything the simulator made up to a station time is on the
    // line before it publishes that time; read the clock, then find the line
    // empty, and all of it has been read.
    double marked_s = -std::numeric_limits<double>::infinity();
    const auto mark_if_empty = [&] {
      if (!slot) return;
      const double t_s = clock_.now_s();
      if (port->pending_bytes() == 0 && t_s > marked_s) {
        slot->consumed(t_s);
        marked_s = t_s;
      }
    };

    while (!stop_) {
      auto got = port->read(buf, kReadTimeout);
      if (!got.ok()) {
        std::lock_guard lock(mu_);
        health_.connected = false;
        ++health_.read_errors;
        health_.last_error = got.error().message;
        break;
      }
      if (*got == 0) {
        if (!held.empty() && std::chrono::steady_clock::now() - held_at >= hold_max) {
          std::vector<DutFrame> none;
          release_as_jump(clock_.now_s(), none);
          deliver(none);
        }
        mark_if_empty();
        continue;
      }
      // Nothing left on the line: this read's last frame arrived just now.
      const bool drained = port->pending_bytes() == 0;
      backoff = kMinBackoff;  // the port delivers data: a later hang-up starts afresh

      frames.clear();
      protocol_->feed(std::span<const uint8_t>(buf.data(), *got), frames);
      const double now_s = clock_.now_s();
      uint64_t invalid = 0;
      for (DutFrame& f : frames) {
        f.t_s = sample_clock.stamp(f.seq, now_s);
        if (has_nan(f, channels)) ++invalid;
      }
      if (!settled) {
        unanchored.insert(unanchored.end(), frames.begin(), frames.end());
        frames.clear();
        if (drained || unanchored.size() >= kMaxUnanchored) {
          if (drained) {
            const double shift_s = sample_clock.settle(now_s);
            for (auto& f : unanchored) f.t_s += shift_s;
          }
          frames.swap(unanchored);
          settled = true;
        }
      } else if (paced) {
        if (drained) {
          if (const double shift_s = sample_clock.realign(now_s); shift_s > 0) {
            for (auto& f : frames) f.t_s += shift_s;
          }
        }
      } else {
        if (!held.empty()) {
          if (sample_clock.lag_s(now_s) > held_lag_s - 0.5 * tolerance_s) {
            release_as_jump(now_s, frames);  // not catching up
          } else {
            frames.insert(frames.begin(), held.begin(), held.end());  // a backlog
            held.clear();
          }
        }
        if (drained && sample_clock.lag_s(now_s) > tolerance_s) {
          held_lag_s = sample_clock.lag_s(now_s);
          held_at = std::chrono::steady_clock::now();
          held.insert(held.end(), frames.begin(), frames.end());
          frames.clear();
        }
      }

      {
        std::lock_guard lock(mu_);
        health_.invalid_samples += invalid;
        health_.parser = protocol_->counters();
      }
      deliver(frames);
      if (drained && slot) {
        // The simulator publishes a time just after it wrote that time's
        // frames: a reader this quick waits a moment for it rather than a
        // whole read timeout.
        if (clock_.now_s() <= marked_s) (void)paced->wait_until(marked_s + 1e-9, kPublishWait);
        mark_if_empty();
      }
    }
    // Nothing read is dropped with the line: held frames go out as stamped.
    if (!held.empty()) {
      std::vector<DutFrame> rest;
      rest.swap(held);
      deliver(rest);
    }
    if (stop_) break;
    if (!wait_unless_stopped(backoff)) break;
    backoff = std::min(backoff * 2, kMaxBackoff);
  }
  std::lock_guard lock(mu_);
  health_.connected = false;
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
