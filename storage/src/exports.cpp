// ExportStore (exports.h): the record of calibration exports (schema v5, tables
// `exports` and `export_runs`). begin_export checks and inserts in one
// IMMEDIATE transaction, so two exporters (the daemon's nightly job and a
// catch-up, or two processes) cannot both take a slot or a run.
#include "gyrotherm/storage/exports.h"

#include <fmt/format.h>
#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;
using internal::Transaction;

namespace {

constexpr const char* kExportColumns =
    "id, kind, slot_unix_s, slot_local, state, directory, files_json, started_utc, finished_utc, "
    "message";

// "slot 1774746000 (2026-03-29 02:00 CET)".
std::string slot_name(double slot_unix_s, const std::string& slot_local) {
  if (slot_local.empty()) return fmt::format("slot {}", slot_unix_s);
  return fmt::format("slot {} ({})", slot_unix_s, slot_local);
}

std::string begin_label(const ExportRecord& r) {
  if (r.kind == "nightly") {
    if (!r.slot_unix_s) return "beginning a nightly export";
    return fmt::format("beginning the nightly export of {}",
                       slot_name(*r.slot_unix_s, r.slot_local));
  }
  if (r.kind == "manual") return fmt::format("beginning a manual export to '{}'", r.directory);
  return fmt::format("beginning an export of kind '{}'", r.kind);
}

// The export's runs, ascending.
Result<std::vector<int64_t>> export_run_ids(sqlite3* db, const std::string& path, Stmt& st,
                                            int64_t export_id) {
  st.reset();
  st.bind(1, export_id);
  std::vector<int64_t> ids;
  int rc;
  while ((rc = st.step()) == SQLITE_ROW) ids.push_back(st.column_int64(0));
  if (rc != SQLITE_DONE) {
    return sqlite_error(db, path, fmt::format("reading the runs of export {}", export_id));
  }
  return ids;
}

Result<std::vector<std::string>> parse_files(const std::string& text, int64_t export_id,
                                             const std::string& path) {
  const auto bad = [&](const std::string& why) {
    return Error::Permanent(
        fmt::format("storage: {}: export {}: files_json {}", path, export_id, why));
  };
  const nlohmann::json files = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (files.is_discarded()) return bad("is not valid JSON");
  if (!files.is_array()) return bad("is not a JSON array");
  std::vector<std::string> out;
  out.reserve(files.size());
  for (const nlohmann::json& f : files) {
    if (!f.is_string()) return bad(fmt::format("element {} is not a string", out.size()));
    out.push_back(f.get<std::string>());
  }
  return out;
}

// Every export the WHERE clause (with `?1` bound to `id` when given)
// selects, newest first, with runs and files.
Result<std::vector<ExportRecord>> read_exports(sqlite3* db, const std::string& path,
                                               std::string_view where, std::optional<int64_t> id) {
  auto st = Stmt::prepare(
      db, path, fmt::format("SELECT {} FROM exports {} ORDER BY id DESC", kExportColumns, where));
  if (!st) return st.error();
  if (id) st->bind(1, *id);
  std::vector<ExportRecord> out;
  std::vector<std::string> files_json;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    ExportRecord r;
    int c = 0;
    r.id = st->column_int64(c++);
    r.kind = st->column_text(c++);
    r.slot_unix_s = st->column_optional_double(c++);
    r.slot_local = st->column_text(c++);
    r.state = st->column_text(c++);
    r.directory = st->column_text(c++);
    files_json.push_back(st->column_text(c++));
    r.started_utc = st->column_text(c++);
    r.finished_utc = st->column_text(c++);
    r.message = st->column_text(c++);
    out.push_back(std::move(r));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db, path, "reading exports");
  auto runs =
      Stmt::prepare(db, path, "SELECT run_id FROM export_runs WHERE export_id = ? ORDER BY run_id");
  if (!runs) return runs.error();
  for (std::size_t i = 0; i < out.size(); ++i) {
    auto ids = export_run_ids(db, path, *runs, out[i].id);
    if (!ids) return ids.error();
    out[i].run_ids = std::move(*ids);
    auto files = parse_files(files_json[i], out[i].id, path);
    if (!files) return files.error();
    out[i].files = std::move(*files);
  }
  return out;
}

}  // namespace

Database& ExportStore::self() { return static_cast<Database&>(*this); }
sqlite3* ExportStore::db() { return self().db_; }
const std::string& ExportStore::path() { return self().path_; }

Result<int64_t> ExportStore::begin_export(const ExportRecord& record) {
  const std::string what = begin_label(record);
  const auto bad = [&](const std::string& why) {
    return Error::Permanent(fmt::format("storage: {}: {}: {}", path(), what, why));
  };
  const bool nightly = record.kind == "nightly";
  if (!nightly && record.kind != "manual") {
    return bad(fmt::format("kind '{}' is neither 'nightly' nor 'manual'", record.kind));
  }
  if (nightly && !record.slot_unix_s) return bad("a nightly export needs its slot (slot_unix_s)");
  if (nightly && !std::isfinite(*record.slot_unix_s)) {
    return bad(fmt::format("slot_unix_s is {} (must be a finite Unix time)", *record.slot_unix_s));
  }
  if (!nightly && record.slot_unix_s) {
    return bad(fmt::format("a manual export has no slot (slot_unix_s is {}, must be unset)",
                           *record.slot_unix_s));
  }
  if (record.directory.empty()) return bad("directory is empty");
  std::vector<int64_t> run_ids = record.run_ids;
  std::sort(run_ids.begin(), run_ids.end());
  run_ids.erase(std::unique(run_ids.begin(), run_ids.end()), run_ids.end());

  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s.error();

  if (nightly) {
    auto taken = Stmt::prepare(db(), path(),
                               "SELECT id, state FROM exports WHERE kind = 'nightly' AND "
                               "slot_unix_s = ?");
    if (!taken) return taken.error();
    taken->bind(1, *record.slot_unix_s);
    const int rc = taken->step();
    if (rc == SQLITE_ROW) {
      return bad(fmt::format("{} already has export {} ({}); a slot is exported once",
                             slot_name(*record.slot_unix_s, record.slot_local),
                             taken->column_int64(0), taken->column_text(1)));
    }
    if (rc != SQLITE_DONE) return sqlite_error(db(), path(), what);
  }

  auto exists = Stmt::prepare(db(), path(), "SELECT 1 FROM runs WHERE id = ?");
  if (!exists) return exists.error();
  // A failed nightly export does not hold its runs: they go to the next one.
  auto held = Stmt::prepare(db(), path(),
                            "SELECT e.id, e.state, e.slot_unix_s, e.slot_local FROM export_runs r "
                            "JOIN exports e ON e.id = r.export_id WHERE r.run_id = ? AND "
                            "e.kind = 'nightly' AND e.state IN ('writing', 'done') "
                            "ORDER BY e.id LIMIT 1");
  if (!held) return held.error();
  for (int64_t run_id : run_ids) {
    exists->reset();
    exists->bind(1, run_id);
    int rc = exists->step();
    if (rc == SQLITE_DONE) return bad(fmt::format("no run with id {}", run_id));
    if (rc != SQLITE_ROW) return sqlite_error(db(), path(), what);
    if (!nightly) continue;
    held->reset();
    held->bind(1, run_id);
    rc = held->step();
    if (rc == SQLITE_ROW) {
      return bad(fmt::format(
          "run {} is already in nightly export {} ({}, {}); a run is exported by one nightly "
          "export",
          run_id, held->column_int64(0), slot_name(held->column_double(2), held->column_text(3)),
          held->column_text(1)));
    }
    if (rc != SQLITE_DONE) return sqlite_error(db(), path(), what);
  }

  auto ins = Stmt::prepare(db(), path(),
                           "INSERT INTO exports(kind, slot_unix_s, slot_local, state, directory, "
                           "files_json, started_utc, finished_utc, message) "
                           "VALUES(?, ?, ?, 'writing', ?, '[]', ?, NULL, ?)");
  if (!ins) return ins.error();
  ins->bind(1, std::string_view(record.kind));
  ins->bind(2, record.slot_unix_s);
  ins->bind(3, std::string_view(record.slot_local));
  ins->bind(4, std::string_view(record.directory));
  ins->bind(5, std::string_view(self().utc_or_now(record.started_utc)));
  ins->bind(6, std::string_view(record.message));
  if (Status s = expect_done(*ins, db(), path(), what); !s) return s.error();
  const auto export_id = static_cast<int64_t>(sqlite3_last_insert_rowid(db()));

  auto link =
      Stmt::prepare(db(), path(), "INSERT INTO export_runs(export_id, run_id) VALUES(?, ?)");
  if (!link) return link.error();
  for (int64_t run_id : run_ids) {
    link->reset();
    link->bind(1, export_id);
    link->bind(2, run_id);
    if (Status s = expect_done(*link, db(), path(), what); !s) return s.error();
  }
  if (Status s = tx.commit(); !s) return s.error();
  return export_id;
}

Status ExportStore::finish_export(int64_t export_id, std::string_view state,
                                  const std::vector<std::string>& files, std::string_view message) {
  const std::string what = fmt::format("finishing export {} as '{}'", export_id, state);
  const auto bad = [&](const std::string& why) {
    return Error::Permanent(fmt::format("storage: {}: {}: {}", path(), what, why));
  };
  if (state != "done" && state != "failed") return bad("the state must be 'done' or 'failed'");
  nlohmann::json list = nlohmann::json::array();
  for (std::size_t i = 0; i < files.size(); ++i) {
    const std::string& f = files[i];
    if (f.empty()) return bad(fmt::format("files[{}] is empty", i));
    if (f.front() == '/') {
      return bad(
          fmt::format("files[{}] '{}' is absolute (files are relative to the directory)", i, f));
    }
    list.push_back(f);
  }
  std::string files_json;
  try {
    files_json = list.dump();
  } catch (const nlohmann::json::exception&) {
    return bad("a file name is not valid UTF-8");
  }

  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s;
  {
    auto cur = Stmt::prepare(db(), path(), "SELECT state, finished_utc FROM exports WHERE id = ?");
    if (!cur) return cur.error();
    cur->bind(1, export_id);
    const int rc = cur->step();
    if (rc == SQLITE_DONE) return bad("no such export");
    if (rc != SQLITE_ROW) return sqlite_error(db(), path(), what);
    // Finishing twice could turn a failed export (whose runs another nightly
    // export may have taken since) into a done one: refused.
    if (const std::string current = cur->column_text(0); current != "writing") {
      return bad(fmt::format("it is already {} (finished {})", current, cur->column_text(1)));
    }
  }
  auto st = Stmt::prepare(db(), path(),
                          "UPDATE exports SET state = ?, files_json = ?, message = ?, "
                          "finished_utc = ? WHERE id = ?");
  if (!st) return st.error();
  st->bind(1, state);
  st->bind(2, std::string_view(files_json));
  st->bind(3, message);
  st->bind(4, std::string_view(self().utc_now()));
  st->bind(5, export_id);
  if (Status s = expect_done(*st, db(), path(), what); !s) return s;
  return tx.commit();
}

Result<std::vector<ExportRecord>> ExportStore::exports() {
  return read_exports(db(), path(), "", std::nullopt);
}

Result<std::optional<ExportRecord>> ExportStore::export_record(int64_t export_id) {
  auto rows = read_exports(db(), path(), "WHERE id = ?1", export_id);
  if (!rows) return rows.error();
  if (rows->empty()) return std::optional<ExportRecord>();
  return std::optional<ExportRecord>(std::move(rows->front()));
}

Result<std::optional<double>> ExportStore::last_nightly_slot_unix_s() {
  auto st =
      Stmt::prepare(db(), path(), "SELECT max(slot_unix_s) FROM exports WHERE kind = 'nightly'");
  if (!st) return st.error();
  if (st->step() != SQLITE_ROW) return sqlite_error(db(), path(), "reading the last nightly slot");
  return st->column_optional_double(0);
}

Result<std::vector<int64_t>> ExportStore::runs_not_exported() {
  auto st = Stmt::prepare(db(), path(),
                          "SELECT id FROM runs WHERE state = 'completed' AND id NOT IN ("
                          "SELECT r.run_id FROM export_runs r JOIN exports e ON e.id = "
                          "r.export_id WHERE e.kind = 'nightly' AND e.state IN ('writing', "
                          "'done')) ORDER BY id");
  if (!st) return st.error();
  std::vector<int64_t> ids;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) ids.push_back(st->column_int64(0));
  if (rc != SQLITE_DONE) return sqlite_error(db(), path(), "reading the runs not yet exported");
  return ids;
}

}  // namespace gyrotherm::storage
