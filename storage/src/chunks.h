// Chunked sample storage (schema v9, docs/storage.md "sample_chunks"): the
// value codec, the sample clock that decides where a chunk ends, and the
// builder the sample writer and the v9 migration share.
//
// A chunk holds up to kChunkCapacity consecutive samples of one channel on a
// regular clock: sample i is at t0_s + i * period_s with counter
// (seq0 + i) mod seq_modulo. Values are the raw values as sent, stored
// exactly in the narrowest encoding that holds every one of them.
#pragma once

#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"

namespace gyrotherm::storage::internal {

// At most this many samples per chunk: 4 s at 1 kHz; a 16 KiB BLOB of f32.
inline constexpr int64_t kChunkCapacity = 4096;

// channel_rollup levels: block length 0.1 * 10^level s (the numbering of
// the older gyro_rollup); level 0 (0.1 s) is not kept, the chunks
// themselves are the finest summaries.
inline constexpr int kChannelRollupFirstLevel = 1;
inline constexpr int kChannelRollupLastLevel = 4;
inline constexpr double kChannelRollupBlockS[] = {0.1, 1.0, 10.0, 100.0, 1000.0};

// The type of each stored value. i64 is only written as the integer of a
// decimal encoding (ChunkEncoding::decimals > 0).
enum class Encoding : uint8_t { kU8, kI8, kU16, kI16, kU32, kI32, kF32, kF64, kI64 };
std::string_view to_string(Encoding e);  // u8, i8, u16, i16, u32, i32, f32, f64, i64
std::optional<Encoding> encoding_from_string(std::string_view s);
std::size_t encoded_size(Encoding e);  // bytes per value

// How a chunk's `data` holds its values: sample_chunks.encoding
// (docs/storage.md "Encodings").
//   <base>                 n values of base, little-endian (u8 ... f64)
//   i32/1e<k>, i64/1e<k>   decimal: n integers m, the value is m / 10^k
//                          (k = 1 ... 15) computed in double, which is the
//                          same double as parsing the decimal; the type's
//                          smallest value is NaN
//   <either>+shuffle+zstd  the same n values with their bytes transposed
//                          (byte 0 of every value, then byte 1, ...) in
//                          one zstd frame
struct ChunkEncoding {
  Encoding base = Encoding::kF64;
  int decimals = 0;  // > 0: base (i32 or i64) holds value × 10^decimals
  bool zstd = false;
  bool operator==(const ChunkEncoding&) const = default;
};
std::string to_string(const ChunkEncoding& e);
std::optional<ChunkEncoding> chunk_encoding_from_string(std::string_view s);
inline constexpr int kMaxDecimals = 15;
inline constexpr int kZstdLevel = 6;

// The fewest decimals k (1 ... kMaxDecimals) with which every value is
// exactly (bit for bit) m / 10^k for an integer |m| < 2^53, the NaNs being
// std::numeric_limits<double>::quiet_NaN(); nullopt when there is none
// (a value that is not such a decimal, -0, an infinity, another NaN) or
// when every value is an integer (k = 0: the integer encodings hold them).
std::optional<int> decimal_places(std::span<const double> raw);

// Encodes `raw` for a chunk that will not grow any more: the smallest of
// the narrowest plain encoding (`plain`, which must hold every value), a
// decimal one, and either packed with shuffle+zstd; a packed or decimal
// encoding is taken only once it decoded back to the same values (bit for
// bit; NaN as NaN). Replaces `out`.
ChunkEncoding encode_closed(Encoding plain, std::span<const double> raw, std::string& out);
// Decodes n values of any ChunkEncoding; false when `data` is not n values
// of it (a wrong size, a damaged zstd frame).
bool decode(const ChunkEncoding& e, const void* data, std::size_t bytes, std::size_t n,
            double* out);

// What a channel's values so far need, kept as values arrive; encoding()
// is the narrowest encoding that stores every one of them exactly
// (integers in the smallest integer type, else f32 when each value
// round-trips through float, else f64; NaN needs a float type).
class EncodingNeed {
 public:
  void add(double raw) {
    // Range first: a cast of NaN or of a value beyond the target type is
    // undefined behaviour.
    const bool int_range = raw >= -2147483648.0 && raw <= 4294967295.0;  // false for NaN
    if (integral_ && int_range && raw == std::trunc(raw) && !(raw == 0 && std::signbit(raw))) {
      if (raw < min_) min_ = raw;
      if (raw > max_) max_ = raw;
    } else {
      integral_ = false;
    }
    if (f32_ && !std::isnan(raw)) {
      const bool float_range =
          std::isinf(raw) ||
          std::fabs(raw) <= static_cast<double>(std::numeric_limits<float>::max());
      if (!float_range || static_cast<double>(static_cast<float>(raw)) != raw) f32_ = false;
    }
  }
  Encoding encoding() const;

 private:
  bool integral_ = true;
  bool f32_ = true;
  double min_ = 0, max_ = 0;
};

// Appends `raw` encoded (little-endian) to `out`. Values must fit (see
// EncodingNeed).
void encode(Encoding e, std::span<const double> raw, std::string& out);
// Decodes n values; false when the BLOB's size is not n values.
bool decode(Encoding e, const void* data, std::size_t bytes, std::size_t n, double* out);

// The clock of an open chunk: does a sample at t_s with counter seq follow
// the chunk's samples?
struct ChunkClock {
  double t0_s = 0;
  double period_s = 0;  // 0 while n < 2
  int64_t n = 0;
  uint32_t seq0 = 0;

  double t_last_s() const { return t0_s + static_cast<double>(n - 1) * period_s; }
  // nominal_period_s: 1 / rate_hz (0 = unknown), bounds the second sample's
  // step; seq_modulo 0: the frames carry no counter (seq not checked).
  bool continues(double t_s, uint32_t seq, double nominal_period_s, uint32_t seq_modulo) const;
  // Takes the sample (continues() held, or n == 0).
  void add(double t_s, uint32_t seq);
};

// A channel of a DUT in a run, as the writer, the readers and the
// migration need it.
struct ChannelInfo {
  int64_t id = 0;
  int index = 0;
  std::string name, unit, axis;
  ChannelKind kind = ChannelKind::kOther;
  double scale = 1.0;
};

// Per-channel rollup accumulator of one block.
struct RollupAcc {
  int64_t n = 0, v_n = 0;
  double t_sum_s = 0, v_sum = 0;
  double v_min = std::numeric_limits<double>::infinity();
  double v_max = -std::numeric_limits<double>::infinity();
  void add(double t_s, double v) {
    ++n;
    t_sum_s += t_s;
    if (std::isfinite(v)) {
      ++v_n;
      v_sum += v;
      v_min = std::min(v_min, v);
      v_max = std::max(v_max, v);
    }
  }
  void merge(const RollupAcc& o) {
    n += o.n;
    v_n += o.v_n;
    t_sum_s += o.t_sum_s;
    v_sum += o.v_sum;
    v_min = std::min(v_min, o.v_min);
    v_max = std::max(v_max, o.v_max);
  }
};

// Builds the chunks of one DUT's channels from its frames, in time order,
// and writes them (and their rollups) with prepared statements on `db`.
// Open chunks are kept in memory; each flush() writes the samples added
// since the last one as a piece: a chunk row of its own, in the narrowest
// plain encoding, numbered (sample_chunks.piece = 1, 2, ...) within its
// chunk. When the chunk closes (a gap, the cap, finish()) a flush() deletes
// its pieces and inserts the whole chunk in its smallest encoding
// (encode_closed), in the same transaction, so a chunk's length does not
// depend on how often the caller commits, and what a commit wrote stays
// readable until the chunk replaces it. A flush packs at most the budget it
// is given (channel-chunks, oldest first); a closed chunk left over gets
// its last samples written as a piece (committed like every sample) and is
// packed by a later flush. Not thread-safe; the caller owns the
// transaction.
class ChunkBuilder {
 public:
  // write_pieces false (the v9 migration, whose table has no `piece`
  // column yet): the open chunk is kept in memory until it closes; flush()
  // writes closed chunks only.
  ChunkBuilder(std::vector<ChannelInfo> channels, double rate_hz, uint32_t seq_modulo,
               bool write_pieces = true);

  // Where the stored samples end (restart: the last stored time of the
  // DUT's channels; samples at or before it are duplicates).
  void set_last_stored_t_s(std::optional<double> t_s) { last_t_s_ = t_s; }
  std::optional<double> last_t_s() const { return last_t_s_; }

  // Adds one frame (raw values by channel index). False: a duplicate (t_s
  // not after the last sample), ignored.
  bool add(double t_s, uint32_t seq, const double* raw);

  // Closes the open chunk (the writer stops, the run is closed): a later
  // flush() packs it. Later samples start a new chunk.
  void finish() { close_open(); }
  // Whether finish() has something to close.
  bool has_open_chunk() const { return clock_.n > 0; }
  // Closed channel-chunks not packed yet (written as pieces or waiting for
  // the next flush).
  std::size_t unpacked() const;
  // Adds the row ids of the pieces this builder owns (of its open chunk and
  // of the closed chunks it has not packed yet).
  void add_piece_ids(std::vector<int64_t>& ids) const;

  // Writes the samples added since the last flush (pieces), packs closed
  // chunks (whole, replacing their pieces; at most *pack_budget of them,
  // which is decreased; nullptr: every one), and writes the rollups of the
  // samples added since, on `db` (inside the caller's transaction).
  Status flush(sqlite3* db, const std::string& path, std::size_t* pack_budget = nullptr);

  uint64_t chunks_written() const { return chunks_written_; }
  const std::vector<ChannelInfo>& channels() const { return channels_; }

 private:
  struct OpenChannel {
    std::vector<int64_t> pieces;  // row ids of the pieces written so far
    std::vector<double> raw;
    EncodingNeed need;
    int64_t v_n = 0;
    double v_sum = 0, v_min = 0, v_max = 0;
    bool packed = false;        // closed chunks: written whole
    bool tail_written = false;  // closed chunks: its last samples written as a piece
  };
  void close_open();
  void roll_block();

  std::vector<ChannelInfo> channels_;
  double nominal_period_s_ = 0;
  uint32_t seq_modulo_ = 0;
  bool write_pieces_ = true;
  std::optional<double> last_t_s_;
  ChunkClock clock_;        // the open chunk
  ChunkClock piece_clock_;  // its samples since the last flush (dirty_)
  int64_t piece_from_ = 0;  // index of the first of them in raw
  bool dirty_ = false;
  std::vector<OpenChannel> open_;
  // Chunks closed and not packed yet, oldest first; the samples each got
  // after the last flush before it closed (its tail, not written yet).
  struct Closed {
    ChunkClock clock;
    std::vector<OpenChannel> channels;
    ChunkClock tail_clock;
    int64_t tail_from = 0;
    bool tail = false;
  };
  std::vector<Closed> closed_;
  // Rollups: the current 1-s block per channel, and finished blocks of
  // every level waiting for flush().
  int64_t block_ = 0;
  bool in_block_ = false;
  std::vector<RollupAcc> block_acc_;
  struct Pending {
    int64_t channel_id;
    int level;
    int64_t block;
    RollupAcc acc;
  };
  std::vector<Pending> rollups_;
  uint64_t chunks_written_ = 0;
  std::string blob_;
};

// Packs pieces no builder owns (a chunk whose writer was killed, or whose
// builder a failed commit dropped: it will not grow any more): each run of
// pieces of one chunk (piece 1, 2, ... of a channel, at most kChunkCapacity
// samples) becomes one chunk in its smallest encoding, in the caller's
// transaction; pieces whose row id is in `owned` (sorted) are left alone.
// At most `max_chunks` chunks (0: every one). Returns how many were packed
// and sets *more when pieces to pack remain.
Result<std::size_t> pack_left_pieces(sqlite3* db, const std::string& path,
                                     const std::vector<int64_t>& owned, std::size_t max_chunks,
                                     bool* more);

// One stored chunk as read (the BLOB is valid during the callback only).
struct ChunkView {
  ChunkClock clock;
  ChunkEncoding encoding;
  const void* data = nullptr;
  std::size_t bytes = 0;
};
// Reads every chunk of one channel that may hold samples in [t_from_s,
// t_to_s), in time order. Returning false from `chunk` stops.
Status for_each_chunk(sqlite3* db, const std::string& path, int64_t channel_id, double t_from_s,
                      double t_to_s, const std::function<bool(const ChunkView&)>& chunk);

// A run's DUT and rate axis resolved to its channels (readers).
struct StreamChannels {
  int64_t dut_id = 0;
  std::string serial;
  std::string axis;  // the rate axis asked for ("" -> the DUT's primary axis)
  uint32_t seq_modulo = 0;
  std::vector<ChannelInfo> channels;
  int rate = -1, status = -1, temperature = -1;  // positions in channels; -1: none
};
// serial "" = the run's first DUT. nullopt: the run has no DUT at all (and
// so no samples). Errors name the run, serial or axis that is unknown.
Result<std::optional<StreamChannels>> resolve_channels(sqlite3* db, const std::string& path,
                                                       int64_t run_id, const std::string& serial,
                                                       const std::string& axis);

// The channels of a run's DUT, by index.
Result<std::vector<ChannelInfo>> read_channels(sqlite3* db, const std::string& path, int64_t run_id,
                                               int64_t dut_id);

// Registers the unnamed gyro (serial "") in a run, as the v9 migration and
// push_gyro on a run without DUT do: channels rate (deg/h, axis `axis`),
// status, temp_c, seq_modulo 128 (the KVH 1750's counter). Returns its
// dut id. Idempotent.
Result<int64_t> register_unnamed_gyro(sqlite3* db, const std::string& path, int64_t run_id,
                                      const std::string& axis, const std::string& now_utc);

// The v9 data step: every run's gyro_samples into chunks of the unnamed
// gyro, then gyro_samples and gyro_rollup dropped.
Status migrate_gyro_samples_to_chunks(sqlite3* db, const std::string& path,
                                      const std::string& now_utc);

}  // namespace gyrotherm::storage::internal
