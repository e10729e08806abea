// The lab outbox (schema v10; docs/storage.md "Lab outbox"): the triggers
// that queue every change of a relayed table in the transaction of the
// change itself, binding a database to a lab station (which queues its
// history), and what the relay reads and acknowledges.
//
// The triggers are generated here from the tables' columns rather than
// written out in a migration: a later migration that adds a column to a
// relayed table runs install_lab_triggers again and the payloads carry the
// new column, with nothing to keep in step by hand.
#include "gyrotherm/storage/outbox.h"

#include <fmt/format.h>
#include <sqlite3.h>

#include <cctype>
#include <charconv>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "duts_internal.h"
#include "gyrotherm/storage/database.h"
#include "migrations.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;

namespace internal {
namespace {

// Where a relayed row's run_uuid comes from.
enum class RunOf {
  kSelf,   // the row is a run: its own uuid
  kRunId,  // the run its run_id names (nil when run_id is NULL or names no run)
  kNone,   // station-level rows (a fit may span runs; exports; DUTs): nil
};

struct RelayedTable {
  const char* table;
  const char* kind;  // outbox.kind, the lab's record kind
  const char* key;   // key columns, comma-separated; local_id joins their text with '/'
  RunOf run;
};

// In the order lab_bind queues a station's history: runs and DUTs before
// what refers to them (the lab does not depend on it; readers of the
// outbox may).
constexpr RelayedTable kRelayed[] = {
    {"runs", "run", "id", RunOf::kSelf},
    {"duts", "dut", "id", RunOf::kNone},
    {"run_duts", "run_dut", "run_id,dut_id", RunOf::kRunId},
    {"channels", "channel", "id", RunOf::kRunId},
    {"segments", "segment", "id", RunOf::kRunId},
    {"events", "event", "id", RunOf::kRunId},
    {"segment_stats", "table1", "segment_id,dut_serial,axis", RunOf::kRunId},
    {"allan", "allan", "id", RunOf::kRunId},
    {"fits", "fit", "id", RunOf::kNone},
    {"fit_runs", "fit_run", "run_id,fit_id", RunOf::kRunId},
    {"scale_factor_points", "sf_point", "id", RunOf::kRunId},
    {"scale_factor_fits", "sf_fit", "run_id,sf_sequence,dut_serial,axis", RunOf::kRunId},
    {"scale_factor_temperature_fits", "sf_temperature_fit", "run_id,dut_serial,axis",
     RunOf::kRunId},
    {"exports", "export", "id", RunOf::kNone},
    {"export_runs", "export_run", "export_id,run_id", RunOf::kRunId},
};

// Columns of runs that stay at the station: the crash-resume checkpoint
// (written about once a second: it would flood the outbox) and the TOML
// text of runs stored before v6.
constexpr std::string_view kRunsNotRelayed[] = {"resume_json", "checkpoint_wall_unix_s",
                                                "config_toml"};

// json_object() takes at most SQLITE_MAX_FUNCTION_ARG (127) arguments: a
// name and a value per column.
constexpr std::size_t kMaxPayloadColumns = 63;

constexpr std::string_view kGate = "EXISTS (SELECT 1 FROM meta WHERE key = 'lab_station_id')";
constexpr std::string_view kNowUnixS = "(julianday('now') - 2440587.5) * 86400.0";
constexpr std::string_view kOutboxInsert =
    "INSERT INTO outbox(kind, run_uuid, local_id, deleted, payload, committed_unix_s)";

struct Column {
  std::string name;
  std::string type;  // as declared
};

std::string quote_identifier(std::string_view name) {
  std::string out = "\"";
  for (char c : name) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + '"';
}

std::string quote_literal(std::string_view text) {
  std::string out = "'";
  for (char c : text) {
    if (c == '\'') out += '\'';
    out += c;
  }
  return out + '\'';
}

std::vector<std::string> split_key(std::string_view key) {
  std::vector<std::string> out;
  while (!key.empty()) {
    const auto comma = key.find(',');
    out.emplace_back(key.substr(0, comma));
    if (comma == std::string_view::npos) break;
    key.remove_prefix(comma + 1);
  }
  return out;
}

bool ends_with(std::string_view s, std::string_view suffix) {
  return s.size() >= suffix.size() && s.substr(s.size() - suffix.size()) == suffix;
}

// Whether a column of this declared type can hold a non-integral REAL that
// the program stored: not one of INTEGER affinity (rule 1: the type names
// INT; the program binds integers there) nor of TEXT affinity (rule 2:
// CHAR, CLOB or TEXT; numbers become text). Only those columns pay for the
// exact formatting below: the triggers' programs are compiled into every
// statement that writes the table, fired or not, so their size is a cost
// of every write (bench/outbox_bench.cpp).
bool may_hold_real(std::string type) {
  for (char& c : type) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  if (type.find("INT") != std::string::npos) return false;
  return type.find("CHAR") == std::string::npos && type.find("CLOB") == std::string::npos &&
         type.find("TEXT") == std::string::npos;
}

// The JSON value of column `c` of row `row` (NEW or OLD):
// - columns named *_json hold JSON text: embedded as JSON when it is valid,
//   else as a string (NULL as null);
// - REAL values are written with as many digits as they need to read back
//   as the same double (15 when those suffice, else 17; json_object()'s own
//   15 digits would round about one value in ten), and the infinities,
//   which JSON cannot hold, as the strings "Infinity" / "-Infinity" (what
//   PostgreSQL's float8 reads);
// - everything else as json_object() writes it (INTEGER and TEXT columns).
std::string value_sql(std::string_view row, const Column& c) {
  const std::string v = fmt::format("{}.{}", row, quote_identifier(c.name));
  if (ends_with(c.name, "_json")) {
    return fmt::format("json(CASE WHEN json_valid({0}) THEN {0} ELSE json_quote({0}) END)", v);
  }
  if (!may_hold_real(c.type)) return v;
  return fmt::format(
      "CASE WHEN typeof({0}) = 'real' THEN json(CASE WHEN {0} = 9e999 THEN '\"Infinity\"' "
      "WHEN {0} = -9e999 THEN '\"-Infinity\"' "
      "WHEN CAST(printf('%!.15g', {0}) AS REAL) = {0} THEN printf('%!.15g', {0}) "
      "ELSE printf('%!.17g', {0}) END) ELSE {0} END",
      v);
}

struct TableSql {
  std::vector<Column> payload_columns;
  std::vector<std::string> key;
  // Expressions over a row alias (NEW or OLD).
  std::string payload(std::string_view row) const {
    std::string out = "json_object(";
    for (std::size_t i = 0; i < payload_columns.size(); ++i) {
      if (i > 0) out += ", ";
      out += quote_literal(payload_columns[i].name);
      out += ", ";
      out += value_sql(row, payload_columns[i]);
    }
    return out + ")";
  }
  std::string local_id(std::string_view row) const {
    std::string out;
    for (std::size_t i = 0; i < key.size(); ++i) {
      if (i > 0) out += " || '/' || ";
      out += fmt::format("coalesce(CAST({}.{} AS TEXT), '')", row, quote_identifier(key[i]));
    }
    return out;
  }
  std::string run_uuid(std::string_view row) const {
    const std::string nil = quote_literal(kNilUuid);
    switch (relayed->run) {
      case RunOf::kSelf:
        return fmt::format("coalesce({}.uuid, {})", row, nil);
      case RunOf::kRunId:
        return fmt::format("coalesce((SELECT uuid FROM runs WHERE id = {}.run_id), {})", row, nil);
      case RunOf::kNone:
        break;
    }
    return nil;
  }
  // The row's outbox key (run_uuid, local_id) differs between OLD and NEW.
  std::string key_changed() const {
    std::vector<std::string> terms;
    bool run_id_in_key = false;
    for (const std::string& k : key) {
      terms.push_back(fmt::format("OLD.{0} IS NOT NEW.{0}", quote_identifier(k)));
      run_id_in_key = run_id_in_key || k == "run_id";
    }
    if (relayed->run == RunOf::kRunId && !run_id_in_key) {
      terms.emplace_back("OLD.run_id IS NOT NEW.run_id");
    }
    // A run without a uuid (inserted by plain SQL) is queued once
    // runs_uuid_on_insert gives it one: there is nothing to retract.
    if (relayed->run == RunOf::kSelf) {
      terms.emplace_back("(OLD.uuid IS NOT NULL AND OLD.uuid IS NOT NEW.uuid)");
    }
    std::string out;
    for (std::size_t i = 0; i < terms.size(); ++i) {
      if (i > 0) out += " OR ";
      out += terms[i];
    }
    return out;
  }
  std::string row_values(std::string_view row) const {
    return fmt::format("VALUES({}, {}, {}, 0, {}, {})", quote_literal(relayed->kind), run_uuid(row),
                       local_id(row), payload(row), kNowUnixS);
  }
  std::string tombstone_select() const {
    return fmt::format("SELECT {}, {}, {}, 1, '{{}}', {}", quote_literal(relayed->kind),
                       run_uuid("OLD"), local_id("OLD"), kNowUnixS);
  }

  const RelayedTable* relayed = nullptr;
};

Result<TableSql> table_sql(sqlite3* db, const std::string& path, const RelayedTable& t) {
  auto st = Stmt::prepare(db, path, "SELECT name, type FROM pragma_table_info(?) ORDER BY cid");
  if (!st) return st.error();
  st->bind(1, std::string_view(t.table));
  TableSql out;
  out.relayed = &t;
  out.key = split_key(t.key);
  int rc;
  std::vector<std::string> names;
  while ((rc = st->step()) == SQLITE_ROW) {
    Column c{st->column_text(0), st->column_text(1)};
    names.push_back(c.name);
    if (std::string_view(t.table) == "runs") {
      bool relayed = true;
      for (std::string_view skip : kRunsNotRelayed) relayed = relayed && c.name != skip;
      if (!relayed) continue;
    }
    out.payload_columns.push_back(std::move(c));
  }
  const std::string what = fmt::format("reading the columns of relayed table {}", t.table);
  if (rc != SQLITE_DONE) return sqlite_error(db, path, what);
  if (names.empty()) {
    return Error::Permanent(fmt::format("storage: {}: {}: no such table", path, what));
  }
  for (const std::string& k : out.key) {
    bool found = false;
    for (const std::string& n : names) found = found || n == k;
    if (!found) {
      return Error::Permanent(
          fmt::format("storage: {}: {}: it has no key column '{}'", path, what, k));
    }
  }
  if (out.payload_columns.size() > kMaxPayloadColumns) {
    return Error::Permanent(
        fmt::format("storage: {}: {}: {} columns, more than the {} one json_object() can hold",
                    path, what, out.payload_columns.size(), kMaxPayloadColumns));
  }
  return out;
}

std::string triggers_sql(const TableSql& t) {
  const std::string table = quote_identifier(t.relayed->table);
  const std::string name = t.relayed->table;
  std::string insert_when(kGate);
  std::string update_of;
  if (t.relayed->run == RunOf::kSelf) {
    // Queued once runs_uuid_on_insert has given the run its uuid (by the
    // update trigger).
    insert_when += " AND NEW.uuid IS NOT NULL";
    // Only the relayed columns: checkpoints (resume_json,
    // checkpoint_wall_unix_s) are written about once a wall second.
    update_of = " OF ";
    for (std::size_t i = 0; i < t.payload_columns.size(); ++i) {
      if (i > 0) update_of += ", ";
      update_of += quote_identifier(t.payload_columns[i].name);
    }
  }
  std::string sql;
  sql += fmt::format(
      "CREATE TRIGGER lab_outbox_{0}_insert AFTER INSERT ON {1} WHEN {2}\n"
      "BEGIN\n  {3} {4};\nEND;\n",
      name, table, insert_when, kOutboxInsert, t.row_values("NEW"));
  // An update that changes the row's key retracts the old key first.
  sql += fmt::format(
      "CREATE TRIGGER lab_outbox_{0}_update AFTER UPDATE{1} ON {2} WHEN {3}\n"
      "BEGIN\n  {4} {5} WHERE {6};\n  {4} {7};\nEND;\n",
      name, update_of, table, kGate, kOutboxInsert, t.tombstone_select(), t.key_changed(),
      t.row_values("NEW"));
  sql += fmt::format(
      "CREATE TRIGGER lab_outbox_{0}_delete AFTER DELETE ON {1} WHEN {2}\n"
      "BEGIN\n  {3} {4};\nEND;\n",
      name, table, kGate, kOutboxInsert, t.tombstone_select());
  return sql;
}

// Every row of the table, queued as the insert trigger would queue it.
std::string enqueue_all_sql(const TableSql& t) {
  std::string order;
  for (std::size_t i = 0; i < t.key.size(); ++i) {
    if (i > 0) order += ", ";
    order += "NEW." + quote_identifier(t.key[i]);
  }
  return fmt::format("{} SELECT {}, {}, {}, 0, {}, {} FROM {} AS NEW ORDER BY {}", kOutboxInsert,
                     quote_literal(t.relayed->kind), t.run_uuid("NEW"), t.local_id("NEW"),
                     t.payload("NEW"), kNowUnixS, quote_identifier(t.relayed->table), order);
}

// [A-Za-z0-9][A-Za-z0-9._-]{0,63}: the lab's stations.station_id.
bool valid_station_id(std::string_view id) {
  if (id.empty() || id.size() > 64) return false;
  const auto alnum = [](char c) {
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9');
  };
  if (!alnum(id[0])) return false;
  for (char c : id) {
    if (!alnum(c) && c != '.' && c != '_' && c != '-') return false;
  }
  return true;
}

}  // namespace

Status install_lab_triggers(sqlite3* db, const std::string& path) {
  std::vector<std::string> old;
  {
    auto st = Stmt::prepare(db, path,
                            "SELECT name FROM sqlite_master WHERE type = 'trigger' AND "
                            "name LIKE 'lab\\_outbox\\_%' ESCAPE '\\'");
    if (!st) return st.error();
    int rc;
    while ((rc = st->step()) == SQLITE_ROW) old.push_back(st->column_text(0));
    if (rc != SQLITE_DONE) return sqlite_error(db, path, "listing the lab outbox triggers");
  }
  for (const std::string& name : old) {
    if (Status s = exec(db, path, "DROP TRIGGER " + quote_identifier(name)); !s) return s;
  }
  for (const RelayedTable& t : kRelayed) {
    auto sql = table_sql(db, path, t);
    if (!sql) return sql.error();
    if (Status s = exec(db, path, triggers_sql(*sql)); !s) return s;
  }
  return Status::Ok();
}

Status install_lab_triggers_step(sqlite3* db, const std::string& path,
                                 const std::string& /*now_utc*/) {
  return install_lab_triggers(db, path);
}

}  // namespace internal

Database& OutboxStore::self() { return static_cast<Database&>(*this); }
sqlite3* OutboxStore::db() { return self().db_; }
const std::string& OutboxStore::path() { return self().path_; }

Result<std::optional<std::string>> OutboxStore::lab_station_id() {
  return self().meta("lab_station_id");
}

Status OutboxStore::lab_bind(std::string_view station_id) {
  if (!internal::valid_station_id(station_id)) {
    return Error::Permanent(
        fmt::format("storage: {}: lab station id '{}' is not valid: 1 to 64 letters, digits, "
                    "'.', '_' or '-', starting with a letter or digit",
                    path(), station_id));
  }
  internal::WriteScope tx(db(), path(), "lab_bind");
  if (Status s = tx.begin(); !s) return s;
  auto bound = self().meta("lab_station_id");
  if (!bound) return bound.error();
  if (*bound) {
    if (**bound == station_id) return Status::Ok();  // rolls back the empty transaction
    return Error::Permanent(fmt::format(
        "storage: {}: the database is bound to lab station '{}', not '{}' (a station database "
        "belongs to one station; give [lab] station_id '{}' or use another database)",
        path(), **bound, station_id, **bound));
  }
  auto set =
      Stmt::prepare(db(), path(), "INSERT INTO meta(key, value) VALUES('lab_station_id', ?)");
  if (!set) return set.error();
  set->bind(1, station_id);
  const std::string what = fmt::format("binding the database to lab station '{}'", station_id);
  if (Status s = expect_done(*set, db(), path(), what); !s) return s;
  // The history, in the transaction that binds: every change from now on
  // is queued by the triggers, everything before it by this.
  for (const internal::RelayedTable& t : internal::kRelayed) {
    auto sql = internal::table_sql(db(), path(), t);
    if (!sql) return sql.error();
    if (Status s = internal::exec(db(), path(), internal::enqueue_all_sql(*sql)); !s) {
      return Error{fmt::format("{} [{}: queueing table {}]", s.error().message, what, t.table),
                   s.error().transient};
    }
  }
  return tx.commit();
}

Result<std::vector<OutboxRecord>> OutboxStore::outbox_batch(int64_t after_seq, int limit,
                                                            int64_t max_bytes) {
  if (limit < 1) {
    return Error::Permanent(
        fmt::format("storage: {}: reading the outbox: limit {} (at least 1)", path(), limit));
  }
  auto st = Stmt::prepare(db(), path(),
                          "SELECT seq, kind, run_uuid, local_id, deleted, payload, "
                          "committed_unix_s FROM outbox WHERE seq > ? ORDER BY seq LIMIT ?");
  if (!st) return st.error();
  st->bind(1, after_seq);
  st->bind(2, limit);
  std::vector<OutboxRecord> out;
  int64_t bytes = 0;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    OutboxRecord r;
    r.seq = st->column_int64(0);
    r.kind = st->column_text(1);
    r.run_uuid = st->column_text(2);
    r.local_id = st->column_text(3);
    r.deleted = st->column_int64(4) != 0;
    r.payload_json = st->column_text(5);
    r.committed_unix_s = st->column_double(6);
    bytes += static_cast<int64_t>(r.payload_json.size());
    if (!out.empty() && bytes > max_bytes) return out;  // at least one row, however large
    out.push_back(std::move(r));
  }
  if (rc != SQLITE_DONE) {
    return sqlite_error(db(), path(), fmt::format("reading the outbox after seq {}", after_seq));
  }
  return out;
}

Status OutboxStore::outbox_ack(int64_t up_to_seq) {
  const std::string what = fmt::format("acknowledging the outbox up to seq {}", up_to_seq);
  internal::WriteScope tx(db(), path(), "outbox_ack");
  if (Status s = tx.begin(); !s) return s;
  // A seq the outbox never wrote would be a relay's bug; accepting it would
  // move the mark past rows still to come.
  auto last = Stmt::prepare(
      db(), path(), "SELECT coalesce((SELECT seq FROM sqlite_sequence WHERE name = 'outbox'), 0)");
  if (!last) return last.error();
  if (last->step() != SQLITE_ROW) return sqlite_error(db(), path(), what);
  const int64_t written = last->column_int64(0);
  if (up_to_seq > written) {
    return Error::Permanent(fmt::format("storage: {}: {}: the outbox has written seq {} at most",
                                        path(), what, written));
  }
  auto del = Stmt::prepare(db(), path(), "DELETE FROM outbox WHERE seq <= ?");
  if (!del) return del.error();
  del->bind(1, up_to_seq);
  if (Status s = expect_done(*del, db(), path(), what); !s) return s;
  // The mark only moves forward (a late, smaller acknowledgement changes
  // nothing).
  auto mark = Stmt::prepare(db(), path(),
                            "INSERT INTO meta(key, value) VALUES('lab_last_acked_seq', ?1) "
                            "ON CONFLICT(key) DO UPDATE SET value = excluded.value "
                            "WHERE CAST(value AS INTEGER) < ?1");
  if (!mark) return mark.error();
  mark->bind(1, up_to_seq);
  if (up_to_seq > 0) {
    if (Status s = expect_done(*mark, db(), path(), what); !s) return s;
  }
  return tx.commit();
}

Result<OutboxStats> OutboxStore::outbox_stats() {
  // One statement: one snapshot, whatever the writers do meanwhile.
  auto st = Stmt::prepare(db(), path(),
                          "SELECT count(*), coalesce(sum(length(CAST(payload AS BLOB))), 0), "
                          "(SELECT committed_unix_s FROM outbox ORDER BY seq LIMIT 1), "
                          "(SELECT value FROM meta WHERE key = 'lab_last_acked_seq') FROM outbox");
  if (!st) return st.error();
  if (st->step() != SQLITE_ROW) return sqlite_error(db(), path(), "reading the outbox's state");
  OutboxStats out;
  out.pending = st->column_int64(0);
  out.pending_bytes = st->column_int64(1);
  out.oldest_unix_s = st->column_optional_double(2);
  const std::string acked = st->column_text(3);
  if (!acked.empty()) {
    const auto [end, ec] =
        std::from_chars(acked.data(), acked.data() + acked.size(), out.last_acked_seq);
    if (ec != std::errc() || end != acked.data() + acked.size()) {
      return Error::Permanent(fmt::format(
          "storage: {}: meta 'lab_last_acked_seq' is not a sequence number: '{}'", path(), acked));
    }
  }
  return out;
}

}  // namespace gyrotherm::storage
