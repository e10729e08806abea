// A series the analysis reads more than once without holding it: a soak of
// any length, streamed from the database a storage chunk at a time.
//
// A SampleSource streams every sample of one series, in time order, in
// blocks of any size, to the callback it is given; it can be called again
// and streams the same samples again (the analysis makes one or two passes, a
// few more to find a median among thousands of distinct spacings: see
// scan_series, allan_deviation and make_analysis_series). A callback
// that returns false stops the pass; the source then returns Ok. Errors of
// the source (a database that cannot be read) come back as its Status.
#pragma once

#include <cstddef>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>

#include "gyrotherm/core/result.h"

namespace gyrotherm::analysis {

using SampleBlock = std::function<bool(std::span<const double> t_s, std::span<const double> value)>;
using SampleSource = std::function<Status(const SampleBlock& block)>;

// A source over two spans held by the caller (which must outlive it), in
// blocks of `block_size` samples (>= 1): the spans' own analysis through the
// streaming path, for tests.
SampleSource span_source(std::span<const double> t_s, std::span<const double> value,
                         std::size_t block_size = 4096);

// `inner` read on a second thread, `max_blocks` blocks ahead of the
// analysis (copied; memory: those blocks), so reading and decoding overlap
// the analysis on a second core. Each pass starts its own reader and joins
// it before it returns; a callback that stops the pass stops the reader.
// `inner` must not be used elsewhere meanwhile (a database connection).
SampleSource prefetched(SampleSource inner, std::size_t max_blocks = 8);

// What one pass over a series tells (scan_series).
struct SeriesScan {
  std::size_t n = 0;
  double t_first_s = 0, t_last_s = 0;
  // The two middle spacings t_{i+1} - t_i by rank (equal for an odd count
  // of spacings; both 0 with fewer than 2 samples). The median is their
  // mean; allan.h and table1.h each say how they form it.
  double spacing_lower_s = 0, spacing_upper_s = 0;
  // The mean of the first min(n, 4096) values: the shift of the Allan
  // variance's prefix sums (allan.h).
  double first_block_mean = 0;
};

// One pass (more when the spacings take over 4096 distinct values: then
// four more per middle rank, over the times, select it exactly): the count,
// the first and last times, the middle spacings. Errors (permanent, naming
// the sample's index and time; the caller puts its own name in front): a
// time or value not finite, times not strictly increasing; and the source's
// own. Memory: O(1) in the series' length.
Result<SeriesScan> scan_series(const SampleSource& source);

// scan_series one block at a time, for a pass that does more than scan.
class SpacingCounts;
class SeriesScanner {
 public:
  SeriesScanner();
  ~SeriesScanner();
  SeriesScanner(const SeriesScanner&) = delete;
  SeriesScanner& operator=(const SeriesScanner&) = delete;

  // Checks and counts the next block: false at the first bad sample (the
  // block's samples before it were counted), then error() says which.
  bool add(std::span<const double> t_s, std::span<const double> value);
  const std::optional<Error>& error() const { return bad_; }
  // The scan of what was added. When the spacings took too many values to
  // count, the middle ranks are selected by passes over `source` (the same
  // samples).
  Result<SeriesScan> finish(const SampleSource& source);

 private:
  std::unique_ptr<SpacingCounts> counts_;
  SeriesScan out_;
  std::size_t i_ = 0;
  double first_sum_ = 0;
  std::optional<Error> bad_;
};

// How much of a streamed Allan deviation may stay in memory (allan.h).
struct StreamLimits {
  // Prefix sums (8 bytes a sample) held in memory up to this many samples;
  // a longer series spills them to an unnamed file in scratch_dir.
  std::size_t prefix_in_memory = std::size_t{1} << 21;  // 16 MiB
  // Samples per window of the spilled sweep (3 windows in memory: 12 MiB).
  std::size_t window = std::size_t{1} << 19;
  // Where the spill file goes: "" takes $TMPDIR, else /tmp.
  std::string scratch_dir;

  // False with a message when window is < 4096 or prefix_in_memory < 2.
  bool is_valid(std::string* why) const;
};

}  // namespace gyrotherm::analysis
