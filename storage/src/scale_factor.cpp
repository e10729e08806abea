// ResultStore (results.h): the stored scale-factor analysis (schema v7;
// docs/storage.md).
#include <fmt/format.h>
#include <sqlite3.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "duts_internal.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/results.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;
using internal::Transaction;

namespace {

// The coefficients must be a JSON array of numbers ("" means none: "[]").
Result<std::string> coefficients_json(const std::string& text, const char* field, int64_t run_id,
                                      const std::string& path) {
  if (text.empty()) return std::string("[]");
  const nlohmann::json j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  bool ok = !j.is_discarded() && j.is_array();
  if (ok) {
    for (const auto& v : j) ok = ok && v.is_number();
  }
  if (!ok) {
    return Error::Permanent(
        fmt::format("storage: {}: storing the scale-factor temperature fit of run {}: {} is not "
                    "a JSON array of numbers: '{}'",
                    path, run_id, field, text));
  }
  return text;
}

}  // namespace

Status ResultStore::store_scale_factor(
    int64_t run_id, const std::vector<ScaleFactorPointRecord>& points,
    const std::vector<ScaleFactorFitRecord>& fits,
    const std::optional<ScaleFactorTemperatureFitRecord>& temperature_fit) {
  // The series is the one the records name (all the same one); records
  // that name none, or no records at all: the run's first DUT, primary axis.
  std::optional<StreamKey> named;
  std::string conflict;
  const auto note = [&](const std::string& serial, const std::string& axis) {
    if (serial.empty() && axis.empty()) return;
    const StreamKey key{serial, axis};
    if (!named) {
      named = key;
    } else if (named->dut_serial != serial || named->axis != axis) {
      conflict = fmt::format(
          "records name DUT '{}' axis '{}' and DUT '{}' axis '{}' (store each "
          "DUT and axis with its own call)",
          named->dut_serial, named->axis, serial, axis);
    }
  };
  for (const auto& p : points) note(p.dut_serial, p.axis);
  for (const auto& f : fits) note(f.dut_serial, f.axis);
  if (temperature_fit) note(temperature_fit->dut_serial, temperature_fit->axis);
  if (!conflict.empty()) {
    return Error::Permanent(fmt::format("storage: {}: storing the scale factor of run {}: {}",
                                        path(), run_id, conflict));
  }
  return store_scale_factor(run_id, named.value_or(StreamKey{}), points, fits, temperature_fit);
}

Status ResultStore::store_scale_factor(
    int64_t run_id, const StreamKey& stream, const std::vector<ScaleFactorPointRecord>& points,
    const std::vector<ScaleFactorFitRecord>& fits,
    const std::optional<ScaleFactorTemperatureFitRecord>& temperature_fit) {
  std::string what = fmt::format("storing the scale factor of run {}", run_id);
  auto key = internal::result_key(db(), path(), run_id, stream.dut_serial, stream.axis, what);
  if (!key) return key.error();
  if (!key->serial.empty() || !key->axis.empty()) {
    what = fmt::format("storing the scale factor of run {} DUT '{}' axis '{}'", run_id, key->serial,
                       key->axis);
  }
  const auto wrong_run = [&](const char* record, int64_t other) {
    return Error::Permanent(
        fmt::format("storage: {}: {}: a {} record belongs to run {}", path(), what, record, other));
  };
  // A record naming its DUT or axis must name this series ("" takes it).
  const auto wrong_series = [&](const char* record, const std::string& serial,
                                const std::string& axis) -> std::optional<Error> {
    const bool serial_ok = serial.empty() || serial == key->serial;
    const bool axis_ok = axis.empty() || axis == key->axis;
    if (serial_ok && axis_ok) return std::nullopt;
    return Error::Permanent(fmt::format("storage: {}: {}: a {} record is for DUT '{}' axis '{}'",
                                        path(), what, record, serial, axis));
  };
  for (const auto& p : points) {
    if (p.run_id != 0 && p.run_id != run_id) return wrong_run("point", p.run_id);
    if (auto e = wrong_series("point", p.dut_serial, p.axis)) return *e;
  }
  for (const auto& f : fits) {
    if (f.run_id != 0 && f.run_id != run_id) return wrong_run("fit", f.run_id);
    if (auto e = wrong_series("fit", f.dut_serial, f.axis)) return *e;
  }
  std::string k_coeffs, bias_coeffs;
  if (temperature_fit) {
    if (temperature_fit->run_id != 0 && temperature_fit->run_id != run_id) {
      return wrong_run("temperature fit", temperature_fit->run_id);
    }
    if (auto e =
            wrong_series("temperature fit", temperature_fit->dut_serial, temperature_fit->axis)) {
      return *e;
    }
    auto k = coefficients_json(temperature_fit->k_coeffs_json, "k_coeffs_json", run_id, path());
    if (!k) return k.error();
    auto b =
        coefficients_json(temperature_fit->bias_coeffs_json, "bias_coeffs_json", run_id, path());
    if (!b) return b.error();
    k_coeffs = std::move(*k);
    bias_coeffs = std::move(*b);
  }

  internal::WriteScope tx(db(), path(), "store_scale_factor");
  if (Status s = tx.begin(); !s) return s;
  // This series' rows only (other DUTs and axes of the run stay), and the
  // rows stored before v8 of this DUT when this is its primary axis.
  for (const char* table :
       {"scale_factor_points", "scale_factor_fits", "scale_factor_temperature_fits"}) {
    auto del = Stmt::prepare(db(), path(),
                             fmt::format("DELETE FROM {} WHERE run_id = ? AND dut_serial = ? AND "
                                         "(axis = ? OR (? AND axis = ''))",
                                         table));
    if (!del) return del.error();
    del->bind(1, run_id);
    del->bind(2, std::string_view(key->serial));
    del->bind(3, std::string_view(key->axis));
    del->bind(4, key->primary ? 1 : 0);
    if (Status s = expect_done(*del, db(), path(), what); !s) return s;
  }

  auto ins_point = Stmt::prepare(
      db(), path(),
      "INSERT INTO scale_factor_points(run_id, segment_id, sf_sequence, repetition, rate_dps, "
      "measured_rate_dps, output_dps, n, temperature_c, duration_s, turns, dut_serial, axis, "
      "guard_s, coverage_samples, coverage_expected, coverage, longest_gap_s, quality, "
      "quality_reasons_json) VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  if (!ins_point) return ins_point.error();
  for (const auto& p : points) {
    Stmt& st = *ins_point;
    st.reset();
    int i = 1;
    st.bind(i++, run_id);
    if (p.segment_id == 0) {
      st.bind_null(i++);
    } else {
      st.bind(i++, p.segment_id);
    }
    st.bind(i++, p.sf_sequence);
    st.bind(i++, p.repetition);
    st.bind(i++, p.rate_dps);
    st.bind(i++, p.measured_rate_dps);
    st.bind(i++, p.output_dps);
    st.bind(i++, p.n);
    st.bind(i++, p.temperature_c);
    st.bind(i++, p.duration_s);
    st.bind(i++, p.turns);
    st.bind(i++, std::string_view(key->serial));
    st.bind(i++, std::string_view(key->axis));
    st.bind(i++, p.guard_s);
    internal::bind_quality(st, i, p.quality);
    const std::string point =
        fmt::format("{}: point of sequence {} repetition {} at {} °/s (segment {})", what,
                    p.sf_sequence, p.repetition, p.rate_dps, p.segment_id);
    if (Status s = expect_done(st, db(), path(), point); !s) return s;
  }

  auto ins_fit = Stmt::prepare(
      db(), path(),
      "INSERT INTO scale_factor_fits(run_id, sf_sequence, temperature_c, k, k_se, bias_dps, "
      "nonlinearity_ppm, nonlinearity_fs_ppm, asymmetry_ppm, repeatability_ppm, n_points, "
      "created_utc, dut_serial, axis, guard_s, coverage_samples, coverage_expected, coverage, "
      "longest_gap_s, quality, quality_reasons_json) VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
      "?, ?, ?, ?, ?, ?, ?, ?)");
  if (!ins_fit) return ins_fit.error();
  for (const auto& f : fits) {
    Stmt& st = *ins_fit;
    st.reset();
    int i = 1;
    st.bind(i++, run_id);
    st.bind(i++, f.sf_sequence);
    st.bind(i++, f.temperature_c);
    st.bind(i++, f.k);
    st.bind(i++, f.k_se);
    st.bind(i++, f.bias_dps);
    st.bind(i++, f.nonlinearity_ppm);
    st.bind(i++, f.nonlinearity_fs_ppm);
    st.bind(i++, f.asymmetry_ppm);
    st.bind(i++, f.repeatability_ppm);
    st.bind(i++, f.n_points);
    st.bind(i++, std::string_view(self().utc_or_now(f.created_utc)));
    st.bind(i++, std::string_view(key->serial));
    st.bind(i++, std::string_view(key->axis));
    st.bind(i++, f.guard_s);
    internal::bind_quality(st, i, f.quality);
    if (Status s = expect_done(st, db(), path(),
                               fmt::format("{}: fit of sequence {}", what, f.sf_sequence));
        !s) {
      return s;
    }
  }

  if (temperature_fit) {
    const auto& t = *temperature_fit;
    auto st = Stmt::prepare(
        db(), path(),
        "INSERT INTO scale_factor_temperature_fits(run_id, poly_order, t_centre_c, "
        "k_coeffs_json, bias_coeffs_json, k_ppm_per_c, bias_dph_per_c, created_utc, dut_serial, "
        "axis) VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
    if (!st) return st.error();
    int i = 1;
    st->bind(i++, run_id);
    st->bind(i++, t.order);
    st->bind(i++, t.t_centre_c);
    st->bind(i++, std::string_view(k_coeffs));
    st->bind(i++, std::string_view(bias_coeffs));
    st->bind(i++, t.k_ppm_per_c);
    st->bind(i++, t.bias_dph_per_c);
    st->bind(i++, std::string_view(self().utc_or_now(t.created_utc)));
    st->bind(i++, std::string_view(key->serial));
    st->bind(i++, std::string_view(key->axis));
    if (Status s = expect_done(*st, db(), path(), fmt::format("{}: temperature fit", what)); !s) {
      return s;
    }
  }
  return tx.commit();
}

namespace {

constexpr const char* kPointColumns =
    "id, run_id, segment_id, sf_sequence, repetition, rate_dps, measured_rate_dps, output_dps, n, "
    "temperature_c, duration_s, turns, dut_serial, axis, guard_s, coverage_samples, "
    "coverage_expected, coverage, longest_gap_s, quality, quality_reasons_json";
constexpr const char* kScaleFactorFitColumns =
    "run_id, sf_sequence, temperature_c, k, k_se, bias_dps, nonlinearity_ppm, "
    "nonlinearity_fs_ppm, asymmetry_ppm, repeatability_ppm, n_points, created_utc, dut_serial, "
    "axis, guard_s, coverage_samples, coverage_expected, coverage, longest_gap_s, quality, "
    "quality_reasons_json";
constexpr const char* kTemperatureFitColumns =
    "run_id, poly_order, t_centre_c, k_coeffs_json, bias_coeffs_json, k_ppm_per_c, "
    "bias_dph_per_c, created_utc, dut_serial, axis";

ScaleFactorPointRecord read_point(const Stmt& st) {
  ScaleFactorPointRecord p;
  int c = 0;
  p.id = st.column_int64(c++);
  p.run_id = st.column_int64(c++);
  p.segment_id = st.column_optional_int64(c++).value_or(0);
  p.sf_sequence = static_cast<int>(st.column_int64(c++));
  p.repetition = static_cast<int>(st.column_int64(c++));
  p.rate_dps = st.column_double(c++);
  p.measured_rate_dps = st.column_double(c++);
  p.output_dps = st.column_double(c++);
  p.n = st.column_int64(c++);
  p.temperature_c = st.column_double(c++);
  p.duration_s = st.column_double(c++);
  p.turns = st.column_double(c++);
  p.dut_serial = st.column_text(c++);
  p.axis = st.column_text(c++);
  p.guard_s = st.column_double(c++);
  p.quality = internal::read_quality(st, c);
  return p;
}

ScaleFactorFitRecord read_fit(const Stmt& st) {
  ScaleFactorFitRecord f;
  int c = 0;
  f.run_id = st.column_int64(c++);
  f.sf_sequence = static_cast<int>(st.column_int64(c++));
  f.temperature_c = st.column_double(c++);
  f.k = st.column_double(c++);
  f.k_se = st.column_double(c++);
  f.bias_dps = st.column_double(c++);
  f.nonlinearity_ppm = st.column_double(c++);
  f.nonlinearity_fs_ppm = st.column_double(c++);
  f.asymmetry_ppm = st.column_optional_double(c++);
  f.repeatability_ppm = st.column_optional_double(c++);
  f.n_points = st.column_int64(c++);
  f.created_utc = st.column_text(c++);
  f.dut_serial = st.column_text(c++);
  f.axis = st.column_text(c++);
  f.guard_s = st.column_double(c++);
  f.quality = internal::read_quality(st, c);
  return f;
}

ScaleFactorTemperatureFitRecord read_temperature_fit(const Stmt& st) {
  ScaleFactorTemperatureFitRecord t;
  int c = 0;
  t.run_id = st.column_int64(c++);
  t.order = static_cast<int>(st.column_int64(c++));
  t.t_centre_c = st.column_double(c++);
  t.k_coeffs_json = st.column_text(c++);
  t.bias_coeffs_json = st.column_text(c++);
  t.k_ppm_per_c = st.column_double(c++);
  t.bias_dph_per_c = st.column_double(c++);
  t.created_utc = st.column_text(c++);
  t.dut_serial = st.column_text(c++);
  t.axis = st.column_text(c++);
  return t;
}

// Every row of `table` for the run, in DUT order, then `order`.
template <class Record>
Result<std::vector<Record>> read_rows(sqlite3* db, const std::string& path, const char* table,
                                      const char* columns, const char* order,
                                      Record (*read)(const Stmt&), int64_t run_id,
                                      std::string_view what) {
  auto st = Stmt::prepare(
      db, path,
      fmt::format("SELECT {} FROM {} x {} WHERE x.run_id = ? ORDER BY {}, x.dut_serial, x.axis{}",
                  internal::qualified(columns, "x"), table, internal::dut_position_join("x"),
                  internal::kDutPositionOrder, order));
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<Record> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) out.push_back(read(*st));
  if (rc != SQLITE_DONE) {
    return sqlite_error(db, path, fmt::format("reading {} of run {}", what, run_id));
  }
  return out;
}

}  // namespace

Result<std::vector<ScaleFactorPointRecord>> ResultStore::scale_factor_points(int64_t run_id) {
  return read_rows(db(), path(), "scale_factor_points", kPointColumns,
                   ", x.sf_sequence, x.repetition, x.rate_dps, x.id", &read_point, run_id,
                   "scale-factor points");
}

Result<std::vector<ScaleFactorFitRecord>> ResultStore::scale_factor_fits(int64_t run_id) {
  return read_rows(db(), path(), "scale_factor_fits", kScaleFactorFitColumns, ", x.sf_sequence",
                   &read_fit, run_id, "scale-factor fits");
}

Result<std::vector<ScaleFactorTemperatureFitRecord>> ResultStore::scale_factor_temperature_fits(
    int64_t run_id) {
  return read_rows(db(), path(), "scale_factor_temperature_fits", kTemperatureFitColumns, "",
                   &read_temperature_fit, run_id, "scale-factor temperature fits");
}

Result<std::optional<ScaleFactorTemperatureFitRecord>> ResultStore::scale_factor_temperature_fit(
    int64_t run_id) {
  return scale_factor_temperature_fit(run_id, StreamKey{});
}

Result<std::optional<ScaleFactorTemperatureFitRecord>> ResultStore::scale_factor_temperature_fit(
    int64_t run_id, const StreamKey& stream) {
  const std::string what =
      fmt::format("reading the scale-factor temperature fit of run {}", run_id);
  auto key = internal::result_key(db(), path(), run_id, stream.dut_serial, stream.axis, what);
  if (!key) return key.error();
  // The series' row; a row stored before v8 (axis '') when the axis is
  // the DUT's primary one.
  auto st = Stmt::prepare(db(), path(),
                          fmt::format("SELECT {} FROM scale_factor_temperature_fits WHERE run_id "
                                      "= ? AND dut_serial = ? AND (axis = ? OR (? AND axis = '')) "
                                      "ORDER BY axis = '' LIMIT 1",
                                      kTemperatureFitColumns));
  if (!st) return st.error();
  st->bind(1, run_id);
  st->bind(2, std::string_view(key->serial));
  st->bind(3, std::string_view(key->axis));
  st->bind(4, key->primary ? 1 : 0);
  const int rc = st->step();
  if (rc == SQLITE_DONE) return std::optional<ScaleFactorTemperatureFitRecord>();
  if (rc != SQLITE_ROW) return sqlite_error(db(), path(), what);
  return std::optional<ScaleFactorTemperatureFitRecord>(read_temperature_fit(*st));
}

}  // namespace gyrotherm::storage
