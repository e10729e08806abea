// Database: the readers of chunked samples (schema v9): gyro_samples,
// for_each_channel_block, the counts and the last sample times.
#include <fmt/format.h>
#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <limits>

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

Status Database::for_each_channel_block(
    int64_t channel_id, double t_from_s, double t_to_s,
    const std::function<bool(std::span<const double> t_s, std::span<const double> value,
                             std::span<const uint32_t> seq)>& block) {
  auto meta =
      Stmt::prepare(db_, path_,
                    "SELECT c.scale, coalesce(rd.seq_modulo, 0) FROM channels c "
                    "LEFT JOIN run_duts rd ON rd.run_id = c.run_id AND rd.dut_id = c.dut_id "
                    "WHERE c.id = ?");
  if (!meta) return meta.error();
  meta->bind(1, channel_id);
  const int rc = meta->step();
  if (rc == SQLITE_DONE) {
    return Error::Permanent(fmt::format("storage: {}: no channel with id {}", path_, channel_id));
  }
  if (rc != SQLITE_ROW) {
    return sqlite_error(db_, path_, fmt::format("reading channel {}", channel_id));
  }
  const double scale = meta->column_double(0);
  const auto modulo = static_cast<uint64_t>(meta->column_int64(1));
  std::vector<double> raw, t, v;
  std::vector<uint32_t> seq;
  Status decode_error = Status::Ok();
  Status s = internal::for_each_chunk(
      db_, path_, channel_id, t_from_s, t_to_s, [&](const internal::ChunkView& c) {
        const auto n = static_cast<std::size_t>(c.clock.n);
        raw.resize(n);
        if (!internal::decode(c.encoding, c.data, c.bytes, n, raw.data())) {
          decode_error = Error::Permanent(fmt::format(
              "storage: {}: sample_chunks of channel {} at t0_s {}: {} bytes of data are not {} "
              "'{}' values",
              path_, channel_id, c.clock.t0_s, c.bytes, n, internal::to_string(c.encoding)));
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

Result<int64_t> Database::count_channel_samples(int64_t channel_id) {
  auto st = Stmt::prepare(db_, path_,
                          "SELECT coalesce(sum(n), 0) FROM sample_chunks WHERE channel_id = ?");
  if (!st) return st.error();
  st->bind(1, channel_id);
  if (st->step() != SQLITE_ROW) {
    return sqlite_error(db_, path_, fmt::format("counting the samples of channel {}", channel_id));
  }
  return st->column_int64(0);
}

Result<int64_t> Database::count_gyro_samples(int64_t run_id) {
  auto stream = internal::resolve_channels(db_, path_, run_id, "", "");
  if (!stream) return stream.error();
  if (!*stream) return int64_t{0};
  return count_channel_samples((*stream)->channels[(*stream)->rate].id);
}

Result<std::vector<GyroSample>> Database::gyro_samples(int64_t run_id, double t_from_s,
                                                       double t_to_s) {
  return gyro_samples(run_id, StreamKey{}, t_from_s, t_to_s);
}

Result<std::vector<GyroSample>> Database::gyro_samples(int64_t run_id, const StreamKey& key,
                                                       double t_from_s, double t_to_s) {
  auto stream = internal::resolve_channels(db_, path_, run_id, key.dut_serial, key.axis);
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

Result<std::optional<double>> Database::last_sample_t_s(int64_t run_id) {
  auto st =
      Stmt::prepare(db_, path_,
                    fmt::format("SELECT {}, "
                                "(SELECT max(t_s) FROM temperature_samples WHERE run_id = ?1), "
                                "(SELECT max(t_s) FROM table_samples WHERE run_id = ?1)",
                                kLastChunkSql));
  if (!st) return st.error();
  st->bind(1, run_id);
  if (st->step() != SQLITE_ROW) {
    return sqlite_error(db_, path_, fmt::format("reading the last sample of run {}", run_id));
  }
  // The largest of whichever exist (SQLite's scalar max() would be NULL when
  // any one is).
  std::optional<double> last;
  for (int c : {0, 1, 2}) {
    if (auto v = st->column_optional_double(c)) last = std::max(last.value_or(*v), *v);
  }
  return last;
}

Result<std::optional<double>> Database::last_gyro_sample_t_s(int64_t run_id) {
  auto st = Stmt::prepare(db_, path_, fmt::format("SELECT {}", kLastChunkSql));
  if (!st) return st.error();
  st->bind(1, run_id);
  if (st->step() != SQLITE_ROW) {
    return sqlite_error(db_, path_, fmt::format("reading the last gyro sample of run {}", run_id));
  }
  return st->column_optional_double(0);
}

}  // namespace gyrotherm::storage
