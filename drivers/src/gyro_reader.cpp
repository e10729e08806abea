#include "gyrotherm/drivers/gyro_reader.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "gyrotherm/core/units.h"
#include "gyrotherm/drivers/dut_reader.h"
#include "gyrotherm/drivers/kvh1750.h"
#include "gyrotherm/drivers/protocol.h"

namespace gyrotherm::drivers {

SampleClock::SampleClock(double rate_hz, double tolerance_s, uint64_t seq_modulo)
    : period_s_(1.0 / rate_hz), tolerance_s_(tolerance_s), seq_modulo_(seq_modulo) {}

double SampleClock::stamp(uint64_t seq, double now_s) {
  if (seq_modulo_ != 0) seq %= seq_modulo_;
  if (anchored_) {
    if (seq_modulo_ == 0) {
      ++n_;  // no counter: the next slot
    } else {
      // Counter steps (1 + frames missed); a repeated counter is a whole wrap.
      const uint64_t step = (seq + seq_modulo_ - last_seq_) % seq_modulo_;
      n_ += step == 0 ? seq_modulo_ : step;
    }
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

double SampleClock::settle(double now_s) {
  if (!anchored_) return 0.0;
  const double shift_s = now_s - last_t_s_;
  anchor_s_ += shift_s;
  last_t_s_ = now_s;
  return shift_s;
}

void SampleClock::reset() { anchored_ = false; }

double to_rate_dph(float value, const GyroFormat& format) {
  double v = value;
  if (format.unit == AngleUnit::kRad) v = units::rad_to_deg(v);
  if (format.kind == OutputKind::kDeltaAngle) v *= format.rate_hz;
  return units::dps_to_dph(v);
}

namespace {

std::string format_error(const GyroFormat& format, const FrameParser* parser) {
  if (parser == nullptr) return "gyro reader has no frame parser";
  if (format.axis < 0 || format.axis > 2 || !(format.rate_hz > 0)) {
    return fmt::format("invalid gyro format: axis {} (expected 0..2), rate {} Hz (must be > 0)",
                       format.axis, format.rate_hz);
  }
  return {};
}

std::unique_ptr<DutProtocol> frame_protocol(const GyroFormat& format,
                                            std::unique_ptr<FrameParser> parser) {
  DutLink link;
  link.unit = format.unit;
  link.kind = format.kind;
  link.rate_hz = format.rate_hz > 0 ? format.rate_hz : 1.0;
  auto channels = dut_channels(link);  // kvh1750: cannot fail with rate_hz > 0
  if (parser == nullptr) parser = std::make_unique<Kvh1750Parser>();  // never read: format_error
  return std::make_unique<GyroFrameProtocol>(std::move(parser), std::move(channels).value());
}

}  // namespace

GyroReader::GyroReader(SerialOptions serial, GyroFormat format, std::unique_ptr<FrameParser> parser,
                       const Clock& clock, Sink sink)
    : format_(format), sink_(std::move(sink)) {
  std::string error = format_error(format, parser.get());
  reader_ = std::make_unique<DutReader>(
      std::move(serial), format.rate_hz > 0 ? format.rate_hz : 1.0,
      frame_protocol(format, std::move(parser)), clock,
      [this](std::span<const DutFrame> frames) { on_frames(frames); }, std::move(error));
}

GyroReader::~GyroReader() { stop(); }

void GyroReader::start() { reader_->start(); }

void GyroReader::stop() { reader_->stop(); }

GyroReaderHealth GyroReader::health() const {
  GyroReaderHealth h = reader_->health();
  std::lock_guard lock(mu_);
  h.samples = samples_;
  h.invalid_samples = invalid_samples_;
  h.last_sample_station_s = last_sample_station_s_;
  return h;
}

void GyroReader::on_frames(std::span<const DutFrame> frames) {
  const auto axis = static_cast<std::size_t>(format_.axis);
  const auto valid_bit = static_cast<uint8_t>(1u << axis);
  batch_.clear();
  uint64_t invalid = 0;
  for (const DutFrame& f : frames) {
    const auto status = static_cast<uint8_t>(f.raw[6]);
    // The status bit, not NaN: a value the gyro sent as NaN with its bit set
    // is passed on as it was before the DUT machinery.
    if (!(status & valid_bit)) {
      ++invalid;
      continue;
    }
    GyroSample s;
    s.t_s = f.t_s;
    s.rate_dph = to_rate_dph(static_cast<float>(f.raw[axis]), format_);
    s.seq = static_cast<uint8_t>(f.seq);
    s.status = status;
    s.temp_c = static_cast<int16_t>(f.raw[7]);
    batch_.push_back(s);
  }
  {
    std::lock_guard lock(mu_);
    samples_ += batch_.size();
    invalid_samples_ += invalid;
    if (!batch_.empty()) last_sample_station_s_ = batch_.back().t_s;
  }
  if (!batch_.empty() && sink_) sink_(batch_);
}

}  // namespace gyrotherm::drivers
