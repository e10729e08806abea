// SampleStore (samples.h): the readers of a run's samples. The chunked samples
// (schema v9): gyro_samples, for_each_channel_block, the counts and the last
// sample times; the temperatures and the rate table's samples (reads, window
// means); decimated reads for plots.
#include "gyrotherm/storage/samples.h"

#include <fmt/format.h>
#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "chunks.h"
#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::sqlite_error;
using internal::Stmt;

namespace internal {

Result<std::optional<StreamChannels>> resolve_channels(sqlite3* db, const std::string& path,
                                                       int64_t run_id, const std::string& serial,
                                                       const std::string& axis) {
  auto st = Stmt::prepare(db, path,
                          "SELECT rd.dut_id, d.serial, rd.primary_axis, rd.seq_modulo "
                          "FROM run_duts rd JOIN duts d ON d.id = rd.dut_id "
                          "WHERE rd.run_id = ? ORDER BY rd.position");
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<std::string> serials;
  std::optional<StreamChannels> found;
  std::string primary_axis;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    std::string s = st->column_text(1);
    if (!found && (serial.empty() || s == serial)) {
      found.emplace();
      found->dut_id = st->column_int64(0);
      found->serial = s;
      primary_axis = st->column_text(2);
      found->seq_modulo = static_cast<uint32_t>(st->column_int64(3));
    }
    serials.push_back(fmt::format("'{}'", s));
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db, path, fmt::format("reading the DUTs of run {}", run_id));
  }
  if (!found) {
    if (serials.empty() && serial.empty()) return std::optional<StreamChannels>();
    return Error::Permanent(
        fmt::format("run {} has no DUT with serial '{}' (its DUTs: {})", run_id, serial,
                    serials.empty() ? "none" : fmt::format("{}", fmt::join(serials, ", "))));
  }
  auto channels = read_channels(db, path, run_id, found->dut_id);
  if (!channels) return channels.error();
  found->channels = std::move(*channels);
  found->axis = axis.empty() ? primary_axis : axis;
  std::vector<std::string> axes;
  for (std::size_t i = 0; i < found->channels.size(); ++i) {
    const ChannelInfo& c = found->channels[i];
    if (c.kind == ChannelKind::kRate) {
      axes.push_back(c.axis);
      if (found->rate < 0 && c.axis == found->axis) found->rate = static_cast<int>(i);
    }
    if (c.kind == ChannelKind::kStatus && found->status < 0) found->status = static_cast<int>(i);
    if (c.kind == ChannelKind::kTemperature && found->temperature < 0) {
      found->temperature = static_cast<int>(i);
    }
  }
  if (found->rate < 0) {
    return Error::Permanent(
        fmt::format("DUT '{}' of run {} has no rate channel for axis '{}' "
                    "(its rate axes: {})",
                    found->serial, run_id, found->axis,
                    axes.empty() ? "none" : fmt::format("{}", fmt::join(axes, ", "))));
  }
  return found;
}

}  // namespace internal
Database& SampleStore::self() { return static_cast<Database&>(*this); }
sqlite3* SampleStore::db() { return self().db_; }
const std::string& SampleStore::path() { return self().path_; }

Status SampleStore::for_each_channel_block(
    int64_t channel_id, double t_from_s, double t_to_s,
    const std::function<bool(std::span<const double> t_s, std::span<const double> value,
                             std::span<const uint32_t> seq)>& block) {
  auto meta =
      Stmt::prepare(db(), path(),
                    "SELECT c.scale, coalesce(rd.seq_modulo, 0) FROM channels c "
                    "LEFT JOIN run_duts rd ON rd.run_id = c.run_id AND rd.dut_id = c.dut_id "
                    "WHERE c.id = ?");
  if (!meta) return meta.error();
  meta->bind(1, channel_id);
  const int rc = meta->step();
  if (rc == SQLITE_DONE) {
    return Error::Permanent(fmt::format("storage: {}: no channel with id {}", path(), channel_id));
  }
  if (rc != SQLITE_ROW) {
    return sqlite_error(db(), path(), fmt::format("reading channel {}", channel_id));
  }
  const double scale = meta->column_double(0);
  const auto modulo = static_cast<uint64_t>(meta->column_int64(1));
  std::vector<double> raw, t, v;
  std::vector<uint32_t> seq;
  Status decode_error = Status::Ok();
  Status s = internal::for_each_chunk(
      db(), path(), channel_id, t_from_s, t_to_s, [&](const internal::ChunkView& c) {
        const auto n = static_cast<std::size_t>(c.clock.n);
        raw.resize(n);
        if (!internal::decode(c.encoding, c.data, c.bytes, n, raw.data())) {
          decode_error = Error::Permanent(fmt::format(
              "storage: {}: sample_chunks of channel {} at t0_s {}: {} bytes of data are not {} "
              "'{}' values",
              path(), channel_id, c.clock.t0_s, c.bytes, n, internal::to_string(c.encoding)));
          return false;
        }
        t.clear();
        v.clear();
        seq.clear();
        for (std::size_t i = 0; i < n; ++i) {
          const double ti = c.clock.t0_s + static_cast<double>(i) * c.clock.period_s;
          if (ti < t_from_s || ti >= t_to_s) continue;
          t.push_back(ti);
          v.push_back(raw[i] * scale);
          seq.push_back(modulo > 0 ? static_cast<uint32_t>((c.clock.seq0 + i) % modulo)
                                   : c.clock.seq0);
        }
        if (t.empty()) return true;
        return block(t, v, seq);
      });
  if (!s) return s;
  return decode_error;
}

Result<int64_t> SampleStore::count_channel_samples(int64_t channel_id) {
  auto st = Stmt::prepare(db(), path(),
                          "SELECT coalesce(sum(n), 0) FROM sample_chunks WHERE channel_id = ?");
  if (!st) return st.error();
  st->bind(1, channel_id);
  if (st->step() != SQLITE_ROW) {
    return sqlite_error(db(), path(),
                        fmt::format("counting the samples of channel {}", channel_id));
  }
  return st->column_int64(0);
}

Result<int64_t> SampleStore::count_gyro_samples(int64_t run_id) {
  auto stream = internal::resolve_channels(db(), path(), run_id, "", "");
  if (!stream) return stream.error();
  if (!*stream) return int64_t{0};
  return count_channel_samples((*stream)->channels[(*stream)->rate].id);
}

Result<std::vector<GyroSample>> SampleStore::gyro_samples(int64_t run_id, double t_from_s,
                                                          double t_to_s) {
  return gyro_samples(run_id, StreamKey{}, t_from_s, t_to_s);
}

Result<std::vector<GyroSample>> SampleStore::gyro_samples(int64_t run_id, const StreamKey& key,
                                                          double t_from_s, double t_to_s) {
  auto stream = internal::resolve_channels(db(), path(), run_id, key.dut_serial, key.axis);
  if (!stream) return stream.error();
  std::vector<GyroSample> out;
  if (!*stream) return out;
  const internal::StreamChannels& sc = **stream;
  std::vector<double> times;
  Status s = for_each_channel_block(
      sc.channels[sc.rate].id, t_from_s, t_to_s,
      [&](std::span<const double> t, std::span<const double> v, std::span<const uint32_t> seq) {
        for (std::size_t i = 0; i < t.size(); ++i) {
          GyroSample g;
          g.t_s = t[i];
          g.rate_dph = v[i];
          g.seq = static_cast<uint8_t>(seq[i]);
          out.push_back(g);
        }
        return true;
      });
  if (!s) return s.error();
  // Status and temperature come from the DUT's channels of the same frames:
  // their chunks have the same clocks, so matching by time is exact up to
  // the rounding of the implicit time stamps.
  auto fill = [&](int which, auto set) -> Status {
    if (which < 0 || out.empty()) return Status::Ok();
    std::size_t j = 0;
    return for_each_channel_block(
        sc.channels[which].id, t_from_s, t_to_s,
        [&](std::span<const double> t, std::span<const double> v, std::span<const uint32_t>) {
          for (std::size_t i = 0; i < t.size() && j < out.size(); ++i) {
            while (j < out.size() && out[j].t_s < t[i] - 1e-9) ++j;
            if (j < out.size() && std::abs(out[j].t_s - t[i]) <= 1e-9) {
              set(out[j], v[i]);
              ++j;
            }
          }
          return j < out.size();
        });
  };
  if (Status st = fill(sc.status,
                       [](GyroSample& g, double v) {
                         g.status = std::isfinite(v) ? static_cast<uint8_t>(v) : 0;
                       });
      !st) {
    return st.error();
  }
  if (Status st = fill(sc.temperature,
                       [](GyroSample& g, double v) {
                         g.temp_c = std::isfinite(v) ? static_cast<int16_t>(std::lround(v)) : 0;
                       });
      !st) {
    return st.error();
  }
  return out;
}

namespace {

// The latest sample time of every channel of a run (the last chunk of each).
constexpr const char* kLastChunkSql =
    "(SELECT max((SELECT t0_s + (n - 1) * period_s FROM sample_chunks k WHERE k.channel_id = c.id "
    "ORDER BY t0_s DESC LIMIT 1)) FROM channels c WHERE c.run_id = ?1)";

}  // namespace

Result<std::optional<double>> SampleStore::last_sample_t_s(int64_t run_id) {
  auto st =
      Stmt::prepare(db(), path(),
                    fmt::format("SELECT {}, "
                                "(SELECT max(t_s) FROM temperature_samples WHERE run_id = ?1), "
                                "(SELECT max(t_s) FROM table_samples WHERE run_id = ?1)",
                                kLastChunkSql));
  if (!st) return st.error();
  st->bind(1, run_id);
  if (st->step() != SQLITE_ROW) {
    return sqlite_error(db(), path(), fmt::format("reading the last sample of run {}", run_id));
  }
  // The largest of whichever exist (SQLite's scalar max() would be NULL when
  // any one is).
  std::optional<double> last;
  for (int c : {0, 1, 2}) {
    if (auto v = st->column_optional_double(c)) last = std::max(last.value_or(*v), *v);
  }
  return last;
}

Result<std::optional<double>> SampleStore::last_gyro_sample_t_s(int64_t run_id) {
  auto st = Stmt::prepare(db(), path(), fmt::format("SELECT {}", kLastChunkSql));
  if (!st) return st.error();
  st->bind(1, run_id);
  if (st->step() != SQLITE_ROW) {
    return sqlite_error(db(), path(),
                        fmt::format("reading the last gyro sample of run {}", run_id));
  }
  return st->column_optional_double(0);
}

Result<std::vector<TemperatureSample>> SampleStore::temperature_samples(int64_t run_id,
                                                                        double t_from_s,
                                                                        double t_to_s) {
  auto st = Stmt::prepare(db(), path(),
                          "SELECT t_s, setpoint_c, chamber_c, top_c, side_c FROM "
                          "temperature_samples WHERE run_id = ? AND t_s >= ? AND t_s < ? "
                          "ORDER BY t_s");
  if (!st) return st.error();
  st->bind(1, run_id);
  st->bind(2, t_from_s);
  st->bind(3, t_to_s);
  std::vector<TemperatureSample> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    TemperatureSample t;
    t.t_s = st->column_double(0);
    t.setpoint_c = st->column_double(1);
    t.chamber_c = st->column_double(2);
    t.top_c = st->column_double(3);
    t.side_c = st->column_double(4);
    out.push_back(t);
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db(), path(), fmt::format("reading temperature samples of run {}", run_id));
  }
  return out;
}

namespace {

constexpr const char* kTableSampleColumns =
    "t_s, demand_mode, demand_rate_dps, demand_position_deg, rate_dps, position_deg, mode, "
    "interlock";

TableSample read_table_sample(const Stmt& st) {
  TableSample t;
  t.t_s = st.column_double(0);
  t.demand_mode = st.column_text(1);
  t.demand_rate_dps = st.column_double(2);
  t.demand_position_deg = st.column_optional_double(3);
  t.rate_dps = st.column_double(4);
  t.position_deg = st.column_double(5);
  t.mode = st.column_text(6);
  t.interlock = st.column_text(7);
  return t;
}

}  // namespace

Result<std::vector<TableSample>> SampleStore::table_samples(int64_t run_id, double t_from_s,
                                                            double t_to_s) {
  auto st = Stmt::prepare(db(), path(),
                          fmt::format("SELECT {} FROM table_samples WHERE run_id = ? AND t_s >= ? "
                                      "AND t_s < ? ORDER BY t_s",
                                      kTableSampleColumns));
  if (!st) return st.error();
  st->bind(1, run_id);
  st->bind(2, t_from_s);
  st->bind(3, t_to_s);
  std::vector<TableSample> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) out.push_back(read_table_sample(*st));
  if (rc != SQLITE_DONE) {
    return sqlite_error(db(), path(), fmt::format("reading table samples of run {}", run_id));
  }
  return out;
}

// The circular mean of angles θ_i is atan2(Σ sin θ_i, Σ cos θ_i); the mean
// resultant length R = |Σ (cos θ_i, sin θ_i)| / n says how concentrated they
// are (1: all equal, 0: spread evenly). sin and cos are taken here, not in
// SQL: SQLite's math functions are optional in a build.
Result<TableWindowMeans> SampleStore::mean_table_over_windows(
    int64_t run_id, const std::vector<std::pair<double, double>>& windows) {
  auto st = Stmt::prepare(db(), path(),
                          "SELECT rate_dps, position_deg FROM table_samples WHERE run_id = ? AND "
                          "t_s >= ? AND t_s < ?");
  if (!st) return st.error();
  TableWindowMeans out;
  int64_t rate_n = 0, position_n = 0;
  double rate_sum = 0, sin_sum = 0, cos_sum = 0;
  constexpr double kRadPerDeg = std::numbers::pi / 180.0;
  for (const auto& [from_s, to_s] : windows) {
    st->reset();
    st->bind(1, run_id);
    st->bind(2, from_s);
    st->bind(3, to_s);
    int rc;
    while ((rc = st->step()) == SQLITE_ROW) {
      ++out.n;
      if (auto rate = st->column_optional_double(0)) {
        ++rate_n;
        rate_sum += *rate;
      }
      if (auto position = st->column_optional_double(1)) {
        ++position_n;
        sin_sum += std::sin(*position * kRadPerDeg);
        cos_sum += std::cos(*position * kRadPerDeg);
      }
    }
    if (rc != SQLITE_DONE) {
      return sqlite_error(
          db(), path(),
          fmt::format("reading table samples of run {} in [{}, {}) s", run_id, from_s, to_s));
    }
  }
  if (rate_n > 0) out.rate_dps = rate_sum / static_cast<double>(rate_n);
  if (position_n > 0) {
    out.position_resultant = std::hypot(sin_sum, cos_sum) / static_cast<double>(position_n);
    if (out.position_resultant >= TableWindowMeans::kMinResultant) {
      double deg = std::atan2(sin_sum, cos_sum) / kRadPerDeg;
      if (deg < 0) deg += 360.0;
      if (deg >= 360.0) deg -= 360.0;  // -tiny + 360 rounds to 360
      out.position_deg = deg;
    }
  }
  return out;
}

// Decimated reads of a run's samples (for plots and the REST samples
// route).
//
// Temperatures and the rate table (about one reading a control tick) are
// bucketed from their rows.
//
// Decimation reads the channel_rollup blocks written with the chunks, so
// the cost depends on max_points, not on the run's length: with w the
// bucket width asked for, the coarsest level whose block fits in w is read
// (at most 10 blocks per bucket, since levels are a decade apart) and
// buckets are made of whole blocks, which keeps min, max and mean exact.
// Only a range with few raw samples is bucketed from the samples
// themselves (decoded from their chunks).

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Raw samples a decimated read may decode before it turns to the rollup.
constexpr int64_t kRawRowBudget = 1'000'000;  // ~250 chunks, a few ms to decode
// Most rollup rows summed to bound the raw rows in range.
constexpr int64_t kCountBlocks = 1000;

double mean_or_nan(double sum, int64_t n) { return n > 0 ? sum / static_cast<double>(n) : kNaN; }

// Appends the rows of a bucket query (columns: bucket, n, sum of t_s, rate
// count, rate sum, rate min, rate max) — from the rollup or from the raw
// rows alike. Returns the last sqlite3_step code.
int read_gyro_buckets(Stmt& st, DecimatedSamples::Gyro& g) {
  int rc;
  while ((rc = st.step()) == SQLITE_ROW) {
    const int64_t n = st.column_int64(1);
    const int64_t rate_n = st.column_int64(3);
    g.t_s.push_back(st.column_double(2) / static_cast<double>(n));
    g.n.push_back(n);
    g.mean_dph.push_back(mean_or_nan(st.column_double(4), rate_n));
    g.min_dph.push_back(rate_n > 0 ? st.column_double(5) : kNaN);
    g.max_dph.push_back(rate_n > 0 ? st.column_double(6) : kNaN);
  }
  return rc;
}

}  // namespace

Result<DecimatedSamples> SampleStore::decimated_samples(int64_t run_id, double from_s,
                                                        std::optional<double> to_s,
                                                        int max_points) {
  return decimated_samples(run_id, StreamKey{}, "", from_s, to_s, max_points);
}

Result<DecimatedSamples> SampleStore::decimated_samples(int64_t run_id, const StreamKey& dut,
                                                        const std::string& channel, double from_s,
                                                        std::optional<double> to_s,
                                                        int max_points) {
  DecimatedSamples out;
  if (max_points < 1) {
    return Error::Permanent(fmt::format("decimated samples: max_points {} < 1", max_points));
  }
  auto stream = internal::resolve_channels(db(), path(), run_id, dut.dut_serial, dut.axis);
  if (!stream) return stream.error();
  int64_t channel_id = 0;  // 0: the run has no DUT (no gyro points)
  if (*stream) {
    const internal::StreamChannels& sc = **stream;
    const internal::ChannelInfo* ch = channel.empty() ? &sc.channels[sc.rate] : nullptr;
    std::vector<std::string> names;
    for (const internal::ChannelInfo& c : sc.channels) {
      if (!ch && c.name == channel) ch = &c;
      names.push_back(c.name);
    }
    if (!ch) {
      return Error::Permanent(
          fmt::format("DUT '{}' of run {} has no channel '{}' (its channels: {})", sc.serial,
                      run_id, channel, fmt::join(names, ", ")));
    }
    out.dut_serial = sc.serial;
    out.channel = ch->name;
    out.unit = ch->unit;
    channel_id = ch->id;
  }
  if (!to_s) {
    auto last = last_sample_t_s(run_id);
    if (!last) return last.error();
    to_s = last->value_or(from_s);
  }
  if (!(std::isfinite(from_s) && std::isfinite(*to_s)) || *to_s < from_s) {
    return Error::Permanent(fmt::format("decimated samples: bad range [{}, {}] s", from_s, *to_s));
  }
  out.from_s = from_s;
  out.to_s = *to_s;
  const double range_s = *to_s - from_s;
  const double want_s = range_s / max_points;
  const std::string what = fmt::format("reading samples of run {}", run_id);
  constexpr int kFirst = internal::kChannelRollupFirstLevel;
  constexpr int kTop = internal::kChannelRollupLastLevel;
  const auto& block_len_s = internal::kChannelRollupBlockS;

  // Upper bound of the raw samples in range, from the finest rollup level
  // that spans it in at most kCountBlocks blocks: a short zoom into a long
  // run is counted in 1 s blocks, not 1000 s ones, so it can still be read
  // raw.
  int count_level = kTop;
  for (int l = kFirst; l < kTop; ++l) {
    if (std::floor(*to_s / block_len_s[l]) - std::floor(from_s / block_len_s[l]) < kCountBlocks) {
      count_level = l;
      break;
    }
  }
  auto count = Stmt::prepare(db(), path(),
                             "SELECT coalesce(sum(n), 0) FROM channel_rollup WHERE channel_id = ? "
                             "AND level = ? AND block BETWEEN ? AND ?");
  if (!count) return count.error();
  count->bind(1, channel_id);
  count->bind(2, count_level);
  count->bind(3, static_cast<int64_t>(std::floor(from_s / block_len_s[count_level])));
  count->bind(4, static_cast<int64_t>(std::floor(*to_s / block_len_s[count_level])));
  if (count->step() != SQLITE_ROW) return sqlite_error(db(), path(), what);
  const int64_t raw_rows = count->column_int64(0);

  int level = -1;  // -1: raw samples
  if (raw_rows > max_points) {
    for (int l = kTop; l >= kFirst; --l) {
      if (block_len_s[l] <= want_s) {
        level = l;
        break;
      }
    }
    // Buckets narrower than the finest block: raw samples (decoded from
    // their chunks) if few enough, else the finest blocks (fewer points
    // than asked for).
    if (level < 0 && raw_rows > kRawRowBudget) level = kFirst;
  }

  auto& g = out.gyro;
  if (level >= 0) {
    const double block_s = block_len_s[level];
    const int64_t first = static_cast<int64_t>(std::floor(from_s / block_s));
    const int64_t last = static_cast<int64_t>(std::floor(*to_s / block_s));
    const int64_t per_bucket =
        std::max<int64_t>(1, static_cast<int64_t>(std::ceil(want_s / block_s - 1e-9)));
    out.bucket_s = static_cast<double>(per_bucket) * block_s;
    out.from_rollup = true;
    out.from_s = static_cast<double>(first) * block_s;
    out.to_s = static_cast<double>(last + 1) * block_s;
    auto st = Stmt::prepare(
        db(), path(),
        "SELECT min((block - ?3) / ?5, ?6) AS b, sum(n), sum(t_sum_s), sum(v_n), "
        "sum(v_sum), min(v_min), max(v_max) FROM channel_rollup "
        "WHERE channel_id = ?1 AND level = ?2 AND block BETWEEN ?3 AND ?4 GROUP BY b ORDER BY b");
    if (!st) return st.error();
    st->bind(1, channel_id);
    st->bind(2, level);
    st->bind(3, first);
    st->bind(4, last);
    st->bind(5, per_bucket);
    // Widened to block edges, the range can span a block or two more than
    // max_points buckets: those go into the last bucket, as in the raw case.
    st->bind(6, static_cast<int64_t>(max_points - 1));
    if (read_gyro_buckets(*st, g) != SQLITE_DONE) return sqlite_error(db(), path(), what);
  } else if (channel_id != 0) {
    // Few enough: the samples as recorded; else exact buckets of want_s
    // from the decoded samples. [from_s, to_s] is closed.
    const double end_s = std::nextafter(*to_s, std::numeric_limits<double>::infinity());
    const bool as_recorded = raw_rows <= max_points;
    if (!as_recorded) out.bucket_s = want_s;
    struct Bucket {
      int64_t n = 0, v_n = 0;
      double t_sum_s = 0, v_sum = 0, v_min = 0, v_max = 0;
    };
    std::vector<Bucket> buckets(as_recorded ? 0 : static_cast<std::size_t>(max_points));
    Status s = for_each_channel_block(
        channel_id, from_s, end_s,
        [&](std::span<const double> t, std::span<const double> v, std::span<const uint32_t>) {
          for (std::size_t i = 0; i < t.size(); ++i) {
            if (as_recorded) {
              if (g.t_s.size() >= static_cast<std::size_t>(max_points)) return false;
              g.t_s.push_back(t[i]);
              g.n.push_back(1);
              g.mean_dph.push_back(v[i]);
              g.min_dph.push_back(v[i]);
              g.max_dph.push_back(v[i]);
              continue;
            }
            const auto k =
                std::min<int64_t>(static_cast<int64_t>((t[i] - from_s) / want_s), max_points - 1);
            Bucket& b = buckets[static_cast<std::size_t>(k)];
            ++b.n;
            b.t_sum_s += t[i];
            if (std::isfinite(v[i])) {
              b.v_min = b.v_n == 0 ? v[i] : std::min(b.v_min, v[i]);
              b.v_max = b.v_n == 0 ? v[i] : std::max(b.v_max, v[i]);
              ++b.v_n;
              b.v_sum += v[i];
            }
          }
          return true;
        });
    if (!s) return s.error();
    for (const Bucket& b : buckets) {
      if (b.n == 0) continue;
      g.t_s.push_back(b.t_sum_s / static_cast<double>(b.n));
      g.n.push_back(b.n);
      g.mean_dph.push_back(mean_or_nan(b.v_sum, b.v_n));
      g.min_dph.push_back(b.v_n > 0 ? b.v_min : kNaN);
      g.max_dph.push_back(b.v_n > 0 ? b.v_max : kNaN);
    }
  }

  // Temperatures (about one a second): bucketed from the rows, on the same
  // bucket width when the gyro is decimated.
  const double temp_bucket_s = out.bucket_s > 0 ? out.bucket_s : want_s;
  auto st = Stmt::prepare(
      db(), path(),
      "SELECT min(CAST((t_s - ?2) / ?4 AS INTEGER), ?5) AS b, avg(t_s), avg(setpoint_c), "
      "avg(chamber_c), avg(top_c), avg(side_c) FROM temperature_samples "
      "WHERE run_id = ?1 AND t_s >= ?2 AND t_s <= ?3 GROUP BY b ORDER BY b");
  if (!st) return st.error();
  st->bind(1, run_id);
  st->bind(2, out.from_s);
  st->bind(3, out.to_s);
  st->bind(4, temp_bucket_s > 0 ? temp_bucket_s : 1.0);
  st->bind(5, static_cast<int64_t>(max_points - 1));
  auto& tp = out.temperature;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    tp.t_s.push_back(st->column_double(1));
    tp.setpoint_c.push_back(st->column_double(2));
    tp.chamber_c.push_back(st->column_double(3));
    tp.top_c.push_back(st->column_double(4));
    tp.side_c.push_back(st->column_double(5));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db(), path(), what);

  // The rate table, on the temperatures' buckets: the rate's mean and
  // envelope, and the state of the bucket's last reading (found by its key).
  auto table = Stmt::prepare(
      db(), path(),
      "WITH buckets AS (SELECT min(CAST((t_s - ?2) / ?4 AS INTEGER), ?5) AS b, count(*) AS n, "
      "avg(t_s) AS t_mean_s, avg(rate_dps) AS mean_dps, min(rate_dps) AS min_dps, "
      "max(rate_dps) AS max_dps, max(t_s) AS t_last_s FROM table_samples "
      "WHERE run_id = ?1 AND t_s >= ?2 AND t_s <= ?3 GROUP BY b) "
      "SELECT k.t_mean_s, k.n, k.mean_dps, k.min_dps, k.max_dps, s.position_deg, "
      "s.demand_rate_dps, s.demand_mode, s.mode, s.interlock FROM buckets k "
      "JOIN table_samples s ON s.run_id = ?1 AND s.t_s = k.t_last_s ORDER BY k.b");
  if (!table) return table.error();
  table->bind(1, run_id);
  table->bind(2, out.from_s);
  table->bind(3, out.to_s);
  table->bind(4, temp_bucket_s > 0 ? temp_bucket_s : 1.0);
  table->bind(5, static_cast<int64_t>(max_points - 1));
  auto& tb = out.table;
  while ((rc = table->step()) == SQLITE_ROW) {
    int c = 0;
    tb.t_s.push_back(table->column_double(c++));
    tb.n.push_back(table->column_int64(c++));
    tb.mean_rate_dps.push_back(table->column_double(c++));
    tb.min_rate_dps.push_back(table->column_double(c++));
    tb.max_rate_dps.push_back(table->column_double(c++));
    tb.position_deg.push_back(table->column_double(c++));
    tb.demand_rate_dps.push_back(table->column_double(c++));
    tb.demand_mode.push_back(table->column_text(c++));
    tb.mode.push_back(table->column_text(c++));
    tb.interlock.push_back(table->column_text(c++));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db(), path(), what);
  return out;
}

}  // namespace gyrotherm::storage
