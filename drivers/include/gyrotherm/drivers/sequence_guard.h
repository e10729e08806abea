// The rule for a frame's sequence counter (docs/devices.md, "Sequence
// counters"): a frame whose counter does not follow the previous frame's is
// not taken on its own word. It is held until the next frame:
//
//   - it lies on the way from the previous frame to the next one (counting
//     forward, modulo the wrap): the jump is real, frames were lost; the held
//     frame is emitted and the frames its counter skipped are counted missed;
//   - it does not (the next frame follows the previous one, or goes back
//     behind the held one): the held frame contradicts both neighbours and is
//     dropped, counted in sequence_rejects (its bytes as skipped, the reason
//     in last_reject); no frame is counted missed.
//
// A frame that follows its predecessor is emitted at once, so only a jump
// costs one frame of delay. After construction or reset() (the port was
// reopened) there is no previous frame: the first frame is held until the
// next one follows it (+1) and then anchors the count (no gap); when the
// next one does not follow, the first is dropped and the next one waits in
// its place. A frame still held at reset() was never confirmed and is
// dropped as above. Used by every protocol with a counter (Kvh1750Parser,
// AsciiLineProtocol), so what reaches the sample clock (SampleClock,
// gyro_reader.h) is only confirmed counters.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "gyrotherm/drivers/frame_parser.h"

namespace gyrotherm::drivers {

// The last_reject text of a dropped frame: `what` (e.g. the line), its
// counter, the counter it jumped from (nullopt: it was the first of the
// stream) and the next frame's counter (nullopt: none came before the line
// was reopened).
std::string sequence_reject_reason(std::string_view what, uint64_t seq,
                                   std::optional<uint64_t> after, std::optional<uint64_t> next_seq);

template <class Frame>
class SequenceGuard {
 public:
  // `modulo`: what the counter wraps at (> 1).
  explicit SequenceGuard(uint64_t modulo) : modulo_(modulo) {}

  // Judges a frame that passed its integrity check: `seq` its counter
  // (< modulo), `bytes` its size on the line (counted as skipped if it is
  // dropped), `what()` how to name it in last_reject (called only when the
  // frame is held). Appends to `out` whatever is now settled, in stream
  // order, counting frames_ok, sequence_gaps, frames_missed and
  // sequence_rejects in `c`.
  template <class Describe>
  void push(Frame frame, uint64_t seq, std::size_t bytes, Describe&& what, std::vector<Frame>& out,
            ParserCounters& c) {
    if (!last_) {
      // The stream's first frame counts once the next one follows it.
      if (held_ && seq == (held_->seq + 1) % modulo_) {
        emit_held(out, c);
        emit(std::move(frame), seq, out, c);
        return;
      }
      if (held_) drop_held(c, seq);
      held_ = Held{std::move(frame), seq, bytes, std::nullopt, std::string(what())};
      return;
    }
    if (held_) {
      const uint64_t to_held = distance(*last_, held_->seq);
      const uint64_t to_this = distance(*last_, seq);
      if (to_held > 0 && to_held < to_this) {
        ++c.sequence_gaps;
        c.frames_missed += to_held - 1;
        emit_held(out, c);
      } else {
        drop_held(c, seq);
      }
    }
    if (seq == (*last_ + 1) % modulo_) {
      emit(std::move(frame), seq, out, c);
      return;
    }
    held_ = Held{std::move(frame), seq, bytes, *last_, std::string(what())};
  }

  // A new stream (the port was reopened): a frame still held is dropped, the
  // count starts afresh.
  void reset(ParserCounters& c) {
    if (held_) drop_held(c, std::nullopt);
    last_.reset();
  }

 private:
  struct Held {
    Frame frame;
    uint64_t seq = 0;
    std::size_t bytes = 0;
    std::optional<uint64_t> after;  // the counter it jumped from; none: the first
    std::string what;
  };

  uint64_t distance(uint64_t from, uint64_t to) const { return (to + modulo_ - from) % modulo_; }

  void emit(Frame frame, uint64_t seq, std::vector<Frame>& out, ParserCounters& c) {
    last_ = seq;
    ++c.frames_ok;
    out.push_back(std::move(frame));
  }

  void emit_held(std::vector<Frame>& out, ParserCounters& c) {
    Held h = std::move(*held_);
    held_.reset();
    emit(std::move(h.frame), h.seq, out, c);
  }

  void drop_held(ParserCounters& c, std::optional<uint64_t> next_seq) {
    ++c.sequence_rejects;
    c.bytes_skipped += held_->bytes;
    c.last_reject = sequence_reject_reason(held_->what, held_->seq, held_->after, next_seq);
    held_.reset();
  }

  uint64_t modulo_;
  std::optional<uint64_t> last_;  // the last emitted frame's counter
  std::optional<Held> held_;
};

}  // namespace gyrotherm::drivers
