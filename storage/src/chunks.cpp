#include "chunks.h"

#include <fmt/format.h>

#include <bit>
#include <cstring>
#include <map>
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
} kEncodings[] = {{Encoding::kU8, "u8", 1},   {Encoding::kI8, "i8", 1},
                  {Encoding::kU16, "u16", 2}, {Encoding::kI16, "i16", 2},
                  {Encoding::kU32, "u32", 4}, {Encoding::kI32, "i32", 4},
                  {Encoding::kF32, "f32", 4}, {Encoding::kF64, "f64", 8}};

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
  }
  return true;
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

ChunkBuilder::ChunkBuilder(std::vector<ChannelInfo> channels, double rate_hz, uint32_t seq_modulo)
    : channels_(std::move(channels)),
      nominal_period_s_(rate_hz > 0 ? 1.0 / rate_hz : 0),
      seq_modulo_(seq_modulo),
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
  if (dirty_) {
    Closed closed{clock_, std::vector<OpenChannel>(channels_.size())};
    std::swap(closed.channels, open_);
    closed_.push_back(std::move(closed));
    for (OpenChannel& o : open_) o.raw.reserve(kChunkCapacity);
  } else {
    open_.assign(channels_.size(), OpenChannel{});
  }
  clock_ = ChunkClock{};
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

Status ChunkBuilder::flush(sqlite3* db, const std::string& path) {
  const std::string what = "writing sample chunks";
  auto insert = Stmt::prepare(db, path,
                              "INSERT INTO sample_chunks(channel_id, t0_s, period_s, n, seq0, "
                              "encoding, vn, vmin, vmax, vsum, data) "
                              "VALUES(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)");
  if (!insert) return insert.error();
  auto update = Stmt::prepare(db, path,
                              "UPDATE sample_chunks SET period_s = ?3, n = ?4, encoding = ?6, "
                              "vn = ?7, vmin = ?8, vmax = ?9, vsum = ?10, data = ?11 "
                              "WHERE id = ?12");
  if (!update) return update.error();

  auto write = [&](const ChunkClock& clock, std::vector<OpenChannel>& chans) -> Status {
    for (std::size_t c = 0; c < chans.size(); ++c) {
      OpenChannel& o = chans[c];
      Stmt& st = o.row_id == 0 ? *insert : *update;
      const Encoding e = o.need.encoding();
      blob_.clear();
      encode(e, o.raw, blob_);
      st.bind(1, channels_[c].id);
      st.bind(2, clock.t0_s);
      st.bind(3, clock.period_s);
      st.bind(4, clock.n);
      st.bind(5, static_cast<int64_t>(clock.seq0));
      st.bind(6, to_string(e));
      st.bind(7, o.v_n);
      if (o.v_n > 0) {
        st.bind(8, o.v_min);
        st.bind(9, o.v_max);
        st.bind(10, o.v_sum);
      } else {
        for (int i : {8, 9, 10}) st.bind_null(i);
      }
      sqlite3_bind_blob(st.get(), 11, blob_.data(), static_cast<int>(blob_.size()), SQLITE_STATIC);
      if (o.row_id != 0) st.bind(12, o.row_id);
      if (st.step() != SQLITE_DONE) {
        st.reset();
        return sqlite_error(db, path, what);
      }
      st.reset();
      if (o.row_id == 0) o.row_id = sqlite3_last_insert_rowid(db);
      ++chunks_written_;
    }
    return Status::Ok();
  };
  for (Closed& closed : closed_) {
    if (Status s = write(closed.clock, closed.channels); !s) return s;
  }
  closed_.clear();
  if (dirty_) {
    if (Status s = write(clock_, open_); !s) return s;
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
    const auto e = encoding_from_string(enc);
    if (!e) {
      return Error::Permanent(
          fmt::format("storage: {}: sample_chunks of channel {}: unknown encoding '{}'", path,
                      channel_id, enc));
    }
    v.encoding = *e;
    v.data = sqlite3_column_blob(st->get(), 5);
    v.bytes = static_cast<std::size_t>(sqlite3_column_bytes(st->get(), 5));
    if (v.bytes != static_cast<std::size_t>(v.clock.n) * encoded_size(*e)) {
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
    ChunkBuilder builder(std::move(*channels), 0, 128);
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
    if (Status s = builder.flush(db, path); !s) return s;
  }
  return exec(db, path, "DROP TABLE gyro_samples; DROP TABLE gyro_rollup;");
}

}  // namespace gyrotherm::storage::internal
