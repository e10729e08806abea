// Database: decimated reads of a run's samples (for plots and the REST
// samples route) and stored drift-model fits.
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
#include <fmt/format.h>
#include <sqlite3.h>

#include <cmath>
#include <limits>

#include "chunks.h"
#include "duts_internal.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::sqlite_error;
using internal::Stmt;
using internal::Transaction;

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

Result<DecimatedSamples> Database::decimated_samples(int64_t run_id, double from_s,
                                                     std::optional<double> to_s, int max_points) {
  return decimated_samples(run_id, StreamKey{}, "", from_s, to_s, max_points);
}

Result<DecimatedSamples> Database::decimated_samples(int64_t run_id, const StreamKey& dut,
                                                     const std::string& channel, double from_s,
                                                     std::optional<double> to_s, int max_points) {
  DecimatedSamples out;
  if (max_points < 1) {
    return Error::Permanent(fmt::format("decimated samples: max_points {} < 1", max_points));
  }
  auto stream = internal::resolve_channels(db_, path_, run_id, dut.dut_serial, dut.axis);
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
  auto count = Stmt::prepare(db_, path_,
                             "SELECT coalesce(sum(n), 0) FROM channel_rollup WHERE channel_id = ? "
                             "AND level = ? AND block BETWEEN ? AND ?");
  if (!count) return count.error();
  count->bind(1, channel_id);
  count->bind(2, count_level);
  count->bind(3, static_cast<int64_t>(std::floor(from_s / block_len_s[count_level])));
  count->bind(4, static_cast<int64_t>(std::floor(*to_s / block_len_s[count_level])));
  if (count->step() != SQLITE_ROW) return sqlite_error(db_, path_, what);
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
        db_, path_,
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
    if (read_gyro_buckets(*st, g) != SQLITE_DONE) return sqlite_error(db_, path_, what);
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
      db_, path_,
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
  if (rc != SQLITE_DONE) return sqlite_error(db_, path_, what);

  // The rate table, on the temperatures' buckets: the rate's mean and
  // envelope, and the state of the bucket's last reading (found by its key).
  auto table = Stmt::prepare(
      db_, path_,
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
  if (rc != SQLITE_DONE) return sqlite_error(db_, path_, what);
  return out;
}

namespace {

constexpr const char* kFitColumns =
    "id, model, form, n, coefficients_json, standard_errors_json, residual_std_dph, r_squared, "
    "inputs_json, computed_utc, dut_serial, axis, coverage_samples, coverage_expected, coverage, "
    "longest_gap_s, quality, quality_reasons_json";

}  // namespace

Result<int64_t> Database::add_fit(const FitRecord& fit) {
  Transaction tx(db_, path_);
  if (Status s = tx.begin_immediate(); !s) return s.error();
  // The DUT and axis as of the first run fitted ("" = its first DUT and
  // that DUT's primary axis); a fit of no run keeps what it is given.
  internal::ResultKey key{fit.dut_serial, fit.axis};
  if (!fit.run_ids.empty()) {
    auto resolved = internal::result_key(db_, path_, fit.run_ids.front(), fit.dut_serial, fit.axis,
                                         "storing a fit");
    if (!resolved) return resolved.error();
    key = std::move(*resolved);
  }
  auto st = Stmt::prepare(db_, path_,
                          "INSERT INTO fits(model, form, n, coefficients_json, "
                          "standard_errors_json, residual_std_dph, r_squared, inputs_json, "
                          "computed_utc, dut_serial, axis, coverage_samples, coverage_expected, "
                          "coverage, longest_gap_s, quality, quality_reasons_json) VALUES(?, ?, "
                          "?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  if (!st) return st.error();
  st->bind(1, fit.model);
  st->bind(2, fit.form);
  st->bind(3, fit.n);
  st->bind(4, fit.coefficients_json);
  st->bind(5, fit.standard_errors_json);
  st->bind(6, fit.residual_std_dph);
  st->bind(7, fit.r_squared);
  st->bind(8, fit.inputs_json.empty() ? std::string_view("{}") : fit.inputs_json);
  st->bind(9, utc_or_now(fit.computed_utc));
  st->bind(10, std::string_view(key.serial));
  st->bind(11, std::string_view(key.axis));
  internal::bind_quality(*st, 12, fit.quality);
  if (st->step() != SQLITE_DONE) return sqlite_error(db_, path_, "storing a fit");
  const int64_t id = sqlite3_last_insert_rowid(db_);
  auto link =
      Stmt::prepare(db_, path_, "INSERT OR IGNORE INTO fit_runs(run_id, fit_id) VALUES(?, ?)");
  if (!link) return link.error();
  for (int64_t run_id : fit.run_ids) {
    link->bind(1, run_id);
    link->bind(2, id);
    if (link->step() != SQLITE_DONE) return sqlite_error(db_, path_, "storing a fit's runs");
    link->reset();
  }
  if (Status s = tx.commit(); !s) return s.error();
  return id;
}

namespace {

Result<std::vector<FitRecord>> read_fits(sqlite3* db, const std::string& path, Stmt& st) {
  std::vector<FitRecord> out;
  int rc;
  while ((rc = st.step()) == SQLITE_ROW) {
    FitRecord f;
    int c = 0;
    f.id = st.column_int64(c++);
    f.model = st.column_text(c++);
    f.form = st.column_text(c++);
    f.n = st.column_int64(c++);
    f.coefficients_json = st.column_text(c++);
    f.standard_errors_json = st.column_text(c++);
    f.residual_std_dph = st.column_double(c++);
    f.r_squared = st.column_double(c++);
    f.inputs_json = st.column_text(c++);
    f.computed_utc = st.column_text(c++);
    f.dut_serial = st.column_text(c++);
    f.axis = st.column_text(c++);
    f.quality = internal::read_quality(st, c);
    out.push_back(std::move(f));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db, path, "reading fits");
  auto runs =
      Stmt::prepare(db, path, "SELECT run_id FROM fit_runs WHERE fit_id = ? ORDER BY run_id");
  if (!runs) return runs.error();
  for (FitRecord& f : out) {
    runs->bind(1, f.id);
    while ((rc = runs->step()) == SQLITE_ROW) f.run_ids.push_back(runs->column_int64(0));
    if (rc != SQLITE_DONE) return sqlite_error(db, path, "reading a fit's runs");
    runs->reset();
  }
  return out;
}

}  // namespace

namespace internal {

Result<std::vector<FitRecord>> fits_of_dut(sqlite3* db, const std::string& path,
                                           const std::string& serial) {
  auto st = Stmt::prepare(
      db, path,
      fmt::format("SELECT {} FROM fits WHERE dut_serial = ? ORDER BY id DESC", kFitColumns));
  if (!st) return st.error();
  st->bind(1, std::string_view(serial));
  return read_fits(db, path, *st);
}

}  // namespace internal

Result<std::vector<FitRecord>> Database::fits(int64_t run_id) {
  auto st = Stmt::prepare(db_, path_,
                          fmt::format("SELECT {} FROM fits WHERE id IN (SELECT fit_id FROM "
                                      "fit_runs WHERE run_id = ?) ORDER BY id DESC",
                                      kFitColumns));
  if (!st) return st.error();
  st->bind(1, run_id);
  return read_fits(db_, path_, *st);
}

Result<std::optional<FitRecord>> Database::fit(int64_t fit_id) {
  auto st = Stmt::prepare(db_, path_, fmt::format("SELECT {} FROM fits WHERE id = ?", kFitColumns));
  if (!st) return st.error();
  st->bind(1, fit_id);
  auto fits = read_fits(db_, path_, *st);
  if (!fits) return fits.error();
  if (fits->empty()) return std::optional<FitRecord>();
  return std::optional<FitRecord>(std::move(fits->front()));
}

}  // namespace gyrotherm::storage
