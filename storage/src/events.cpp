// EventStore (events.h): events, of a run or of the station.
#include "gyrotherm/storage/events.h"

#include <fmt/format.h>
#include <sqlite3.h>

#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;

Database& EventStore::self() { return static_cast<Database&>(*this); }
sqlite3* EventStore::db() { return self().db_; }
const std::string& EventStore::path() { return self().path_; }

Result<int64_t> EventStore::add_event(const EventRecord& event) {
  auto st = Stmt::prepare(db(), path(),
                          "INSERT INTO events(run_id, t_s, wall_utc, kind, from_state, to_state, "
                          "message) VALUES(?, ?, ?, ?, ?, ?, ?)");
  if (!st) return st.error();
  st->bind(1, event.run_id);
  st->bind(2, event.t_s);
  st->bind(3, std::string_view(self().utc_or_now(event.wall_utc)));
  st->bind(4, std::string_view(event.kind));
  st->bind_text_or_null(5, event.from_state);
  st->bind_text_or_null(6, event.to_state);
  st->bind(7, std::string_view(event.message));
  if (Status s = expect_done(*st, db(), path(), fmt::format("adding a '{}' event", event.kind));
      !s) {
    return s.error();
  }
  return static_cast<int64_t>(sqlite3_last_insert_rowid(db()));
}

Result<std::vector<EventRecord>> EventStore::events(int64_t run_id) {
  auto st = Stmt::prepare(db(), path(),
                          "SELECT id, run_id, t_s, wall_utc, kind, from_state, to_state, message "
                          "FROM events WHERE run_id = ? ORDER BY id");
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<EventRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    EventRecord e;
    e.id = st->column_int64(0);
    e.run_id = st->column_optional_int64(1);
    e.t_s = st->column_double(2);
    e.wall_utc = st->column_text(3);
    e.kind = st->column_text(4);
    e.from_state = st->column_text(5);
    e.to_state = st->column_text(6);
    e.message = st->column_text(7);
    out.push_back(std::move(e));
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db(), path(), fmt::format("reading events of run {}", run_id));
  }
  return out;
}

}  // namespace gyrotherm::storage
