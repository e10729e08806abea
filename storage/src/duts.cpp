// DutStore (duts.h): devices under test (schema v8; docs/storage.md "Devices
// under test"): the station's registry of gyros by serial number, the DUTs of
// each run with their channels, and the resolution of a StreamKey to one DUT
// and axis of a run.
#include "gyrotherm/storage/duts.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <set>

#include "duts_internal.h"
#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;

namespace internal {

Status WriteScope::begin() {
  nested_ = sqlite3_get_autocommit(db_) == 0;
  Status s =
      internal::exec(db_, path_, nested_ ? fmt::format("SAVEPOINT {}", name_) : "BEGIN IMMEDIATE");
  open_ = s.ok();
  return s;
}

Status WriteScope::commit() {
  Status s =
      internal::exec(db_, path_, nested_ ? fmt::format("RELEASE SAVEPOINT {}", name_) : "COMMIT");
  if (s.ok()) open_ = false;
  return s;
}

WriteScope::~WriteScope() {
  if (!open_) return;
  if (nested_) {
    (void)internal::exec(db_, path_,
                         fmt::format("ROLLBACK TO SAVEPOINT {0}; RELEASE SAVEPOINT {0}", name_));
  } else {
    (void)internal::exec(db_, path_, "ROLLBACK");
  }
}

std::string strings_json(const std::vector<std::string>& values) {
  return nlohmann::json(values).dump();
}

Result<std::vector<std::string>> strings_from_json(const std::string& text,
                                                   const std::string& where) {
  if (text.empty()) return std::vector<std::string>{};
  const nlohmann::json j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_array()) {
    return Error::Permanent(fmt::format("{} is not a JSON array: '{}'", where, text));
  }
  std::vector<std::string> out;
  for (const auto& v : j) {
    if (!v.is_string()) {
      return Error::Permanent(fmt::format("{}[{}] is not a string: '{}'", where, out.size(), text));
    }
    out.push_back(v.get<std::string>());
  }
  return out;
}

Result<std::optional<std::pair<std::string, std::string>>> first_dut_of_run(sqlite3* db,
                                                                            const std::string& path,
                                                                            int64_t run_id) {
  auto st = Stmt::prepare(db, path,
                          "SELECT d.serial, rd.primary_axis FROM run_duts rd JOIN duts d ON "
                          "d.id = rd.dut_id WHERE rd.run_id = ? ORDER BY rd.position LIMIT 1");
  if (!st) return st.error();
  st->bind(1, run_id);
  const int rc = st->step();
  using Out = std::optional<std::pair<std::string, std::string>>;
  if (rc == SQLITE_DONE) return Out();
  if (rc != SQLITE_ROW) {
    return sqlite_error(db, path, fmt::format("reading the first DUT of run {}", run_id));
  }
  return Out(std::make_pair(st->column_text(0), st->column_text(1)));
}

Result<ResultKey> result_key(sqlite3* db, const std::string& path, int64_t run_id,
                             const std::string& serial, const std::string& axis,
                             std::string_view what) {
  auto st = Stmt::prepare(db, path,
                          "SELECT d.serial, rd.primary_axis FROM run_duts rd JOIN duts d ON "
                          "d.id = rd.dut_id WHERE rd.run_id = ? ORDER BY rd.position");
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<std::pair<std::string, std::string>> duts;  // serial, primary axis
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) duts.emplace_back(st->column_text(0), st->column_text(1));
  if (rc != SQLITE_DONE) return sqlite_error(db, path, what);
  // A run without DUTs (results of an older run, tests) stores what it is
  // given: "" is the unnamed gyro; its primary axis is not known.
  if (duts.empty()) return ResultKey{serial, axis, axis.empty()};
  auto it = duts.begin();
  if (!serial.empty()) {
    it = std::find_if(duts.begin(), duts.end(), [&](const auto& d) { return d.first == serial; });
    // A typo would otherwise file results under a gyro that was not there.
    if (it == duts.end()) {
      return Error::Permanent(fmt::format("storage: {}: {}: run {} has no DUT with serial '{}'",
                                          path, what, run_id, serial));
    }
  }
  const std::string& resolved_axis = axis.empty() ? it->second : axis;
  return ResultKey{it->first, resolved_axis, resolved_axis == it->second};
}

std::string dut_position_join(std::string_view alias) {
  return fmt::format(
      " LEFT JOIN duts rd_d ON rd_d.serial = {0}.dut_serial LEFT JOIN run_duts rd_rd ON "
      "rd_rd.run_id = {0}.run_id AND rd_rd.dut_id = rd_d.id ",
      alias);
}

std::string qualified(std::string_view columns, std::string_view alias) {
  std::string out;
  std::size_t from = 0;
  while (from <= columns.size()) {
    std::size_t comma = columns.find(',', from);
    if (comma == std::string_view::npos) comma = columns.size();
    std::string_view c = columns.substr(from, comma - from);
    while (!c.empty() && c.front() == ' ') c.remove_prefix(1);
    out += fmt::format("{}{}.{}", out.empty() ? "" : ", ", alias, c);
    from = comma + 1;
  }
  return out;
}

}  // namespace internal

namespace {

using internal::strings_from_json;
using internal::strings_json;
using internal::WriteScope;

constexpr const char* kRunDutSelect =
    "SELECT rd.run_id, rd.position, d.id, d.serial, d.model, d.first_seen_utc, rd.config_json, "
    "rd.primary_axis, rd.axes_json, rd.rate_hz, rd.seq_modulo FROM run_duts rd "
    "JOIN duts d ON d.id = rd.dut_id ";

Result<RunDutRecord> read_run_dut(const Stmt& st, const std::string& path) {
  RunDutRecord r;
  int c = 0;
  r.run_id = st.column_int64(c++);
  r.position = static_cast<int>(st.column_int64(c++));
  r.dut.id = st.column_int64(c++);
  r.dut.serial = st.column_text(c++);
  r.dut.model = st.column_text(c++);
  r.dut.first_seen_utc = st.column_text(c++);
  r.config_json = st.column_text(c++);
  r.primary_axis = st.column_text(c++);
  auto axes = strings_from_json(
      st.column_text(c++), fmt::format("storage: {}: run_duts row (run {}, DUT '{}'): axes_json",
                                       path, r.run_id, r.dut.serial));
  if (!axes) return axes.error();
  r.axes = std::move(*axes);
  r.rate_hz = st.column_optional_double(c++).value_or(0.0);
  r.seq_modulo = static_cast<uint32_t>(st.column_int64(c++));
  return r;
}

// Fills each record's channels (by idx).
Status read_channels(sqlite3* db, const std::string& path, std::vector<RunDutRecord>& duts) {
  auto st = Stmt::prepare(db, path,
                          "SELECT id, idx, name, unit, kind, axis, scale FROM channels "
                          "WHERE run_id = ? AND dut_id = ? ORDER BY idx");
  if (!st) return st.error();
  for (RunDutRecord& d : duts) {
    st->reset();
    st->bind(1, d.run_id);
    st->bind(2, d.dut.id);
    int rc;
    while ((rc = st->step()) == SQLITE_ROW) {
      ChannelRecord ch;
      ch.id = st->column_int64(0);
      ch.run_id = d.run_id;
      ch.dut_id = d.dut.id;
      ch.index = static_cast<int>(st->column_int64(1));
      ch.spec.name = st->column_text(2);
      ch.spec.unit = st->column_text(3);
      const std::string kind = st->column_text(4);
      const auto k = channel_kind_from_string(kind);
      if (!k) {
        return Error::Permanent(fmt::format(
            "storage: {}: channels row {} (run {}, DUT '{}', channel '{}'): unknown kind '{}' "
            "(rate, accel, temperature, status, other)",
            path, ch.id, d.run_id, d.dut.serial, ch.spec.name, kind));
      }
      ch.spec.kind = *k;
      ch.spec.axis = st->column_text(5);
      ch.spec.scale = st->column_double(6);
      d.channels.push_back(std::move(ch));
    }
    if (rc != SQLITE_DONE) {
      return sqlite_error(
          db, path,
          fmt::format("reading the channels of DUT '{}' in run {}", d.dut.serial, d.run_id));
    }
  }
  return Status::Ok();
}

// Refuses a DUT record that cannot be stored, naming the field.
Status check_run_dut(const RunDutRecord& d, int64_t run_id, const std::string& what) {
  const auto bad = [&](const std::string& why) {
    return Error::Permanent(fmt::format("{}: {}", what, why));
  };
  if (d.run_id != 0 && d.run_id != run_id) {
    return bad(fmt::format("the record belongs to run {}", d.run_id));
  }
  if (d.position < 0) return bad(fmt::format("position is {} (from 0)", d.position));
  if (d.channels.size() > kMaxChannels) {
    return bad(fmt::format("{} channels, at most {}", d.channels.size(), kMaxChannels));
  }
  std::set<std::string> names;
  for (std::size_t i = 0; i < d.channels.size(); ++i) {
    const ChannelRecord& ch = d.channels[i];
    if (ch.spec.name.empty()) return bad(fmt::format("channel {} has no name", i));
    if (!names.insert(ch.spec.name).second) {
      return bad(fmt::format("channel name '{}' is used twice", ch.spec.name));
    }
    // index is the channel's place in DutFrame::raw: the list's order.
    if (ch.index != 0 && ch.index != static_cast<int>(i)) {
      return bad(fmt::format("channel '{}' has index {} but is number {} in the list", ch.spec.name,
                             ch.index, i));
    }
    if (!std::isfinite(ch.spec.scale)) {
      return bad(fmt::format("channel '{}' has scale {}", ch.spec.name, ch.spec.scale));
    }
  }
  if (!d.config_json.empty()) {
    const nlohmann::json j =
        nlohmann::json::parse(d.config_json, nullptr, /*allow_exceptions=*/false);
    if (j.is_discarded() || !j.is_object()) return bad("config_json is not a JSON object");
  }
  return Status::Ok();
}

}  // namespace

Database& DutStore::self() { return static_cast<Database&>(*this); }
sqlite3* DutStore::db() { return self().db_; }
const std::string& DutStore::path() { return self().path_; }

Result<RunDutRecord> DutStore::add_run_dut(int64_t run_id, const RunDutRecord& in) {
  const std::string what =
      fmt::format("storage: {}: registering DUT '{}' in run {}", path(), in.dut.serial, run_id);
  if (Status s = check_run_dut(in, run_id, what); !s) return s.error();

  WriteScope tx(db(), path(), "add_run_dut");
  if (Status s = tx.begin(); !s) return s.error();
  {
    auto st = Stmt::prepare(db(), path(), "SELECT 1 FROM runs WHERE id = ?");
    if (!st) return st.error();
    st->bind(1, run_id);
    const int rc = st->step();
    if (rc == SQLITE_DONE) return Error::Permanent(fmt::format("{}: no such run", what));
    if (rc != SQLITE_ROW) return sqlite_error(db(), path(), what);
  }
  // The registry: created on first sight; a model given updates it (a
  // serial first seen in an old run without model gets one later).
  auto dut = Stmt::prepare(db(), path(),
                           "INSERT INTO duts(serial, model, first_seen_utc) VALUES(?, ?, ?) "
                           "ON CONFLICT(serial) DO UPDATE SET model = CASE WHEN excluded.model "
                           "!= '' THEN excluded.model ELSE duts.model END RETURNING id");
  if (!dut) return dut.error();
  dut->bind(1, std::string_view(in.dut.serial));
  dut->bind(2, std::string_view(in.dut.model));
  dut->bind(3, std::string_view(self().utc_or_now(in.dut.first_seen_utc)));
  if (dut->step() != SQLITE_ROW) return sqlite_error(db(), path(), what);
  const int64_t dut_id = dut->column_int64(0);
  if (Status s = expect_done(*dut, db(), path(), what); !s) return s.error();

  auto taken = Stmt::prepare(db(), path(),
                             "SELECT rd.dut_id, rd.position, d.serial FROM run_duts rd JOIN duts "
                             "d ON d.id = rd.dut_id WHERE rd.run_id = ? AND (rd.dut_id = ? OR "
                             "rd.position = ?)");
  if (!taken) return taken.error();
  taken->bind(1, run_id);
  taken->bind(2, dut_id);
  taken->bind(3, in.position);
  bool present = false;
  int rc;
  while ((rc = taken->step()) == SQLITE_ROW) {
    if (taken->column_int64(0) == dut_id) {
      present = true;  // crash resume: registered before
    } else {
      return Error::Permanent(
          fmt::format("{}: position {} is DUT '{}''s", what, in.position, taken->column_text(2)));
    }
  }
  if (rc != SQLITE_DONE) return sqlite_error(db(), path(), what);

  if (!present) {
    auto ins = Stmt::prepare(db(), path(),
                             "INSERT INTO run_duts(run_id, dut_id, position, primary_axis, "
                             "axes_json, rate_hz, seq_modulo, config_json) "
                             "VALUES(?, ?, ?, ?, ?, ?, ?, ?)");
    if (!ins) return ins.error();
    int i = 1;
    ins->bind(i++, run_id);
    ins->bind(i++, dut_id);
    ins->bind(i++, in.position);
    ins->bind(i++, std::string_view(in.primary_axis));
    ins->bind(i++, std::string_view(strings_json(in.axes)));
    if (in.rate_hz > 0) {
      ins->bind(i++, in.rate_hz);
    } else {
      ins->bind_null(i++);
    }
    ins->bind(i++, static_cast<int64_t>(in.seq_modulo));
    ins->bind(i++, std::string_view(in.config_json.empty() ? "{}" : in.config_json));
    if (Status s = expect_done(*ins, db(), path(), what); !s) return s.error();

    auto ch = Stmt::prepare(db(), path(),
                            "INSERT INTO channels(run_id, dut_id, idx, name, unit, kind, axis, "
                            "scale) VALUES(?, ?, ?, ?, ?, ?, ?, ?)");
    if (!ch) return ch.error();
    for (std::size_t k = 0; k < in.channels.size(); ++k) {
      const ChannelSpec& spec = in.channels[k].spec;
      ch->reset();
      int j = 1;
      ch->bind(j++, run_id);
      ch->bind(j++, dut_id);
      ch->bind(j++, static_cast<int64_t>(k));
      ch->bind(j++, std::string_view(spec.name));
      ch->bind(j++, std::string_view(spec.unit));
      ch->bind(j++, to_string(spec.kind));
      ch->bind(j++, std::string_view(spec.axis));
      ch->bind(j++, spec.scale);
      if (Status s =
              expect_done(*ch, db(), path(), fmt::format("{}: channel '{}'", what, spec.name));
          !s) {
        return s.error();
      }
    }
  }

  auto st = Stmt::prepare(db(), path(),
                          std::string(kRunDutSelect) + "WHERE rd.run_id = ? AND rd.dut_id = ?");
  if (!st) return st.error();
  st->bind(1, run_id);
  st->bind(2, dut_id);
  if (st->step() != SQLITE_ROW) return sqlite_error(db(), path(), what);
  auto rec = read_run_dut(*st, path());
  if (!rec) return rec.error();
  std::vector<RunDutRecord> one{std::move(*rec)};
  if (Status s = read_channels(db(), path(), one); !s) return s.error();
  if (Status s = tx.commit(); !s) return s.error();
  return std::move(one.front());
}

Result<std::vector<RunDutRecord>> DutStore::run_duts(int64_t run_id) {
  auto st = Stmt::prepare(db(), path(),
                          std::string(kRunDutSelect) + "WHERE rd.run_id = ? ORDER BY rd.position");
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<RunDutRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    auto rec = read_run_dut(*st, path());
    if (!rec) return rec.error();
    out.push_back(std::move(*rec));
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db(), path(), fmt::format("reading the DUTs of run {}", run_id));
  }
  if (Status s = read_channels(db(), path(), out); !s) return s.error();
  return out;
}

Result<std::vector<DutRecord>> DutStore::duts() {
  auto st = Stmt::prepare(db(), path(),
                          "SELECT id, serial, model, first_seen_utc FROM duts ORDER BY serial");
  if (!st) return st.error();
  std::vector<DutRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    out.push_back(
        DutRecord{st->column_int64(0), st->column_text(1), st->column_text(2), st->column_text(3)});
  }
  if (rc != SQLITE_DONE) return sqlite_error(db(), path(), "reading the DUTs");
  return out;
}

Result<std::optional<DutRecord>> DutStore::dut(std::string_view serial) {
  auto st = Stmt::prepare(db(), path(),
                          "SELECT id, serial, model, first_seen_utc FROM duts WHERE serial = ?");
  if (!st) return st.error();
  st->bind(1, serial);
  const int rc = st->step();
  if (rc == SQLITE_DONE) return std::optional<DutRecord>();
  if (rc != SQLITE_ROW) return sqlite_error(db(), path(), fmt::format("reading DUT '{}'", serial));
  return std::optional<DutRecord>(
      DutRecord{st->column_int64(0), st->column_text(1), st->column_text(2), st->column_text(3)});
}

Result<std::pair<RunDutRecord, std::string>> DutStore::resolve_stream(int64_t run_id,
                                                                      const StreamKey& key) {
  auto duts = run_duts(run_id);
  if (!duts) return duts.error();
  if (duts->empty()) {
    return Error::Permanent(fmt::format("storage: {}: run {} has no DUTs", path(), run_id));
  }
  auto it = duts->begin();
  if (!key.dut_serial.empty()) {
    it = std::find_if(duts->begin(), duts->end(),
                      [&](const RunDutRecord& d) { return d.dut.serial == key.dut_serial; });
    if (it == duts->end()) {
      std::vector<std::string> serials;
      for (const auto& d : *duts) serials.push_back(fmt::format("'{}'", d.dut.serial));
      return Error::Permanent(fmt::format("storage: {}: run {} has no DUT '{}' (its DUTs: {})",
                                          path(), run_id, key.dut_serial,
                                          fmt::join(serials, ", ")));
    }
  }
  if (key.axis.empty()) {
    std::string axis = it->primary_axis;
    return std::make_pair(std::move(*it), std::move(axis));
  }
  // A rate axis of the DUT: its primary axis, one it analyses, or the axis
  // of one of its rate channels.
  std::set<std::string> axes(it->axes.begin(), it->axes.end());
  if (!it->primary_axis.empty()) axes.insert(it->primary_axis);
  for (const auto& ch : it->channels) {
    if (ch.spec.kind == ChannelKind::kRate && !ch.spec.axis.empty()) axes.insert(ch.spec.axis);
  }
  if (!axes.contains(key.axis)) {
    return Error::Permanent(
        fmt::format("storage: {}: DUT '{}' of run {} has no rate axis '{}' "
                    "(its axes: {})",
                    path(), it->dut.serial, run_id, key.axis, fmt::join(axes, ", ")));
  }
  std::string axis = key.axis;
  return std::make_pair(std::move(*it), std::move(axis));
}

Result<DutHistory> DutStore::dut_history(std::string_view serial) {
  auto known = dut(serial);
  if (!known) return known.error();
  if (!*known) {
    return Error::Permanent(fmt::format("storage: {}: no DUT with serial '{}'", path(), serial));
  }
  DutHistory h;
  h.dut = **known;
  // Its runs through run_duts_by_dut; each run's rows through the run's
  // indexes (a run holds a few DUTs: filtering its rows here reads little).
  auto st = Stmt::prepare(db(), path(),
                          std::string(kRunDutSelect) + "WHERE rd.dut_id = ? ORDER BY rd.run_id");
  if (!st) return st.error();
  st->bind(1, h.dut.id);
  std::vector<RunDutRecord> in_runs;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    auto rec = read_run_dut(*st, path());
    if (!rec) return rec.error();
    in_runs.push_back(std::move(*rec));
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db(), path(), fmt::format("reading the runs of DUT '{}'", serial));
  }
  if (Status s = read_channels(db(), path(), in_runs); !s) return s.error();

  const auto mine = [&](const std::string& row_serial) { return row_serial == h.dut.serial; };
  for (RunDutRecord& in_run : in_runs) {
    DutHistory::Run r;
    const int64_t run_id = in_run.run_id;
    auto rec = self().run(run_id);
    if (!rec) return rec.error();
    r.run = std::move(*rec);
    r.run.config_json.clear();
    r.run.config_toml.clear();
    r.run.resume_json.clear();
    auto segs = self().segments(run_id);
    if (!segs) return segs.error();
    r.segments = std::move(*segs);
    auto stats = self().segment_stats(run_id);
    if (!stats) return stats.error();
    for (auto& row : *stats) {
      if (mine(row.dut_serial)) r.stats.push_back(std::move(row));
    }
    auto allan_rows = self().allan(run_id);
    if (!allan_rows) return allan_rows.error();
    for (auto& row : *allan_rows) {
      if (mine(row.dut_serial)) r.allan.push_back(std::move(row));
    }
    auto sf = self().scale_factor_fits(run_id);
    if (!sf) return sf.error();
    for (auto& row : *sf) {
      if (mine(row.dut_serial)) r.scale_factor.push_back(std::move(row));
    }
    r.in_run = std::move(in_run);
    h.runs.push_back(std::move(r));
  }
  auto fits = internal::fits_of_dut(db(), path(), h.dut.serial);
  if (!fits) return fits.error();
  h.fits = std::move(*fits);
  return h;
}

}  // namespace gyrotherm::storage
