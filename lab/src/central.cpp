// Writing to the lab database: registering stations and readers, and the
// relay's batch upsert (docs/lab.md "Central schema").
#include "gyrotherm/lab/central.h"

#include <fmt/format.h>
#include <libpq-fe.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>
#include <regex>
#include <tuple>

#include "pg_transaction.h"

namespace gyrotherm::lab {
namespace {

using json = nlohmann::json;

Status check_role_name(const std::string& role) {
  // PostgreSQL truncates identifiers to 63 bytes and reserves pg_*.
  if (role.empty() || role.size() > 63 || role.rfind("pg_", 0) == 0 ||
      role.find('\0') != std::string::npos) {
    return Error::Permanent(
        fmt::format("'{}' cannot be a role name (1 to 63 bytes, not starting with pg_)", role));
  }
  if (role == "gyrotherm_station" || role == "gyrotherm_reader") {
    return Error::Permanent(fmt::format(
        "'{}' is one of the lab's group roles; give each station or reader its own login role",
        role));
  }
  return {};
}

Status require_schema(PgConnection& pg) {
  auto version = central_schema_version(pg);
  if (!version.ok()) return version.error();
  if (*version < 1) {
    return Error::Permanent(fmt::format(
        "lab database {} has no lab schema yet: run `gyrotherm lab migrate` first", pg.server()));
  }
  return {};
}

// Creates login role `role` when missing (no password: the administrator
// sets one, or a certificate maps to it) and makes it a member of `group`.
// A role that bypasses row-level security (superuser, BYPASSRLS) is
// refused: through it a station could write any station's rows.
Status ensure_login_member(PgConnection& pg, const std::string& role, const std::string& group) {
  auto found =
      pg.exec_params("SELECT rolsuper OR rolbypassrls FROM pg_roles WHERE rolname = $1", {role});
  if (!found.ok()) return found.error();
  const std::string quoted = internal::quote_ident(pg, role);
  if (quoted.empty()) return Error::Permanent(fmt::format("cannot quote role name '{}'", role));
  if (found->rows.empty()) {
    if (auto r = pg.exec("CREATE ROLE " + quoted + " LOGIN"); !r.ok()) return r.error();
  } else if (found->rows[0][0] == "t") {
    return Error::Permanent(fmt::format(
        "role '{}' is a superuser or bypasses row-level security: the lab's policies would not "
        "apply to it; use a plain login role",
        role));
  }
  if (auto r = pg.exec("GRANT " + group + " TO " + quoted); !r.ok()) return r.error();
  return {};
}

// The role the connection logged in as.
std::string login_role(PgConnection& pg) {
  const char* user = pg.handle() ? PQuser(pg.handle()) : nullptr;
  return user ? user : "";
}

// Why the lab refused `station_id` to this connection, from lab.stations.
// Read through libpq directly so the connection's last SQLSTATE stays the
// refusal's.
std::string refusal_reason(PgConnection& pg, const std::string& station_id,
                           const std::string& role) {
  if (!pg.handle() || PQstatus(pg.handle()) != CONNECTION_OK) return "";
  const char* values[] = {station_id.c_str()};
  PGresult* res =
      PQexecParams(pg.handle(), "SELECT db_role::text FROM lab.stations WHERE station_id = $1", 1,
                   nullptr, values, nullptr, nullptr, 0);
  std::string why;
  if (PQresultStatus(res) == PGRES_TUPLES_OK) {
    if (PQntuples(res) == 0) {
      why = fmt::format(
          "station id '{}' is not registered in lab.stations (an administrator registers it "
          "for its role)",
          station_id);
    } else {
      const std::string owner = PQgetvalue(res, 0, 0);
      why = owner == role ? fmt::format(
                                "station id '{}' is registered to role '{}', but the role may not "
                                "write it (is it a member of gyrotherm_station?)",
                                station_id, role)
                          : fmt::format("station id '{}' is registered to role '{}', not to '{}'",
                                        station_id, owner, role);
    }
  }
  PQclear(res);
  return why;
}

// The batch as the upsert's $1: one JSON object per record, keys reduced
// to their last record (a key updated twice in one batch: the later
// version; ON CONFLICT cannot touch one row twice in a statement).
json batch_json(std::span<const storage::OutboxRecord> batch) {
  std::map<std::tuple<std::string_view, std::string_view, std::string_view>, size_t> last;
  for (size_t i = 0; i < batch.size(); ++i) {
    const auto& r = batch[i];
    const std::string_view uuid = r.run_uuid.empty() ? storage::kNilUuid : r.run_uuid;
    last[{uuid, r.kind, r.local_id}] = i;
  }
  std::vector<size_t> keep;
  keep.reserve(last.size());
  for (const auto& [key, index] : last) keep.push_back(index);
  std::sort(keep.begin(), keep.end());
  json rows = json::array();
  for (size_t i : keep) {
    const auto& r = batch[i];
    json row = {{"run_uuid", r.run_uuid.empty() ? std::string(storage::kNilUuid) : r.run_uuid},
                {"kind", r.kind},
                {"local_id", r.local_id},
                {"outbox_seq", r.seq},
                {"deleted", r.deleted},
                {"payload", r.payload_json}};
    // A non-finite time cannot be a timestamp: the lab's commit time stands in.
    row["committed_unix_s"] =
        std::isfinite(r.committed_unix_s) ? json(r.committed_unix_s) : json(nullptr);
    rows.push_back(std::move(row));
  }
  return rows;
}

// One statement, so one transaction: the records upserted and the station's
// relay progress advanced, or (any row refused, the connection lost)
// nothing. `before` reads the rows as they were (every part of a statement
// sees the same snapshot, so it does not see the upsert's effects): the
// batch's outcome per record is classified from it. A concurrent push of
// the same station's keys (one relay per station: not expected) could make
// the counts approximate, never the data.
constexpr const char* kPushSql = R"sql(
WITH input AS (
  SELECT * FROM jsonb_to_recordset($1::jsonb)
    AS i(run_uuid uuid, kind text, local_id text, outbox_seq bigint, deleted boolean,
         payload text, committed_unix_s float8)
), before AS (
  -- One primary-key lookup per record (a correlated subquery): a join let
  -- the planner scan every record the station has, so a batch's cost grew
  -- with the station's history (57 -> 116 ms per 500 records over 100 k).
  SELECT i.outbox_seq AS seq,
         (SELECT r.outbox_seq FROM lab.records r
          WHERE r.station_id = $2 AND r.run_uuid = i.run_uuid AND r.kind = i.kind
            AND r.local_id = i.local_id) AS held_seq
  FROM input i
), upsert AS (
  INSERT INTO lab.records(station_id, run_uuid, kind, local_id, outbox_seq, deleted, payload,
                          station_committed_at)
  SELECT $2, run_uuid, kind, local_id, outbox_seq, deleted, payload::jsonb,
         coalesce(to_timestamp(committed_unix_s), now())
  FROM input
  ON CONFLICT (station_id, run_uuid, kind, local_id) DO UPDATE SET
    outbox_seq = EXCLUDED.outbox_seq,
    deleted = EXCLUDED.deleted,
    payload = EXCLUDED.payload,
    station_committed_at = EXCLUDED.station_committed_at,
    central_committed_at = CASE WHEN lab.records.outbox_seq = EXCLUDED.outbox_seq
                                THEN lab.records.central_committed_at ELSE now() END,
    redeliveries = lab.records.redeliveries
                   + CASE WHEN lab.records.outbox_seq = EXCLUDED.outbox_seq THEN 1 ELSE 0 END
  WHERE lab.records.outbox_seq <= EXCLUDED.outbox_seq
  RETURNING 1
), progress AS (
  INSERT INTO lab.relay_progress(station_id, last_seq, last_batch_at, batches, records)
  VALUES ($2, $3::bigint, now(), 1, $4::bigint)
  ON CONFLICT (station_id) DO UPDATE SET
    last_seq = greatest(lab.relay_progress.last_seq, EXCLUDED.last_seq),
    last_batch_at = EXCLUDED.last_batch_at,
    batches = lab.relay_progress.batches + 1,
    records = lab.relay_progress.records + EXCLUDED.records
  RETURNING 1
)
SELECT count(*) FILTER (WHERE held_seq IS NULL OR held_seq < seq),
       count(*) FILTER (WHERE held_seq = seq),
       count(*) FILTER (WHERE held_seq > seq),
       (SELECT count(*) FROM upsert),
       (SELECT count(*) FROM progress)
FROM before
)sql";

}  // namespace

// lab.stations' CHECK, tested here first for a message that names the id.
bool valid_station_id(const std::string& id) {
  static const std::regex pattern("^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$");
  return std::regex_match(id, pattern);
}

Status add_station(PgConnection& pg, const std::string& station_id, const std::string& db_role,
                   const std::string& description) {
  if (!valid_station_id(station_id)) {
    return Error::Permanent(fmt::format(
        "station id '{}' is not valid: 1 to 64 letters, digits, '.', '_' or '-', starting with "
        "a letter or digit",
        station_id));
  }
  if (auto s = check_role_name(db_role); !s.ok()) return s;
  if (auto s = require_schema(pg); !s.ok()) return s;

  internal::PgTransaction tx(pg);
  if (auto s = tx.begin(); !s.ok()) return s;
  // Serialise registrations (two administrators at once): the checks below
  // then see each other's rows.
  if (auto r = pg.exec("LOCK TABLE lab.stations IN SHARE ROW EXCLUSIVE MODE"); !r.ok()) {
    return r.error();
  }
  auto taken = pg.exec_params(
      "SELECT station_id, db_role::text FROM lab.stations WHERE station_id = $1 OR db_role = $2",
      {station_id, db_role});
  if (!taken.ok()) return taken.error();
  bool registered = false;
  for (const auto& row : taken->rows) {
    const std::string& id = *row[0];
    const std::string& role = *row[1];
    if (id == station_id && role == db_role) {
      registered = true;
    } else if (id == station_id) {
      return Error::Permanent(fmt::format(
          "station id '{}' is already registered to role '{}', not '{}'", id, role, db_role));
    } else {
      return Error::Permanent(fmt::format(
          "role '{}' is already registered for station id '{}', not '{}'", role, id, station_id));
    }
  }
  if (registered) return {};  // the same pair again: nothing to do (the transaction rolls back)
  if (auto s = ensure_login_member(pg, db_role, "gyrotherm_station"); !s.ok()) return s;
  auto inserted = pg.exec_params(
      "INSERT INTO lab.stations(station_id, db_role, description) VALUES ($1, $2, $3)",
      {station_id, db_role, description});
  if (!inserted.ok()) return inserted.error();
  return tx.commit();
}

Status check_station(PgConnection& pg, const std::string& station_id) {
  const std::string role = login_role(pg);
  auto rows =
      pg.exec_params("SELECT db_role::text FROM lab.stations WHERE station_id = $1", {station_id});
  if (!rows) {
    const std::string& state = pg.last_sqlstate();
    if (state == "42501") {
      return Error::Permanent(fmt::format(
          "the lab refused station id '{}' for role '{}': the role may not read lab.stations "
          "(is it a member of gyrotherm_station? `gyrotherm lab add-station {} --role {}` makes "
          "it one) ({})",
          station_id, role, station_id, role, rows.error().message));
    }
    if (state == "42P01" || state == "3F000") {
      return Error::Permanent(fmt::format(
          "lab database {} has no lab schema: an administrator runs `gyrotherm lab migrate` ({})",
          pg.server(), rows.error().message));
    }
    return rows.error();
  }
  if (rows->rows.empty()) {
    return Error::Permanent(fmt::format(
        "the lab refused station id '{}' for role '{}': the id is not registered in lab.stations "
        "(an administrator registers it: `gyrotherm lab add-station {} --role {}`)",
        station_id, role, station_id, role));
  }
  const std::string owner = rows->rows[0][0].value_or("");
  if (owner != role) {
    return Error::Permanent(fmt::format(
        "the lab refused station id '{}' for role '{}': the id is registered to role '{}' (a "
        "wrong station_id in [lab], or another station's credentials)",
        station_id, role, owner));
  }
  return {};
}

Status add_reader(PgConnection& pg, const std::string& db_role) {
  if (auto s = check_role_name(db_role); !s.ok()) return s;
  if (auto s = require_schema(pg); !s.ok()) return s;
  internal::PgTransaction tx(pg);
  if (auto s = tx.begin(); !s.ok()) return s;
  if (auto s = ensure_login_member(pg, db_role, "gyrotherm_reader"); !s.ok()) return s;
  return tx.commit();
}

// The counts are over the batch's distinct keys (upserted + redelivered +
// stale = keys); relay_progress.records counts every record received.
Result<PushResult> push_batch(PgConnection& pg, const std::string& station_id,
                              std::span<const storage::OutboxRecord> batch) {
  if (batch.empty()) return PushResult{};  // nothing to say, not even progress
  int64_t last_seq = 0;
  for (const auto& r : batch) last_seq = std::max(last_seq, r.seq);
  const std::string rows = batch_json(batch).dump();
  auto result = pg.exec_params(
      kPushSql, {rows, station_id, std::to_string(last_seq), std::to_string(batch.size())});
  if (!result.ok()) {
    const std::string what =
        fmt::format("batch of {} records (outbox seq {} to {}) from station '{}'", batch.size(),
                    batch.front().seq, batch.back().seq, station_id);
    const std::string& state = pg.last_sqlstate();
    const bool refused = std::find(std::begin(kRefusedSqlstates), std::end(kRefusedSqlstates),
                                   state) != std::end(kRefusedSqlstates);
    if (refused) {
      const std::string role = login_role(pg);
      std::string why = refusal_reason(pg, station_id, role);
      return Error::Permanent(fmt::format("the lab refused station id '{}' for role '{}': {}{}({})",
                                          station_id, role, why, why.empty() ? "" : " ",
                                          result.error().message));
    }
    return Error{fmt::format("{}: {}", what, result.error().message), result.error().transient};
  }
  const auto& row = result->rows.at(0);
  PushResult out;
  out.upserted = std::stoll(row[0].value_or("0"));
  out.redelivered = std::stoll(row[1].value_or("0"));
  out.stale = std::stoll(row[2].value_or("0"));
  return out;
}

}  // namespace gyrotherm::lab
