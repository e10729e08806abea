#include "chunks.h"

#include <fmt/format.h>
#include <zstd.h>

#include <bit>
#include <cstring>
#include <map>
#include <memory>
#include <tuple>

#include "sqlite_util.h"

namespace gyrotherm::storage::internal {

static_assert(std::endian::native == std::endian::little,
              "sample_chunks BLOBs are little-endian; this build copies them as they are");

namespace {

constexpr struct {
  Encoding e;
  const char* name;
  std::size_t size;
} kEncodings[] = {
    {Encoding::kU8, "u8", 1},   {Encoding::kI8, "i8", 1},   {Encoding::kU16, "u16", 2},
    {Encoding::kI16, "i16", 2}, {Encoding::kU32, "u32", 4}, {Encoding::kI32, "i32", 4},
    {Encoding::kF32, "f32", 4}, {Encoding::kF64, "f64", 8}, {Encoding::kI64, "i64", 8}};

constexpr std::string_view kPackedSuffix = "+shuffle+zstd";

// 10^k, exact in double for k <= 22.
constexpr double kPow10[] = {1e0, 1e1, 1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                             1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15};
static_assert(sizeof(kPow10) / sizeof(kPow10[0]) == kMaxDecimals + 1);
constexpr double kTwo53 = 9007199254740992.0;

bool same_bits(double a, double b) {
  return std::bit_cast<uint64_t>(a) == std::bit_cast<uint64_t>(b);
}
bool is_the_nan(double v) { return same_bits(v, std::numeric_limits<double>::quiet_NaN()); }

template <class T>
void put_all(std::span<const double> raw, std::string& out) {
  const std::size_t at = out.size();
  out.resize(at + raw.size() * sizeof(T));
  char* p = out.data() + at;
  for (double v : raw) {
    const T x = static_cast<T>(v);
    std::memcpy(p, &x, sizeof(T));
    p += sizeof(T);
  }
}

template <class T>
void get_all(const void* data, std::size_t n, double* out) {
  const char* p = static_cast<const char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    T x;
    std::memcpy(&x, p + i * sizeof(T), sizeof(T));
    out[i] = static_cast<double>(x);
  }
}

// Smallest distance to the next double at |x|: what rounding of a time
// stamp near x can amount to.
double ulp(double x) {
  const double a = std::abs(x);
  return std::nextafter(a, std::numeric_limits<double>::infinity()) - a;
}

// floor(a / b) for integers, b > 0.
int64_t floor_div(int64_t a, int64_t b) { return a / b - ((a % b != 0) && (a < 0)); }

// The statistics of a chunk's finite physical values (raw × scale), summed
// in sample order (as ChunkBuilder::add does).
struct ChunkStats {
  int64_t v_n = 0;
  double v_sum = 0, v_min = 0, v_max = 0;
  static ChunkStats of(std::span<const double> raw, double scale) {
    ChunkStats s;
    for (double v : raw) {
      const double physical = v * scale;
      if (!std::isfinite(physical)) continue;
      if (s.v_n == 0) {
        s.v_min = s.v_max = physical;
      } else {
        s.v_min = std::min(s.v_min, physical);
        s.v_max = std::max(s.v_max, physical);
      }
      ++s.v_n;
      s.v_sum += physical;
    }
    return s;
  }
};

// Inserts and deletes sample_chunks rows. Without pieces the statements do
// not name the `piece` column (the v9 migration's table has none yet).
class ChunkRows {
 public:
  static Result<ChunkRows> prepare(sqlite3* db, const std::string& path, bool pieces) {
    ChunkRows r(db, path);
    auto insert = Stmt::prepare(
        db, path,
        pieces ? "INSERT INTO sample_chunks(channel_id, t0_s, period_s, n, seq0, encoding, vn, "
                 "vmin, vmax, vsum, data, piece) "
                 "VALUES(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12)"
               : "INSERT INTO sample_chunks(channel_id, t0_s, period_s, n, seq0, encoding, vn, "
                 "vmin, vmax, vsum, data) VALUES(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)");
    if (!insert) return insert.error();
    r.insert_ = std::move(*insert);
    r.pieces_ = pieces;
    auto remove = Stmt::prepare(db, path, "DELETE FROM sample_chunks WHERE id = ?1");
    if (!remove) return remove.error();
    r.remove_ = std::move(*remove);
    return r;
  }

  // piece: 0 for a whole chunk, else its number within its chunk.
  Result<int64_t> insert(int64_t channel_id, const ChunkClock& clock, std::string_view encoding,
                         const ChunkStats& s, const std::string& blob, int64_t piece) {
    Stmt& st = insert_;
    st.bind(1, channel_id);
    st.bind(2, clock.t0_s);
    st.bind(3, clock.period_s);
    st.bind(4, clock.n);
    st.bind(5, static_cast<int64_t>(clock.seq0));
    st.bind(6, encoding);
    st.bind(7, s.v_n);
    if (s.v_n > 0) {
      st.bind(8, s.v_min);
      st.bind(9, s.v_max);
      st.bind(10, s.v_sum);
    } else {
      for (int i : {8, 9, 10}) st.bind_null(i);
    }
    sqlite3_bind_blob(st.get(), 11, blob.data(), static_cast<int>(blob.size()), SQLITE_STATIC);
    if (pieces_) st.bind(12, piece);
    const int rc = st.step();
    st.reset();
    if (rc != SQLITE_DONE) return sqlite_error(db_, path_, "writing sample chunks");
    return sqlite3_last_insert_rowid(db_);
  }

  Status remove(int64_t id) {
    remove_.bind(1, id);
    const int rc = remove_.step();
    remove_.reset();
    if (rc != SQLITE_DONE) return sqlite_error(db_, path_, "writing sample chunks");
    return Status::Ok();
  }

 private:
  ChunkRows(sqlite3* db, const std::string& path) : db_(db), path_(path) {}
  sqlite3* db_;
  std::string path_;
  Stmt insert_, remove_;
  bool pieces_ = true;
};

}  // namespace

std::string_view to_string(Encoding e) {
  for (const auto& k : kEncodings) {
    if (k.e == e) return k.name;
  }
  return "f64";
}

std::optional<Encoding> encoding_from_string(std::string_view s) {
  for (const auto& k : kEncodings) {
    if (s == k.name) return k.e;
  }
  return std::nullopt;
}

std::size_t encoded_size(Encoding e) {
  for (const auto& k : kEncodings) {
    if (k.e == e) return k.size;
  }
  return 8;
}

Encoding EncodingNeed::encoding() const {
  if (integral_) {
    if (min_ >= 0) {
      if (max_ <= 255) return Encoding::kU8;
      if (max_ <= 65535) return Encoding::kU16;
      return Encoding::kU32;
    }
    if (min_ >= -128 && max_ <= 127) return Encoding::kI8;
    if (min_ >= -32768 && max_ <= 32767) return Encoding::kI16;
    if (max_ <= 2147483647.0) return Encoding::kI32;
  }
  return f32_ ? Encoding::kF32 : Encoding::kF64;
}

void encode(Encoding e, std::span<const double> raw, std::string& out) {
  switch (e) {
    case Encoding::kU8:
      return put_all<uint8_t>(raw, out);
    case Encoding::kI8:
      return put_all<int8_t>(raw, out);
    case Encoding::kU16:
      return put_all<uint16_t>(raw, out);
    case Encoding::kI16:
      return put_all<int16_t>(raw, out);
    case Encoding::kU32:
      return put_all<uint32_t>(raw, out);
    case Encoding::kI32:
      return put_all<int32_t>(raw, out);
    case Encoding::kF32:
      return put_all<float>(raw, out);
    case Encoding::kF64:
      return put_all<double>(raw, out);
    case Encoding::kI64:
      return put_all<int64_t>(raw, out);
  }
}

bool decode(Encoding e, const void* data, std::size_t bytes, std::size_t n, double* out) {
  if (bytes != n * encoded_size(e)) return false;
  switch (e) {
    case Encoding::kU8:
      get_all<uint8_t>(data, n, out);
      break;
    case Encoding::kI8:
      get_all<int8_t>(data, n, out);
      break;
    case Encoding::kU16:
      get_all<uint16_t>(data, n, out);
      break;
    case Encoding::kI16:
      get_all<int16_t>(data, n, out);
      break;
    case Encoding::kU32:
      get_all<uint32_t>(data, n, out);
      break;
    case Encoding::kI32:
      get_all<int32_t>(data, n, out);
      break;
    case Encoding::kF32:
      get_all<float>(data, n, out);
      break;
    case Encoding::kF64:
      get_all<double>(data, n, out);
      break;
    case Encoding::kI64:
      get_all<int64_t>(data, n, out);
      break;
  }
  return true;
}

// ---------------------------------------------------------------- chunk encodings

std::string to_string(const ChunkEncoding& e) {
  std::string s(to_string(e.base));
  if (e.decimals > 0) s += fmt::format("/1e{}", e.decimals);
  if (e.zstd) s += kPackedSuffix;
  return s;
}

std::optional<ChunkEncoding> chunk_encoding_from_string(std::string_view s) {
  ChunkEncoding e;
  if (s.size() > kPackedSuffix.size() && s.ends_with(kPackedSuffix)) {
    e.zstd = true;
    s.remove_suffix(kPackedSuffix.size());
  }
  if (const auto slash = s.find("/1e"); slash != std::string_view::npos) {
    const std::string_view k = s.substr(slash + 3);
    if (k.empty() || k.size() > 2 || (k.size() == 2 && k[0] == '0')) return std::nullopt;
    int d = 0;
    for (char c : k) {
      if (c < '0' || c > '9') return std::nullopt;
      d = d * 10 + (c - '0');
    }
    if (d < 1 || d > kMaxDecimals) return std::nullopt;
    e.decimals = d;
    s = s.substr(0, slash);
  }
  const auto base = encoding_from_string(s);
  if (!base) return std::nullopt;
  if (e.decimals > 0 ? (*base != Encoding::kI32 && *base != Encoding::kI64)
                     : *base == Encoding::kI64) {
    return std::nullopt;  // decimals need i32 or i64; i64 is only a decimal's
  }
  e.base = *base;
  return e;
}

std::optional<int> decimal_places(std::span<const double> raw) {
  int k = 0;
  for (double v : raw) {
    if (is_the_nan(v)) continue;
    if (!std::isfinite(v) || (v == 0 && std::signbit(v))) return std::nullopt;
    // A value that is m / 10^k is also 10m / 10^(k+1) (both are the
    // double nearest to the same number), so k only grows.
    for (;; ++k) {
      if (k > kMaxDecimals) return std::nullopt;
      const double m = std::nearbyint(v * kPow10[k]);
      if (std::abs(m) < kTwo53 && same_bits(m / kPow10[k], v)) break;
    }
  }
  if (k == 0) return std::nullopt;
  // Every value again at the final k (10m may pass 2^53).
  for (double v : raw) {
    if (is_the_nan(v)) continue;
    const double m = std::nearbyint(v * kPow10[k]);
    if (!(std::abs(m) < kTwo53) || !same_bits(m / kPow10[k], v)) return std::nullopt;
  }
  return k;
}

namespace {

// The decimal's integers (the type's smallest value for NaN).
template <class T>
void put_decimals(std::span<const double> raw, int k, std::string& out) {
  const std::size_t at = out.size();
  out.resize(at + raw.size() * sizeof(T));
  char* p = out.data() + at;
  for (double v : raw) {
    const T x = std::isnan(v) ? std::numeric_limits<T>::min()
                              : static_cast<T>(std::nearbyint(v * kPow10[k]));
    std::memcpy(p, &x, sizeof(T));
    p += sizeof(T);
  }
}

template <class T>
void get_decimals(const char* p, std::size_t n, int k, double* out) {
  for (std::size_t i = 0; i < n; ++i) {
    T x;
    std::memcpy(&x, p + i * sizeof(T), sizeof(T));
    out[i] = x == std::numeric_limits<T>::min() ? std::numeric_limits<double>::quiet_NaN()
                                                : static_cast<double>(x) / kPow10[k];
  }
}

// Byte b of value i goes to b * n + i.
void shuffle(const char* in, std::size_t n, std::size_t size, char* out) {
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t b = 0; b < size; ++b) out[b * n + i] = in[i * size + b];
  }
}
void unshuffle(const char* in, std::size_t n, std::size_t size, char* out) {
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t b = 0; b < size; ++b) out[i * size + b] = in[b * n + i];
  }
}

// The plain bytes of a chunk encoding (before packing).
void encode_plain(const ChunkEncoding& e, std::span<const double> raw, std::string& out) {
  if (e.decimals == 0) return encode(e.base, raw, out);
  if (e.base == Encoding::kI32) return put_decimals<int32_t>(raw, e.decimals, out);
  return put_decimals<int64_t>(raw, e.decimals, out);
}

bool decode_plain(const ChunkEncoding& e, const char* data, std::size_t bytes, std::size_t n,
                  double* out) {
  if (e.decimals == 0) return decode(e.base, data, bytes, n, out);
  if (bytes != n * encoded_size(e.base)) return false;
  if (e.base == Encoding::kI32) {
    get_decimals<int32_t>(data, n, e.decimals, out);
  } else {
    get_decimals<int64_t>(data, n, e.decimals, out);
  }
  return true;
}

// The same values: bit for bit, or both NaN.
bool same_values(std::span<const double> a, const std::vector<double>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (!same_bits(a[i], b[i]) && !(std::isnan(a[i]) && std::isnan(b[i]))) return false;
  }
  return true;
}

}  // namespace

ChunkEncoding encode_closed(Encoding plain, std::span<const double> raw, std::string& out) {
  out.clear();
  ChunkEncoding best{plain, 0, false};
  encode(plain, raw, out);
  // The candidates' plain forms: the narrowest plain encoding, and a
  // decimal when the values are decimals with few enough digits to be
  // narrower than f64 or to pack better.
  std::vector<ChunkEncoding> candidates{best};
  if (plain == Encoding::kF64) {
    if (const auto k = decimal_places(raw)) {
      double most = 0;
      for (double v : raw) {
        if (!std::isnan(v)) most = std::max(most, std::abs(std::nearbyint(v * kPow10[*k])));
      }
      const bool fits32 = most <= 2147483647.0;
      candidates.push_back({fits32 ? Encoding::kI32 : Encoding::kI64, *k, false});
    }
  }
  std::string plain_bytes, packed, shuffled;
  std::vector<double> back(raw.size());
  auto try_take = [&](const ChunkEncoding& e, const std::string& bytes) {
    if (bytes.size() >= out.size()) return;
    if (!decode(e, bytes.data(), bytes.size(), raw.size(), back.data()) ||
        !same_values(raw, back)) {
      return;  // never taken unless it reads back as it was given
    }
    best = e;
    out = bytes;
  };
  for (const ChunkEncoding& c : candidates) {
    plain_bytes.clear();
    encode_plain(c, raw, plain_bytes);
    if (c.decimals > 0) try_take(c, plain_bytes);
    const std::size_t size = encoded_size(c.base);
    shuffled.resize(plain_bytes.size());
    shuffle(plain_bytes.data(), raw.size(), size, shuffled.data());
    // With the frame's content size and checksum: a damaged BLOB is an
    // error when read, not other numbers.
    thread_local const std::unique_ptr<ZSTD_CCtx, size_t (*)(ZSTD_CCtx*)> cctx(ZSTD_createCCtx(),
                                                                               ZSTD_freeCCtx);
    if (!cctx) continue;
    ZSTD_CCtx_reset(cctx.get(), ZSTD_reset_session_and_parameters);
    ZSTD_CCtx_setParameter(cctx.get(), ZSTD_c_compressionLevel, kZstdLevel);
    ZSTD_CCtx_setParameter(cctx.get(), ZSTD_c_checksumFlag, 1);
    ZSTD_CCtx_setParameter(cctx.get(), ZSTD_c_contentSizeFlag, 1);
    packed.resize(ZSTD_compressBound(shuffled.size()));
    const std::size_t z =
        ZSTD_compress2(cctx.get(), packed.data(), packed.size(), shuffled.data(), shuffled.size());
    if (ZSTD_isError(z)) continue;
    packed.resize(z);
    try_take({c.base, c.decimals, true}, packed);
  }
  return best;
}

bool decode(const ChunkEncoding& e, const void* data, std::size_t bytes, std::size_t n,
            double* out) {
  const auto* p = static_cast<const char*>(data);
  if (!e.zstd) return decode_plain(e, p, bytes, n, out);
  const std::size_t size = encoded_size(e.base);
  const unsigned long long content = ZSTD_getFrameContentSize(p, bytes);
  if (content != n * size) return false;  // also ZSTD_CONTENTSIZE_ERROR / _UNKNOWN
  thread_local std::string shuffled, plain;
  shuffled.resize(n * size);
  plain.resize(n * size);
  const std::size_t got = ZSTD_decompress(shuffled.data(), shuffled.size(), p, bytes);
  if (ZSTD_isError(got) || got != n * size) return false;
  unshuffle(shuffled.data(), n, size, plain.data());
  return decode_plain(e, plain.data(), plain.size(), n, out);
}

// ---------------------------------------------------------------- the clock

bool ChunkClock::continues(double t_s, uint32_t seq, double nominal_period_s,
                           uint32_t seq_modulo) const {
  if (n == 0) return true;
  if (seq_modulo > 0 &&
      seq != static_cast<uint32_t>((uint64_t{seq0} + static_cast<uint64_t>(n)) % seq_modulo)) {
    return false;  // a lost frame (or a counter that does not count)
  }
  const double step_s = t_s - t_last_s();
  if (n == 1) {
    // The second sample sets the period: it must be a step of the nominal
    // clock when there is one (not a gap after the first sample).
    if (!(step_s > 0)) return false;
    return nominal_period_s <= 0 || std::abs(step_s / nominal_period_s - 1) < 0.5;
  }
  // On the clock: within 1e-6 of a period of where the chunk's clock puts
  // sample n, or the rounding of the time stamps themselves.
  const double expected_s = t0_s + static_cast<double>(n) * period_s;
  const double tolerance_s = std::max(1e-6 * period_s, 8 * ulp(std::max(t_s, t0_s)));
  return std::abs(t_s - expected_s) <= tolerance_s;
}

void ChunkClock::add(double t_s, uint32_t seq) {
  if (n == 0) {
    t0_s = t_s;
    seq0 = seq;
    period_s = 0;
    n = 1;
    return;
  }
  ++n;
  // From the first and the last sample, so the rounding of one step is not
  // multiplied along the chunk.
  period_s = (t_s - t0_s) / static_cast<double>(n - 1);
}

// ---------------------------------------------------------------- the builder

ChunkBuilder::ChunkBuilder(std::vector<ChannelInfo> channels, double rate_hz, uint32_t seq_modulo,
                           bool write_pieces)
    : channels_(std::move(channels)),
      nominal_period_s_(rate_hz > 0 ? 1.0 / rate_hz : 0),
      seq_modulo_(seq_modulo),
      write_pieces_(write_pieces),
      open_(channels_.size()),
      block_acc_(channels_.size()) {
  for (OpenChannel& o : open_) o.raw.reserve(kChunkCapacity);
}

bool ChunkBuilder::add(double t_s, uint32_t seq, const double* raw) {
  if (last_t_s_) {
    // At or before the last stored sample (within the rounding of the
    // implicit time stamps): already stored.
    const double tolerance_s = std::max(1e-9, 8 * ulp(t_s));
    if (t_s <= *last_t_s_ + tolerance_s) return false;
  }
  if (clock_.n >= kChunkCapacity || !clock_.continues(t_s, seq, nominal_period_s_, seq_modulo_)) {
    close_open();
  }
  clock_.add(t_s, seq);
  piece_clock_.add(t_s, seq);
  const auto block = static_cast<int64_t>(std::floor(t_s));
  if (!in_block_ || block != block_) {
    roll_block();
    block_ = block;
    in_block_ = true;
  }
  for (std::size_t c = 0; c < channels_.size(); ++c) {
    const double v = raw[channels_[c].index];
    OpenChannel& o = open_[c];
    o.raw.push_back(v);
    o.need.add(v);
    const double physical = v * channels_[c].scale;
    if (std::isfinite(physical)) {
      if (o.v_n == 0) {
        o.v_min = o.v_max = physical;
      } else {
        o.v_min = std::min(o.v_min, physical);
        o.v_max = std::max(o.v_max, physical);
      }
      ++o.v_n;
      o.v_sum += physical;
    }
    block_acc_[c].add(t_s, physical);
  }
  last_t_s_ = t_s;
  dirty_ = true;
  return true;
}

void ChunkBuilder::close_open() {
  if (clock_.n == 0) return;
  // Packed by a later flush() (replacing the pieces written so far); its
  // samples since the last flush are its tail.
  Closed closed{clock_, std::vector<OpenChannel>(channels_.size()), piece_clock_, piece_from_,
                dirty_ && write_pieces_};
  std::swap(closed.channels, open_);
  closed_.push_back(std::move(closed));
  for (OpenChannel& o : open_) o.raw.reserve(kChunkCapacity);
  clock_ = ChunkClock{};
  piece_clock_ = ChunkClock{};
  piece_from_ = 0;
  dirty_ = false;
}

void ChunkBuilder::roll_block() {
  if (!in_block_) return;
  for (std::size_t c = 0; c < channels_.size(); ++c) {
    if (block_acc_[c].n == 0) continue;
    rollups_.push_back({channels_[c].id, kChannelRollupFirstLevel, block_, block_acc_[c]});
    block_acc_[c] = RollupAcc{};
  }
}

std::size_t ChunkBuilder::unpacked() const {
  std::size_t n = 0;
  for (const Closed& closed : closed_) {
    for (const OpenChannel& o : closed.channels) n += o.packed ? 0 : 1;
  }
  return n;
}

void ChunkBuilder::add_piece_ids(std::vector<int64_t>& ids) const {
  for (const OpenChannel& o : open_) ids.insert(ids.end(), o.pieces.begin(), o.pieces.end());
  for (const Closed& closed : closed_) {
    for (const OpenChannel& o : closed.channels) {
      if (!o.packed) ids.insert(ids.end(), o.pieces.begin(), o.pieces.end());
    }
  }
}

Status ChunkBuilder::flush(sqlite3* db, const std::string& path, std::size_t* pack_budget) {
  auto rows = ChunkRows::prepare(db, path, write_pieces_);
  if (!rows) return rows.error();
  // Writes raw[from...] of channel c as the next piece of `o`.
  auto write_piece = [&](std::size_t c, OpenChannel& o, int64_t from,
                         const ChunkClock& clock) -> Status {
    const auto piece = std::span<const double>(o.raw).subspan(static_cast<std::size_t>(from));
    EncodingNeed need;
    for (double v : piece) need.add(v);
    const Encoding e = need.encoding();
    blob_.clear();
    encode(e, piece, blob_);
    auto id = rows->insert(channels_[c].id, clock, to_string(e),
                           ChunkStats::of(piece, channels_[c].scale), blob_,
                           static_cast<int64_t>(o.pieces.size()) + 1);
    if (!id) return id.error();
    ++chunks_written_;
    o.pieces.push_back(*id);
    return Status::Ok();
  };

  // Closed chunks, oldest first: whole, in their smallest encoding, in
  // place of their pieces, as long as the budget lasts; the others get
  // their tail written as a piece, so that what this commit took is
  // stored.
  for (Closed& closed : closed_) {
    for (std::size_t c = 0; c < closed.channels.size(); ++c) {
      OpenChannel& o = closed.channels[c];
      if (o.packed) continue;
      if (!pack_budget || *pack_budget > 0) {
        for (int64_t id : o.pieces) {
          if (Status s = rows->remove(id); !s) return s;
        }
        const ChunkEncoding e = encode_closed(o.need.encoding(), o.raw, blob_);
        auto id = rows->insert(channels_[c].id, closed.clock, to_string(e),
                               {o.v_n, o.v_sum, o.v_min, o.v_max}, blob_, 0);
        if (!id) return id.error();
        ++chunks_written_;
        o.packed = true;
        o.pieces.clear();
        o.raw = {};
        if (pack_budget) --*pack_budget;
      } else if (closed.tail && !o.tail_written) {
        if (Status s = write_piece(c, o, closed.tail_from, closed.tail_clock); !s) return s;
        o.tail_written = true;
      }
    }
  }
  std::erase_if(closed_, [](const Closed& closed) {
    return std::all_of(closed.channels.begin(), closed.channels.end(),
                       [](const OpenChannel& o) { return o.packed; });
  });
  // The open chunk: the samples since the last flush, as a piece in the
  // narrowest plain encoding.
  if (dirty_ && write_pieces_) {
    for (std::size_t c = 0; c < open_.size(); ++c) {
      if (Status s = write_piece(c, open_[c], piece_from_, piece_clock_); !s) return s;
    }
    piece_from_ = clock_.n;
    piece_clock_ = ChunkClock{};
    dirty_ = false;
  }

  // Rollups: the 1-s blocks since the last flush (the current one so far;
  // the rest of it is added by the next flush), summed into the coarser
  // levels.
  roll_block();
  if (!rollups_.empty()) {
    std::map<std::tuple<int64_t, int, int64_t>, RollupAcc> blocks;
    for (const Pending& p : rollups_) {
      int64_t divisor = 1;
      for (int level = kChannelRollupFirstLevel; level <= kChannelRollupLastLevel; ++level) {
        blocks[{p.channel_id, level, floor_div(p.block, divisor)}].merge(p.acc);
        divisor *= 10;
      }
    }
    rollups_.clear();
    auto upsert = Stmt::prepare(
        db, path,
        "INSERT INTO channel_rollup(channel_id, level, block, n, t_sum_s, v_n, v_sum, v_min, "
        "v_max) VALUES(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9) "
        "ON CONFLICT(channel_id, level, block) DO UPDATE SET n = n + ?4, "
        "t_sum_s = t_sum_s + ?5, v_n = v_n + ?6, v_sum = coalesce(v_sum + ?7, v_sum, ?7), "
        "v_min = coalesce(min(v_min, ?8), v_min, ?8), v_max = coalesce(max(v_max, ?9), v_max, ?9)");
    if (!upsert) return upsert.error();
    for (const auto& [key, acc] : blocks) {
      upsert->bind(1, std::get<0>(key));
      upsert->bind(2, std::get<1>(key));
      upsert->bind(3, std::get<2>(key));
      upsert->bind(4, acc.n);
      upsert->bind(5, acc.t_sum_s);
      upsert->bind(6, acc.v_n);
      if (acc.v_n > 0) {
        upsert->bind(7, acc.v_sum);
        upsert->bind(8, acc.v_min);
        upsert->bind(9, acc.v_max);
      } else {
        for (int i : {7, 8, 9}) upsert->bind_null(i);
      }
      if (upsert->step() != SQLITE_DONE) {
        upsert->reset();
        return sqlite_error(db, path, "writing channel rollups");
      }
      upsert->reset();
    }
  }
  return Status::Ok();
}

Result<std::size_t> pack_left_pieces(sqlite3* db, const std::string& path,
                                     const std::vector<int64_t>& owned, std::size_t max_chunks,
                                     bool* more) {
  *more = false;
  auto st = Stmt::prepare(db, path,
                          "SELECT k.id, k.channel_id, k.t0_s, k.period_s, k.n, k.seq0, k.encoding, "
                          "k.piece, k.data, coalesce(c.scale, 1) FROM sample_chunks k LEFT JOIN "
                          "channels c ON c.id = k.channel_id WHERE k.piece > 0 "
                          "ORDER BY k.channel_id, k.t0_s");
  if (!st) return st.error();
  auto rows = ChunkRows::prepare(db, path, true);
  if (!rows) return rows.error();
  // The run of pieces being gathered: one chunk's, in order.
  struct Group {
    int64_t channel_id = 0;
    int64_t last_piece = 0;
    double scale = 1;
    ChunkClock clock;
    double t_last_s = 0;
    std::vector<int64_t> ids;
    std::vector<double> raw;
  } g;
  std::size_t packed = 0;
  std::string blob;
  auto pack = [&]() -> Status {
    if (g.ids.empty()) return Status::Ok();
    g.clock.n = static_cast<int64_t>(g.raw.size());
    g.clock.period_s =
        g.clock.n > 1 ? (g.t_last_s - g.clock.t0_s) / static_cast<double>(g.clock.n - 1) : 0;
    EncodingNeed need;
    for (double v : g.raw) need.add(v);
    const ChunkEncoding e = encode_closed(need.encoding(), g.raw, blob);
    for (int64_t id : g.ids) {
      if (Status s = rows->remove(id); !s) return s;
    }
    auto id =
        rows->insert(g.channel_id, g.clock, to_string(e), ChunkStats::of(g.raw, g.scale), blob, 0);
    if (!id) return id.error();
    ++packed;
    g.ids.clear();
    g.raw.clear();
    return Status::Ok();
  };
  // Read first, written after: the statement's rows are not changed under it.
  struct Piece {
    int64_t id, channel_id, piece;
    ChunkClock clock;
    double scale;
    std::vector<double> raw;
  };
  std::vector<Piece> pieces;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    const int64_t id = st->column_int64(0);
    if (std::binary_search(owned.begin(), owned.end(), id)) continue;
    Piece p;
    p.id = id;
    p.channel_id = st->column_int64(1);
    p.clock.t0_s = st->column_double(2);
    p.clock.period_s = st->column_double(3);
    p.clock.n = st->column_int64(4);
    p.clock.seq0 = static_cast<uint32_t>(st->column_int64(5));
    p.piece = st->column_int64(7);
    p.scale = st->column_double(9);
    const std::string enc = st->column_text(6);
    const auto e = chunk_encoding_from_string(enc);
    p.raw.resize(static_cast<std::size_t>(std::max<int64_t>(p.clock.n, 0)));
    if (!e || p.clock.n <= 0 ||
        !decode(*e, sqlite3_column_blob(st->get(), 8),
                static_cast<std::size_t>(sqlite3_column_bytes(st->get(), 8)), p.raw.size(),
                p.raw.data())) {
      return Error::Permanent(fmt::format(
          "storage: {}: sample_chunks piece {} of channel {} at t0_s {}: '{}' data that does not "
          "decode",
          path, id, p.channel_id, p.clock.t0_s, enc));
    }
    pieces.push_back(std::move(p));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db, path, "reading the pieces of sample chunks");
  st->reset();
  for (Piece& p : pieces) {
    const bool continues = !g.ids.empty() && p.channel_id == g.channel_id &&
                           p.piece == g.last_piece + 1 &&
                           static_cast<int64_t>(g.raw.size()) + p.clock.n <= kChunkCapacity;
    if (!continues) {
      if (Status s = pack(); !s) return s.error();
      if (max_chunks > 0 && packed >= max_chunks) {
        *more = true;
        return packed;
      }
      g.channel_id = p.channel_id;
      g.scale = p.scale;
      g.clock = p.clock;
    }
    g.last_piece = p.piece;
    g.t_last_s = p.clock.t_last_s();
    g.ids.push_back(p.id);
    g.raw.insert(g.raw.end(), p.raw.begin(), p.raw.end());
  }
  if (Status s = pack(); !s) return s.error();
  return packed;
}

// ---------------------------------------------------------------- reading

Status for_each_chunk(sqlite3* db, const std::string& path, int64_t channel_id, double t_from_s,
                      double t_to_s, const std::function<bool(const ChunkView&)>& chunk) {
  // Chunks of a channel do not overlap: the first one that can hold
  // t_from_s is the last one starting at or before it.
  auto st = Stmt::prepare(
      db, path,
      "SELECT t0_s, period_s, n, seq0, encoding, data FROM sample_chunks WHERE channel_id = ?1 "
      "AND t0_s < ?3 AND t0_s >= coalesce((SELECT max(t0_s) FROM sample_chunks WHERE "
      "channel_id = ?1 AND t0_s <= ?2), -1e308) ORDER BY t0_s");
  if (!st) return st.error();
  st->bind(1, channel_id);
  st->bind(2, t_from_s);
  st->bind(3, t_to_s);
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    ChunkView v;
    v.clock.t0_s = st->column_double(0);
    v.clock.period_s = st->column_double(1);
    v.clock.n = st->column_int64(2);
    v.clock.seq0 = static_cast<uint32_t>(st->column_int64(3));
    const std::string enc = st->column_text(4);
    const auto e = chunk_encoding_from_string(enc);
    if (!e) {
      return Error::Permanent(
          fmt::format("storage: {}: sample_chunks of channel {}: unknown encoding '{}'", path,
                      channel_id, enc));
    }
    v.encoding = *e;
    v.data = sqlite3_column_blob(st->get(), 5);
    v.bytes = static_cast<std::size_t>(sqlite3_column_bytes(st->get(), 5));
    if (!e->zstd && v.bytes != static_cast<std::size_t>(v.clock.n) * encoded_size(e->base)) {
      return Error::Permanent(fmt::format(
          "storage: {}: sample_chunks of channel {} at t0_s {}: {} bytes of data for n {} '{}' "
          "values",
          path, channel_id, v.clock.t0_s, v.bytes, v.clock.n, enc));
    }
    if (!chunk(v)) return Status::Ok();
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db, path, fmt::format("reading the chunks of channel {}", channel_id));
  }
  return Status::Ok();
}

Result<std::vector<ChannelInfo>> read_channels(sqlite3* db, const std::string& path, int64_t run_id,
                                               int64_t dut_id) {
  auto st = Stmt::prepare(db, path,
                          "SELECT id, idx, name, unit, kind, axis, scale FROM channels "
                          "WHERE run_id = ? AND dut_id = ? ORDER BY idx");
  if (!st) return st.error();
  st->bind(1, run_id);
  st->bind(2, dut_id);
  std::vector<ChannelInfo> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    ChannelInfo c;
    c.id = st->column_int64(0);
    c.index = static_cast<int>(st->column_int64(1));
    c.name = st->column_text(2);
    c.unit = st->column_text(3);
    c.kind = channel_kind_from_string(st->column_text(4)).value_or(ChannelKind::kOther);
    c.axis = st->column_text(5);
    c.scale = st->column_double(6);
    if (c.index < 0 || c.index >= static_cast<int>(kMaxChannels)) {
      return Error::Permanent(
          fmt::format("storage: {}: channels row {} ('{}'): idx {} outside 0..{}", path, c.id,
                      c.name, c.index, kMaxChannels - 1));
    }
    out.push_back(std::move(c));
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db, path, fmt::format("reading the channels of run {}", run_id));
  }
  return out;
}

Result<int64_t> register_unnamed_gyro(sqlite3* db, const std::string& path, int64_t run_id,
                                      const std::string& axis, const std::string& now_utc) {
  const std::string what = fmt::format("registering the unnamed gyro in run {}", run_id);
  auto dut = Stmt::prepare(db, path,
                           "INSERT INTO duts(serial, model, first_seen_utc) VALUES('', '', ?) "
                           "ON CONFLICT(serial) DO NOTHING");
  if (!dut) return dut.error();
  dut->bind(1, std::string_view(now_utc));
  if (dut->step() != SQLITE_DONE) return sqlite_error(db, path, what);
  auto id = Stmt::prepare(db, path, "SELECT id FROM duts WHERE serial = ''");
  if (!id) return id.error();
  if (id->step() != SQLITE_ROW) return sqlite_error(db, path, what);
  const int64_t dut_id = id->column_int64(0);
  auto in_run = Stmt::prepare(
      db, path,
      "INSERT OR IGNORE INTO run_duts(run_id, dut_id, position, primary_axis, axes_json, "
      "rate_hz, seq_modulo, config_json) VALUES(?1, ?2, (SELECT count(*) FROM run_duts WHERE "
      "run_id = ?1), ?3, json_array(?3), NULL, 128, '{}')");
  if (!in_run) return in_run.error();
  in_run->bind(1, run_id);
  in_run->bind(2, dut_id);
  in_run->bind(3, std::string_view(axis));
  if (in_run->step() != SQLITE_DONE) return sqlite_error(db, path, what);
  auto chans = Stmt::prepare(
      db, path,
      "INSERT OR IGNORE INTO channels(run_id, dut_id, idx, name, unit, kind, axis, scale) "
      "VALUES(?1, ?2, 0, 'rate', 'deg/h', 'rate', ?3, 1), (?1, ?2, 1, 'status', '', 'status', "
      "'', 1), (?1, ?2, 2, 'temp_c', 'degC', 'temperature', '', 1)");
  if (!chans) return chans.error();
  chans->bind(1, run_id);
  chans->bind(2, dut_id);
  chans->bind(3, std::string_view(axis));
  if (chans->step() != SQLITE_DONE) return sqlite_error(db, path, what);
  return dut_id;
}

Status migrate_gyro_samples_to_chunks(sqlite3* db, const std::string& path,
                                      const std::string& now_utc) {
  // Runs with samples, and the axis their [gyro] was configured with (runs
  // of an unknown run id cannot be registered: their samples are dropped,
  // as docs/storage.md says).
  auto runs = Stmt::prepare(
      db, path,
      "SELECT r.id, CASE WHEN json_valid(r.config_json) AND json_extract(r.config_json, "
      "'$.gyro.axis') IN ('x', 'y', 'z') THEN json_extract(r.config_json, '$.gyro.axis') "
      "ELSE 'z' END FROM runs r WHERE EXISTS (SELECT 1 FROM gyro_samples g WHERE g.run_id = r.id) "
      "ORDER BY r.id");
  if (!runs) return runs.error();
  std::vector<std::pair<int64_t, std::string>> todo;
  int rc;
  while ((rc = runs->step()) == SQLITE_ROW)
    todo.emplace_back(runs->column_int64(0), runs->column_text(1));
  if (rc != SQLITE_DONE) return sqlite_error(db, path, "listing the runs with gyro samples");

  auto rows = Stmt::prepare(db, path,
                            "SELECT t_s, seq, rate_dph, status, temp_c FROM gyro_samples "
                            "WHERE run_id = ? ORDER BY t_s");
  if (!rows) return rows.error();
  for (const auto& [run_id, axis] : todo) {
    auto dut_id = register_unnamed_gyro(db, path, run_id, axis, now_utc);
    if (!dut_id) return dut_id.error();
    auto channels = read_channels(db, path, run_id, *dut_id);
    if (!channels) return channels.error();
    ChunkBuilder builder(std::move(*channels), 0, 128, /*write_pieces=*/false);
    rows->bind(1, run_id);
    std::array<double, kMaxChannels> raw{};
    int64_t since_flush = 0;
    while ((rc = rows->step()) == SQLITE_ROW) {
      raw[0] = rows->column_double(2);
      raw[1] = rows->column_double(3);
      raw[2] = rows->column_double(4);
      builder.add(rows->column_double(0), static_cast<uint32_t>(rows->column_int64(1)), raw.data());
      if (++since_flush == 100'000) {  // bounded memory whatever the run's length
        if (Status s = builder.flush(db, path); !s) return s;
        since_flush = 0;
      }
    }
    if (rc != SQLITE_DONE) {
      return sqlite_error(db, path, fmt::format("reading the gyro samples of run {}", run_id));
    }
    rows->reset();
    // The run's last chunk is closed too: packed like the others.
    builder.finish();
    if (Status s = builder.flush(db, path); !s) return s;
  }
  return exec(db, path, "DROP TABLE gyro_samples; DROP TABLE gyro_rollup;");
}

}  // namespace gyrotherm::storage::internal
