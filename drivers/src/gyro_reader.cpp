#include "gyrotherm/drivers/gyro_reader.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "gyrotherm/core/units.h"
#include "gyrotherm/drivers/kvh1750.h"

namespace gyrotherm::drivers {
namespace {

constexpr std::chrono::milliseconds kMinBackoff{100};
constexpr std::chrono::milliseconds kMaxBackoff{5000};
constexpr std::chrono::milliseconds kReadTimeout{50};

}  // namespace

SampleClock::SampleClock(double rate_hz, double tolerance_s)
    : period_s_(1.0 / rate_hz), tolerance_s_(tolerance_s) {}

double SampleClock::stamp(int seq, double now_s) {
  seq %= kKvh1750SeqModulo;
  if (anchored_) {
    // Counter steps (1 + frames missed); the KVH 1750 counter wraps at 128.
    const int step = (seq - last_seq_ + kKvh1750SeqModulo) % kKvh1750SeqModulo;
    n_ += static_cast<uint64_t>(step == 0 ? kKvh1750SeqModulo : step);
  }
  last_seq_ = seq;
  double t_s = anchor_s_ + static_cast<double>(n_) * period_s_;
  const bool ahead = t_s - now_s > tolerance_s_;
  if (!anchored_ || ahead) {
    // Ahead: frames come faster than rate_hz says (misconfigured); back to
    // the clock, but strictly after the previous sample.
    t_s = anchored_ && ahead ? std::max(now_s, last_t_s_ + 1e-6) : now_s;
    anchored_ = true;
    anchor_s_ = t_s;
    n_ = 0;
  }
  last_t_s_ = t_s;
  return t_s;
}

double SampleClock::realign(double now_s) {
  if (!anchored_) return 0.0;
  const double lag_s = now_s - last_t_s_;
  if (lag_s <= tolerance_s_) return 0.0;
  anchor_s_ += lag_s;
  last_t_s_ = now_s;
  return lag_s;
}

void SampleClock::reset() { anchored_ = false; }

double to_rate_dph(float value, const GyroFormat& format) {
  double v = value;
  if (format.unit == AngleUnit::kRad) v = units::rad_to_deg(v);
  if (format.kind == OutputKind::kDeltaAngle) v *= format.rate_hz;
  return units::dps_to_dph(v);
}

GyroReader::GyroReader(SerialOptions serial, GyroFormat format, std::unique_ptr<FrameParser> parser,
                       const Clock& clock, Sink sink)
    : serial_(std::move(serial)),
      format_(format),
      parser_(std::move(parser)),
      clock_(clock),
      sink_(std::move(sink)) {}

GyroReader::~GyroReader() { stop(); }

void GyroReader::start() {
  if (thread_.joinable()) return;
  {
    std::lock_guard lock(mu_);
    stop_ = false;
  }
  thread_ = std::thread([this] { run(); });
}

void GyroReader::stop() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
  }
  stop_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

GyroReaderHealth GyroReader::health() const {
  std::lock_guard lock(mu_);
  return health_;
}

bool GyroReader::wait_unless_stopped(std::chrono::milliseconds wall) {
  std::unique_lock lock(mu_);
  stop_cv_.wait_for(lock, wall, [this] { return stop_.load(); });
  return !stop_;
}

void GyroReader::run() {
  if (format_.axis < 0 || format_.axis > 2 || !(format_.rate_hz > 0) || parser_ == nullptr) {
    std::lock_guard lock(mu_);
    health_.last_error =
        parser_ == nullptr
            ? std::string("gyro reader has no frame parser")
            : fmt::format("invalid gyro format: axis {} (expected 0..2), rate {} Hz (must be > 0)",
                          format_.axis, format_.rate_hz);
    return;
  }
  // How far the sample clock may drift from the station clock before it is
  // re-anchored: 2 s, or one wall second at high time scales (where a
  // descheduled reader or simulator is late by many station seconds).
  const double tolerance_s = std::max(2.0, 1.0 * clock_.time_scale());
  const auto valid_bit = static_cast<uint8_t>(1u << format_.axis);

  std::array<uint8_t, 4096> buf{};
  std::vector<GyroFrame> frames;
  std::vector<GyroSample> samples;
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
    parser_->reset();
    {
      std::lock_guard lock(mu_);
      health_.connected = true;
      if (opened_before) ++health_.reopens;
      health_.parser = parser_->counters();
    }
    opened_before = true;

    SampleClock sample_clock(format_.rate_hz, tolerance_s);

    while (!stop_) {
      auto got = port->read(buf, kReadTimeout);
      if (!got.ok()) {
        std::lock_guard lock(mu_);
        health_.connected = false;
        ++health_.read_errors;
        health_.last_error = got.error().message;
        break;
      }
      if (*got == 0) continue;
      // Nothing left on the line: this read's last frame arrived just now.
      const bool drained = port->pending_bytes() == 0;
      backoff = kMinBackoff;  // the port delivers data: a later hang-up starts afresh

      frames.clear();
      samples.clear();
      parser_->feed(std::span<const uint8_t>(buf.data(), *got), frames);
      uint64_t invalid = 0;
      const double now_s = clock_.now_s();
      for (std::size_t i = 0; i < frames.size(); ++i) {
        const GyroFrame& f = frames[i];
        const double t_s = sample_clock.stamp(f.seq, now_s);
        if (!(f.status & valid_bit)) {
          ++invalid;
          continue;
        }
        GyroSample s;
        s.t_s = t_s;
        s.rate_dph = to_rate_dph(f.gyro[static_cast<std::size_t>(format_.axis)], format_);
        s.seq = f.seq;
        s.status = f.status;
        s.temp_c = f.temp_c;
        samples.push_back(s);
      }
      if (drained) {
        if (const double shift_s = sample_clock.realign(now_s); shift_s > 0) {
          for (auto& s : samples) s.t_s += shift_s;
        }
      }
      {
        std::lock_guard lock(mu_);
        health_.samples += samples.size();
        health_.invalid_samples += invalid;
        health_.parser = parser_->counters();
        if (!samples.empty()) health_.last_sample_station_s = samples.back().t_s;
      }
      if (!samples.empty() && sink_) {
        try {
          sink_(samples);
        } catch (const std::exception& e) {
          std::lock_guard lock(mu_);
          health_.last_error = fmt::format("gyro sample sink failed: {}", e.what());
        }
      }
    }
    if (stop_) break;
    if (!wait_unless_stopped(backoff)) break;
    backoff = std::min(backoff * 2, kMaxBackoff);
  }
  std::lock_guard lock(mu_);
  health_.connected = false;
}

SerialGyro::SerialGyro(SerialOptions serial, GyroFormat format, std::unique_ptr<FrameParser> parser,
                       const Clock& clock)
    : reader_(std::move(serial), format, std::move(parser), clock,
              [this](std::span<const GyroSample> samples) { sink_(samples); }) {}

void SerialGyro::start(Sink sink) {
  sink_ = std::move(sink);
  reader_.start();
}

}  // namespace gyrotherm::drivers
