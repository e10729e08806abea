// Streamed series: span_source, scan_series (sample_source.h).
#include "gyrotherm/analysis/sample_source.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "allan_detail.h"

namespace gyrotherm::analysis {

// The distinct spacings of a pass and how often each occurs, in an open
// addressing table of kSlots: exact while at most kMaxDistinct differ (a
// clock that stamps samples on a grid gives a handful), full otherwise.
class SpacingCounts {
 public:
  static constexpr std::size_t kSlots = 8192;
  static constexpr std::size_t kMaxDistinct = kSlots / 2;

  // False once the table is full (the counts are then incomplete).
  bool add(double d) {
    if (full_) return false;
    const uint64_t key = std::bit_cast<uint64_t>(d);
    if (last_ != nullptr && last_->key == key) {  // a regular clock: mostly the same spacing
      ++last_->count;
      return true;
    }
    std::size_t i = (key * 0x9E3779B97F4A7C15ULL) >> 51;  // 13 bits: kSlots
    while (true) {
      Slot& s = slots_[i];
      if (s.count != 0 && s.key == key) {
        ++s.count;
        last_ = &s;
        return true;
      }
      if (s.count == 0) {
        if (distinct_ == kMaxDistinct) {
          full_ = true;
          return false;
        }
        s.key = key;
        s.count = 1;
        ++distinct_;
        last_ = &s;
        return true;
      }
      i = (i + 1) & (kSlots - 1);
    }
  }
  bool full() const { return full_; }

  // The spacing of rank r (0-based, ascending) among those counted.
  double at_rank(uint64_t r) const {
    std::vector<std::pair<double, uint64_t>> v;
    for (const Slot& s : slots_) {
      if (s.count != 0) v.emplace_back(std::bit_cast<double>(s.key), s.count);
    }
    std::sort(v.begin(), v.end());
    for (const auto& [d, c] : v) {
      if (r < c) return d;
      r -= c;
    }
    return v.empty() ? 0.0 : v.back().first;
  }

 private:
  struct Slot {
    uint64_t key = 0;
    uint64_t count = 0;
  };
  std::array<Slot, kSlots> slots_{};
  Slot* last_ = nullptr;  // the slot counted last
  std::size_t distinct_ = 0;
  bool full_ = false;
};

namespace {

// The values whose mean is the Allan prefix sums' shift (SeriesScan): the
// prefix sums' first block, so a streamed pass shifts them as the in-memory
// path does (allan_detail::first_block_mean).
constexpr std::size_t kShiftBlock = allan_detail::kBlock;

// The spacing of rank r among all spacings of a clean series, by four
// passes over its times: a positive double orders as its bit pattern, so
// each pass counts the next 16 bits among the spacings that share the
// bits fixed so far.
Result<double> select_spacing(const SampleSource& source, uint64_t r) {
  uint64_t prefix = 0;
  for (int pass = 0; pass < 4; ++pass) {
    const int shift = 48 - 16 * pass;
    const uint64_t high_mask = pass == 0 ? 0 : ~uint64_t{0} << (shift + 16);
    std::vector<uint64_t> hist(65536, 0);
    std::optional<double> prev;
    Status st = source([&](std::span<const double> t, std::span<const double>) {
      for (const double ti : t) {
        if (prev) {
          const uint64_t bits = std::bit_cast<uint64_t>(ti - *prev);
          if ((bits & high_mask) == prefix) ++hist[(bits >> shift) & 0xFFFF];
        }
        prev = ti;
      }
      return true;
    });
    if (!st) return st.error();
    uint64_t digit = 0;
    while (digit < 65535 && r >= hist[digit]) r -= hist[digit++];
    prefix |= digit << shift;
  }
  return std::bit_cast<double>(prefix);
}

}  // namespace

SampleSource span_source(std::span<const double> t_s, std::span<const double> value,
                         std::size_t block_size) {
  block_size = std::max<std::size_t>(block_size, 1);
  return [t_s, value, block_size](const SampleBlock& block) -> Status {
    const std::size_t n = std::min(t_s.size(), value.size());
    for (std::size_t b = 0; b < n; b += block_size) {
      const std::size_t len = std::min(block_size, n - b);
      if (!block(t_s.subspan(b, len), value.subspan(b, len))) break;
    }
    return Status::Ok();
  };
}

SampleSource prefetched(SampleSource inner, std::size_t max_blocks) {
  max_blocks = std::max<std::size_t>(max_blocks, 1);
  return [inner = std::move(inner), max_blocks](const SampleBlock& block) -> Status {
    struct Block {
      std::vector<double> t, v;
    };
    std::mutex mu;
    std::condition_variable changed;
    std::deque<Block> ready;
    std::vector<Block> spare;
    bool stop = false, done = false;
    Status result = Status::Ok();
    std::thread reader([&] {
      Status st = inner([&](std::span<const double> t, std::span<const double> v) {
        Block b;
        {
          std::unique_lock lock(mu);
          changed.wait(lock, [&] { return stop || ready.size() < max_blocks; });
          if (stop) return false;
          if (!spare.empty()) {
            b = std::move(spare.back());
            spare.pop_back();
          }
        }
        b.t.assign(t.begin(), t.end());
        b.v.assign(v.begin(), v.end());
        std::lock_guard lock(mu);
        ready.push_back(std::move(b));
        changed.notify_all();
        return true;
      });
      std::lock_guard lock(mu);
      result = std::move(st);
      done = true;
      changed.notify_all();
    });
    while (true) {
      Block b;
      {
        std::unique_lock lock(mu);
        changed.wait(lock, [&] { return done || !ready.empty(); });
        if (ready.empty()) break;  // done, everything consumed
        b = std::move(ready.front());
        ready.pop_front();
        changed.notify_all();
      }
      const bool more = block(b.t, b.v);
      std::lock_guard lock(mu);
      spare.push_back(std::move(b));
      if (!more) {
        stop = true;
        changed.notify_all();
        break;
      }
    }
    reader.join();
    return result;
  };
}

bool StreamLimits::is_valid(std::string* why) const {
  if (window < 4096) {
    if (why) *why = fmt::format("window = {} samples, at least 4096 are needed", window);
    return false;
  }
  if (prefix_in_memory < 2) {
    if (why) *why = fmt::format("prefix_in_memory = {}, at least 2 is needed", prefix_in_memory);
    return false;
  }
  return true;
}

SeriesScanner::SeriesScanner() : counts_(std::make_unique<SpacingCounts>()) {}
SeriesScanner::~SeriesScanner() = default;

bool SeriesScanner::add(std::span<const double> t, std::span<const double> y) {
  if (bad_) return false;
  for (std::size_t j = 0; j < t.size(); ++j, ++i_) {
    if (!std::isfinite(t[j])) {
      bad_ = Error::Permanent(fmt::format("sample {}: time is not finite ({})", i_, t[j]));
      return false;
    }
    if (!std::isfinite(y[j])) {
      bad_ = Error::Permanent(
          fmt::format("sample {} at t_s={}: value is not finite ({})", i_, t[j], y[j]));
      return false;
    }
    if (i_ > 0) {
      if (!(t[j] > out_.t_last_s)) {
        bad_ = Error::Permanent(
            fmt::format("sample {}: time t_s={} does not increase (previous sample at t_s={})", i_,
                        t[j], out_.t_last_s));
        return false;
      }
      counts_->add(t[j] - out_.t_last_s);
    } else {
      out_.t_first_s = t[j];
    }
    if (i_ < kShiftBlock) first_sum_ += y[j];
    out_.t_last_s = t[j];
  }
  return true;
}

Result<SeriesScan> SeriesScanner::finish(const SampleSource& source) {
  if (bad_) return *bad_;
  SeriesScan out = out_;
  out.n = i_;
  out.first_block_mean =
      out.n == 0 ? 0.0 : first_sum_ / static_cast<double>(std::min(out.n, kShiftBlock));
  if (!std::isfinite(out.first_block_mean)) out.first_block_mean = 0;
  if (out.n < 2) return out;
  const uint64_t spacings = out.n - 1;
  const uint64_t upper_rank = spacings / 2;
  const uint64_t lower_rank = spacings % 2 == 1 ? upper_rank : upper_rank - 1;
  if (!counts_->full()) {
    out.spacing_lower_s = counts_->at_rank(lower_rank);
    out.spacing_upper_s = counts_->at_rank(upper_rank);
    return out;
  }
  auto upper = select_spacing(source, upper_rank);
  if (!upper) return upper.error();
  out.spacing_upper_s = *upper;
  if (lower_rank == upper_rank) {
    out.spacing_lower_s = *upper;
    return out;
  }
  auto lower = select_spacing(source, lower_rank);
  if (!lower) return lower.error();
  out.spacing_lower_s = *lower;
  return out;
}

Result<SeriesScan> scan_series(const SampleSource& source) {
  SeriesScanner scanner;
  Status st = source(
      [&](std::span<const double> t, std::span<const double> y) { return scanner.add(t, y); });
  if (!st) return st.error();
  return scanner.finish(source);
}

}  // namespace gyrotherm::analysis
