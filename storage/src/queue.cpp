// QueueStore (queue.h): the run queue and station settings (meta). Queue
// changes run in one IMMEDIATE transaction each, so the HTTP thread and the
// control thread (each with its own connection) never see a half-renumbered
// queue, and a claimed entry cannot be removed.
#include "gyrotherm/storage/queue.h"

#include <fmt/format.h>
#include <sqlite3.h>

#include <algorithm>

#include "duts_internal.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;
using internal::Transaction;

namespace {

constexpr const char* kQueueSelect =
    "SELECT q.id, q.schedule_id, q.position, q.state, q.added_utc, q.ignore_failures, q.run_id, "
    "s.name, s.source_path, s.toml_text, q.operator, q.comment, q.tags_json, q.dut_serials_json "
    "FROM queue q JOIN schedules s ON s.id = q.schedule_id ";

Result<QueueEntry> read_entry(const Stmt& st, const std::string& path) {
  QueueEntry e;
  e.id = st.column_int64(0);
  e.schedule_id = st.column_int64(1);
  e.position = static_cast<int>(st.column_int64(2));
  e.state = st.column_text(3);
  e.added_utc = st.column_text(4);
  e.ignore_failures = st.column_int64(5) != 0;
  e.run_id = st.column_optional_int64(6);
  e.schedule_name = st.column_text(7);
  e.source_path = st.column_text(8);
  e.toml_text = st.column_text(9);
  auto metadata =
      internal::read_metadata(st, 10, fmt::format("storage: {}: queue entry {}", path, e.id));
  if (!metadata) return metadata.error();
  e.metadata = std::move(*metadata);
  return e;
}

// Queued entry ids in position order.
Result<std::vector<int64_t>> queued_ids(sqlite3* db, const std::string& path) {
  auto st =
      Stmt::prepare(db, path, "SELECT id FROM queue WHERE state = 'queued' ORDER BY position, id");
  if (!st) return st.error();
  std::vector<int64_t> ids;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) ids.push_back(st->column_int64(0));
  if (rc != SQLITE_DONE) return sqlite_error(db, path, "reading the queue");
  return ids;
}

// Writes positions 0..n-1 in the given order.
Status renumber(sqlite3* db, const std::string& path, const std::vector<int64_t>& ids) {
  auto st = Stmt::prepare(db, path, "UPDATE queue SET position = ? WHERE id = ?");
  if (!st) return st.error();
  for (std::size_t i = 0; i < ids.size(); ++i) {
    st->reset();
    st->bind(1, static_cast<int64_t>(i));
    st->bind(2, ids[i]);
    if (Status s = expect_done(*st, db, path, "renumbering the queue"); !s) return s;
  }
  return Status::Ok();
}

}  // namespace

Database& QueueStore::self() { return static_cast<Database&>(*this); }
sqlite3* QueueStore::db() { return self().db_; }
const std::string& QueueStore::path() { return self().path_; }

Result<QueueEntry> QueueStore::queue_add(const std::string& schedule_name,
                                         const std::string& source_path,
                                         const std::string& toml_text, bool ignore_failures,
                                         const RunMetadata& metadata) {
  if (Status s = internal::check_metadata(metadata, path(), "adding to the queue"); !s) {
    return s.error();
  }
  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s.error();
  const std::string now = self().utc_now();
  auto sched = Stmt::prepare(
      db(), path(),
      "INSERT INTO schedules(name, source_path, toml_text, created_utc) VALUES(?, ?, ?, ?)");
  if (!sched) return sched.error();
  sched->bind(1, std::string_view(schedule_name));
  sched->bind_text_or_null(2, source_path);
  sched->bind(3, std::string_view(toml_text));
  sched->bind(4, std::string_view(now));
  if (Status s = expect_done(*sched, db(), path(), "storing a schedule"); !s) return s.error();
  const int64_t schedule_id = sqlite3_last_insert_rowid(db());
  auto ins = Stmt::prepare(
      db(), path(),
      "INSERT INTO queue(schedule_id, position, state, added_utc, ignore_failures, operator, "
      "comment, tags_json, dut_serials_json) "
      "VALUES(?, (SELECT coalesce(max(position) + 1, 0) FROM queue WHERE state = 'queued'), "
      "'queued', ?, ?, ?, ?, ?, ?)");
  if (!ins) return ins.error();
  ins->bind(1, schedule_id);
  ins->bind(2, std::string_view(now));
  ins->bind(3, ignore_failures ? 1 : 0);
  internal::bind_metadata(*ins, 4, metadata);
  if (Status s = expect_done(*ins, db(), path(), "adding to the queue"); !s) return s.error();
  const int64_t id = sqlite3_last_insert_rowid(db());
  if (Status s = tx.commit(); !s) return s.error();
  auto entry = queue_entry(id);
  if (!entry) return entry.error();
  return **entry;
}

Result<std::vector<QueueEntry>> QueueStore::queue_entries() {
  auto st = Stmt::prepare(db(), path(),
                          std::string(kQueueSelect) +
                              "WHERE q.state IN ('running', 'queued') "
                              "ORDER BY q.state = 'queued', q.position, q.id");
  if (!st) return st.error();
  std::vector<QueueEntry> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    auto entry = read_entry(*st, path());
    if (!entry) return entry.error();
    out.push_back(std::move(*entry));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db(), path(), "reading the queue");
  return out;
}

Result<std::optional<QueueEntry>> QueueStore::queue_entry(int64_t id) {
  auto st = Stmt::prepare(db(), path(), std::string(kQueueSelect) + "WHERE q.id = ?");
  if (!st) return st.error();
  st->bind(1, id);
  const int rc = st->step();
  if (rc == SQLITE_ROW) {
    auto entry = read_entry(*st, path());
    if (!entry) return entry.error();
    return std::optional<QueueEntry>(std::move(*entry));
  }
  if (rc == SQLITE_DONE) return std::optional<QueueEntry>();
  return sqlite_error(db(), path(), fmt::format("reading queue entry {}", id));
}

Result<bool> QueueStore::queue_remove(int64_t id) {
  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s.error();
  auto st = Stmt::prepare(
      db(), path(),
      "UPDATE queue SET state = 'removed', position = -1 WHERE id = ? AND state = 'queued'");
  if (!st) return st.error();
  st->bind(1, id);
  if (Status s = expect_done(*st, db(), path(), "removing a queue entry"); !s) return s.error();
  if (sqlite3_changes(db()) == 0) return false;
  auto ids = queued_ids(db(), path());
  if (!ids) return ids.error();
  if (Status s = renumber(db(), path(), *ids); !s) return s.error();
  if (Status s = tx.commit(); !s) return s.error();
  return true;
}

Result<bool> QueueStore::queue_move(int64_t id, int position) {
  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s.error();
  auto ids = queued_ids(db(), path());
  if (!ids) return ids.error();
  auto it = std::find(ids->begin(), ids->end(), id);
  if (it == ids->end()) return false;
  ids->erase(it);
  const auto at = static_cast<std::size_t>(std::clamp(position, 0, static_cast<int>(ids->size())));
  ids->insert(ids->begin() + static_cast<std::ptrdiff_t>(at), id);
  if (Status s = renumber(db(), path(), *ids); !s) return s.error();
  if (Status s = tx.commit(); !s) return s.error();
  return true;
}

Result<bool> QueueStore::queue_claim(int64_t id, int64_t run_id) {
  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s.error();
  auto st = Stmt::prepare(db(), path(),
                          "UPDATE queue SET state = 'running', position = -1, run_id = ? "
                          "WHERE id = ? AND state = 'queued'");
  if (!st) return st.error();
  st->bind(1, run_id);
  st->bind(2, id);
  if (Status s = expect_done(*st, db(), path(), "taking a queue entry"); !s) return s.error();
  if (sqlite3_changes(db()) == 0) return false;
  auto ids = queued_ids(db(), path());
  if (!ids) return ids.error();
  if (Status s = renumber(db(), path(), *ids); !s) return s.error();
  if (Status s = tx.commit(); !s) return s.error();
  return true;
}

Result<std::optional<int64_t>> QueueStore::queue_start_run(int64_t id, const RunRecord& run) {
  // One IMMEDIATE transaction: the claim and the run row commit together, or
  // neither does. Another connection's queue_remove either ran before (the
  // claim finds the entry removed: no run row) or waits for the commit (and
  // finds the entry running).
  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s.error();
  auto claim = Stmt::prepare(db(), path(),
                             "UPDATE queue SET state = 'running', position = -1 "
                             "WHERE id = ? AND state = 'queued' RETURNING schedule_id, "
                             "operator, comment, tags_json, dut_serials_json");
  if (!claim) return claim.error();
  claim->bind(1, id);
  int rc = claim->step();
  if (rc == SQLITE_DONE) return std::optional<int64_t>();  // not queued: rolled back
  if (rc != SQLITE_ROW) return sqlite_error(db(), path(), fmt::format("taking queue entry {}", id));
  RunRecord rec = run;
  rec.queue_id = id;
  rec.schedule_id = claim->column_int64(0);
  // The entry's metadata goes to the run; a field the entry left empty
  // takes the caller's.
  auto queued =
      internal::read_metadata(*claim, 1, fmt::format("storage: {}: queue entry {}", path(), id));
  if (!queued) return queued.error();
  if (!queued->operator_name.empty()) rec.metadata.operator_name = queued->operator_name;
  if (!queued->comment.empty()) rec.metadata.comment = queued->comment;
  if (!queued->tags.empty()) rec.metadata.tags = queued->tags;
  if (!queued->dut_serials.empty()) rec.metadata.dut_serials = queued->dut_serials;
  if (Status s = expect_done(*claim, db(), path(), fmt::format("taking queue entry {}", id)); !s) {
    return s.error();
  }
  auto run_id = self().create_run(rec);
  if (!run_id) return run_id.error();
  auto link = Stmt::prepare(db(), path(), "UPDATE queue SET run_id = ? WHERE id = ?");
  if (!link) return link.error();
  link->bind(1, *run_id);
  link->bind(2, id);
  if (Status s = expect_done(*link, db(), path(), fmt::format("starting queue entry {}", id)); !s) {
    return s.error();
  }
  auto ids = queued_ids(db(), path());
  if (!ids) return ids.error();
  if (Status s = renumber(db(), path(), *ids); !s) return s.error();
  if (Status s = tx.commit(); !s) return s.error();
  return std::optional<int64_t>(*run_id);
}

Status QueueStore::queue_finish(int64_t id, std::string_view state) {
  auto st = Stmt::prepare(db(), path(), "UPDATE queue SET state = ?, position = -1 WHERE id = ?");
  if (!st) return st.error();
  st->bind(1, state);
  st->bind(2, id);
  return expect_done(*st, db(), path(), fmt::format("closing queue entry {}", id));
}

Status QueueStore::queue_requeue(int64_t id) {
  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s;
  auto ids = queued_ids(db(), path());
  if (!ids) return ids.error();
  ids->insert(ids->begin(), id);
  auto st =
      Stmt::prepare(db(), path(), "UPDATE queue SET state = 'queued', run_id = NULL WHERE id = ?");
  if (!st) return st.error();
  st->bind(1, id);
  if (Status s = expect_done(*st, db(), path(), "requeueing"); !s) return s;
  if (Status s = renumber(db(), path(), *ids); !s) return s;
  return tx.commit();
}

Result<std::optional<std::string>> QueueStore::meta(std::string_view key) {
  auto st = Stmt::prepare(db(), path(), "SELECT value FROM meta WHERE key = ?");
  if (!st) return st.error();
  st->bind(1, key);
  const int rc = st->step();
  if (rc == SQLITE_ROW) return std::optional<std::string>(st->column_text(0));
  if (rc == SQLITE_DONE) return std::optional<std::string>();
  return sqlite_error(db(), path(), fmt::format("reading meta '{}'", key));
}

Status QueueStore::set_meta(std::string_view key, std::string_view value) {
  auto st = Stmt::prepare(db(), path(), "INSERT OR REPLACE INTO meta(key, value) VALUES(?, ?)");
  if (!st) return st.error();
  st->bind(1, key);
  st->bind(2, value);
  return expect_done(*st, db(), path(), fmt::format("writing meta '{}'", key));
}

Status QueueStore::delete_meta(std::string_view key) {
  auto st = Stmt::prepare(db(), path(), "DELETE FROM meta WHERE key = ?");
  if (!st) return st.error();
  st->bind(1, key);
  return expect_done(*st, db(), path(), fmt::format("deleting meta '{}'", key));
}

}  // namespace gyrotherm::storage
