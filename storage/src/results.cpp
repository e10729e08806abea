// ResultStore (results.h): Table I rows (segment_stats), Allan deviations
// (schema v4) and stored drift-model fits. The scale factor is in
// scale_factor.cpp.
#include "gyrotherm/storage/results.h"

#include <fmt/format.h>
#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <utility>

#include "duts_internal.h"
#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;
using internal::Transaction;

namespace {

constexpr const char* kStatsColumns =
    "segment_id, run_id, segment_index, setpoint_c, n, duration_s, temp_mean_c, bias_mean_dph, "
    "bias_std_dph, bias_std_ma_dph, bias_mean_earth_removed_dph, bin_s, ma_window, "
    "earth_rate_dph, t_from_s, t_to_s, computed_utc, dut_serial, axis, coverage_samples, "
    "coverage_expected, coverage, longest_gap_s, quality, quality_reasons_json, bias_u_dph, "
    "bias_u_expanded_dph, bias_u_k, bias_u_dof, bias_u_floor_dph, bias_u_random_walk, "
    "bias_u_note";

void bind_bias_u(Stmt& st, int& i, const SegmentStatsRecord& s) {
  if (const auto& u = s.bias_u) {
    st.bind(i++, u->u_dph);
    st.bind(i++, u->expanded_dph);
    st.bind(i++, u->k);
    st.bind(i++, std::min(u->dof, kMaxStoredDof));
    st.bind(i++, u->floor_dph);
    st.bind(i++, static_cast<int64_t>(u->random_walk_dominated));
  } else {
    for (int k = 0; k < 6; ++k) st.bind_null(i++);
  }
  st.bind(i++, std::string_view(s.bias_u_note));
}

void read_bias_u(const Stmt& st, int& c, SegmentStatsRecord& r) {
  const std::optional<double> u = st.column_optional_double(c);
  if (u) {
    BiasUncertainty b;
    b.u_dph = *u;
    b.expanded_dph = st.column_double(c + 1);
    b.k = st.column_double(c + 2);
    b.dof = st.column_double(c + 3);
    b.floor_dph = st.column_double(c + 4);
    b.random_walk_dominated = st.column_optional_int64(c + 5).value_or(0) != 0;
    r.bias_u = b;
  }
  c += 6;
  r.bias_u_note = st.column_text(c++);
}

}  // namespace

Database& ResultStore::self() { return static_cast<Database&>(*this); }
sqlite3* ResultStore::db() { return self().db_; }
const std::string& ResultStore::path() { return self().path_; }

Status ResultStore::put_segment_stats(const SegmentStatsRecord& s) {
  const std::string what = fmt::format("storing statistics of segment {}", s.segment_id);
  auto key = internal::result_key(db(), path(), s.run_id, s.dut_serial, s.axis, what);
  if (!key) return key.error();
  auto st =
      Stmt::prepare(db(), path(),
                    fmt::format("INSERT OR REPLACE INTO segment_stats({}) "
                                "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
                                "?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                                kStatsColumns));
  if (!st) return st.error();
  int i = 1;
  st->bind(i++, s.segment_id);
  st->bind(i++, s.run_id);
  st->bind(i++, s.segment_index);
  st->bind(i++, s.setpoint_c);
  st->bind(i++, s.n);
  st->bind(i++, s.duration_s);
  st->bind(i++, s.temp_mean_c);
  st->bind(i++, s.bias_mean_dph);
  st->bind(i++, s.bias_std_dph);
  st->bind(i++, s.bias_std_ma_dph);
  st->bind(i++, s.bias_mean_earth_removed_dph);
  st->bind(i++, s.bin_s);
  st->bind(i++, s.ma_window);
  st->bind(i++, s.earth_rate_dph);
  st->bind(i++, s.t_from_s);
  st->bind(i++, s.t_to_s);
  st->bind(i++, std::string_view(self().utc_or_now(s.computed_utc)));
  st->bind(i++, std::string_view(key->serial));
  st->bind(i++, std::string_view(key->axis));
  internal::bind_quality(*st, i, s.quality);
  i += internal::kQualityColumnCount;
  bind_bias_u(*st, i, s);
  internal::WriteScope tx(db(), path(), "put_segment_stats");
  if (Status s = tx.begin(); !s) return s;
  if (Status s = expect_done(*st, db(), path(), what); !s) return s;
  if (key->primary && !key->axis.empty()) {
    // The row stored before v8 for this DUT (axis '' = its primary axis)
    // is this series: the new row replaces it.
    auto legacy = Stmt::prepare(db(), path(),
                                "DELETE FROM segment_stats WHERE segment_id = ? AND "
                                "dut_serial = ? AND axis = ''");
    if (!legacy) return legacy.error();
    legacy->bind(1, s.segment_id);
    legacy->bind(2, std::string_view(key->serial));
    if (Status e = expect_done(*legacy, db(), path(), what); !e) return e;
  }
  return tx.commit();
}

Result<std::vector<SegmentStatsRecord>> ResultStore::segment_stats(std::optional<int64_t> run_id) {
  const std::string columns = internal::qualified(kStatsColumns, "s");
  auto st = Stmt::prepare(
      db(), path(),
      fmt::format("SELECT {} FROM segment_stats s {} WHERE ?1 IS NULL OR s.run_id = ?1 "
                  "ORDER BY s.run_id, s.segment_index, s.segment_id, {}, s.dut_serial, s.axis",
                  columns, internal::dut_position_join("s"), internal::kDutPositionOrder));
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<SegmentStatsRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    SegmentStatsRecord r;
    int c = 0;
    r.segment_id = st->column_int64(c++);
    r.run_id = st->column_int64(c++);
    r.segment_index = static_cast<int>(st->column_int64(c++));
    r.setpoint_c = st->column_double(c++);
    r.n = st->column_int64(c++);
    r.duration_s = st->column_double(c++);
    r.temp_mean_c = st->column_double(c++);
    r.bias_mean_dph = st->column_double(c++);
    r.bias_std_dph = st->column_double(c++);
    r.bias_std_ma_dph = st->column_double(c++);
    r.bias_mean_earth_removed_dph = st->column_double(c++);
    r.bin_s = st->column_double(c++);
    r.ma_window = static_cast<int>(st->column_int64(c++));
    r.earth_rate_dph = st->column_double(c++);
    r.t_from_s = st->column_double(c++);
    r.t_to_s = st->column_double(c++);
    r.computed_utc = st->column_text(c++);
    r.dut_serial = st->column_text(c++);
    r.axis = st->column_text(c++);
    r.quality = internal::read_quality(*st, c);
    c += internal::kQualityColumnCount;
    read_bias_u(*st, c, r);
    out.push_back(std::move(r));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db(), path(), "reading segment statistics");
  return out;
}

namespace {

constexpr const char* kAllanColumns =
    "id, run_id, segment_id, segment_index, t_from_s, t_to_s, taus, tau0_s, n_samples, "
    "curve_json, angle_random_walk_dprh, bias_instability_dph, bias_instability_tau_s, "
    "rate_random_walk_dphprh, bias_instability_method, inputs_json, computed_utc, dut_serial, "
    "axis, coverage_samples, coverage_expected, coverage, longest_gap_s, quality, "
    "quality_reasons_json";

// The curve's arrays, in the order of curve_json.
struct AllanCurveField {
  const char* name;
  std::vector<double> AllanRecord::*values;
};
constexpr AllanCurveField kAllanCurve[] = {{"tau_s", &AllanRecord::tau_s},
                                           {"adev_dph", &AllanRecord::adev_dph},
                                           {"adev_lo_dph", &AllanRecord::adev_lo_dph},
                                           {"adev_hi_dph", &AllanRecord::adev_hi_dph}};

std::string allan_label(const AllanRecord& a) {
  if (a.dut_serial.empty() && a.axis.empty()) {
    return fmt::format("Allan deviation of run {} step {} (taus '{}')", a.run_id, a.segment_index,
                       a.taus);
  }
  return fmt::format("Allan deviation of run {} step {} DUT '{}' axis '{}' (taus '{}')", a.run_id,
                     a.segment_index, a.dut_serial, a.axis, a.taus);
}

// The curve as JSON, or an error naming the field (and index) that cannot be
// stored: JSON has no NaN or infinity, and the arrays must line up.
Result<std::string> allan_curve_json(const AllanRecord& a, const std::string& path) {
  const auto bad = [&](const std::string& why) {
    return Error::Permanent(fmt::format("storage: {}: storing {}: {}", path, allan_label(a), why));
  };
  const std::size_t n = a.tau_s.size();
  nlohmann::ordered_json curve = nlohmann::ordered_json::object();  // keys in documented order
  for (const AllanCurveField& f : kAllanCurve) {
    const std::vector<double>& values = a.*f.values;
    if (values.size() != n) {
      return bad(
          fmt::format("{} has {} values but tau_s has {} (the arrays must have the same "
                      "length)",
                      f.name, values.size(), n));
    }
    for (std::size_t i = 0; i < values.size(); ++i) {
      if (!std::isfinite(values[i])) {
        return bad(
            fmt::format("{}[{}] is {} (only finite numbers can be stored)", f.name, i, values[i]));
      }
    }
    curve[f.name] = values;
  }
  return curve.dump();
}

Status check_allan_scalars(const AllanRecord& a, const std::string& path) {
  const auto bad = [&](const char* field, double v) {
    return Error::Permanent(
        fmt::format("storage: {}: storing {}: {} is {} (only finite numbers "
                    "can be stored; leave a noise term unset instead)",
                    path, allan_label(a), field, v));
  };
  const std::pair<const char*, double> required[] = {
      {"t_from_s", a.t_from_s}, {"t_to_s", a.t_to_s}, {"tau0_s", a.tau0_s}};
  for (const auto& [field, v] : required) {
    if (!std::isfinite(v)) return bad(field, v);
  }
  const std::pair<const char*, const std::optional<double>*> optional[] = {
      {"angle_random_walk_dprh", &a.angle_random_walk_dprh},
      {"bias_instability_dph", &a.bias_instability_dph},
      {"bias_instability_tau_s", &a.bias_instability_tau_s},
      {"rate_random_walk_dphprh", &a.rate_random_walk_dphprh}};
  for (const auto& [field, v] : optional) {
    if (v->has_value() && !std::isfinite(**v)) return bad(field, **v);
  }
  if (a.taus.empty()) {
    return Error::Permanent(
        fmt::format("storage: {}: storing {}: taus is empty", path, allan_label(a)));
  }
  return Status::Ok();
}

Status read_allan_curve(AllanRecord& r, const std::string& text, const std::string& path) {
  const auto bad = [&](const std::string& why) {
    return Error::Permanent(fmt::format("storage: {}: allan row {} (run {} step {}): curve_json {}",
                                        path, r.id, r.run_id, r.segment_index, why));
  };
  const nlohmann::json curve = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (curve.is_discarded()) return bad("is not valid JSON");
  if (!curve.is_object()) return bad("is not a JSON object");
  for (const AllanCurveField& f : kAllanCurve) {
    const auto it = curve.find(f.name);
    if (it == curve.end() || !it->is_array()) {
      return bad(fmt::format("has no array '{}'", f.name));
    }
    std::vector<double>& values = r.*f.values;
    values.reserve(it->size());
    for (const nlohmann::json& v : *it) {
      if (!v.is_number()) {
        return bad(fmt::format("'{}'[{}] is not a number", f.name, values.size()));
      }
      values.push_back(v.get<double>());
    }
    if (values.size() != r.tau_s.size()) {
      return bad(fmt::format("'{}' has {} values but 'tau_s' has {}", f.name, values.size(),
                             r.tau_s.size()));
    }
  }
  return Status::Ok();
}

}  // namespace

Result<int64_t> ResultStore::put_allan(const AllanRecord& a) {
  if (Status s = check_allan_scalars(a, path()); !s) return s.error();
  auto curve = allan_curve_json(a, path());
  if (!curve) return curve.error();
  const std::string inputs = a.inputs_json.empty() ? "{}" : a.inputs_json;
  if (!nlohmann::json::accept(inputs)) {
    return Error::Permanent(fmt::format("storage: {}: storing {}: inputs_json is not valid JSON",
                                        path(), allan_label(a)));
  }
  auto key = internal::result_key(db(), path(), a.run_id, a.dut_serial, a.axis,
                                  fmt::format("storing {}", allan_label(a)));
  if (!key) return key.error();
  // An upsert keeps the row's id when a recomputation replaces it.
  auto st = Stmt::prepare(
      db(), path(),
      "INSERT INTO allan(run_id, segment_id, segment_index, t_from_s, t_to_s, taus, tau0_s, "
      "n_samples, curve_json, angle_random_walk_dprh, bias_instability_dph, "
      "bias_instability_tau_s, rate_random_walk_dphprh, bias_instability_method, inputs_json, "
      "computed_utc, dut_serial, axis, coverage_samples, coverage_expected, coverage, "
      "longest_gap_s, quality, quality_reasons_json) VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
      "?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
      "ON CONFLICT(run_id, segment_index, taus, dut_serial, axis) DO UPDATE SET segment_id = "
      "excluded.segment_id, "
      "t_from_s = excluded.t_from_s, t_to_s = excluded.t_to_s, tau0_s = excluded.tau0_s, "
      "n_samples = excluded.n_samples, curve_json = excluded.curve_json, "
      "angle_random_walk_dprh = excluded.angle_random_walk_dprh, "
      "bias_instability_dph = excluded.bias_instability_dph, "
      "bias_instability_tau_s = excluded.bias_instability_tau_s, "
      "rate_random_walk_dphprh = excluded.rate_random_walk_dphprh, "
      "bias_instability_method = excluded.bias_instability_method, "
      "inputs_json = excluded.inputs_json, computed_utc = excluded.computed_utc, "
      "coverage_samples = excluded.coverage_samples, coverage_expected = "
      "excluded.coverage_expected, coverage = excluded.coverage, longest_gap_s = "
      "excluded.longest_gap_s, quality = excluded.quality, quality_reasons_json = "
      "excluded.quality_reasons_json "
      "RETURNING id");
  if (!st) return st.error();
  int i = 1;
  st->bind(i++, a.run_id);
  if (a.segment_id == 0) {
    st->bind_null(i++);
  } else {
    st->bind(i++, a.segment_id);
  }
  st->bind(i++, a.segment_index);
  st->bind(i++, a.t_from_s);
  st->bind(i++, a.t_to_s);
  st->bind(i++, std::string_view(a.taus));
  st->bind(i++, a.tau0_s);
  st->bind(i++, a.n_samples);
  st->bind(i++, std::string_view(*curve));
  st->bind(i++, a.angle_random_walk_dprh);
  st->bind(i++, a.bias_instability_dph);
  st->bind(i++, a.bias_instability_tau_s);
  st->bind(i++, a.rate_random_walk_dphprh);
  st->bind(i++, std::string_view(a.bias_instability_method));
  st->bind(i++, std::string_view(inputs));
  st->bind(i++, std::string_view(self().utc_or_now(a.computed_utc)));
  st->bind(i++, std::string_view(key->serial));
  st->bind(i++, std::string_view(key->axis));
  internal::bind_quality(*st, i, a.quality);
  const std::string what = fmt::format("storing {}", allan_label(a));
  internal::WriteScope tx(db(), path(), "put_allan");
  if (Status s = tx.begin(); !s) return s.error();
  if (st->step() != SQLITE_ROW) return sqlite_error(db(), path(), what);
  const int64_t id = st->column_int64(0);
  if (Status s = expect_done(*st, db(), path(), what); !s) return s.error();
  if (key->primary && !key->axis.empty()) {
    // The row stored before v8 for this DUT (axis '' = its primary axis)
    // is this series: the new row replaces it.
    auto legacy = Stmt::prepare(db(), path(),
                                "DELETE FROM allan WHERE run_id = ? AND segment_index = ? AND "
                                "taus = ? AND dut_serial = ? AND axis = ''");
    if (!legacy) return legacy.error();
    legacy->bind(1, a.run_id);
    legacy->bind(2, a.segment_index);
    legacy->bind(3, std::string_view(a.taus));
    legacy->bind(4, std::string_view(key->serial));
    if (Status s = expect_done(*legacy, db(), path(), what); !s) return s.error();
  }
  if (Status s = tx.commit(); !s) return s.error();
  return id;
}

Result<std::vector<AllanRecord>> ResultStore::allan(int64_t run_id) {
  auto st =
      Stmt::prepare(db(), path(),
                    fmt::format("SELECT {} FROM allan a {} WHERE a.run_id = ? "
                                "ORDER BY a.segment_index, {}, a.dut_serial, a.axis, a.taus",
                                internal::qualified(kAllanColumns, "a"),
                                internal::dut_position_join("a"), internal::kDutPositionOrder));
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<AllanRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    AllanRecord r;
    int c = 0;
    r.id = st->column_int64(c++);
    r.run_id = st->column_int64(c++);
    r.segment_id = st->column_optional_int64(c++).value_or(0);
    r.segment_index = static_cast<int>(st->column_int64(c++));
    r.t_from_s = st->column_double(c++);
    r.t_to_s = st->column_double(c++);
    r.taus = st->column_text(c++);
    r.tau0_s = st->column_double(c++);
    r.n_samples = st->column_int64(c++);
    const std::string curve = st->column_text(c++);
    r.angle_random_walk_dprh = st->column_optional_double(c++);
    r.bias_instability_dph = st->column_optional_double(c++);
    r.bias_instability_tau_s = st->column_optional_double(c++);
    r.rate_random_walk_dphprh = st->column_optional_double(c++);
    r.bias_instability_method = st->column_text(c++);
    r.inputs_json = st->column_text(c++);
    r.computed_utc = st->column_text(c++);
    r.dut_serial = st->column_text(c++);
    r.axis = st->column_text(c++);
    r.quality = internal::read_quality(*st, c);
    if (Status s = read_allan_curve(r, curve, path()); !s) return s.error();
    out.push_back(std::move(r));
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db(), path(), fmt::format("reading Allan deviations of run {}", run_id));
  }
  return out;
}

namespace {

constexpr const char* kDriftFitColumns =
    "id, model, form, n, coefficients_json, standard_errors_json, residual_std_dph, r_squared, "
    "inputs_json, computed_utc, dut_serial, axis, coverage_samples, coverage_expected, coverage, "
    "longest_gap_s, quality, quality_reasons_json";

}  // namespace

Result<int64_t> ResultStore::add_fit(const FitRecord& fit) {
  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s.error();
  // The DUT and axis as of the first run fitted ("" = its first DUT and
  // that DUT's primary axis); a fit of no run keeps what it is given.
  internal::ResultKey key{fit.dut_serial, fit.axis};
  if (!fit.run_ids.empty()) {
    auto resolved = internal::result_key(db(), path(), fit.run_ids.front(), fit.dut_serial,
                                         fit.axis, "storing a fit");
    if (!resolved) return resolved.error();
    key = std::move(*resolved);
  }
  auto st = Stmt::prepare(db(), path(),
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
  st->bind(9, self().utc_or_now(fit.computed_utc));
  st->bind(10, std::string_view(key.serial));
  st->bind(11, std::string_view(key.axis));
  internal::bind_quality(*st, 12, fit.quality);
  if (st->step() != SQLITE_DONE) return sqlite_error(db(), path(), "storing a fit");
  const int64_t id = sqlite3_last_insert_rowid(db());
  auto link =
      Stmt::prepare(db(), path(), "INSERT OR IGNORE INTO fit_runs(run_id, fit_id) VALUES(?, ?)");
  if (!link) return link.error();
  for (int64_t run_id : fit.run_ids) {
    link->bind(1, run_id);
    link->bind(2, id);
    if (link->step() != SQLITE_DONE) return sqlite_error(db(), path(), "storing a fit's runs");
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
      fmt::format("SELECT {} FROM fits WHERE dut_serial = ? ORDER BY id DESC", kDriftFitColumns));
  if (!st) return st.error();
  st->bind(1, std::string_view(serial));
  return read_fits(db, path, *st);
}

}  // namespace internal

Result<std::vector<FitRecord>> ResultStore::fits(int64_t run_id) {
  auto st = Stmt::prepare(db(), path(),
                          fmt::format("SELECT {} FROM fits WHERE id IN (SELECT fit_id FROM "
                                      "fit_runs WHERE run_id = ?) ORDER BY id DESC",
                                      kDriftFitColumns));
  if (!st) return st.error();
  st->bind(1, run_id);
  return read_fits(db(), path(), *st);
}

Result<std::optional<FitRecord>> ResultStore::fit(int64_t fit_id) {
  auto st = Stmt::prepare(db(), path(),
                          fmt::format("SELECT {} FROM fits WHERE id = ?", kDriftFitColumns));
  if (!st) return st.error();
  st->bind(1, fit_id);
  auto fits = read_fits(db(), path(), *st);
  if (!fits) return fits.error();
  if (fits->empty()) return std::optional<FitRecord>();
  return std::optional<FitRecord>(std::move(fits->front()));
}

}  // namespace gyrotherm::storage
